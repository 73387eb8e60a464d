//! `lfr-bench tracer`: the tracer's ray throughput against raw Embree on the very same rays, measured
//! in one run, and the tracer's scaling from one thread to all.
//!
//! For each scene the paths are first traced with a recorder that keeps every ray. Then, for
//! each repetition, the tracer renders (timed; rays counted inside the integrator) and the
//! recorded rays are replayed through Embree alone (`rtcIntersect1`/`rtcOccluded1`, no shading,
//! no sampling) on the same number of threads. The ratio tracer/raw says how much of Embree's
//! speed the shading, sampling and bookkeeping leave. It is given best against best and as the
//! median of the alternating pairs: on a shared machine a slow phase hits both runs of a pair,
//! so the pairs show how much the best-against-best figure owes to noise.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use embree3::Ray;
use rayon::prelude::*;
use serde::Serialize;
use tracer::integrator::{RayKind, RecordedRay};
use tracer::render::{record_rays, thread_pool};
use tracer::Accel;

use crate::common::{RunArgs, SceneListArgs};

#[derive(clap::Args)]
pub struct BenchArgs {
    /// The scenes, at 256×256 unless --width and --height say otherwise, on all cores unless
    /// --threads says otherwise (the scaling is measured from one thread to that many).
    #[command(flatten)]
    scenes: SceneListArgs,
    #[arg(long, default_value_t = 16)]
    spp: u32,
    /// Timed repetitions, each a tracer render followed by the raw replay; the best of each is
    /// reported, with the median ratio of the pairs.
    #[arg(long, default_value_t = 3, value_parser = crate::common::repeats_parser())]
    repeats: u32,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Serialize)]
struct SceneResult {
    scene: String,
    triangles: usize,
    width: u32,
    height: u32,
    spp: u32,
    threads: usize,
    rays: u64,
    tracer_seconds: f64,
    tracer_mrays_per_s: f64,
    raw_seconds: f64,
    raw_mrays_per_s: f64,
    tracer_over_raw: f64,
    /// raw/tracer of each alternating (tracer, raw) pair, and their median.
    pair_ratios: Vec<f64>,
    tracer_over_raw_median_pair: f64,
    tracer_one_thread_seconds: f64,
    speedup_all_threads_over_one: f64,
}

fn to_embree(ray: &RecordedRay) -> Ray {
    let mut r = Ray::segment(ray.origin.to_array(), ray.direction.to_array(), 0.0, ray.t_max);
    r.time = ray.time;
    r
}

/// The median of `values` (the mean of the middle two for an even count; 0 for none).
fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    match sorted.len() {
        0 => 0.0,
        n if n % 2 == 1 => sorted[n / 2],
        n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}

pub fn run(args: &BenchArgs) -> Result<()> {
    let size = args.scenes.size.or(256, 256);
    let threads = args.scenes.run.thread_count()?;
    let run = RunArgs { threads, ..args.scenes.run.clone() };
    let mut plan = crate::outputs::json_plan(args.json.as_deref(), &args.scenes.scene_paths())?;
    let mut results = Vec::new();
    for scene_path in args.scenes.scene_paths() {
        let scene = args.scenes.load_scene(scene_path.as_deref())?;
        plan.scene(&scene).check()?;
        let accel = Accel::build(&scene)?;
        let settings = size.settings(&scene, args.spp, &run, run.seed_or(0), false)?;
        // Every ray is kept for the replay: at least a camera ray and a shadow ray a sample,
        // beside a render's worth of pixels.
        let (width, height) = (settings.width, settings.height);
        let ray_bytes = 2 * std::mem::size_of::<tracer::integrator::RecordedRay>() as u64;
        tracer::memory::check(
            &format!("recording the rays of a {width}x{height} render at {} spp", settings.spp),
            tracer::memory::render_bytes(width, height)
                + width as u64 * height as u64 * settings.spp as u64 * ray_bytes,
        )?;
        // The rays first, so that the timed tracer and raw runs can alternate: a slow phase of
        // a shared machine then hits both, and the median of the per-pair ratios shows it.
        let recorded = record_rays(&scene, &accel, &settings)?;
        let closest: Vec<Ray> = recorded.iter().filter(|r| r.kind == RayKind::Closest).map(to_embree).collect();
        let shadow: Vec<Ray> = recorded.iter().filter(|r| r.kind == RayKind::Shadow).map(to_embree).collect();
        drop(recorded);
        let pool = thread_pool(threads)?;
        let mut pairs = Vec::new();
        let mut rays = 0;
        for _ in 0..args.repeats.max(1) {
            let frame = tracer::render(&scene, &accel, &settings)?;
            rays = frame.rays;
            let start = Instant::now();
            let hits: usize = pool.install(|| {
                closest.par_chunks(4096).map(|c| accel.intersect_batch(c)).sum::<usize>()
                    + shadow.par_chunks(4096).map(|c| accel.occluded_batch(c)).sum::<usize>()
            });
            std::hint::black_box(hits);
            pairs.push((frame.seconds, start.elapsed().as_secs_f64()));
        }
        let tracer_seconds = pairs.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let raw_seconds = pairs.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        let pair_ratios: Vec<f64> = pairs.iter().map(|(tracer, raw)| raw / tracer).collect();
        let mut one = settings.clone();
        one.threads = 1;
        // Best of two: a single run on a shared machine can make the scaling look superlinear.
        let one_seconds =
            tracer::render(&scene, &accel, &one)?.seconds.min(tracer::render(&scene, &accel, &one)?.seconds);

        let raw_rays = (closest.len() + shadow.len()) as u64;
        anyhow::ensure!(
            raw_rays == rays,
            "{}: the recorded paths traced {raw_rays} rays but the timed render {rays}; the tracer is not deterministic",
            scene.source.display()
        );
        let result = SceneResult {
            scene: scene.source.display().to_string(),
            triangles: accel.triangle_count,
            width: settings.width,
            height: settings.height,
            spp: args.spp,
            threads,
            rays,
            tracer_seconds,
            tracer_mrays_per_s: rays as f64 / tracer_seconds / 1e6,
            raw_seconds,
            raw_mrays_per_s: raw_rays as f64 / raw_seconds / 1e6,
            tracer_over_raw: raw_seconds / tracer_seconds,
            tracer_over_raw_median_pair: median(&pair_ratios),
            pair_ratios,
            tracer_one_thread_seconds: one_seconds,
            speedup_all_threads_over_one: one_seconds / tracer_seconds,
        };
        println!(
            "{}: {} triangles, {} rays ({} closest, {} shadow)\n  tracer   {:8.3} s  {:7.2} Mrays/s ({} threads)\n  raw      {:8.3} s  {:7.2} Mrays/s (same rays, Embree only)\n  tracer/raw = {:.2} (best against best; median of {} alternating pairs {:.2}, range {:.2}-{:.2}); {} threads vs 1: {:.2}x",
            result.scene,
            result.triangles,
            rays,
            closest.len(),
            shadow.len(),
            result.tracer_seconds,
            result.tracer_mrays_per_s,
            threads,
            result.raw_seconds,
            result.raw_mrays_per_s,
            result.tracer_over_raw,
            result.pair_ratios.len(),
            result.tracer_over_raw_median_pair,
            result.pair_ratios.iter().copied().fold(f64::INFINITY, f64::min),
            result.pair_ratios.iter().copied().fold(0.0, f64::max),
            threads,
            result.speedup_all_threads_over_one,
        );
        results.push(result);
    }
    if let Some(path) = &args.json {
        crate::common::write_json(path, &results)?;
    }
    Ok(())
}
