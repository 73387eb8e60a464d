//! Dropped non-finite values are warned about, with their count, once per run: an emitter too bright for f32 in `lfr render` and `lfr dump`, and a sample file
//! whose radiance is all NaN in `lfr reconstruct`, no longer give a silently black image.

use crate::common;

use std::process::{Command, Output};

use common::project_root;
use sampleio::{Camera, Coc, FieldSpec, FieldType, HeaderSpec, SampleKind, SampleWriter};

fn lfr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfr")).args(args).current_dir(project_root()).output().expect("lfr runs")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

const BRIGHT_POINT_LIGHT: &str = r#"
[render]
max_bounces = 2
[camera]
position = [0, 5, 0]
look_at = [0, 0, 0]
up = [0, 0, 1]
fov = 10
[[material]]
name = "grey"
base_color = [0.5, 0.5, 0.5]
specular = 0
[[mesh]]
shape = "polygon"
material = "grey"
points = [[-10, 0, -10], [-10, 0, 10], [10, 0, 10], [10, 0, -10]]
[[light]]
type = "point"
position = [0, 0.5, 0]
intensity = [3e38, 3e38, 3e38]
"#;

#[test]
fn render_and_dump_warn_about_overflowing_contributions() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bright.toml");
    std::fs::write(&scene, BRIGHT_POINT_LIGHT).unwrap();
    let out = dir.path().join("bright.exr");
    let size = ["--width", "8", "--height", "8", "--spp", "2", "--quiet"];
    let mut args = vec!["render", "--scene", scene.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend(size);
    let result = lfr(&args);
    let message = stderr(&result);
    assert!(result.status.success(), "{message}");
    let warnings: Vec<&str> =
        message.lines().filter(|l| l.contains("path contributions were NaN or infinite")).collect();
    assert_eq!(warnings.len(), 1, "one warning per run: {message}");
    let count: u64 = warnings[0].trim_start_matches("warning: ").split(' ').next().unwrap().parse().unwrap();
    assert!(count >= 8 * 8 * 2, "every sample's light sample overflows: {message}");

    let samples = dir.path().join("bright.lfrs");
    let mut args = vec!["dump", "--kind", "lens-time", "--scene", scene.to_str().unwrap(), "--out"];
    args.push(samples.to_str().unwrap());
    args.extend(size);
    let result = lfr(&args);
    let message = stderr(&result);
    assert!(result.status.success(), "{message}");
    assert_eq!(message.matches("path contributions were NaN or infinite").count(), 1, "{message}");

    // The same scene with a finite light warns about nothing.
    std::fs::write(&scene, BRIGHT_POINT_LIGHT.replace("3e38", "1")).unwrap();
    let mut args = vec!["render", "--scene", scene.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend(size);
    let result = lfr(&args);
    assert!(result.status.success() && !stderr(&result).contains("warning"), "{}", stderr(&result));
}

/// A floor and a ceiling with a 3e38 point light between them: the light reflected once off the
/// ceiling onto the floor (the guide's indirect light) is about 1e37, its square far beyond f32.
const BRIGHT_LIGHT_BETWEEN_TWO_PLANES: &str = r#"
[render]
max_bounces = 3
[camera]
position = [0, 0.8, 0]
look_at = [0, 0, 0]
up = [0, 0, 1]
fov = 60
[[material]]
name = "grey"
base_color = [0.5, 0.5, 0.5]
specular = 0
[[mesh]]
shape = "polygon"
material = "grey"
points = [[-10, 0, -10], [-10, 0, 10], [10, 0, 10], [10, 0, -10]]
[[mesh]]
shape = "polygon"
material = "grey"
points = [[-10, 1, -10], [10, 1, -10], [10, 1, 10], [-10, 1, 10]]
[[light]]
type = "point"
position = [0, 0.5, 0]
intensity = [3e38, 3e38, 3e38]
"#;

#[test]
fn the_guide_dump_and_filter_count_and_warn_about_overflowing_light() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bright.toml");
    std::fs::write(&scene, BRIGHT_LIGHT_BETWEEN_TWO_PLANES).unwrap();
    let guide = dir.path().join("guide.exr");
    let size = ["--width", "8", "--height", "8", "--spp", "4", "--quiet"];
    let warned =
        |message: &str| message.lines().filter(|l| l.starts_with("warning:")).map(str::to_string).collect::<Vec<_>>();
    let mut args =
        vec!["dump", "--kind", "guide", "--scene", scene.to_str().unwrap(), "--out", guide.to_str().unwrap()];
    args.extend(size);
    let result = lfr(&args);
    let message = stderr(&result);
    assert!(result.status.success(), "{message}");
    let warnings = warned(&message);
    assert!(
        warnings.iter().any(|w| w.contains("path contributions were NaN or infinite"))
            && warnings.iter().any(|w| w.contains("values exceed the f32 range")),
        "the dropped light and the clamped variance are both counted: {message}"
    );
    let (_, _, channels) = tracer::output::read_exr(&guide).unwrap();
    for (name, values) in &channels {
        assert!(values.iter().all(|v| v.is_finite()), "{name} holds a non-finite value");
    }
    let variance: Vec<f32> =
        channels.iter().filter(|(n, _)| n.starts_with("indirect_variance")).flat_map(|(_, v)| v.clone()).collect();
    assert!(variance.contains(&f32::MAX), "the overflowing variance is stored as f32::MAX");

    let filtered = dir.path().join("filtered.exr");
    let mut args = vec!["filter", "--scene", scene.to_str().unwrap(), "--out", filtered.to_str().unwrap()];
    args.extend(size);
    let result = lfr(&args);
    let message = stderr(&result);
    assert!(result.status.success(), "{message}");
    assert!(warned(&message).iter().any(|w| w.contains("path contributions were NaN or infinite")), "{message}");

    // The same scene with a finite light: nothing dropped, nothing clamped, no warning.
    std::fs::write(&scene, BRIGHT_LIGHT_BETWEEN_TWO_PLANES.replace("3e38", "1")).unwrap();
    for command in ["dump", "filter"] {
        let out = if command == "dump" { &guide } else { &filtered };
        let mut args = vec![command, "--scene", scene.to_str().unwrap(), "--out", out.to_str().unwrap()];
        if command == "dump" {
            args.extend(["--kind", "guide"]);
        }
        args.extend(size);
        let result = lfr(&args);
        assert!(result.status.success() && warned(&stderr(&result)).is_empty(), "{}", stderr(&result));
    }
}

