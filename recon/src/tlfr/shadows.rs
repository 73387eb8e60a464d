//! Soft shadows from a planar area light (paper Section 5, Appendix B): the 7D reconstruction
//! (x̂, ŷ, û, v̂, t̂, ũ, ṽ) as two 5D ones at the same time t̂.
//!
//! 1. The camera reconstruction at (x̂, ŷ, û, v̂, t̂) finds the covering surface
//!    (`query::covering_surface`); its samples' `radiance_without_light` (everything but the
//!    planar light's reflected light) is tent-filtered as usual, and its nearest sample gives
//!    the depth z' at t̂ of the visible point p, its albedo and normal.
//! 2. p, unprojected from the location's lens-centre position at depth z', is taken to light
//!    space at t̂; the light location is where the ray from the light point (ũ, ṽ) through p
//!    crosses Π (`light_space`).
//! 3. The light reconstruction there, over the `light` samples reprojected exactly like camera
//!    samples (the light's rectangle is their lens), with radius R·ρ (ρ the receiver's
//!    `density`, Appendix B), finds the covering surface as seen from the light (a surface in
//!    front of p also at the rim of its silhouette, `query::covering_blocker`): each of its
//!    samples carries the light's radiance if it reaches p (its depth at t̂ is not in front of
//!    p's, "L = 0 for light samples that end before the receiver") and 0 otherwise; the tent
//!    filter of those values is the light arriving from (ũ, ṽ).
//! 4. The location's value is the camera part plus the Lambertian direct term of that light
//!    (`light_space::lambertian_direct`): one light point per location, so Eq. 1's average over
//!    N locations integrates over the light's area too.
//!
//! Choices the paper leaves open (docs/tlfr-design.md §3 #15): the receiver is shaded with its
//! albedo as a Lambertian surface (the tracer's soft-shadow effect is direct light only; glossy
//! receivers are not handled); p lies on the tangent plane of the covering surface's nearest
//! sample (`visible_point`); the lit test compares each light sample's end with the depth at
//! which its ray from (ũ, ṽ) meets that plane (`ReceiverPlane`), less `SHADOW_BIAS_RELATIVE` of
//! it and `SHADOW_BIAS_FOOTPRINTS` filter radii (R·ρ), where the authors' code extrapolates
//! each light sample's own depth with its light-space depth gradient (format gap G2): either way
//! a receiver seen steeply from the light does not shadow itself. Receivers within
//! atan(1/`light_space::GRAZING_LIMIT`) of the light's plane, outside the light-space domain,
//! are lit without a shadow test (their light is below 5 % of normal incidence).

use sampleio::SampleFile;

use super::coverage::tent_filter;
use super::fused::{Entries, Fused, FusedScratch, LitTest, Query};
use super::light_space::{decode_octahedral, lambertian_direct, LightSpace};
use super::query::{covering_blocker, covering_surface, QueryStats, Scene, Scratch};
use super::reprojection::{reproject, LensTime, LensTimeSample};
use super::samples::LensTimeSamples;
use crate::error::Error;

/// The lit test's depth tolerance relative to the receiver's light-space depth.
pub const SHADOW_BIAS_RELATIVE: f32 = 1e-3;
/// ... plus this many footprints R·ρ.
pub const SHADOW_BIAS_FOOTPRINTS: f32 = 2.0;

/// The soft-shadow fields of a `lens-time` file, aligned with its usable samples.
#[derive(Clone, Debug)]
pub struct Shading {
    pub albedo: Vec<[f32; 3]>,
    pub normal: Vec<[f32; 3]>,
    pub without_light: Vec<[f32; 3]>,
}

/// Reads `albedo`, `normal` and `radiance_without_light` for the samples `camera` kept.
pub fn read_shading(file: &SampleFile, camera: &LensTimeSamples) -> Result<Shading, Error> {
    file.check_needs(&crate::needs::TLFR_SOFT_SHADOW)?;
    let content = |message: String| Error::sample_content(file.path(), message);
    let required = |name: &str| {
        file.field(name).ok_or_else(|| {
            content(format!(
                "soft shadows need the lens-time field `{name}` (dump with `lfr dump --kind lens-time --soft-shadow`)"
            ))
        })
    };
    let (albedo, normal, without) = (required("albedo")?, required("normal")?, required("radiance_without_light")?);
    let mut shading = Shading {
        albedo: Vec::with_capacity(camera.samples.len()),
        normal: Vec::with_capacity(camera.samples.len()),
        without_light: Vec::with_capacity(camera.samples.len()),
    };
    for &i in &camera.file_index {
        let i = i as usize;
        let three = |field| [0, 1, 2].map(|c| file.value(i, field, c));
        let (a, w) = (three(albedo), three(without));
        if !a.iter().chain(&w).all(|v| v.is_finite()) {
            return Err(content(format!("sample {i} has a non-finite `albedo` or `radiance_without_light`")));
        }
        shading.albedo.push(a);
        shading.normal.push(decode_octahedral([file.value(i, normal, 0), file.value(i, normal, 1)]));
        shading.without_light.push(w);
    }
    Ok(shading)
}

