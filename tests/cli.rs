//! The `lfr` command end to end: every scene file renders, and bad input gives a clear error
//! naming the file and field, a non-zero exit, no panic and no output file.

use crate::common;
use crate::lfr_runner as cli;

use std::path::{Path, PathBuf};
use std::process::Command;

use cli::{lfr, lfr_bench, stderr};
use common::{exr_channel, project_root, shared_scenes};

/// Runs `lfr render` on `scene` expecting failure; checks the message and that nothing was written.
fn expect_render_error(scene: &Path, extra: &[&str], must_mention: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.exr");
    let mut args = vec!["render", "--scene", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"];
    args.extend_from_slice(extra);
    let result = lfr(&args);
    let message = stderr(&result);
    assert!(!result.status.success(), "expected failure for {}: {message}", scene.display());
    assert!(!message.contains("panicked"), "panic instead of an error: {message}");
    for needle in must_mention {
        assert!(message.contains(needle), "error should mention {needle:?}: {message}");
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no partial output may be left");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn default_scene_renders_with_all_layers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cornell.exr");
    let result =
        lfr(&["render", "--out", out.to_str().unwrap(), "--width", "24", "--height", "24", "--spp", "2", "--quiet"]);
    assert!(result.status.success(), "{}", stderr(&result));
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(stdout.contains("Mrays/s") && stdout.contains("s "), "prints time and ray rate: {stdout}");
    assert!(dir.path().join("cornell.png").is_file());
    let (w, h, channels) = tracer::output::read_exr(&out).unwrap();
    assert_eq!((w, h), (24, 24));
    let names: Vec<&str> = channels.iter().map(|(n, _)| n.as_str()).collect();
    for layer in
        ["R", "G", "B", "direct.R", "indirect.B", "albedo.G", "normal.X", "depth.Z", "position.Y", "variance.R"]
    {
        assert!(names.contains(&layer), "missing {layer} in {names:?}");
    }
    // The box fills the view but for the outermost columns, which look past its front edge.
    let depth = exr_channel(&out, "depth.Z");
    assert!(depth.iter().filter(|d| **d > 0.0).count() >= 24 * 22, "{depth:?}");
}

#[test]
fn every_scene_file_renders() {
    for name in
        ["cornell", "cbox-mitsuba", "sponza", "veach-mis", "roughness-sweep", "monkeys", "monkeys-dof-depths", "bunny"]
    {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join(format!("{name}.exr"));
        let scene = format!("scenes/{name}.toml");
        let result = lfr(&[
            "render",
            "--scene",
            &scene,
            "--out",
            out.to_str().unwrap(),
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "1",
            "--quiet",
        ]);
        assert!(result.status.success(), "{name}: {}", stderr(&result));
        let beauty = exr_channel(&out, "G");
        assert!(beauty.iter().all(|v| v.is_finite()), "{name}: non-finite pixels");
        assert!(beauty.iter().any(|v| *v > 0.0), "{name}: the image is black");
    }
}

#[test]
fn gltf_and_obj_files_render_directly() {
    let scenes = shared_scenes();
    for file in ["glossy-monkeys/Suzanne/glTF/Suzanne.gltf", "cornell-box-mcguire/CornellBox-Original.obj"] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("x.exr");
        let path = scenes.join(file);
        let result = lfr(&[
            "render",
            "--scene",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--width",
            "16",
            "--height",
            "16",
            "--spp",
            "1",
            "--quiet",
        ]);
        assert!(result.status.success(), "{file}: {}", stderr(&result));
    }
}

#[test]
fn missing_and_malformed_scenes_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    expect_render_error(&dir.path().join("nothere.toml"), &[], &["nothere.toml"]);
    let malformed = write(dir.path(), "malformed.toml", "[render\nwidth = 3\n");
    expect_render_error(&malformed, &[], &["malformed.toml", "line"]);
    let wrong_type =
        write(dir.path(), "wrongtype.toml", "[camera]\nposition = [0, 0]\nlook_at = [0, 0, 1]\nfov = 40\n");
    expect_render_error(&wrong_type, &[], &["wrongtype.toml", "position"]);
    let missing_mesh = write(dir.path(), "mesh.toml", "[[mesh]]\nfile = \"gone.obj\"\n");
    expect_render_error(&missing_mesh, &[], &["gone.obj"]);
    let bad_ext = write(dir.path(), "scene.xyz", "");
    expect_render_error(&bad_ext, &[], &["scene.xyz", "extension"]);
}

