//! Interrupts leave no litter: SIGINT or SIGTERM while `lfr dump` writes its
//! sample file, or while `lfr compare` runs its methods, removes the temporary file
//! (`NAME.<pid>.tmp`) and the comparison's input samples, writes no half file under the target's
//! name, and exits with 130.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::project_root;

fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(args)
        .current_dir(project_root())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("lfr starts")
}

/// Every path under `dir` (recursively).
fn tree(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for entry in entries.flatten() {
            let path = entry.path();
            if path.is_dir() {
                found.extend(tree(&path));
            }
            found.push(path);
        }
    }
    found
}

/// Waits until `ready` holds (or the child ends or 120 s pass); true when it held.
fn wait_for(child: &mut Child, ready: impl Fn() -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(120) {
        if ready() {
            return true;
        }
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    false
}

fn signal(child: &Child, name: &str) {
    let status = Command::new("kill").args([&format!("-{name}"), &child.id().to_string()]).status().unwrap();
    assert!(status.success(), "kill -{name}");
}

/// Sends `name` and returns the exit code and standard error.
fn interrupt(child: Child, name: &str) -> (Option<i32>, String) {
    signal(&child, name);
    let output = child.wait_with_output().unwrap();
    (output.status.code(), String::from_utf8_lossy(&output.stderr).into_owned())
}

fn is_temporary(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "tmp")
}

#[test]
fn an_interrupted_dump_leaves_neither_its_temporary_file_nor_a_half_target() {
    for name in ["INT", "TERM"] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("samples.lfrs");
        // Large enough to take many seconds: the signal arrives while the file is written.
        let child = spawn(&[
            "dump",
            "--kind",
            "indirect",
            "--width",
            "256",
            "--height",
            "256",
            "--spp",
            "4096",
            "--out",
            out.to_str().unwrap(),
        ]);
        let mut child = child;
        let writing = wait_for(&mut child, || tree(dir.path()).iter().any(|p| is_temporary(p)));
        assert!(writing, "the dump never started writing its temporary file");
        let (code, stderr) = interrupt(child, name);
        assert_eq!(code, Some(130), "SIG{name}: {stderr}");
        assert!(stderr.contains("interrupted: removed"), "SIG{name}: {stderr}");
        assert_eq!(tree(dir.path()), Vec::<PathBuf>::new(), "SIG{name}: nothing left behind");
    }
}

#[test]
fn an_interrupted_compare_removes_its_input_samples() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("out"), dir.path().join("cache"));
    // ILFR at many rays on large inputs: the signal arrives while the inputs exist.
    let mut child = spawn(&[
        "compare",
        "--effect",
        "indirect",
        "--methods",
        "ilfr",
        "--width",
        "64",
        "--height",
        "64",
        "--spp",
        "64",
        "--recon-rays",
        "4096",
        "--reference-spp",
        "16",
        "--pt-max-spp",
        "1",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ]);
    let inputs = out.join("inputs");
    let has_samples = || tree(&inputs).iter().any(|p| p.extension().is_some_and(|e| e == "lfrs"));
    assert!(wait_for(&mut child, has_samples), "the comparison never wrote its input samples");
    let (code, stderr) = interrupt(child, "INT");
    assert_eq!(code, Some(130), "{stderr}");
    assert!(!inputs.exists(), "the input samples are removed: {:?}", tree(&out));
    assert!(tree(&out).iter().all(|p| !is_temporary(p)), "{:?}", tree(&out));
    assert!(!out.join("results.json").exists(), "no results of an unfinished run");
    assert!(tree(&cache).iter().all(|p| !is_temporary(p)), "{:?}", tree(&cache));
}
