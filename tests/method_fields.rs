//! Every method that reads sample files declares the fields it reads (`Method::sample_needs`),
//! and `lfr compare` traces its input with those fields only. The declaration must be complete:
//! each such method, on each effect it reconstructs, gives bit for bit the image of the full
//! dump from a dump of just its fields (a field it reads but does not declare would be missing
//! and change the image or fail the run).

use crate::common;

use std::path::Path;

use common::project_root;
use recon::method::{InputData, Inputs, Method};
use recon::registry::METHODS;
use recon::Effect;
use tracer::samples::FieldSelection;
use tracer::{Accel, RenderSettings, Scene};

const WIDTH: u32 = 16;
const HEIGHT: u32 = 12;
const SPP: u32 = 2;

/// The effect's input files (samples, light samples) with the fields `fields` selects.
fn dump(
    scene: &Scene,
    effect: Effect,
    fields: &FieldSelection,
    dir: &Path,
) -> (std::path::PathBuf, Option<std::path::PathBuf>) {
    let accel = Accel::build(scene).unwrap();
    let settings =
        RenderSettings { width: WIDTH, height: HEIGHT, spp: SPP, seed: 3, max_bounces: 3, threads: 0, progress: false };
    let samples = dir.join("samples.lfrs");
    let soft_shadows = effect == Effect::SoftShadow;
    tracer::samples::dump(scene, &accel, &settings, effect.sample_kind(), soft_shadows, fields, &samples).unwrap();
    if !soft_shadows {
        return (samples, None);
    }
    let light_samples = dir.join("light.lfrs");
    tracer::samples::dump(scene, &accel, &settings, sampleio::SampleKind::Light, false, fields, &light_samples)
        .unwrap();
    (samples, Some(light_samples))
}

fn run(method: &dyn Method, effect: Effect, files: &(std::path::PathBuf, Option<std::path::PathBuf>)) -> recon::Image {
    let inputs = Inputs {
        effect,
        width: WIDTH,
        height: HEIGHT,
        spp: SPP,
        data: InputData::Samples { samples: &files.0, light_samples: files.1.as_deref() },
        ao_radius: 0.5,
        seed: 3,
        threads: 0,
    };
    let rays = method.default_recon_rays(effect).into_iter().min().unwrap_or(0).min(8);
    method.run(&inputs, rays).unwrap_or_else(|e| panic!("{effect:?}: {e}")).image
}

#[test]
fn every_sample_reader_gives_the_same_image_from_a_dump_of_its_declared_fields() {
    let scene = |name: &str| Scene::load(&project_root().join("scenes").join(name)).unwrap();
    let (cornell, monkeys, glossy) =
        (scene("cornell.toml"), scene("monkeys-defocus-motion.toml"), scene("monkeys.toml"));
    let cases = [
        (Effect::Indirect, &cornell),
        (Effect::Glossy, &glossy),
        (Effect::Ao, &cornell),
        (Effect::DofMotion, &monkeys),
        (Effect::SoftShadow, &cornell),
    ];
    let mut checked = Vec::new();
    for (effect, scene) in cases {
        let dir = tempfile::tempdir().unwrap();
        let full_dir = dir.path().join("full");
        std::fs::create_dir(&full_dir).unwrap();
        // The full dump: every field of the layout plus the optional ones a full dump leaves
        // out (`lens-time`'s `direct`, which `tlfr`'s default gi=split reads).
        let all = dump(scene, effect, &FieldSelection::All, &full_dir);
        let full = if effect == Effect::SoftShadow {
            all
        } else {
            let file = sampleio::SampleFile::open(&all.0).unwrap();
            let mut names: Vec<String> = file.fields().iter().map(|f| f.name.clone()).collect();
            names.push("direct".into());
            drop(file);
            dump(scene, effect, &FieldSelection::named(names), &full_dir)
        };
        for spec in METHODS.iter().filter(|spec| spec.effects.contains(&effect)) {
            let method = spec.build(&spec.parse_options("").unwrap()).unwrap();
            if method.input() != recon::method::Input::Samples {
                continue;
            }
            let Some(needs) = method.sample_needs(effect) else { continue };
            let fields = FieldSelection::reading(&needs);
            let own_dir = dir.path().join(spec.name);
            std::fs::create_dir(&own_dir).unwrap();
            let own = dump(scene, effect, &fields, &own_dir);
            assert!(std::fs::metadata(&own.0).unwrap().len() <= std::fs::metadata(&full.0).unwrap().len());
            let (from_full, from_own) = (run(&*method, effect, &full), run(&*method, effect, &own));
            assert!(
                from_full == from_own,
                "{} on {effect:?}: the image differs with only its declared fields",
                spec.name
            );
            checked.push(format!("{} {effect:?}", spec.name));
        }
    }
    // The readers that declare their fields, each on every effect it takes samples for.
    for expected in [
        "box Indirect",
        "box SoftShadow",
        "tlfr DofMotion",
        "tlfr SoftShadow",
        "ilfr Ao",
        "ilfr Glossy",
        "ilfr-dof DofMotion",
    ] {
        assert!(checked.iter().any(|c| c == expected), "{expected} not checked: {checked:?}");
    }
}
