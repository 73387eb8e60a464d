//! Sample files the format allows but a method cannot read: a known field
//! declared with another type or component count. Every method of the registry that reads
//! sample files, on every effect it handles, must refuse them with an error naming the file and
//! the field (what it is, what is needed), never panic nor read past the field's end.

use std::path::{Path, PathBuf};

use recon::method::{Effect, Input, InputData, Inputs, MethodError};
use recon::registry::METHODS;
use sampleio::{FieldSpec, FieldType, HeaderSpec, LightGeometry, SampleKind, SampleWriter};
use testkit::sample_camera::camera;

use FieldType::{F16, F32, U16, U8};

/// Every field the format defines for `kind`, with the format's type and component count
/// (docs/sample-format.md, "Sample kinds").
fn format_fields(kind: SampleKind) -> Vec<(&'static str, FieldType, u32)> {
    match kind {
        SampleKind::LensTime => vec![
            ("x", F32, 1),
            ("y", F32, 1),
            ("u", F32, 1),
            ("v", F32, 1),
            ("t", F32, 1),
            ("z", F32, 1),
            ("motion", F32, 3),
            ("radiance", F32, 3),
            ("depth_gradient", F32, 2),
            ("bandwidth", F16, 1),
            ("albedo", F16, 3),
            ("normal", U16, 2),
            ("radiance_without_light", F32, 3),
        ],
        SampleKind::Light => vec![
            ("lu", F32, 1),
            ("lv", F32, 1),
            ("lx", F32, 1),
            ("ly", F32, 1),
            ("z", F32, 1),
            ("radiance", F32, 3),
            ("density", F32, 1),
        ],
        SampleKind::Indirect | SampleKind::Ao => {
            let mut fields = vec![
                ("x", F32, 1),
                ("y", F32, 1),
                ("direction", U16, 2),
                ("origin", F32, 3),
                ("hit", F32, 3),
                ("origin_normal", U16, 2),
                ("hit_normal", U16, 2),
            ];
            if kind == SampleKind::Ao {
                fields.push(("distance", F32, 1));
            } else {
                fields.extend([
                    ("radiance", F32, 3),
                    ("albedo", F16, 3),
                    ("direct", F32, 3),
                    ("secondary_albedo", F16, 3),
                    ("secondary_direct", F16, 3),
                ]);
            }
            fields
        }
    }
}

/// A 4×4, 2-spp file of `kind` with every format field, `changed` (name, type, components)
/// replacing one of them; values are 1 (within every type's range).
fn write(dir: &Path, name: &str, kind: SampleKind, changed: Option<(&str, FieldType, u32)>) -> PathBuf {
    let mut spec = HeaderSpec::new(kind, 4, 4, 2);
    let mut values = 0;
    for (field, ty, components) in format_fields(kind) {
        let (ty, components) = match changed {
            Some((c, t, n)) if c == field => (t, n),
            _ => (ty, components),
        };
        spec = spec.field(FieldSpec::new(field, ty, components));
        values += components as usize;
    }
    spec.camera = Some(camera());
    if kind == SampleKind::Light {
        spec.light = Some(LightGeometry {
            corner: Some([-0.5, -1.0, 2.0]),
            edge_u: Some([1.0, 0.0, 0.0]),
            edge_v: Some([0.0, 0.0, 1.0]),
            normal: Some([0.0, 1.0, 0.0]),
            plane_distance: Some(1.0),
        });
    }
    let path = dir.join(name);
    let mut writer = SampleWriter::create(&path, spec).unwrap();
    for _ in 0..32 {
        writer.push(&vec![1.0; values]).unwrap();
    }
    writer.finish().unwrap()
}

/// Runs method `name` on `effect` with the given files; the error message.
fn run(name: &str, effect: Effect, samples: &Path, light: Option<&Path>) -> Result<(), String> {
    let method = recon::registry::find(name).unwrap().unwrap();
    let inputs = Inputs {
        effect,
        width: 4,
        height: 4,
        spp: 2,
        data: InputData::Samples { samples, light_samples: light },
        ao_radius: 1.0,
        seed: 1,
        threads: 1,
    };
    match method.run(&inputs, 4) {
        Ok(_) => Ok(()),
        Err(MethodError::Failed(e) | MethodError::Unavailable(e)) => Err(e.to_string()),
        Err(MethodError::Unsupported(m)) => Err(m),
    }
}

/// Every sample-reading method with every effect it handles.
fn sample_methods() -> Vec<(&'static str, Effect)> {
    let mut pairs = Vec::new();
    for spec in METHODS {
        let method = recon::registry::find(spec.name).unwrap().unwrap();
        if method.input() == Input::Samples {
            pairs.extend(spec.effects.iter().map(|&e| (spec.name, e)));
        }
    }
    pairs
}

