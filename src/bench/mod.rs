//! `lfr-bench`: the benchmarks, apart from the user's commands in `lfr`. Each reports ratios
//! against a baseline measured in the same run (never absolute times alone): the tracer against
//! raw Embree on the same rays (`tracer`), the filters on the same guide buffers (`filters`),
//! ILFR's gather against Embree on the gather's own rays (`ilfr`), and TLFR's cost per location
//! in traced samples (`tlfr`).

pub mod filters;
pub mod ilfr;
pub mod tlfr;
pub mod tracer;

use anyhow::Result;
use clap::Subcommand;

/// The benchmarks, one per subcommand of `lfr-bench`.
#[derive(Subcommand)]
pub enum Benchmark {
    /// Tracer throughput against raw Embree on the same rays, and thread scaling.
    Tracer(tracer::BenchArgs),
    /// Times the guided filter (1/3/4 guide channels, radii 8-32), A-Trous and the
    /// cross-bilateral filter on the same guide buffers, with ratios from the same run.
    Filters(filters::BenchFiltersArgs),
    /// Indirect light field reconstruction: reconstruction rays per second beside Embree's on the
    /// same rays, the time split, and time against input spp (the paper's scaling study).
    Ilfr(ilfr::BenchIlfrArgs),
    /// Temporal light field reconstruction: locations per second beside the tracer's samples
    /// per second on the same scene in the same run, and the reconstruction's time split.
    Tlfr(tlfr::BenchTlfrArgs),
}

impl Benchmark {
    /// Runs this benchmark.
    pub fn run(&self) -> Result<()> {
        match self {
            Benchmark::Tracer(args) => tracer::run(args),
            Benchmark::Filters(args) => filters::run(args),
            Benchmark::Ilfr(args) => ilfr::run(args),
            Benchmark::Tlfr(args) => tlfr::run(args),
        }
    }

    /// The `lfr-bench` subcommand's name, for the note that the old `lfr bench-*` aliases print.
    pub fn name(&self) -> &'static str {
        match self {
            Benchmark::Tracer(_) => "tracer",
            Benchmark::Filters(_) => "filters",
            Benchmark::Ilfr(_) => "ilfr",
            Benchmark::Tlfr(_) => "tlfr",
        }
    }
}
