//! `lfr compare` end to end at 32×32: results.json validates against docs/compare.schema.json,
//! path-tracing error falls as spp grows, `box` matches path tracing at equal spp (the same
//! estimator read back through the sample file), the reference cache is reused, a seed
//! reproduces every number, an all-black reference scores as documented, and bad input fails
//! cleanly.

use crate::common;
use crate::lfr_runner as cli;

use std::path::{Path, PathBuf};
use std::process::Command;

use cli::lfr;
use common::project_root;
use serde_json::Value;

/// A tiny compare of the embedded Cornell box; returns results.json.
fn tiny_compare(out: &Path, cache: &Path, extra: &[&str]) -> Value {
    let mut args = vec![
        "compare",
        "--effect",
        "indirect",
        "--width",
        "32",
        "--height",
        "32",
        "--spp",
        "1,4",
        "--reference-spp",
        "512",
        "--pt-max-spp",
        "64",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    if !extra.contains(&"--seed") {
        args.extend_from_slice(&["--seed", "7"]);
    }
    let result = lfr(&args);
    assert!(result.status.success(), "lfr compare failed: {}", String::from_utf8_lossy(&result.stderr));
    serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap()
}

fn runs<'a>(results: &'a Value, method: &str) -> Vec<&'a Value> {
    results["runs"].as_array().unwrap().iter().filter(|r| r["method"] == method).collect()
}

fn number(value: &Value) -> f64 {
    value.as_f64().unwrap_or_else(|| panic!("not a number: {value}"))
}

fn check_schema(results: &Value) {
    let schema: Value =
        serde_json::from_slice(&std::fs::read(project_root().join("docs/compare.schema.json")).unwrap()).unwrap();
    let validator = jsonschema::validator_for(&schema).expect("the schema is valid JSON Schema");
    let errors: Vec<String> = validator.iter_errors(results).map(|e| format!("{} at {}", e, e.instance_path)).collect();
    assert!(errors.is_empty(), "results.json violates docs/compare.schema.json:\n{}", errors.join("\n"));
}

