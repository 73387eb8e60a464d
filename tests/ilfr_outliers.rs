//! "Fireflies pass through": ILFR's error must not grow as its input grows on a scene
//! whose sample radiance has outliers (the Cornell box's indirect light: rare paths that reach
//! the small ceiling light after a bounce or two), judged against a traced reference of many
//! more samples. With one gather set per primary hit and no robust splat radiance, this
//! very comparison gave a relative MSE of 2.999e-3 at 4 spp and 3.109e-3 at 16 spp; with them
//! 2.606e-3 and 1.676e-3 (docs/history/ilfr.md, the section on the error that grew with the input).

use crate::lfr_runner as cli;

use cli::lfr;
use serde_json::Value;

fn number(value: &Value) -> f64 {
    value.as_f64().unwrap_or_else(|| panic!("not a number: {value}"))
}

/// (input spp, PSNR, relative MSE, outlier fraction) of every run of `method`.
fn runs(results: &Value, method: &str) -> Vec<(u64, f64, f64, f64)> {
    results["runs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["method"] == method)
        .map(|r| {
            let outliers = r["stats"]["outlier_fraction"].as_f64().unwrap_or(0.0);
            (r["input_spp"].as_u64().unwrap(), number(&r["psnr_db"]), number(&r["rel_mse"]), outliers)
        })
        .collect()
}

#[test]
fn ilfr_error_does_not_grow_with_the_input_on_a_scene_with_outliers() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    let args = [
        "compare",
        "--scene",
        "scenes/cornell.toml",
        "--effect",
        "indirect",
        "--width",
        "48",
        "--height",
        "48",
        "--spp",
        "4,16",
        "--recon-rays",
        "64",
        "--methods",
        "ilfr:variant=paper,ilfr:variant=paper:robust=off,ilfr",
        "--reference-spp",
        "2048",
        "--pt-max-spp",
        "1",
        "--repeats",
        "1",
        "--seed",
        "3",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ];
    let result = lfr(&args);
    assert!(result.status.success(), "lfr compare failed: {}", String::from_utf8_lossy(&result.stderr));
    let results: Value = serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();

    // The test above is the paper's gather (one gather set per primary hit); the default gather (sparse)
    // must not grow its error with the input either.
    let robust = runs(&results, "ilfr:variant=paper");
    let plain = runs(&results, "ilfr:variant=paper:robust=off");
    let default = runs(&results, "ilfr");
    assert_eq!(robust.len(), 2);
    assert_eq!(plain.len(), 2);
    assert_eq!(default.len(), 2);
    let report = format!("robust {robust:?}, plain {plain:?}, default {default:?}");
    assert!(default[1].1 >= default[0].1 && default[1].2 <= default[0].2, "the default gather: {report}");
    // The robust estimate: more input, no more error, by PSNR and by relative MSE.
    let (low, high) = (robust[0], robust[1]);
    assert_eq!((low.0, high.0), (4, 16));
    assert!(high.1 >= low.1, "PSNR fell from 4 to 16 spp: {report}");
    assert!(high.2 <= low.2, "relative MSE rose from 4 to 16 spp: {report}");
    // It found outliers, few of them (a handful per thousand splats), …
    for run in &robust {
        assert!(run.3 > 0.0 && run.3 < 0.02, "outlier fraction {}: {report}", run.3);
    }
    // … and the robust radiance is better than the plain filter of the same gather at both.
    assert!(low.2 < plain[0].2 && high.2 < plain[1].2, "{report}");
}
