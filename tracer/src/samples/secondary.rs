//! `indirect` and `ao` samples for the indirect light field reconstruction (Lehtinen et al.
//! 2012, Section 2.1): each sample is one secondary ray, from the primary hit o of a camera
//! ray at (x, y, u, v, t) in direction ω drawn from o's BSDF (`indirect`) or cosine-weighted
//! (`ao`), to its hit h.
//!
//! Paper tuple s : {x, y, u, v, t, ω} ↦ {L, o, h, n_o, n_h, v_o, v_h, κ}, plus primary albedo,
//! primary direct light, secondary albedo and secondary direct light. Fields in record order
//! (present only when the scene needs them):
//!
//! | field | type × n | present | meaning |
//! |---|---|---|---|
//! | `x`, `y` | f32 | always | film position, pixels |
//! | `u`, `v` | f32 | aperture | lens position on the unit disk (u image +x, v image +y) |
//! | `t` | f32 | motion | time in [0, 1] |
//! | `direction` | u16 × 2 | always | ω, world space, octahedral (see `encode_octahedral`) |
//! | `radiance` | f32 × 3 | `indirect` | L: radiance arriving at o from ω, without the emission of h itself |
//! | `distance` | f32 | `ao` | distance from o to h; +inf when the ray escapes; 0 when the cosine direction about the shading normal lies below the geometric surface (no ray is traced: the surface itself occludes it) |
//! | `origin` | f32 × 3 | always | o, world space |
//! | `hit` | f32 × 3 | always | h, world space; equal to o when the ray escapes |
//! | `origin_normal`, `hit_normal` | u16 × 2 | always | shading normals at o and h facing the ray's origin side, octahedral; (0, 0) → zero for a miss |
//! | `origin_motion`, `hit_motion` | f16 × 3 | motion | world-space displacement over the shutter of o and h (f32 when a mesh moves further than 60000 units) |
//! | `bandwidth` | f16 | glossy `indirect` | κ of the von Mises-Fisher lobe at h (Eq. 2); 0 for diffuse |
//! | `albedo` | f16 × 3 | `indirect` | reflectance at o (demodulation) |
//! | `weight` | f16 × 3 | glossy `indirect` | BSDF sampling weight f·\|cos\|/pdf of ω at o; for a Lambertian o it equals `albedo`, so it is left out of all-diffuse scenes |
//! | `origin_base_color` | f16 × 3 | glossy `indirect` | o's BSDF (`shading::Bsdf`), textures resolved: base colour |
//! | `origin_metallic` | f16 | glossy `indirect` | metalness in [0, 1] |
//! | `origin_roughness` | f16 | glossy `indirect` | GGX roughness, α = roughness² (≥ 1e-3, as the BSDF clamps it) |
//! | `origin_specular` | f16 | glossy `indirect` | dielectric specular weight in [0, 1] |
//! | `origin_f0` | f16 | glossy `indirect` | dielectric reflectance at normal incidence, ((ior − 1)/(ior + 1))² |
//! | `origin_geometric_normal` | u16 × 2 | glossy `indirect` | geometric normal at o on the shading normal's side, octahedral: directions below it are never traced |
//! | `hit_base_color`, `hit_metallic`, `hit_roughness`, `hit_specular`, `hit_f0` | f16 × 3, f16 × 4 | glossy `indirect` | h's BSDF, as for o (zeros for an escaped ray): recursive filtering reflects at glossy h with it |
//! | `direct` | f32 × 3 | `indirect` | direct light at o towards the camera (emission of o, next-event estimation at o, and emitters hit by this ray, MIS-weighted) |
//! | `secondary_albedo` | f16 × 3 | `indirect` | reflectance at h |
//! | `secondary_direct` | f16 × 3 | `indirect` | the part of L that h reflects straight from emitters (clamped to ±65504) |
//!
//! The pixel's estimate from one sample is `direct + weight · radiance` (`albedo` for
//! `weight` in all-diffuse scenes). f16 values are clamped to the largest finite f16, 65504.
//!
//! Samples whose camera ray escapes have o = h = 0, distance 0 (`ao`), zero normals, and only
//! `direct` (the environment) set.
//!
//! κ for our GGX lobes: the paper takes κ = 4·sqrt(1/r) for pbrt's Blinn roughness r, whose
//! exponent is n = 1/r. The Beckmann correspondence α = sqrt(2/(n + 2)) gives n = 2/α² − 2, so
//! κ = 4·sqrt(2/α² − 2) for α = roughness². A surface counts as glossy when its specular lobe
//! reflects more than its diffuse lobe at normal incidence; otherwise κ = 0. κ is stored as f16
//! and clamped to its largest finite value 65504 (a lobe 0.004 rad wide: a mirror at any
//! resolution we use).

use glam::{Vec2, Vec3};
use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleKind};