/// The `light` samples as lens-time samples of the light's own "camera".
#[derive(Clone, Debug)]
pub struct LightSamples {
    pub space: LightSpace,
    pub samples: Vec<LensTimeSample>,
    pub radiance: Vec<[f32; 3]>,
    /// ρ of every record of the file (0 where it has no visible point), indexed like the
    /// camera file's records: record i of both files belongs to the same camera sample.
    pub density: Vec<f32>,
    /// The median ρ over the usable samples; one light-space unit is about this long on Π.
    pub median_density: f32,
    /// Records without a visible point or with unusable values.
    pub skipped: usize,
    /// Usable records whose ray ends outside the light-space domain (`LightSpace::is_grazing`),
    /// left out of the reconstruction.
    pub grazing: usize,
    /// The largest radiance among the usable samples: the emitter's, for receivers outside the
    /// light-space domain.
    pub emission: [f32; 3],
    /// The samples' screen positions span [0, extent] (light-space units).
    pub extent: [f32; 2],
}

/// Reads a `light` file written for the camera file of `camera_records` records.
pub fn read_light(file: &SampleFile, camera_records: usize) -> Result<LightSamples, Error> {
    let content = |message: String| Error::sample_content(file.path(), message);
    if file.header().kind != sampleio::SampleKind::Light {
        return Err(content(format!(
            "soft shadows read `light` samples, the file holds `{}`",
            file.header().kind.name()
        )));
    }
    if file.len() != camera_records {
        return Err(content(format!(
            "{} light samples for {camera_records} camera samples; both must come from one seed and spp",
            file.len()
        )));
    }
    file.check_needs(&crate::needs::TLFR_LIGHT)?;
    let mut space = LightSpace::from_file(file)?;
    let required = |name: &str| file.field(name).ok_or_else(|| content(format!("`light` samples lack `{name}`")));
    let (lu, lv, lx, ly) = (required("lu")?, required("lv")?, required("lx")?, required("ly")?);
    let (z, radiance, density) = (required("z")?, required("radiance")?, required("density")?);
    let (t, motion) = (file.field("t"), file.field("motion"));
    let mut densities = Vec::with_capacity(file.len());
    let mut raw = Vec::with_capacity(file.len());
    let mut skipped = 0;
    for i in 0..file.len() {
        let value = |field, c| file.value(i, field, c);
        let rho = value(density, 0);
        let sample = LensTimeSample {
            x: value(lx, 0),
            y: value(ly, 0),
            u: 2.0 * value(lu, 0) - 1.0,
            v: 2.0 * value(lv, 0) - 1.0,
            t: t.map_or(0.5, |f| value(f, 0)),
            z: value(z, 0),
            motion: motion.map_or([0.0; 3], |f| [value(f, 0), value(f, 1), value(f, 2)]),
        };
        let colour = [0, 1, 2].map(|c| value(radiance, c));
        let usable = rho > 0.0
            && rho.is_finite()
            && sample.z > 0.0
            && sample.z.is_finite()
            && [sample.x, sample.y, sample.u, sample.v].iter().all(|c| c.is_finite())
            && (0.0..=1.0).contains(&sample.t)
            && sample.motion.iter().chain(&colour).all(|c| c.is_finite());
        densities.push(if usable { rho } else { 0.0 });
        if usable {
            raw.push((sample, colour));
        } else {
            skipped += 1;
        }
    }
    let mut sorted: Vec<f32> = densities.iter().copied().filter(|&d| d > 0.0).collect();
    sorted.sort_by(f32::total_cmp);
    let median_density = sorted.get(sorted.len() / 2).copied().unwrap_or(1.0);
    space.scale = 0.5 * (space.width_u * space.width_v).sqrt() / median_density;
    let emission = raw.iter().fold([0.0f32; 3], |m, (_, c)| [0, 1, 2].map(|k| m[k].max(c[k])));
    // Rays that end just below the light's plane cross Π far away (l_x ∝ 1/z): one such sample
    // made the offset below 1e7 units at 64×48 on the Cornell box, where f32 positions are
    // 1 unit apart, far coarser than the filter radius R·ρ (0.1 unit on the walls), and the lit
    // test then compared samples reprojected to the wrong places. Only the domain of
    // `LightSpace::is_grazing` is reconstructed.
    let before = raw.len();
    raw.retain(|(s, _)| !space.is_grazing(space.ray_end(s.u, s.v, s.x, s.y, s.z)));
    let grazing = before - raw.len();
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for (s, _) in &raw {
        let p = space.screen_of_crossing(s.x, s.y);
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    if raw.is_empty() {
        (lo, hi) = ([0.0; 2], [1.0; 2]);
    }
    space.offset = lo;
    let extent = [hi[0] - lo[0], hi[1] - lo[1]];
    let (samples, radiance) = raw
        .into_iter()
        .map(|(s, colour)| {
            let [x, y] = space.screen_of_crossing(s.x, s.y);
            (LensTimeSample { x, y, ..s }, colour)
        })
        .unzip();
    Ok(LightSamples {
        space,
        samples,
        radiance,
        density: densities,
        median_density,
        skipped,
        grazing,
        emission,
        extent,
    })
}

/// Camera-space to world: the header's pose.
#[derive(Clone, Copy, Debug)]
pub struct CameraPose {
    pub position: [f32; 3],
    /// World directions of camera X (right), Y (down), Z (forward).
    pub axes: [[f32; 3]; 3],
}

impl CameraPose {
    pub fn from_camera(camera: &sampleio::Camera) -> CameraPose {
        let f = |v: [f64; 3]| v.map(|c| c as f32);
        let rows = camera.world_to_camera;
        CameraPose {
            position: f(camera.position),
            axes: [0, 1, 2].map(|r| [rows[r][0] as f32, rows[r][1] as f32, rows[r][2] as f32]),
        }
    }

    /// The world point at camera-space (X, Y, Z).
    pub fn to_world(&self, camera_space: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|k| {
            self.position[k]
                + self.axes[0][k] * camera_space[0]
                + self.axes[1][k] * camera_space[1]
                + self.axes[2][k] * camera_space[2]
        })
    }
}

