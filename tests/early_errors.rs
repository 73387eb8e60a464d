//! Errors that used to come late or unclear: `lfr compare` refuses a
//! reference cache it cannot write and a soft-shadow scene whose light is not planar before it
//! traces anything; a bad MTL line is named with its file and line number.

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

use common::{project_root, shared_scenes};

fn lfr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(args)
        .current_dir(project_root())
        .env("LFR_SCENES", shared_scenes())
        .output()
        .expect("lfr runs")
}

/// Runs a tiny `lfr compare` into `out` expecting an error that mentions every needle, before
/// anything was traced: the first line of progress (`compare: ... reference ...`) is never
/// printed and `out` is never created.
fn expect_early_compare_error(out: &Path, extra: &[&str], needles: &[&str]) {
    let mut args = vec!["compare", "--out", out.to_str().unwrap(), "--width", "8", "--height", "8"];
    args.extend_from_slice(&["--spp", "1", "--reference-spp", "2", "--pt-max-spp", "1", "--methods", "box"]);
    args.extend_from_slice(extra);
    let result = lfr(&args);
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(!result.status.success(), "{extra:?} must fail: {message}");
    assert!(!message.contains("panicked"), "{message}");
    for needle in needles {
        assert!(message.contains(needle), "{extra:?}: expected {needle:?} in {message}");
    }
    assert!(!message.contains("reference"), "{extra:?}: nothing may be traced first: {message}");
    assert!(!out.exists(), "{extra:?}: {} was created", out.display());
}

#[test]
fn compare_refuses_an_unusable_cache_dir_before_tracing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let file = dir.path().join("a-file");
    std::fs::write(&file, "not a directory").unwrap();
    let extra = ["--effect", "indirect", "--cache-dir", file.to_str().unwrap()];
    expect_early_compare_error(&out, &extra, &["--cache-dir", "a-file", "not a directory"]);
    // A directory below a regular file cannot be created.
    let below = file.join("cache");
    let extra = ["--effect", "indirect", "--cache-dir", below.to_str().unwrap()];
    expect_early_compare_error(&out, &extra, &["--cache-dir", "cannot create the directory"]);

    // A read-only directory: only meaningful when permissions apply (not for root).
    use std::os::unix::fs::PermissionsExt;
    let read_only = dir.path().join("read-only");
    std::fs::create_dir(&read_only).unwrap();
    std::fs::set_permissions(&read_only, std::fs::Permissions::from_mode(0o555)).unwrap();
    if std::fs::write(read_only.join("probe"), "").is_err() {
        let extra = ["--effect", "indirect", "--cache-dir", read_only.to_str().unwrap()];
        expect_early_compare_error(&out, &extra, &["--cache-dir", "read-only", "cannot write into the directory"]);
    } else {
        testkit::skip_unless_unprivileged("the read-only case: this user writes into a 0555 directory (root)");
    }
    std::fs::set_permissions(&read_only, std::fs::Permissions::from_mode(0o755)).unwrap();
}

#[test]
fn soft_shadow_refuses_a_non_planar_light_before_tracing() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("ball-light.toml");
    std::fs::write(
        &scene,
        r#"
        [camera]
        position = [0, 1, 4]
        look_at = [0, 0, 0]
        fov = 50
        [[material]]
        name = "grey"
        base_color = [0.5, 0.5, 0.5]
        [[material]]
        name = "lamp"
        base_color = [0, 0, 0]
        emission = [4, 4, 4]
        [[mesh]]
        shape = "polygon"
        material = "grey"
        points = [[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]]
        [[mesh]]
        shape = "sphere"
        material = "lamp"
        center = [0, 2, 0]
        radius = 0.3
        subdivisions = 1
        "#,
    )
    .unwrap();
    let out = dir.path().join("out");
    let cache = dir.path().join("cache");
    let extra = ["--effect", "soft-shadow", "--scene", scene.to_str().unwrap(), "--cache-dir", cache.to_str().unwrap()];
    expect_early_compare_error(&out, &extra, &["ball-light.toml", "not planar"]);
}

#[test]
fn a_bad_mtl_line_is_named_by_render() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tri.mtl"), "newmtl red\nKd 0.8 0.1\n").unwrap();
    let obj = dir.path().join("tri.obj");
    std::fs::write(&obj, "mtllib tri.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n").unwrap();
    let out = dir.path().join("out.exr");
    let result = lfr(&["render", "--scene", obj.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"]);
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(!result.status.success() && !message.contains("panicked"), "{message}");
    let expected = format!("{}, line 2: `Kd` needs three numbers", dir.path().join("tri.mtl").display());
    assert!(message.contains(&expected), "expected {expected:?} in {message}");
    assert!(!out.exists());
}

/// An effect the scene lacks the means for is refused before tracing, and the message says how
/// to give it: an aperture on the command line, motion or an area light in a .toml scene. The
/// aperture given as the message says is then accepted.
#[test]
fn a_scene_without_the_effects_means_is_refused_with_how_to_give_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let bunny = format!("{}/stanford-bunny/bunny.ply", shared_scenes().display());
    let scene = ["--scene", bunny.as_str()];
    let with = |effect: &'static str| -> Vec<&str> { scene.iter().copied().chain(["--effect", effect]).collect() };
    expect_early_compare_error(&out, &with("dof"), &["bunny.ply", "aperture", "--aperture-radius"]);
    expect_early_compare_error(&out, &with("dof-motion"), &["aperture", "--aperture-radius"]);
    expect_early_compare_error(&out, &with("motion"), &["moving geometry", "`motion`", "scene-format.md"]);
    expect_early_compare_error(&out, &with("soft-shadow"), &["area light", "`emission`", "scene-format.md"]);
    let mut args = vec!["compare", "--out", out.to_str().unwrap(), "--width", "8", "--height", "8", "--quiet"];
    args.extend_from_slice(&["--spp", "1", "--reference-spp", "2", "--pt-max-spp", "1", "--methods", "box"]);
    args.extend_from_slice(&with("dof"));
    args.extend_from_slice(&["--aperture-radius", "0.01", "--cache-dir", dir.path().to_str().unwrap()]);
    let given = lfr(&args);
    assert!(given.status.success(), "{}", String::from_utf8_lossy(&given.stderr));
}