use super::{camera_header, write_samples, DumpReport, DumpTarget, FieldSelection};
use crate::accel::Accel;
use crate::bsdf::{sample_cosine_hemisphere, Bsdf, Frame};
use crate::error::RenderError;
use crate::integrator::{FirstHit, Integrator, NoRecording, PathStart, TracedRay};
use crate::lights::LightSampler;
use crate::render::RenderSettings;
use crate::sampler::Sampler;
use crate::scene::Scene;

/// Which of the two secondary-ray kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SecondaryKind {
    Indirect,
    AmbientOcclusion,
}

/// Octahedral encoding of a unit vector into two integers in 1..=65535 (stored exactly as u16
/// by the writer); a zero or non-finite vector encodes as (0, 0), which no unit vector uses.
pub fn encode_octahedral(n: Vec3) -> [f32; 2] {
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    if !(l1 > 0.0) || !l1.is_finite() {
        return [0.0, 0.0];
    }
    let mut p = Vec2::new(n.x, n.y) / l1;
    if n.z < 0.0 {
        p = (Vec2::ONE - Vec2::new(p.y.abs(), p.x.abs())) * Vec2::new(sign(p.x), sign(p.y));
    }
    // [-1, 1] → [1, 65535]: 0 is reserved for "no vector".
    let quantize = |v: f32| round_non_negative((v.clamp(-1.0, 1.0) + 1.0) * 0.5 * 65534.0) + 1.0;
    [quantize(p.x), quantize(p.y)]
}

/// `x.round()` for finite x in [0, 2^23), without the library call that `round` becomes on
/// x86-64 without SSE 4.1 (1 % of an indirect dump's time): the fraction x − trunc(x) is exact
/// there, and a fraction of one half rounds up (away from zero), as `round` does.
#[inline]
fn round_non_negative(x: f32) -> f32 {
    debug_assert!((0.0..8_388_608.0).contains(&x), "{x}");
    let whole = x as u32 as f32;
    if x - whole >= 0.5 {
        whole + 1.0
    } else {
        whole
    }
}

fn sign(v: f32) -> f32 {
    if v >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// Inverse of `encode_octahedral`: (0, 0) decodes to the zero vector.
pub fn decode_octahedral(q: [f32; 2]) -> Vec3 {
    if q[0] == 0.0 && q[1] == 0.0 {
        return Vec3::ZERO;
    }
    let p = Vec2::new((q[0] - 1.0) / 65534.0 * 2.0 - 1.0, (q[1] - 1.0) / 65534.0 * 2.0 - 1.0);
    let z = 1.0 - p.x.abs() - p.y.abs();
    let (x, y) = if z < 0.0 { ((1.0 - p.y.abs()) * sign(p.x), (1.0 - p.x.abs()) * sign(p.y)) } else { (p.x, p.y) };
    Vec3::new(x, y, z).normalize()
}

/// The angular bandwidth κ at a surface (see the module documentation).
pub fn bandwidth(bsdf: &Bsdf) -> f32 {
    if !bsdf.specular_outweighs_diffuse() {
        return 0.0;
    }
    let alpha2 = bsdf.alpha * bsdf.alpha;
    let exponent = (2.0 / alpha2 - 2.0).max(0.0);
    (4.0 * exponent.sqrt()).min(65504.0)
}

/// Whether any material may be glossy (κ > 0 somewhere): textured roughness or metalness may
/// make any part of a surface glossy.
pub fn scene_is_glossy(scene: &Scene) -> bool {
    scene.materials.iter().any(|m| {
        let bsdf = Bsdf::with_ior(m.base_color, m.metallic, m.roughness, m.specular, m.ior);
        bandwidth(&bsdf) > 0.0 || m.metallic_roughness_texture.is_some()
    })
}

/// Which optional fields a scene needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SecondaryLayout {
    pub kind: SecondaryKind,
    pub lens: bool,
    pub time: bool,
    pub bandwidth: bool,
    /// The BSDF sampling weight at o (glossy scenes; it equals `albedo` for Lambertian o).
    pub weight: bool,
    /// o's BSDF parameters and geometric normal, for a final gather that samples o's BSDF,
    /// and h's BSDF, for recursive filtering at glossy h (glossy scenes; a Lambertian o or h
    /// needs only `albedo` or `secondary_albedo`).
    pub origin_bsdf: bool,
    /// Motion vectors are stored as f16 unless a mesh moves further than f16 can hold.
    pub motion_type: FieldType,
}

/// Largest motion stored as f16 (its largest finite value is 65504).
const F16_MOTION_LIMIT: f32 = 60000.0;

impl SecondaryLayout {
    pub fn for_scene(scene: &Scene, kind: SecondaryKind) -> SecondaryLayout {
        let glossy = scene_is_glossy(scene);
        SecondaryLayout {
            kind,
            lens: scene.camera.has_lens(),
            time: scene.has_motion(),
            bandwidth: kind == SecondaryKind::Indirect && glossy,
            weight: kind == SecondaryKind::Indirect && glossy,
            origin_bsdf: kind == SecondaryKind::Indirect && glossy,
            motion_type: if scene.meshes.iter().all(|m| m.motion.abs().max_element() <= F16_MOTION_LIMIT) {
                FieldType::F16
            } else {
                FieldType::F32
            },
        }
    }