#[test]
fn tiny_compare_follows_the_schema_and_path_tracing_error_falls() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    let results = tiny_compare(&out, &cache, &["--methods", "box,oidn"]);
    check_schema(&results);

    // The schema check itself must be able to fail.
    let mut broken = results.clone();
    broken["runs"][0]["psnr_db"] = Value::String("high".into());
    let schema: Value =
        serde_json::from_slice(&std::fs::read(project_root().join("docs/compare.schema.json")).unwrap()).unwrap();
    assert!(!jsonschema::is_valid(&schema, &broken));

    // The ladder: 1, 2, 4, ..., 64 spp; error falls as spp grows (steps of 4x: ~6 dB each).
    let pt = runs(&results, "pt");
    let spp: Vec<u64> = pt.iter().map(|r| r["input_spp"].as_u64().unwrap()).collect();
    assert_eq!(spp, vec![1, 2, 4, 8, 16, 32, 64]);
    for pair in [(0, 2), (2, 4), (4, 6)] {
        let (low, high) = (pt[pair.0], pt[pair.1]);
        assert!(number(&high["psnr_db"]) > number(&low["psnr_db"]) + 3.0, "PSNR must rise: {low} → {high}");
        assert!(number(&high["rel_mse"]) < number(&low["rel_mse"]), "rel. MSE must fall: {low} → {high}");
        assert!(number(&high["ssim"]) > number(&low["ssim"]));
    }

    // `box` is path tracing at the input spp read back from the sample file: same error up to noise.
    for run in runs(&results, "box") {
        let n = run["input_spp"].as_u64().unwrap();
        let twin = pt.iter().find(|r| r["input_spp"].as_u64() == Some(n)).unwrap();
        let difference = number(&run["psnr_db"]) - number(&twin["psnr_db"]);
        assert!(difference.abs() < 1.5, "box at {n} spp differs from path tracing by {difference} dB");
        assert!(run["speedup"].is_number() && run["equal_time_psnr_gain_db"].is_number());
    }
    // The reference is better than every run it judges.
    let reference_psnr = number(&results["reference"]["estimated_psnr_db"]);
    assert!(reference_psnr > number(&pt.last().unwrap()["psnr_db"]) + 3.0);

    // Every file the results name exists; the report embeds the plot and states a verdict.
    for run in results["runs"].as_array().unwrap() {
        for key in ["image", "preview", "error_map"] {
            let path = out.join(run[key].as_str().unwrap());
            assert!(path.is_file(), "missing {}", path.display());
        }
    }
    for file in
        ["report.md", "error-vs-time.png", "error-vs-time.svg", "images/reference.exr", "images/error-scale.png"]
    {
        assert!(out.join(file).is_file(), "missing {file}");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("## Verdict") && report.contains("![PSNR against time](error-vs-time.png)"));
    assert!(report.contains("**box**"));
    assert!(!out.join("inputs").exists(), "input samples are removed unless --keep-samples");

    // Repeated timings: these runs are short, so each is timed three times (the default), and a
    // run's time is its median repetition.
    for run in results["runs"].as_array().unwrap() {
        let timings: Vec<f64> = run["timings"].as_array().unwrap().iter().map(number).collect();
        assert_eq!(timings.len(), 3, "{run}");
        let mut sorted = timings.clone();
        sorted.sort_by(f64::total_cmp);
        assert_eq!(number(&run["total_s"]), sorted[1], "the median repetition: {run}");
        let spread = (sorted[2] - sorted[0]) / sorted[1];
        assert!((number(&run["timing_spread"]) - spread).abs() <= 1e-9 * spread.max(1.0), "{run}");
        let parts = number(&run["trace_s"]) + number(&run["preprocess_s"]) + number(&run["recon_s"]);
        assert!((parts - number(&run["total_s"])).abs() < 1e-9, "the parts are the median repetition's: {run}");
        if run["method"] != "pt" {
            let [lo, hi] = [0, 1].map(|i| number(&run["speedup_range"][i]));
            assert!(lo <= number(&run["speedup"]) && number(&run["speedup"]) <= hi, "{run}");
            // No repetition gave another image (the warning note says so when one does).
            assert!(!run["notes"].to_string().contains("not deterministic"), "{run}");
        }
    }
    for verdict in results["verdicts"].as_array().unwrap() {
        let difference = verdict["difference"].as_str().unwrap();
        let [lo, hi] = [0, 1].map(|i| number(&verdict["best_speedup_range"][i]));
        // Within `between_runs_noise` of 1 (either way) is no clear difference too.
        let noise = number(&results["between_runs_noise"]);
        let speedup = number(&verdict["best_speedup"]);
        let expected = if (lo <= 1.0 && 1.0 <= hi) || (speedup <= 1.0 + noise && speedup * (1.0 + noise) >= 1.0) {
            "no clear difference"
        } else if number(&verdict["best_speedup"]) >= 1.0 {
            "faster"
        } else {
            "slower"
        };
        assert_eq!(difference, expected, "{verdict}");
        assert_eq!(
            verdict["summary"].as_str().unwrap().contains("no clear difference"),
            expected == "no clear difference"
        );
    }

    // OIDN: run when pyoidn is installed, otherwise skipped with a reason.
    let oidn = runs(&results, "oidn");
    let skipped = results["skipped"].as_array().unwrap();
    if oidn.is_empty() {
        assert!(skipped.iter().any(|s| s["method"] == "oidn" && s["reason"].as_str().unwrap().contains("pyoidn")));
        testkit::skip("pyoidn is not installed, so oidn's runs were not checked");
    } else {
        // The denoiser reads the path-traced frame, so it runs on every rung of the ladder
        // (Plan::spp_of): its spp are path tracing's.
        let spp = |runs: &[&Value]| runs.iter().map(|r| r["input_spp"].as_u64().unwrap()).collect::<Vec<_>>();
        assert_eq!(spp(&oidn), spp(&pt));
        // The denoiser must beat its own noisy input (path tracing at the same spp).
        for run in oidn {
            let n = run["input_spp"].as_u64().unwrap();
            let twin = pt.iter().find(|r| r["input_spp"].as_u64() == Some(n)).unwrap();
            assert!(number(&run["psnr_db"]) > number(&twin["psnr_db"]) + 2.0, "{run}");
        }
    }
}