/// Counters of the shadow pass.
#[derive(Clone, Copy, Debug, Default)]
pub struct ShadowStats {
    pub camera: QueryStats,
    pub light: QueryStats,
    /// Locations whose visible point is lit or shadowed by the light reconstruction.
    pub shaded: u64,
    /// ... of which the light reconstruction found the light blocked.
    pub blocked: u64,
    /// Locations whose visible point lies outside the light-space domain
    /// (`LightSpace::is_grazing`), lit without a shadow test.
    pub grazing: u64,
}

impl super::integrate::Counters for ShadowStats {
    fn add(&mut self, other: &Self) {
        self.camera.add(&other.camera);
        self.light.add(&other.light);
        self.shaded += other.shaded;
        self.blocked += other.blocked;
        self.grazing += other.grazing;
    }
}

/// Everything a soft-shadow location reads.
pub struct ShadowScene<'a> {
    pub camera: &'a Scene<'a>,
    pub shading: &'a Shading,
    pub pose: CameraPose,
    pub light: &'a Scene<'a>,
    pub light_samples: &'a LightSamples,
    /// The light's area.
    pub area: f32,
    /// File record of each camera sample (`LensTimeSamples::file_index`).
    pub file_index: &'a [u32],
}

/// The light's side of a shaded location, from the visible point: where it lies in light space,
/// the light-view location and lens/time of the light point (ũ, ṽ), the light scene with R
/// scaled by the receiver's own light-sample density ρ (in units of the median), and the
/// receiver's plane.
struct LightSide<'a> {
    in_light: [f32; 3],
    light_screen: [f32; 2],
    light_at: LensTime,
    light_lens: &'a super::lens::LensModel,
    light_scene: Scene<'a>,
    plane: ReceiverPlane,
    /// The visible point p, its shading normal and albedo, and the light point in the world.
    receiver: [f32; 3],
    normal: [f32; 3],
    albedo: [f32; 3],
    light_point: [f32; 3],
}

impl LightSide<'_> {
    /// The direct light p reflects towards the camera from `arriving`, the light's radiance
    /// reconstructed at (ũ, ṽ) as seen from p.
    fn direct(&self, scene: &ShadowScene, arriving: [f32; 3]) -> [f32; 3] {
        let space = &scene.light_samples.space;
        lambertian_direct(self.albedo, self.normal, self.receiver, self.light_point, space.normal, scene.area, arriving)
    }
}

/// The steps from the visible point (camera-view position `moved` of sample `nearest`) to the
/// light's side, shared by the oracle and the fused path; `Err` holds the location's final
/// value where no shadow test is needed: `value` for a miss, a point above the light's plane
/// or one outside the light's view, `value` plus the unshadowed light where the receiver is
/// grazing (outside the light-space domain).
#[allow(clippy::too_many_arguments)]
fn light_side<'a>(
    scene: &ShadowScene<'a>,
    screen: [f32; 2],
    at: LensTime,
    moved: [f32; 3],
    nearest: usize,
    (light_u, light_v): (f32, f32),
    value: [f32; 3],
    stats: &mut ShadowStats,
) -> Result<LightSide<'a>, [f32; 3]> {
    let depth = moved[2];
    if !depth.is_finite() || scene.shading.normal[nearest] == [0.0; 3] {
        return Err(value); // a miss: nothing to shade
    }
    let normal = scene.shading.normal[nearest];
    let receiver = visible_point(scene.camera.lens, &scene.pose, screen, at, moved, normal);
    let space = &scene.light_samples.space;
    let in_light = space.to_light(receiver, at.t);
    if in_light[2].is_nan() || in_light[2] <= 0.0 {
        return Err(value); // above the light's plane: it cannot light p
    }
    if space.is_grazing(in_light) {
        // Outside the light-space domain: no shadow test, the emitter's radiance.
        stats.grazing += 1;
        let light_point = space.light_point(light_u, light_v, at.t);
        let albedo = scene.shading.albedo[nearest];
        let emission = scene.light_samples.emission;
        let direct = lambertian_direct(albedo, normal, receiver, light_point, space.normal, scene.area, emission);
        return Err([0, 1, 2].map(|c| value[c] + direct[c]));
    }
    let Some(light_centre) = space.centre_screen(in_light) else {
        return Err(value);
    };
    let light_lens = scene.light.lens;
    let light_coc = light_lens.coc(in_light[2]);
    let light_screen = [light_centre[0] + light_u * light_coc, light_centre[1] + light_v * light_coc];
    let light_at = LensTime { u: light_u, v: light_v, t: at.t };
    let record = scene.file_index[nearest] as usize;
    let rho = scene.light_samples.density.get(record).copied().filter(|&d| d > 0.0);
    let relative = rho.map_or(1.0, |d| d / scene.light_samples.median_density);
    let light_scene = Scene { radius: scene.light.radius * relative, ..*scene.light };
    stats.shaded += 1;
    let plane = ReceiverPlane::new(space, in_light, normal, light_u, light_v);
    let (albedo, light_point) = (scene.shading.albedo[nearest], space.light_point(light_u, light_v, at.t));
    Ok(LightSide {
        in_light,
        light_screen,
        light_at,
        light_lens,
        light_scene,
        plane,
        receiver,
        normal,
        albedo,
        light_point,
    })
}

