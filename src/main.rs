//! `lfr`: the one user-facing command. It orchestrates the tracer, the sample dumps and the
//! reconstructions and times them; this file only dispatches to one module per subcommand
//! (`common` holds what they share, `convert` the tracer-to-recon conversions).

mod bench;
mod bench_filters;
mod bench_ilfr;
mod bench_tlfr;
mod common;
mod compare;
mod convert;
mod demo;
mod dump;
mod export;
mod filter;
mod fingerprint;
mod merge;
mod outputs;
mod probes;
mod reconstruct;
mod render;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// mimalloc instead of glibc's malloc: glibc hands large freed blocks (image planes, sample
/// arrays) back to the kernel and faults them in again on the next allocation, which cost the
/// guided filter about 20 ms of its ~45 ms per 1024×768 call in `lfr bench-filters`; mimalloc
/// keeps them for reuse. Built with `no_thp`: mimalloc otherwise asks for transparent huge
/// pages on its arenas, and where the system grants them on request (Debian's `madvise`
/// setting) every fresh 2 MiB page is compacted and zeroed on first touch — 0.9–1.0 s of
/// kernel time in `lfr bench-ilfr` on Sponza (5.3 → 4.6 s wall) and 0.3–0.4 s in loading and
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
    /// Tracer throughput against raw Embree on the same rays, and thread scaling.
    Bench(bench::BenchArgs),
    /// Error against run time for path tracing and reconstruction methods, against a cached
    /// high-spp reference: results.json, report.md, images and plots (docs/compare.md).
    Compare(compare::CompareArgs),
    /// Times the guided filter (1/3/4 guide channels, radii 8-32), A-Trous and the
    /// cross-bilateral filter on the same guide buffers, with ratios from the same run.
    BenchFilters(bench_filters::BenchFiltersArgs),
    /// Indirect light field reconstruction: reconstruction rays per second beside Embree's on the
    /// same rays, the time split, and time against input spp (the paper's scaling study).
    BenchIlfr(bench_ilfr::BenchIlfrArgs),
    /// Temporal light field reconstruction: locations per second beside the tracer's samples
    /// per second on the same scene in the same run, and the reconstruction's time split.
    BenchTlfr(bench_tlfr::BenchTlfrArgs),
    /// Filtered path tracing (Bauszat et al. 2011): guide rays, filtered indirect light,
    /// additional eye rays by the geometry-aware lookup, composite; a multi-layer EXR and PNG.
    Filter(filter::FilterArgs),
    /// Temporal light field reconstruction of a lens-time sample file (depth of field, motion
    /// blur), optionally refocused: --focus-distance D --aperture A.
    Reconstruct(reconstruct::ReconstructArgs),
    /// Sparse radiance probes (Silvennoinen & Lehtinen 2017): `stats` reports receivers, probe
    /// placement, coverage and memory (docs/probes.md).
    Probes(probes::ProbesArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // SIGINT, SIGTERM and SIGHUP: remove the temporary files and folders being written
    // (`sampleio::interrupt`) and exit with 130, leaving no half-written output behind.
    if let Err(error) = ctrlc::set_handler(|| sampleio::interrupt::clean_up_and_exit(130)) {
        eprintln!("warning: no interrupt handler ({error}); an interrupt may leave temporary files behind");
    }
    let result = match &cli.command {
        Command::Demo(args) => demo::run(args),
        Command::Render(args) => render::run(args),
        Command::Merge(args) => merge::run(args),
        Command::Dump(args) => dump::run(args),
        Command::Export(args) => export::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Compare(args) => compare::run(args),
        Command::BenchFilters(args) => bench_filters::run(args),
        Command::BenchIlfr(args) => bench_ilfr::run(args),
        Command::BenchTlfr(args) => bench_tlfr::run(args),
        Command::Filter(args) => filter::run(args),
        Command::Reconstruct(args) => reconstruct::run(args),
        Command::Probes(args) => probes::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
