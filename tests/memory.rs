//! Memory estimated before allocation: a size within the option limits that
//! this machine cannot hold is refused at once with the estimate and what is available, before
//! any tracing and without writing anything, instead of an aborted allocation or the OOM killer.

use crate::common;

use std::process::{Command, Output};
use std::time::{Duration, Instant};

use common::project_root;

fn lfr(args: &[&str], available: Option<&str>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_lfr"));
    command.args(args).current_dir(project_root()).env_remove("LFR_MEMORY_AVAILABLE");
    if let Some(bytes) = available {
        command.env("LFR_MEMORY_AVAILABLE", bytes);
    }
    command.output().expect("lfr runs")
}

#[test]
fn sizes_beyond_the_machine_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.exr");
    let out = out.to_str().unwrap();
    // 32768² needs about 320 GiB: more than any test machine has.
    let start = Instant::now();
    let refused = lfr(&["render", "--width", "32768", "--height", "32768", "--spp", "1", "--out", out], None);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success(), "{stderr}");
    assert!(stderr.contains("a 32768x32768 render needs about 320.0 GiB") && stderr.contains("available"), "{stderr}");
    assert!(start.elapsed() < Duration::from_secs(60), "refused at once, not after tracing");

    // With the available memory set low, small sizes are refused by every tracing command too.
    let tiny = Some("1000000");
    let cases: [&[&str]; 3] = [
        &["render", "--width", "100", "--height", "100", "--spp", "1", "--out", out],
        &["filter", "--width", "100", "--height", "100", "--spp", "1", "--out", out],
        &["compare", "--effect", "indirect", "--width", "100", "--height", "100", "--out", out],
    ];
    for args in cases {
        let refused = lfr(args, tiny);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert!(!refused.status.success(), "{args:?}: {stderr}");
        assert!(stderr.contains("needs about") && stderr.contains("976.6 KiB is available"), "{args:?}: {stderr}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "{args:?}: nothing written");
    }
    // The same render fits when the memory is there.
    let fits =
        lfr(&["render", "--width", "16", "--height", "16", "--spp", "1", "--quiet", "--out", out], Some("100000000"));
    assert!(fits.status.success(), "{}", String::from_utf8_lossy(&fits.stderr));
}

#[test]
fn a_reconstruction_beyond_the_machine_is_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("s.lfrs");
    let samples = samples.to_str().unwrap();
    let dumped = lfr(
        &["dump", "--scene", "scenes/monkeys-defocus-motion.toml", "--kind", "lens-time", "--width", "8"]
            .into_iter()
            .chain(["--height", "8", "--spp", "4", "--quiet", "--out", samples])
            .collect::<Vec<_>>(),
        None,
    );
    assert!(dumped.status.success(), "{}", String::from_utf8_lossy(&dumped.stderr));
    let out = dir.path().join("r.exr");
    let out = out.to_str().unwrap();
    // 256 samples at recon::tlfr::method::BYTES_PER_SAMPLE each: about 96 KiB.
    let refused = lfr(&["reconstruct", "--samples", samples, "--locations", "4", "--out", out], Some("50000"));
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success(), "{stderr}");
    assert!(stderr.contains(&format!("reconstructing the 256 samples of {samples} needs about 96.0 KiB")), "{stderr}");
    assert!(!std::path::Path::new(out).exists() && !std::path::Path::new(out).with_extension("png").exists());
    let fits = lfr(&["reconstruct", "--samples", samples, "--locations", "4", "--out", out], Some("100000000"));
    assert!(fits.status.success(), "{}", String::from_utf8_lossy(&fits.stderr));
}

/// `compare` with `probes` counts the largest probes method's precompute, compression and
/// image beside its images: a receiver budget the machine cannot hold is refused before the
/// reference is traced, naming the method, while the same comparison without it fits.
#[test]
fn a_comparison_with_probes_counts_their_memory_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let out = out.to_str().unwrap();
    let cache = dir.path().join("cache");
    let base = ["compare", "--effect", "indirect", "--width", "16", "--height", "16", "--spp", "1", "--quiet"];
    let base: Vec<&str> = base.into_iter().chain(["--cache-dir", cache.to_str().unwrap()]).collect();
    let big = "box,probes:receivers=20000000";
    let mut args = base.to_vec();
    args.extend_from_slice(&["--methods", big, "--out", out]);
    let start = Instant::now();
    let refused = lfr(&args, Some("8589934592"));
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        stderr.contains("needs about")
            && stderr.contains("8.0 GiB is available")
            && stderr.contains("probes:receivers=20000000")
            && stderr.contains("receivers"),
        "{stderr}"
    );
    assert!(start.elapsed() < Duration::from_secs(60), "refused at once, not after tracing");
    assert!(!std::path::Path::new(out).exists() && !cache.exists(), "nothing written");
    // Without the probes the same comparison's images fit in the same memory: the refusal was
    // the probes' estimate.
    let mut args = base.to_vec();
    args.extend_from_slice(&["--methods", "box", "--reference-spp", "4", "--pt-max-spp", "2", "--out", out]);
    let fits = lfr(&args, Some("8589934592"));
    assert!(fits.status.success(), "{}", String::from_utf8_lossy(&fits.stderr));
}