/// Per-thread scratch of the two reconstructions.
#[derive(Default)]
pub struct ShadowScratch {
    camera: Scratch,
    light: Scratch,
    points: Vec<[f32; 2]>,
    values: Vec<[f32; 3]>,
}

/// The value at one location: (x̂, ŷ) = `screen`, (û, v̂, t̂) = `at`, light point (ũ, ṽ).
pub fn reconstruct_with_shadow(
    scene: &ShadowScene,
    screen: [f32; 2],
    at: LensTime,
    light_uv: (f32, f32),
    scratch: &mut ShadowScratch,
    stats: &mut ShadowStats,
) -> Option<[f32; 3]> {
    let radius = covering_surface(scene.camera, screen, at, &mut scratch.camera, &mut stats.camera)?;
    let covering = &scratch.camera.covering;
    scratch.values.clear();
    scratch.values.extend(covering.iter().map(|&i| scene.shading.without_light[i as usize]));
    let value = tent_filter(&scratch.camera.points, &scratch.values, screen, radius)?;

    // The visible point: the covering surface's sample nearest to the location.
    let squared = |p: [f32; 2]| (p[0] - screen[0]).powi(2) + (p[1] - screen[1]).powi(2);
    let Some((nearest, _)) = covering
        .iter()
        .zip(&scratch.camera.points)
        .min_by(|a, b| squared(*a.1).total_cmp(&squared(*b.1)).then(a.0.cmp(b.0)))
    else {
        return Some(value);
    };
    let nearest = *nearest as usize;
    let sample = &scene.camera.samples[nearest];
    let Some(moved) = reproject(sample, scene.camera.lens, at, scene.camera.z_near) else {
        return Some(value);
    };
    let side = match light_side(scene, screen, at, [moved.x, moved.y, moved.z], nearest, light_uv, value, stats) {
        Ok(side) => side,
        Err(done) => return Some(done),
    };
    let (in_light, light_screen, light_at, light_lens, plane) =
        (side.in_light, side.light_screen, side.light_at, side.light_lens, &side.plane);
    let light_scene = &side.light_scene;
    let reaches = |i: u32, footprint: f32| {
        let light_sample = &scene.light_samples.samples[i as usize];
        reproject(light_sample, light_lens, light_at, scene.light.z_near).is_some_and(|end| {
            let depth = plane.depth_at([end.x, end.y], in_light[2]);
            end.z >= depth - SHADOW_BIAS_RELATIVE * depth - SHADOW_BIAS_FOOTPRINTS * footprint
        })
    };
    // A surface in front of p keeps the rim of its silhouette (`query::takes_rim`).
    let first_footprint = light_scene.radius * scene.light_samples.median_density;
    let blocks = |i: u32| !reaches(i, first_footprint);
    let Some(light_radius) =
        covering_blocker(light_scene, light_screen, light_at, &blocks, &mut scratch.light, &mut stats.light)
    else {
        stats.blocked += 1;
        return Some(value); // no light sample within 16R: no light (counted as blocked)
    };
    let footprint = light_radius * scene.light_samples.median_density;
    scratch.values.clear();
    let mut any_lit = false;
    for &i in &scratch.light.covering {
        let reaches = reaches(i, footprint);
        any_lit |= reaches;
        scratch.values.push(if reaches { scene.light_samples.radiance[i as usize] } else { [0.0; 3] });
    }
    if !any_lit {
        stats.blocked += 1;
    }
    scratch.points.clear();
    scratch.points.extend_from_slice(&scratch.light.points);
    let Some(arriving) = tent_filter(&scratch.points, &scratch.values, light_screen, light_radius) else {
        return Some(value);
    };
    let direct = side.direct(scene, arriving);
    Some([0, 1, 2].map(|c| value[c] + direct[c]))
}

/// The fused kernel's view of a soft-shadow scene: the camera entries carrying
/// `radiance_without_light`, the light entries carrying the light's radiance.
pub struct FusedShadows<'a> {
    pub scene: &'a ShadowScene<'a>,
    pub camera: &'a Entries,
    pub light: &'a Entries,
    pub has_lens: bool,
    pub has_time: bool,
}

/// Per-thread scratch of `reconstruct_with_shadow_fused`.
#[derive(Default)]
pub struct FusedShadowScratch {
    camera: FusedScratch,
    light: FusedScratch,
}