    fn indirect(&self) -> bool {
        self.kind == SecondaryKind::Indirect
    }

    /// The record's fields, built anew (strings and all) on every call: call it per command or
    /// per layout, never per pixel or sample (see `AoPixel`).
    pub fn fields(&self) -> Vec<FieldSpec> {
        #[cfg(test)]
        tests::FIELD_LISTS_BUILT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let f = |name: &str, ty: FieldType, n: u32, unit: &str, meaning: &str| {
            FieldSpec::new(name, ty, n).unit(unit).meaning(meaning)
        };
        let octahedral = "octahedral u16 pair, 0 = none; see docs/sample-format.md";
        let mut fields = vec![f("x", FieldType::F32, 1, "px", "film x"), f("y", FieldType::F32, 1, "px", "film y")];
        if self.lens {
            fields.push(f("u", FieldType::F32, 1, "unit disk", "lens position along image +x"));
            fields.push(f("v", FieldType::F32, 1, "unit disk", "lens position along image +y"));
        }
        if self.time {
            fields.push(f("t", FieldType::F32, 1, "shutter fraction", "time in [0, 1]"));
        }
        fields.push(f("direction", FieldType::U16, 2, octahedral, "secondary ray direction, world space"));
        if self.indirect() {
            fields.push(f(
                "radiance",
                FieldType::F32,
                3,
                "W/(m^2 sr)",
                "radiance arriving at the origin from the direction, without the hit's emission",
            ));
        } else {
            fields.push(f(
                "distance",
                FieldType::F32,
                1,
                "scene units",
                "distance to the secondary hit; +inf for a miss",
            ));
        }
        fields.push(f("origin", FieldType::F32, 3, "scene units", "primary hit o, world space"));
        fields.push(f("hit", FieldType::F32, 3, "scene units", "secondary hit h, world space; o for a miss"));
        fields.push(f("origin_normal", FieldType::U16, 2, octahedral, "shading normal at o"));
        fields.push(f("hit_normal", FieldType::U16, 2, octahedral, "shading normal at h, facing o"));
        if self.time {
            fields.push(f(
                "origin_motion",
                self.motion_type,
                3,
                "scene units",
                "world displacement of o over the shutter",
            ));
            fields.push(f(
                "hit_motion",
                self.motion_type,
                3,
                "scene units",
                "world displacement of h over the shutter",
            ));
        }
        if self.bandwidth {
            fields.push(f("bandwidth", FieldType::F16, 1, "", "von Mises-Fisher concentration kappa at h; 0 diffuse"));
        }
        if self.indirect() {
            fields.push(f("albedo", FieldType::F16, 3, "", "reflectance at o"));
            if self.weight {
                fields.push(f(
                    "weight",
                    FieldType::F16,
                    3,
                    "",
                    "BSDF sampling weight f |cos| / pdf of the direction at o",
                ));
            }
            if self.origin_bsdf {
                fields.extend(bsdf_fields("origin", "o"));
                fields.push(f(
                    "origin_geometric_normal",
                    FieldType::U16,
                    2,
                    octahedral,
                    "geometric normal at o, on the side of the shading normal",
                ));
            }
            fields.push(f("direct", FieldType::F32, 3, "W/(m^2 sr)", "direct light at o towards the camera"));
            fields.push(f("secondary_albedo", FieldType::F16, 3, "", "reflectance at h"));
            fields.push(f(
                "secondary_direct",
                FieldType::F16,
                3,
                "W/(m^2 sr)",
                "part of radiance reflected at h straight from emitters",
            ));
            if self.origin_bsdf {
                fields.extend(bsdf_fields("hit", "h"));
            }
        }
        fields
    }

    pub fn values_per_sample(&self) -> usize {
        self.fields().iter().map(|f| f.components as usize).sum()
    }

    /// Where the field `name`'s first value lies among a sample's values (the fields'
    /// components in record order); `None` when the layout has no such field.
    pub fn value_offset(&self, name: &str) -> Option<usize> {
        let fields = self.fields();
        let index = fields.iter().position(|f| f.name == name)?;
        Some(fields[..index].iter().map(|f| f.components as usize).sum())
    }
}

/// The five f16 fields of a BSDF (`shading::Bsdf`, roughness for α) at the point `at`.
fn bsdf_fields(prefix: &str, at: &str) -> [FieldSpec; 5] {
    let field = |name: &str, n: u32, meaning: String| {
        FieldSpec::new(format!("{prefix}_{name}"), FieldType::F16, n).unit("").meaning(meaning)
    };
    [
        field("base_color", 3, format!("base colour of the BSDF at {at}")),
        field("metallic", 1, format!("metalness of the BSDF at {at}")),
        field("roughness", 1, format!("GGX roughness at {at} (alpha = roughness^2)")),
        field("specular", 1, format!("dielectric specular weight at {at}")),
        field("f0", 1, format!("dielectric reflectance at normal incidence at {at}")),
    ]
}