#[test]
fn impossible_parameters_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let ok = write(dir.path(), "ok.toml", "[render]\nenvironment = [1, 1, 1]\n");
    expect_render_error(&ok, &["--spp", "0"], &["spp"]);
    expect_render_error(&ok, &["--width", "0"], &["width"]);
    // One place for the limits (tracer::limits): render holds to the dump's spp and thread caps.
    expect_render_error(&ok, &["--spp", "1048577"], &["--spp", "1048576"]);
    expect_render_error(&ok, &["--width", "32769"], &["--width", "32768"]);
    expect_render_error(&ok, &["--threads", "100000"], &["--threads", "1024"]);
    // Transforms that cannot be meant: a rotation about no axis, a projective matrix.
    let no_axis =
        write(dir.path(), "axis.toml", "[[mesh]]\nshape = \"sphere\"\ntransform = { rotate = [0, 0, 0, 30] }\n");
    expect_render_error(&no_axis, &[], &["axis.toml", "mesh[0].transform.rotate", "axis"]);
    let projective = write(
        dir.path(),
        "projective.toml",
        "[[mesh]]\nshape = \"sphere\"\ntransform = { matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.5, 1]] }\n",
    );
    expect_render_error(&projective, &[], &["projective.toml", "mesh[0].transform.matrix", "last row"]);
    let result = lfr_bench(&["tracer", "--repeats", "0"]);
    assert!(!result.status.success() && stderr(&result).contains("--repeats"), "{}", stderr(&result));
    let zero_res = write(dir.path(), "zero.toml", "[render]\nheight = 0\n");
    expect_render_error(&zero_res, &[], &["zero.toml", "render.height", "got 0"]);
    let fov = write(dir.path(), "fov.toml", "[camera]\nposition = [0, 0, 1]\nlook_at = [0, 0, 0]\nfov = 180\n");
    expect_render_error(&fov, &[], &["fov.toml", "camera.fov"]);
    let same = write(dir.path(), "same.toml", "[camera]\nposition = [0, 0, 0]\nlook_at = [0, 0, 0]\nfov = 40\n");
    expect_render_error(&same, &[], &["same.toml", "camera"]);
    let negative = write(
        dir.path(),
        "neg.toml",
        "[[material]]\nname = \"m\"\nbase_color = [-1, 0, 0]\n[[mesh]]\nshape = \"box\"\nmin = [0,0,0]\nmax = [1,1,1]\nmaterial = \"m\"\n",
    );
    expect_render_error(&negative, &[], &["neg.toml", "base_color"]);
}

#[test]
fn nan_vertices_degenerate_triangles_and_missing_textures() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "nan.obj", "v 0 0 0\nv 1 0 0\nv 0 1e999 0\nf 1 2 3\n");
    let nan = write(dir.path(), "nan.toml", "[[mesh]]\nfile = \"nan.obj\"\n");
    expect_render_error(&nan, &[], &["nan.obj", "line 3", "`1e999` is not a finite number"]);

    // Degenerate triangles are dropped with a warning; the render succeeds.
    write(dir.path(), "degenerate.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n");
    let degenerate =
        write(dir.path(), "degenerate.toml", "[render]\nenvironment = [1,1,1]\n[[mesh]]\nfile = \"degenerate.obj\"\n");
    let out = dir.path().join("degenerate.exr");
    let result = lfr(&["render", "--scene", degenerate.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(result.status.success(), "{}", stderr(&result));
    assert!(stderr(&result).contains("degenerate"), "{}", stderr(&result));
    std::fs::remove_file(&out).unwrap();
    std::fs::remove_file(out.with_extension("png")).unwrap();

    write(dir.path(), "tex.mtl", "newmtl m\nKd 1 1 1\nmap_Kd missing_texture.png\n");
    write(dir.path(), "tex.obj", "mtllib tex.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n");
    let tex = write(dir.path(), "tex.toml", "[[mesh]]\nfile = \"tex.obj\"\n");
    expect_render_error(&tex, &[], &["missing_texture.png", "map_Kd"]);
}

#[test]
fn unsupported_required_gltf_extension_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let gltf = write(
        dir.path(),
        "draco.gltf",
        r#"{"asset":{"version":"2.0"},"extensionsUsed":["KHR_draco_mesh_compression"],"extensionsRequired":["KHR_draco_mesh_compression"],"scenes":[{"nodes":[]}],"scene":0}"#,
    );
    expect_render_error(&gltf, &[], &["draco.gltf", "KHR_draco_mesh_compression"]);
}

