//! `lfr-bench`: the benchmarks (`lfr::bench`), each reporting ratios against a baseline measured
//! in the same run. The user's commands are `lfr`.

use std::process::ExitCode;

use clap::Parser;
use lfr::bench::Benchmark;

/// The same allocator as `lfr` (its reasons are in `main.rs`), so that the benchmarks time what
/// the user runs.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
#[command(name = "lfr-bench", version, about = "Benchmarks of lfr: ratios against a baseline measured in the same run")]
struct Cli {
    #[command(subcommand)]
    benchmark: Benchmark,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    lfr::remove_partial_outputs_on_interrupt();
    lfr::exit_code(cli.benchmark.run())
}
