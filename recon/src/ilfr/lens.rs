//! Section 3.4, "Motion and Defocus": the same machinery on primary rays. Instead of secondary
//! rays, the input rays are the camera rays of a `lens-time` file — from a point on the lens to
//! their first hit — and the reconstruction rays are new camera rays through the pixel and the
//! lens (design: docs/ilfr-design.md, slice 10).
//!
//! Paper → code:
//! - "we now store the primary rays cast from a lens": [`read_primary_rays`] turns each record
//!   (x, y, u, v, z, radiance, depth gradient) into an input ray in camera space (X right, Y
//!   down, Z forward, lens centre at the origin): from the lens point L = (a·u, a·v, 0) through
//!   the focus-plane point F·((x − cx)/fx, (y − cy)/fy, 1) to the hit at depth z,
//!   P = L(1 − z/F) + z·((x − cx)/fx, (y − cy)/fy, 1). Splats sit at P. A miss (z = +∞) is an
//!   escaped ray carrying the environment.
//! - The hit normal (our `lens-time` files carry none; design gap G5) from the depth gradient
//!   (∂z/∂x, ∂z/∂y at fixed (u, v)): n ∝ ∂P/∂x × ∂P/∂y with ∂P/∂x = (z/fx, 0, 0) + z_x ∂P/∂z
//!   and ∂P/∂z = −L/F + ((x − cx)/fx, (y − cy)/fy, 1) — exact for the flat triangle the ray hit.
//!   Where the gradient is not finite or the tangents are parallel (a grazing hit), the splat
//!   faces its ray (counted).
//! - "reconstruct the incident temporal light field at different points on the lens":
//!   [`gather_lens`] traces `rays_per_pixel` reconstruction rays per pixel, pixel positions and
//!   lens points from two Owen-scrambled Sobol' sequences (the lens one on a shuffled index so
//!   the two stay independent), and averages RECONSTRUCT over the rays with support (the sky
//!   fallback of the final gather for rays that meet no splat; the pixel's own samples when no
//!   ray has support).
//! - Sizing (§2.2), the hierarchy, shrinking (§2.3.1, retracing every input camera ray) and
//!   apparent surfaces (§2.3.2) are the unchanged modules.
//!
//! - Motion: a record's `motion` (camera-space displacement of its hit over the shutter) makes its
//!   splat translate: the disc is indexed where it is at time 0.5 (sizing finds the neighbours of
//!   a moving surface among its samples of all times), its box holds it over the whole shutter,
//!   and every ray (input rays at their sample's `t`, reconstruction rays at a third scrambled
//!   Sobol' dimension) meets it where it is at the ray's time (`disc::Disc::centre_at`).
//!   Translation only, as the tracer's meshes move; the normal does not turn.
//!
//! Choices: every splat is filtered as diffuse (κ is not read): across the lens the view
//! direction changes by at most 2a/z rad, a few degrees in our scenes, and the glossy nearest
//! neighbour made the monkeys worse (docs/history/ilfr.md).

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use sampleio::{SampleFile, SampleKind};

use super::disc::Ray;
use shading::sampling::{hash_u32, laine_karras_permutation, sobol_2d_scrambled};

use super::gather::{assemble_rows, sky_samples, GatherSettings, GatherStats};
use super::reconstruct::{Reconstructor, Scratch};
use super::samples::{IndirectSamples, SampleClass};
use crate::error::Error;
use crate::image::Image;

/// The thin-lens camera of a `lens-time` header, in camera space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensCamera {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// Lens radius (0: pinhole).
    pub aperture: f32,
    /// Depth of the plane in focus.
    pub focus: f32,
}

impl LensCamera {
    pub fn from_header(camera: &sampleio::Camera) -> Result<LensCamera, Error> {
        let model = crate::tlfr::lens::LensModel::from_camera(camera)?;
        let (aperture, focus) = (camera.aperture_radius as f32, camera.focus_distance as f32);
        if !(aperture.is_finite() && aperture >= 0.0 && focus.is_finite() && focus > 0.0) {
            let message = format!("camera: aperture {aperture} and focus distance {focus} are not a thin lens");
            return Err(Error::parameter("camera", message));
        }
        Ok(LensCamera { fx: model.fx, fy: model.fy, cx: model.cx, cy: model.cy, aperture, focus })
    }