#[test]
fn the_ladder_holds_every_input_spp_and_a_rerun_replaces_the_previous_output() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    // Whatever the methods, the ladder holds the input spp (3 is not a power of two).
    let first = tiny_compare(&out, &cache, &["--methods", "gif", "--spp", "3", "--repeats", "1"]);
    let spp: Vec<u64> = runs(&first, "pt").iter().map(|r| r["input_spp"].as_u64().unwrap()).collect();
    assert_eq!(spp, vec![1, 2, 3, 4, 8, 16, 32, 64]);
    assert!(runs(&first, "pt").iter().all(|r| r["timings"].as_array().unwrap().len() == 1));
    let gif_images = |dir: &Path| {
        std::fs::read_dir(dir.join("images"))
            .unwrap()
            .filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with("gif"))
            .count()
    };
    assert!(gif_images(&out) > 0);
    // A rerun with other methods leaves no image of the previous run behind.
    let second = tiny_compare(&out, &cache, &["--methods", "box", "--spp", "1", "--repeats", "1"]);
    assert!(runs(&second, "gif").is_empty());
    assert_eq!(gif_images(&out), 0, "the previous run's images are removed");
    // A folder holding other files is refused before any work, and nothing in it is touched.
    std::fs::write(out.join("thesis.tex"), b"mine").unwrap();
    let refused = lfr(&[
        "compare",
        "--effect",
        "indirect",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(!refused.status.success());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(stderr.contains("thesis.tex") && stderr.contains("--force"), "{stderr}");
    assert!(out.join("results.json").is_file() && out.join("thesis.tex").is_file());
}

#[test]
fn a_seed_reproduces_every_number_and_the_reference_is_cached() {
    let dir = tempfile::tempdir().unwrap();
    let first_cache = dir.path().join("cache-1");
    let first = tiny_compare(&dir.path().join("a"), &first_cache, &["--methods", "box"]);
    let cached = tiny_compare(&dir.path().join("b"), &first_cache, &["--methods", "box"]);
    let fresh = tiny_compare(&dir.path().join("c"), &dir.path().join("cache-2"), &["--methods", "box"]);
    assert_eq!(first["reference"]["from_cache"], false);
    assert_eq!(cached["reference"]["from_cache"], true);
    assert_eq!(fresh["reference"]["from_cache"], false);
    assert_eq!(first["reference"]["cache_key"], fresh["reference"]["cache_key"]);
    assert_eq!(first["reference"]["seconds"], cached["reference"]["seconds"], "the cache records the original time");
    for other in [&cached, &fresh] {
        let (a, b) = (first["runs"].as_array().unwrap(), other["runs"].as_array().unwrap());
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            for key in ["method", "input_spp", "recon_rays", "psnr_db", "rel_mse", "ssim", "flip", "nonfinite_pixels"] {
                assert_eq!(x[key], y[key], "{key} differs between runs with the same seed");
            }
        }
        assert_eq!(first["tone_map"], other["tone_map"]);
    }
    // Another seed gives other numbers (the comparison does depend on it).
    let other_seed = tiny_compare(&dir.path().join("d"), &first_cache, &["--methods", "box", "--seed", "8"]);
    assert_ne!(first["runs"][0]["psnr_db"], other_seed["runs"][0]["psnr_db"]);
}

#[test]
fn an_all_black_reference_scores_as_documented() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("dark.toml");
    // A box and a floor, no light at all: every layer is black.
    std::fs::write(
        &scene,
        "[render]\nmax_bounces = 4\n[camera]\nposition = [0, 1, 4]\nlook_at = [0, 0, 0]\nfov = 40\n\
         [[material]]\nname = \"grey\"\nbase_color = [0.5, 0.5, 0.5]\n\
         [[mesh]]\nshape = \"polygon\"\nmaterial = \"grey\"\npoints = [[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]]\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let result = lfr(&[
        "compare",
        "--scene",
        scene.to_str().unwrap(),
        "--effect",
        "indirect",
        "--width",
        "8",
        "--height",
        "8",
        "--spp",
        "1",
        "--reference-spp",
        "8",
        "--pt-max-spp",
        "2",
        "--methods",
        "box",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        dir.path().join("cache").to_str().unwrap(),
    ]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let results: Value = serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    check_schema(&results);
    assert_eq!(results["tone_map"]["exposure"], 1.0, "an all-black reference keeps exposure 1");
    for run in results["runs"].as_array().unwrap() {
        assert_eq!(number(&run["psnr_db"]), 100.0, "identical black images score the 100 dB ceiling: {run}");
        assert_eq!(number(&run["rel_mse"]), 0.0);
        assert_eq!(number(&run["ssim"]), 1.0);
    }
}

#[test]
fn bad_input_fails_cleanly_without_results() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let out_arg = out.to_str().unwrap();
    let cases: &[(&[&str], &[&str])] = &[
        (&["--effect", "bokeh"], &["bokeh", "indirect", "soft-shadow"]),
        (&["--effect", "dof"], &["aperture"]),
        (&["--effect", "motion"], &["motion"]),
        (&["--effect", "indirect", "--methods", "box,magic"], &["magic", "known"]),
        (&["--effect", "indirect", "--spp", "0"], &["--spp"]),
        (&["--effect", "indirect", "--max-bounces", "1"], &["bounces"]),
        (&["--effect", "glossy"], &["glossy"]),
        (&["--effect", "ao", "--ao-radius=-1"], &["--ao-radius"]),
        (&["--effect", "ao", "--ao-radius", "NaN"], &["--ao-radius"]),
        (&["--effect", "indirect", "--exposure", "0"], &["--exposure"]),
        (&["--effect", "dof", "--aperture-radius=-0.1"], &["--aperture-radius"]),
        (&["--effect", "dof", "--aperture-radius", "inf"], &["--aperture-radius"]),
        (&["--effect", "dof", "--aperture-radius", "0.1", "--focus-distance", "0"], &["--focus-distance"]),
        (&["--effect", "indirect", "--scene", "does/not/exist.toml"], &["does/not/exist.toml"]),
        (&["--effect", "indirect", "--reference-spp", "3"], &["--reference-spp", "even"]),
        (&["--effect", "indirect", "--threads", "100000"], &["--threads", "1024"]),
        (&["--effect", "indirect", "--methods", "gif:radius=0"], &["`gif:radius=0`", "at least 1"]),
        (&["--effect", "indirect", "--reference-check", "0"], &["--reference-check", "`off` or a whole number"]),
        (&["--effect", "indirect", "--reference-check", "lots"], &["--reference-check", "1..=64"]),
    ];
    for (extra, needles) in cases {
        let mut args = vec!["compare", "--out", out_arg, "--quiet", "--width", "8", "--height", "8"];
        args.extend_from_slice(extra);
        let result = lfr(&args);
        let message = String::from_utf8_lossy(&result.stderr);
        assert!(!result.status.success(), "{extra:?} should fail");
        assert!(!message.contains("panicked"), "{extra:?} panicked: {message}");
        for needle in *needles {
            assert!(message.contains(needle), "{extra:?}: the error should mention {needle:?}: {message}");
        }
        assert!(!out.join("results.json").exists(), "{extra:?} left results behind");
    }
}

