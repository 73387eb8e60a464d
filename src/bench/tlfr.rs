//! `lfr-bench tlfr`: the temporal light field reconstruction's cost per location beside the
//! tracer's cost per sample on the same scene in the same run, and where the
//! reconstruction's time goes.
//!
//! For every scene and input spp the tracer first renders the image at that spp (timed: traced
//! samples per second; direct light by default, `--max-bounces 1`, the paper's setting), then
//! dumps the `lens-time` samples the reconstruction reads. The reconstruction prepares them
//! (timed: reading, measuring R, building the hierarchy; `recon::tlfr::method::prepare`), then,
//! for every location count, integrates the image once plainly (timed: locations per second,
//! the best of `--repeats`) and once with every location's stages clocked (query: hierarchy
//! walk, reprojection and grouping; coverage: the surface choice; filter: the tent), which must
//! give the same image bit for bit. `location_in_traced_samples` is the traced samples per
//! second over the locations per second: what one location costs in traced samples.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use recon::image::Image;
use recon::tlfr::integrate::{integrate_adaptive, integrate_clocked, Clocked};
use recon::tlfr::method::{prepare, Prepared};
use recon::tlfr::query::{reconstruct, QueryStats, Scene};
use recon::tlfr::settings::{Kernel, TlfrSettings};
use serde::Serialize;
use tracer::render::thread_pool;
use tracer::Accel;

use crate::common::{RunArgs, SceneListArgs, SizeArgs};

#[derive(clap::Args)]
pub struct BenchTlfrArgs {
    /// The scenes, at 128×72 unless --width and --height say otherwise, with direct light
    /// (--max-bounces 1) unless --max-bounces says otherwise, seed 1 unless --seed says
    /// otherwise; scenes/monkeys-defocus-motion.toml when omitted.
    #[command(flatten)]
    scenes: SceneListArgs,
    /// Input samples per pixel, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "4,16")]
    spp: Vec<u32>,
    /// Reconstruction locations per pixel (N of Eq. 1), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "32,128")]
    locations: Vec<u32>,
    /// N locations in every pixel: the adaptive rule off (`recon::tlfr::integrate::AdaptiveRule`).
    #[arg(long)]
    fixed_locations: bool,
    /// The kernels timed, comma-separated, alternating within each repetition: `fused` (one SIMD
    /// pass per sample, what `tlfr` runs) and `oracle` (the per-location code it is tested
    /// against). With both, each row also gives the largest difference between their images.
    #[arg(long, value_delimiter = ',', default_value = "fused")]
    kernel: Vec<String>,
    /// Timed repetitions of the render and of the plain reconstruction; the best of each is
    /// reported.
    #[arg(long, default_value_t = 2, value_parser = crate::common::repeats_parser())]
    repeats: u32,
    /// Also write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Serialize)]
struct Row {
    scene: String,
    width: u32,
    height: u32,
    max_bounces: u32,
    spp: u32,
    /// Locations per pixel asked for, and whether the adaptive rule could spend fewer.
    locations: u32,
    adaptive: bool,
    /// `fused` or `oracle`.
    kernel: String,
    threads: usize,
    /// Samples the tracer rendered (width × height × spp) and its best time.
    traced_samples: u64,
    trace_s: f64,
    traced_samples_per_s: f64,
    /// The reconstruction's preparation.
    read_s: f64,
    radius_s: f64,
    hierarchy_s: f64,
    /// The plain integration (best of the repeats) and what it evaluated.
    reconstruct_s: f64,
    evaluated_locations: u64,
    mean_locations_per_pixel: f64,
    locations_per_s: f64,
    /// traced_samples_per_s / locations_per_s: one location's cost in traced samples.
    location_in_traced_samples: f64,
    /// The same over the budget (width × height × locations per reconstruction second): what
    /// the image at N locations per pixel costs per location once the adaptive rule spent fewer.
    budget_locations_per_s: f64,
    budget_location_in_traced_samples: f64,
    /// The clocked integration: its wall time and its stages' time summed over the threads
    /// (so the stages add up to about threads × clocked_s).
    clocked_s: f64,
    query_s: f64,
    coverage_s: f64,
    filter_s: f64,
    /// read + R + hierarchy + the plain integration, and that over the render at this spp.
    tlfr_total_s: f64,
    tlfr_total_over_trace: f64,
    /// Shares of the evaluated locations (%), and leaves per location and pass.
    one_surface_percent: f64,
    triangle_search_percent: f64,
    leaves_per_location: f64,
    radius_px: f32,
    hierarchy_leaves: usize,
    /// The largest difference of a pixel channel between this kernel's image and the first
    /// kernel's, relative to the larger of the two (0 for the first kernel).
    largest_relative_difference: f64,
}

/// The kernels `--kernel` names.
fn kernels(names: &[String]) -> Result<Vec<Kernel>> {
    let mut kernels = Vec::new();
    for name in names {
        let kernel = match name.as_str() {
            "fused" => Kernel::Fused,
            "oracle" => Kernel::Oracle,
            other => bail!("--kernel: unknown kernel `{other}` (fused, oracle)"),
        };
        if kernels.contains(&kernel) {
            bail!("--kernel names `{name}` twice");
        }
        kernels.push(kernel);
    }
    if kernels.is_empty() {
        bail!("--kernel must name a kernel");
    }
    Ok(kernels)
}

fn kernel_name(kernel: Kernel) -> &'static str {
    match kernel {
        Kernel::Fused => "fused",
        Kernel::Oracle => "oracle",
    }
}

