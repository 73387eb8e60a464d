//! What each effect means for the tracer: how the scene is set up for it (what is switched
//! off), which estimate gives its image and what the image's layer is called ([`image_layer`],
//! the one table of it), and which samples the methods read (`Effect::sample_kind`).
//!
//! | effect | scene set-up | image (reference, ladder, `Image` input) | layer | samples |
//! |---|---|---|---|---|
//! | `indirect` | as given; needs `max_bounces ≥ 2` | render's `indirect` | `indirect` | `indirect` |
//! | `glossy` | as given; needs a glossy material | render's `indirect` | `indirect` | `indirect` |
//! | `ao` | as given | ambient visibility within the AO radius | `ao` | `ao` |
//! | `dof` | motion removed; needs an aperture | render's `beauty` | `beauty` | `lens-time` |
//! | `motion` | lens closed; needs motion | render's `beauty` | `beauty` | `lens-time` |
//! | `dof-motion` | needs both | render's `beauty` | `beauty` | `lens-time` |
//! | `soft-shadow` | `max_bounces = 1` (direct light only); needs an emissive mesh | render's `beauty` | `direct` | `lens-time` + `light` |

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Result};
use glam::Vec3;
use recon::method::{GuideInput, ImageInput};
use recon::{Effect, Image};
use tracer::samples::secondary::{ambient_occlusion_frame, scene_is_glossy};
use tracer::samples::{DumpTarget, FieldSelection};
use tracer::{Accel, RenderSettings, Scene};

use crate::convert::{guide_input, image_from_vec3};

/// The effect `lfr compare` measures when `--effect` is not given, from what the scene has (its
/// camera with `--aperture-radius` applied): a lens and moving geometry: `dof-motion`; a lens:
/// `dof`; moving geometry: `motion`; a glossy material: `glossy`; otherwise `indirect`. Returns the
/// effect and the reason, for the notice.
pub fn default_for(scene: &Scene) -> (Effect, &'static str) {
    match (scene.camera.has_lens(), scene.has_motion()) {
        (true, true) => (Effect::DofMotion, "its camera has an aperture and it has moving geometry"),
        (true, false) => (Effect::Dof, "its camera has an aperture"),
        (false, true) => (Effect::Motion, "it has moving geometry"),
        (false, false) if scene_is_glossy(scene) => (Effect::Glossy, "it has a glossy material"),
        (false, false) => (Effect::Indirect, "it has neither a lens, motion nor a glossy material"),
    }
}

/// Switches off what `effect` does not measure and checks the scene has what it does.
/// Returns the path length to trace with.
pub fn prepare_scene(effect: Effect, scene: &mut Scene, max_bounces: Option<u32>) -> Result<u32> {
    let source = scene.source.display().to_string();
    let mut bounces = max_bounces.unwrap_or(scene.max_bounces);
    let needs_lens = matches!(effect, Effect::Dof | Effect::DofMotion);
    let needs_motion = matches!(effect, Effect::Motion | Effect::DofMotion);
    if needs_lens && !scene.camera.has_lens() {
        bail!(
            "{source}: --effect {} needs a camera with an aperture (camera.aperture_radius > 0): give one with \
             --aperture-radius R (and --focus-distance D), or in a .toml scene's [camera] (docs/scene-format.md)",
            effect.name()
        );
    }
    if needs_motion && !scene.has_motion() {
        bail!(
            "{source}: --effect {} needs moving geometry: give a mesh a `motion` in a .toml scene that includes \
             this file (docs/scene-format.md, [[mesh]])",
            effect.name()
        );
    }
    match effect {
        Effect::Dof => scene.meshes.iter_mut().for_each(|m| m.motion = Vec3::ZERO),
        Effect::Motion => scene.camera.aperture_radius = 0.0,
        Effect::SoftShadow => {
            let emissive =
                scene.meshes.iter().any(|m| scene.materials[m.material as usize].emission.max_element() > 0.0);
            if !emissive {
                bail!(
                    "{source}: --effect soft-shadow needs an area light (an emissive mesh): give a mesh an \
                     emissive material in a .toml scene (docs/scene-format.md, [[material]] `emission`)"
                );
            }
            // The light samples need the brightest emitter to be planar; checked here, before
            // the reference and the ladder are traced, rather than when the inputs are dumped.
            tracer::samples::light::PlanarLight::find(scene)?;
            bounces = 1;
        }
        Effect::Indirect | Effect::Glossy => {
            if bounces < 2 {
                bail!("--effect {} needs at least 2 bounces, --max-bounces is {bounces}", effect.name());
            }
            if effect == Effect::Glossy && !scene_is_glossy(scene) {
                bail!("{source}: --effect glossy needs a glossy material (specular lobe stronger than diffuse)");
            }
        }
        Effect::Ao | Effect::DofMotion => {}
    }
    Ok(bounces)
}

