//! Scale-out: `lfr render --shard I/N` in separate processes and `lfr merge` give the
//! image one process renders, bit for bit in every channel; shards of different renders,
//! missing or repeated shards are refused before anything is written. Shards by sample ranges
//! (`--shard-by samples`) merge into it within float rounding.

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

use common::project_root;

fn lfr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfr")).args(args).current_dir(project_root()).output().expect("lfr runs")
}

fn ok(output: Output) -> Output {
    assert!(output.status.success(), "lfr failed: {}", String::from_utf8_lossy(&output.stderr));
    output
}

/// 40x24 is 3x2 tiles of 16, the last column and row partial.
fn render(out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["render", "--width", "40", "--height", "24", "--quiet"];
    if !extra.contains(&"--spp") {
        args.extend_from_slice(&["--spp", "3"]);
    }
    args.extend_from_slice(extra);
    if !extra.contains(&"--seed") {
        args.extend_from_slice(&["--seed", "5"]);
    }
    args.extend_from_slice(&["--out", out.to_str().unwrap()]);
    lfr(&args)
}

fn channels(path: &Path) -> Vec<(String, Vec<u32>)> {
    let (_, _, channels) = tracer::output::read_exr(path).unwrap();
    channels.into_iter().map(|(name, values)| (name, values.iter().map(|v| v.to_bits()).collect())).collect()
}

#[test]
fn shards_in_separate_processes_merge_into_the_single_process_image() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.exr");
    ok(render(&whole, &[]));
    // 4 shards of 6 tiles: shard 3 has one tile, and the shards run with other thread counts.
    let shards: Vec<String> =
        (0..4).map(|i| dir.path().join(format!("s{i}.exr")).to_str().unwrap().to_string()).collect();
    for (i, shard) in shards.iter().enumerate() {
        let threads = if i % 2 == 0 { "1" } else { "2" };
        ok(render(Path::new(shard), &["--shard", &format!("{i}/4"), "--threads", threads]));
    }
    // A shard alone is not the image (its other tiles are empty).
    assert_ne!(channels(Path::new(&shards[0])), channels(&whole));
    let merged = dir.path().join("merged.exr");
    let mut args = vec!["merge", "--out", merged.to_str().unwrap()];
    // In any order.
    args.extend(shards.iter().rev().map(String::as_str));
    ok(lfr(&args));
    assert_eq!(channels(&merged), channels(&whole), "bit for bit, every channel");
    assert!(merged.with_extension("png").is_file());

    // The merged record sums the shards' rays and equals the whole render's.
    let attribute = |path: &Path| {
        let attributes = tracer::output::read_exr_attributes(path).unwrap();
        let json = &attributes.iter().find(|(n, _)| n == "lfr.render").expect("a record").1;
        serde_json::from_str::<serde_json::Value>(json).unwrap()
    };
    let (whole_record, merged_record) = (attribute(&whole), attribute(&merged));
    for key in ["scene_sha256", "width", "height", "spp", "seed", "max_bounces", "rays", "shard"] {
        assert_eq!(whole_record[key], merged_record[key], "{key}");
    }
}

#[test]
fn sample_shards_in_separate_processes_merge_into_the_single_process_image_within_rounding() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let spp = ["--spp", "7"];
    ok(render(Path::new(&path("whole.exr")), &spp));
    // 7 samples in 3 shards: 0..2, 2..4, 4..7, with other thread counts.
    let mut args = vec!["merge".to_string(), "--out".into(), path("merged.exr")];
    for i in 0..3 {
        let threads = if i == 1 { "1" } else { "2" };
        let shard = format!("{i}/3");
        let extra = ["--spp", "7", "--shard", &shard, "--shard-by", "samples", "--threads", threads];
        ok(render(Path::new(&path(&format!("s{i}.exr"))), &extra));
        args.push(path(&format!("s{i}.exr")));
    }
    ok(lfr(&args.iter().map(String::as_str).collect::<Vec<_>>()));
    let read = |name: &str| tracer::output::read_exr(Path::new(&path(name))).unwrap().2;
    let (whole, merged) = (read("whole.exr"), read("merged.exr"));
    assert_eq!(whole.iter().map(|c| &c.0).collect::<Vec<_>>(), merged.iter().map(|c| &c.0).collect::<Vec<_>>());
    for ((name, a), (_, b)) in whole.iter().zip(&merged) {
        let tolerance = if name.starts_with("variance") { 1e-4 } else { 1e-5 };
        let within = |x: f32, y: f32| (x - y).abs() <= tolerance * x.abs().max(y.abs()) + 1e-7;
        if ["albedo", "normal", "position", "depth"].iter().any(|guide| name.starts_with(guide)) {
            // Guide layers are weighted by the shards' sample counts, not their hits (and normals
            // add the shards' unit normals): exact where all of a pixel's samples hit one surface.
            let exact = a.iter().zip(b).filter(|(x, y)| within(**x, **y) || (**x - **y).abs() < 1e-4).count();
            // At 40x24, pixels on the box's and blocks' edges are about a tenth of the image.
            assert!(exact as f32 >= 0.8 * a.len() as f32, "{name}: {exact} of {} pixels", a.len());
        } else {
            for (p, (x, y)) in a.iter().zip(b).enumerate() {
                assert!(within(*x, *y), "{name} at pixel {p}: whole {x}, merged {y}");
            }
        }
    }
    // A shard alone holds fewer samples: a different image.
    assert_ne!(channels(Path::new(&path("s0.exr"))), channels(Path::new(&path("whole.exr"))));
    let attribute = |name: &str| {
        let attributes = tracer::output::read_exr_attributes(Path::new(&path(name))).unwrap();
        let json = &attributes.iter().find(|(n, _)| n == "lfr.render").expect("a record").1;
        serde_json::from_str::<serde_json::Value>(json).unwrap()
    };
    let (whole_record, merged_record) = (attribute("whole.exr"), attribute("merged.exr"));
    for key in ["scene_sha256", "spp", "rays", "shard", "shard_by", "samples"] {
        assert_eq!(whole_record[key], merged_record[key], "{key}");
    }
    assert_eq!(attribute("s2.exr")["samples"], serde_json::json!([4, 7]));

    // More shards than samples, and tile shards mixed with sample shards, are refused.
    let output = render(Path::new(&path("bad.exr")), &["--spp", "7", "--shard", "7/8", "--shard-by", "samples"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && stderr.contains("at most 7 sample shards"), "{stderr}");
    assert!(!Path::new(&path("bad.exr")).exists());
    ok(render(Path::new(&path("t1.exr")), &["--spp", "7", "--shard", "1/3"]));
    let output = lfr(&["merge", "--out", &path("mixed.exr"), &path("s0.exr"), &path("t1.exr"), &path("s2.exr")]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && stderr.contains("not shards of one render"), "{stderr}");
}

