//! `lfr`: the one user-facing command. It orchestrates the tracer (and, as they arrive, the
//! sample dumps and reconstructions) and times them.

mod bench;
mod bench_filters;
mod bench_ilfr;
mod compare;
mod export;
mod filter;
mod reconstruct;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use tracer::samples::secondary::SecondaryKind;
use tracer::{Accel, RenderSettings, Scene};

/// mimalloc instead of glibc's malloc: glibc hands large freed blocks (image planes, sample
/// arrays) back to the kernel and faults them in again on the next allocation, which cost the
/// guided filter about 20 ms of its ~45 ms per 1024×768 call in `lfr bench-filters`; mimalloc
/// keeps them for reuse.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// The embedded default scene (scenes/cornell.toml).
pub const DEFAULT_SCENE: &str = include_str!("../scenes/cornell.toml");
pub const DEFAULT_SCENE_NAME: &str = "<embedded>/cornell.toml";

#[derive(Parser)]
#[command(name = "lfr", version, about = "Path tracing with Embree and light-field reconstruction from sparse samples")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Path trace a scene into a multi-layer EXR (beauty, direct, indirect, albedo, normal,
    /// depth, position, variance) and a PNG preview beside it.
    Render(RenderArgs),
    /// Write samples for the reconstructions and external tools (docs/sample-format.md).
    Dump(DumpArgs),
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
    /// Filtered path tracing (Bauszat et al. 2011): guide rays, filtered indirect light,
    /// additional eye rays by the geometry-aware lookup, composite; a multi-layer EXR and PNG.
    Filter(filter::FilterArgs),
    /// Temporal light field reconstruction of a lens-time sample file (depth of field, motion
    /// blur), optionally refocused: --focus-distance D --aperture A.
    Reconstruct(reconstruct::ReconstructArgs),
}

/// Sample kinds `lfr dump` writes.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum DumpKind {
    /// Camera samples over pixel, lens and time for the temporal light field (TLFR).
    LensTime,
    /// Rays from a planar area light towards the visible points, for TLFR soft shadows.
    Light,
    /// Secondary rays with their radiance for the indirect light field (ILFR).
    Indirect,
    /// Cosine-weighted secondary rays with their hit distance (ILFR ambient occlusion).
    Ao,
    /// Per-pixel guide buffers for the guided image filter, as a multi-layer EXR.
    Guide,
}

/// What both `render` and `dump` take: the scene and how to trace it.
#[derive(clap::Args)]
struct TraceArgs {
    /// Scene file (.toml, .gltf, .glb, .obj); the embedded Cornell box when omitted.
    #[arg(long)]
    scene: Option<PathBuf>,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    #[arg(long, default_value_t = 0)]
    seed: u32,
    /// Maximum number of bounces (default: the scene's).
    #[arg(long)]
    max_bounces: Option<u32>,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

#[derive(clap::Args)]
struct DumpArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[arg(long, value_enum)]
    kind: DumpKind,
    /// Samples per pixel.
    #[arg(long)]
    spp: u32,
    /// Output sample file (conventionally .lfrs; .exr for guide buffers).
    #[arg(long)]
    out: PathBuf,
    /// With --kind lens-time: also write `albedo`, `normal` and `radiance_without_light` for
    /// the soft-shadow reconstruction (needs a planar area light).
    #[arg(long)]
    soft_shadow: bool,
}

#[derive(clap::Args)]
struct RenderArgs {
    #[command(flatten)]
    trace: TraceArgs,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    spp: Option<u32>,
    /// Output EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
}

/// Writes `value` as pretty JSON to `path` through a temporary file (no half-written output);
/// the error names the file. The benchmarks' `--json`.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let json = serde_json::to_vec_pretty(value)?;
    tracer::output::write_atomically(path, |tmp| std::fs::write(tmp, &json).map_err(|e| e.to_string()))
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Loads a scene file, or the embedded default when `path` is `None`.
pub fn load_scene(path: Option<&Path>) -> Result<Scene> {
    let scene = match path {
        Some(p) => Scene::load(p)?,
        None => {
            let mut scene = tracer::scene::description::parse(DEFAULT_SCENE, Path::new(DEFAULT_SCENE_NAME))?;
            scene.validate()?;
            scene
        }
    };
    for warning in &scene.warnings {
        eprintln!("warning: {}: {warning}", scene.source.display());
    }
    Ok(scene)
}