#[test]
fn reconstruct_warns_about_an_all_nan_radiance() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.lfrs");
    let mut spec = HeaderSpec::new(SampleKind::LensTime, 4, 4, 2)
        .field(FieldSpec::new("x", FieldType::F32, 1))
        .field(FieldSpec::new("y", FieldType::F32, 1))
        .field(FieldSpec::new("z", FieldType::F32, 1))
        .field(FieldSpec::new("radiance", FieldType::F32, 3));
    // The sample camera as a pinhole.
    spec.camera =
        Some(Camera { aperture_radius: 0.0, coc: Coc { c1: 0.0, c2: 0.0 }, ..testkit::sample_camera::camera() });
    let mut writer = SampleWriter::create(&path, spec).unwrap();
    for i in 0..32u32 {
        let pixel = i / 2;
        let (x, y) = ((pixel % 4) as f32 + 0.25 + 0.5 * (i % 2) as f32, (pixel / 4) as f32 + 0.5);
        writer.push(&[x, y, 2.0, f32::NAN, f32::NAN, f32::NAN]).unwrap();
    }
    writer.finish().unwrap();
    let out = dir.path().join("out.exr");
    let result =
        lfr(&["reconstruct", "--samples", path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--locations", "4"]);
    let message = stderr(&result);
    assert!(result.status.success(), "{message}");
    let expected = format!("warning: {}: 32 of 32 samples have a non-finite", path.display());
    assert!(message.contains(&expected), "expected {expected:?} in {message}");
    assert!(message.contains("the image is black"), "{message}");
    assert_eq!(message.matches("warning").count(), 1, "one warning: {message}");
}

/// A scene's warning names the file once: a base colour above 1 in a TOML scene reads
/// `warning: FILE: material[i] 'grey'.base_color: ...`, not `FILE: FILE: ...`.
#[test]
fn a_scene_warning_names_its_file_once() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bright-grey.toml");
    let text =
        BRIGHT_POINT_LIGHT.replace("3e38", "1").replace("base_color = [0.5, 0.5, 0.5]", "base_color = [1.5, 0.5, 0.5]");
    std::fs::write(&scene, text).unwrap();
    let out = dir.path().join("o.exr");
    let result = lfr(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--width",
        "4",
        "--height",
        "4",
        "--spp",
        "1",
        "--quiet",
    ]);
    let message = stderr(&result);
    assert!(result.status.success(), "{message}");
    let name = scene.display().to_string();
    let line = message.lines().find(|l| l.contains("base_color")).unwrap_or_else(|| panic!("no warning: {message}"));
    assert!(line.starts_with(&format!("warning: {name}: material[")) && line.contains("'grey'.base_color"), "{line}");
    assert_eq!(line.matches(&name).count(), 1, "{line}");
}
