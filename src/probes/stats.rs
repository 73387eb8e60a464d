//! `lfr probes stats`: the receivers, the probe placement, its coverage, a survey of the hit
//! points no covering probe sees, the memory the precompute will need and, with `--frame`, the
//! dense pipeline once, timed.

use std::path::PathBuf;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use probes::defaults;
use probes::direct::direct_irradiance;
use probes::frame::{indirect, surfel_albedo};
use probes::layout::{Layout, Step};
use probes::memory::MemoryEstimate;
use probes::precompute::PrecomputeSettings;
use probes::relight::RelightTable;
use probes::transport::{TransportContext, TransportSettings};
use probes::visibility::{survey_unseen, UnseenSurvey};
use serde::Serialize;

use super::check_memory;
use super::options::PlacementArgs;
use crate::common::{write_json, TraceArgs};
use crate::outputs::OutputPlan;

#[derive(clap::Args)]
pub struct StatsArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[command(flatten)]
    placement: PlacementArgs,
    /// Receivers to survey for hit points no covering probe sees (0: no survey).
    #[arg(long, default_value_t = 2000)]
    survey: usize,
    /// Cosine-distributed directions per surveyed receiver.
    #[arg(long, default_value_t = 128)]
    survey_directions: u32,
    /// Receivers whose dense transport (order 7) is computed and timed, to estimate the
    /// precompute (0: none).
    #[arg(long, default_value_t = 0)]
    time_transport: usize,
    /// Directions per receiver for --time-transport.
    #[arg(long, default_value_t = defaults::DIRECTIONS)]
    directions: u32,
    /// Run the whole dense pipeline once on every receiver (transport with --directions, relight
    /// rays, direct light, bounces to convergence or --max-bounces) and time a relit frame; slow
    /// on big budgets. No image is made: `lfr probes relight` makes one.
    #[arg(long)]
    frame: bool,
    /// Relight rays per probe for --frame.
    #[arg(long, default_value_t = defaults::RELIGHT_RAYS)]
    relight_rays: u32,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Serialize)]
struct Report {
    scene: String,
    triangles: usize,
    scene_extent: f64,
    threads: usize,
    receivers_budget: usize,
    receivers: usize,
    receiver_cell: f64,
    receiver_area: f64,
    area_samples: usize,
    degenerate_triangles: usize,
    probes_target: usize,
    probes: usize,
    candidate_rule: String,
    spacing: f64,
    voxel: f64,
    voxel_grid: [usize; 3],
    solid_voxels: usize,
    reached_voxels: usize,
    candidates: usize,
    flood_fill_seeds: usize,
    probes_inside_geometry_dropped: usize,
    overlap_target: f64,
    support_radius: f64,
    probes_per_receiver_min: usize,
    probes_per_receiver_mean: f64,
    probes_per_receiver_max: usize,
    receivers_without_probe: usize,
    surfel_bytes: f64,
    dense_transport_bytes: f64,
    dense_transport_bytes_per_receiver: f64,
    survey_receivers: usize,
    survey_directions: u32,
    survey_back_facing_receivers: usize,
    survey_hidden_receivers: usize,
    survey_unseen_fraction: f64,
    survey_escaped: u64,
    survey_covering_per_hit: f64,
    survey_seeing_per_hit: f64,
    survey_receivers_losing_none: f64,
    survey_receivers_losing_at_most_5_percent: f64,
    survey_receivers_losing_over_90_percent: f64,
    surfels_s: f64,
    placement_s: f64,
    radius_s: f64,
    coverage_s: f64,
    survey_s: f64,
    transport_receivers: usize,
    transport_directions: u32,
    transport_s_per_receiver: f64,
    transport_estimate_all_s: f64,
    frame: Option<FrameReport>,
}

#[derive(Serialize)]
struct FrameReport {
    precompute_transport_s: f64,
    precompute_relight_s: f64,
    direct_s: f64,
    bounces_s: f64,
    iterations: usize,
    bounce_s: f64,
    clamped_channels: u64,
    mean_indirect_irradiance: [f32; 3],
    unseen_direction_fraction: f64,
    relight_escaped: u64,
    relight_holes: u64,
    hidden_receivers: usize,
}