#[test]
fn output_must_be_exr_and_unwritable_output_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let result = lfr(&["render", "--out", dir.path().join("x.png").to_str().unwrap(), "--quiet"]);
    assert!(!result.status.success());
    assert!(stderr(&result).contains(".exr"));
    // A directory in the way of the output file.
    let blocked = dir.path().join("blocked.exr");
    std::fs::create_dir(&blocked).unwrap();
    let result =
        lfr(&["render", "--out", blocked.to_str().unwrap(), "--width", "4", "--height", "4", "--spp", "1", "--quiet"]);
    assert!(!result.status.success());
    assert!(stderr(&result).contains("blocked.exr"), "{}", stderr(&result));
    assert!(!stderr(&result).contains("panicked"));
}

#[test]
fn every_sample_kind_dumps_from_its_scene_and_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("scenes/cornell.toml", "indirect", "c-indirect.lfrs"),
        ("scenes/cornell.toml", "ao", "c-ao.lfrs"),
        ("scenes/cornell.toml", "light", "c-light.lfrs"),
        ("scenes/cornell.toml", "guide", "c-guide.exr"),
        ("scenes/monkeys-defocus-motion.toml", "lens-time", "m-lens-time.lfrs"),
    ];
    for (scene, kind, name) in cases {
        let out = dir.path().join(name);
        let result = lfr(&[
            "dump",
            "--scene",
            scene,
            "--kind",
            kind,
            "--spp",
            "2",
            "--width",
            "20",
            "--height",
            "12",
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(result.status.success(), "{kind}: {}", stderr(&result));
        let stdout = String::from_utf8_lossy(&result.stdout);
        assert!(stdout.contains("bytes per sample"), "{kind}: prints bytes per sample: {stdout}");
        if kind == "guide" {
            let (w, h, channels) = tracer::output::read_exr(&out).unwrap();
            assert_eq!((w, h), (20, 12));
            for layer in ["normal.X", "depth.Z", "albedo.R", "direct.G", "indirect.B", "indirect_variance.R"] {
                assert!(channels.iter().any(|(n, _)| n == layer), "guide lacks {layer}");
            }
        } else {
            let file = sampleio::SampleFile::open(&out).unwrap();
            assert_eq!(file.len(), 20 * 12 * 2);
            // The numpy reader agrees on the header.
            let python = Command::new("python3")
                .args([project_root().join("docs/tools/read_samples.py").to_str().unwrap(), out.to_str().unwrap()])
                .output()
                .expect("python3 runs");
            assert!(python.status.success(), "{}", String::from_utf8_lossy(&python.stderr));
            assert!(String::from_utf8_lossy(&python.stdout).contains(&format!("kind {kind}")));
        }
    }
    // A guide must be an EXR.
    let result = lfr(&["dump", "--kind", "guide", "--spp", "1", "--out", dir.path().join("g.lfrs").to_str().unwrap()]);
    assert!(!result.status.success());
    assert!(stderr(&result).contains(".exr"));
}

/// `lfr dump --fields` writes only the named fields, in the kind's order; a name the scene's
/// layout lacks, an empty name or a guide dump is an error naming it, with nothing written.
#[test]
fn dump_fields_selects_columns_and_refuses_unknown_names() {
    let dir = tempfile::tempdir().unwrap();
    let dump = |fields: &str, kind: &str, name: &str| {
        let out = dir.path().join(name);
        let args = ["dump", "--kind", kind, "--spp", "1", "--width", "6", "--height", "4", "--fields", fields];
        let result = lfr(&[&args[..], &["--out", out.to_str().unwrap(), "--quiet"]].concat());
        (result, out)
    };
    let (result, out) = dump("radiance,x", "indirect", "selected.lfrs");
    assert!(result.status.success(), "{}", stderr(&result));
    let file = sampleio::SampleFile::open(&out).unwrap();
    let names: Vec<&str> = file.fields().iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["x", "radiance"]);
    assert_eq!(file.len(), 6 * 4);
    let before: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    for (fields, kind, needle) in [
        ("radiance,colour", "indirect", "`colour`"),
        ("radiance,,x", "indirect", "empty field name"),
        ("u", "lens-time", "`u`"), // the Cornell box has no lens
        ("radiance", "guide", "--kind guide"),
    ] {
        let name = if kind == "guide" { "g.exr" } else { "bad.lfrs" };
        let (result, _) = dump(fields, kind, name);
        let message = stderr(&result);
        assert!(!result.status.success() && message.contains(needle), "{fields} ({kind}): {message}");
        assert!(!message.contains("panicked"), "{message}");
    }
    let after: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(before, after, "a refused dump writes nothing");
}

