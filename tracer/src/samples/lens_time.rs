//! `lens-time` samples for the temporal light field reconstruction (Lehtinen et al. 2011,
//! Section 3): each sample is one camera path at (x, y, u, v, t) with the depth, the 3D motion
//! and the depth gradient of the surface it first hits, and the path's radiance.
//!
//! Fields, in record order (a field is present only when the scene needs it):
//!
//! | field | components | present | meaning |
//! |---|---|---|---|
//! | `x`, `y` | 1 each | always | film position in pixels, origin top-left, pixel centres at +0.5 |
//! | `u`, `v` | 1 each | aperture > 0 | lens position on the unit disk; u along image +x, v along image +y |
//! | `t` | 1 | moving geometry | time in [0, 1] over the shutter |
//! | `z` | 1 | always | camera-space depth of the first hit (+inf when the ray hits nothing) |
//! | `motion` | 3 | moving geometry | camera-space displacement (X right, Y down, Z forward) of the hit point from t = 0 to t = 1 |
//! | `radiance` | 3 | always | path-traced radiance (linear RGB) |
//! | `depth_gradient` | 2 | always | ∂z/∂x, ∂z/∂y in scene units per pixel at fixed (u, v, t) |
//! | `bandwidth` | 1 | glossy materials | κ of the BRDF lobe at the hit (as for `indirect` samples, `secondary::bandwidth`); 0 for diffuse and misses; for the bandwidth-weighted reconstruction of TLFR Fig. 14 |
//! | `albedo` | f16 × 3 | soft-shadow dumps, or selected by name (with `normal`) | reflectance of the first hit (0 for a miss) |
//! | `normal` | u16 × 2 | soft-shadow dumps, or selected by name (with `albedo`) | shading normal of the first hit facing the camera, world space, octahedral; (0, 0) for a miss |
//! | `radiance_without_light` | 3 | soft-shadow dumps | `radiance` minus the light the planar light (`light::PlanarLight`) sent to the first hit directly or after more bounces; its emission seen by the camera stays |
//! | `direct` | 3 | selected by name | the part of `radiance` that is emission seen by the camera or light reflected by the first hit straight from an emitter (`PathSample::direct`); `radiance − direct` is the light of longer paths |
//!
//! The soft-shadow dump (`dump_for_soft_shadows`) adds the last three so a reconstruction can
//! shade the visible point with its own estimate of the planar light (paper Section 5), taking
//! everything else from `radiance_without_light`.
//!
//! `direct` is written only when a selection names it (`FieldSelection::names`): a full dump
//! keeps its record size, and only a consumer that reads it (TLFR's `gi=split`) pays its 12
//! bytes.
//!
//! With the circle of confusion C(z) = C1/z + C2 (header `camera.coc`), a sample reprojects as
//! in the paper's Eq. 2–3; the homogeneous screen motion of Eq. 3 is v = (fx·ΔX + cx·ΔZ,
//! fy·ΔY + cy·ΔZ, ΔZ) with the focal lengths and principal point of `pixel_to_camera`.

use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleKind};

use super::{camera_header, write_samples, DumpReport, DumpTarget, FieldSelection};
use crate::accel::Accel;
use crate::camera::depth_gradient;
use crate::error::RenderError;
use crate::integrator::NoRecording;
use crate::lights::LightSampler;
use crate::render::RenderSettings;
use crate::sampler::Sampler;
use crate::scene::Scene;

/// Which optional fields a scene needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LensTimeLayout {
    pub lens: bool,
    pub time: bool,
    pub bandwidth: bool,
    /// `albedo`, `normal` and `radiance_without_light` for soft shadows.
    pub shading: bool,
    /// `albedo` and `normal` alone, when a selection names either (a denoiser's auxiliary
    /// images from these samples; the soft-shadow layout has them already).
    pub auxiliary: bool,
    /// `direct`: emission plus the first hit's direct light, when a selection names it.
    pub direct: bool,
}

impl LensTimeLayout {
    pub fn for_scene(scene: &Scene) -> LensTimeLayout {
        LensTimeLayout {
            lens: scene.camera.has_lens(),
            time: scene.has_motion(),
            bandwidth: super::secondary::scene_is_glossy(scene),
            shading: false,
            auxiliary: false,
            direct: false,
        }
    }

    /// This layout with `direct` when `fields` names it, and `albedo` and `normal` when it
    /// names either.
    pub fn with_selected(self, fields: &FieldSelection) -> LensTimeLayout {
        let auxiliary = fields.names("albedo") || fields.names("normal");
        LensTimeLayout { direct: fields.names("direct"), auxiliary, ..self }
    }