fn render(args: &RenderArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        anyhow::bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let load_start = Instant::now();
    let trace = &args.trace;
    let scene = load_scene(trace.scene.as_deref())?;
    let mut settings = RenderSettings::from_scene(&scene);
    settings.width = trace.width.unwrap_or(settings.width);
    settings.height = trace.height.unwrap_or(settings.height);
    settings.spp = args.spp.unwrap_or(settings.spp);
    settings.max_bounces = trace.max_bounces.unwrap_or(settings.max_bounces);
    settings.seed = trace.seed;
    settings.threads = trace.threads;
    settings.progress = !trace.quiet;
    settings.validate()?;
    let accel = Accel::build(&scene)?;
    let setup = load_start.elapsed().as_secs_f64();
    let frame = tracer::render(&scene, &accel, &settings)?;
    let preview = tracer::output::write_frame(&args.out, &frame).with_context(|| "writing the image")?;
    println!(
        "rendered {} ({} triangles) at {}x{}, {} spp in {:.3} s (scene and BVH {:.3} s): {} rays, {:.2} Mrays/s",
        scene.source.display(),
        accel.triangle_count,
        frame.width,
        frame.height,
        frame.spp,
        frame.seconds,
        setup,
        frame.rays,
        frame.rays as f64 / frame.seconds.max(1e-9) / 1e6,
    );
    if frame.invalid_samples > 0 {
        eprintln!("warning: {} samples had non-finite radiance and were dropped", frame.invalid_samples);
    }
    println!("wrote {} and {}", args.out.display(), preview.display());
    Ok(())
}

impl TraceArgs {
    /// Dump settings for `scene` at `spp` from these options (the scene's size and path length
    /// where not given), validated.
    fn dump_settings(&self, scene: &Scene, spp: u32) -> Result<tracer::samples::DumpSettings> {
        let settings = tracer::samples::DumpSettings {
            width: self.width.unwrap_or(scene.width),
            height: self.height.unwrap_or(scene.height),
            spp,
            seed: self.seed,
            max_bounces: self.max_bounces.unwrap_or(scene.max_bounces),
            threads: self.threads,
            progress: !self.quiet,
        };
        settings.validate()?;
        Ok(settings)
    }
}

fn dump(args: &DumpArgs) -> Result<()> {
    let trace = &args.trace;
    let scene = load_scene(trace.scene.as_deref())?;
    let settings = trace.dump_settings(&scene, args.spp)?;
    let accel = Accel::build(&scene)?;
    let report = match args.kind {
        DumpKind::LensTime if args.soft_shadow => {
            tracer::samples::lens_time::dump_for_soft_shadows(&scene, &accel, &settings, &args.out)?
        }
        DumpKind::LensTime => tracer::samples::lens_time::dump(&scene, &accel, &settings, &args.out)?,
        _ if args.soft_shadow => anyhow::bail!("--soft-shadow only applies to --kind lens-time"),
        DumpKind::Light => tracer::samples::light::dump(&scene, &accel, &settings, &args.out)?,
        DumpKind::Indirect => {
            tracer::samples::secondary::dump(&scene, &accel, &settings, SecondaryKind::Indirect, &args.out)?
        }
        DumpKind::Guide => {
            if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
                anyhow::bail!("--out {}: guide buffers are written as an .exr file", args.out.display());
            }
            tracer::samples::guide::dump(&scene, &accel, &settings, &args.out)?
        }
        DumpKind::Ao => {
            tracer::samples::secondary::dump(&scene, &accel, &settings, SecondaryKind::AmbientOcclusion, &args.out)?
        }
    };
    println!(
        "wrote {} samples of {} to {} in {:.3} s: {} bytes per record, {:.1} bytes per sample with header and checksums; fields: {}",
        report.samples,
        scene.source.display(),
        args.out.display(),
        report.seconds,
        report.record_size,
        report.bytes_per_sample(),
        report.fields.join(", "),
    );
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Render(args) => render(args),
        Command::Dump(args) => dump(args),
        Command::Export(args) => export::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Compare(args) => compare::run(args),
        Command::BenchFilters(args) => bench_filters::run(args),
        Command::BenchIlfr(args) => bench_ilfr::run(args),
        Command::Filter(args) => filter::run(args),
        Command::Reconstruct(args) => reconstruct::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