/// `lfr-bench tracer` times the tracer and the raw replay of its rays in alternating pairs: the pairs'
/// ratios, their median and the best-against-best ratio are consistent with the seconds
/// reported, and the replay traced exactly the rays the tracer counted (the command itself
/// fails otherwise).
#[test]
fn bench_alternates_tracer_and_raw_replay() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let result = lfr_bench(&[
        "tracer",
        "--scenes",
        "scenes/cornell.toml",
        "--width",
        "24",
        "--height",
        "16",
        "--spp",
        "2",
        "--repeats",
        "3",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 1);
    let row = &rows[0];
    let number = |key: &str| row[key].as_f64().unwrap_or_else(|| panic!("{key} in {row}"));
    // 24 x 16 pixels at 2 spp: at least one camera ray each.
    assert!(number("rays") >= (24 * 16 * 2) as f64, "{row}");
    let (tracer, raw) = (number("tracer_seconds"), number("raw_seconds"));
    assert!(tracer > 0.0 && raw > 0.0, "{row}");
    assert!((number("tracer_over_raw") - raw / tracer).abs() < 1e-9, "{row}");
    let mut pairs: Vec<f64> = row["pair_ratios"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert_eq!(pairs.len(), 3, "one pair per repetition");
    pairs.sort_by(f64::total_cmp);
    assert_eq!(number("tracer_over_raw_median_pair"), pairs[1]);
    assert!(pairs.iter().all(|r| r.is_finite() && *r > 0.0), "{row}");
    assert!(number("speedup_all_threads_over_one") > 0.0, "{row}");
}

/// `lfr-bench filters` runs every filter on real guide buffers and reports ratios against its
/// baseline from the same run (the baseline's own ratio is exactly 1).
#[test]
fn bench_filters_reports_ratios_from_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let result = lfr_bench(&[
        "filters",
        "--width",
        "48",
        "--height",
        "32",
        "--repeats",
        "1",
        "--no-bilateral",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2 * 12 + 3, "guided exact and s = 2: 3 guides x 4 radii each, A-Trous 3 settings");
    let baseline = rows.iter().find(|r| r["filter"] == "guided" && r["setting"] == "4 channels, radius 8").unwrap();
    assert_eq!(baseline["ratio_to_baseline"], 1.0);
    let fast = rows.iter().filter(|r| r["filter"] == "guided, s = 2").count();
    assert_eq!(fast, 12, "the fast guided filter at every guide and radius");
    for row in rows {
        let ms = row["milliseconds"].as_f64().unwrap();
        assert!(ms.is_finite() && ms > 0.0, "{row}");
    }
}

/// `lfr-bench ilfr` traces the gather's own rays through Embree in the same run: as many rays as
/// the gather reconstructed (rays per hit × primary hits; the command itself fails on any
/// mismatch), the scaling ratio of the first spp is exactly 1, and every rate is positive.
#[test]
fn bench_ilfr_replays_the_gathers_rays_through_embree() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let scene = project_root().join("scenes/cornell.toml");
    let result = lfr_bench(&[
        "ilfr",
        "--scenes",
        scene.to_str().unwrap(),
        "--width",
        "16",
        "--height",
        "12",
        "--spp",
        "1,2",
        "--recon-rays",
        "8",
        "--repeats",
        "1",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2);
    assert_eq!(rows[0]["time_over_first_spp"], 1.0);
    for (row, spp) in rows.iter().zip([1u64, 2]) {
        // 8 / spp rays per primary hit; most camera rays hit the box, some see the background.
        let hits = row["primary_hits"].as_u64().unwrap();
        assert!(hits > 16 * 12 * spp / 2 && hits < 16 * 12 * spp, "{row}");
        assert_eq!(row["reconstruction_rays"].as_u64().unwrap(), hits * (8 / spp), "{row}");
        for key in ["traced_paths_per_s", "reconstruction_rays_per_s", "embree_rays_per_s", "ilfr_total_s"] {
            let value = row[key].as_f64().unwrap();
            assert!(value.is_finite() && value > 0.0, "{key}: {row}");
        }
    }
    let result = lfr_bench(&["ilfr", "--spp", "0"]);
    assert!(!result.status.success() && stderr(&result).contains("--spp"));
}

/// `lfr-bench tlfr` times the tracer and the reconstruction on the same scene in one run: a row
/// per (spp, locations) with direct light by default, every time and rate positive, the rates
/// the quotients of their counts and times, and `location_in_traced_samples` the quotient of the
/// two rates.
#[test]
fn bench_tlfr_reports_a_locations_cost_in_traced_samples() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let scene = project_root().join("scenes/monkeys-defocus-motion.toml");
    let result = lfr_bench(&[
        "tlfr",
        "--scenes",
        scene.to_str().unwrap(),
        "--width",
        "16",
        "--height",
        "12",
        "--spp",
        "1,2",
        "--locations",
        "4,8",
        "--repeats",
        "1",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(result.status.success(), "{}", stderr(&result));
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rows = rows.as_array().unwrap();
    let order: Vec<(u64, u64)> =
        rows.iter().map(|r| (r["spp"].as_u64().unwrap(), r["locations"].as_u64().unwrap())).collect();
    assert_eq!(order, [(1, 4), (1, 8), (2, 4), (2, 8)]);
    for row in rows {
        let number = |key: &str| row[key].as_f64().unwrap_or_else(|| panic!("{key} missing: {row}"));
        assert_eq!(number("max_bounces"), 1.0, "direct light by default: {row}");
        for key in [
            "trace_s",
            "traced_samples_per_s",
            "read_s",
            "radius_s",
            "hierarchy_s",
            "reconstruct_s",
            "locations_per_s",
            "location_in_traced_samples",
            "clocked_s",
            "query_s",
            "coverage_s",
            "filter_s",
            "tlfr_total_s",
            "mean_locations_per_pixel",
            "leaves_per_location",
        ] {
            let value = number(key);
            assert!(value.is_finite() && value > 0.0, "{key}: {row}");
        }
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs());
        let (spp, locations) = (number("spp"), number("locations"));
        assert_eq!(number("traced_samples"), 16.0 * 12.0 * spp, "{row}");
        assert!(close(number("traced_samples_per_s"), number("traced_samples") / number("trace_s")), "{row}");
        let evaluated = number("evaluated_locations");
        assert!(evaluated > 0.0 && evaluated <= 16.0 * 12.0 * locations, "{row}");
        assert!(close(number("mean_locations_per_pixel"), evaluated / (16.0 * 12.0)), "{row}");
        assert!(close(number("locations_per_s"), evaluated / number("reconstruct_s")), "{row}");
        assert!(
            close(number("location_in_traced_samples"), number("traced_samples_per_s") / number("locations_per_s")),
            "{row}"
        );
        assert!(close(number("budget_locations_per_s"), 16.0 * 12.0 * locations / number("reconstruct_s")), "{row}");
        assert!(
            close(
                number("budget_location_in_traced_samples"),
                number("traced_samples_per_s") / number("budget_locations_per_s")
            ),
            "{row}"
        );
        assert_eq!(row["adaptive"], true, "{row}");
        let total = number("read_s") + number("radius_s") + number("hierarchy_s") + number("reconstruct_s");
        assert!(close(number("tlfr_total_s"), total), "{row}");
        assert!(close(number("tlfr_total_over_trace"), total / number("trace_s")), "{row}");
        let percent = number("one_surface_percent");
        assert!((0.0..=100.0).contains(&percent), "{row}");
    }
    // Both kernels in one run: a row each, alternating, the oracle's image within f32 rounding
    // of the fused kernel's.
    let both = dir.path().join("both.json");
    let size = ["--width", "16", "--height", "12", "--repeats", "1", "--spp", "2", "--locations", "8"];
    let mut args = vec!["tlfr", "--scenes", scene.to_str().unwrap(), "--kernel", "fused,oracle", "--json"];
    args.push(both.to_str().unwrap());
    args.extend_from_slice(&size);
    let result = lfr_bench(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&both).unwrap()).unwrap();
    assert_eq!((rows[0]["kernel"].as_str(), rows[1]["kernel"].as_str()), (Some("fused"), Some("oracle")));
    assert_eq!(rows[0]["largest_relative_difference"], 0.0);
    let difference = rows[1]["largest_relative_difference"].as_f64().unwrap();
    assert!(difference < 1e-5, "{difference}");
    assert_eq!(rows[0]["evaluated_locations"], rows[1]["evaluated_locations"]);
    let result = lfr_bench(&["tlfr", "--kernel", "fast"]);
    assert!(!result.status.success() && stderr(&result).contains("--kernel"), "{}", stderr(&result));
    // Without the adaptive rule every pixel evaluates all N locations.
    let fixed = dir.path().join("fixed.json");
    let size = ["--width", "16", "--height", "12", "--repeats", "1", "--spp", "1", "--locations", "4"];
    let mut args = vec!["tlfr", "--scenes", scene.to_str().unwrap(), "--fixed-locations", "--json"];
    args.push(fixed.to_str().unwrap());
    args.extend_from_slice(&size);
    let result = lfr_bench(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&fixed).unwrap()).unwrap();
    assert_eq!(rows[0]["adaptive"], false);
    assert_eq!(rows[0]["evaluated_locations"], 16 * 12 * 4);
    for bad in [["--spp", "0"], ["--locations", "0"]] {
        let result = lfr_bench(&["tlfr", bad[0], bad[1]]);
        assert!(!result.status.success() && stderr(&result).contains(bad[0]), "{bad:?}: {}", stderr(&result));
    }
}