    /// Whether the records hold `albedo` and `normal`.
    fn has_albedo_and_normal(&self) -> bool {
        self.shading || self.auxiliary
    }

    pub fn values_per_sample(&self) -> usize {
        2 + 2 * self.lens as usize
            + self.time as usize
            + 1
            + 3 * self.time as usize
            + 3
            + 2
            + self.bandwidth as usize
            + 5 * self.has_albedo_and_normal() as usize
            + 3 * self.shading as usize
            + 3 * self.direct as usize
    }

    pub fn header(&self, scene: &Scene, settings: &RenderSettings) -> HeaderSpec {
        let f32_field = |name: &str, n: u32, unit: &str, meaning: &str| {
            FieldSpec::new(name, FieldType::F32, n).unit(unit).meaning(meaning)
        };
        let mut spec = HeaderSpec::new(SampleKind::LensTime, settings.width, settings.height, settings.spp)
            .field(f32_field("x", 1, "px", "film x, origin at the left edge"))
            .field(f32_field("y", 1, "px", "film y, origin at the top edge"));
        if self.lens {
            spec = spec.field(f32_field("u", 1, "unit disk", "lens position along image +x")).field(f32_field(
                "v",
                1,
                "unit disk",
                "lens position along image +y",
            ));
        }
        if self.time {
            spec = spec.field(f32_field("t", 1, "shutter fraction", "time in [0, 1] over the shutter"));
        }
        spec = spec.field(f32_field("z", 1, "scene units", "camera-space depth of the first hit; +inf for a miss"));
        if self.time {
            spec = spec.field(f32_field(
                "motion",
                3,
                "scene units",
                "camera-space displacement (X right, Y down, Z forward) of the hit point over the shutter",
            ));
        }
        spec = spec.field(f32_field("radiance", 3, "W/(m^2 sr)", "path-traced radiance, linear RGB")).field(f32_field(
            "depth_gradient",
            2,
            "scene units/px",
            "dz/dx and dz/dy at fixed lens and time",
        ));
        if self.bandwidth {
            spec = spec.field(
                FieldSpec::new("bandwidth", FieldType::F16, 1)
                    .unit("")
                    .meaning("von Mises-Fisher concentration kappa of the BRDF at the hit; 0 diffuse"),
            );
        }
        if self.has_albedo_and_normal() {
            spec = spec
                .field(
                    FieldSpec::new("albedo", FieldType::F16, 3)
                        .unit("")
                        .meaning("reflectance of the first hit; 0 miss"),
                )
                .field(
                    FieldSpec::new("normal", FieldType::U16, 2)
                        .unit("octahedral u16 pair, 0 = none; see docs/sample-format.md")
                        .meaning("world-space shading normal of the first hit, facing the camera"),
                );
        }
        if self.shading {
            spec = spec.field(f32_field(
                "radiance_without_light",
                3,
                "W/(m^2 sr)",
                "radiance minus the planar light's light reflected by the first hit (directly or not)",
            ));
        }
        if self.direct {
            spec = spec.field(f32_field(
                "direct",
                3,
                "W/(m^2 sr)",
                "emission seen by the camera plus light reflected by the first hit straight from emitters; \
                 radiance - direct is the rest of the path",
            ));
        }
        spec.camera = Some(camera_header(&scene.camera, settings.width, settings.height));
        spec.scene = Some(scene.source.display().to_string());
        spec.seed = Some(settings.seed);
        let mut coordinates = std::collections::BTreeMap::new();
        coordinates
            .insert("pixel".into(), "x right, y down, origin top-left; pixel (i, j) covers [i, i+1) x [j, j+1)".into());
        coordinates.insert("camera".into(), "X right, Y down, Z forward (depth), origin at the lens centre".into());
        coordinates.insert("lens".into(), "unit disk; lens point = position + aperture_radius (u right - v up)".into());
        spec.coordinates = Some(coordinates);
        spec
    }
}

/// Writes `lens-time` samples of `scene` to `target`, the fields `fields` selects.
pub fn dump<'a>(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    fields: &FieldSelection,
    target: impl Into<DumpTarget<'a>>,
) -> Result<DumpReport, RenderError> {
    dump_with(
        scene,
        accel,
        settings,
        LensTimeLayout::for_scene(scene).with_selected(fields),
        fields,
        None,
        target.into(),
    )
}