/// `reconstruct_with_shadow` through the fused kernel (`fused::covering_surface` on both
/// sides, the lit test folded into the light side's pass): the same steps, the same surfaces
/// and samples, the filters' sums in the kernel's order.
pub fn reconstruct_with_shadow_fused(
    fused: &FusedShadows,
    pixel: (u32, u32),
    screen: [f32; 2],
    at: LensTime,
    light_uv: (f32, f32),
    scratch: &mut FusedShadowScratch,
    stats: &mut ShadowStats,
) -> Option<[f32; 3]> {
    let scene = fused.scene;
    let camera_view =
        Fused { scene: scene.camera, entries: fused.camera, has_lens: fused.has_lens, has_time: fused.has_time };
    let query = Query { pixel: Some(pixel), location: screen, at, light: None, nearest: true };
    let covering = super::fused::covering_surface(&camera_view, &query, &mut scratch.camera, &mut stats.camera)?;
    let value = covering.value(fused.camera, None, scene.camera.lens, at, scene.camera.z_near);

    // The visible point: the covering surface's sample nearest to the location.
    let Some((_, nearest)) = covering.nearest else {
        return Some(value);
    };
    let nearest = nearest as usize;
    let Some(moved) = fused.camera.position(nearest, at, scene.camera.lens, scene.camera.z_near) else {
        return Some(value);
    };
    let side = match light_side(scene, screen, at, moved, nearest, light_uv, value, stats) {
        Ok(side) => side,
        Err(done) => return Some(done),
    };
    let (in_light, light_screen, light_at, light_lens, plane) =
        (side.in_light, side.light_screen, side.light_at, side.light_lens, &side.plane);
    let light_scene = &side.light_scene;
    let median = scene.light_samples.median_density;
    let first_test = plane.lit_test(in_light[2], light_scene.radius * median);
    let blocks = |i: u32| {
        let end = fused.light.position(i as usize, light_at, light_lens, scene.light.z_near);
        !end.is_some_and(|end| first_test.reaches(end))
    };
    let lit_for = |radius: f32| plane.lit_test(in_light[2], radius * median);
    let light_view = Fused { scene: light_scene, entries: fused.light, has_lens: true, has_time: fused.has_time };
    let query =
        Query { pixel: None, location: light_screen, at: light_at, light: Some((&lit_for, &blocks)), nearest: false };
    let Some(light_covering) =
        super::fused::covering_surface(&light_view, &query, &mut scratch.light, &mut stats.light)
    else {
        stats.blocked += 1;
        return Some(value); // no light sample within 16R: no light (counted as blocked)
    };
    if light_covering.lit == 0 {
        stats.blocked += 1;
    }
    let lit = lit_for(light_covering.radius);
    let arriving = light_covering.value(fused.light, Some(&lit), light_lens, light_at, scene.light.z_near);
    let direct = side.direct(scene, arriving);
    Some([0, 1, 2].map(|c| value[c] + direct[c]))
}

/// The visible point p of a location: where the location's camera ray (through (x̂, ŷ) =
/// `screen` from the lens point (û, v̂)) meets the tangent plane of the covering surface's nearest
/// sample, which lies at `nearest` = (x′, y′, z′) reprojected to the location's (û, v̂, t̂) with
/// the world `normal`. The nearest sample lies up to 2R away on the screen, so its own depth
/// would put p off a surface seen at a slant (behind it half of the time, where the surface's
/// own light samples then shadow it). Falls back to that depth where the ray runs (nearly)
/// parallel to the plane.
pub fn visible_point(
    lens: &super::lens::LensModel,
    pose: &CameraPose,
    screen: [f32; 2],
    at: LensTime,
    nearest: [f32; 3],
    normal: [f32; 3],
) -> [f32; 3] {
    // Camera-space points seen at screen x̂ through lens point û: x̂ = fx·X/Z + cx + û·C(Z),
    // so X = ((x̂ − cx − û·c2)·Z − û·c1)/fx: the ray A + Z·B.
    let unproject = |x: f32, y: f32, z: f32| {
        let a = [-at.u * lens.c1 / lens.fx, -at.v * lens.c1 / lens.fy, 0.0];
        let b = [(x - lens.cx - at.u * lens.c2) / lens.fx, (y - lens.cy - at.v * lens.c2) / lens.fy, 1.0];
        [a[0] + z * b[0], a[1] + z * b[1], z]
    };
    let [x, y, z] = nearest;
    let on_surface = pose.to_world(unproject(x, y, z));
    let origin = pose.to_world(unproject(screen[0], screen[1], 0.0));
    let fallback = pose.to_world(unproject(screen[0], screen[1], z));
    let direction = [0, 1, 2].map(|k| fallback[k] - origin[k]); // B·z in world space
    let along = crate::vector::dot(normal, direction);
    let offset = crate::vector::dot(normal, [0, 1, 2].map(|k| on_surface[k] - origin[k]));
    let scale = offset / along;
    // Within a factor of 2 of the nearest sample's depth, else the slant is too steep to trust.
    if along.abs() > 1e-6 * crate::vector::dot(direction, direction).sqrt() && (0.5..=2.0).contains(&scale) {
        [0, 1, 2].map(|k| origin[k] + scale * direction[k])
    } else {
        fallback
    }
}

/// The receiver's tangent plane in light space, for the lit test: the light-space depth at
/// which the ray from the location's light point through a screen position meets it. A light
/// sample on the receiver's own surface then ends exactly there, however steeply the surface
/// is seen from the light (the role of the light-space depth gradient in the authors' test).
pub struct ReceiverPlane {
    /// The receiver's light-space normal and its offset n·p.
    normal: [f32; 3],
    offset: f32,
    /// The light point (ũ, ṽ) in light space (depth 0).
    from: [f32; 3],
    /// Light-space lateral units per screen unit along u and v, the screen offset, Π's depth.
    per_unit: [f32; 2],
    screen_offset: [f32; 2],
    plane_distance: f32,
}

