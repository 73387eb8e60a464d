//! `lfr probes stats` (issue 25, phase 3): bad parameters are refused with an error naming the
//! field before the scene is read, and a small run on the embedded Cornell box reports a
//! placement whose numbers agree with each other.

#[path = "common/cli.rs"]
mod cli;
#[path = "../tracer/tests/common/mod.rs"]
mod common;

use cli::lfr;

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
