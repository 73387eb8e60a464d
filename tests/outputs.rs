//! Outputs never replace an input or another output, and every refusal comes before the work:
//! each command plans all its output paths (`src/outputs.rs`) and checks them against every
//! file it reads, the scene's textures and buffers included, and against each other, by the
//! file they lead to; a dump too large for its file system, a folder
//! spelled as an output and `-` are refused before tracing; errors name the file and the line or
//! key.

use crate::common;
use crate::lfr_runner as cli;

use std::path::{Path, PathBuf};

use cli::{lfr, lfr_bench, stderr};

/// A 2×2 PNG (the texture the outputs must not replace).
fn write_png(path: &Path) -> Vec<u8> {
    image::RgbImage::from_pixel(2, 2, image::Rgb([200, 100, 50])).save(path).unwrap();
    std::fs::read(path).unwrap()
}

/// A TOML scene with one textured material (`X.png`) on a lit square.
fn textured_toml(dir: &Path) -> PathBuf {
    let text = r#"
[render]
width = 8
height = 8
spp = 1
[camera]
position = [0, 0, 3]
look_at = [0, 0, 0]
fov = 60
[[material]]
name = "printed"
base_color_texture = "X.png"
[[mesh]]
shape = "polygon"
material = "printed"
points = [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]
[[light]]
type = "point"
position = [0, 0, 2]
intensity = [4, 4, 4]
"#;
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// A glTF square whose base-colour texture is named `sub/../X.png` (the file `X.png` beside it
/// by another spelling).
fn textured_gltf(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let mut bin = Vec::new();
    for p in [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]] {
        p.iter().for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for uv in [[0.0f32, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]] {
        uv.iter().for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    std::fs::write(dir.join("quad.bin"), &bin).unwrap();
    let json = r#"{
      "asset": {"version": "2.0"},
      "scene": 0,
      "scenes": [{"nodes": [0]}],
      "nodes": [{"mesh": 0}],
      "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
      "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
      "textures": [{"source": 0}],
      "images": [{"uri": "sub/../X.png"}],
      "buffers": [{"uri": "quad.bin", "byteLength": 92}],
      "bufferViews": [
        {"buffer": 0, "byteOffset": 0, "byteLength": 48},
        {"buffer": 0, "byteOffset": 48, "byteLength": 32},
        {"buffer": 0, "byteOffset": 80, "byteLength": 12}
      ],
      "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
        {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}
      ]
    }"#;
    let path = dir.join("quad.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

fn text(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Runs `args`, which must fail before any work with an error containing every one of
/// `needles` and no panic.
fn refused(args: &[&str], needles: &[&str]) -> String {
    let result = lfr(args);
    let message = stderr(&result);
    assert!(!result.status.success(), "{args:?} must be refused: {message}");
    assert!(!message.contains("panicked"), "{message}");
    for needle in needles {
        assert!(message.contains(needle), "{args:?}: expected {needle:?} in {message}");
    }
    message
}

const SMALL: [&str; 7] = ["--width", "8", "--height", "8", "--spp", "1", "--quiet"];

#[test]
fn a_preview_never_replaces_a_texture_the_scene_reads() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let texture = d.join("X.png");
    let bytes = write_png(&texture);
    let toml = textured_toml(d);
    let gltf = textured_gltf(d);
    let out = d.join("X.exr");
    // `./a/../X.exr`: the same place by another spelling.
    std::fs::create_dir(d.join("a")).unwrap();
    let spelled = d.join("a/../X.exr");
    for scene in [&toml, &gltf] {
        for command in ["render", "filter"] {
            for out in [&out, &spelled] {
                let mut args = vec![command, "--scene", text(scene), "--out", text(out)];
                args.extend(SMALL);
                refused(&args, &["X.png", "the PNG preview beside --out", "which the command reads"]);
            }
        }
    }
    assert_eq!(std::fs::read(&texture).unwrap(), bytes, "the texture is untouched");
    assert!(!out.exists(), "nothing rendered");
    // Through a hard link to the texture, too.
    std::fs::hard_link(&texture, d.join("L.png")).unwrap();
    let linked_out = d.join("L.exr");
    let mut args = vec!["render", "--scene", text(&toml), "--out", text(&linked_out)];
    args.extend(SMALL);
    refused(&args, &["L.png", "which the command reads"]);
    // Another name renders.
    let image_out = d.join("image.exr");
    let mut args = vec!["render", "--scene", text(&gltf), "--out", text(&image_out)];
    args.extend(SMALL);
    let result = lfr(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    assert_eq!(std::fs::read(&texture).unwrap(), bytes);
}

#[test]
fn probes_relight_never_replaces_its_reference_cache_or_json() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let reference = d.join("R.exr");
    std::fs::write(&reference, b"a reference").unwrap();
    let cache = d.join("c.probes");
    let base = ["probes", "relight", "--quiet", "--width", "8", "--height", "8"];
    let with = |extra: &[&str]| -> Vec<String> { base.iter().chain(extra).map(|s| s.to_string()).collect() };
    for (extra, needles) in [
        (
            vec!["--cache", text(&cache), "--reference", text(&reference), "--out", text(&reference)],
            vec!["--reference", "which the command reads"],
        ),
        (
            vec!["--cache", text(&cache), "--json", text(&d.join("F.exr")), "--out", text(&d.join("F.exr"))],
            vec!["same file", "--json"],
        ),
        (vec!["--cache", text(&d.join("c.exr")), "--out", text(&d.join("c.exr"))], vec!["same file", "--cache"]),
        (
            vec![
                "--cache",
                text(&cache),
                "--out",
                text(&d.join("o.exr")),
                "--cpca",
                "--json",
                text(&d.join("c.probes.cpca")),
            ],
            vec!["same file", "CPCA cache"],
        ),
    ] {
        let args = with(&extra);
        refused(&args.iter().map(String::as_str).collect::<Vec<_>>(), &needles);
    }
    assert_eq!(std::fs::read(&reference).unwrap(), b"a reference");
    assert!(!cache.exists(), "refused before the precompute");
}

#[test]
fn folders_spelled_as_outputs_files_as_folders_and_standard_output_are_refused_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for spelled in ["o.exr/", "o.exr/."] {
        let folder = format!("{}/{spelled}", d.display());
        let mut args = vec!["render", "--out", folder.as_str()];
        args.extend(SMALL);
        refused(&args, &["names a folder"]);
    }
    let samples = format!("{}/x.lfrs/", d.display());
    refused(&["dump", "--kind", "lens-time", "--spp", "1", "--out", &samples, "--quiet"], &["names a folder"]);
    // A regular file where a folder of the output should be: refused before the work, whichever
    // folder of the path it is; the file is kept.
    std::fs::write(d.join("notes"), b"mine").unwrap();
    for out in ["notes/o.exr", "notes/deeper/o.exr"] {
        let out = d.join(out);
        let mut args = vec!["render", "--out", text(&out)];
        args.extend(SMALL);
        refused(&args, &["notes", "is not a folder"]);
        refused(
            &["dump", "--kind", "ao", "--spp", "1", "--out", &format!("{}.lfrs", out.display())],
            &["is not a folder"],
        );
    }
    assert_eq!(std::fs::read(d.join("notes")).unwrap(), b"mine");
    // Folders that do not exist yet are created, for images and sample files alike.
    let image = d.join("no/such/folder/o.exr");
    let mut args = vec!["render", "--out", text(&image)];
    args.extend(SMALL);
    let result = lfr(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(image.is_file() && image.with_extension("png").is_file());
    let samples = d.join("new/samples/x.lfrs");
    let result = lfr(&[
        "dump",
        "--kind",
        "ao",
        "--spp",
        "1",
        "--width",
        "4",
        "--height",
        "4",
        "--quiet",
        "--out",
        text(&samples),
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(samples.is_file());
    // A symbolic link as the output: the link would be replaced, not its target.
    let target = d.join("target.exr");
    std::fs::write(&target, b"kept").unwrap();
    let link = d.join("link.exr");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let mut args = vec!["render", "--out", text(&link)];
    args.extend(SMALL);
    refused(&args, &["symbolic link"]);
    assert_eq!(std::fs::read(&target).unwrap(), b"kept");
    // `export FILE -`: no standard output; nothing named `-` is written.
    let file = d.join("s.lfrs");
    let result = lfr(&[
        "dump",
        "--kind",
        "lens-time",
        "--spp",
        "1",
        "--width",
        "4",
        "--height",
        "4",
        "--quiet",
        "--out",
        text(&file),
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    let result = std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(["export", "--format", "tlfr-1.3", text(&file), "-"])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(!result.status.success() && stderr(&result).contains("standard output"), "{}", stderr(&result));
    assert!(!d.join("-").exists() && !d.join("-.header").exists());
    // An export's header beside the sample file it reads: `s` + `.header` is not the input,
    // but `export s.lfrs s.lfrs` is.
    refused(&["export", "--format", "tlfr-1.3", text(&file), text(&file)], &["the sample file"]);
}

#[test]
fn a_dump_larger_than_its_file_system_holds_is_refused_before_tracing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("huge.lfrs");
    // The issue's terabyte dump (32768 × 1 pixels at 2^20 spp) against 1 TB free, and a small
    // dump against 10 kB free (`LFR_FREE_SPACE` stands in for the file system's free space).
    for (size, free) in [
        (["--width", "32768", "--height", "1", "--spp", "1048576"], "1000000000000"),
        (["--width", "16", "--height", "16", "--spp", "4"], "10000"),
    ] {
        let mut args = vec!["dump", "--kind", "lens-time", "--quiet", "--out", text(&out)];
        args.extend(size);
        let result = std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
            .args(&args)
            .current_dir(common::project_root())
            .env("LFR_FREE_SPACE", free)
            .output()
            .unwrap();
        let message = stderr(&result);
        assert!(!result.status.success(), "{message}");
        assert!(message.contains("would take about") && message.contains("free"), "{message}");
        assert!(!message.contains("panicked"), "{message}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no file and no temporary: {message}");
    }
}

#[test]
fn a_comparison_never_clears_what_it_reads() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("cmp");
    std::fs::create_dir_all(out.join("images")).unwrap();
    let reference = out.join("images/reference.exr");
    std::fs::write(&reference, b"a reference from the last run").unwrap();
    let cache = d.join("cache");
    std::fs::create_dir(&cache).unwrap();
    let common_args =
        ["compare", "--effect", "indirect", "--methods", "box", "--width", "8", "--height", "8", "--quiet", "--force"];
    let mut args: Vec<&str> = common_args.to_vec();
    args.extend(["--out", text(&out), "--cache-dir", text(&cache), "--reference", text(&reference)]);
    refused(&args, &["--reference", "lies at or inside this path"]);
    // The cache inside the comparison's images folder would be removed with it.
    let inside = out.join("images/cache");
    std::fs::create_dir(&inside).unwrap();
    let mut args: Vec<&str> = common_args.to_vec();
    args.extend(["--out", text(&out), "--cache-dir", text(&inside)]);
    refused(&args, &["reference cache", "lies at or inside this path"]);
    assert_eq!(std::fs::read(&reference).unwrap(), b"a reference from the last run");
}

/// The scene of a comparison, and every file it reads, may not lie among what the comparison
/// removes and rewrites in OUT (report.md, results.json, images/, inputs/, ...): refused before
/// the scene is traced, the files untouched. A symbolic link to a folder is a valid OUT.
#[test]
fn a_comparison_never_clears_its_scene_or_the_files_the_scene_reads() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("cmp");
    std::fs::create_dir_all(out.join("images")).unwrap();
    std::fs::create_dir_all(out.join("inputs")).unwrap();
    let cache = d.join("cache");
    let common_args = [
        "compare",
        "--effect",
        "indirect",
        "--methods",
        "box",
        "--width",
        "8",
        "--height",
        "8",
        "--spp",
        "1",
        "--reference-spp",
        "4",
        "--pt-max-spp",
        "2",
        "--quiet",
        "--force",
    ];
    let scene_text = std::fs::read_to_string(textured_toml(d)).unwrap();
    write_png(&d.join("X.png"));
    // The scene file itself at one of the comparison's names or inside its folders.
    for at in ["report.md", "results.json", "images/scene.toml", "inputs/scene.toml"] {
        let scene = out.join(at);
        std::fs::write(&scene, &scene_text).unwrap();
        let mut args: Vec<&str> = common_args.to_vec();
        args.extend(["--out", text(&out), "--cache-dir", text(&cache), "--scene", text(&scene)]);
        refused(&args, &["the scene file", at, "removes and rewrites"]);
        assert_eq!(std::fs::read_to_string(&scene).unwrap(), scene_text, "{at} untouched");
    }
    // A texture the scene reads, inside OUT/images: the scene beside it is outside OUT.
    let texture = out.join("images/X.png");
    let bytes = write_png(&texture);
    let scene = d.join("textured.toml");
    std::fs::write(&scene, scene_text.replace("\"X.png\"", "\"cmp/images/X.png\"")).unwrap();
    let mut args: Vec<&str> = common_args.to_vec();
    args.extend(["--out", text(&out), "--cache-dir", text(&cache), "--scene", text(&scene)]);
    refused(&args, &["cmp/images/X.png", "a file the scene", "removes and rewrites"]);
    assert_eq!(std::fs::read(&texture).unwrap(), bytes);
    assert!(!cache.exists(), "refused before the cache folder is made");
    // Through a symbolic link to OUT, the same files are found.
    let link = d.join("link");
    std::os::unix::fs::symlink(&out, &link).unwrap();
    let mut args: Vec<&str> = common_args.to_vec();
    args.extend(["--out", text(&link), "--cache-dir", text(&cache), "--scene", text(&scene)]);
    refused(&args, &["X.png", "removes and rewrites"]);
    // A symbolic link to a folder is a valid OUT: the comparison runs and writes into its target.
    let target = d.join("target");
    std::fs::create_dir(&target).unwrap();
    let linked = d.join("linked-out");
    std::os::unix::fs::symlink(&target, &linked).unwrap();
    let plain = textured_toml(d);
    let mut args: Vec<&str> = common_args.to_vec();
    args.extend(["--out", text(&linked), "--cache-dir", text(&cache), "--scene", text(&plain)]);
    let result = lfr(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(target.join("results.json").is_file() && target.join("report.md").is_file());
    assert!(std::fs::symlink_metadata(&linked).unwrap().file_type().is_symlink(), "the link is kept");
}

#[test]
fn a_benchmark_json_never_replaces_a_scene_file_and_repeats_are_positive() {
    let dir = tempfile::tempdir().unwrap();
    let scene = d_scene(dir.path());
    let bytes = std::fs::read(&scene).unwrap();
    let refused = |args: &[&str], needle: &str| {
        let result = lfr_bench(args);
        let message = stderr(&result);
        assert!(!result.status.success() && !message.contains("panicked"), "{args:?} must be refused: {message}");
        assert!(message.contains(needle), "{args:?}: expected {needle:?} in {message}");
    };
    refused(&["filters", "--scene", text(&scene), "--json", text(&scene), "--repeats", "1"], "--json");
    assert_eq!(std::fs::read(&scene).unwrap(), bytes);
    for benchmark in ["filters", "ilfr", "tracer", "tlfr"] {
        refused(&[benchmark, "--repeats", "0"], "--repeats");
    }
}

fn d_scene(dir: &Path) -> PathBuf {
    let path = dir.join("cornell.toml");
    std::fs::copy(common::project_root().join("scenes/cornell.toml"), &path).unwrap();
    path
}

#[test]
fn errors_name_the_obj_line_and_the_scene_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("o.exr");
    for (faces, line) in [("f -999999 1 2\n", 4), ("f 1 2 3\nf 0 1 2\n", 5)] {
        let obj = d.join("bad.obj");
        std::fs::write(&obj, format!("v 0 0 0\nv 1 0 0\nv 0 1 0\n{faces}")).unwrap();
        let mut args = vec!["render", "--scene", text(&obj), "--out", text(&out)];
        args.extend(SMALL);
        refused(&args, &[&format!("bad.obj: line {line}: ")]);
    }
    let toml = d.join("many.toml");
    let cornell = std::fs::read_to_string(common::project_root().join("scenes/cornell.toml")).unwrap();
    std::fs::write(&toml, cornell.replacen("[render]", "[render]\nspp = 2000000", 1).replace("\nspp = 16", ""))
        .unwrap();
    let message =
        refused(&["render", "--scene", text(&toml), "--out", text(&out), "--quiet"], &["many.toml: render.spp"]);
    assert!(!message.contains("--spp"), "names the key, not an option never given: {message}");
}