/// `lfr reconstruct` spends fewer locations where the adaptive rule lets it, and exactly
/// `--locations` in every pixel with `--fixed-locations`; its notes say how many.
#[test]
fn reconstruct_fixed_locations_turns_the_adaptive_rule_off() {
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("s.lfrs");
    let scene = project_root().join("scenes/monkeys-defocus-motion.toml");
    let (scene, samples_arg) = (scene.to_str().unwrap(), samples.to_str().unwrap());
    let dump = ["dump", "--scene", scene, "--kind", "lens-time", "--spp", "2", "--width", "16", "--height", "12"];
    let mut args = dump.to_vec();
    args.extend_from_slice(&["--max-bounces", "1", "--out", samples_arg]);
    let result = lfr(&args);
    assert!(result.status.success(), "{}", stderr(&result));
    let per_pixel = |fixed: bool| {
        let out = dir.path().join(format!("r-{fixed}.exr"));
        let mut args = vec!["reconstruct", "--samples", samples_arg, "--locations", "32", "--quiet"];
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        if fixed {
            args.push("--fixed-locations");
        }
        let result = lfr(&args);
        assert!(result.status.success(), "{}", stderr(&result));
        let text = format!("{}{}", String::from_utf8_lossy(&result.stdout), stderr(&result));
        let note = text.split(" per pixel)").next().unwrap();
        note.rsplit('(').next().unwrap().parse::<f64>().unwrap_or_else(|_| panic!("no locations note: {text}"))
    };
    assert_eq!(per_pixel(true), 32.0);
    let adaptive = per_pixel(false);
    assert!((16.0..=32.0).contains(&adaptive), "{adaptive}");
}

