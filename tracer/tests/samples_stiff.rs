//! Stiff cases for every sample kind: 1x1 images at 1 spp, an empty scene, a lens a millionth
//! of a unit from a wall, a 1e9 radiance spike, motion beyond f16's range. Every value written
//! stays finite where the format promises finite values.

use crate::common;

use common::{scene_from_toml, SceneToml};
use sampleio::SampleFile;
use tracer::samples::secondary::SecondaryKind;
use tracer::samples::{guide, lens_time, light, secondary};
use tracer::RenderSettings;
use tracer::{Accel, Scene};

fn settings(width: u32, height: u32, spp: u32) -> RenderSettings {
    RenderSettings { width, height, spp, seed: 1, max_bounces: 8, threads: 0, progress: false }
}

/// Dumps every sample-file kind the scene supports and returns the opened files.
fn dump_all(scene: &Scene, settings: &RenderSettings) -> Vec<(String, SampleFile, tempfile::TempDir)> {
    let accel = Accel::build(scene).unwrap();
    let mut files = Vec::new();
    for kind in ["lens-time", "light", "indirect", "ao"] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.lfrs");
        let result = match kind {
            "lens-time" => lens_time::dump(scene, &accel, settings, &tracer::samples::FieldSelection::All, &path),
            "light" => light::dump(scene, &accel, settings, &tracer::samples::FieldSelection::All, &path),
            "indirect" => secondary::dump(
                scene,
                &accel,
                settings,
                SecondaryKind::Indirect,
                &tracer::samples::FieldSelection::All,
                &path,
            ),
            _ => secondary::dump(
                scene,
                &accel,
                settings,
                SecondaryKind::AmbientOcclusion,
                &tracer::samples::FieldSelection::All,
                &path,
            ),
        };
        match result {
            Ok(_) => files.push((kind.to_string(), SampleFile::open(&path).unwrap(), dir)),
            Err(e) => {
                // Only light samples may be refused, and only for want of a planar emitter.
                assert_eq!(kind, "light", "{kind}: {e}");
                assert!(e.to_string().contains("emissive") || e.to_string().contains("planar"), "{e}");
                assert!(!path.exists(), "no partial file");
            }
        }
    }
    files
}

/// Fields that must be finite in every sample (z, distance may be +inf by definition).
fn assert_finite(kind: &str, file: &SampleFile) {
    for field in file.fields() {
        if matches!(field.name.as_str(), "z" | "distance") {
            continue;
        }
        let values = file.column(&field.name).unwrap();
        assert!(values.iter().all(|v| v.is_finite()), "{kind}: non-finite {}", field.name);
    }
}

const SPIKE: &str = r#"
    [render]
    environment = [0.1, 0.1, 0.1]
    [camera]
    position = [0, 1, 4]
    look_at = [0, 0, 0]
    fov = 40
    aperture_radius = 0.3
    focus_distance = 2
    [[material]]
    name = "mirror"
    base_color = [1, 1, 1]
    metallic = 1
    roughness = 0.001
    [[material]]
    name = "lamp"
    base_color = [0, 0, 0]
    specular = 0
    emission = [1e9, 1e9, 1e9]
    [[mesh]]
    shape = "polygon"
    material = "mirror"
    points = [[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]]
    [[mesh]]
    shape = "box"
    min = [-0.3, 0, -0.3]
    max = [0.3, 0.6, 0.3]
    motion = [100000, 0, 0]
    [[mesh]]
    shape = "polygon"
    material = "lamp"
    points = [[-0.01, 2, -0.01], [0.01, 2, -0.01], [0.01, 2, 0.01], [-0.01, 2, 0.01]]
"#;

#[test]
fn one_pixel_one_sample_for_every_kind() {
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let files = dump_all(&scene, &settings(1, 1, 1));
    assert_eq!(files.len(), 4);
    for (kind, file, _dir) in &files {
        assert_eq!(file.len(), 1, "{kind}");
        assert_finite(kind, file);
    }
    let accel = Accel::build(&scene).unwrap();
    let buffers = guide::guide_buffers(&scene, &accel, &settings(1, 1, 1)).unwrap();
    assert!(buffers.direct[0].is_finite() && buffers.indirect[0].is_finite());
    assert_eq!(buffers.indirect_variance[0], glam::Vec3::ZERO, "one sample has no variance estimate");
}

#[test]
fn an_empty_scene_gives_inert_samples_not_errors() {
    let scene = SceneToml::lit_by_environment([0.5, 0.5, 0.5]).scene();
    let files = dump_all(&scene, &settings(3, 2, 2));
    assert_eq!(files.len(), 3, "lens-time, indirect and ao; light samples need an emitter");
    for (kind, file, _dir) in &files {
        assert_finite(kind, file);
        if kind == "lens-time" {
            assert!(file.column("z").unwrap().iter().all(|z| *z == f32::INFINITY));
        }
        if kind == "indirect" {
            assert!(file.column("direct").unwrap().iter().all(|v| *v == 0.5), "the environment, seen directly");
        }
    }
}

#[test]
fn radiance_spikes_mirrors_and_huge_motion_stay_finite() {
    let scene = scene_from_toml(SPIKE);
    let files = dump_all(&scene, &settings(12, 8, 4));
    assert_eq!(files.len(), 4);
    for (kind, file, _dir) in &files {
        assert_finite(kind, file);
        if kind == "indirect" {
            let motion = file.field("hit_motion").unwrap();
            assert_eq!(motion.ty, sampleio::FieldType::F32, "motion beyond f16's range is stored as f32");
            assert!(file.column("bandwidth").unwrap().iter().all(|k| *k <= 65504.0));
        }
    }
}

#[test]
fn a_lens_a_millionth_from_a_wall_gives_finite_depths_and_gradients() {
    let scene = common::camera_a_millionth_from_a_wall("aperture_radius = 0.0000005\nfocus_distance = 1\n");
    let files = dump_all(&scene, &settings(6, 6, 2));
    let (_, lens_time, _dir) = files.iter().find(|(k, _, _)| k == "lens-time").unwrap();
    assert_finite("lens-time", lens_time);
    for z in lens_time.column("z").unwrap() {
        assert!((0.0..1e-5).contains(&z), "z = {z}");
    }
}

/// f16 fields are clamped to 65504 as docs/sample-format.md promises, never
/// stored as infinity: an (energy-gaining) base colour of 1e6 gives albedo 65504 in the file.
#[test]
fn f16_fields_are_clamped_not_infinite() {
    let scene = common::SceneToml::new(2, Some([1.0; 3]))
        .camera([0.0, 1.0, 4.0], [0.0; 3], 40.0, "")
        .diffuse("blinding", [1e6; 3])
        .polygon("blinding", &common::FLOOR, "")
        .scene();
    for (kind, file, _dir) in dump_all(&scene, &settings(4, 4, 2)) {
        assert_finite(&kind, &file);
        if kind == "indirect" {
            let albedo = file.column("albedo").unwrap();
            assert!(albedo.contains(&65504.0), "the albedo of 1e6 is stored as 65504");
            assert!(albedo.iter().all(|&a| a <= 65504.0));
        }
    }
}