    /// The point on the lens for unit-disk coordinates (u, v).
    pub fn lens_point(&self, u: f32, v: f32) -> Vec3 {
        Vec3::new(self.aperture * u, self.aperture * v, 0.0)
    }

    /// Pixel (x, y) on the plane z = 1 through the lens centre.
    fn film_direction(&self, x: f32, y: f32) -> Vec3 {
        Vec3::new((x - self.cx) / self.fx, (y - self.cy) / self.fy, 1.0)
    }

    /// The camera ray of film point (x, y) and lens point (u, v).
    pub fn ray(&self, x: f32, y: f32, u: f32, v: f32) -> Ray {
        let lens = self.lens_point(u, v);
        let direction = (self.film_direction(x, y) * self.focus - lens).normalize();
        Ray { time: 0.0, origin: lens.to_array(), direction: direction.to_array() }
    }

    /// Where that ray reaches depth z.
    pub fn hit_point(&self, x: f32, y: f32, u: f32, v: f32, z: f32) -> Vec3 {
        self.lens_point(u, v) * (1.0 - z / self.focus) + self.film_direction(x, y) * z
    }

    /// The unit normal of the surface whose depth along the rays of lens point (u, v) changes
    /// by (z_x, z_y) per pixel, facing the lens; `None` when it is not determined.
    pub fn normal_from_depth_gradient(
        &self,
        x: f32,
        y: f32,
        u: f32,
        v: f32,
        z: f32,
        gradient: [f32; 2],
    ) -> Option<Vec3> {
        let lens = self.lens_point(u, v);
        let along_depth = self.film_direction(x, y) - lens / self.focus;
        let tangent_x = Vec3::new(z / self.fx, 0.0, 0.0) + along_depth * gradient[0];
        let tangent_y = Vec3::new(0.0, z / self.fy, 0.0) + along_depth * gradient[1];
        let normal = tangent_x.cross(tangent_y).normalize_or_zero();
        if normal == Vec3::ZERO || !normal.is_finite() {
            return None;
        }
        let to_lens = lens - self.hit_point(x, y, u, v, z);
        Some(if normal.dot(to_lens) < 0.0 { -normal } else { normal })
    }
}

/// What [`read_primary_rays`] had to work around.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PrimaryRayStats {
    /// Hits whose normal the depth gradient did not determine (the splat faces its ray).
    pub normals_from_the_ray: usize,
}

