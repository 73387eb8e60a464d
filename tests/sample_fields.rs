//! `lfr reconstruct` and `lfr export` on sample files the format allows but the command cannot
//! read: a known field with another type or component count. Each must
//! exit non-zero with an error naming the file (once) and the field, without a panic and
//! without leaving any file (no output, no `OUT.<pid>.tmp`).

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::project_root;
use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleKind, SampleWriter};
use testkit::sample_camera::camera;

use FieldType::{F16, F32, U16, U32, U8};

/// A field as declared: name, type, component count.
type Declared = (&'static str, FieldType, u32);

fn lfr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfr")).args(args).current_dir(project_root()).output().expect("lfr runs")
}

const LENS_TIME: &[Declared] = &[
    ("x", F32, 1),
    ("y", F32, 1),
    ("u", F32, 1),
    ("v", F32, 1),
    ("t", F32, 1),
    ("z", F32, 1),
    ("motion", F32, 3),
    ("radiance", F32, 3),
    ("depth_gradient", F32, 2),
];

const INDIRECT: &[Declared] = &[
    ("x", F32, 1),
    ("y", F32, 1),
    ("direction", U16, 2),
    ("radiance", F32, 3),
    ("origin", F32, 3),
    ("hit", F32, 3),
    ("origin_normal", U16, 2),
    ("hit_normal", U16, 2),
    ("albedo", F16, 3),
    ("direct", F32, 3),
    ("secondary_albedo", F16, 3),
    ("secondary_direct", F16, 3),
];

/// A 4×4, 2-spp file of `kind` with `fields` (the format's), `changed` replacing one of them
/// (or added when the list lacks it); every value 1.
fn write(dir: &Path, kind: SampleKind, fields: &[(&str, FieldType, u32)], changed: (&str, FieldType, u32)) -> PathBuf {
    let mut fields = fields.to_vec();
    match fields.iter_mut().find(|f| f.0 == changed.0) {
        Some(field) => *field = changed,
        None => fields.push(changed),
    }
    let mut spec = HeaderSpec::new(kind, 4, 4, 2);
    for (name, ty, n) in &fields {
        spec = spec.field(FieldSpec::new(*name, *ty, *n));
    }
    spec.camera = Some(camera());
    let values: u32 = fields.iter().map(|f| f.2).sum();
    let path = dir.join(format!("{}-{}{}.lfrs", changed.0, changed.1.name(), changed.2));
    let mut writer = SampleWriter::create(&path, spec).unwrap();
    for _ in 0..32 {
        writer.push(&vec![1.0; values as usize]).unwrap();
    }
    writer.finish().unwrap()
}

/// Runs `args`, expects the refusal of `samples`'s `field` as `found`, and that `out_dir` stays
/// empty.
fn expect_refusal(args: &[&str], samples: &Path, field: &str, found: &str, needed: &str, out_dir: &Path) {
    let result = lfr(args);
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(!result.status.success(), "{args:?} must fail: {message}");
    assert!(!message.contains("panicked"), "{args:?}: a panic: {message}");
    let expected = format!("{}: field `{field}` is {found}, ", samples.display());
    assert!(message.contains(&expected), "{args:?}: expected {expected:?} in {message}");
    assert!(message.contains(&format!("needs {needed}")), "{args:?}: {message}");
    let path = samples.display().to_string();
    assert_eq!(message.matches(&path).count(), 1, "{args:?}: the path once: {message}");
    let left: Vec<_> = std::fs::read_dir(out_dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(left.is_empty(), "{args:?} left {left:?}");
}

#[test]
fn reconstruct_refuses_fields_it_cannot_read() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("out.exr");
    for (changed, needed) in [
        (("radiance", U8, 1), "f32×3 or f16×3"),
        (("radiance", F32, 2), "f32×3 or f16×3"),
        (("motion", F32, 2), "f32×3 or f16×3"),
        (("z", U32, 1), "f32×1 or f16×1"),
        (("bandwidth", U8, 1), "f32×1 or f16×1"),
    ] {
        let samples = write(dir.path(), SampleKind::LensTime, LENS_TIME, changed);
        let args =
            ["reconstruct", "--samples", samples.to_str().unwrap(), "--out", out.to_str().unwrap(), "--locations", "4"];
        let found = format!("{}×{}", changed.1.name(), changed.2);
        expect_refusal(&args, &samples, changed.0, &found, needed, out_dir.path());
    }
}

#[test]
fn export_refuses_fields_it_cannot_read_and_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("out.bin");
    let cases: [(&str, SampleKind, &[Declared], Declared, &str); 7] = [
        ("tlfr-1.3", SampleKind::LensTime, LENS_TIME, ("radiance", U8, 1), "f32×3 or f16×3"),
        ("tlfr-1.3", SampleKind::LensTime, LENS_TIME, ("depth_gradient", F32, 1), "f32×2 or f16×2"),
        ("tlfr-1.3", SampleKind::LensTime, LENS_TIME, ("motion", F32, 2), "f32×3 or f16×3"),
        ("ilfr-2.2", SampleKind::Indirect, INDIRECT, ("radiance", U8, 1), "f32×3 or f16×3"),
        ("ilfr-2.2", SampleKind::Indirect, INDIRECT, ("origin_normal", F32, 2), "u16×2"),
        ("ilfr-2.2", SampleKind::Indirect, INDIRECT, ("secondary_direct", F16, 2), "f32×3 or f16×3"),
        ("ilfr-2.2", SampleKind::Indirect, INDIRECT, ("hit_motion", F32, 2), "f32×3 or f16×3"),
    ];
    for (format, kind, fields, changed, needed) in cases {
        let samples = write(dir.path(), kind, fields, changed);
        let args = ["export", "--format", format, samples.to_str().unwrap(), out.to_str().unwrap()];
        let found = format!("{}×{}", changed.1.name(), changed.2);
        expect_refusal(&args, &samples, changed.0, &found, needed, out_dir.path());
    }
    // The same files with the field as the format has it export (the refusal is the field's).
    let samples = write(dir.path(), SampleKind::Indirect, INDIRECT, ("hit_motion", F16, 3));
    let result = lfr(&["export", "--format", "ilfr-2.2", samples.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    assert_eq!(std::fs::metadata(&out).unwrap().len(), 32 * 39 * 4);
}