impl ReceiverPlane {
    pub fn new(space: &LightSpace, position: [f32; 3], world_normal: [f32; 3], u: f32, v: f32) -> ReceiverPlane {
        use crate::vector::dot;
        let normal =
            [dot(world_normal, space.axis_u), dot(world_normal, space.axis_v), dot(world_normal, space.normal)];
        let (half_u, half_v) = (0.5 * space.width_u, 0.5 * space.width_v);
        ReceiverPlane {
            normal,
            offset: dot(normal, position),
            from: [u * half_u, v * half_v, 0.0],
            per_unit: [half_u / space.scale, half_v / space.scale],
            screen_offset: space.offset,
            plane_distance: space.plane_distance,
        }
    }

    /// The lit test of `reaches` in the form the fused pass evaluates per sample: a light
    /// sample reaches when it ends no nearer than `depth_at` (with `fallback`) less
    /// `SHADOW_BIAS_RELATIVE` of it and `SHADOW_BIAS_FOOTPRINTS` × `footprint`.
    pub fn lit_test(&self, fallback: f32, footprint: f32) -> LitTest {
        use crate::vector::dot;
        LitTest {
            normal: self.normal,
            numerator: self.offset - dot(self.normal, self.from),
            from: self.from,
            per_unit: self.per_unit,
            screen_offset: self.screen_offset,
            plane_distance: self.plane_distance,
            fallback,
            relative: SHADOW_BIAS_RELATIVE,
            footprint_tolerance: SHADOW_BIAS_FOOTPRINTS * footprint,
        }
    }

    /// The depth at which the ray through `screen` (seen from the light point) meets the
    /// plane; `fallback` where the ray runs (nearly) parallel to it or meets it behind the light.
    pub fn depth_at(&self, screen: [f32; 2], fallback: f32) -> f32 {
        use crate::vector::dot;
        let on_pi = [
            (screen[0] + self.screen_offset[0]) * self.per_unit[0],
            (screen[1] + self.screen_offset[1]) * self.per_unit[1],
            self.plane_distance,
        ];
        let direction = [0, 1, 2].map(|k| on_pi[k] - self.from[k]);
        let along = dot(self.normal, direction);
        let t = (self.offset - dot(self.normal, self.from)) / along;
        let depth = t * self.plane_distance;
        if depth.is_finite() && depth > 0.0 && along.abs() > 1e-6 * dot(direction, direction).sqrt() {
            depth
        } else {
            fallback
        }
    }
}

/// Light coordinates (ũ, ṽ) ∈ [−1, 1]² of location `j` of pixel (x, y): Halton bases 13 and 17
/// with the pixel's Cranley–Patterson shift, continuing `integrate::location`'s dimensions.
pub fn light_coordinates(seed: u32, x: u32, y: u32, j: u32) -> (f32, f32) {
    let halton = super::integrate::RotatedHalton::new(seed, x, y);
    (2.0 * halton.dimension(j, 13, 5) - 1.0, 2.0 * halton.dimension(j, 17, 6) - 1.0)
}