/// The shared options (`common::RunArgs`, `SizeArgs`) are one definition flattened into every
/// command that computes: each lists them and holds them to the same limits, before any work.
#[test]
fn every_computing_command_takes_the_shared_options_with_the_same_limits() {
    let dir = tempfile::tempdir().unwrap();
    let out = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let (exr, lfrs, compare) = (out("never.exr"), out("never.lfrs"), out("never"));
    type Runner = fn(&[&str]) -> std::process::Output;
    let commands: [(Runner, Vec<&str>); 9] = [
        (lfr, vec!["render", "--out", &exr]),
        (lfr, vec!["dump", "--kind", "indirect", "--spp", "1", "--out", &lfrs]),
        (lfr, vec!["filter", "--out", &exr]),
        (lfr, vec!["compare", "--effect", "indirect", "--out", &compare]),
        (lfr_bench, vec!["tracer"]),
        (lfr_bench, vec!["ilfr"]),
        (lfr_bench, vec!["tlfr"]),
        (lfr_bench, vec!["filters"]),
        (lfr, vec!["reconstruct", "--samples", &lfrs, "--out", &exr]),
    ];
    for (run, command) in &commands {
        let help = run(&[command[0], "--help"]);
        let text = String::from_utf8_lossy(&help.stdout).to_string();
        for option in ["--seed", "--threads"] {
            assert!(text.contains(option), "{} --help lacks {option}:\n{text}", command[0]);
        }
        if command[0] != "reconstruct" {
            for option in ["--width", "--height", "--max-bounces"] {
                assert!(text.contains(option), "{} --help lacks {option}:\n{text}", command[0]);
            }
        }
        let mut args = command.clone();
        args.extend_from_slice(&["--threads", "100000"]);
        let result = run(&args);
        assert!(
            !result.status.success() && stderr(&result).contains("--threads must be at most 1024"),
            "{args:?}: {}",
            stderr(&result)
        );
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "a refused command wrote a file");
    for benchmark in ["tracer", "ilfr", "tlfr"] {
        let result = lfr_bench(&[benchmark, "--width", "0"]);
        assert!(!result.status.success() && stderr(&result).contains("width"), "{benchmark}: {}", stderr(&result));
    }
}