/// One integration of `prepared` with `kernel` (`clocked`: every location's stages timed).
fn integrate_with_kernel(
    kernel: Kernel,
    prepared: &Prepared,
    scene: &Scene,
    n: (u32, Option<recon::tlfr::integrate::AdaptiveRule>),
    seed: u32,
    clocked: bool,
) -> (Image, Clocked) {
    let (width, height) = (prepared.width, prepared.height);
    let fallback = |x: u32, y: u32| prepared.box_image.pixels[(y * width + x) as usize];
    let has = (prepared.has_lens, prepared.has_time);
    let plain = |(image, stats): (Image, QueryStats)| (image, Clocked { stats, ..Clocked::default() });
    match (kernel, prepared.fused(scene)) {
        (Kernel::Fused, Some(fused)) if clocked => {
            recon::tlfr::fused::integrate_clocked(&fused, (width, height), n, seed, fallback)
        }
        (Kernel::Fused, Some(fused)) => {
            plain(recon::tlfr::fused::integrate(&fused, (width, height), n, seed, fallback))
        }
        _ if clocked => integrate_clocked(scene, (width, height), n, has, seed, fallback),
        _ => plain(integrate_adaptive(reconstruct, scene, (width, height), n, has, seed, fallback)),
    }
}

pub fn run(args: &BenchTlfrArgs) -> Result<()> {
    if args.spp.is_empty() || args.spp.contains(&0) {
        bail!("--spp must list positive sample counts");
    }
    if args.locations.is_empty() || args.locations.contains(&0) {
        bail!("--locations must list positive location counts");
    }
    let size =
        SizeArgs { max_bounces: Some(args.scenes.size.max_bounces.unwrap_or(1)), ..args.scenes.size.or(128, 72) };
    let kernels = kernels(&args.kernel)?;
    let threads = args.scenes.run.thread_count()?;
    let run = RunArgs { threads, ..args.scenes.run.clone() };
    let seed = run.seed_or(1);
    let pool = thread_pool(threads)?;
    let scene_paths = if args.scenes.scenes.is_empty() {
        vec![Some(PathBuf::from("scenes/monkeys-defocus-motion.toml"))]
    } else {
        args.scenes.scene_paths()
    };
    let mut plan = crate::outputs::json_plan(args.json.as_deref(), &scene_paths)?;
    let dir = tempfile::tempdir().context("a temporary directory for the samples")?;
    let _registration = sampleio::interrupt::remove_on_interrupt(dir.path());
    let mut rows = Vec::new();
    for scene_path in scene_paths {
        let scene = args.scenes.load_scene(scene_path.as_deref())?;
        plan.scene(&scene).check()?;
        let accel = Accel::build(&scene)?;
        for &spp in &args.spp {
            let settings = size.settings(&scene, spp, &run, seed, false)?;
            // The samples are read back whole: TLFR's measured bytes a sample, beside a render.
            let (width, height) = (settings.width, settings.height);
            let samples = width as u64 * height as u64 * spp as u64;
            tracer::memory::check(
                &format!("{samples} samples at {width}x{height}"),
                tracer::memory::render_bytes(width, height) + samples * recon::tlfr::method::BYTES_PER_SAMPLE,
            )?;
            let mut trace_s = f64::INFINITY;
            for _ in 0..args.repeats {
                trace_s = trace_s.min(tracer::render(&scene, &accel, &settings)?.seconds);
            }
            let traced_samples = settings.width as u64 * settings.height as u64 * spp as u64;
            let traced_samples_per_s = traced_samples as f64 / trace_s;
            let path = dir.path().join("bench.lfrs");
            tracer::samples::lens_time::dump(&scene, &accel, &settings, &tracer::samples::FieldSelection::All, &path)?;
            let defaults = TlfrSettings::default();
            let adaptive = if args.fixed_locations { None } else { defaults.adaptive };
            let tlfr = TlfrSettings { seed, adaptive, kernel: Kernel::Fused, ..defaults };
            let prepared = pool.install(|| prepare(&path, &tlfr)).map_err(|e| anyhow::anyhow!("{e}"))?;
            let (width, height) = (prepared.width, prepared.height);
            for &locations in &args.locations {
                let scene_view = prepared.scene(locations);
                let n = (locations, tlfr.adaptive);
                // The kernels alternate within each repetition, so that a slow phase of the
                // machine hits them alike.
                let mut times = vec![f64::INFINITY; kernels.len()];
                let mut plain: Vec<Option<(Image, QueryStats)>> = kernels.iter().map(|_| None).collect();
                for _ in 0..args.repeats {
                    for (k, &kernel) in kernels.iter().enumerate() {
                        let start = Instant::now();
                        let (image, clocked) =
                            pool.install(|| integrate_with_kernel(kernel, &prepared, &scene_view, n, seed, false));
                        times[k] = times[k].min(start.elapsed().as_secs_f64());
                        plain[k] = Some((image, clocked.stats));
                    }
                }
                let first_image = plain[0].as_ref().expect("at least one repeat").0.pixels.clone();
                for (k, &kernel) in kernels.iter().enumerate() {
                    let (image, stats) = plain[k].take().expect("at least one repeat");
                    let reconstruct_s = times[k];
                    let start = Instant::now();
                    let (clocked_image, clocked) =
                        pool.install(|| integrate_with_kernel(kernel, &prepared, &scene_view, n, seed, true));
                    let clocked_s = start.elapsed().as_secs_f64();
                    if clocked_image.pixels != image.pixels || clocked.stats != stats {
                        bail!("the clocked reconstruction differs from the plain one: the bench would time other work");
                    }
                    let largest_relative_difference = image
                        .pixels
                        .iter()
                        .zip(&first_image)
                        .flat_map(|(a, b)| (0..3).map(move |c| (a[c] as f64, b[c] as f64)))
                        .map(|(a, b)| (a - b).abs() / a.abs().max(b.abs()).max(1e-30))
                        .fold(0.0f64, f64::max);
                    let pixels = width as f64 * height as f64;
                    let locations_per_s = stats.locations as f64 / reconstruct_s;
                    let tlfr_total_s = prepared.read_s + prepared.radius_s + prepared.hierarchy_s + reconstruct_s;
                    let percent = |n: u64| 100.0 * n as f64 / stats.locations.max(1) as f64;
                    let row = Row {
                        scene: scene.source.display().to_string(),
                        width,
                        height,
                        max_bounces: settings.max_bounces,
                        spp,
                        locations,
                        adaptive: tlfr.adaptive.is_some(),
                        kernel: kernel_name(kernel).to_string(),
                        threads,
                        traced_samples,
                        trace_s,
                        traced_samples_per_s,
                        read_s: prepared.read_s,
                        radius_s: prepared.radius_s,
                        hierarchy_s: prepared.hierarchy_s,
                        reconstruct_s,
                        evaluated_locations: stats.locations,
                        mean_locations_per_pixel: stats.locations as f64 / pixels,
                        locations_per_s,
                        location_in_traced_samples: traced_samples_per_s / locations_per_s,
                        budget_locations_per_s: pixels * locations as f64 / reconstruct_s,
                        budget_location_in_traced_samples: traced_samples_per_s
                            / (pixels * locations as f64 / reconstruct_s),
                        clocked_s,
                        query_s: clocked.times.query_s,
                        coverage_s: clocked.times.coverage_s,
                        filter_s: clocked.times.filter_s,
                        tlfr_total_s,
                        tlfr_total_over_trace: tlfr_total_s / trace_s,
                        one_surface_percent: percent(stats.one_surface),
                        triangle_search_percent: percent(stats.coverage.triangle_searches),
                        leaves_per_location: stats.leaves as f64 / stats.locations.max(1) as f64,
                        radius_px: prepared.radius,
                        hierarchy_leaves: prepared.hierarchy.leaf_count(),
                        largest_relative_difference,
                    };
                    let staged = row.query_s + row.coverage_s + row.filter_s;
                    let share = |s: f64| 100.0 * s / staged.max(f64::MIN_POSITIVE);
                    println!(
                        "{} {}x{} max-bounces {}, {} spp, {} locations/pixel, {} threads, {} kernel\n  \
                     trace   {:8.3} s  {} samples, {:.0} samples/s\n  \
                     prepare {:8.3} s  read {:.3}, R {:.3} ({:.3} px), hierarchy {:.3} ({} leaves)\n  \
                     locate  {:8.3} s  {} locations ({:.1} per pixel), {:.0} locations/s; clocked {:.3} s: \
                     query {:.1}%, coverage {:.1}%, filter {:.1}%\n  \
                     {:.1}% one surface, {:.2}% triangle searches, {:.1} leaves per location\n  \
                     one location costs {:.3} traced samples ({:.3} per location of the budget); \
                     tlfr in all {:.3} s = {:.2}x the render; largest difference from the first kernel's image {:.2e}",
                        row.scene,
                        width,
                        height,
                        row.max_bounces,
                        spp,
                        locations,
                        threads,
                        row.kernel,
                        row.trace_s,
                        row.traced_samples,
                        row.traced_samples_per_s,
                        row.read_s + row.radius_s + row.hierarchy_s,
                        row.read_s,
                        row.radius_s,
                        row.radius_px,
                        row.hierarchy_s,
                        row.hierarchy_leaves,
                        row.reconstruct_s,
                        row.evaluated_locations,
                        row.mean_locations_per_pixel,
                        row.locations_per_s,
                        row.clocked_s,
                        share(row.query_s),
                        share(row.coverage_s),
                        share(row.filter_s),
                        row.one_surface_percent,
                        row.triangle_search_percent,
                        row.leaves_per_location,
                        row.location_in_traced_samples,
                        row.budget_location_in_traced_samples,
                        row.tlfr_total_s,
                        row.tlfr_total_over_trace,
                        row.largest_relative_difference,
                    );
                    rows.push(row);
                }
            }
        }
    }
    if let Some(path) = &args.json {
        crate::common::write_json(path, &rows)?;
    }
    Ok(())
}