#[test]
fn wrong_shard_sets_are_refused_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    ok(render(Path::new(&path("a0.exr")), &["--shard", "0/2"]));
    ok(render(Path::new(&path("a1.exr")), &["--shard", "1/2"]));
    ok(render(Path::new(&path("b1.exr")), &["--shard", "1/2", "--seed", "6"]));
    ok(render(Path::new(&path("c1.exr")), &["--shard", "1/3"]));
    ok(render(Path::new(&path("plain.exr")), &[]));
    let out = path("out.exr");
    let cases: [(&[String], &[&str]); 5] = [
        (&[path("a0.exr")], &["shard 1 of 2 missing"]),
        (&[path("a0.exr"), path("a0.exr")], &["both shard 0/2"]),
        (&[path("a0.exr"), path("b1.exr")], &["not shards of one render", "seed 6"]),
        (&[path("a0.exr"), path("c1.exr")], &["not shards of one render", "3 shards"]),
        (&[path("plain.exr"), path("a1.exr")], &["not shards of one render"]),
    ];
    for (shards, expected) in cases {
        let mut args = vec!["merge", "--out", out.as_str()];
        args.extend(shards.iter().map(String::as_str));
        let output = lfr(&args);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{shards:?} merged");
        for needle in expected {
            assert!(stderr.contains(needle), "{shards:?}: `{needle}` not in: {stderr}");
        }
        assert!(!Path::new(&out).exists(), "nothing written for {shards:?}");
    }
    for bad in ["2/2", "1/0", "x/3", "3"] {
        let output = render(Path::new(&path("bad.exr")), &["--shard", bad]);
        assert!(!output.status.success(), "--shard {bad} accepted");
        assert!(String::from_utf8_lossy(&output.stderr).contains("--shard"), "{bad}");
    }
    // An EXR without a record (not written by lfr) is named.
    let foreign = path("foreign.exr");
    let layers =
        vec![tracer::output::Layer { name: "", channels: vec![("R", vec![1.0]), ("G", vec![1.0]), ("B", vec![1.0])] }];
    tracer::output::write_exr(Path::new(&foreign), 1, 1, &layers).unwrap();
    let output = lfr(&["merge", "--out", out.as_str(), foreign.as_str()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success() && stderr.contains("foreign.exr") && stderr.contains("no lfr.render record"),
        "{stderr}"
    );
}

/// A 1x1 image: one tile, so a second tile shard is empty (and still merges), and two sample
/// shards of its 4 samples merge into the single-process pixel.
#[test]
fn a_one_pixel_image_shards_and_merges() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let one_pixel = |out: &str, extra: &[&str]| {
        let mut args = vec!["render", "--width", "1", "--height", "1", "--spp", "4", "--seed", "3", "--quiet"];
        args.extend_from_slice(extra);
        let out = path(out);
        args.extend_from_slice(&["--out", &out]);
        ok(lfr(&args))
    };
    one_pixel("whole.exr", &[]);
    for (by, tolerance) in [("tiles", 0.0f32), ("samples", 1e-5)] {
        for i in 0..2 {
            one_pixel(&format!("{by}{i}.exr"), &["--shard", &format!("{i}/2"), "--shard-by", by]);
        }
        let merged = path(&format!("{by}-merged.exr"));
        ok(lfr(&["merge", "--out", &merged, &path(&format!("{by}1.exr")), &path(&format!("{by}0.exr"))]));
        let whole = tracer::output::read_exr(Path::new(&path("whole.exr"))).unwrap().2;
        let merged = tracer::output::read_exr(Path::new(&merged)).unwrap().2;
        for ((name, a), (_, b)) in whole.iter().zip(&merged) {
            if by == "samples" && ["albedo", "normal", "position", "depth"].iter().any(|g| name.starts_with(g)) {
                continue; // guide layers: weighted by sample counts (the test above)
            }
            let tolerance = if name.starts_with("variance") { 10.0 * tolerance } else { tolerance };
            assert!(
                (a[0] - b[0]).abs() <= tolerance * a[0].abs().max(b[0].abs()),
                "{by} {name}: whole {}, merged {}",
                a[0],
                b[0]
            );
        }
    }
}
