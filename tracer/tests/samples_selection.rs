//! A dump with a field selection (`FieldSelection`) is the full dump with the other columns left
//! out: the same samples in the same order, each kept field with the same type and the same
//! bytes, whatever the kind and whatever the layout skips computing (the depth gradient).

use crate::common;

use std::path::Path;

use common::project_root;
use sampleio::SampleFile;
use tracer::samples::secondary::SecondaryKind;
use tracer::samples::{lens_time, light, secondary, FieldSelection};
use tracer::{Accel, RenderSettings, Scene};

fn settings(threads: usize) -> RenderSettings {
    RenderSettings { width: 9, height: 7, spp: 3, seed: 5, max_bounces: 3, threads, progress: false }
}

fn dump(scene: &Scene, kind: &str, fields: &FieldSelection, threads: usize, path: &Path) {
    let accel = Accel::build(scene).unwrap();
    let settings = settings(threads);
    let result = match kind {
        "lens-time" => lens_time::dump(scene, &accel, &settings, fields, path),
        "soft-shadow" => lens_time::dump_for_soft_shadows(scene, &accel, &settings, fields, path),
        "light" => light::dump(scene, &accel, &settings, fields, path),
        "indirect" => secondary::dump(scene, &accel, &settings, SecondaryKind::Indirect, fields, path),
        _ => secondary::dump(scene, &accel, &settings, SecondaryKind::AmbientOcclusion, fields, path),
    };
    result.unwrap_or_else(|e| panic!("{kind}: {e}"));
}

/// Every kept field of `selected` holds, sample by sample, the bytes of the same field of `full`.
fn assert_columns_equal(full: &SampleFile, selected: &SampleFile, expected: &[&str]) {
    let names: Vec<&str> = selected.fields().iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, expected);
    assert_eq!(selected.len(), full.len());
    for field in selected.fields() {
        let original = full.field(&field.name).unwrap();
        assert_eq!((field.ty, field.components), (original.ty, original.components), "{}", field.name);
        let size = field.ty.size() * field.components as usize;
        for sample in 0..full.len() {
            let (a, b) = (full.record(sample), selected.record(sample));
            assert_eq!(
                &a[original.offset as usize..original.offset as usize + size],
                &b[field.offset as usize..field.offset as usize + size],
                "{} of sample {sample}",
                field.name
            );
        }
    }
}

#[test]
fn a_selected_dump_is_the_full_dump_without_the_other_columns() {
    let monkeys = Scene::load(&project_root().join("scenes/monkeys-defocus-motion.toml")).unwrap();
    let lamp = Scene::load(&project_root().join("scenes/soft-shadow.toml")).unwrap();
    let cases: [(&Scene, &str, &[&str], &[&str]); 6] = [
        // Without the gradient, which the layout then does not compute.
        (&monkeys, "lens-time", &["radiance"], &["radiance"]),
        (
            &monkeys,
            "lens-time",
            &["x", "y", "u", "v", "t", "z", "motion", "radiance", "bandwidth"],
            &["x", "y", "u", "v", "t", "z", "motion", "radiance", "bandwidth"],
        ),
        // Names the layout lacks are ignored (this scene has no lens and no motion).
        (
            &lamp,
            "soft-shadow",
            &["radiance", "normal", "u", "motion", "depth_gradient"],
            &["radiance", "depth_gradient", "normal"],
        ),
        (&lamp, "light", &["density", "lu", "radiance"], &["lu", "radiance", "density"]),
        (&monkeys, "indirect", &["weight", "radiance", "albedo"], &["radiance", "albedo", "weight"]),
        (&monkeys, "ao", &["origin_normal", "distance"], &["distance", "origin_normal"]),
    ];
    for (scene, kind, names, expected) in cases {
        let dir = tempfile::tempdir().unwrap();
        let (full, selected) = (dir.path().join("full.lfrs"), dir.path().join("selected.lfrs"));
        dump(scene, kind, &FieldSelection::All, 0, &full);
        // One thread against all of them: the selection keeps the thread-count independence.
        dump(scene, kind, &FieldSelection::named(names.iter().copied()), 1, &selected);
        let (full, selected) = (SampleFile::open(&full).unwrap(), SampleFile::open(&selected).unwrap());
        assert_columns_equal(&full, &selected, expected);
        assert!(selected.header().record_size < full.header().record_size, "{kind}");
    }
}

#[test]
fn a_strict_selection_naming_a_missing_field_writes_nothing() {
    let lamp = Scene::load(&project_root().join("scenes/soft-shadow.toml")).unwrap();
    let accel = Accel::build(&lamp).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.lfrs");
    // The lamp scene has no lens: `u` is not one of its lens-time fields.
    let fields = FieldSelection::parse_strict("radiance,u").unwrap();
    let error = lens_time::dump(&lamp, &accel, &settings(0), &fields, &path).unwrap_err().to_string();
    assert!(error.contains("`u`") && error.contains("lens-time") && error.contains("radiance"), "{error}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no file, no temporary left");
}