/// Every effect runs, and `box` (the samples read back through `sampleio`) scores what path
/// tracing scores at the same spp: exactly for the effects whose samples are the render's own
/// camera samples (ao, the lens-time effects), and within 0.01 dB for the indirect ones, whose
/// secondary rays continue the camera paths with the same random numbers but store the weight
/// or albedo at o as f16. (Their paths are the camera paths' only up to three bounces, where
/// Russian roulette has not begun: beyond, the secondary path's roulette weighs its own
/// throughput; docs/sample-format.md.)
#[test]
fn every_effect_runs_and_box_matches_path_tracing() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("ao", "scenes/cornell.toml", true),
        ("soft-shadow", "scenes/cornell.toml", true),
        ("dof", "scenes/monkeys-defocus-motion.toml", true),
        ("motion", "scenes/monkeys-defocus-motion.toml", true),
        ("dof-motion", "scenes/monkeys-defocus-motion.toml", true),
        ("indirect", "scenes/cornell.toml", false),
        ("glossy", "scenes/monkeys.toml", false),
    ];
    for (effect, scene, exact) in cases {
        let out = dir.path().join(effect);
        let cache = dir.path().join("cache");
        let mut args = vec![
            "compare",
            "--effect",
            effect,
            "--scene",
            scene,
            "--width",
            "16",
            "--height",
            "12",
            "--spp",
            "2",
            "--reference-spp",
            "32",
            "--pt-max-spp",
            "2",
            "--methods",
            "box",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
            "--cache-dir",
            cache.to_str().unwrap(),
        ];
        if !exact {
            args.extend(["--max-bounces", "3"]);
        }
        let result = lfr(&args);
        assert!(result.status.success(), "{effect}: {}", String::from_utf8_lossy(&result.stderr));
        let results: Value = serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
        check_schema(&results);
        let psnr_of = |method: &str| {
            let run = runs(&results, method).into_iter().find(|r| r["input_spp"] == 2).unwrap().clone();
            number(&run["psnr_db"])
        };
        let (pt, boxed) = (psnr_of("pt"), psnr_of("box"));
        if exact {
            assert_eq!(pt, boxed, "{effect}: box must reproduce path tracing at equal spp");
        } else {
            assert!((pt - boxed).abs() < 0.01, "{effect}: box {boxed} dB vs path tracing {pt} dB");
        }
    }
}

/// The filters of the guided-filtering pipeline run through the harness on guide buffers and
/// beat the unfiltered input at equal spp; effects they do not handle are refused.
#[test]
fn guide_filters_run_and_beat_the_unfiltered_input() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let tuned = "gif:radius=6:eps_normal=0.001:eps_depth=0.001";
    let methods = format!("box,gif,bilateral,atrous,atrous-sn,{tuned}");
    let results = tiny_compare(&out, &dir.path().join("cache"), &["--methods", &methods]);
    check_schema(&results);
    assert!(out.join("images/gif_radius-6_eps_normal-0.001_eps_depth-0.001-1spp.png").is_file());
    for method in ["gif", "bilateral", "atrous", "atrous-sn", tuned] {
        for run in runs(&results, method) {
            let n = run["input_spp"].as_u64().unwrap();
            let unfiltered = runs(&results, "box").into_iter().find(|r| r["input_spp"].as_u64() == Some(n)).unwrap();
            assert!(
                number(&run["psnr_db"]) > number(&unfiltered["psnr_db"]) + 3.0,
                "{method} at {n} spp: {} dB vs unfiltered {} dB",
                run["psnr_db"],
                unfiltered["psnr_db"]
            );
            assert!(run["valid"].as_bool().unwrap());
        }
    }
    let refused = lfr(&["compare", "--effect", "ao", "--methods", "gif", "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("gif does not handle --effect ao"));
}

/// Without pyoidn (here: no Python at all) `oidn` is skipped with a printed notice and a reason
/// in results.json, and the rest of the comparison still runs.
#[test]
fn a_missing_denoiser_is_skipped_with_a_notice() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let result = Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(["compare", "--effect", "indirect", "--width", "8", "--height", "8", "--spp", "1"])
        .args(["--reference-spp", "8", "--pt-max-spp", "2", "--methods", "box,oidn", "--quiet"])
        .args(["--out", out.to_str().unwrap(), "--cache-dir", dir.path().join("cache").to_str().unwrap()])
        .current_dir(project_root())
        .env("LFR_PYTHON", "/nonexistent/python3")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(result.status.success(), "{stderr}");
    assert!(stderr.contains("skipping oidn"), "{stderr}");
    let results: Value = serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    check_schema(&results);
    assert!(runs(&results, "oidn").is_empty());
    assert_eq!(results["skipped"][0]["method"], "oidn");
    assert!(!runs(&results, "box").is_empty());
}