/// The default ambient-occlusion radius: a tenth of the scene's bounding-box diagonal.
pub fn default_ao_radius(scene: &Scene) -> f32 {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for mesh in &scene.meshes {
        for &p in &mesh.positions {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    let diagonal = (hi - lo).length();
    if diagonal.is_finite() && diagonal > 0.0 {
        0.1 * diagonal
    } else {
        1.0
    }
}

/// Which of the tracer's estimates gives an effect's image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Estimate {
    /// The full radiance (`beauty`): with soft shadows' one bounce, emission plus direct light.
    Beauty,
    /// Light after at least one more bounce (`indirect`).
    Indirect,
    /// The fraction of cosine-weighted rays unoccluded within the AO radius.
    AmbientVisibility,
}

/// Where an effect's image comes from and what its layer is called: a row of the table in the
/// module doc.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageLayer {
    pub estimate: Estimate,
    /// The layer of the comparison's EXR images (the reference's and every run's).
    pub name: &'static str,
}

/// The one effect → image-layer table (module doc).
pub const fn image_layer(effect: Effect) -> ImageLayer {
    let (estimate, name) = match effect {
        Effect::Indirect | Effect::Glossy => (Estimate::Indirect, "indirect"),
        Effect::Ao => (Estimate::AmbientVisibility, "ao"),
        Effect::Dof | Effect::Motion | Effect::DofMotion => (Estimate::Beauty, "beauty"),
        // Traced with one bounce, the beauty is the direct light the layer is named after.
        Effect::SoftShadow => (Estimate::Beauty, "direct"),
    };
    ImageLayer { estimate, name }
}

impl Estimate {
    /// The layer of an `lfr render` EXR holding this estimate (`""`: its beauty channels);
    /// `None` where it writes none.
    pub fn render_layer(self) -> Option<&'static str> {
        match self {
            Estimate::Beauty => Some(""),
            Estimate::Indirect => Some("indirect"),
            Estimate::AmbientVisibility => None,
        }
    }

    /// Of a render's `beauty` and `indirect` (images or pixels), the one this estimate reads
    /// (`tracer::render` has no ambient visibility: that is traced on its own).
    fn pick<T>(self, beauty: T, indirect: T) -> T {
        match self {
            Estimate::Indirect => indirect,
            Estimate::Beauty | Estimate::AmbientVisibility => beauty,
        }
    }
}

/// How the effect's images are traced.
pub struct Tracing<'a> {
    pub scene: &'a Scene,
    pub accel: &'a Accel,
    pub effect: Effect,
    pub width: u32,
    pub height: u32,
    pub max_bounces: u32,
    pub ao_radius: f32,
    pub threads: usize,
}

/// The sample files of one dump.
#[derive(Clone, Debug)]
pub struct Dumped {
    /// The effect's samples (`Effect::sample_kind`).
    pub samples: std::path::PathBuf,
    /// Soft shadows: the `light` samples that pair with `samples`.
    pub light_samples: Option<std::path::PathBuf>,
    /// Wall time of tracing and writing `samples`.
    pub samples_s: f64,
    /// Wall time of tracing and writing `light_samples`: only the methods that read them pay it.
    pub light_samples_s: Option<f64>,
}

/// A traced image of the effect with the denoiser's auxiliary buffers and its wall time.
pub struct Traced {
    pub frame: ImageInput,
    pub seconds: f64,
}

