//! The `lfr` and `lfr-bench` runners the commands' integration tests share: the built binary,
//! run from the project root with `$LFR_SCENES` set to the shared scenes.

use std::process::{Command, Output};

use super::common::{project_root, shared_scenes};

/// Runs `lfr` with `args` and waits for it.
pub fn lfr(args: &[&str]) -> Output {
    run(env!("CARGO_BIN_EXE_lfr"), args)
}

/// Runs `lfr-bench` (the benchmarks) with `args` and waits for it.
pub fn lfr_bench(args: &[&str]) -> Output {
    run(env!("CARGO_BIN_EXE_lfr-bench"), args)
}

fn run(program: &str, args: &[&str]) -> Output {
    Command::new(program)
        .args(args)
        .current_dir(project_root())
        .env("LFR_SCENES", shared_scenes())
        .output()
        .unwrap_or_else(|e| panic!("{program} runs: {e}"))
}

/// Standard error as text.
pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}