pub(super) fn run_stats(args: &StatsArgs) -> Result<()> {
    if args.trace.size.width.is_some() || args.trace.size.height.is_some() {
        anyhow::bail!(
            "--width/--height: `lfr probes stats` makes no image (the receivers do not depend on it); `lfr probes \
             relight` makes one"
        );
    }
    let (surfel_settings, placement_settings) = args.placement.settings(args.trace.seed());
    // Every setting and output is checked before the scene is read.
    surfel_settings.validate()?;
    placement_settings.validate()?;
    let threads = args.trace.run.thread_count()?;
    if args.survey > 0 && !(1..=65536).contains(&args.survey_directions) {
        anyhow::bail!("survey-directions: must be between 1 and 65536, got {}", args.survey_directions);
    }
    let transport_settings =
        TransportSettings { directions: args.directions, seed: args.trace.seed(), ..Default::default() };
    transport_settings.validate()?;
    let coefficients = (transport_settings.order + 1) * (transport_settings.order + 1);
    if args.frame && !(args.relight_rays >= 4 * coefficients as u32 && args.relight_rays <= probes::relight::MAX_RAYS) {
        anyhow::bail!(
            "relight-rays: must be between {} and {}, got {}",
            4 * coefficients,
            probes::relight::MAX_RAYS,
            args.relight_rays
        );
    }
    let mut plan = OutputPlan::new();
    if let Some(json) = &args.json {
        plan.file(json, "--json");
    }
    plan.scene_file(args.trace.scene.as_deref()).check()?;
    let scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    if args.frame {
        // --frame builds the whole dense pipeline: the precompute's memory.
        let settings = PrecomputeSettings {
            surfels: surfel_settings,
            placement: placement_settings,
            transport: transport_settings,
            relight_rays: args.relight_rays,
        };
        check_memory("probes stats --frame", &MemoryEstimate::precompute(&settings, threads))?;
    }
    let pool = tracer::render::thread_pool(threads)?;

    let bar = if args.trace.quiet { ProgressBar::hidden() } else { ProgressBar::new_spinner() };
    bar.set_style(
        ProgressStyle::with_template("{spinner} probes stats: {msg} [{elapsed_precise}]")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let layout = pool
        .install(|| {
            Layout::build(&scene, &surfel_settings, &placement_settings, &mut |step| {
                bar.set_message(match step {
                    Step::Placement => "voxels, flood fill and probe placement",
                    Step::Surfels => "receivers (surfels)",
                    Step::Radius => "support radius",
                    Step::Coverage => "coverage",
                });
            })
        })
        .with_context(|| format!("probes on {}", scene.source.display()))?;
    let t = std::time::Instant::now();
    let survey = if args.survey > 0 {
        bar.set_message("survey of unseen hit points (rays)");
        let accel = tracer::Accel::build(&scene)?;
        pool.install(|| {
            survey_unseen(
                &accel,
                &layout.surfels,
                Some(&layout.placement.grid),
                &layout.placement.probes,
                layout.radius,
                args.survey,
                args.survey_directions,
                args.trace.seed(),
            )
        })
    } else {
        UnseenSurvey::default()
    };
    let survey_s = t.elapsed().as_secs_f64();
    let mut transport_s = 0.0;
    let timed = args.time_transport.min(layout.surfels.surfels.len());
    if let Some(stride) = layout.surfels.surfels.len().checked_div(timed) {
        bar.set_message("timing the dense transport");
        let accel = tracer::Accel::build(&scene)?;
        let ctx = TransportContext::new(
            &accel,
            &layout.placement.probes,
            layout.radius,
            layout.scale as f32,
            transport_settings,
        )?;
        let t = std::time::Instant::now();
        pool.install(|| {
            use rayon::prelude::*;
            (0..timed).into_par_iter().for_each(|k| {
                let s = &layout.surfels.surfels[k * stride];
                std::hint::black_box(ctx.receiver((k * stride) as u32, s.position, s.normal));
            })
        });
        transport_s = t.elapsed().as_secs_f64();
    }
    let frame = if args.frame {
        bar.set_message("dense pipeline: transport, relight rays, direct light, bounces");
        let max_bounces = args.trace.size.max_bounces.unwrap_or(scene.max_bounces);
        Some(pool.install(|| {
            run_frame(&scene, &layout, transport_settings, args.relight_rays, max_bounces, args.trace.seed())
        })?)
    } else {
        None
    };
    bar.finish_and_clear();
    let share = |n: usize| n as f64 / survey.counted_receivers.max(1) as f64;

    let s = &layout.surfels.stats;
    let p = &layout.placement;
    let c = &layout.coverage;
    let report = Report {
        scene: scene.source.display().to_string(),
        triangles: s.triangles,
        scene_extent: layout.scale,
        threads,
        receivers_budget: args.placement.receivers,
        receivers: s.surfels,
        receiver_cell: s.h,
        receiver_area: s.area,
        area_samples: s.samples,
        degenerate_triangles: s.degenerate_triangles,
        probes_target: args.placement.probes,
        probes: p.probes.len(),
        candidate_rule: format!("{:?}", args.placement.candidates).to_lowercase(),
        spacing: p.spacing,
        voxel: p.voxel,
        voxel_grid: p.dims,
        solid_voxels: p.solid_voxels,
        reached_voxels: p.reached_voxels,
        candidates: p.candidates,
        flood_fill_seeds: p.seeds_used,
        probes_inside_geometry_dropped: layout.probes_inside,
        overlap_target: args.placement.overlap,
        support_radius: layout.radius,
        probes_per_receiver_min: c.min,
        probes_per_receiver_mean: c.mean,
        probes_per_receiver_max: c.max,
        receivers_without_probe: c.uncovered,
        surfel_bytes: layout.surfel_bytes(),
        dense_transport_bytes: layout.dense_transport_bytes(),
        dense_transport_bytes_per_receiver: layout.dense_transport_bytes() / s.surfels.max(1) as f64,
        survey_receivers: survey.receivers,
        survey_directions: survey.directions,
        survey_back_facing_receivers: survey.back_facing_receivers,
        survey_hidden_receivers: survey.hidden_receivers,
        survey_unseen_fraction: survey.unseen_fraction(),
        survey_escaped: survey.escaped,
        survey_covering_per_hit: survey.covering_per_hit,
        survey_seeing_per_hit: survey.seeing_per_hit,
        survey_receivers_losing_none: share(survey.lose_none),
        survey_receivers_losing_at_most_5_percent: share(survey.lose_at_most_5_percent),
        survey_receivers_losing_over_90_percent: share(survey.lose_over_90_percent),
        surfels_s: layout.timings.surfels_s,
        placement_s: layout.timings.placement_s,
        radius_s: layout.timings.radius_s,
        coverage_s: layout.timings.coverage_s,
        survey_s,
        transport_receivers: timed,
        transport_directions: args.directions,
        transport_s_per_receiver: transport_s / timed.max(1) as f64,
        transport_estimate_all_s: transport_s / timed.max(1) as f64 * s.surfels as f64,
        frame,
    };
    print_report(&report);
    if let Some(json) = &args.json {
        write_json(json, &report)?;
    }
    Ok(())
}

/// The dense pipeline once, timed.
fn run_frame(
    scene: &tracer::Scene,
    layout: &Layout,
    settings: TransportSettings,
    relight_rays: u32,
    max_bounces: u32,
    seed: u32,
) -> Result<FrameReport> {
    use std::time::Instant;
    let accel = tracer::Accel::build(scene)?;
    let scale = layout.scale as f32;
    let t = Instant::now();
    let ctx = TransportContext::new(&accel, &layout.placement.probes, layout.radius, scale, settings)?;
    let (transports, hidden_receivers) = ctx.all_valid(&layout.surfels, &layout.placement.grid);
    let precompute_transport_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let table =
        RelightTable::build(&accel, &layout.surfels, &layout.placement.probes, relight_rays, settings.order, scale)?;
    let precompute_relight_s = t.elapsed().as_secs_f64();
    let albedo = surfel_albedo(scene, &layout.surfels);
    let t = Instant::now();
    let direct = direct_irradiance(scene, &accel, &layout.surfels, defaults::LIGHT_SAMPLES, seed, scale)?;
    let direct_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let out = indirect(&transports, &table, &albedo, &direct, max_bounces.max(1) as usize, defaults::BOUNCE_TOLERANCE)?;
    let bounces_s = t.elapsed().as_secs_f64();
    let n = out.irradiance.len().max(1) as f32;
    let mean = out.irradiance.iter().fold(glam::Vec3::ZERO, |a, e| a + *e) / n;
    let hits: u64 = transports.iter().map(|t| t.hits as u64).sum();
    let unseen: u64 = transports.iter().map(|t| t.unseen as u64).sum();
    Ok(FrameReport {
        precompute_transport_s,
        precompute_relight_s,
        direct_s,
        bounces_s,
        iterations: out.iterations,
        bounce_s: bounces_s / out.iterations.max(1) as f64,
        clamped_channels: out.clamped,
        mean_indirect_irradiance: mean.to_array(),
        unseen_direction_fraction: unseen as f64 / hits.max(1) as f64,
        relight_escaped: table.escaped,
        relight_holes: table.holes,
        hidden_receivers,
    })
}

fn print_report(r: &Report) {
    let mb = |b: f64| b / 1e6;
    let pct = |n: usize, of: usize| 100.0 * n as f64 / of.max(1) as f64;
    println!(
        "scene       {} ({} triangles, extent {:.4e}, {} threads)",
        r.scene, r.triangles, r.scene_extent, r.threads
    );
    println!(
        "receivers   {} surfels (budget {}), cell h {:.4e}, two-sided area {:.4e}, {} area samples, {} degenerate triangles skipped",
        r.receivers, r.receivers_budget, r.receiver_cell, r.receiver_area, r.area_samples, r.degenerate_triangles
    );
    println!(
        "placement   {} probes (target {}, rule {}), spacing {:.4e}, voxel {:.4e}, grid {}x{}x{}",
        r.probes,
        r.probes_target,
        r.candidate_rule,
        r.spacing,
        r.voxel,
        r.voxel_grid[0],
        r.voxel_grid[1],
        r.voxel_grid[2]
    );
    println!(
        "            {} solid voxels, {} reached by the flood fill ({} seeds inside the grid), {} candidates, {} probes dropped inside geometry",
        r.solid_voxels, r.reached_voxels, r.flood_fill_seeds, r.candidates, r.probes_inside_geometry_dropped
    );
    println!(
        "radius      r = {:.4e} ({:.2} spacings) for a mean overlap of {}",
        r.support_radius,
        r.support_radius / r.spacing,
        r.overlap_target
    );
    println!(
        "coverage    probes per receiver min {} / mean {:.2} / max {}; {} receivers ({:.2} %) with no probe in range",
        r.probes_per_receiver_min,
        r.probes_per_receiver_mean,
        r.probes_per_receiver_max,
        r.receivers_without_probe,
        pct(r.receivers_without_probe, r.receivers)
    );
    if r.survey_receivers > 0 {
        println!(
            "unseen      {} receivers x {} cosine rays; left out: {} hidden (front voxel never reached by the flood fill), {} on the wrong side of closed geometry (>= 30 % back-face hits);",
            r.survey_receivers, r.survey_directions, r.survey_hidden_receivers, r.survey_back_facing_receivers
        );
        println!(
            "            {:.2} % of hit directions seen by no covering probe; per hit {:.2} covering probes, {:.2} seeing; receivers losing none {:.1} %, <= 5 % {:.1} %, > 90 % {:.1} %",
            100.0 * r.survey_unseen_fraction,
            r.survey_covering_per_hit,
            r.survey_seeing_per_hit,
            100.0 * r.survey_receivers_losing_none,
            100.0 * r.survey_receivers_losing_at_most_5_percent,
            100.0 * r.survey_receivers_losing_over_90_percent
        );
    }
    println!(
        "memory      surfels {:.1} MB; dense order-7 transport (f32) {:.1} MB = {:.0} B per receiver before CPCA",
        mb(r.surfel_bytes),
        mb(r.dense_transport_bytes),
        r.dense_transport_bytes_per_receiver
    );
    if let Some(f) = &r.frame {
        println!(
            "frame       precompute: transport {:.1} s, relight rays {:.1} s; relit frame: direct {:.3} s + {} bounces {:.3} s ({:.4} s each), {} channels clamped",
            f.precompute_transport_s,
            f.precompute_relight_s,
            f.direct_s,
            f.iterations,
            f.bounces_s,
            f.bounce_s,
            f.clamped_channels
        );
        println!(
            "            {} hidden receivers without transport; mean indirect irradiance {:.4e} {:.4e} {:.4e}; {:.2} % of the valid receivers' hit directions unseen; relight rays escaped {}, on holes {}",
            f.hidden_receivers,
            f.mean_indirect_irradiance[0],
            f.mean_indirect_irradiance[1],
            f.mean_indirect_irradiance[2],
            100.0 * f.unseen_direction_fraction,
            f.relight_escaped,
            f.relight_holes
        );
    }
    if r.transport_receivers > 0 {
        println!(
            "transport   {} receivers x {} directions (order 7, dense): {:.3} ms per receiver on {} threads; all {} receivers ~ {:.0} s",
            r.transport_receivers,
            r.transport_directions,
            1e3 * r.transport_s_per_receiver,
            r.threads,
            r.receivers,
            r.transport_estimate_all_s
        );
    }
    println!(
        "time        surfels {:.2} s, placement {:.2} s, radius {:.2} s, coverage {:.2} s, survey {:.2} s",
        r.surfels_s, r.placement_s, r.radius_s, r.coverage_s, r.survey_s
    );
}