/// A cached reference is used only when its record matches the comparison
/// and its image matches the record's checksum; a poisoned one is traced again, with a warning.
#[test]
fn a_poisoned_reference_cache_is_traced_again() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let first = tiny_compare(&dir.path().join("a"), &cache, &["--methods", "box"]);
    assert_eq!(first["reference"]["from_cache"], false);
    let key = first["reference"]["cache_key"].as_str().unwrap().to_string();
    let (json, exr) = (cache.join(format!("{key}.json")), cache.join(format!("{key}.exr")));
    // An edited record: a negative time and another spp.
    let record = std::fs::read_to_string(&json).unwrap();
    std::fs::write(&json, record.replace("\"spp\": 512", "\"spp\": 999999")).unwrap();
    let edited = tiny_compare(&dir.path().join("b"), &cache, &["--methods", "box"]);
    assert_eq!(edited["reference"]["from_cache"], false, "an edited record is not trusted");
    assert_eq!(edited["reference"]["spp"], 512);
    // The record was written anew: the next run uses the cache again.
    let again = tiny_compare(&dir.path().join("c"), &cache, &["--methods", "box"]);
    assert_eq!(again["reference"]["from_cache"], true);
    // A damaged image (one byte changed) fails its checksum.
    let mut bytes = std::fs::read(&exr).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x55;
    std::fs::write(&exr, bytes).unwrap();
    let damaged = tiny_compare(&dir.path().join("d"), &cache, &["--methods", "box"]);
    assert_eq!(damaged["reference"]["from_cache"], false, "a damaged image is not trusted");
    for (x, y) in first["runs"].as_array().unwrap().iter().zip(damaged["runs"].as_array().unwrap()) {
        assert_eq!(x["psnr_db"], y["psnr_db"], "the same reference once traced again");
    }
    // The reference's check, cached beside it: used again, and traced again (to the same
    // estimate) once its record is edited.
    assert_eq!(
        (first["reference"]["check"]["from_cache"].clone(), again["reference"]["check"]["from_cache"].clone()),
        (false.into(), true.into())
    );
    let check = std::fs::read_dir(&cache)
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .find(|path| path.to_string_lossy().ends_with(".check.json"))
        .expect("the check is cached");
    let record = std::fs::read_to_string(&check).unwrap();
    assert!(record.contains("\"seconds\":"));
    std::fs::write(&check, record.replacen("\"seconds\":", "\"seconds\":-", 1)).unwrap();
    let rechecked = tiny_compare(&dir.path().join("e"), &cache, &["--methods", "box"]);
    assert_eq!(rechecked["reference"]["check"]["from_cache"], false, "an edited check is not trusted");
    assert_eq!(rechecked["reference"]["estimated_psnr_db"], first["reference"]["estimated_psnr_db"]);
}