/// A `lens-time` file as input rays in camera space: sample i is camera ray i, from its lens
/// point (`primary_hit`) to its hit (`secondary_hit`, where it was at the sample's time), with
/// the time and the hit's motion when the file has them. Errors name the file, field and sample.
pub fn read_primary_rays(file: &SampleFile) -> Result<(IndirectSamples, LensCamera, PrimaryRayStats), Error> {
    let path = file.path().display().to_string();
    let content = |message: String| Error::sample_content(file.path(), message);
    let header = file.header();
    if header.kind != SampleKind::LensTime {
        return Err(content(format!(
            "the lens mode reads `lens-time` samples, the file holds `{}`",
            header.kind.name()
        )));
    }
    file.check_needs(&crate::needs::ILFR_LENS)?;
    let camera = header.camera.as_ref().ok_or_else(|| content("the header has no `camera` block".to_string()))?;
    let camera = LensCamera::from_header(camera).map_err(|e| content(e.to_string()))?;
    let column = |name: &str, components: u32, required: bool| -> Result<Option<Vec<f32>>, Error> {
        match file.field(name) {
            None if required => Err(content(format!("`lens-time` samples lack the field `{name}`"))),
            None => Ok(None),
            Some(f) if f.components != components => {
                Err(content(format!("field `{name}` has {} components, {components} expected", f.components)))
            }
            Some(_) => Ok(Some(file.column(name)?)),
        }
    };
    let (x, y, z) = (column("x", 1, true)?, column("y", 1, true)?, column("z", 1, true)?);
    let (radiance, gradient) = (column("radiance", 3, true)?, column("depth_gradient", 2, true)?);
    let (x, y, z, radiance, gradient) = (
        x.unwrap_or_default(),
        y.unwrap_or_default(),
        z.unwrap_or_default(),
        radiance.unwrap_or_default(),
        gradient.unwrap_or_default(),
    );
    let (u, v) = (column("u", 1, false)?, column("v", 1, false)?);
    if u.is_some() != v.is_some() {
        return Err(content("the file has only one of the lens fields `u`, `v`".to_string()));
    }
    let (time, motion) = (column("t", 1, false)?, column("motion", 3, false)?);
    if motion.is_some() && time.is_none() {
        return Err(content("the file has `motion` but no time field `t`".to_string()));
    }
    let bad = |name: &str, i: usize, what: String| content(format!("field `{name}` of sample {i} is {what}"));
    let n = file.len();
    let mut samples =
        IndirectSamples::empty(path.clone(), SampleKind::LensTime, (header.width, header.height, header.spp), n);
    let mut radiances = Vec::with_capacity(n);
    let mut stats = PrimaryRayStats::default();
    samples.time = time.as_ref().map(|_| Vec::with_capacity(n));
    samples.secondary_motion = motion.as_ref().map(|_| Vec::with_capacity(n));
    for i in 0..n {
        let (sx, sy) = (x[i], y[i]);
        let (su, sv) = (u.as_ref().map_or(0.0, |u| u[i]), v.as_ref().map_or(0.0, |v| v[i]));
        for (name, value) in [("x", sx), ("y", sy), ("u", su), ("v", sv)] {
            if !value.is_finite() {
                return Err(bad(name, i, format!("{value}, not finite")));
            }
        }
        let sample_time = time.as_ref().map_or(0.0, |t| t[i]);
        if !(0.0..=1.0).contains(&sample_time) {
            return Err(bad("t", i, format!("{sample_time}, not in [0, 1]")));
        }
        let sample_motion = motion.as_ref().map_or([0.0; 3], |m| [m[3 * i], m[3 * i + 1], m[3 * i + 2]]);
        if !sample_motion.iter().all(|c| c.is_finite()) {
            return Err(bad("motion", i, format!("{sample_motion:?}, not finite")));
        }
        let colour = [radiance[3 * i], radiance[3 * i + 1], radiance[3 * i + 2]];
        if !colour.iter().all(|c| c.is_finite()) {
            return Err(bad("radiance", i, format!("{colour:?}, not finite")));
        }
        let depth = z[i];
        if depth.is_nan() || depth <= 0.0 {
            return Err(bad("z", i, format!("{depth}, not a depth > 0")));
        }
        let ray = camera.ray(sx, sy, su, sv);
        if let Some(times) = samples.time.as_mut() {
            times.push(sample_time);
        }
        if let Some(motions) = samples.secondary_motion.as_mut() {
            motions.push(sample_motion);
        }
        samples.film.push([sx, sy]);
        samples.primary_hit.push(ray.origin);
        samples.primary_normal.push([0.0, 0.0, 1.0]);
        samples.direction.push(ray.direction);
        radiances.push(colour);
        if depth == f32::INFINITY {
            samples.class.push(SampleClass::Escaped);
            samples.secondary_hit.push(ray.origin);
            samples.secondary_normal.push([0.0; 3]);
            continue;
        }
        let hit = camera.hit_point(sx, sy, su, sv, depth);
        let normal =
            match camera.normal_from_depth_gradient(sx, sy, su, sv, depth, [gradient[2 * i], gradient[2 * i + 1]]) {
                Some(n) => n,
                None => {
                    stats.normals_from_the_ray += 1;
                    -Vec3::from(ray.direction)
                }
            };
        samples.class.push(SampleClass::Hit);
        samples.secondary_hit.push(hit.to_array());
        samples.secondary_normal.push(normal.to_array());
    }
    samples.radiance = Some(radiances);
    Ok((samples, camera, stats))
}

/// Index shuffle (nested uniform scramble of the bit-reversed index), so that a second Sobol'
/// pair indexed by it is independent of the first.
fn shuffle(index: u32, seed: u32) -> u32 {
    laine_karras_permutation(index, seed)
}