/// `lfr --help` lists the user's commands only; the benchmarks are `lfr-bench`, and their old
/// `lfr bench-*` names still run them (same arguments, same checks) with a note naming the new one.
#[test]
fn the_benchmarks_are_lfr_bench_and_their_old_names_still_run() {
    let help = String::from_utf8_lossy(&lfr(&["--help"]).stdout).to_string();
    assert!(help.contains("compare") && !help.contains("bench"), "{help}");
    let bench_help = String::from_utf8_lossy(&lfr_bench(&["--help"]).stdout).to_string();
    for benchmark in ["tracer", "filters", "ilfr", "tlfr"] {
        assert!(bench_help.lines().any(|line| line.trim_start().starts_with(benchmark)), "{bench_help}");
    }
    for (old, new) in
        [("bench", "tracer"), ("bench-filters", "filters"), ("bench-ilfr", "ilfr"), ("bench-tlfr", "tlfr")]
    {
        let result = lfr(&[old, "--threads", "100000"]);
        let text = stderr(&result);
        assert!(!result.status.success(), "{old}: {text}");
        assert!(
            text.contains(&format!("`lfr-bench {new}`")) && text.contains("--threads must be at most"),
            "{old}: {text}"
        );
    }
}

#[test]
fn compare_lists_every_method_with_its_options() {
    let result = lfr(&["compare", "--list-methods"]);
    assert!(result.status.success(), "{}", stderr(&result));
    let listing = String::from_utf8_lossy(&result.stdout);
    for name in ["box", "oidn", "gif", "gif-normal", "gif-grey", "bilateral", "atrous", "atrous-sn", "tlfr", "tlfr-nn"]
    {
        assert!(listing.lines().any(|line| line == name), "{name} missing:\n{listing}");
    }
    for line in [
        "radius = 1..=1024, default 24",
        "quality = high|balanced|fast|default, default high",
        "effects: indirect, glossy",
    ] {
        assert!(listing.contains(line), "{line} missing:\n{listing}");
    }
    let result = lfr(&["compare", "--effect", "indirect", "--out", "x", "--methods", "gif:radius=0"]);
    assert!(!result.status.success() && stderr(&result).contains("`gif:radius=0`"), "{}", stderr(&result));
    let result = lfr(&["compare", "--effect", "indirect"]);
    assert!(!result.status.success() && stderr(&result).contains("--out"), "{}", stderr(&result));
    // Without --effect the scene's effect is chosen and named before the methods are checked
    // (the unknown method stops the run before anything is traced or written).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let result = lfr(&["compare", "--out", out.to_str().unwrap(), "--methods", "nosuch"]);
    let text = stderr(&result);
    assert!(
        !result.status.success() && text.contains("no --effect given: indirect") && text.contains("nosuch"),
        "{text}"
    );
    assert!(!out.exists(), "nothing is written");
}