/// ILFR runs carry their statistics as named numbers, consistent with the
/// run: the paper's gather shoots `recon_rays` rays per pixel whose primary hit it gathers (in
/// the Cornell box all but the lamp's pixels, a few percent); each splat is one input sample
/// that hit; fractions are fractions. The default's sparse grid and the full gather's records
/// count themselves. Other methods have an empty `stats` object.
#[test]
fn ilfr_runs_report_their_statistics_as_named_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let results = tiny_compare(
        &dir.path().join("out"),
        &dir.path().join("cache"),
        &["--methods", "box,ilfr:variant=paper,ilfr,ilfr:gather=full", "--recon-rays", "8"],
    );
    check_schema(&results);
    assert!(!runs(&results, "ilfr").is_empty() && !runs(&results, "ilfr:variant=paper").is_empty());
    for run in runs(&results, "ilfr") {
        let stats = &run["stats"];
        let (grid, refined) = (number(&stats["sparse_grid_fraction"]), number(&stats["sparse_refined_fraction"]));
        assert!(grid > 0.0 && grid + refined <= 1.0 && number(&stats["rays"]) > 0.0, "{stats}");
        assert_eq!(number(&stats["cache_records"]), 0.0, "{stats}");
    }
    assert!(!runs(&results, "ilfr:gather=full").is_empty());
    for run in runs(&results, "ilfr:gather=full") {
        let stats = &run["stats"];
        assert!(number(&stats["cache_records"]) >= 1.0 && number(&stats["rays"]) > 0.0, "{stats}");
        assert_eq!(number(&stats["sparse_grid_fraction"]), 0.0, "{stats}");
    }
    for run in runs(&results, "ilfr:variant=paper") {
        let stats = &run["stats"];
        let spp = number(&run["input_spp"]);
        let rays = number(&stats["rays"]);
        assert!(rays % (8.0 / spp) == 0.0 && (0.9 * 8192.0..=8192.0).contains(&rays), "{stats}");
        let splats = number(&stats["splats"]);
        assert!(splats > 0.0 && splats <= 32.0 * 32.0 * spp, "{stats}");
        for fraction in ["merged_fraction", "shrunk_fraction", "no_surface_fraction", "glossy_fraction"] {
            assert!((0.0..=1.0).contains(&number(&stats[fraction])), "{fraction}: {stats}");
        }
        assert!(number(&stats["nodes_per_ray"]) >= 1.0, "{stats}");
        assert!(number(&stats["gather_s"]) > 0.0 && number(&stats["gather_s"]) <= number(&run["recon_s"]), "{stats}");
    }
    for run in runs(&results, "box") {
        assert_eq!(run["stats"].as_object().map(|o| o.len()), Some(0), "{run}");
    }
}

#[test]
fn an_external_reference_rendered_as_shards_gives_the_same_comparison() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let own = tiny_compare(&dir.path().join("own"), &cache, &["--methods", "box", "--repeats", "1"]);
    let seeds: Vec<u64> = own["reference"]["seeds"].as_array().unwrap().iter().map(|s| s.as_u64().unwrap()).collect();
    // The same two halves rendered elsewhere: half A whole, half B as three shards merged.
    let render = |out: &Path, seed: u64, extra: &[&str]| {
        let seed = seed.to_string();
        let mut args = vec!["render", "--width", "32", "--height", "32", "--spp", "256", "--seed", &seed, "--quiet"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        let result = lfr(&args);
        assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    };
    let half_a = dir.path().join("half-a.exr");
    render(&half_a, seeds[0], &[]);
    let shards: Vec<PathBuf> = (0..3).map(|i| dir.path().join(format!("b{i}.exr"))).collect();
    for (i, shard) in shards.iter().enumerate() {
        render(shard, seeds[1], &["--shard", &format!("{i}/3")]);
    }
    let half_b = dir.path().join("half-b.exr");
    let mut merge = vec!["merge".to_string(), "--out".into(), half_b.to_str().unwrap().into()];
    merge.extend(shards.iter().map(|s| s.to_str().unwrap().to_string()));
    assert!(lfr(&merge.iter().map(String::as_str).collect::<Vec<_>>()).status.success());

    let both = format!("{},{}", half_a.display(), half_b.display());
    let external =
        tiny_compare(&dir.path().join("ext"), &cache, &["--methods", "box", "--repeats", "1", "--reference", &both]);
    check_schema(&external);
    assert_eq!(external["reference"]["external"].as_array().unwrap().len(), 2);
    assert_eq!(external["reference"]["seeds"], own["reference"]["seeds"]);
    assert_eq!(external["reference"]["spp"], own["reference"]["spp"]);
    assert_eq!(external["reference"]["estimated_psnr_db"], own["reference"]["estimated_psnr_db"]);
    for (a, b) in own["runs"].as_array().unwrap().iter().zip(external["runs"].as_array().unwrap()) {
        for key in ["method", "input_spp", "psnr_db", "rel_mse", "ssim"] {
            assert_eq!(a[key], b[key], "{key}: the external reference is the same image");
        }
    }
    // One image: no halves, so no estimate from them.
    let one = tiny_compare(
        &dir.path().join("one"),
        &cache,
        &["--methods", "box", "--repeats", "1", "--reference", half_a.to_str().unwrap()],
    );
    check_schema(&one);
    assert!(one["reference"]["halves_psnr_db"].is_null());
    // A reference rendered elsewhere may be too expensive to check here: `--reference-check off`
    // leaves the halves' estimate (none for one image), `1` checks at its own spp.
    let unchecked = tiny_compare(
        &dir.path().join("off"),
        &cache,
        &["--methods", "box", "--repeats", "1", "--reference", &both, "--reference-check", "off"],
    );
    check_schema(&unchecked);
    assert!(unchecked["reference"]["check"].is_null());
    assert_eq!(unchecked["reference"]["estimated_psnr_db"], own["reference"]["halves_psnr_db"]);
    let one_unchecked = tiny_compare(
        &dir.path().join("one-off"),
        &cache,
        &["--methods", "box", "--repeats", "1", "--reference", half_a.to_str().unwrap(), "--reference-check", "off"],
    );
    check_schema(&one_unchecked);
    assert!(one_unchecked["reference"]["estimated_psnr_db"].is_null());
    let cheap = tiny_compare(
        &dir.path().join("cheap"),
        &cache,
        &["--methods", "box", "--repeats", "1", "--reference", &both, "--reference-check", "1"],
    );
    assert_eq!(cheap["reference"]["check"]["spp"], cheap["reference"]["spp"]);
    assert_eq!(own["reference"]["check"]["spp"].as_u64(), own["reference"]["spp"].as_u64().map(|spp| 4 * spp));
    // The check measures its error all the same: one half has half the samples, so its squared
    // error is about twice the two halves' mean's (−3 dB; the tiny image leaves ±1.5 dB).
    let one_db = number(&one["reference"]["estimated_psnr_db"]);
    let own_db = number(&own["reference"]["estimated_psnr_db"]);
    assert!((own_db - one_db - 3.0).abs() < 1.5, "one half {one_db:.2} dB, both {own_db:.2} dB");

    // Refused, naming the file, before anything is written: a shard, the comparison's own seed,
    // another path length, another size, the same seed twice.
    let refuse = |reference: &str, extra: &[&str], expected: &str| {
        let out = dir.path().join("refused");
        let mut args = vec!["compare", "--effect", "indirect", "--width", "32", "--height", "32", "--seed", "7"];
        args.extend_from_slice(&["--reference", reference, "--out", out.to_str().unwrap(), "--quiet"]);
        args.extend_from_slice(extra);
        let result = lfr(&args);
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert!(!result.status.success() && stderr.contains(expected), "{reference}: {stderr}");
        assert!(!out.exists(), "nothing written");
    };
    refuse(shards[0].to_str().unwrap(), &[], "shard 0/3 only");
    let own_seed = dir.path().join("seed7.exr");
    render(&own_seed, 7, &[]);
    refuse(own_seed.to_str().unwrap(), &[], "the comparison's own");
    refuse(half_a.to_str().unwrap(), &["--max-bounces", "2"], "bounces");
    refuse(&format!("{0},{0}", half_a.display()), &[], "same samples");
    let wide = dir.path().join("wide.exr");
    let result = lfr(&[
        "render",
        "--width",
        "33",
        "--height",
        "32",
        "--spp",
        "1",
        "--seed",
        "3",
        "--quiet",
        "--out",
        wide.to_str().unwrap(),
    ]);
    assert!(result.status.success());
    refuse(wide.to_str().unwrap(), &[], "33x32");
}