/// The values of `bsdf_fields` for `bsdf`.
fn push_bsdf(values: &mut Vec<f32>, bsdf: &Bsdf) {
    values.extend_from_slice(&clamp_f16(bsdf.base_color).to_array());
    values.extend_from_slice(&[bsdf.metallic, bsdf.alpha.sqrt(), bsdf.specular, bsdf.f0]);
}

/// Writes `indirect` or `ao` samples of `scene` to `path`, the fields `fields` selects.
pub fn dump<'a>(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    kind: SecondaryKind,
    fields: &FieldSelection,
    target: impl Into<DumpTarget<'a>>,
) -> Result<DumpReport, RenderError> {
    settings.validate()?;
    let layout = SecondaryLayout::for_scene(scene, kind);
    let lights = LightSampler::new(scene);
    let integrator = super::integrator(scene, accel, &lights, settings);
    let mut spec = HeaderSpec::new(
        match kind {
            SecondaryKind::Indirect => SampleKind::Indirect,
            SecondaryKind::AmbientOcclusion => SampleKind::Ao,
        },
        settings.width,
        settings.height,
        settings.spp,
    );
    spec.fields = layout.fields();
    spec.camera = Some(camera_header(&scene.camera, settings.width, settings.height));
    spec.scene = Some(scene.source.display().to_string());
    spec.seed = Some(settings.seed);
    let mut coordinates = std::collections::BTreeMap::new();
    coordinates.insert("world".into(), "the scene's world space (right-handed)".into());
    coordinates.insert(
        "octahedral".into(),
        "q in 1..=65535 per component: p = (q - 1) / 65534 * 2 - 1; z = 1 - |p.x| - |p.y|; if z < 0: (x, y) = ((1 - |p.y|) sign p.x, (1 - |p.x|) sign p.y) else (x, y) = p; normalise; q = (0, 0) means no vector".into(),
    );
    spec.coordinates = Some(coordinates);
    let values = layout.values_per_sample();
    let mut report = write_samples(target, spec, fields, settings, values, |x, y, samples, out| {
        for index in samples {
            let mut sampler = Sampler::new(settings.seed, x, y, index);
            let before = out.len();
            trace_secondary(&integrator, &layout, x, y, &mut sampler, out);
            debug_assert_eq!(out.len() - before, values);
        }
    })?;
    report.dropped_contributions = integrator.dropped_contributions();
    Ok(report)
}

/// Ambient occlusion per pixel, from exactly the samples an `ao` dump with the same settings
/// would write: the fraction of a pixel's samples whose cosine-weighted secondary ray travels
/// at least `radius` (or escapes). A sample whose camera ray escapes counts as unoccluded (1):
/// nothing occludes the background. A direction (about the shading normal) below the geometric
/// surface counts as occluded: it enters the surface. Also returns what a denoiser takes as auxiliary buffers:
/// the mean first-hit normal and an albedo of 1 wherever a surface was hit.
#[derive(Clone, Debug)]
pub struct AmbientOcclusionFrame {
    pub width: u32,
    pub height: u32,
    pub visibility: Vec<f32>,
    pub normal: Vec<Vec3>,
    pub albedo: Vec<Vec3>,
    pub seconds: f64,
}

/// Whether an `ao` sample counts as unoccluded at `radius`: its camera ray escaped (no origin
/// normal) or its secondary ray reached at least `radius`.
pub fn ao_visible(distance: f32, origin_normal_present: bool, radius: f32) -> bool {
    !origin_normal_present || distance >= radius
}

