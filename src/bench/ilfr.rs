//! `lfr-bench ilfr`: the indirect light field reconstruction's throughput beside Embree's on
//! the same rays in the same run, its time split, and how its time grows with
//! the input sample count (the paper's Section 4 scaling study: 1 → 8 input spp costs "only
//! about 40 %" more).
//!
//! For every scene and input spp: the tracer dumps `indirect` samples (timed: traced paths per
//! second), `ilfr` reconstructs them (timed per stage), and then the gather's very reconstruction
//! rays (`recon::ilfr::gather::reconstruction_rays`) are traced through Embree alone as
//! closest-hit rays against the scene's triangles (`rtcIntersect1`, no shading) on the same
//! threads. The method pays off only where a reconstruction ray costs much less than a traced
//! path; the report gives that cost in traced path samples.

use std::path::PathBuf;
use std::time::Instant;

use crate::common::{RunArgs, SceneListArgs};
use anyhow::{anyhow, bail, Context, Result};
use rayon::prelude::*;
use recon::ilfr::choices::{IlfrChoices, Variant};
use recon::ilfr::gather::reconstruction_rays;
use recon::ilfr::pipeline::{reconstruct_samples, GatherTarget, IlfrSettings};
use recon::ilfr::samples::read_indirect;
use recon::method::Effect;
use sampleio::SampleFile;
use serde::Serialize;
use tracer::render::thread_pool;
use tracer::samples::secondary::{dump, SecondaryKind};
use tracer::Accel;

#[derive(clap::Args)]
pub struct BenchIlfrArgs {
    /// The scenes, at 128×128 unless --width and --height say otherwise, seed 1 unless --seed
    /// says otherwise.
    #[command(flatten)]
    scenes: SceneListArgs,
    /// Input samples per pixel, comma-separated: the scaling study.
    #[arg(long, value_delimiter = ',', default_value = "1,8")]
    spp: Vec<u32>,
    /// Reconstruction rays per pixel.
    #[arg(long, default_value_t = 256)]
    recon_rays: u32,
    /// Timed repetitions of the Embree replay; the best is reported.
    #[arg(long, default_value_t = 3, value_parser = crate::common::repeats_parser())]
    repeats: u32,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// The gather: `nearest-splat` (the rays of the default, at every hit) or `paper` (the
    /// paper's apparent surfaces). The records of `ilfr`'s default for indirect light gather other
    /// rays than the per-hit gather whose rays are replayed here.
    #[arg(long, default_value = "nearest-splat", value_parser = ["nearest-splat", "paper"])]
    variant: String,
}

#[derive(Serialize)]
struct Row {
    scene: String,
    triangles: usize,
    width: u32,
    height: u32,
    spp: u32,
    threads: usize,
    samples: u64,
    bytes_per_sample: usize,
    trace_s: f64,
    traced_paths_per_s: f64,
    read_s: f64,
    sizing_s: f64,
    hierarchy_s: f64,
    shrinking_s: f64,
    /// The robust radiance of the splats, before the gather (not in `gather_s`).
    robust_s: f64,
    gather_s: f64,
    ilfr_total_s: f64,
    splats: usize,
    primary_hits: u64,
    reconstruction_rays: u64,
    reconstruction_rays_per_s: f64,
    embree_s: f64,
    embree_rays_per_s: f64,
    embree_over_reconstruction: f64,
    /// Time of one reconstruction ray over the time of one traced path sample.
    reconstruction_ray_in_traced_paths: f64,
    /// ILFR total time over the first spp's on the same scene.
    time_over_first_spp: f64,
    /// The reconstruction's statistics (`recon::ilfr::pipeline::Reconstructed::stats`).
    stats: recon::method::Stats,
}

