//! The `lfr` library: what the two commands on top of the workspace run. `lfr` (`main.rs`) holds
//! the user's commands, one module per subcommand (`common` holds what they share, `convert` the
//! tracer-to-recon conversions); `lfr-bench` (`bin/lfr-bench.rs`) holds the benchmarks
//! (`bench`). Both binaries only parse their arguments and dispatch here; other front ends
//! (tests, a Python package) reach the same code through this crate.

pub mod bench;
pub mod common;
pub mod compare;
pub mod convert;
pub mod demo;
pub mod dump;
pub mod export;
pub mod filter;
pub mod fingerprint;
pub mod merge;
pub mod outputs;
pub mod probes;
pub mod reconstruct;
pub mod render;

use std::process::ExitCode;

/// SIGINT, SIGTERM and SIGHUP: remove the temporary files and folders being written
/// (`sampleio::interrupt`) and exit with 130, leaving no half-written output behind.
pub fn remove_partial_outputs_on_interrupt() {
    if let Err(error) = ctrlc::set_handler(|| sampleio::interrupt::clean_up_and_exit(130)) {
        eprintln!("warning: no interrupt handler ({error}); an interrupt may leave temporary files behind");
    }
}

/// A command's exit: success, or the error and its causes on stderr and exit status 1.
pub fn exit_code(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
