//! The `lfr` runner the command's integration tests share: the built binary, run from the
//! project root with `$LFR_SCENES` set to the shared scenes.
#![allow(dead_code)]

use std::process::{Command, Output};

use super::common::{project_root, shared_scenes};

/// Runs `lfr` with `args` and waits for it.
pub fn lfr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfr"))
        .args(args)
        .current_dir(project_root())
        .env("LFR_SCENES", shared_scenes())
        .output()
        .expect("lfr runs")
}

/// Standard error as text.
pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}
