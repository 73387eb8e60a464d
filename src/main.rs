//! `lfr`: the user-facing command. It orchestrates the tracer, the sample dumps and the
//! reconstructions and times them; this file only dispatches to the library's module for each
//! subcommand. The benchmarks are `lfr-bench` (`bin/lfr-bench.rs`).

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use lfr::bench::{filters, ilfr, tlfr, tracer, Benchmark};
use lfr::{compare, demo, dump, export, filter, merge, probes, reconstruct, render};

/// mimalloc instead of glibc's malloc: glibc hands large freed blocks (image planes, sample
/// arrays) back to the kernel and faults them in again on the next allocation, which cost the
/// guided filter about 20 ms of its ~45 ms per 1024×768 call in `lfr-bench filters`; mimalloc
/// keeps them for reuse. Built with `no_thp`: mimalloc otherwise asks for transparent huge
/// pages on its arenas, and where the system grants them on request (Debian's `madvise`
/// setting) every fresh 2 MiB page is compacted and zeroed on first touch — 0.9–1.0 s of
/// kernel time in `lfr-bench ilfr` on Sponza (5.3 → 4.6 s wall) and 0.3–0.4 s in loading and
/// rendering Sponza (1.7–2.0 → 1.5 s), with no gather or tracing time gained by the large pages.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
#[command(name = "lfr", version, about = "Path tracing with Embree and light-field reconstruction from sparse samples")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The product in one command on the embedded Cornell box: path tracing, the indirect light
    /// field reconstruction, the same fed to the denoiser and the denoiser alone, compared at
    /// equal time against a reference; writes report.html and prints what won (`lfr compare`
    /// with the arguments it prints).
    Demo(demo::DemoArgs),
    /// Path trace a scene into a multi-layer EXR (beauty, direct, indirect, albedo, normal,
    /// depth, position, variance) and a PNG preview beside it.
    Render(render::RenderArgs),
    /// Assemble the shards of `lfr render --shard I/N` into the image one process would render.
    Merge(merge::MergeArgs),
    /// Write samples for the reconstructions and external tools (docs/sample-format.md).
    Dump(dump::DumpArgs),
    /// Convert a sample file to the authors' public sample-buffer formats.
    Export(export::ExportArgs),
    /// Error against run time for path tracing and reconstruction methods, against a cached
    /// high-spp reference: results.json, report.md, images and plots (docs/compare.md).
    Compare(compare::CompareArgs),
    /// Filtered path tracing (Bauszat et al. 2011): guide rays, filtered indirect light,
    /// additional eye rays by the geometry-aware lookup, composite; a multi-layer EXR and PNG.
    Filter(filter::FilterArgs),
    /// Temporal light field reconstruction of a lens-time sample file (depth of field, motion
    /// blur), optionally refocused: --focus-distance D --aperture A.
    Reconstruct(reconstruct::ReconstructArgs),
    /// Sparse radiance probes (Silvennoinen & Lehtinen 2017): `stats` reports receivers, probe
    /// placement, coverage and memory (docs/probes.md).
    Probes(probes::ProbesArgs),
    /// `lfr-bench tracer`, kept for scripts that call `lfr bench`.
    #[command(hide = true)]
    Bench(tracer::BenchArgs),
    /// `lfr-bench filters`, kept for scripts that call `lfr-bench filters`.
    #[command(hide = true)]
    BenchFilters(filters::BenchFiltersArgs),
    /// `lfr-bench ilfr`, kept for scripts that call `lfr-bench ilfr`.
    #[command(hide = true)]
    BenchIlfr(ilfr::BenchIlfrArgs),
    /// `lfr-bench tlfr`, kept for scripts that call `lfr bench-tlfr`.
    #[command(hide = true)]
    BenchTlfr(tlfr::BenchTlfrArgs),
}

/// A benchmark reached through its old `lfr bench-*` name: a note naming `lfr-bench`, then the run.
fn moved_benchmark(benchmark: Benchmark) -> anyhow::Result<()> {
    eprintln!("note: the benchmarks moved to `lfr-bench`; this is `lfr-bench {}`", benchmark.name());
    benchmark.run()
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    lfr::remove_partial_outputs_on_interrupt();
    let result = match cli.command {
        Command::Demo(args) => demo::run(&args),
        Command::Render(args) => render::run(&args),
        Command::Merge(args) => merge::run(&args),
        Command::Dump(args) => dump::run(&args),
        Command::Export(args) => export::run(&args),
        Command::Compare(args) => compare::run(&args),
        Command::Filter(args) => filter::run(&args),
        Command::Reconstruct(args) => reconstruct::run(&args),
        Command::Probes(args) => probes::run(&args),
        Command::Bench(args) => moved_benchmark(Benchmark::Tracer(args)),
        Command::BenchFilters(args) => moved_benchmark(Benchmark::Filters(args)),
        Command::BenchIlfr(args) => moved_benchmark(Benchmark::Ilfr(args)),
        Command::BenchTlfr(args) => moved_benchmark(Benchmark::Tlfr(args)),
    };
    lfr::exit_code(result)
}