/// Reconstructs the soft-shadowed image of a soft-shadow `lens-time` file and its `light`
/// file (same seed and spp).
pub fn reconstruct_soft_shadow(
    camera_path: &std::path::Path,
    light_path: &std::path::Path,
    settings: &super::settings::TlfrSettings,
) -> Result<super::reconstruction::Reconstruction, crate::method::MethodError> {
    use super::bounds::ScreenArea;
    use super::dispersion::measure_radius;
    use super::hierarchy::{reorder, Hierarchy};
    use super::query::max_reach;
    use super::reprojection::near_limit;
    use super::same_surface::window_half_width;
    use super::samples::read_lens_time;
    use super::settings::RADIUS_TRIALS;
    use crate::method::Effect;
    use std::time::Instant;

    let start = Instant::now();
    let camera_file = SampleFile::open(camera_path)?;
    let camera = read_lens_time(&camera_file)?;
    let shading = read_shading(&camera_file, &camera)?;
    let pose = CameraPose::from_camera(camera_file.header().camera.as_ref().expect("read_lens_time checked it"));
    let (box_image, _) = crate::baselines::box_filter::average(&camera_file, Effect::SoftShadow, 0.0)?;
    let records = camera_file.len();
    drop(camera_file);
    let light_file = SampleFile::open(light_path)?;
    let light = read_light(&light_file, records)?;
    drop(light_file);
    let read_s = start.elapsed().as_secs_f64();

    let (width, height) = (camera.width, camera.height);
    // R, the camera's hierarchy and the light's, for the caller's progress bar.
    crate::progress::begin("preprocessing", 3, "steps");
    let radius_start = Instant::now();
    let radius = measure_radius(&camera.samples, width, height, camera.spp, RADIUS_TRIALS, settings.seed)
        .filter(|r| r.is_finite() && *r > 0.0)
        .unwrap_or(1.0);
    let radius_s = radius_start.elapsed().as_secs_f64();
    crate::progress::advance(1);
    let z_near = near_limit(camera.samples.iter().map(|s| s.z));
    // The hierarchies; every array aligned with the samples follows their new order.
    let build_start = Instant::now();
    let area = ScreenArea { width: width as f32, height: height as f32, max_reach: max_reach(radius) };
    let (tree, order) = Hierarchy::build(&camera.samples, &camera.lens, z_near, &area);
    let (mut camera, mut shading) = (camera, shading);
    camera.samples = reorder(&camera.samples, &order);
    camera.radiance = reorder(&camera.radiance, &order);
    camera.file_index = reorder(&camera.file_index, &order);
    shading.albedo = reorder(&shading.albedo, &order);
    shading.normal = reorder(&shading.normal, &order);
    shading.without_light = reorder(&shading.without_light, &order);
    let light_lens = light.space.lens_model();
    let light_z_near = near_limit(light.samples.iter().map(|s| s.z));
    // Light queries use R·ρ/median ρ: reach for the largest ρ.
    let largest_density = light.density.iter().fold(light.median_density, |m, &d| m.max(d));
    let light_area = ScreenArea {
        width: light.extent[0].max(1.0),
        height: light.extent[1].max(1.0),
        max_reach: max_reach(radius * largest_density / light.median_density),
    };
    let camera_build_s = build_start.elapsed().as_secs_f64();
    crate::progress::advance(1);
    let build_start = Instant::now();
    let (light_tree, light_order) = Hierarchy::build(&light.samples, &light_lens, light_z_near, &light_area);
    let mut light = light;
    light.samples = reorder(&light.samples, &light_order);
    light.radiance = reorder(&light.radiance, &light_order);
    let light_build_s = build_start.elapsed().as_secs_f64();
    crate::progress::end();
    let (camera, shading, light) = (camera, shading, light);
    let preprocess_s = start.elapsed().as_secs_f64();

    let start = Instant::now();
    let locations = settings.locations.max(1);
    let delta = window_half_width(locations);
    let camera_scene = Scene {
        samples: &camera.samples,
        radiance: &camera.radiance,
        lens: &camera.lens,
        hierarchy: &tree,
        radius,
        z_near,
        delta,
        view_bandwidth: None,
    };
    let light_scene = Scene {
        samples: &light.samples,
        radiance: &light.radiance,
        lens: &light_lens,
        hierarchy: &light_tree,
        radius,
        z_near: light_z_near,
        delta,
        view_bandwidth: None,
    };
    let area = light.space.width_u * light.space.width_v;
    let scene = ShadowScene {
        camera: &camera_scene,
        shading: &shading,
        pose,
        light: &light_scene,
        light_samples: &light,
        area,
        file_index: &camera.file_index,
    };
    let has = (camera.has_lens, camera.has_time);
    let fallback = |x: u32, y: u32| box_image.pixels[(y * width + x) as usize];
    let (image, stats) = match settings.kernel {
        super::settings::Kernel::Fused => {
            let camera_entries = Entries::new(&camera.samples, &shading.without_light, &camera.lens, &tree);
            let light_entries = Entries::new(&light.samples, &light.radiance, &light_lens, &light_tree);
            let fused = FusedShadows {
                scene: &scene,
                camera: &camera_entries,
                light: &light_entries,
                has_lens: has.0,
                has_time: has.1,
            };
            super::integrate::integrate_locations(
                (width, height),
                (locations, None),
                has,
                settings.seed,
                |(x, y, j), screen, at, scratch: &mut FusedShadowScratch, stats: &mut ShadowStats| {
                    let light_uv = light_coordinates(settings.seed, x, y, j);
                    reconstruct_with_shadow_fused(&fused, (x, y), screen, at, light_uv, scratch, stats)
                },
                fallback,
            )
        }
        super::settings::Kernel::Oracle => super::integrate::integrate_locations(
            (width, height),
            (locations, None),
            has,
            settings.seed,
            |(x, y, j), screen, at, scratch: &mut ShadowScratch, stats: &mut ShadowStats| {
                let light_uv = light_coordinates(settings.seed, x, y, j);
                reconstruct_with_shadow(&scene, screen, at, light_uv, scratch, stats)
            },
            fallback,
        ),
    };
    let recon_s = start.elapsed().as_secs_f64();
    let mut notes = vec![
        format!(
            "R = {radius:.3} px measured on the camera pattern; light radius R·ρ with median ρ = {:.4} scene units/px",
            light.median_density
        ),
        format!(
            "{} locations, {} shaded by the light reconstruction, {:.1}% of those blocked, {} outside the light-space domain \
             (lit without a shadow test); {} light samples without a visible point, {} outside the domain",
            stats.camera.locations,
            stats.shaded,
            100.0 * stats.blocked as f64 / stats.shaded.max(1) as f64,
            stats.grazing,
            light.skipped,
            light.grazing
        ),
        format!(
            "preprocess: reading {read_s:.3} s, R {radius_s:.3} s, camera hierarchy {camera_build_s:.3} s ({} leaves), \
             light hierarchy {light_build_s:.3} s ({} leaves)",
            tree.leaf_count(),
            light_tree.leaf_count()
        ),
    ];
    if camera.dropped > 0 {
        let total = camera.samples.len() + camera.dropped;
        notes.push(super::samples::dropped_warning(camera_path, camera.dropped, total));
    }
    Ok(super::reconstruction::Reconstruction { image, preprocess_s, recon_s, notes })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tlfr::lens::LensModel;

    /// A 1 × 0.5 light at y = 2 facing down, Π at depth 1, 7 units per half-width, offset.
    fn light() -> LightSpace {
        LightSpace { offset: [-3.0, 5.0], ..crate::tlfr::light_space::tests::light() }
    }

    #[test]
    fn points_of_the_receivers_plane_pass_the_lit_test_however_steep() {
        // A wall x = 1.5 (seen almost edge-on from the light) and a tilted plane: every point of
        // the plane, seen from the light point (ũ, ṽ) at its screen position, ends exactly at the
        // depth `ReceiverPlane` gives there, while the receiver's own depth differs by up to 40 %.
        let space = light();
        let lens = space.lens_model();
        let planes = [([1.5, 0.2, 0.0], [-1.0, 0.0, 0.0]), ([0.2, 0.0, 0.1], [0.3, 0.9, 0.3])];
        for (point, normal) in planes {
            let length = crate::vector::dot(normal, normal).sqrt();
            let normal = normal.map(|c| c / length);
            let receiver = space.to_light(point, 0.0);
            for (u, v) in [(0.0, 0.0), (-0.8, 0.6), (1.0, -1.0)] {
                let plane = ReceiverPlane::new(&space, receiver, normal, u, v);
                // Points of the plane around the receiver: two tangent directions.
                let a = if normal[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 0.0, 1.0] };
                let t1 = [
                    normal[1] * a[2] - normal[2] * a[1],
                    normal[2] * a[0] - normal[0] * a[2],
                    normal[0] * a[1] - normal[1] * a[0],
                ];
                let t2 = [
                    normal[1] * t1[2] - normal[2] * t1[1],
                    normal[2] * t1[0] - normal[0] * t1[2],
                    normal[0] * t1[1] - normal[1] * t1[0],
                ];
                for (s, t) in [(0.3, 0.0), (-0.25, 0.1), (0.0, -0.3), (0.0, 0.0)] {
                    let world: [f32; 3] = [0, 1, 2].map(|k| point[k] + s * t1[k] + t * t2[k]);
                    let q = space.to_light(world, 0.0);
                    let centre = space.centre_screen(q).unwrap();
                    let coc = lens.coc(q[2]);
                    let screen = [centre[0] + u * coc, centre[1] + v * coc];
                    let depth = plane.depth_at(screen, f32::NAN);
                    assert!((depth - q[2]).abs() < 1e-4 * q[2], "({u}, {v}) {world:?}: {depth} vs {}", q[2]);
                }
            }
        }
        // A ray parallel to the plane takes the fallback.
        let plane = ReceiverPlane::new(&space, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], 0.0, 0.0);
        let screen = [0.0 - space.offset[0], 0.0 - space.offset[1]];
        assert_eq!(plane.depth_at(screen, 1.0), 1.0);
    }

    #[test]
    fn the_visible_point_lies_on_the_location_ray_and_the_nearest_samples_plane() {
        // A lens camera (c1 = −fx·a with a = 0.1, focused at 2) at the origin looking along +z,
        // a floor y = 1 (camera Y points down) seen at a slant.
        let (fx, a, focus) = (40.0f32, 0.1f32, 2.0f32);
        let lens = LensModel { c1: -fx * a, c2: fx * a / focus, fx, fy: fx, cx: 32.0, cy: 24.0 };
        let pose = CameraPose { position: [0.0; 3], axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] };
        let normal = [0.0, -1.0, 0.0];
        let project = |p: [f32; 3], at: LensTime| {
            let c = lens.coc(p[2]);
            [lens.fx * p[0] / p[2] + lens.cx + at.u * c, lens.fy * p[1] / p[2] + lens.cy + at.v * c, p[2]]
        };
        for at in [LensTime { u: 0.0, v: 0.0, t: 0.5 }, LensTime { u: 0.7, v: -0.4, t: 0.5 }] {
            let sample = [0.3, 1.0, 3.0]; // on the floor
            let nearest = project(sample, at);
            let screen = [nearest[0] + 1.3, nearest[1] + 0.9]; // over a pixel away
            let p = visible_point(&lens, &pose, screen, at, nearest, normal);
            assert!((p[1] - 1.0).abs() < 1e-4, "on the floor: {p:?}");
            let seen = project(p, at);
            assert!((seen[0] - screen[0]).abs() < 1e-3 && (seen[1] - screen[1]).abs() < 1e-3, "{seen:?} vs {screen:?}");
            // The nearest sample's own depth would have put p off the floor.
            let depth_only = [
                (screen[0] - lens.cx - at.u * lens.coc(3.0)) / fx * 3.0,
                (screen[1] - lens.cy - at.v * lens.coc(3.0)) / fx * 3.0,
                3.0,
            ];
            assert!((depth_only[1] - 1.0).abs() > 0.01);
        }
        // A plane seen edge-on: the nearest sample's depth.
        let at = LensTime { u: 0.0, v: 0.0, t: 0.5 };
        let p = visible_point(&lens, &pose, [40.0, 30.0], at, [38.0, 30.0, 3.0], [0.0, 0.0, 0.0]);
        assert!((p[2] - 3.0).abs() < 1e-5, "{p:?}");
    }
}