impl Tracing<'_> {
    /// Path traces the effect's image at `spp` with `seed` (box pixel filter).
    pub fn trace(&self, spp: u32, seed: u32, progress: bool) -> Result<Traced> {
        let (width, height) = (self.width, self.height);
        let start = Instant::now();
        let estimate = image_layer(self.effect).estimate;
        let frame = if estimate == Estimate::AmbientVisibility {
            let settings = RenderSettings { progress, ..self.dump_settings(spp, seed) };
            let ao = ambient_occlusion_frame(self.scene, self.accel, &settings, self.ao_radius)?;
            ImageInput {
                color: Image::from_pixels(width, height, ao.visibility.iter().map(|&v| [v; 3]).collect()),
                albedo: image_from_vec3(width, height, &ao.albedo),
                normal: image_from_vec3(width, height, &ao.normal),
            }
        } else {
            let settings = RenderSettings {
                width,
                height,
                spp,
                seed,
                max_bounces: self.max_bounces,
                threads: self.threads,
                progress,
            };
            let frame = tracer::render(self.scene, self.accel, &settings)?;
            let color = estimate.pick(&frame.beauty, &frame.indirect);
            ImageInput {
                color: image_from_vec3(width, height, color),
                albedo: image_from_vec3(width, height, &frame.albedo),
                normal: image_from_vec3(width, height, &frame.normal),
            }
        };
        Ok(Traced { frame, seconds: start.elapsed().as_secs_f64() })
    }

    /// The effect's value at each of `pixels` only, traced at `spp` with `seed`: bit-identical
    /// to those pixels of [`Tracing::trace`]'s colour with the same arguments. Returns the
    /// values and the wall time.
    pub fn trace_pixels(
        &self,
        spp: u32,
        seed: u32,
        pixels: &[(u32, u32)],
        progress: bool,
    ) -> Result<(Vec<[f32; 3]>, f64)> {
        let start = Instant::now();
        let settings = RenderSettings { progress, ..self.dump_settings(spp, seed) };
        let estimate = image_layer(self.effect).estimate;
        let values = if estimate == Estimate::AmbientVisibility {
            tracer::samples::secondary::ambient_occlusion_pixels(
                self.scene,
                self.accel,
                &settings,
                self.ao_radius,
                pixels,
            )?
            .into_iter()
            .map(|v| [v; 3])
            .collect()
        } else {
            tracer::render::render_pixels(self.scene, self.accel, &settings, pixels)?
                .into_iter()
                .map(|m| estimate.pick(m.beauty, m.indirect).to_array())
                .collect()
        };
        Ok((values, start.elapsed().as_secs_f64()))
    }

    fn dump_settings(&self, spp: u32, seed: u32) -> RenderSettings {
        RenderSettings {
            width: self.width,
            height: self.height,
            spp,
            seed,
            max_bounces: self.max_bounces,
            threads: self.threads,
            progress: false,
        }
    }

    /// Traces the guide buffers with `spp` indirect estimates per guide hit; returns them and
    /// the wall time. Only for the effects whose image is the indirect layer.
    pub fn guide(&self, spp: u32, seed: u32) -> Result<(GuideInput, f64)> {
        if image_layer(self.effect).estimate != Estimate::Indirect {
            bail!("guide buffers carry indirect light: --effect {} has no guide input", self.effect.name());
        }
        let start = Instant::now();
        let buffers = tracer::samples::guide::guide_buffers(self.scene, self.accel, &self.dump_settings(spp, seed))?;
        let seconds = start.elapsed().as_secs_f64();
        let input = guide_input(&buffers);
        Ok((input, seconds))
    }

    /// Writes the effect's samples at `spp` with the fields `fields` selects into the folder
    /// `dir` (`<kind>-<spp>spp-fields<N>.lfrs`, N = `selection` + 1; for soft shadows the
    /// lens-time file with its shading fields and `light-<spp>spp-fields<N>.lfrs`); returns the
    /// files and the wall time of tracing each. The files are scratch files, read back by this
    /// process and removed: not synced to disk (`DumpTarget::scratch`).
    pub fn dump(&self, spp: u32, seed: u32, dir: &Path, fields: &FieldSelection, selection: usize) -> Result<Dumped> {
        let settings = self.dump_settings(spp, seed);
        let start = Instant::now();
        let (scene, accel) = (self.scene, self.accel);
        let name = |kind: sampleio::SampleKind| format!("{}-{spp}spp-fields{}.lfrs", kind.name(), selection + 1);
        let path = dir.join(name(self.effect.sample_kind()));
        // Soft shadows' camera samples carry the shading fields their light samples pair with.
        let soft_shadows = self.effect == Effect::SoftShadow;
        let kind = self.effect.sample_kind();
        tracer::samples::dump(scene, accel, &settings, kind, soft_shadows, fields, DumpTarget::scratch(&path))?;
        let samples_s = start.elapsed().as_secs_f64();
        if !soft_shadows {
            return Ok(Dumped { samples: path, light_samples: None, samples_s, light_samples_s: None });
        }
        let light_start = Instant::now();
        let light_path = dir.join(name(sampleio::SampleKind::Light));
        let target = DumpTarget::scratch(&light_path);
        tracer::samples::dump(scene, accel, &settings, sampleio::SampleKind::Light, false, fields, target)?;
        let light_samples_s = Some(light_start.elapsed().as_secs_f64());
        Ok(Dumped { samples: path, light_samples: Some(light_path), samples_s, light_samples_s })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default effect follows what the scene has, in the documented order, checked on the
    /// Cornell box (diffuse, pinhole, static) with each property switched on in turn.
    #[test]
    fn the_default_effect_follows_the_scenes_lens_motion_and_materials() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let cornell = Scene::load(&root.join("scenes/cornell.toml")).unwrap();
        assert!(!scene_is_glossy(&cornell) && !cornell.camera.has_lens() && !cornell.has_motion());
        assert_eq!(default_for(&cornell).0, Effect::Indirect);
        let mut glossy = cornell.clone();
        glossy.materials[0].metallic = 1.0;
        glossy.materials[0].roughness = 0.1;
        assert!(scene_is_glossy(&glossy));
        assert_eq!(default_for(&glossy).0, Effect::Glossy);
        let mut moving = glossy.clone();
        moving.meshes[0].motion = Vec3::new(0.1, 0.0, 0.0);
        assert_eq!(default_for(&moving).0, Effect::Motion);
        let mut lens = glossy.clone();
        lens.camera.aperture_radius = 0.05;
        assert_eq!(default_for(&lens).0, Effect::Dof);
        let mut both = moving.clone();
        both.camera.aperture_radius = 0.05;
        assert_eq!(default_for(&both).0, Effect::DofMotion);
    }

    /// The reference's check traces single pixels (`Tracing::trace_pixels`); for every effect
    /// it must read the same layer, with the same estimator, as the whole image
    /// (`Tracing::trace`): equal bit for bit at those pixels.
    #[test]
    fn tracing_pixels_reads_the_whole_image_s_values_for_every_effect() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let cases = [
            ("scenes/cornell.toml", Effect::Indirect, None),
            ("scenes/cornell.toml", Effect::Ao, None),
            ("scenes/cornell.toml", Effect::SoftShadow, None),
            ("scenes/monkeys.toml", Effect::Glossy, Some(2)),
            ("scenes/monkeys-defocus-motion.toml", Effect::Dof, None),
            ("scenes/monkeys-defocus-motion.toml", Effect::Motion, None),
            ("scenes/monkeys-defocus-motion.toml", Effect::DofMotion, None),
        ];
        for (path, effect, bounces) in cases {
            let mut scene = Scene::load(&root.join(path)).unwrap();
            let max_bounces = prepare_scene(effect, &mut scene, bounces).unwrap();
            let accel = Accel::build(&scene).unwrap();
            let ao_radius = default_ao_radius(&scene);
            let tracing = Tracing {
                scene: &scene,
                accel: &accel,
                effect,
                width: 13,
                height: 9,
                max_bounces,
                ao_radius,
                threads: 2,
            };
            let whole = tracing.trace(3, 17, false).unwrap().frame.color;
            let pixels: Vec<(u32, u32)> = (0..40u32).map(|i| ((i * 5) % 13, (i * 7 + i / 3) % 9)).collect();
            let (values, _) = tracing.trace_pixels(3, 17, &pixels, false).unwrap();
            for (&(x, y), value) in pixels.iter().zip(&values) {
                let expected = whole.pixels[(y * 13 + x) as usize];
                assert_eq!(value.map(f32::to_bits), expected.map(f32::to_bits), "{path} {effect:?} at ({x}, {y})");
            }
            assert!(values.iter().flatten().any(|v| *v > 0.0), "{path} {effect:?}: not vacuous");
        }
    }
}
