//! File references inside scene files stay inside the referencing file's folder (or the shared
//! scenes folder) unless `--allow-outside-scene-dir`: glTF buffer URIs,
//! TOML mesh files and textures, OBJ material libraries and texture maps. `..` and symbolic
//! links that lead out are refused; the error names the file, the field and the reference and
//! shows nothing of the refused file.

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

fn render(scene: &Path, out: &Path, allow: bool) -> Output {
    let mut args =
        vec!["render", "--scene", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet", "--spp", "1"];
    args.extend(["--width", "8", "--height", "8"]);
    if allow {
        args.push("--allow-outside-scene-dir");
    }
    lfr(&args)
}

fn expect_refusal(scene: &Path, out: &Path, needles: &[&str]) {
    let result = render(scene, out, false);
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(!result.status.success(), "{}: must be refused: {message}", scene.display());
    assert!(!message.contains("panicked"), "{message}");
    for needle in needles {
        assert!(message.contains(needle), "expected {needle:?} in {message}");
    }
    assert!(message.contains("--allow-outside-scene-dir"), "{message}");
    assert!(!out.exists());
}

const TRIANGLE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

/// `scene/` and `outside/` side by side in a temporary folder.
fn folders() -> (tempfile::TempDir, std::path::PathBuf, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let (scene, outside) = (dir.path().join("scene"), dir.path().join("outside"));
    std::fs::create_dir_all(&scene).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    (dir, scene, outside)
}

#[test]
fn a_gltf_buffer_outside_the_scene_folder_needs_the_option() {
    let (dir, scene_dir, outside) = folders();
    let out = dir.path().join("out.exr");
    // One triangle: 3 positions, u16 indices.
    let mut bin = Vec::new();
    for v in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    for i in [0u16, 1, 2] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    std::fs::write(outside.join("tri.bin"), &bin).unwrap();
    let gltf = |uri: &str, length: usize| {
        format!(
            r#"{{"asset": {{"version": "2.0"}}, "buffers": [{{"byteLength": {length}, "uri": "{uri}"}}],
            "bufferViews": [{{"buffer": 0, "byteLength": 36}}, {{"buffer": 0, "byteOffset": 36, "byteLength": 6}}],
            "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}},
                          {{"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}}],
            "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1}}]}}],
            "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}]}}"#
        )
    };
    // The issue's case: far enough up to reach the root, then /etc/passwd.
    let passwd = format!("{}etc/passwd", "../".repeat(scene_dir.components().count()));
    let scene = scene_dir.join("tri.gltf");
    std::fs::write(&scene, gltf(&passwd, 42)).unwrap();
    expect_refusal(&scene, &out, &["tri.gltf", "buffers[0]", &format!("`{passwd}` resolves to /etc/passwd")]);
    let message = String::from_utf8_lossy(&render(&scene, &out, false).stderr).into_owned();
    assert!(!message.contains("root:"), "no byte of /etc/passwd: {message}");

    std::fs::write(&scene, gltf("../outside/tri.bin", bin.len())).unwrap();
    expect_refusal(&scene, &out, &["buffers[0]", "`../outside/tri.bin` resolves to"]);
    let result = render(&scene, &out, true);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    assert!(out.is_file());
}

#[test]
fn toml_and_obj_references_outside_the_folder_need_the_option() {
    let (dir, scene_dir, outside) = folders();
    let out = dir.path().join("out.exr");
    std::fs::write(outside.join("tri.obj"), TRIANGLE_OBJ).unwrap();
    std::fs::write(outside.join("grey.mtl"), "newmtl grey\nKd 0.5 0.5 0.5\n").unwrap();
    std::fs::write(outside.join("t.png"), b"never read").unwrap();
    let toml = |mesh: &str, texture: &str| {
        let texture = if texture.is_empty() { String::new() } else { format!("base_color_texture = \"{texture}\"\n") };
        format!(
            "[camera]\nposition = [0.3, 0.3, 3]\nlook_at = [0.3, 0.3, 0]\nfov = 40\n\
             [[material]]\nname = \"m\"\n{texture}\
             [[mesh]]\nfile = \"{mesh}\"\nmaterial = \"m\"\n\
             [[light]]\ntype = \"point\"\nposition = [0, 0, 2]\nintensity = [1, 1, 1]\n"
        )
    };
    let scene = scene_dir.join("scene.toml");
    std::fs::write(&scene, toml("../outside/tri.obj", "")).unwrap();
    expect_refusal(&scene, &out, &["scene.toml", "mesh[0].file", "`../outside/tri.obj` resolves to"]);
    let result = render(&scene, &out, true);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    std::fs::remove_file(&out).unwrap();
    std::fs::remove_file(dir.path().join("out.png")).unwrap();

    std::fs::write(scene_dir.join("tri.obj"), TRIANGLE_OBJ).unwrap();
    std::fs::write(&scene, toml("tri.obj", "../outside/t.png")).unwrap();
    expect_refusal(&scene, &out, &["material[0].base_color_texture", "`../outside/t.png` resolves to"]);
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(outside.join("t.png"), scene_dir.join("link.png")).unwrap();
        std::fs::write(&scene, toml("tri.obj", "link.png")).unwrap();
        expect_refusal(&scene, &out, &["material[0].base_color_texture", "`link.png` resolves to"]);
    }

    // An OBJ's material library and texture maps.
    let obj = scene_dir.join("tri.obj");
    std::fs::write(&obj, format!("mtllib ../outside/grey.mtl\n{TRIANGLE_OBJ}")).unwrap();
    expect_refusal(&obj, &out, &["tri.obj", "mtllib", "`../outside/grey.mtl` resolves to"]);
    let result = render(&obj, &out, true);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    std::fs::remove_file(&out).unwrap();
    std::fs::write(scene_dir.join("grey.mtl"), "newmtl grey\nKd 0.5 0.5 0.5\nmap_Kd ../outside/t.png\n").unwrap();
    std::fs::write(&obj, format!("mtllib grey.mtl\n{TRIANGLE_OBJ}")).unwrap();
    expect_refusal(&obj, &out, &["material 'grey'.map_Kd", "`../outside/t.png` resolves to"]);
}