/// Reads an EXR's channels (name → values).
fn exr_channels(path: &Path) -> std::collections::HashMap<String, Vec<f32>> {
    let (_, _, channels) = tracer::output::read_exr(path).unwrap();
    channels.into_iter().collect()
}

/// Pipelines run through the harness: `ilfr+oidn`, `gif+oidn` and `box+oidn` on indirect light, their time
/// the sum of their stages with the denoiser's in the stats; every run read against OIDN's
/// curve, a verdict per method against it, and a headline naming a winner; OIDN's ambient
/// occlusion (alone and as a pipeline's last stage) a grey visibility in [0, 1]; `tlfr+oidn` on
/// depth of field reads the auxiliary fields of its own samples.
#[test]
fn pipelines_run_with_verdicts_against_oidn_and_a_headline() {
    if recon::registry::find("oidn").unwrap().unwrap().available().is_err() {
        testkit::skip("pyoidn is not installed: the pipelines' denoiser cannot run");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    let results = tiny_compare(
        &out,
        &cache,
        &["--methods", "box+oidn,gif+oidn,ilfr+oidn:quality=fast,oidn", "--recon-rays", "4", "--repeats", "1"],
    );
    check_schema(&results);
    // A filter of guide buffers then OIDN: the guide's auxiliaries, the denoiser's time in the sum.
    let guided = runs(&results, "gif+oidn");
    assert_eq!(guided.len(), 2, "one run per input spp");
    for run in guided {
        let parts = number(&run["trace_s"]) + number(&run["preprocess_s"]) + number(&run["recon_s"]);
        assert!((number(&run["total_s"]) - parts).abs() < 1e-9, "{run}");
        assert!(number(&run["stats"]["pipeline_denoise_s"]) > 0.0 && run["oidn_curve_position"].is_string(), "{run}");
    }
    let pipeline = runs(&results, "ilfr+oidn:quality=fast");
    assert_eq!(pipeline.len(), 2, "one run per input spp");
    for run in &pipeline {
        let parts = number(&run["trace_s"]) + number(&run["preprocess_s"]) + number(&run["recon_s"]);
        assert!((number(&run["total_s"]) - parts).abs() < 1e-9, "{run}");
        let stats = &run["stats"];
        assert!(number(&stats["pipeline_denoise_s"]) > 0.0 && number(&stats["gather_s"]) > 0.0, "{stats}");
        assert!(number(&run["recon_s"]) >= number(&stats["pipeline_denoise_s"]), "the denoiser's time is in recon_s");
        assert!(run["oidn_curve_position"].is_string(), "read against OIDN: {run}");
    }
    // Denoising the box average of the same samples beats the box average at equal spp.
    let box_oidn = runs(&results, "box+oidn").into_iter().find(|r| r["input_spp"] == 4).unwrap();
    let pt4 = runs(&results, "pt").into_iter().find(|r| r["input_spp"] == 4).unwrap();
    assert!(number(&box_oidn["psnr_db"]) > number(&pt4["psnr_db"]) + 3.0, "{box_oidn} vs {pt4}");
    let peer: Vec<&str> =
        results["verdicts_against_oidn"].as_array().unwrap().iter().map(|v| v["method"].as_str().unwrap()).collect();
    assert_eq!(peer, ["pt", "box+oidn", "gif+oidn", "ilfr+oidn:quality=fast"]);
    assert!(runs(&results, "oidn").iter().all(|r| r["oidn_curve_position"].is_null()));
    let headline = results["headline"].as_str().unwrap();
    assert!(headline.starts_with("Winner by PSNR at each time budget"), "{headline}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains(headline) && report.contains("against OIDN:") && report.contains("vs OIDN"));

    // Ambient occlusion: OIDN's output, alone or after box, is grey and within [0, 1].
    let ao_out = dir.path().join("ao");
    let mut args = vec!["--methods", "oidn,box+oidn", "--repeats", "1", "--effect", "ao"];
    args.extend(["--scene", "scenes/cornell.toml"]);
    let ao = {
        let mut all = vec![
            "compare",
            "--width",
            "16",
            "--height",
            "16",
            "--spp",
            "2",
            "--reference-spp",
            "32",
            "--pt-max-spp",
            "2",
            "--quiet",
            "--out",
            ao_out.to_str().unwrap(),
            "--cache-dir",
            cache.to_str().unwrap(),
        ];
        all.extend(args.iter());
        let result = lfr(&all);
        assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
        serde_json::from_slice::<Value>(&std::fs::read(ao_out.join("results.json")).unwrap()).unwrap()
    };
    for method in ["oidn", "box+oidn"] {
        let run = runs(&ao, method)[0];
        let channels = exr_channels(&ao_out.join(run["image"].as_str().unwrap()));
        let (r, g, b) = (&channels["ao.R"], &channels["ao.G"], &channels["ao.B"]);
        for i in 0..r.len() {
            assert!(r[i] == g[i] && g[i] == b[i], "{method}: pixel {i} is coloured");
            assert!((0.0..=1.0).contains(&r[i]), "{method}: pixel {i} = {}", r[i]);
        }
    }

    // Depth of field: tlfr+oidn runs on lens-time samples that carry albedo and normal.
    let dof_out = dir.path().join("dof");
    let result = lfr(&[
        "compare",
        "--effect",
        "dof",
        "--scene",
        "scenes/monkeys-defocus-motion.toml",
        "--width",
        "24",
        "--height",
        "16",
        "--spp",
        "4",
        "--reference-spp",
        "32",
        "--pt-max-spp",
        "4",
        "--methods",
        "tlfr+oidn,tlfr:gi=whole",
        "--recon-rays",
        "4",
        "--repeats",
        "1",
        "--quiet",
        "--keep-samples",
        "--out",
        dof_out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let dof: Value = serde_json::from_slice(&std::fs::read(dof_out.join("results.json")).unwrap()).unwrap();
    check_schema(&dof);
    assert_eq!(runs(&dof, "tlfr+oidn").len(), 1);
    let with_aux = std::fs::read_dir(dof_out.join("inputs"))
        .unwrap()
        .flatten()
        .filter_map(|e| sampleio::SampleFile::open(e.path()).ok())
        .filter(|f| f.field("albedo").is_some() && f.field("normal").is_some())
        .count();
    assert_eq!(with_aux, 1, "only the pipeline's input carries the auxiliary fields");
}

/// The per-run lines printed during a comparison show each run's first timing while the
/// verdicts use the median of the repetitions: with repetitions, the output says so.
#[test]
fn the_printed_run_lines_say_they_are_first_timings() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    let (out, cache) = (out.to_str().unwrap(), cache.to_str().unwrap());
    let size = ["--width", "8", "--height", "8", "--spp", "1", "--reference-spp", "8", "--pt-max-spp", "2"];
    let mut args = vec!["compare", "--effect", "indirect", "--methods", "box", "--out", out, "--cache-dir", cache];
    args.extend_from_slice(&size);
    args.extend_from_slice(&["--repeats", "2"]);
    let result = lfr(&args);
    let text = String::from_utf8_lossy(&result.stderr);
    assert!(result.status.success(), "{text}");
    assert!(text.contains("the lines above show each run's first timing"), "{text}");
    assert!(text.contains("use the median of up to 2 repetitions"), "{text}");
}