/// The image of `rays_per_pixel` reconstruction rays per pixel through the pixel and the lens.
pub fn gather_lens(
    samples: &IndirectSamples,
    reconstructor: &Reconstructor,
    camera: &LensCamera,
    settings: &GatherSettings,
) -> Result<(Image, GatherStats), Error> {
    let radiance = samples.radiance.as_ref().ok_or_else(|| Error::sample_content(&samples.path, "no `radiance`"))?;
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1) as usize);
    if samples.len() != width as usize * height as usize * spp {
        let message = format!("{} samples for {width}x{height} pixels at {spp} spp", samples.len());
        return Err(Error::sample_content(&samples.path, message));
    }
    let n = settings.rays_per_pixel.max(1);
    let moving = samples.time.is_some();
    crate::progress::begin("gather", height as u64, "rows");
    let rows: Vec<(Vec<[f32; 3]>, GatherStats)> = (0..height)
        .into_par_iter()
        .map(|y| {
            let (mut scratch, mut stats, mut sky) = (Scratch::default(), GatherStats::default(), Vec::new());
            let row = (0..width)
                .map(|x| {
                    let pixel = y as usize * width as usize + x as usize;
                    let min_cosine = sky_samples(samples, x, y, settings.sky_pixel_radius, &mut sky)
                        .map(|spacing| (settings.sky_spacing_factor * spacing).min(std::f32::consts::PI).cos());
                    let seed = hash_u32(settings.seed ^ hash_u32(pixel as u32 ^ 0x2b7e_1516));
                    let (film_seed, lens_seed, shuffle_seed) =
                        (hash_u32(seed ^ 1), hash_u32(seed ^ 2), hash_u32(seed ^ 3));
                    let (time_seed, time_shuffle) = (hash_u32(seed ^ 4), hash_u32(seed ^ 5));
                    let (mut sum, mut supported) = ([0.0f64; 3], 0u32);
                    stats.primary_hits += 1; // here: pixels gathered
                    for j in 0..n {
                        let (fx, fy) = sobol_2d_scrambled(j, film_seed);
                        let (lu, lv) = sobol_2d_scrambled(shuffle(j, shuffle_seed), lens_seed);
                        let lens = shading::concentric_disk(Vec2::new(lu, lv));
                        let mut ray = camera.ray(x as f32 + fx, y as f32 + fy, lens.x, lens.y);
                        if moving {
                            ray.time = sobol_2d_scrambled(shuffle(j, time_shuffle), time_seed).0;
                        }
                        let value = reconstructor.radiance_or_sky(
                            &ray,
                            (&sky, min_cosine),
                            &mut scratch,
                            &mut stats.reconstruct,
                            &mut stats.fallbacks,
                        );
                        if let Some(l) = value {
                            for c in 0..3 {
                                sum[c] += l[c] as f64;
                            }
                            supported += 1;
                        }
                    }
                    if supported > 0 {
                        return sum.map(|s| (s / supported as f64) as f32);
                    }
                    // No ray found support: the pixel's own samples (the box value).
                    stats.unsupported_hits += 1;
                    let mut own = [0.0f64; 3];
                    for l in &radiance[pixel * spp..(pixel + 1) * spp] {
                        for c in 0..3 {
                            own[c] += l[c] as f64 / spp as f64;
                        }
                    }
                    own.map(|s| s as f32)
                })
                .collect();
            crate::progress::advance(1);
            (row, stats)
        })
        .collect();
    crate::progress::end();
    Ok(assemble_rows(width, height, rows))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ilfr::pipeline::GatherTarget;
    use crate::ilfr::pipeline::{reconstruct_samples, IlfrSettings};
    use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleWriter};

    const APERTURE: f32 = 0.4;

    /// The TLFR tests' camera (64×48, fx = fy = 80, focus 4) with a wider lens.
    fn header_camera() -> sampleio::Camera {
        let mut camera = crate::tlfr::lens::tests::camera();
        camera.aperture_radius = APERTURE as f64;
        camera.coc = sampleio::Coc { c1: -80.0 * APERTURE as f64, c2: 80.0 * APERTURE as f64 / 4.0 };
        camera
    }

    fn lens_camera() -> LensCamera {
        LensCamera::from_header(&header_camera()).unwrap()
    }

    /// A disc of radius 1.5 about `CENTRE` with normal `plane_normal()`, radiance varying over
    /// it; the sky behind has radiance 0.2.
    const CENTRE: [f32; 3] = [0.3, 0.2, 6.0];

    fn plane_normal() -> Vec3 {
        Vec3::new(0.3, -0.2, -1.0).normalize()
    }

    fn radiance_at(p: Vec3) -> f32 {
        0.5 + 0.4 * (3.0 * p.x).sin() * (2.0 * p.y).cos()
    }

    /// The disc's centre at the ray's time when it translates by `motion` over the shutter.
    fn centre(ray: &Ray, motion: Vec3) -> Vec3 {
        Vec3::from(CENTRE) + motion * (ray.time - 0.5)
    }

    /// Where `ray` meets the disc's plane (at its time), if inside the disc: the point and its
    /// position on the texture, which moves with the disc.
    fn hit(ray: &Ray, motion: Vec3) -> Option<(Vec3, Vec3)> {
        let (o, d, c) = (Vec3::from(ray.origin), Vec3::from(ray.direction), centre(ray, motion));
        let t = (c - o).dot(plane_normal()) / d.dot(plane_normal());
        let p = o + d * t;
        (t > 0.0 && (p - c).length() < 1.5).then_some((p, p - c + Vec3::from(CENTRE)))
    }

    fn trace(ray: &Ray) -> Option<f32> {
        hit(ray, Vec3::ZERO).map(|(p, _)| p.z)
    }

    fn radiance_along(ray: &Ray, motion: Vec3) -> f32 {
        hit(ray, motion).map_or(0.2, |(_, texture)| radiance_at(texture))
    }

    #[test]
    fn thin_lens_rays_meet_in_the_focus_plane_and_hits_lie_on_their_rays() {
        let camera = lens_camera();
        let (x, y) = (20.3, 31.7);
        let in_focus = camera.hit_point(x, y, 0.0, 0.0, 4.0);
        for (u, v) in [(0.5, -0.3), (-0.9, 0.1), (0.0, 0.7)] {
            assert!((camera.hit_point(x, y, u, v, 4.0) - in_focus).length() < 1e-5);
            let ray = camera.ray(x, y, u, v);
            let p = camera.hit_point(x, y, u, v, 7.5);
            assert!((p.z - 7.5).abs() < 1e-5);
            let along = (p - Vec3::from(ray.origin)).normalize();
            assert!((along - Vec3::from(ray.direction)).length() < 1e-5);
        }
        // The pinhole image of the lens centre ray: the pixel back through the intrinsics.
        let p = camera.hit_point(x, y, 0.0, 0.0, 2.0);
        assert!((80.0 * p.x / p.z + 32.0 - x).abs() < 1e-4 && (80.0 * p.y / p.z + 24.0 - y).abs() < 1e-4);
    }

    #[test]
    fn the_depth_gradient_gives_the_plane_normal() {
        let camera = lens_camera();
        for (x, y, u, v) in [(36.0, 27.0, 0.0, 0.0), (25.5, 35.2, 0.6, -0.5), (45.0, 18.0, -0.7, 0.7)] {
            let depth = |x: f32, y: f32| trace(&camera.ray(x, y, u, v)).unwrap();
            let h = 0.01;
            let gradient =
                [(depth(x + h, y) - depth(x - h, y)) / (2.0 * h), (depth(x, y + h) - depth(x, y - h)) / (2.0 * h)];
            let n = camera.normal_from_depth_gradient(x, y, u, v, depth(x, y), gradient).unwrap();
            assert!((n - plane_normal()).length() < 2e-3, "({x}, {y}, {u}, {v}): {n} vs {}", plane_normal());
        }
        assert_eq!(camera.normal_from_depth_gradient(3.0, 3.0, 0.0, 0.0, 5.0, [f32::NAN, 0.0]), None);
    }

    /// `spp` samples per pixel of the disc translating by `motion` (with `t` and `motion`
    /// fields when it is `Some`; `motion` without `t` when `time_field` is false).
    fn write_samples(dir: &std::path::Path, spp: u32, motion: Option<Vec3>, time_field: bool) -> std::path::PathBuf {
        let camera = lens_camera();
        let mut spec = HeaderSpec::new(SampleKind::LensTime, 64, 48, spp);
        for (name, n) in [("x", 1), ("y", 1), ("u", 1), ("v", 1), ("z", 1), ("radiance", 3), ("depth_gradient", 2)] {
            spec = spec.field(FieldSpec::new(name, FieldType::F32, n));
        }
        if motion.is_some() {
            if time_field {
                spec = spec.field(FieldSpec::new("t", FieldType::F32, 1));
            }
            spec = spec.field(FieldSpec::new("motion", FieldType::F32, 3));
        }
        let moving = motion.unwrap_or(Vec3::ZERO);
        spec.camera = Some(header_camera());
        let path = dir.join("lens.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        let mut state = 99u32;
        let mut next = || {
            state = hash_u32(state.wrapping_add(0x9e37_79b9));
            (state >> 8) as f32 / (1u32 << 24) as f32
        };
        for y in 0..48 {
            for x in 0..64 {
                for _ in 0..spp {
                    let (fx, fy) = (x as f32 + next(), y as f32 + next());
                    let lens = shading::concentric_disk(Vec2::new(next(), next()));
                    let time = if motion.is_some() { next() } else { 0.5 };
                    let ray = Ray { time, ..camera.ray(fx, fy, lens.x, lens.y) };
                    let (z, gradient) = match hit(&ray, moving) {
                        Some((p, _)) => {
                            // The plane at this time, along the rays of this lens point.
                            let c = centre(&ray, moving);
                            let depth = |x: f32, y: f32| {
                                let r = camera.ray(x, y, lens.x, lens.y);
                                let (o, d) = (Vec3::from(r.origin), Vec3::from(r.direction));
                                let t = (c - o).dot(plane_normal()) / d.dot(plane_normal());
                                (o + d * t).z
                            };
                            let (dx, dy) = (
                                (depth(fx + 0.01, fy) - depth(fx - 0.01, fy)) / 0.02,
                                (depth(fx, fy + 0.01) - depth(fx, fy - 0.01)) / 0.02,
                            );
                            (p.z, [dx, dy])
                        }
                        None => (f32::INFINITY, [0.0, 0.0]),
                    };
                    let l = radiance_along(&ray, moving);
                    let mut row = vec![fx, fy, lens.x, lens.y, z, l, l, l, gradient[0], gradient[1]];
                    if motion.is_some() {
                        if time_field {
                            row.push(time);
                        }
                        row.extend(moving.to_array());
                    }
                    writer.push(&row).unwrap();
                }
            }
        }
        writer.finish().unwrap()
    }

    /// ILFR's image of the disc (translating by `motion`) from `spp` samples, and the mean
    /// absolute errors of it and of the box average of the same samples against a 1024-ray
    /// brute force over pixel, lens and shutter; and how many pixels straddle the rim.
    fn errors_against_brute_force(spp: u32, motion: Option<Vec3>) -> (f64, f64, u32) {
        let dir = tempfile::tempdir().unwrap();
        let file = SampleFile::open(write_samples(dir.path(), spp, motion, true)).unwrap();
        let (samples, camera, stats) = read_primary_rays(&file).unwrap();
        assert_eq!(stats.normals_from_the_ray, 0);
        let settings = IlfrSettings { recon_rays: 256, ..IlfrSettings::default() };
        let result = reconstruct_samples(&samples, GatherTarget::Lens(camera), &settings).unwrap();
        let radiance = samples.radiance.as_ref().unwrap();
        let moving = motion.unwrap_or(Vec3::ZERO);
        let (mut ilfr_error, mut box_error, mut edge_pixels) = (0.0f64, 0.0f64, 0);
        for y in 0..48u32 {
            for x in 0..64u32 {
                let mut sum = 0.0f64;
                let n = 1024u32;
                let (mut on_disc, mut off_disc) = (false, false);
                for j in 0..n {
                    let (fx, fy) = sobol_2d_scrambled(j, 5);
                    let (lu, lv) = sobol_2d_scrambled(shuffle(j, 11), 7);
                    let time = if motion.is_some() { sobol_2d_scrambled(shuffle(j, 13), 17).0 } else { 0.5 };
                    let lens = shading::concentric_disk(Vec2::new(lu, lv));
                    let ray = Ray { time, ..camera.ray(x as f32 + fx, y as f32 + fy, lens.x, lens.y) };
                    sum += radiance_along(&ray, moving) as f64;
                    match hit(&ray, moving) {
                        Some(_) => on_disc = true,
                        None => off_disc = true,
                    }
                }
                let expected = sum / n as f64;
                edge_pixels += (on_disc && off_disc) as u32;
                let pixel = (y * 64 + x) as usize;
                let own: f64 =
                    radiance[pixel * spp as usize..(pixel + 1) * spp as usize].iter().map(|l| l[0] as f64).sum::<f64>()
                        / spp as f64;
                let got = result.image.get(x, y)[0] as f64;
                assert!(got.is_finite());
                ilfr_error += (got - expected).abs() / (64.0 * 48.0);
                box_error += (own - expected).abs() / (64.0 * 48.0);
            }
        }
        (ilfr_error, box_error, edge_pixels)
    }

    #[test]
    fn a_defocused_textured_disc_before_the_sky_is_reconstructed_better_than_its_samples() {
        let (ilfr_error, box_error, edge_pixels) = errors_against_brute_force(4, None);
        assert!(edge_pixels > 50, "the disc's blurred rim covers {edge_pixels} pixels");
        assert!(ilfr_error < 0.5 * box_error && ilfr_error < 0.01, "ilfr {ilfr_error}, box {box_error}");
    }

    #[test]
    fn a_moving_defocused_disc_is_reconstructed_better_than_its_samples() {
        // 0.8 units sideways and 0.5 towards the camera over the shutter: about 11 pixels of
        // motion blur at depth 6, on top of the defocus.
        let (ilfr_error, box_error, edge_pixels) = errors_against_brute_force(4, Some(Vec3::new(0.8, 0.0, -0.5)));
        assert!(edge_pixels > 150, "the moving rim covers {edge_pixels} pixels");
        assert!(ilfr_error < 0.6 * box_error, "ilfr {ilfr_error}, box {box_error}");
    }

    /// One 1×1 file with the given (z, t, motion z) records.
    fn one_pixel_file(dir: &std::path::Path, records: &[(f32, f32, f32)]) -> std::path::PathBuf {
        let mut spec = HeaderSpec::new(SampleKind::LensTime, 1, 1, records.len() as u32);
        for (name, n) in [
            ("x", 1),
            ("y", 1),
            ("u", 1),
            ("v", 1),
            ("z", 1),
            ("radiance", 3),
            ("depth_gradient", 2),
            ("t", 1),
            ("motion", 3),
        ] {
            spec = spec.field(FieldSpec::new(name, FieldType::F32, n));
        }
        let mut camera = header_camera();
        camera.pixel_to_camera[0][2] = -0.5 / 80.0; // principal point at the single pixel's centre
        camera.pixel_to_camera[1][2] = -0.5 / 80.0;
        spec.camera = Some(camera);
        let path = dir.join("one.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        for &(z, t, motion_z) in records {
            writer.push(&[0.5, 0.5, 0.3, -0.2, z, 1.0, 2.0, 3.0, 0.0, 0.0, t, 0.0, 0.0, motion_z]).unwrap();
        }
        writer.finish().unwrap()
    }

    #[test]
    fn one_pixel_depth_near_zero_and_motion_through_the_lens_stay_finite() {
        // A 1×1 image whose samples hit a wall 1e-3 and 0.5 in front of the lens that moves 12 units
        // towards and through the camera over the shutter: at most times the wall is behind the
        // lens. The pixel is a weighted mean of the samples (radiance (1, 2, 3)) or the sky.
        let dir = tempfile::tempdir().unwrap();
        let path = one_pixel_file(
            dir.path(),
            &[(1e-3, 0.0, -12.0), (0.5, 0.02, -12.0), (0.5, 0.9, -12.0), (f32::INFINITY, 0.5, 0.0)],
        );
        let (samples, camera, _) = read_primary_rays(&SampleFile::open(&path).unwrap()).unwrap();
        let settings = IlfrSettings { recon_rays: 64, ..IlfrSettings::default() };
        let result = reconstruct_samples(&samples, GatherTarget::Lens(camera), &settings).unwrap();
        let p = result.image.get(0, 0);
        assert!(p.iter().all(|v| v.is_finite()), "{p:?}");
        for (c, top) in [1.0f32, 2.0, 3.0].into_iter().enumerate() {
            assert!(p[c] >= 0.0 && p[c] <= top * (1.0 + 1e-5), "{p:?}");
        }
    }

    #[test]
    fn bad_depths_and_times_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        for (record, field) in [
            ((f32::NAN, 0.5, 0.0), "`z`"),
            ((0.0, 0.5, 0.0), "`z`"),
            ((1.0, 1.5, 0.0), "`t`"),
            ((1.0, 0.5, f32::NAN), "`motion`"),
        ] {
            let path = one_pixel_file(dir.path(), &[record]);
            let error = read_primary_rays(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
            assert!(error.contains("one.lfrs") && error.contains(field), "{record:?}: {error}");
        }
    }

    #[test]
    fn motion_without_time_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let file = SampleFile::open(write_samples(dir.path(), 1, Some(Vec3::X), false)).unwrap();
        let error = read_primary_rays(&file).unwrap_err().to_string();
        assert!(error.contains("lens.lfrs") && error.contains("`t`"), "{error}");
    }
}