/// An output path that names a device node, a symbolic link or the
/// command's own input is refused before any work, and left as it was.
#[test]
fn outputs_never_replace_devices_links_or_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name);
    let render_to = |out: &Path| {
        lfr(&["render", "--width", "8", "--height", "8", "--spp", "1", "--quiet", "--out", out.to_str().unwrap()])
    };
    // A symbolic link to a regular file: refused, the link and its target untouched.
    std::fs::write(path("target.exr"), b"keep").unwrap();
    std::os::unix::fs::symlink(path("target.exr"), path("link.exr")).unwrap();
    let result = render_to(&path("link.exr"));
    assert!(!result.status.success() && stderr(&result).contains("symbolic link"), "{}", stderr(&result));
    assert!(std::fs::symlink_metadata(path("link.exr")).unwrap().file_type().is_symlink());
    assert_eq!(std::fs::read(path("target.exr")).unwrap(), b"keep");
    // A character device (the null device's numbers, made here, never under /dev): needs root.
    let made =
        std::process::Command::new("mknod").args(["-m", "666"]).arg(path("null.exr")).args(["c", "1", "3"]).status();
    if made.is_ok_and(|s| s.success()) {
        let result = render_to(&path("null.exr"));
        assert!(!result.status.success() && stderr(&result).contains("character device"), "{}", stderr(&result));
        use std::os::unix::fs::FileTypeExt;
        assert!(std::fs::symlink_metadata(path("null.exr")).unwrap().file_type().is_char_device());
    } else {
        testkit::skip("mknod needs root: the character-device case was not run");
    }
    // A directory named like an output.
    std::fs::create_dir(path("dir.exr")).unwrap();
    let result = render_to(&path("dir.exr"));
    assert!(!result.status.success() && stderr(&result).contains("a directory"), "{}", stderr(&result));
    // The input as the output: `export x.lfrs x.lfrs` must not destroy x.lfrs.
    let samples = path("x.lfrs");
    let dumped = lfr(&[
        "dump",
        "--kind",
        "lens-time",
        "--width",
        "4",
        "--height",
        "4",
        "--spp",
        "1",
        "--quiet",
        "--out",
        samples.to_str().unwrap(),
    ]);
    assert!(dumped.status.success(), "{}", stderr(&dumped));
    let before = std::fs::read(&samples).unwrap();
    let result = lfr(&["export", "--format", "tlfr-1.3", samples.to_str().unwrap(), samples.to_str().unwrap()]);
    let message = stderr(&result);
    assert!(!result.status.success() && message.contains("the sample file") && message.contains("reads"), "{message}");
    assert_eq!(std::fs::read(&samples).unwrap(), before, "the input is intact");
    // Samples go to .lfrs files, not into an image's name.
    let result = lfr(&["dump", "--kind", "ao", "--spp", "1", "--quiet", "--out", path("x.exr").to_str().unwrap()]);
    assert!(!result.status.success() && stderr(&result).contains(".lfrs"), "{}", stderr(&result));
    assert!(!path("x.exr").exists());
}

/// Special files as inputs are clear errors at once, never a read
/// until memory runs out or a wait forever, and each error names what is wrong.
#[test]
fn special_files_as_inputs_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name);
    // The scene itself: a device, a FIFO, a directory.
    std::os::unix::fs::symlink("/dev/zero", path("zero.toml")).unwrap();
    expect_render_error(&path("zero.toml"), &[], &["zero.toml", "not a regular file"]);
    if std::process::Command::new("mkfifo").arg(path("fifo.toml")).status().is_ok_and(|s| s.success()) {
        expect_render_error(&path("fifo.toml"), &[], &["fifo.toml", "not a regular file"]);
    }
    std::fs::create_dir(path("dir.toml")).unwrap();
    expect_render_error(&path("dir.toml"), &[], &["dir.toml", "directory"]);
    // A scene that does not exist is named once, not as its own referencing file too.
    let missing = lfr(&["render", "--scene", path("missing.toml").to_str().unwrap(), "--out", "x.exr", "--quiet"]);
    let message = stderr(&missing);
    assert!(!missing.status.success() && message.contains("file not found"), "{message}");
    assert_eq!(message.matches("missing.toml").count(), 1, "{message}");
    // A mesh that is a directory, a symlink loop, a device.
    std::fs::create_dir(path("meshdir.obj")).unwrap();
    let scene = write(dir.path(), "a.toml", "[[mesh]]\nfile = \"meshdir.obj\"\n");
    expect_render_error(&scene, &[], &["meshdir.obj", "directory"]);
    std::os::unix::fs::symlink(path("loop.obj"), path("loop.obj")).unwrap();
    let scene = write(dir.path(), "b.toml", "[[mesh]]\nfile = \"loop.obj\"\n");
    expect_render_error(&scene, &[], &["loop.obj", "cannot read"]);
    // A material library that is /dev/zero: named with its field, not read.
    std::os::unix::fs::symlink("/dev/zero", path("zero.mtl")).unwrap();
    write(dir.path(), "tri.obj", "mtllib zero.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let scene = write(dir.path(), "c.toml", "[[mesh]]\nfile = \"tri.obj\"\n");
    // The link leads out of the scene's folder (tests/confinement.rs); allowed, it is still
    // refused as a device.
    expect_render_error(&scene, &[], &["tri.obj", "mtllib", "`zero.mtl` resolves to /dev/zero", "outside"]);
    let allow = ["--allow-outside-scene-dir"];
    expect_render_error(&scene, &allow, &["tri.obj", "mtllib", "zero.mtl", "not a regular file"]);
}
