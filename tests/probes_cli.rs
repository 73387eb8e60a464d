//! `lfr probes`: bad parameters are refused with an error naming the field before the
//! scene is read; a small `stats` run on the embedded Cornell box reports a placement whose
//! numbers agree with each other; `relight` builds the cache once and reuses it bit for bit
//! whatever the lights, writes the image's named layers consistently, refuses corrupt,
//! truncated, foreign and stale caches by file name; `animate` and CPCA end to end.

use crate::common;
use crate::lfr_runner as cli;

use std::path::Path;

use cli::{lfr, stderr};

#[test]
fn bad_parameters_are_refused_before_any_work() {
    for (extra, needle) in [
        (vec!["--probes", "0"], "probes:"),
        (vec!["--overlap", "NaN"], "overlap:"),
        (vec!["--overlap", "0"], "overlap:"),
        (vec!["--receivers", "0"], "receivers:"),
        (vec!["--receivers", "100000000000"], "receivers:"),
        (vec!["--threads", "100000"], "--threads"),
        (vec!["--survey-directions", "0"], "survey-directions:"),
        (vec!["--directions", "0"], "directions:"),
        (vec!["--frame", "--relight-rays", "10"], "relight-rays:"),
        (vec!["--width", "64"], "makes no image"),
        (vec!["--height", "64"], "makes no image"),
    ] {
        // A scene that does not exist: the settings must be refused before it is looked for.
        let mut args = vec!["probes", "stats", "--quiet", "--scene", "does-not-exist.toml"];
        args.extend_from_slice(&extra);
        let out = lfr(&args);
        let message = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{extra:?} must fail");
        assert!(!message.contains("panicked"), "{message}");
        assert!(message.contains(needle), "{extra:?}: expected {needle:?} in {message}");
        assert!(!message.contains("does-not-exist"), "{extra:?}: the scene was read first: {message}");
    }
    let out = lfr(&["probes", "stats", "--quiet", "--scene", "does-not-exist.toml"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("does-not-exist"));
}

#[test]
fn stats_on_the_cornell_box_are_consistent() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("stats.json");
    let out = lfr(&[
        "probes",
        "stats",
        "--quiet",
        "--probes",
        "12",
        "--receivers",
        "3000",
        "--time-transport",
        "50",
        "--directions",
        "64",
        "--frame",
        "--relight-rays",
        "512",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("coverage") && stdout.contains("memory"), "{stdout}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(report["probes"], 12);
    let receivers = report["receivers"].as_f64().unwrap();
    assert!(receivers > 2000.0 && receivers < 5000.0, "{receivers}");
    let mean = report["probes_per_receiver_mean"].as_f64().unwrap();
    assert!((10.0..10.05).contains(&mean), "mean overlap {mean}");
    let (min, max) =
        (report["probes_per_receiver_min"].as_f64().unwrap(), report["probes_per_receiver_max"].as_f64().unwrap());
    assert!(min <= mean && mean <= max && max <= 12.0);
    let survey = report["survey_receivers"].as_f64().unwrap();
    assert!(survey > 0.0 && survey <= receivers);
    let unseen = report["survey_unseen_fraction"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&unseen), "{unseen}");
    assert_eq!(report["transport_receivers"], 50);
    assert!(report["transport_s_per_receiver"].as_f64().unwrap() > 0.0);
    let frame = &report["frame"];
    assert!(frame["iterations"].as_u64().unwrap() >= 1);
    let indirect = frame["mean_indirect_irradiance"].as_array().unwrap();
    assert!(indirect.iter().all(|v| v.as_f64().unwrap() > 0.0 && v.as_f64().unwrap().is_finite()), "{indirect:?}");
    let dense = report["dense_transport_bytes"].as_f64().unwrap();
    assert!((dense / (receivers * mean * 256.0) - 1.0).abs() < 1e-9);
}

/// Small precompute settings on the embedded Cornell box.
const SMALL: [&str; 10] =
    ["--probes", "8", "--receivers", "1500", "--directions", "32", "--order", "2", "--relight-rays", "200"];

fn relight(cache: &Path, out: &Path, json: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["probes", "relight", "--quiet", "--width", "24", "--height", "20", "--light-samples", "4"];
    args.extend_from_slice(&SMALL);
    args.extend_from_slice(&["--cache", cache.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    args.extend_from_slice(&["--json", json.to_str().unwrap()]);
    args.extend_from_slice(extra);
    lfr(&args)
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn channels(path: &Path) -> std::collections::HashMap<String, Vec<f32>> {
    let (w, h, list) = tracer::output::read_exr(path).unwrap();
    assert_eq!((w, h), (24, 20));
    list.into_iter().collect()
}

#[test]
fn relight_builds_the_cache_once_and_reuses_it_whatever_the_lights() {
    let dir = tempfile::tempdir().unwrap();
    let (cache, a, b, j) =
        (dir.path().join("c.probes"), dir.path().join("a.exr"), dir.path().join("b.exr"), dir.path().join("r.json"));
    // The dense transport first: the oracle CPCA is checked against below. One ray per pixel,
    // so that the layers' relation holds per pixel (with more, the product's mean is not the
    // product of the means at edges).
    let dense = ["--cpca=off", "--pixel-samples", "1"];
    let out = relight(&cache, &a, &j, &dense);
    assert!(out.status.success(), "{}", stderr(&out));
    let report = json(&j);
    assert_eq!(report["precompute"]["precompute_from_cache"], false);
    assert!(report["cpca"].is_null(), "{report}");
    assert!(a.with_extension("png").is_file());
    // The frame split as the paper's Table 2, and the camera's kept lookups.
    let times = &report["times"];
    for key in ["direct_s", "probe_relight_s", "cluster_projection_s", "receiver_irradiance_s", "image_s", "frame_s"] {
        assert!(times[key].as_f64().is_some_and(|v| v >= 0.0 && v.is_finite()), "{key}: {times}");
    }
    assert!(report["image_operator_s"].as_f64().unwrap() > 0.0 && report["image_operator_bytes"].as_u64().unwrap() > 0);
    let bytes = std::fs::read(&cache).unwrap();

    // The layers agree with each other: beauty = direct + indirect, indirect = albedo E / π.
    let c = channels(&a);
    for name in ["R", "direct.R", "indirect.G", "irradiance.B", "albedo.R", "unseen.Y", "probes.Y", "hole.Y"] {
        assert!(c.contains_key(name), "no channel {name}: {:?}", c.keys().collect::<Vec<_>>());
    }
    let pi = std::f32::consts::PI;
    let mut lit = 0;
    for ch in ["R", "G", "B"] {
        let (beauty, direct, indirect) = (&c[ch], &c[&format!("direct.{ch}")], &c[&format!("indirect.{ch}")]);
        let (albedo, e) = (&c[&format!("albedo.{ch}")], &c[&format!("irradiance.{ch}")]);
        for i in 0..beauty.len() {
            assert!(beauty[i].is_finite() && indirect[i] >= 0.0 && direct[i] >= 0.0);
            assert_eq!(beauty[i], direct[i] + indirect[i]);
            assert!((indirect[i] - albedo[i] * e[i] / pi).abs() <= 1e-5 * indirect[i].max(1e-3));
            lit += usize::from(indirect[i] > 0.0);
        }
    }
    assert!(lit > 24 * 20, "the Cornell box has indirect light almost everywhere: {lit}");
    assert!(c["unseen.Y"].iter().all(|u| (0.0..=1.0).contains(u)));
    assert!(c["probes.Y"].iter().any(|p| *p > 0.0));

    // Again: from the cache, the same image bit for bit, the cache untouched.
    let out = relight(&cache, &b, &j, &dense);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(json(&j)["precompute"]["precompute_from_cache"], true);
    assert_eq!(channels(&b), c);
    assert_eq!(std::fs::read(&cache).unwrap(), bytes);

    // Another light (the scene's removed, a point light added): still the same cache, another image.
    let out = relight(
        &cache,
        &b,
        &j,
        &[&dense[..], &["--no-scene-lights", "--light-position", "150,300,250", "--light-intensity", "40000"]].concat(),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(json(&j)["precompute"]["precompute_from_cache"], true);
    assert_eq!(std::fs::read(&cache).unwrap(), bytes);
    let moved = channels(&b);
    assert_ne!(moved["indirect.R"], c["indirect.R"]);
    assert!(moved["indirect.R"].iter().any(|v| *v > 0.0));

    // CPCA at the default tolerance (default on): close to the dense image, smaller per receiver.
    let out = relight(&cache, &b, &j, &["--cpca", "--cpca-coefficients", "16", "--pixel-samples", "1"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let r = json(&j);
    let cpca = &r["cpca"];
    assert!(cpca["max_cluster_error"].as_f64().unwrap() <= 0.005, "{cpca}");
    assert!(cpca["mean_coefficients"].as_f64().unwrap() <= 16.0);
    assert_eq!(cpca["from_cache"], false);
    assert!(Path::new(&format!("{}.cpca", cache.display())).is_file());
    let compressed = channels(&b);
    // Again: the compressed transport from its cache, the same image.
    let out = relight(&cache, &b, &j, &["--cpca", "--cpca-coefficients", "16", "--pixel-samples", "1"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(json(&j)["cpca"]["from_cache"], true);
    assert_eq!(channels(&b), compressed);
    // Other CPCA settings replace it; a damaged one is an error naming it.
    let out = relight(&cache, &b, &j, &["--cpca", "--cpca-coefficients", "12"]);
    assert!(out.status.success() && stderr(&out).contains("replacing it"), "{}", stderr(&out));
    let cpca_file = format!("{}.cpca", cache.display());
    let mut damaged = std::fs::read(&cpca_file).unwrap();
    let at = damaged.len() / 2;
    damaged[at] ^= 8;
    std::fs::write(&cpca_file, &damaged).unwrap();
    let out = relight(&cache, &b, &j, &["--cpca", "--cpca-coefficients", "12"]);
    let message = stderr(&out);
    assert!(!out.status.success() && message.contains(&cpca_file) && message.contains("checksum"), "{message}");
    for ch in ["indirect.R", "indirect.G", "indirect.B"] {
        let diff: f32 = compressed[ch].iter().zip(&c[ch]).map(|(x, y)| (x - y).abs()).sum();
        let total: f32 = c[ch].iter().sum();
        assert!(diff < 0.05 * total, "{ch}: CPCA differs by {diff} of {total}");
    }
}

#[test]
fn relight_runs_the_bounces_projected_or_in_full_to_the_same_image() {
    let dir = tempfile::tempdir().unwrap();
    let (cache, a, b, j) =
        (dir.path().join("c.probes"), dir.path().join("a.exr"), dir.path().join("b.exr"), dir.path().join("r.json"));
    // Six bounces: the loops differ only in where negative irradiance is clamped (after every
    // bounce or once at the end). To convergence: each stops by its own test of the change,
    // so they agree within the bounce tolerance (1e-3 of the largest irradiance). Without the
    // near field, whose light of later bounces the projected loop takes through U (its own
    // test, `near_field::tests`).
    for (bounces, within) in [("6", 1e-4f32), ("0", 2e-3)] {
        let out = relight(&cache, &a, &j, &["--cpca", "--near-field=off", "--bounces", bounces]);
        assert!(out.status.success(), "{}", stderr(&out));
        let r = json(&j);
        assert_eq!(r["bounce_loop"], "projected", "{r}");
        let size = r["projected"]["size"].as_u64().unwrap();
        assert!(size > 0 && r["projected"]["bytes"].as_u64().unwrap() == 12 * size * size, "{r}");
        assert!(r["times"]["projected_bounces_s"].as_f64().unwrap() >= 0.0);
        let projected_iterations = r["times"]["iterations"].as_u64().unwrap();
        let out =
            relight(&cache, &b, &j, &["--cpca", "--near-field=off", "--bounces", bounces, "--bounce-loop", "full"]);
        assert!(out.status.success(), "{}", stderr(&out));
        let r = json(&j);
        assert_eq!(r["bounce_loop"], "full");
        assert!(r["projected"].is_null() && r["times"]["projected_bounces_s"].as_f64() == Some(0.0), "{r}");
        if bounces != "0" {
            assert_eq!(r["times"]["iterations"].as_u64().unwrap(), projected_iterations);
        }
        let (pa, pb) = (channels(&a), channels(&b));
        for ch in ["irradiance.R", "irradiance.G", "irradiance.B"] {
            let largest = pb[ch].iter().fold(0.0f32, |m, v| m.max(*v));
            assert!(largest > 0.0);
            let worst = pa[ch].iter().zip(&pb[ch]).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
            assert!(worst <= within * largest, "{bounces} bounces, {ch}: off by {worst} of {largest}");
        }
    }
}

#[test]
fn corrupt_truncated_foreign_and_stale_caches_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let (cache, out_exr, j) = (dir.path().join("c.probes"), dir.path().join("a.exr"), dir.path().join("r.json"));
    // Not a cache: relight and precompute both refuse it, naming it, and leave it alone.
    std::fs::write(&cache, b"some other file").unwrap();
    let out = relight(&cache, &out_exr, &j, &[]);
    let message = stderr(&out);
    assert!(!out.status.success() && !message.contains("panicked"), "{message}");
    assert!(message.contains(cache.to_str().unwrap()) && message.contains("not a probes cache"), "{message}");
    assert!(!out_exr.exists());
    let mut args = vec!["probes", "precompute", "--quiet", "--cache", cache.to_str().unwrap()];
    args.extend_from_slice(&SMALL);
    let out = lfr(&args);
    assert!(!out.status.success() && stderr(&out).contains("not a probes cache"), "{}", stderr(&out));
    assert_eq!(std::fs::read(&cache).unwrap(), b"some other file");

    // A real cache, then damaged: relight refuses it; precompute rebuilds it.
    std::fs::remove_file(&cache).unwrap();
    let out = lfr(&args);
    assert!(out.status.success(), "{}", stderr(&out));
    let good = std::fs::read(&cache).unwrap();
    let mut flipped = good.clone();
    let at = good.len() / 2;
    flipped[at] ^= 1;
    let mut future = good.clone();
    future[8] = future[8].wrapping_add(1);
    for (bytes, needle) in [(good[..good.len() - 7].to_vec(), "truncated"), (flipped, "checksum"), (future, "version")]
    {
        std::fs::write(&cache, &bytes).unwrap();
        let out = relight(&cache, &out_exr, &j, &[]);
        let message = stderr(&out);
        assert!(!out.status.success() && !message.contains("panicked"), "{message}");
        assert!(message.contains(cache.to_str().unwrap()) && message.contains(needle), "{needle}: {message}");
        assert!(!out_exr.exists());
    }
    let out = lfr(&args);
    let message = stderr(&out);
    // The last damage was the version: said in words, not as the variant's name.
    assert!(out.status.success() && message.contains("another format version; building it again"), "{message}");
    assert!(!message.contains("(Version)"), "{message}");
    assert_eq!(std::fs::read(&cache).unwrap(), good, "the rebuilt cache differs");

    // Other settings against this cache: refused by relight, naming the file.
    let out = relight(&cache, &out_exr, &j, &["--overlap", "5"]);
    let message = stderr(&out);
    assert!(!out.status.success() && message.contains("c.probes") && message.contains("other settings"), "{message}");
}

#[test]
fn relight_and_animate_refuse_bad_parameters_before_any_work() {
    for (command, extra, needle) in [
        ("relight", vec!["--light-position", "1,2"], "light-position:"),
        ("relight", vec!["--light-position", "1,2,NaN"], "light-position:"),
        ("relight", vec!["--light-position", "1,2,3", "--light-intensity", "-1"], "light-intensity:"),
        ("relight", vec!["--light-intensity", "5"], "light-intensity:"),
        ("relight", vec!["--order", "9"], "order:"),
        ("relight", vec!["--relight-rays", "10"], "relight-rays:"),
        ("relight", vec!["--directions", "0"], "directions:"),
        ("relight", vec!["--probes", "0"], "probes:"),
        ("relight", vec!["--cpca", "--cpca-tolerance", "2"], "tolerance:"),
        ("relight", vec!["--cpca", "--cpca-coefficients", "0"], "coefficients:"),
        ("relight", vec!["--cpca=off", "--fp16"], "fp16:"),
        ("relight", vec!["--light-samples", "0"], "light-samples:"),
        ("relight", vec!["--pixel-samples", "0"], "pixel-samples:"),
        ("relight", vec!["--bounces", "20000"], "bounces:"),
        ("relight", vec!["--cpca=off", "--bounce-loop", "projected"], "bounce-loop:"),
        ("relight", vec!["--cpca", "--bounce-loop", "some"], "--bounce-loop"),
        ("animate", vec!["--frames", "0"], "frames:"),
        ("animate", vec!["--light-to", "1,2"], "light-to:"),
        ("animate", vec!["--bounces-per-frame", "0"], "bounces-per-frame:"),
    ] {
        let mut args = vec!["probes", command, "--quiet", "--scene", "does-not-exist.toml", "--cache", "x.probes"];
        if command == "relight" {
            args.extend_from_slice(&["--out", "x.exr"]);
        } else {
            args.extend_from_slice(&["--out-dir", "xdir", "--light-from", "0,0,0"]);
            if !extra.contains(&"--light-to") {
                args.extend_from_slice(&["--light-to", "1,1,1"]);
            }
        }
        args.extend_from_slice(&extra);
        let out = lfr(&args);
        let message = stderr(&out);
        assert!(!out.status.success(), "{extra:?} must fail");
        assert!(!message.contains("panicked"), "{message}");
        assert!(message.contains(needle), "{extra:?}: expected {needle:?} in {message}");
        assert!(!message.contains("does-not-exist"), "{extra:?}: the scene was read first: {message}");
    }
    let out = lfr(&["probes", "relight", "--quiet", "--cache", "x.probes", "--out", "x.png"]);
    assert!(!out.status.success() && stderr(&out).contains(".exr"), "{}", stderr(&out));
}

#[test]
fn animate_moves_a_light_over_frames_from_one_cache() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("c.probes");
    let frames = dir.path().join("frames");
    let mut args = vec!["probes", "animate", "--quiet", "--width", "24", "--height", "20", "--light-samples", "4"];
    args.extend_from_slice(&SMALL);
    args.extend_from_slice(&["--cache", cache.to_str().unwrap(), "--out-dir", frames.to_str().unwrap()]);
    args.extend_from_slice(&["--frames", "3", "--no-scene-lights", "--light-intensity", "40000"]);
    args.extend_from_slice(&["--light-from", "100,400,200", "--light-to", "450,400,400"]);
    let out = lfr(&args);
    assert!(out.status.success(), "{}", stderr(&out));
    let report = json(&frames.join("timings.json"));
    let list = report["frames"].as_array().unwrap();
    assert_eq!(list.len(), 3);
    for (f, frame) in list.iter().enumerate() {
        assert!(
            frames.join(format!("frame_{f:04}.exr")).is_file() && frames.join(format!("frame_{f:04}.png")).is_file()
        );
        assert!(frame["frame_s"].as_f64().unwrap().is_finite());
        for key in ["direct_s", "probe_relight_s", "cluster_projection_s", "receiver_irradiance_s", "image_s"] {
            assert!(frame[key].as_f64().is_some_and(|v| v >= 0.0), "{key}: {frame}");
        }
    }
    assert!(report["image_operator_s"].as_f64().unwrap() > 0.0);
    assert_eq!(list[2]["light_position"][0].as_f64().unwrap(), 450.0);
    assert_ne!(list[0]["mean_indirect"], list[2]["mean_indirect"]);
    assert!(list.iter().all(|f| f["mean_indirect"].as_array().unwrap().iter().all(|v| v.as_f64().unwrap() > 0.0)));
}

#[test]
fn a_moving_light_reuses_the_same_precompute_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("c.probes");
    let animate = |frames: &Path, from: &str, to: &str| {
        let mut args = vec!["probes", "animate", "--quiet", "--width", "16", "--height", "12", "--light-samples", "2"];
        args.extend_from_slice(&SMALL);
        args.extend_from_slice(&["--cache", cache.to_str().unwrap(), "--out-dir", frames.to_str().unwrap()]);
        args.extend_from_slice(&["--frames", "3", "--no-scene-lights", "--light-intensity", "40000"]);
        args.extend_from_slice(&["--light-from", from, "--light-to", to]);
        let out = lfr(&args);
        assert!(out.status.success(), "{}", stderr(&out));
        json(&frames.join("timings.json"))
    };
    let read = |p: &Path| std::fs::read(p).unwrap();
    // The first run builds the cache; every frame of it uses that one precompute.
    let (first, second, other) = (dir.path().join("a"), dir.path().join("b"), dir.path().join("c"));
    let report = animate(&first, "100,400,200", "450,400,400");
    assert_eq!(report["precompute"]["precompute_from_cache"], false);
    let bytes = read(&cache);
    // The same light path again: the precompute comes from the cache, the file is untouched, and
    // every frame is the same bit for bit as the frames made from the freshly built precompute.
    let report = animate(&second, "100,400,200", "450,400,400");
    assert_eq!(report["precompute"]["precompute_from_cache"], true);
    assert_eq!(read(&cache), bytes, "the cache changed");
    for f in 0..3 {
        let name = format!("frame_{f:04}.exr");
        assert_eq!(read(&first.join(&name)), read(&second.join(&name)), "{name} differs from the cache's");
    }
    // Another light path: still the cache's precompute, the file unchanged, other images.
    let report = animate(&other, "300,200,100", "200,500,300");
    assert_eq!(report["precompute"]["precompute_from_cache"], true);
    assert_eq!(read(&cache), bytes, "a moved light changed the cache");
    assert_ne!(read(&first.join("frame_0002.exr")), read(&other.join("frame_0002.exr")));
}

/// `lfr` with `$LFR_MEMORY_AVAILABLE` set to `bytes` (the measured available memory replaced).
fn lfr_with_memory(args: &[&str], bytes: u64) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(args)
        .current_dir(common::project_root())
        .env("LFR_SCENES", common::shared_scenes())
        .env("LFR_MEMORY_AVAILABLE", bytes.to_string())
        .output()
        .expect("lfr runs")
}

#[test]
fn an_estimated_memory_above_the_machines_is_refused_before_the_precompute() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("c.probes");
    let (c, exr, frames) = (cache.to_str().unwrap(), dir.path().join("x.exr"), dir.path().join("frames"));
    let (exr, frames) = (exr.to_str().unwrap(), frames.to_str().unwrap());
    let mut runs: Vec<Vec<&str>> = vec![
        vec!["probes", "precompute", "--cache", c],
        vec!["probes", "relight", "--cache", c, "--out", exr, "--width", "24", "--height", "20"],
        vec!["probes", "relight", "--cache", c, "--out", exr, "--width", "24", "--height", "20", "--cpca"],
        vec!["probes", "animate", "--cache", c, "--out-dir", frames, "--light-from", "0,0,0", "--light-to", "1,1,1"],
    ];
    for run in &mut runs {
        run.push("--quiet");
        run.extend_from_slice(&SMALL);
    }
    let mut stats = vec!["probes", "stats", "--quiet", "--frame", "--survey", "0"];
    stats.extend_from_slice(&SMALL[..6]);
    runs.push(stats);
    for args in &runs {
        // 1 MB available: every run is refused with the estimate, before anything is built.
        let out = lfr_with_memory(args, 1 << 20);
        let message = stderr(&out);
        assert!(!out.status.success(), "{args:?} must fail");
        assert!(!message.contains("panicked"), "{message}");
        assert!(message.contains("needs about") && message.contains("1.0 MiB is available"), "{args:?}: {message}");
        assert!(message.contains("receivers") && message.contains("LFR_MEMORY_AVAILABLE"), "{message}");
        assert!(!cache.exists() && !Path::new(exr).exists() && !Path::new(frames).exists(), "{args:?} did work");
    }
    // The case: a budget the machine cannot hold (20 M receivers need tens of GB of
    // dense transport) against 8 GiB, refused within a test's time instead of killed later.
    let mut big = vec!["probes", "precompute", "--quiet", "--cache", c, "--receivers", "20000000"];
    big.extend_from_slice(&["--directions", "32", "--relight-rays", "512"]);
    let out = lfr_with_memory(&big, 8 << 30);
    assert!(!out.status.success() && stderr(&out).contains("8.0 GiB is available"), "{}", stderr(&out));
    assert!(!cache.exists());
    // The same small precompute with 16 GiB available runs.
    let out = lfr_with_memory(&runs[0], 16 << 30);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(cache.is_file());
}

/// `lfr compare --methods probes...` on the embedded Cornell box at 32×32 (tiny precompute).
fn probes_compare(out: &Path, cache: &Path, methods: &str, effect: &str) -> std::process::Output {
    lfr(&[
        "compare",
        "--effect",
        effect,
        "--width",
        "32",
        "--height",
        "32",
        "--spp",
        "1",
        "--reference-spp",
        "256",
        "--pt-max-spp",
        "64",
        "--repeats",
        "2",
        "--quiet",
        "--seed",
        "3",
        "--methods",
        methods,
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ])
}

#[test]
fn compare_runs_probes_with_its_precompute_times_and_per_frame_verdicts() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let tiny = "probes:probes=4:receivers=1500:directions=32:relight_rays=1024:order=3:pixel_samples=1";
    let spatial = format!("{tiny}:cpca=off:reconstruction=spatial:miss_weight=1");
    // The frame's image through the camera's kept lookups (the default) or traced and looked
    // up every frame: the same image.
    let lookups = format!("{tiny}:image=lookups");
    let methods = format!("{tiny},{spatial},{lookups}");
    let first = dir.path().join("first");
    let out = probes_compare(&first, &cache, &methods, "indirect");
    assert!(out.status.success(), "{}", stderr(&out));
    let results = json(&first.join("results.json"));
    let schema: serde_json::Value =
        serde_json::from_slice(&std::fs::read(common::project_root().join("docs/compare.schema.json")).unwrap())
            .unwrap();
    let validator = jsonschema::validator_for(&schema).unwrap();
    let errors: Vec<String> = validator.iter_errors(&results).map(|e| format!("{e} at {}", e.instance_path)).collect();
    assert!(errors.is_empty(), "{errors:?}");
    let runs = results["runs"].as_array().unwrap();
    let pt: Vec<&serde_json::Value> = runs.iter().filter(|r| r["method"] == "pt").collect();
    assert!(pt.iter().all(|r| r["precompute_from_cache"].is_null() && r["per_frame_speedup"].is_null()));
    let mine: Vec<&serde_json::Value> =
        runs.iter().filter(|r| r["method"].as_str().unwrap().starts_with("probes")).collect();
    assert_eq!(mine.len(), 3);
    for (i, run) in mine.iter().enumerate() {
        assert_eq!(run["input_spp"], 0);
        assert_eq!(run["recon_rays"], 1);
        // The third has the first one's precompute settings: it reads the first one's cache.
        assert_eq!(run["precompute_from_cache"], i == 2, "{run}");
        let (pre, recon, total) =
            (run["preprocess_s"].as_f64().unwrap(), run["recon_s"].as_f64().unwrap(), run["total_s"].as_f64().unwrap());
        assert!(pre > 0.0 && recon > 0.0 && (total - pre - recon).abs() < 1e-9, "{run}");
        assert_eq!(run["timings"].as_array().unwrap().len(), 2);
        assert!(run["stats"]["probes"].as_f64().unwrap() >= 1.0 && run["stats"]["receivers"].as_f64().unwrap() > 100.0);
        // The per-frame verdicts follow from the run's own numbers: speedup = PT time / recon_s
        // and break-even = preprocess_s / (PT time − recon_s).
        let speedup = run["per_frame_speedup"].as_f64().expect("a PT curve to read");
        let pt_time = speedup * recon;
        assert!((run["speedup"].as_f64().unwrap() * total - pt_time).abs() < 1e-6 * pt_time, "{run}");
        match run["break_even_frames"].as_f64() {
            Some(n) => assert!(pt_time > recon && (n * (pt_time - recon) - pre).abs() < 1e-6 * pre.max(1e-9), "{run}"),
            None => assert!(pt_time <= recon, "{run}"),
        }
        assert!(!run["notes"].as_array().unwrap().iter().any(|n| n.as_str().unwrap().contains("not deterministic")));
    }
    assert!(mine[0]["stats"]["cpca_clusters"].as_f64().unwrap() >= 1.0);
    assert!(mine[1]["stats"].get("cpca_clusters").is_none());
    // Kept lookups and projected bounces (the defaults with CPCA) are formed once per run; the
    // dense transport has no projected bounce; `image=lookups` keeps none and gives the same
    // image (the same PSNR bit for bit).
    assert!(mine[0]["stats"]["image_operator_s"].as_f64().unwrap() > 0.0);
    assert!(mine[0]["stats"]["projected_size"].as_f64().unwrap() >= 1.0);
    assert!(mine[1]["stats"].get("projected_size").is_none() && mine[1]["stats"]["image_operator_s"].is_f64());
    assert!(mine[2]["stats"].get("image_operator_s").is_none());
    assert_eq!(mine[2]["psnr_db"], mine[0]["psnr_db"]);
    for key in ["direct_s", "probe_relight_s", "cluster_projection_s", "receiver_irradiance_s", "image_s"] {
        assert!(mine[0]["stats"][key].as_f64().is_some_and(|v| v >= 0.0), "{key}: {}", mine[0]["stats"]);
    }
    let verdicts = results["verdicts"].as_array().unwrap();
    for (verdict, run) in verdicts.iter().zip(&mine) {
        assert_eq!(verdict["method"], run["method"]);
        assert_eq!(verdict["best_per_frame_speedup"], run["per_frame_speedup"]);
        assert_eq!(verdict["break_even_frames"], run["break_even_frames"]);
        assert!(verdict["summary"].as_str().unwrap().contains("one frame takes"), "{verdict}");
    }
    // A rerun reads both precomputes from the cache: the same image, the build time kept.
    let second = dir.path().join("second");
    let out = probes_compare(&second, &cache, &methods, "indirect");
    assert!(out.status.success(), "{}", stderr(&out));
    let again = json(&second.join("results.json"));
    let rerun: Vec<&serde_json::Value> = again["runs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["method"].as_str().unwrap().starts_with("probes"))
        .collect();
    for (a, b) in mine.iter().zip(&rerun) {
        assert_eq!(b["precompute_from_cache"], true);
        assert_eq!(a["psnr_db"], b["psnr_db"]);
        // The precompute's and CPCA's build times are kept beside the cache; the camera's
        // lookups and the projected bounce are formed in every run, and preprocess_s is the sum.
        for key in ["precompute_s", "cpca_s"] {
            assert_eq!(a["stats"][key], b["stats"][key], "{key}: the build time is kept beside the cache");
        }
        for run in [a, b] {
            let parts: f64 = ["precompute_s", "cpca_s", "image_operator_s", "projected_bounce_s"]
                .iter()
                .filter_map(|k| run["stats"][*k].as_f64())
                .sum();
            let pre = run["preprocess_s"].as_f64().unwrap();
            assert!((pre - parts).abs() <= 1e-9 * parts.max(1.0), "{pre} against {parts}: {run}");
        }
    }
    // Another effect, and bad options, are refused before anything is traced.
    for (methods, effect, needle) in [
        (tiny.to_string(), "ao", "indirect only"),
        ("probes:order=9".to_string(), "indirect", "order"),
        ("probes:cpca=perhaps".to_string(), "indirect", "cpca"),
    ] {
        let bad = dir.path().join("bad");
        let out = probes_compare(&bad, &cache, &methods, effect);
        let message = stderr(&out);
        assert!(!out.status.success() && message.contains(needle) && !message.contains("panicked"), "{message}");
        assert!(!bad.join("results.json").exists());
    }
}

/// The CLI and the harness run one pipeline (`probes::pipeline`): `lfr probes relight` with the
/// scene's own lights and `lfr compare`'s `probes` with the same settings, seed, size and
/// bounces give the same indirect image, bit for bit; with the near field off, at its default
/// and at another radius.
#[test]
fn relight_and_compare_give_the_same_image_for_the_same_settings() {
    for (flags, options) in [
        (&["--near-field=off"][..], ":near_field=off"),
        (&[][..], ""),
        (&["--near-radius", "0.5"][..], ":near_radius=0.5"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let relit = dir.path().join("relit.exr");
        let cache = dir.path().join("c.probes");
        #[rustfmt::skip]
        let mut argv = vec![
            "probes", "relight", "--quiet", "--width", "32", "--height", "32", "--seed", "3",
            "--probes", "4", "--receivers", "1500", "--directions", "32", "--relight-rays", "1024", "--order", "3",
            "--pixel-samples", "1", "--cache", cache.to_str().unwrap(), "--out", relit.to_str().unwrap(),
        ];
        argv.extend_from_slice(flags);
        let out = lfr(&argv);
        assert!(out.status.success(), "{}", stderr(&out));
        let compared = dir.path().join("compare");
        let spec =
            format!("probes:probes=4:receivers=1500:directions=32:relight_rays=1024:order=3:pixel_samples=1{options}");
        let out = probes_compare(&compared, &dir.path().join("cache"), &spec, "indirect");
        assert!(out.status.success(), "{}", stderr(&out));
        let results = json(&compared.join("results.json"));
        let run = results["runs"].as_array().unwrap().iter().find(|r| r["method"] != "pt").expect("the probes run");
        assert_eq!(run["stats"]["near_field_hits"].is_number(), !options.contains("off"), "{run}");
        let (w, h, harness) = tracer::output::read_exr(&compared.join(run["image"].as_str().unwrap())).unwrap();
        let (_, _, cli) = tracer::output::read_exr(&relit).unwrap();
        assert_eq!((w, h), (32, 32));
        let layer = |list: &[(String, Vec<f32>)], c: &str| -> Vec<u32> {
            let found = list.iter().find(|(name, _)| name == &format!("indirect.{c}")).unwrap_or_else(|| panic!("{c}"));
            found.1.iter().map(|v| v.to_bits()).collect()
        };
        for c in ["R", "G", "B"] {
            let (a, b) = (layer(&cli, c), layer(&harness, c));
            assert!(a.iter().any(|&v| f32::from_bits(v) > 0.0), "a lit image");
            assert!(a == b, "{options}: channel {c}: the relight's and the comparison's images differ");
        }
    }
}

/// Same seed, same output whatever the thread count: the whole precompute (the cache file, byte
/// for byte) and a relit frame with CPCA and the projected bounces (every layer, bit for bit)
/// with one, two and three worker threads.
#[test]
fn the_precompute_and_a_relit_frame_do_not_depend_on_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    type CacheAndLayers = (Vec<u8>, std::collections::HashMap<String, Vec<f32>>);
    let mut first: Option<CacheAndLayers> = None;
    for threads in ["1", "2", "3"] {
        let (cache, exr, j) = (
            dir.path().join(format!("c{threads}.probes")),
            dir.path().join(format!("a{threads}.exr")),
            dir.path().join(format!("r{threads}.json")),
        );
        let out = relight(&cache, &exr, &j, &["--cpca", "--threads", threads]);
        assert!(out.status.success(), "{}", stderr(&out));
        assert_eq!(json(&j)["precompute"]["precompute_from_cache"], false);
        let (bytes, layers) = (std::fs::read(&cache).unwrap(), channels(&exr));
        match &first {
            None => first = Some((bytes, layers)),
            Some((bytes_1, layers_1)) => {
                assert!(bytes == *bytes_1, "the cache differs with {threads} threads");
                for (name, values) in layers_1 {
                    let other = &layers[name];
                    let same = values.iter().zip(other).all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(same && values.len() == other.len(), "layer {name} differs with {threads} threads");
                }
            }
        }
    }
}
