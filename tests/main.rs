//! The `lfr` command's integration tests, one binary (one link) with a module per file: each
//! module drives the `lfr` binary or the library crates end to end. Shared helpers: `common`
//! (the tracer's test scenes and paths) and `lfr_runner` (runs `lfr` and reads its output).

use testkit::scenes as common;

mod lfr_runner;

mod architecture;
mod cli;
mod compare;
mod confinement;
mod early_errors;
mod export_ilfr;
mod export_tlfr;
mod filter;
mod ilfr_lens;
mod ilfr_outliers;
mod interrupts;
mod lighting;
mod memory;
mod method_fields;
mod outputs;
mod probes_cli;
mod report_html;
mod sample_fields;
mod scale_out;
mod tlfr;
mod warnings;