/// Writes `lens-time` samples with the soft-shadow fields (`albedo`, `normal`,
/// `radiance_without_light`) for the scene's planar light (`light::PlanarLight::find`).
pub fn dump_for_soft_shadows<'a>(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    fields: &FieldSelection,
    target: impl Into<DumpTarget<'a>>,
) -> Result<DumpReport, RenderError> {
    let light = super::light::PlanarLight::find(scene)?;
    let layout = LensTimeLayout { shading: true, ..LensTimeLayout::for_scene(scene).with_selected(fields) };
    dump_with(scene, accel, settings, layout, fields, Some(light.mesh), target.into())
}

fn dump_with(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    layout: LensTimeLayout,
    fields: &FieldSelection,
    split_emitter: Option<u32>,
    target: DumpTarget,
) -> Result<DumpReport, RenderError> {
    settings.validate()?;
    // The gradient's four extra camera rays are a tenth of a dump: only when it is written.
    let with_gradient = fields.wants("depth_gradient");
    let lights = LightSampler::new(scene);
    let mut integrator = super::integrator(scene, accel, &lights, settings);
    integrator.split_emitter = split_emitter;
    let camera = &scene.camera;
    let spec = layout.header(scene, settings);
    let mut report =
        write_samples(target, spec, fields, settings, layout.values_per_sample(), |x, y, samples, values| {
            for index in samples {
                let mut sampler = Sampler::new(settings.seed, x, y, index);
                let camera_sample = integrator.camera_sample(x, y, &mut sampler);
                let path = integrator.trace_camera_sample(&camera_sample, &mut sampler, &mut NoRecording);
                values.extend_from_slice(&[camera_sample.film.x, camera_sample.film.y]);
                if layout.lens {
                    // The file's v runs along image +y, the camera's lens.y along up.
                    values.extend_from_slice(&[camera_sample.lens.x, -camera_sample.lens.y]);
                }
                if layout.time {
                    values.push(camera_sample.time);
                }
                match path.first_hit {
                    Some(hit) => {
                        values.push(hit.depth);
                        if layout.time {
                            let motion = scene.meshes[hit.mesh as usize].motion;
                            values.extend_from_slice(&camera.vector_to_camera_space(motion).to_array());
                        }
                        values.extend_from_slice(&path.radiance().to_array());
                        let gradient = match with_gradient {
                            true => depth_gradient(
                                camera,
                                &camera_sample,
                                hit.position,
                                hit.geometric_normal,
                                settings.width,
                                settings.height,
                            ),
                            false => glam::Vec2::ZERO, // left out of the file
                        };
                        values.extend_from_slice(&gradient.to_array());
                        if layout.bandwidth {
                            values.push(super::secondary::bandwidth(&hit.bsdf));
                        }
                        if layout.has_albedo_and_normal() {
                            values.extend_from_slice(&super::secondary::clamp_f16(hit.albedo).to_array());
                            values.extend_from_slice(&super::secondary::encode_octahedral(hit.normal));
                        }
                        if layout.shading {
                            values.extend_from_slice(&(path.radiance() - path.split_emitter_light).to_array());
                        }
                        if layout.direct {
                            values.extend_from_slice(&path.direct.to_array());
                        }
                    }
                    None => {
                        values.push(f32::INFINITY);
                        if layout.time {
                            values.extend_from_slice(&[0.0; 3]);
                        }
                        values.extend_from_slice(&path.radiance().to_array());
                        values.extend_from_slice(&[0.0, 0.0]);
                        if layout.bandwidth {
                            values.push(0.0);
                        }
                        if layout.has_albedo_and_normal() {
                            values.extend_from_slice(&[0.0; 5]);
                        }
                        if layout.shading {
                            values.extend_from_slice(&path.radiance().to_array());
                        }
                        if layout.direct {
                            values.extend_from_slice(&path.direct.to_array());
                        }
                    }
                }
            }
        })?;
    report.dropped_contributions = integrator.dropped_contributions();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::FovAxis;
    use crate::camera::{Camera, CameraSample};
    use glam::{Vec2, Vec3};

    #[test]
    fn grazing_surfaces_give_a_finite_clamped_gradient() {
        let camera = Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 60.0, FovAxis::Y);
        let sample = CameraSample { film: Vec2::new(20.0, 15.0), lens: Vec2::ZERO, time: 0.0 };
        let (o, d) = camera.generate_ray(sample.film, sample.lens, 40, 30);
        let hit = o + d * 3.0;
        // A plane containing the view ray.
        let normal = d.cross(Vec3::Y).normalize();
        let g = depth_gradient(&camera, &sample, hit, normal, 40, 30);
        assert!(g.is_finite());
        assert!(g.x.abs() <= camera.depth(hit) + 1e-5);
    }
}