pub fn ambient_occlusion_frame(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    radius: f32,
) -> Result<AmbientOcclusionFrame, RenderError> {
    settings.validate()?;
    check_ao_radius(radius)?;
    let lights = LightSampler::new(scene);
    let ao = AoPixel::new(scene, accel, &lights, settings, radius);
    let pool = crate::render::thread_pool(settings.threads)?;
    let bar =
        crate::progress::StepProgress::begin(settings.progress, "ambient occlusion", settings.height as u64, "rows");
    let start = std::time::Instant::now();
    let rows: Vec<Vec<(f32, Vec3, Vec3)>> = pool.install(|| {
        use rayon::prelude::*;
        (0..settings.height)
            .into_par_iter()
            .map(|y| {
                let row: Vec<(f32, Vec3, Vec3)> = (0..settings.width).map(|x| ao.trace(x, y)).collect();
                bar.advance(1);
                row
            })
            .collect()
    });
    bar.finish();
    let pixels: Vec<(f32, Vec3, Vec3)> = rows.into_iter().flatten().collect();
    Ok(AmbientOcclusionFrame {
        width: settings.width,
        height: settings.height,
        visibility: pixels.iter().map(|p| p.0).collect(),
        normal: pixels.iter().map(|p| p.1).collect(),
        albedo: pixels.iter().map(|p| p.2).collect(),
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The visibility of only `pixels` (each inside the image, any order), bit-identical to those
/// pixels of [`ambient_occlusion_frame`] with the same settings, for any thread count.
pub fn ambient_occlusion_pixels(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    radius: f32,
    pixels: &[(u32, u32)],
) -> Result<Vec<f32>, RenderError> {
    settings.validate()?;
    check_ao_radius(radius)?;
    settings.check_inside(pixels)?;
    let lights = LightSampler::new(scene);
    let ao = AoPixel::new(scene, accel, &lights, settings, radius);
    let pool = crate::render::thread_pool(settings.threads)?;
    let bar =
        crate::progress::StepProgress::begin(settings.progress, "ambient occlusion", pixels.len() as u64, "pixels");
    let visibility = pool.install(|| {
        use rayon::prelude::*;
        pixels
            .par_iter()
            .map(|&(x, y)| {
                let visibility = ao.trace(x, y).0;
                bar.advance(1);
                visibility
            })
            .collect()
    });
    bar.finish();
    Ok(visibility)
}

fn check_ao_radius(radius: f32) -> Result<(), RenderError> {
    if radius.is_finite() && radius > 0.0 {
        Ok(())
    } else {
        Err(RenderError::Settings(format!("the ambient-occlusion radius must be positive, got {radius}")))
    }
}

/// One pixel of an ambient-occlusion image: its samples traced as `ao` secondary samples.
struct AoPixel<'a> {
    integrator: Integrator<'a>,
    layout: SecondaryLayout,
    /// Values a sample appends (`SecondaryLayout::values_per_sample`, which builds the field
    /// list: computed once here, not per pixel, where it cost about 1 µs a pixel and made the
    /// ambient-occlusion image 60 ms slower than the dump of the same samples at 256², 1 spp).
    values_per_sample: usize,
    distance_at: usize,
    normal_at: usize,
    spp: u32,
    seed: u32,
    radius: f32,
}

impl<'a> AoPixel<'a> {
    fn new(
        scene: &'a Scene,
        accel: &'a Accel,
        lights: &'a LightSampler,
        settings: &RenderSettings,
        radius: f32,
    ) -> AoPixel<'a> {
        let layout = SecondaryLayout::for_scene(scene, SecondaryKind::AmbientOcclusion);
        let offset_of =
            |name: &str| layout.value_offset(name).unwrap_or_else(|| unreachable!("ao samples always have {name}"));
        let (distance_at, normal_at) = (offset_of("distance"), offset_of("origin_normal"));
        AoPixel {
            integrator: super::integrator(scene, accel, lights, settings),
            values_per_sample: layout.values_per_sample(),
            layout,
            distance_at,
            normal_at,
            spp: settings.spp,
            seed: settings.seed,
            radius,
        }
    }

    /// Pixel (x, y)'s visibility, mean first-hit normal and albedo (1 where a surface was hit).
    fn trace(&self, x: u32, y: u32) -> (f32, Vec3, Vec3) {
        let (mut visible, mut normal, mut hits) = (0u32, Vec3::ZERO, 0u32);
        let mut values = Vec::with_capacity(self.values_per_sample);
        for index in 0..self.spp {
            let mut sampler = Sampler::new(self.seed, x, y, index);
            values.clear();
            trace_secondary(&self.integrator, &self.layout, x, y, &mut sampler, &mut values);
            let has_normal = values[self.normal_at] != 0.0 || values[self.normal_at + 1] != 0.0;
            visible += ao_visible(values[self.distance_at], has_normal, self.radius) as u32;
            if has_normal {
                normal += decode_octahedral([values[self.normal_at], values[self.normal_at + 1]]);
                hits += 1;
            }
        }
        let spp = self.spp as f32;
        let albedo = if hits > 0 { Vec3::ONE } else { Vec3::ZERO };
        (visible as f32 / spp, normal.normalize_or_zero(), albedo)
    }
}

/// One secondary-ray sample: appends the record's values, in field order, to `values`.
fn trace_secondary(
    integrator: &Integrator,
    layout: &SecondaryLayout,
    x: u32,
    y: u32,
    sampler: &mut Sampler,
    values: &mut Vec<f32>,
) {
    let scene = integrator.scene;
    let camera_sample = integrator.camera_sample(x, y, sampler);
    let time = camera_sample.time;
    let PathStart { origin, direction, .. } = integrator.camera_path_start(&camera_sample);
    values.extend_from_slice(&[camera_sample.film.x, camera_sample.film.y]);
    if layout.lens {
        values.extend_from_slice(&[camera_sample.lens.x, -camera_sample.lens.y]);
    }
    if layout.time {
        values.push(time);
    }

    // The primary vertex: what the camera ray hits, its emission and its direct light.
    let mut rays = 0;
    let Some(hit) = integrator.accel.intersect(origin, direction, 0.0, f32::INFINITY, time) else {
        // Camera ray escapes: the environment is all there is.
        push_miss(values, layout, scene.environment);
        return;
    };
    let wo = -direction;
    let footprint_width = integrator.camera_cone().width_at(hit.distance);
    let surface = crate::integrator::SurfacePoint::new(scene, &hit, wo, time, footprint_width);
    let frame = Frame::new(surface.shading_normal);
    let wo_local = frame.to_local(wo);
    let emitted_at_origin = surface.emission(scene, &hit, wo);
    let [u_select, u_lobe] = sampler.next_2d();
    let u_light = sampler.next_2d();
    let u_direction = sampler.next_2d();
    let _roulette = sampler.next_2d(); // the camera path's dimension layout, kept for the secondary path
    let direct_at_origin = if layout.indirect() {
        integrator.next_event(&surface, wo, time, [u_select, u_light[0], u_light[1]], &mut rays, &mut NoRecording)
    } else {
        Vec3::ZERO
    };

    // The secondary ray: BSDF-sampled (indirect) or cosine-weighted (ambient occlusion).
    let (wi, weight, pdf) = match layout.kind {
        SecondaryKind::Indirect => match surface.bsdf.sample(wo_local, u_lobe, u_direction) {
            Some(s) => (frame.to_world(s.wi), s.weight, s.pdf),
            None => (Vec3::ZERO, Vec3::ZERO, 0.0),
        },
        SecondaryKind::AmbientOcclusion => {
            let local = sample_cosine_hemisphere(u_direction);
            (frame.to_world(local), Vec3::ONE, local.z * std::f32::consts::FRAC_1_PI)
        }
    };
    let valid_direction = pdf > 0.0 && wi.dot(surface.geometric_normal) > 0.0;
    let secondary = if valid_direction {
        let start = PathStart {
            origin: surface.spawn_origin(wi),
            direction: wi,
            time,
            bounce: 1,
            previous: Some((pdf, surface.position)),
        };
        match layout.kind {
            SecondaryKind::Indirect => integrator.trace_ray(&start, sampler, &mut NoRecording),
            SecondaryKind::AmbientOcclusion => {
                // Only the first hit matters: trace one ray.
                let mut traced = TracedRay::default();
                if let Some(h) = integrator.accel.intersect(start.origin, wi, 0.0, f32::INFINITY, time) {
                    let width = integrator.cone_after_bounce_at(surface.position, pdf).width_at(h.distance);
                    let s = crate::integrator::SurfacePoint::new(scene, &h, -wi, time, width);
                    traced.first_hit = Some(FirstHit::new(&s, h.mesh, 0.0));
                }
                traced
            }
        }
    } else {
        TracedRay::default()
    };

    values.extend_from_slice(&encode_octahedral(if valid_direction { wi } else { Vec3::ZERO }));
    let secondary_hit = secondary.first_hit;
    match layout.kind {
        SecondaryKind::Indirect => values.extend_from_slice(&secondary.reflected().to_array()),
        // A cosine direction about the shading normal that points below the geometric surface
        // enters the surface: it is occluded at distance 0 (as the indirect dump gives such a
        // direction no light), not an escape.
        SecondaryKind::AmbientOcclusion => values.push(match &secondary_hit {
            Some(h) => (h.position - surface.position).length(),
            None if valid_direction => f32::INFINITY,
            None => 0.0,
        }),
    }
    values.extend_from_slice(&surface.position.to_array());
    values.extend_from_slice(&secondary_hit.map_or(surface.position, |h| h.position).to_array());
    values.extend_from_slice(&encode_octahedral(surface.shading_normal));
    values.extend_from_slice(&encode_octahedral(secondary_hit.map_or(Vec3::ZERO, |h| h.normal)));
    if layout.time {
        values.extend_from_slice(&scene.meshes[hit.mesh as usize].motion.to_array());
        values
            .extend_from_slice(&secondary_hit.map_or(Vec3::ZERO, |h| scene.meshes[h.mesh as usize].motion).to_array());
    }
    if layout.bandwidth {
        values.push(secondary_hit.map_or(0.0, |h| bandwidth(&h.bsdf)));
    }
    if layout.indirect() {
        let direct = emitted_at_origin + direct_at_origin + weight * secondary.emitted;
        values.extend_from_slice(&clamp_f16(surface.bsdf.albedo()).to_array());
        if layout.weight {
            values.extend_from_slice(&clamp_f16(weight).to_array());
        }
        if layout.origin_bsdf {
            push_bsdf(values, &surface.bsdf);
            values.extend_from_slice(&encode_octahedral(surface.geometric_normal));
        }
        values.extend_from_slice(&finite_or_zero(direct).to_array());
        values.extend_from_slice(&clamp_f16(secondary_hit.map_or(Vec3::ZERO, |h| h.bsdf.albedo())).to_array());
        values.extend_from_slice(&clamp_f16(secondary.direct).to_array());
        if layout.origin_bsdf {
            match &secondary_hit {
                Some(h) => push_bsdf(values, &h.bsdf),
                None => values.extend_from_slice(&[0.0; 7]),
            }
        }
    }
}

/// Non-finite → 0, then clamped to the finite f16 range: every f16 field the dumps write goes
/// through it (docs/sample-format.md promises it).
pub(super) fn clamp_f16(v: Vec3) -> Vec3 {
    finite_or_zero(v).clamp(Vec3::splat(-F16_MAX), Vec3::splat(F16_MAX))
}

/// The largest finite f16.
const F16_MAX: f32 = 65504.0;

fn finite_or_zero(v: Vec3) -> Vec3 {
    if v.is_finite() {
        v
    } else {
        Vec3::ZERO
    }
}

/// Values of a sample whose camera ray hits nothing.
fn push_miss(values: &mut Vec<f32>, layout: &SecondaryLayout, environment: Vec3) {
    values.extend_from_slice(&[0.0, 0.0]); // direction: none
    if layout.indirect() {
        values.extend_from_slice(&[0.0; 3]);
    } else {
        values.push(0.0);
    }
    values.extend_from_slice(&[0.0; 6]); // origin, hit
    values.extend_from_slice(&[0.0; 4]); // normals: none
    if layout.time {
        values.extend_from_slice(&[0.0; 6]);
    }
    if layout.bandwidth {
        values.push(0.0);
    }
    if layout.indirect() {
        values.extend_from_slice(&[0.0; 3]); // albedo
        if layout.weight {
            values.extend_from_slice(&[0.0; 3]);
        }
        if layout.origin_bsdf {
            values.extend_from_slice(&[0.0; 9]); // BSDF parameters and geometric normal: none
        }
        values.extend_from_slice(&environment.to_array());
        values.extend_from_slice(&[0.0; 6]); // secondary albedo and direct
        if layout.origin_bsdf {
            values.extend_from_slice(&[0.0; 7]); // h's BSDF: none
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Field lists built by `SecondaryLayout::fields` in this test binary, every thread.
    pub(super) static FIELD_LISTS_BUILT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

    /// The ambient-occlusion image once rebuilt the layout's field list for
    /// every pixel (about 1 µs each, 60 ms at 256²), which the dump of the same samples builds
    /// once, so `box` on the image read 1.6× faster than path tracing. The work per call must
    /// not grow with the pixels: 4096 pixels, at most a few lists (other tests of this binary
    /// running meanwhile build a handful per call; the defect built one per pixel).
    #[test]
    fn the_ambient_occlusion_image_builds_its_field_list_per_call_not_per_pixel() {
        use std::sync::atomic::Ordering;
        let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/cornell.toml"));
        let scene = crate::Scene::load(path).unwrap();
        let accel = crate::Accel::build(&scene).unwrap();
        let settings = RenderSettings { width: 64, height: 64, spp: 1, seed: 1, ..RenderSettings::from_scene(&scene) };
        let pixels: Vec<(u32, u32)> = (0..64).flat_map(|y| (0..64).map(move |x| (x, y))).collect();
        let before = FIELD_LISTS_BUILT.load(Ordering::Relaxed);
        let frame = ambient_occlusion_frame(&scene, &accel, &settings, 10.0).unwrap();
        let some = ambient_occlusion_pixels(&scene, &accel, &settings, 10.0, &pixels).unwrap();
        let built = FIELD_LISTS_BUILT.load(Ordering::Relaxed) - before;
        assert!(built < pixels.len() / 8, "{built} field lists for two calls of {} pixels", pixels.len());
        // The counter counts: one layout's offsets build the list once per query.
        let layout = SecondaryLayout::for_scene(&scene, SecondaryKind::AmbientOcclusion);
        let before = FIELD_LISTS_BUILT.load(Ordering::Relaxed);
        layout.value_offset("distance").unwrap();
        assert!(FIELD_LISTS_BUILT.load(Ordering::Relaxed) > before);
        assert_eq!(some, frame.visibility);
    }

    /// The indirect dump's samples continue the camera paths: the secondary path draws the
    /// camera path's dimensions, so per sample `weight · radiance` (here `albedo`, all
    /// Lambertian) is the camera path's `indirect` up to float rounding wherever Russian
    /// roulette does not decide (paths of at most three bounces). Beyond, the secondary path's
    /// roulette weighs survival by its own throughput from h, not the camera path's (which
    /// also holds o's albedo): a better estimate of the radiance the reconstructions reuse at
    /// other receivers, at more rays (docs/sample-format.md, "Russian roulette").
    #[test]
    fn an_indirect_sample_is_the_camera_paths_indirect_light() {
        let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/cornell.toml"));
        let scene = crate::Scene::load(path).unwrap();
        let accel = crate::Accel::build(&scene).unwrap();
        let (width, height, spp) = (24, 24, 8);
        let settings =
            RenderSettings { width, height, spp, seed: 3, max_bounces: 3, ..RenderSettings::from_scene(&scene) };
        let lights = LightSampler::new(&scene);
        let integrator = super::super::integrator(&scene, &accel, &lights, &settings);
        let layout = SecondaryLayout::for_scene(&scene, SecondaryKind::Indirect);
        let (radiance, albedo) = (layout.value_offset("radiance").unwrap(), layout.value_offset("albedo").unwrap());
        let (mut compared, mut lit) = (0, 0);
        let mut values = Vec::new();
        for (x, y, index) in (0..height).flat_map(|y| (0..width).flat_map(move |x| (0..spp).map(move |i| (x, y, i)))) {
            let camera_path = integrator.trace(x, y, &mut Sampler::new(settings.seed, x, y, index), &mut NoRecording);
            values.clear();
            trace_secondary(&integrator, &layout, x, y, &mut Sampler::new(settings.seed, x, y, index), &mut values);
            let value =
                Vec3::from_slice(&values[albedo..albedo + 3]) * Vec3::from_slice(&values[radiance..radiance + 3]);
            let scale = camera_path.indirect.max_element().max(1e-6);
            assert!(
                (value - camera_path.indirect).abs().max_element() <= 1e-4 * scale,
                "pixel ({x}, {y}) sample {index}: dump {value} against the camera path's {}",
                camera_path.indirect
            );
            compared += 1;
            lit += usize::from(camera_path.indirect.max_element() > 0.0);
        }
        assert!(lit > compared / 2, "{lit} of {compared} samples carry indirect light");
    }

    /// The octahedral quantiser's rounding against `f32::round`: every value within eight ulps
    /// of each tie k + 1/2 and of each integer up to 65534, and the ends of the range.
    #[test]
    fn rounding_without_the_library_call_is_round() {
        let near = |centre: f32, check: &mut dyn FnMut(f32)| {
            let first = centre.to_bits().saturating_sub(8);
            for bits in first..first + 17 {
                check(f32::from_bits(bits));
            }
        };
        let mut checked = 0;
        let mut check = |x: f32| {
            if (0.0..=65534.0).contains(&x) {
                assert_eq!(round_non_negative(x).to_bits(), x.round().to_bits(), "{x}");
                checked += 1;
            }
        };
        for k in 0..=65534u32 {
            near(k as f32, &mut check);
            near(k as f32 + 0.5, &mut check);
        }
        check(0.0);
        check(65534.0);
        assert!(checked > 2_000_000, "{checked}");
    }

    #[test]
    fn octahedral_round_trip_is_accurate_everywhere() {
        let mut worst = 0.0f32;
        for i in 0..64 {
            for j in 0..32 {
                let phi = i as f32 / 64.0 * std::f32::consts::TAU;
                let theta = j as f32 / 31.0 * std::f32::consts::PI;
                let n = Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
                let q = encode_octahedral(n);
                assert!(q.iter().all(|&v| (1.0..=65535.0).contains(&v) && v.fract() == 0.0));
                // Chord length: the angle for small errors, without acos's f32 cancellation.
                worst = worst.max((decode_octahedral(q) - n).length());
            }
        }
        assert!(worst < 1e-4, "worst angular error {worst} rad");
        assert_eq!(encode_octahedral(Vec3::ZERO), [0.0, 0.0]);
        assert_eq!(decode_octahedral([0.0, 0.0]), Vec3::ZERO);
        assert_eq!(encode_octahedral(Vec3::splat(f32::NAN)), [0.0, 0.0]);
    }

    #[test]
    fn bandwidth_is_zero_for_diffuse_and_grows_with_gloss() {
        assert_eq!(bandwidth(&Bsdf::new(Vec3::splat(0.7), 0.0, 1.0, 0.0)), 0.0);
        assert_eq!(bandwidth(&Bsdf::new(Vec3::splat(0.7), 0.0, 0.2, 1.0)), 0.0, "a coated diffuse surface");
        let rough = bandwidth(&Bsdf::new(Vec3::splat(0.9), 1.0, 0.7, 1.0));
        let glossy = bandwidth(&Bsdf::new(Vec3::splat(0.9), 1.0, 0.3, 1.0));
        let mirror = bandwidth(&Bsdf::new(Vec3::splat(0.9), 1.0, 1e-3, 1.0));
        assert!(0.0 < rough && rough < glossy && glossy < mirror);
        assert_eq!(mirror, 65504.0);
        // pbrt roughness r = 0.01 (exponent 100) through the Beckmann correspondence: kappa = 40.
        let alpha = (2.0f32 / 102.0).sqrt();
        let k = bandwidth(&Bsdf::new(Vec3::splat(0.9), 1.0, alpha.sqrt(), 1.0));
        assert!((k - 40.0).abs() < 0.01, "{k}");
    }
}
