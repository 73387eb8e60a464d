//! `lfr-bench filters`: the filters of the filtered path-tracing pipeline timed on the same
//! guide buffers in one run (the guided filter's Table 2 of Bauszat et al. 2011): the guided
//! filter with 1, 3 and 4 guide channels at radii 8–32 (its time must not grow with the
//! radius), exact and as the fast guided filter with subsampling 2, À-Trous at 4–6 iterations and the cross-bilateral filter at radii 16–32. Ratios are
//! against the guided filter with the 4-channel guide at radius 8, measured in the same run.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use recon::baselines::atrous::{atrous, AtrousParams};
use recon::baselines::bilateral::{cross_bilateral, BilateralParams};
use recon::gif::guided_filter::{guided_filter, GuideKind, GuidedFilterParams};
use recon::gif::modulation::demodulate;
use serde::Serialize;
use tracer::Accel;

use crate::common::{RunArgs, TraceArgs};

#[derive(clap::Args)]
pub struct BenchFiltersArgs {
    /// The scene whose guide buffers are filtered, at 1024×768 unless --width and --height say
    /// otherwise, seed 1 unless --seed does.
    #[command(flatten)]
    trace: TraceArgs,
    /// Timed repetitions of the fast filters; the best is reported (the bilateral runs once).
    #[arg(long, default_value_t = 5, value_parser = crate::common::repeats_parser())]
    repeats: u32,
    /// Skip the cross-bilateral filter (seconds per run at large radii).
    #[arg(long)]
    no_bilateral: bool,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Serialize)]
struct Timing {
    filter: String,
    setting: String,
    milliseconds: f64,
    ms_per_megapixel: f64,
    ratio_to_baseline: f64,
}

fn best_of(repeats: u32, mut run: impl FnMut() -> Result<()>) -> Result<f64> {
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        run()?;
        best = best.min(start.elapsed().as_secs_f64());
    }
    Ok(best * 1e3)
}

pub fn run(args: &BenchFiltersArgs) -> Result<()> {
    let trace = &args.trace;
    let mut plan = crate::outputs::json_plan(args.json.as_deref(), std::slice::from_ref(&trace.scene))?;
    let scene = trace.load_scene()?;
    plan.scene(&scene).check()?;
    let accel = Accel::build(&scene)?;
    let defaults = TraceArgs {
        size: trace.size.or(1024, 768),
        run: RunArgs { seed: Some(trace.run.seed_or(1)), ..trace.run.clone() },
        quiet: true,
        ..trace.clone()
    };
    let settings = defaults.settings(&scene, 1)?;
    // The guide buffers and the filters' planes: about two renders' worth, as `filter`.
    let (width, height) = (settings.width, settings.height);
    tracer::memory::check(&format!("filtering {width}x{height}"), 2 * tracer::memory::render_bytes(width, height))?;
    let buffers = tracer::samples::guide::guide_buffers(&scene, &accel, &settings)?;
    let (width, height) = (settings.width, settings.height);
    let input = crate::convert::guide_input(&buffers);
    let guide = &input.guide;
    let noisy = demodulate(&input.indirect, &input.albedo);
    let megapixels = width as f64 * height as f64 / 1e6;
    let pool = tracer::render::thread_pool(trace.run.threads)?;
    let threads = pool.current_num_threads();
    println!(
        "filters on the guide buffers of {} at {width}x{height} ({megapixels:.2} MP), {threads} threads, best of {}:",
        scene.source.display(),
        args.repeats
    );

    let mut rows: Vec<(String, String, f64)> = Vec::new();
    pool.install(|| -> Result<()> {
        for (kind, name) in [
            (GuideKind::GreyNormal, "1 channel"),
            (GuideKind::Normal, "3 channels"),
            (GuideKind::NormalDepth, "4 channels"),
        ] {
            for subsample in [1, 2] {
                for radius in [8, 16, 24, 32] {
                    let params = GuidedFilterParams { radius, guide: kind, subsample, ..GuidedFilterParams::default() };
                    let ms = best_of(args.repeats, || {
                        guided_filter(&noisy, guide, &params).map(|_| ()).map_err(anyhow::Error::msg)
                    })?;
                    let filter = if subsample == 1 { "guided".to_string() } else { format!("guided, s = {subsample}") };
                    rows.push((filter, format!("{name}, radius {radius}"), ms));
                }
            }
        }
        for iterations in [4, 5, 6] {
            let params = AtrousParams { iterations, ..AtrousParams::default() };
            let ms = best_of(args.repeats, || atrous(&noisy, guide, &params).map(|_| ()).map_err(anyhow::Error::msg))?;
            rows.push(("a-trous".into(), format!("{iterations} iterations"), ms));
        }
        if !args.no_bilateral {
            for radius in [16, 24, 32] {
                let params = BilateralParams::with_radius(radius);
                let ms =
                    best_of(1, || cross_bilateral(&noisy, guide, &params).map(|_| ()).map_err(anyhow::Error::msg))?;
                rows.push(("cross-bilateral".into(), format!("radius {radius}"), ms));
            }
        }
        Ok(())
    })?;

    let baseline = rows
        .iter()
        .find(|(f, s, _)| f == "guided" && s == "4 channels, radius 8")
        .map(|r| r.2)
        .context("the baseline run is missing")?;
    let timings: Vec<Timing> = rows
        .into_iter()
        .map(|(filter, setting, ms)| Timing {
            filter,
            setting,
            milliseconds: ms,
            ms_per_megapixel: ms / megapixels,
            ratio_to_baseline: ms / baseline,
        })
        .collect();
    println!("{:<16} {:<24} {:>10} {:>10} {:>8}", "filter", "setting", "ms", "ms/MP", "ratio");
    for t in &timings {
        println!(
            "{:<16} {:<24} {:>10.1} {:>10.1} {:>8.2}",
            t.filter, t.setting, t.milliseconds, t.ms_per_megapixel, t.ratio_to_baseline
        );
    }
    println!("ratio: time / guided filter with the 4-channel guide at radius 8, same run");
    if let Some(path) = &args.json {
        crate::common::write_json(path, &timings)?;
    }
    Ok(())
}