pub fn run(args: &BenchIlfrArgs) -> Result<()> {
    if args.spp.is_empty() || args.spp.contains(&0) || args.recon_rays == 0 {
        bail!("--spp and --recon-rays must be positive");
    }
    let size = args.scenes.size.or(128, 128);
    let threads = args.scenes.run.thread_count()?;
    let run = RunArgs { threads, ..args.scenes.run.clone() };
    let seed = run.seed_or(1);
    let pool = thread_pool(threads)?;
    let dir = tempfile::tempdir().context("a temporary directory for the samples")?;
    let _registration = sampleio::interrupt::remove_on_interrupt(dir.path());
    let mut plan = crate::outputs::json_plan(args.json.as_deref(), &args.scenes.scene_paths())?;
    let mut rows = Vec::new();
    for scene_path in args.scenes.scene_paths() {
        let scene = args.scenes.load_scene(scene_path.as_deref())?;
        plan.scene(&scene).check()?;
        let accel = Accel::build(&scene)?;
        let mut first_total = None;
        for &spp in &args.spp {
            let settings = size.settings(&scene, spp, &run, seed, false)?;
            // The samples are read back whole: TLFR's measured bytes a sample, beside a render.
            let (width, height) = (settings.width, settings.height);
            let samples = width as u64 * height as u64 * spp as u64;
            tracer::memory::check(
                &format!("{samples} samples at {width}x{height}"),
                tracer::memory::render_bytes(width, height) + samples * recon::tlfr::method::BYTES_PER_SAMPLE,
            )?;
            let path = dir.path().join("bench.lfrs");
            let report =
                dump(&scene, &accel, &settings, SecondaryKind::Indirect, &tracer::samples::FieldSelection::All, &path)?;
            let start = Instant::now();
            let file = SampleFile::open(&path)?;
            let samples = read_indirect(&file).map_err(|e| anyhow!("{e}"))?;
            drop(file);
            let read_s = start.elapsed().as_secs_f64();
            // What `ilfr:variant=…` does for indirect light (its per-effect choices applied).
            let variant = if args.variant == "paper" { Variant::Paper } else { Variant::NearestSplat };
            let choices = IlfrChoices { variant: Some(variant), ..IlfrChoices::default() };
            let ilfr = choices
                .apply(IlfrSettings { recon_rays: args.recon_rays, seed, ..IlfrSettings::default() }, Effect::Indirect);
            let result = pool
                .install(|| reconstruct_samples(&samples, GatherTarget::Indirect, &ilfr))
                .map_err(|e| anyhow!("{e}"))?;
            let rays: Vec<embree3::Ray> = reconstruction_rays(&samples, &result.gather_settings)
                .iter()
                .map(|r| embree3::Ray::segment(r.origin, r.direction, 0.0, f32::INFINITY))
                .collect();
            if rays.len() as u64 != result.gather.reconstruct.rays {
                bail!(
                    "the replayed rays ({}) are not the gather's ({}): reconstruction_rays and the gather disagree",
                    rays.len(),
                    result.gather.reconstruct.rays
                );
            }
            let mut embree_s = f64::INFINITY;
            for _ in 0..args.repeats.max(1) {
                let start = Instant::now();
                let hits: usize = pool.install(|| rays.par_chunks(4096).map(|c| accel.intersect_batch(c)).sum());
                embree_s = embree_s.min(start.elapsed().as_secs_f64());
                std::hint::black_box(hits);
            }
            let t = &result.timings;
            let ilfr_total_s = read_s + t.preprocess_s() + t.recon_s();
            let first = *first_total.get_or_insert(ilfr_total_s);
            let n_rays = rays.len() as f64;
            let paths_per_s = report.samples as f64 / report.seconds;
            let recon_per_s = n_rays / t.reconstruct_s;
            let row = Row {
                scene: scene.source.display().to_string(),
                triangles: accel.triangle_count,
                width: settings.width,
                height: settings.height,
                spp,
                threads,
                samples: report.samples,
                bytes_per_sample: report.record_size,
                trace_s: report.seconds,
                traced_paths_per_s: paths_per_s,
                read_s,
                sizing_s: t.sizing_s,
                hierarchy_s: t.hierarchy_s,
                shrinking_s: t.shrinking_s,
                robust_s: t.robust_s,
                gather_s: t.reconstruct_s,
                ilfr_total_s,
                splats: result.splats,
                primary_hits: result.gather.primary_hits,
                reconstruction_rays: rays.len() as u64,
                reconstruction_rays_per_s: recon_per_s,
                embree_s,
                embree_rays_per_s: n_rays / embree_s,
                embree_over_reconstruction: (n_rays / embree_s) / recon_per_s,
                reconstruction_ray_in_traced_paths: paths_per_s / recon_per_s,
                time_over_first_spp: ilfr_total_s / first,
                stats: result.stats(),
            };
            println!(
                "{} ({} triangles) {}x{} at {} spp, {} threads\n  trace   {:8.3} s  {} samples, {:.0} paths/s, {} B/sample\n  \
                 ilfr    {:8.3} s  read {:.3}, sizing {:.3}, hierarchy {:.3}, shrinking {:.3}, robust radiance {:.3}, gather {:.3} ({} splats); {:.2}x the first spp's\n  \
                 gather  {} rays, {:.0} rays/s; per ray {:.1} nodes, {:.1} discs tested, {:.1} collected, {:.1} in the surface; \
                 {:.2}% merged\n  embree  {:8.3} s  the same rays, closest hit: {:.0} rays/s = {:.2}x the gather's\n  \
                 one reconstruction ray costs {:.3} traced path samples",
                row.scene,
                row.triangles,
                row.width,
                row.height,
                spp,
                threads,
                row.trace_s,
                row.samples,
                row.traced_paths_per_s,
                row.bytes_per_sample,
                row.ilfr_total_s,
                row.read_s,
                row.sizing_s,
                row.hierarchy_s,
                row.shrinking_s,
                row.robust_s,
                row.gather_s,
                row.splats,
                row.time_over_first_spp,
                row.reconstruction_rays,
                row.reconstruction_rays_per_s,
                row.stats["nodes_per_ray"],
                row.stats["discs_tested_per_ray"],
                row.stats["collected_per_ray"],
                row.stats["surface_members_per_ray"],
                100.0 * row.stats["merged_fraction"],
                row.embree_s,
                row.embree_rays_per_s,
                row.embree_over_reconstruction,
                row.reconstruction_ray_in_traced_paths,
            );
            rows.push(row);
        }
    }
    if let Some(path) = &args.json {
        crate::common::write_json(path, &rows)?;
    }
    Ok(())
}
