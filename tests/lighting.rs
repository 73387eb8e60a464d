//! Lighting for the scenes users bring: a file without lights gets the
//! documented default lighting with a notice; `--environment`, `--sun` and `--sun-irradiance`
//! light any scene, `--camera N` picks among a glTF file's cameras, and bad values are refused.

use crate::common;
use crate::lfr_runner as cli;

use std::path::{Path, PathBuf};
use std::process::Output;

use cli::{lfr, lfr_bench, stderr};
use common::exr_channel;

/// A bare glTF file: the square [-1, 1]² in z = 0 facing +z, no material, no light, and two
/// cameras at (0, 0, 3): camera 0 looks down −z at the square (aspect 1), camera 1 is turned
/// half a turn about y and looks away from it (aspect 2).
fn bare_gltf(dir: &Path) -> PathBuf {
    let mut bin = Vec::new();
    for p in [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]] {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    std::fs::write(dir.join("quad.bin"), &bin).unwrap();
    let json = r#"{
      "asset": {"version": "2.0"},
      "scene": 0,
      "scenes": [{"nodes": [0, 1, 2]}],
      "nodes": [
        {"mesh": 0},
        {"camera": 0, "translation": [0, 0, 3]},
        {"camera": 1, "translation": [0, 0, 3], "rotation": [0, 1, 0, 0]}
      ],
      "cameras": [
        {"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 1.0, "znear": 0.1}},
        {"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 2.0, "znear": 0.1}}
      ],
      "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
      "buffers": [{"uri": "quad.bin", "byteLength": 60}],
      "bufferViews": [
        {"buffer": 0, "byteOffset": 0, "byteLength": 48},
        {"buffer": 0, "byteOffset": 48, "byteLength": 12}
      ],
      "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
      ]
    }"#;
    let path = dir.join("quad.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

/// A bare OBJ square like [`bare_gltf`]'s (facing +z) with a pure Lambertian MTL material of
/// albedo `albedo` (no `Ks`: no specular coat).
fn lambertian_obj(dir: &Path, albedo: f32) -> PathBuf {
    std::fs::write(dir.join("quad.mtl"), format!("newmtl matte\nKd {albedo} {albedo} {albedo}\n")).unwrap();
    let obj = "mtllib quad.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nusemtl matte\nf 1 2 3 4\n";
    let path = dir.join("quad.obj");
    std::fs::write(&path, obj).unwrap();
    path
}

/// Renders `scene` with `extra` options at 16 × 16 (at the file's size when `extra` holds
/// `--file-size`, which is not passed on) and 16 spp; returns the run and the output path.
fn render(scene: &Path, extra: &[&str]) -> (Output, PathBuf) {
    let out = scene.with_file_name(format!("out-{}.exr", extra.join("_").replace([',', '-', '.'], "")));
    let mut args = vec!["render", "--scene", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"];
    if !extra.contains(&"--file-size") {
        args.extend_from_slice(&["--width", "16", "--height", "16"]);
    }
    args.extend_from_slice(&["--spp", "16"]);
    let extra: Vec<&str> = extra.iter().copied().filter(|&a| a != "--file-size").collect();
    args.extend_from_slice(&extra);
    (lfr(&args), out)
}

fn mean(values: &[f32]) -> f64 {
    values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64
}

#[test]
fn a_bare_gltf_renders_lit_by_the_default_lighting_with_a_notice() {
    let dir = tempfile::tempdir().unwrap();
    let scene = bare_gltf(dir.path());
    let (result, out) = render(&scene, &[]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(stderr(&result).contains("notice:") && stderr(&result).contains("no lights"), "{}", stderr(&result));
    let beauty = exr_channel(&out, "G");
    assert!(beauty.iter().all(|v| v.is_finite()));
    assert!(mean(&beauty) > 0.05, "mean {}", mean(&beauty));
    // The square, seen from the front with the sun behind the camera, is brighter than the
    // background (the environment alone).
    let centre = beauty[8 * 16 + 8] as f64;
    assert!(centre > tracer::scene::DEFAULT_ENVIRONMENT as f64 * 1.2, "centre {centre}");

    // An explicit black environment is a choice: no default, no notice, a black image.
    let (result, out) = render(&scene, &["--environment", "0"]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(!stderr(&result).contains("notice:"), "{}", stderr(&result));
    assert!(exr_channel(&out, "G").iter().all(|&v| v == 0.0));
}

#[test]
fn camera_n_picks_the_files_nth_camera_with_its_aspect_ratio() {
    let dir = tempfile::tempdir().unwrap();
    let scene = bare_gltf(dir.path());
    let env = [0.3f32, 0.5, 0.7];
    // Camera 1 looks away from the square: every pixel is the environment, and its aspect
    // ratio 2 makes the image twice as wide as high (the height of a bare file: 256).
    let (result, out) = render(&scene, &["--camera", "1", "--environment", "0.3,0.5,0.7", "--file-size"]);
    assert!(result.status.success(), "{}", stderr(&result));
    let (width, height, _) = tracer::output::read_exr(&out).unwrap();
    assert_eq!((width, height), (512, 256));
    for (channel, value) in ["R", "G", "B"].iter().zip(env) {
        let pixels = exr_channel(&out, channel);
        assert!(pixels.iter().all(|&v| (v - value).abs() < 1e-5), "{channel}: {pixels:?}");
    }
    // Camera 0 (the default) sees the square, which is not the environment's colour.
    let (result, out) = render(&scene, &["--camera", "0", "--environment", "0.3,0.5,0.7", "--file-size"]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert_eq!(tracer::output::read_exr(&out).unwrap().0, 256, "camera 0's aspect ratio is 1");
    let red = exr_channel(&out, "R");
    assert!(red.iter().filter(|&&v| (v - env[0]).abs() > 0.01).count() > 1000);

    // Wrapped in a .toml scene, the file's cameras stay choosable; the default is the table's.
    let toml = dir.path().join("wrapped.toml");
    let text = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\n[[mesh]]\nfile = \"quad.gltf\"\n";
    std::fs::write(&toml, text).unwrap();
    for (camera, sees_the_square) in [(None, true), (Some("1"), false)] {
        let mut args = vec!["--environment", "0.3,0.5,0.7"];
        args.extend(camera.map(|c| ["--camera", c]).into_iter().flatten());
        let (result, out) = render(&toml, &args);
        assert!(result.status.success(), "{}", stderr(&result));
        let red = exr_channel(&out, "R");
        assert_eq!(red.iter().any(|&v| (v - env[0]).abs() > 0.01), sees_the_square, "--camera {camera:?}");
    }

    let (result, _) = render(&scene, &["--camera", "2"]);
    assert!(!result.status.success());
    assert!(stderr(&result).contains("--camera 2") && stderr(&result).contains("defines 2 cameras (0 to 1), not 2"));
    let obj = lambertian_obj(dir.path(), 0.5);
    let (result, _) = render(&obj, &["--camera", "0"]);
    assert!(!result.status.success() && stderr(&result).contains("defines no cameras"), "{}", stderr(&result));
}

#[test]
fn the_sun_lights_a_lambertian_square_by_cosine_over_pi() {
    let dir = tempfile::tempdir().unwrap();
    let scene = lambertian_obj(dir.path(), 0.5);
    // Direct light only: radiance = albedo × E × cos θ / π where the framing camera sees the
    // square, 0 elsewhere (black environment).
    for (towards, cos) in [("0,0,1", 1.0f64), ("0,1,1", std::f64::consts::FRAC_1_SQRT_2), ("0,0,-1", 0.0)] {
        let (result, out) =
            render(&scene, &["--sun", towards, "--sun-irradiance", "2", "--environment", "0", "--max-bounces", "1"]);
        assert!(result.status.success(), "{}", stderr(&result));
        let expected = 0.5 * 2.0 * cos / std::f64::consts::PI;
        let beauty = exr_channel(&out, "G");
        let centre = beauty[8 * 16 + 8] as f64;
        assert!((centre - expected).abs() < 1e-4, "sun towards {towards}: {centre} vs {expected}");
    }
}

#[test]
fn an_environment_alone_makes_a_white_square_vanish_into_it() {
    // The white furnace: a white Lambertian square under a uniform environment reflects exactly
    // the environment, so the image is the environment everywhere (within noise).
    let dir = tempfile::tempdir().unwrap();
    let scene = lambertian_obj(dir.path(), 1.0);
    let (result, out) = render(&scene, &["--environment", "0.6"]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(!stderr(&result).contains("notice:"), "{}", stderr(&result));
    let beauty = exr_channel(&out, "G");
    let centre: Vec<f32> =
        (4..12).flat_map(|y| (4..12).map(move |x| (x, y))).map(|(x, y)| beauty[y * 16 + x]).collect();
    assert!((mean(&centre) / 0.6 - 1.0).abs() < 0.03, "mean over the square {}", mean(&centre));
    assert!(beauty.iter().all(|&v| v > 0.0 && v.is_finite()));
}

#[test]
fn bad_lighting_values_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let scene = lambertian_obj(dir.path(), 0.5);
    for (args, needle) in [
        (vec!["--environment", "nan"], "--environment must be finite and non-negative"),
        (vec!["--environment", "0.5,-1,0.5"], "--environment must be finite and non-negative"),
        (vec!["--environment", "1,1"], "--environment takes one value or three"),
        (vec!["--sun", "0,0,0"], "--sun must be a finite, non-zero direction"),
        (vec!["--sun", "0,inf,1"], "--sun must be a finite, non-zero direction"),
        (vec!["--sun", "0,1"], "--sun takes a direction X,Y,Z"),
        (vec!["--sun", "0,1,0", "--sun-irradiance", "-2"], "--sun-irradiance must be finite and non-negative"),
        (vec!["--sun-irradiance", "2"], "--sun-irradiance needs --sun"),
    ] {
        let (result, out) = render(&scene, &args);
        assert!(!result.status.success(), "{args:?} accepted");
        assert!(stderr(&result).contains(needle), "{args:?}: {}", stderr(&result));
        assert!(!stderr(&result).contains("panicked"));
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
    // The same options on every command that traces a scene.
    let out = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let (exr, lfrs, compare) = (out("never.exr"), out("never.lfrs"), out("never"));
    type Runner = fn(&[&str]) -> Output;
    let commands: [(Runner, Vec<&str>); 5] = [
        (lfr, vec!["render", "--out", &exr]),
        (lfr, vec!["dump", "--kind", "indirect", "--spp", "1", "--out", &lfrs]),
        (lfr, vec!["filter", "--out", &exr]),
        (lfr, vec!["compare", "--effect", "indirect", "--out", &compare]),
        (lfr_bench, vec!["filters"]),
    ];
    for (run, command) in commands {
        let help = String::from_utf8_lossy(&run(&[command[0], "--help"]).stdout).to_string();
        for option in ["--environment", "--sun", "--sun-irradiance", "--camera"] {
            assert!(help.contains(option), "{} --help lacks {option}", command[0]);
        }
        let mut args = command.clone();
        args.extend_from_slice(&["--sun", "0,0,0"]);
        let result = run(&args);
        assert!(!result.status.success() && stderr(&result).contains("--sun must be"), "{args:?}: {}", stderr(&result));
    }
    let written: Vec<_> = std::fs::read_dir(dir.path()).unwrap().flatten().map(|e| e.file_name()).collect();
    assert_eq!(written.len(), 2, "only the scene files: {written:?}");
}

#[test]
fn a_bare_ply_renders_lit_by_the_default_lighting() {
    let dir = tempfile::tempdir().unwrap();
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
               element face 1\nproperty list uchar int vertex_indices\nend_header\n\
               -1 -1 0\n1 -1 0\n1 1 0\n-1 1 0\n4 0 1 2 3\n";
    let scene = dir.path().join("square.ply");
    std::fs::write(&scene, ply).unwrap();
    let (result, out) = render(&scene, &[]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(stderr(&result).contains("notice:"), "{}", stderr(&result));
    let beauty = exr_channel(&out, "G");
    assert!(beauty[8 * 16 + 8] > tracer::scene::DEFAULT_ENVIRONMENT * 1.2, "the square is lit: {beauty:?}");
    // A truncated file: an error naming it, no output.
    std::fs::write(&scene, &ply[..ply.len() - 6]).unwrap();
    let (result, out) = render(&scene, &["--seed", "1"]);
    assert!(!result.status.success() && stderr(&result).contains("square.ply"), "{}", stderr(&result));
    assert!(stderr(&result).contains("square.ply: line 14: not a valid PLY file: "), "{}", stderr(&result));
    assert!(!out.exists());
}

/// A bare glTF file like [`bare_gltf`]'s square (grey, camera 0 only) with a small emissive
/// patch of radiance 1 in front of its upper-right corner ([0.6, 0.9]² at z = 0.01): a model
/// whose only light is an emissive texture or panel, as DamagedHelmet's.
fn emissive_patch_gltf(dir: &Path) -> PathBuf {
    let mut bin = Vec::new();
    let square = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]];
    let patch = [[0.6f32, 0.6, 0.01], [0.9, 0.6, 0.01], [0.9, 0.9, 0.01], [0.6, 0.9, 0.01]];
    for p in square.iter().chain(&patch) {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    std::fs::write(dir.join("patch.bin"), &bin).unwrap();
    let json = r#"{
      "asset": {"version": "2.0"},
      "scene": 0,
      "scenes": [{"nodes": [0, 1, 2]}],
      "nodes": [{"mesh": 0}, {"mesh": 1}, {"camera": 0, "translation": [0, 0, 3]}],
      "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 1.0, "znear": 0.1}}],
      "materials": [
        {"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1], "metallicFactor": 0}},
        {"emissiveFactor": [1, 1, 1], "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0}}
      ],
      "meshes": [
        {"primitives": [{"attributes": {"POSITION": 0}, "indices": 2, "material": 0}]},
        {"primitives": [{"attributes": {"POSITION": 1}, "indices": 2, "material": 1}]}
      ],
      "buffers": [{"uri": "patch.bin", "byteLength": 108}],
      "bufferViews": [
        {"buffer": 0, "byteOffset": 0, "byteLength": 48},
        {"buffer": 0, "byteOffset": 48, "byteLength": 48},
        {"buffer": 0, "byteOffset": 96, "byteLength": 12}
      ],
      "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0.6, 0.6, 0.01], "max": [0.9, 0.9, 0.01]},
        {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}
      ]
    }"#;
    let path = dir.join("patch.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

#[test]
fn a_bare_gltf_with_an_emissive_patch_is_lit_as_viewers_light_it_and_a_toml_scene_stays_as_authored() {
    let dir = tempfile::tempdir().unwrap();
    let scene = emissive_patch_gltf(dir.path());
    let (result, out) = render(&scene, &[]);
    assert!(result.status.success(), "{}", stderr(&result));
    let err = stderr(&result);
    assert!(err.contains("notice:") && err.contains("emissive surfaces"), "{err}");
    let lit = exr_channel(&out, "G");
    // The lower-left quarter of the image sees only the grey square, far from the patch: lit by
    // the default sun and environment it is brighter than the environment behind it.
    let lower_left = lit[12 * 16 + 3] as f64;
    assert!(lower_left > tracer::scene::DEFAULT_ENVIRONMENT as f64 * 1.2, "lower left {lower_left}");
    // The patch still glows: its pixel holds at least its own emission.
    let patch_pixel = lit[3 * 16 + 12];
    assert!(patch_pixel >= 0.95, "patch {patch_pixel}");

    // `--environment 0` keeps the file's own light only: the patch glows and the far corner of
    // the square, lit by the patch alone at a distance, is far darker than under the default.
    let (result, out) = render(&scene, &["--environment", "0"]);
    assert!(result.status.success() && !stderr(&result).contains("notice:"), "{}", stderr(&result));
    let own = exr_channel(&out, "G");
    assert!((own[12 * 16 + 3] as f64) < lower_left * 0.1, "{} against {lower_left}", own[12 * 16 + 3]);

    // The same file through a TOML scene is rendered exactly as authored: no default lighting.
    let toml = dir.path().join("patch.toml");
    std::fs::write(&toml, "[[mesh]]\nfile = \"patch.gltf\"\n").unwrap();
    let (result, out) = render(&toml, &[]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(!stderr(&result).contains("notice:"), "{}", stderr(&result));
    let authored = exr_channel(&out, "G");
    assert!(authored.iter().sum::<f32>() < lit.iter().sum::<f32>() * 0.5);
}