fn assert_names(error: &Result<(), String>, path: &Path, what: &str, context: &str) {
    let message = error.as_ref().expect_err(context);
    let expected = format!("{}: field {what}", path.display());
    assert!(message.contains(&expected), "{context}: expected {expected:?} in {message:?}");
    assert_eq!(message.matches(&path.display().to_string()).count(), 1, "{context}: the path once: {message}");
}

#[test]
fn every_sample_method_refuses_a_byte_radiance() {
    let dir = tempfile::tempdir().unwrap();
    let pairs = sample_methods();
    let names: Vec<&str> = pairs.iter().map(|p| p.0).collect();
    for expected in ["box", "tlfr", "tlfr-nn", "tlfr-bw", "ilfr", "ilfr-recursive", "ilfr-dof"] {
        assert!(names.contains(&expected), "{expected} reads samples: {names:?}");
    }
    for (name, effect) in pairs {
        let kind = effect.sample_kind();
        let (field, needed) = match kind {
            SampleKind::Ao => ("distance", "f32×1 or f16×1"),
            _ => ("radiance", "f32×3 or f16×3"),
        };
        let path = write(dir.path(), &format!("{name}-{}.lfrs", effect.name()), kind, Some((field, U8, 1)));
        let light = write(dir.path(), "light.lfrs", SampleKind::Light, None);
        let result = run(name, effect, &path, Some(&light));
        let context = format!("{name} on {}", effect.name());
        assert_names(&result, &path, &format!("`{field}` is u8×1"), &context);
        assert!(result.unwrap_err().contains(&format!("needs {needed}")), "{context}");
    }
}

#[test]
fn lens_time_readers_refuse_a_short_motion_and_integer_positions() {
    let dir = tempfile::tempdir().unwrap();
    for (name, effect) in sample_methods() {
        if effect.sample_kind() != SampleKind::LensTime || effect == Effect::SoftShadow {
            continue;
        }
        let context = format!("{name} on {}", effect.name());
        // The format's general table allows a 2-component (screen-space) motion; these readers
        // need the camera-space 3-vector. `box` reads only the radiance.
        for (field, ty, n) in [("x", U16, 1), ("motion", F32, 2), ("z", F32, 3)] {
            let path = write(dir.path(), &format!("{field}.lfrs"), SampleKind::LensTime, Some((field, ty, n)));
            let result = run(name, effect, &path, None);
            if name == "box" {
                assert!(result.is_ok(), "{context}: {result:?}");
            } else {
                assert_names(&result, &path, &format!("`{field}` is {}×{n}", ty.name()), &context);
            }
        }
    }
}

#[test]
fn indirect_readers_refuse_float_directions_and_short_albedo() {
    let dir = tempfile::tempdir().unwrap();
    for (name, effect) in sample_methods() {
        let kind = effect.sample_kind();
        if !matches!(kind, SampleKind::Indirect | SampleKind::Ao) {
            continue;
        }
        let context = format!("{name} on {}", effect.name());
        let path = write(dir.path(), "normal.lfrs", kind, Some(("origin_normal", F32, 2)));
        let result = run(name, effect, &path, None);
        if name == "box" && kind == SampleKind::Indirect {
            // `box` weights radiance by albedo; it never reads a normal.
            assert!(result.is_ok(), "{context}: {result:?}");
        } else {
            assert_names(&result, &path, "`origin_normal` is f32×2", &context);
            assert!(result.unwrap_err().contains("needs u16×2"), "{context}");
        }
        if kind == SampleKind::Indirect {
            let path = write(dir.path(), "albedo.lfrs", kind, Some(("albedo", F16, 1)));
            assert_names(&run(name, effect, &path, None), &path, "`albedo` is f16×1", &context);
        }
    }
}

#[test]
fn soft_shadows_refuse_bad_shading_and_light_fields() {
    let dir = tempfile::tempdir().unwrap();
    let good_camera = write(dir.path(), "camera.lfrs", SampleKind::LensTime, None);
    for (field, ty, n) in [("normal", F32, 2), ("albedo", U8, 3), ("radiance_without_light", F32, 1)] {
        let camera = write(dir.path(), &format!("camera-{field}.lfrs"), SampleKind::LensTime, Some((field, ty, n)));
        let light = write(dir.path(), "light.lfrs", SampleKind::Light, None);
        let result = run("tlfr", Effect::SoftShadow, &camera, Some(&light));
        assert_names(&result, &camera, &format!("`{field}` is {}×{n}", ty.name()), "tlfr soft-shadow camera");
        assert!(result.unwrap_err().contains("TLFR soft shadows needs"));
    }
    for (field, ty, n) in [("density", U8, 1), ("radiance", F32, 4), ("lu", F16, 2)] {
        let light = write(dir.path(), &format!("light-{field}.lfrs"), SampleKind::Light, Some((field, ty, n)));
        let result = run("tlfr", Effect::SoftShadow, &good_camera, Some(&light));
        assert_names(&result, &light, &format!("`{field}` is {}×{n}", ty.name()), "tlfr soft-shadow light");
    }
}
