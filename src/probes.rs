//! `lfr probes`: sparse radiance probes (Silvennoinen & Lehtinen 2017, crate `probes`,
//! docs/probes.md). `lfr probes stats` builds the receivers and places the probes, and
//! prints the placement, the coverage it gives and the memory the precompute will need;
//! `precompute` writes the cache; `relight` renders one relit frame from it (building it first
//! when there is none), optionally with a light moved; `animate` moves a point light along a
//! line, one bounce per frame with the paper's feedback, and times every frame.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use probes::cache::CacheKey;
use probes::cpca::{Cpca, CpcaSettings, Precision};
use probes::defaults;
use probes::direct::direct_irradiance;
use probes::error::CacheProblem;
use probes::frame::{indirect, indirect_timed, surfel_albedo, Indirect, ReceiverTransport};
use probes::image::{render_image, ImageSettings, ProbeImage};
use probes::image_operator::ImageOperator;
use probes::layout::{Layout, Step};
use probes::memory::MemoryEstimate;
use probes::placement::{CandidateRule, PlacementSettings};
use probes::precompute::{Precompute, PrecomputeSettings, Stage};
use probes::projected_bounce::ProjectedBounce;
use probes::relight::RelightTable;
use probes::surfels::SurfelSettings;
use probes::transport::{TransportContext, TransportSettings};
use probes::visibility::{survey_unseen, UnseenSurvey};
use probes::ProbesError;
use serde::Serialize;
use tracer::output::{write_exr_with_attributes, write_png, Layer};

use crate::common::{write_json, TraceArgs};
use crate::compare::probes_method::MAX_PROJECTED;
use crate::outputs::{preview_of, OutputPlan};

#[derive(clap::Args)]
pub struct ProbesArgs {
    #[command(subcommand)]
    command: ProbesCommand,
}

#[derive(clap::Subcommand)]
enum ProbesCommand {
    /// Receivers, probe placement, support radius, coverage and memory of a scene.
    Stats(StatsArgs),
    /// Build the precompute (receivers, probes, transport, relight rays) and write its cache.
    Precompute(PrecomputeArgs),
    /// One relit frame from the cache (built and written first when the file does not exist):
    /// a multi-layer EXR (beauty, direct, indirect, irradiance, albedo, unseen, probes, hole)
    /// and a PNG preview.
    Relight(RelightArgs),
    /// A point light moved along a line over frames (one bounce per frame, fed back), every
    /// frame from the same cache: EXR and PNG per frame and a timing table.
    Animate(AnimateArgs),
}

/// Which empty voxels may hold a probe.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum Candidates {
    /// Next to a surface that faces the voxel (default; an extension of the paper).
    Front,
    /// Next to any surface (the paper's rule).
    Paper,
}

/// How `relight` runs the bounces after the first with the CPCA transport.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum BounceLoop {
    /// In CPCA's projected space (`probes::projected_bounce`).
    Projected,
    /// Every bounce through the relight rays and the cluster projection (`probes::frame`).
    Full,
}

/// Receivers and probe placement, shared by `stats` and `precompute`.
#[derive(clap::Args, Clone, Debug)]
pub struct PlacementArgs {
    /// Number of probes.
    #[arg(long, default_value_t = defaults::PROBES)]
    probes: usize,
    /// Receiver budget (surfels; the count comes close to it).
    #[arg(long, default_value_t = defaults::RECEIVERS)]
    receivers: usize,
    /// N_overlap: mean number of probes covering a receiver (sets the support radius).
    #[arg(long, default_value_t = defaults::OVERLAP)]
    overlap: f64,
    /// Candidate rule for probe positions.
    #[arg(long, value_enum, default_value_t = Candidates::Front)]
    candidates: Candidates,
}

impl PlacementArgs {
    /// The receivers' and the placement's settings.
    fn settings(&self, seed: u32) -> (SurfelSettings, PlacementSettings) {
        let rule = match self.candidates {
            Candidates::Front => CandidateRule::FrontFacing,
            Candidates::Paper => CandidateRule::Paper,
        };
        (
            SurfelSettings { budget: self.receivers, seed, ..Default::default() },
            PlacementSettings { probes: self.probes, overlap: self.overlap, rule },
        )
    }
}

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

pub fn run(args: &ProbesArgs) -> Result<()> {
    match &args.command {
        ProbesCommand::Stats(stats) => run_stats(stats),
        ProbesCommand::Precompute(a) => run_precompute(a),
        ProbesCommand::Relight(a) => run_relight(a),
        ProbesCommand::Animate(a) => run_animate(a),
    }
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

fn run_stats(args: &StatsArgs) -> Result<()> {
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
                    Step::Surfels => "receivers (surfels)",
                    Step::Placement => "voxels, flood fill and probe placement",
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

/// A boolean default as its flag's value (`--cpca=on|off`).
const fn on_off(value: bool) -> &'static str {
    if value {
        "on"
    } else {
        "off"
    }
}

/// The precompute's settings and its cache, shared by `precompute`, `relight` and `animate`.
#[derive(clap::Args, Clone, Debug)]
pub struct PrecomputeOptions {
    /// The precompute cache file (keyed by geometry and these settings, never by lights or
    /// albedo).
    #[arg(long)]
    cache: PathBuf,
    #[command(flatten)]
    placement: PlacementArgs,
    /// SH order of the probes (0 to 7).
    #[arg(long, default_value_t = defaults::ORDER)]
    order: usize,
    /// Directions per receiver of the transport.
    #[arg(long, default_value_t = defaults::DIRECTIONS)]
    directions: u32,
    /// Relight rays per probe.
    #[arg(long, default_value_t = defaults::RELIGHT_RAYS)]
    relight_rays: u32,
}

impl PrecomputeOptions {
    fn settings(&self, seed: u32) -> PrecomputeSettings {
        let (surfels, placement) = self.placement.settings(seed);
        PrecomputeSettings {
            surfels,
            placement,
            transport: TransportSettings { order: self.order, directions: self.directions, seed, ..Default::default() },
            relight_rays: self.relight_rays,
        }
    }
}

#[derive(clap::Args)]
pub struct PrecomputeArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[command(flatten)]
    pre: PrecomputeOptions,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// How a frame is lit and computed (`relight`, `animate`).
#[derive(clap::Args, Clone, Debug)]
pub struct FrameOptions {
    /// Remove the scene's own lights (point, spot and directional lights, emission, the
    /// environment) before adding the point light of --light-position (or the animated one).
    #[arg(long)]
    no_scene_lights: bool,
    /// Radiant intensity of the added point light (W/sr), one value or R,G,B; default
    /// (extent / 2)², which gives an irradiance of 1 at half the scene's largest extent.
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "V|R,G,B", allow_negative_numbers = true)]
    light_intensity: Option<Vec<f32>>,
    /// Light samples per sender and per primary ray for the direct light.
    #[arg(long, default_value_t = defaults::LIGHT_SAMPLES)]
    light_samples: u32,
    /// Primary rays per pixel (1: through the centre; more: stratified, averaged).
    #[arg(long, default_value_t = defaults::PIXEL_SAMPLES)]
    pixel_samples: u32,
    /// Compress the transport with CPCA before relighting (`--cpca=off`: the dense transport).
    #[arg(long, value_name = "on|off", num_args = 0..=1, require_equals = true, default_value = on_off(defaults::CPCA),
        default_missing_value = "on", value_parser = clap::builder::BoolishValueParser::new())]
    cpca: bool,
    /// CPCA: the largest relative residual energy per cluster.
    #[arg(long, default_value_t = CpcaSettings::default().tolerance)]
    cpca_tolerance: f64,
    /// CPCA: the most coefficients per cluster.
    #[arg(long, default_value_t = CpcaSettings::default().max_coefficients)]
    cpca_coefficients: usize,
    /// CPCA: clusters hold fewer receivers than this.
    #[arg(long, default_value_t = CpcaSettings::default().cluster_limit)]
    cpca_cluster_limit: usize,
    /// CPCA: store the compressed transport in fp16.
    #[arg(long)]
    fp16: bool,
    /// Weight of the relight rays that escape (or hit a lookup hole) in each probe's SH fit:
    /// 1 is the paper's projection (radiance zero along them); smaller fits the SH to the hit
    /// rays only, which are the only directions a receiver reads a probe in (docs/probes.md:
    /// Cornell's image 0.90 → 0.97 as bright as the path tracer's).
    #[arg(long, default_value_t = defaults::MISS_WEIGHT)]
    relight_miss_weight: f64,
    /// Unseen directions (hits no covering probe sees) take the mean of the receiver's seen
    /// ones instead of zero (the paper's): its transport scaled by hits / seen hits.
    #[arg(long)]
    renormalise_unseen: bool,
    /// Drop hidden senders (no transport; mostly inside geometry) from relight hits that also
    /// read valid ones (docs/probes.md: Sponza's one-bounce gather at the camera's hits 0.62 →
    /// 0.87 of the exact direct light there; Cornell's PSNR −0.14 dB).
    #[arg(long)]
    drop_hidden_senders: bool,
}

impl FrameOptions {
    /// The CPCA settings (when --cpca) and the added light's intensity, checked.
    /// Applies the run-time choices that change the precompute's use, not its cache: the
    /// relight fit and the unseen directions' fill.
    fn apply(&self, pre: &mut Precompute, pool: &rayon::ThreadPool) -> Result<()> {
        if self.drop_hidden_senders {
            pre.drop_hidden_senders()?;
        }
        if self.relight_miss_weight < 1.0 {
            pool.install(|| pre.table.fit(self.relight_miss_weight))?;
        }
        if self.renormalise_unseen {
            pre.transports.iter_mut().for_each(|t| t.renormalise_unseen());
        }
        Ok(())
    }

    fn validated(&self) -> Result<(Option<CpcaSettings>, Option<glam::Vec3>)> {
        if self.light_samples == 0 || self.light_samples > probes::direct::MAX_SAMPLES {
            anyhow::bail!(
                "light-samples: must be between 1 and {}, got {}",
                probes::direct::MAX_SAMPLES,
                self.light_samples
            );
        }
        let intensity = match self.light_intensity.as_deref() {
            None => None,
            Some(v) => {
                let c = match v {
                    [g] => glam::Vec3::splat(*g),
                    [r, g, b] => glam::Vec3::new(*r, *g, *b),
                    _ => anyhow::bail!("light-intensity: takes one value or three (R,G,B), got {}", v.len()),
                };
                if !c.is_finite() || c.min_element() < 0.0 {
                    anyhow::bail!("light-intensity: must be finite and non-negative, got {v:?}");
                }
                Some(c)
            }
        };
        if !(1..=probes::image::MAX_PIXEL_SAMPLES).contains(&self.pixel_samples) {
            anyhow::bail!(
                "pixel-samples: must be between 1 and {}, got {}",
                probes::image::MAX_PIXEL_SAMPLES,
                self.pixel_samples
            );
        }
        if self.fp16 && !self.cpca {
            anyhow::bail!("fp16: stores the CPCA-compressed transport, which --cpca=off turns off");
        }
        if !(self.relight_miss_weight > 0.0 && self.relight_miss_weight <= 1.0) {
            anyhow::bail!(
                "relight-miss-weight: must be in (0, 1] (1: the paper's projection), got {}",
                self.relight_miss_weight
            );
        }
        if self.renormalise_unseen && self.cpca {
            anyhow::bail!("renormalise-unseen: applies to the dense transport only (the CPCA cache holds the paper's); add --cpca=off");
        }
        let cpca = CpcaSettings {
            cluster_limit: self.cpca_cluster_limit,
            tolerance: self.cpca_tolerance,
            max_coefficients: self.cpca_coefficients,
            precision: if self.fp16 { Precision::F16 } else { Precision::F32 },
        };
        cpca.validate()?;
        Ok((self.cpca.then_some(cpca), intensity))
    }
}

#[derive(clap::Args)]
pub struct RelightArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[command(flatten)]
    pre: PrecomputeOptions,
    #[command(flatten)]
    frame: FrameOptions,
    /// Add a point light at X,Y,Z (with --light-intensity).
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "X,Y,Z", allow_negative_numbers = true)]
    light_position: Option<Vec<f32>>,
    /// Bounces of indirect light (0: to convergence, at most --max-bounces or the scene's).
    #[arg(long, default_value_t = 0)]
    bounces: u32,
    /// With --cpca, how the bounces after the first run: `projected` (the default: R × R
    /// products in CPCA's projected space, `probes::projected_bounce`, the matrix formed once
    /// per run; the full loop when R is over the limit) or `full` (every bounce through the
    /// relight rays and the cluster projection). The dense transport runs them in full.
    #[arg(long, value_enum)]
    bounce_loop: Option<BounceLoop>,
    /// Output EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
    /// A path-traced EXR of the same scene, size and lights (`lfr render`): the indirect layer
    /// is compared with it (PSNR, relative MSE, mean ratio).
    #[arg(long)]
    reference: Option<PathBuf>,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Diagnosis: also solve the same receivers and senders by brute-force surfel radiosity
    /// (this many cosine rays per receiver, no probes) and compare it with --reference.
    #[arg(long, default_value_t = 0)]
    brute_force_rays: u32,
}

#[derive(clap::Args)]
pub struct AnimateArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[command(flatten)]
    pre: PrecomputeOptions,
    #[command(flatten)]
    frame: FrameOptions,
    /// The point light's position in the first frame.
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "X,Y,Z", allow_negative_numbers = true)]
    light_from: Vec<f32>,
    /// The point light's position in the last frame (straight line between).
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "X,Y,Z", allow_negative_numbers = true)]
    light_to: Vec<f32>,
    /// Number of frames.
    #[arg(long, default_value_t = 8)]
    frames: u32,
    /// Bounces per frame, each frame starting from the last one's indirect light (the paper's
    /// feedback).
    #[arg(long, default_value_t = 1)]
    bounces_per_frame: u32,
    /// Folder for frame_NNNN.exr, frame_NNNN.png and timings.json.
    #[arg(long)]
    out_dir: PathBuf,
}

/// A point option: three finite numbers.
fn point_option(name: &str, values: &[f32]) -> Result<glam::Vec3> {
    match values {
        [x, y, z] if [x, y, z].iter().all(|v| v.is_finite()) => Ok(glam::Vec3::new(*x, *y, *z)),
        _ => anyhow::bail!("{name}: takes a finite point X,Y,Z, got {values:?}"),
    }
}

/// The progress bar of the long steps.
fn spinner(quiet: bool, what: &'static str) -> ProgressBar {
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new_spinner() };
    bar.set_style(
        ProgressStyle::with_template(&format!("{{spinner}} probes {what}: {{msg}} [{{elapsed_precise}}]"))
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// Whether `precompute` may replace a cache that cannot be used, or the error stands.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stale {
    Replace,
    Refuse,
}

/// The precompute of `scene` from `cache` when it holds this scene's, else built (with
/// progress) and written there; with `Stale::Refuse` a cache that cannot be used is an error.
/// Returns it, whether it came from the cache, and the seconds it took.
pub(crate) fn obtain(
    scene: &tracer::Scene,
    settings: &PrecomputeSettings,
    cache: &Path,
    stale: Stale,
    pool: &rayon::ThreadPool,
    bar: &ProgressBar,
) -> Result<(Precompute, bool, f64)> {
    let key = CacheKey::of(scene, settings);
    let t = Instant::now();
    if std::fs::symlink_metadata(cache).is_ok() {
        bar.set_message("reading the cache");
        match probes::cache::read(cache, &key, settings) {
            Ok(pre) => return Ok((pre, true, t.elapsed().as_secs_f64())),
            Err(ProbesError::Cache { problem, .. })
                if stale == Stale::Replace && !matches!(problem, CacheProblem::NotACache | CacheProblem::Io) =>
            {
                bar.suspend(|| eprintln!("note: {} cannot be used: {problem}; building it again", cache.display()));
            }
            Err(e) => return Err(e.into()),
        }
    }
    // Each step's name, with its receivers or probes done and the time left where it counts
    // them (`shading::progress`).
    let message = std::sync::Mutex::new(String::from("precompute"));
    let build = || {
        pool.install(|| {
            Precompute::build(scene, settings, &mut |stage| {
                let name = match stage {
                    Stage::Layout(Step::Surfels) => "receivers (surfels)",
                    Stage::Layout(Step::Placement) => "voxels, flood fill and probe placement",
                    Stage::Layout(Step::Radius) => "support radius",
                    Stage::Layout(Step::Coverage) => "coverage",
                    Stage::Transport => "transport of every receiver (the long step)",
                    Stage::Relight => "relight rays",
                };
                *message.lock().unwrap_or_else(|e| e.into_inner()) = name.to_string();
                bar.set_message(name);
            })
        })
    };
    let pre = crate::common::with_changing_progress(bar, &message, None, build)
        .with_context(|| format!("precompute on {}", scene.source.display()))?;
    bar.set_message("writing the cache");
    probes::cache::write(cache, &key, &pre)?;
    Ok((pre, false, t.elapsed().as_secs_f64()))
}

#[derive(Serialize)]
struct PrecomputeReport {
    scene: String,
    cache: String,
    cache_bytes: u64,
    precompute_from_cache: bool,
    precompute_s: f64,
    layout_s: f64,
    transport_s: f64,
    relight_rays_s: f64,
    receivers: usize,
    hidden_receivers: usize,
    probes: usize,
    support_radius: f64,
    dense_transport_bytes: usize,
    dense_transport_bytes_per_receiver: f64,
}

fn precompute_report(
    scene: &tracer::Scene,
    cache: &Path,
    pre: &Precompute,
    from_cache: bool,
    s: f64,
) -> PrecomputeReport {
    let n = pre.surfels.surfels.len();
    PrecomputeReport {
        scene: scene.source.display().to_string(),
        cache: cache.display().to_string(),
        cache_bytes: std::fs::metadata(cache).map(|m| m.len()).unwrap_or(0),
        precompute_from_cache: from_cache,
        precompute_s: s,
        layout_s: pre.timings.layout_s,
        transport_s: pre.timings.transport_s,
        relight_rays_s: pre.timings.relight_s,
        receivers: n,
        hidden_receivers: pre.hidden,
        probes: pre.probes.len(),
        support_radius: pre.radius,
        dense_transport_bytes: pre.dense_transport_bytes(),
        dense_transport_bytes_per_receiver: pre.dense_transport_bytes() as f64 / n.max(1) as f64,
    }
}

fn print_precompute(r: &PrecomputeReport) {
    if r.precompute_from_cache {
        println!(
            "precompute  from the cache {} ({:.1} MB) in {:.2} s",
            r.cache,
            r.cache_bytes as f64 / 1e6,
            r.precompute_s
        );
    } else {
        println!(
            "precompute  {:.1} s (layout {:.1} s, transport {:.1} s, relight rays {:.1} s); cache {} ({:.1} MB)",
            r.precompute_s,
            r.layout_s,
            r.transport_s,
            r.relight_rays_s,
            r.cache,
            r.cache_bytes as f64 / 1e6
        );
    }
    println!(
        "            {} receivers ({} hidden), {} probes, radius {:.4e}; dense transport {:.1} MB = {:.0} B per receiver",
        r.receivers,
        r.hidden_receivers,
        r.probes,
        r.support_radius,
        r.dense_transport_bytes as f64 / 1e6,
        r.dense_transport_bytes_per_receiver
    );
}

/// Checks the precompute settings and the outputs in `plan` with the cache (read when it holds
/// this precompute, else written) among them, all before the scene is read; returns the
/// settings and the plan, to be checked again with the scene's files once it is loaded.
fn check_common(
    trace: &TraceArgs,
    pre: &PrecomputeOptions,
    mut plan: OutputPlan,
) -> Result<(PrecomputeSettings, OutputPlan)> {
    let settings = pre.settings(trace.seed());
    settings.validate()?;
    trace.run.thread_count()?;
    plan.file(&pre.cache, "the precompute cache (--cache)").scene_file(trace.scene.as_deref()).check()?;
    Ok((settings, plan))
}

/// Refuses the run when its estimated peak memory (`probes::memory`) is over what the machine
/// has available (`tracer::memory`; `LFR_MEMORY_AVAILABLE` replaces the measurement). Called
/// after the scene is read (its memory is then out of the measured available memory) and
/// before the precompute, the cache read or any frame.
fn check_memory(what: &str, estimate: &MemoryEstimate) -> Result<()> {
    tracer::memory::check(&estimate.describe(what), estimate.total())?;
    Ok(())
}

/// The estimate of a relit frame (`relight`, `animate`): the precompute or its cache, CPCA and
/// the projected bounce when asked for, and the image.
pub(crate) fn frame_estimate(
    settings: &PrecomputeSettings,
    cpca: Option<&CpcaSettings>,
    projected: bool,
    image: &ImageSettings,
    threads: usize,
) -> MemoryEstimate {
    let mut e = MemoryEstimate::precompute(settings, threads);
    if let Some(cpca) = cpca {
        e = e.with_cpca(settings, cpca, threads, projected.then_some(MAX_PROJECTED));
    }
    e.with_image(image.width, image.height, image.pixel_samples)
}

fn run_precompute(args: &PrecomputeArgs) -> Result<()> {
    let mut plan = OutputPlan::new();
    if let Some(json) = &args.json {
        plan.file(json, "--json");
    }
    let (settings, mut plan) = check_common(&args.trace, &args.pre, plan)?;
    let scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    let threads = args.trace.run.thread_count()?;
    check_memory("the probes precompute", &MemoryEstimate::precompute(&settings, threads))?;
    let pool = tracer::render::thread_pool(threads)?;
    let bar = spinner(args.trace.quiet, "precompute");
    let (pre, from_cache, s) = obtain(&scene, &settings, &args.pre.cache, Stale::Replace, &pool, &bar)?;
    bar.finish_and_clear();
    let report = precompute_report(&scene, &args.pre.cache, &pre, from_cache, s);
    print_precompute(&report);
    if let Some(json) = &args.json {
        write_json(json, &report)?;
    }
    Ok(())
}

/// `scene` lit for a frame: its own lights unless --no-scene-lights, plus a point light at
/// `light` when given.
fn lit_scene(scene: &tracer::Scene, no_scene_lights: bool, light: Option<(glam::Vec3, glam::Vec3)>) -> tracer::Scene {
    let mut lit = scene.clone();
    if no_scene_lights {
        lit.lights.clear();
        lit.environment = glam::Vec3::ZERO;
        for m in &mut lit.materials {
            m.emission = glam::Vec3::ZERO;
            m.emission_texture = None;
        }
    }
    if let Some((position, intensity)) = light {
        lit.lights.push(tracer::scene::PunctualLight::Point { position, intensity });
    }
    lit
}

/// The dense transports or their CPCA compression.
pub(crate) enum Operator<'a> {
    Dense(&'a Vec<probes::transport::Transport>),
    Cpca(Cpca),
}

impl Operator<'_> {
    pub(crate) fn transport(&self) -> &dyn ReceiverTransport {
        match self {
            Operator::Dense(t) => *t,
            Operator::Cpca(c) => c,
        }
    }
}

#[derive(Serialize)]
pub(crate) struct CpcaReport {
    pub(crate) clusters: usize,
    pub(crate) mean_coefficients: f64,
    pub(crate) max_cluster_error: f64,
    pub(crate) tolerance: f64,
    pub(crate) fp16: bool,
    pub(crate) bytes: usize,
    pub(crate) bytes_per_receiver: f64,
    /// Seconds to compress, or to read from the cache.
    pub(crate) compress_s: f64,
    pub(crate) from_cache: bool,
    pub(crate) cache: String,
}

/// The compressed transport's cache beside the precompute's: `CACHE.cpca`.
pub(crate) fn cpca_path(cache: &Path) -> PathBuf {
    let mut name = cache.as_os_str().to_os_string();
    name.push(".cpca");
    PathBuf::from(name)
}

/// The dense transports, or with `settings` their CPCA compression, read from
/// [`cpca_path`] when it holds this one (keyed by the precompute's key and the CPCA
/// settings), else compressed and written there.
pub(crate) fn operator<'a>(
    pre: &'a Precompute,
    settings: Option<CpcaSettings>,
    pool: &rayon::ThreadPool,
    cache: &Path,
    key: &CacheKey,
) -> Result<(Operator<'a>, Option<CpcaReport>)> {
    let Some(settings) = settings else {
        return Ok((Operator::Dense(&pre.transports), None));
    };
    let t = Instant::now();
    let path = cpca_path(cache);
    let ckey = probes::cache::cpca_key(key, &settings);
    // A compressed transport of other settings, geometry or version is replaced (one file per
    // precompute cache); a damaged one or another file is an error naming it.
    let cached = match std::fs::symlink_metadata(&path) {
        Err(_) => None,
        Ok(_) => match probes::cache::read_cpca(&path, &ckey, &settings, pre) {
            Ok(cpca) => Some(cpca),
            Err(ProbesError::Cache { problem, .. })
                if matches!(
                    problem,
                    CacheProblem::OtherSettings | CacheProblem::OtherGeometry | CacheProblem::Version
                ) =>
            {
                eprintln!("note: {} holds another compression ({problem}); replacing it", path.display());
                None
            }
            Err(e) => return Err(e.into()),
        },
    };
    let from_cache = cached.is_some();
    let cpca = match cached {
        Some(cpca) => cpca,
        None => {
            let positions: Vec<glam::Vec3> = pre.surfels.surfels.iter().map(|s| s.position).collect();
            let cpca = pool.install(|| Cpca::build(&pre.transports, &positions, pre.coefficients(), &settings))?;
            probes::cache::write_cpca(&path, &ckey, &cpca)?;
            cpca
        }
    };
    let report = CpcaReport {
        clusters: cpca.clusters.len(),
        mean_coefficients: cpca.mean_rank(),
        max_cluster_error: cpca.clusters.iter().map(|c| c.error).fold(0.0, f64::max),
        tolerance: settings.tolerance,
        fp16: settings.precision == Precision::F16,
        bytes: cpca.bytes(),
        bytes_per_receiver: cpca.bytes() as f64 / pre.surfels.surfels.len().max(1) as f64,
        compress_s: t.elapsed().as_secs_f64(),
        from_cache,
        cache: path.display().to_string(),
    };
    Ok((Operator::Cpca(cpca), Some(report)))
}

/// One relit frame's seconds, split as the paper's Table 2 (scene relight, probe relight,
/// cluster projection, receiver irradiance), plus the image.
#[derive(Serialize, Clone, Copy, Debug)]
pub(crate) struct FrameTimes {
    /// Scene relight: direct light at the senders.
    pub(crate) direct_s: f64,
    /// The bounces, all three stages below together.
    pub(crate) bounces_s: f64,
    /// Probe relight (sender radiance, the relight rays' SH and the fit), summed over the
    /// bounces.
    pub(crate) probe_relight_s: f64,
    /// Cluster projection (CPCA only), summed over the bounces.
    pub(crate) cluster_projection_s: f64,
    /// Receiver irradiance (and the clamp and convergence test), summed over the bounces.
    pub(crate) receiver_irradiance_s: f64,
    /// The bounces after the first in CPCA's projected space (all three stages at once), when
    /// they run there.
    pub(crate) projected_bounces_s: f64,
    pub(crate) iterations: usize,
    /// The image from the receivers: the kept lookups' weighted sums when the camera's image
    /// operator was built, else primary rays and lookups.
    pub(crate) image_s: f64,
    /// Direct light at the senders and the bounces: the relit frame without the image.
    pub(crate) frame_s: f64,
}

#[derive(Serialize)]
struct RelightReport {
    precompute: PrecomputeReport,
    cpca: Option<CpcaReport>,
    width: u32,
    height: u32,
    light_position: Option<[f32; 3]>,
    light_intensity: Option<[f32; 3]>,
    /// Seconds to trace the camera's primary rays and keep their lookups (once per camera).
    image_operator_s: f64,
    image_operator_bytes: usize,
    /// How the bounces after the first ran: `projected` or `full`.
    bounce_loop: &'static str,
    /// The projected bounces' matrix, when they ran projected.
    projected: Option<ProjectedReport>,
    times: FrameTimes,
    clamped_channels: u64,
    lookup_holes: u64,
    lookup_nearest: u64,
    misses: u64,
    mean_indirect: [f32; 3],
    reference: Option<ReferenceReport>,
}

/// The projected bounces' matrix M (`probes::projected_bounce`).
#[derive(Serialize)]
struct ProjectedReport {
    /// R: projected values in all clusters (M is R × R per channel).
    size: usize,
    bytes: usize,
    /// Seconds to form M (once per run: it depends on the albedo, not the light).
    build_s: f64,
}

#[derive(Serialize)]
struct ReferenceReport {
    path: String,
    /// PSNR of the indirect layer under the display transform of `lfr compare` (exposure from
    /// the reference's 99th percentile).
    indirect_psnr_db: f64,
    indirect_relative_mse: f64,
    /// Mean indirect radiance of this image over the reference's, per channel.
    indirect_mean_ratio: [f64; 3],
    /// Pixels whose receivers have no transport (hidden, or no probe in range: the `probes`
    /// layer below one half), and the share of the reference's indirect light in them.
    pixels_without_probes: f64,
    reference_share_without_probes: f64,
    /// Mean direct radiance of this image over the reference's (when it has a direct layer).
    direct_mean_ratio: Option<[f64; 3]>,
}

/// The `indirect.R,G,B` layer of a path-traced EXR, `width` × `height`.
fn read_indirect(path: &Path, width: u32, height: u32) -> Result<recon::Image> {
    let (w, h, channels) = tracer::output::read_exr(path).with_context(|| format!("reading {}", path.display()))?;
    if (w, h) != (width, height) {
        anyhow::bail!("reference {}: {w}x{h}, the image is {width}x{height}", path.display());
    }
    let find = |name: &str| -> Result<&Vec<f32>> {
        channels
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v)
            .ok_or_else(|| anyhow::anyhow!("reference {}: no channel {name}", path.display()))
    };
    let (r, g, b) = (find("indirect.R")?, find("indirect.G")?, find("indirect.B")?);
    Ok(recon::Image { width, height, pixels: (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect() })
}

fn compare_indirect(path: &Path, img: &ProbeImage) -> Result<ReferenceReport> {
    let reference = read_indirect(path, img.width, img.height)?;
    let test = recon::Image {
        width: img.width,
        height: img.height,
        pixels: img.indirect.iter().map(|v| v.to_array()).collect(),
    };
    let tone = recon::metrics::ToneMap::auto(&reference);
    let psnr = recon::metrics::psnr_db(&reference, &test, &tone).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let rel = recon::metrics::relative_mse(&reference, &test).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let mut ratio = [0.0; 3];
    for (c, r) in ratio.iter_mut().enumerate() {
        let a: f64 = test.pixels.iter().map(|p| p[c] as f64).sum();
        let b: f64 = reference.pixels.iter().map(|p| p[c] as f64).sum();
        *r = if b > 0.0 { a / b } else { f64::NAN };
    }
    // The direct layer's mean ratio too (the pixels' albedo, normals and lights checked).
    let direct_mean_ratio = match tracer::output::read_exr(path) {
        Ok((_, _, channels)) => {
            let layer = |name: &str| channels.iter().find(|(n, _)| n == name).map(|(_, v)| v);
            match (layer("direct.R"), layer("direct.G"), layer("direct.B")) {
                (Some(r), Some(g), Some(b)) => {
                    let mut out = [0.0; 3];
                    for (c, values) in [r, g, b].into_iter().enumerate() {
                        let a: f64 = img.direct.iter().map(|v| v[c] as f64).sum();
                        let b: f64 = values.iter().map(|&v| v as f64).sum();
                        out[c] = if b > 0.0 { a / b } else { f64::NAN };
                    }
                    Some(out)
                }
                _ => None,
            }
        }
        Err(_) => None,
    };
    let without: Vec<bool> = img.probes.iter().map(|&p| p < 0.5).collect();
    let luminance = |p: &[f32; 3]| (p[0] + p[1] + p[2]) as f64;
    let total: f64 = reference.pixels.iter().map(luminance).sum();
    let share: f64 = reference.pixels.iter().zip(&without).filter(|(_, &w)| w).map(|(p, _)| luminance(p)).sum();
    Ok(ReferenceReport {
        pixels_without_probes: without.iter().filter(|&&w| w).count() as f64 / without.len().max(1) as f64,
        reference_share_without_probes: if total > 0.0 { share / total } else { 0.0 },
        path: path.display().to_string(),
        indirect_psnr_db: psnr,
        indirect_relative_mse: rel,
        indirect_mean_ratio: ratio,
        direct_mean_ratio,
    })
}

/// One relit frame: direct light at the senders, bounces (from `start`), the image (through
/// `camera`'s kept lookups when given, built for `image`; else traced and looked up).
#[allow(clippy::too_many_arguments)]
pub(crate) fn relit_frame(
    lit: &tracer::Scene,
    accel: &tracer::Accel,
    pre: &Precompute,
    op: &Operator,
    projected: Option<&ProjectedBounce>,
    start: Option<&[glam::Vec3]>,
    bounces: usize,
    tolerance: f32,
    light_samples: u32,
    image: &ImageSettings,
    camera: Option<&ImageOperator>,
    pool: &rayon::ThreadPool,
) -> Result<(Indirect, ProbeImage, FrameTimes)> {
    pool.install(|| {
        let albedo = surfel_albedo(lit, &pre.surfels);
        let scale = pre.scale as f32;
        let t = Instant::now();
        let direct = direct_irradiance(lit, accel, &pre.surfels, light_samples, image.seed, scale)?;
        let direct_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let (out, split) = match (projected, op) {
            (Some(projected), Operator::Cpca(cpca)) => {
                projected.indirect(cpca, &pre.table, &albedo, &direct, start, bounces, tolerance)?
            }
            (Some(_), Operator::Dense(_)) => anyhow::bail!("internal: projected bounces need the CPCA transport"),
            (None, op) => indirect_timed(op.transport(), &pre.table, &albedo, &direct, start, bounces, tolerance)?,
        };
        let bounces_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let img = match camera {
            Some(camera) => {
                if camera.settings != *image {
                    anyhow::bail!("internal: the image operator was built for other image settings");
                }
                camera.render(lit, accel, &out.irradiance)?
            }
            None => render_image(lit, accel, pre, &out.irradiance, image)?,
        };
        let image_s = t.elapsed().as_secs_f64();
        let times = FrameTimes {
            direct_s,
            bounces_s,
            probe_relight_s: split.probe_relight_s,
            cluster_projection_s: split.cluster_projection_s,
            receiver_irradiance_s: split.receiver_irradiance_s,
            projected_bounces_s: split.projected_bounces_s,
            iterations: out.iterations,
            image_s,
            frame_s: direct_s + bounces_s,
        };
        Ok((out, img, times))
    })
}

/// The camera's image operator (the lookups kept for every frame) and its build seconds.
pub(crate) fn image_operator(
    lit: &tracer::Scene,
    accel: &tracer::Accel,
    pre: &Precompute,
    image: &ImageSettings,
    pool: &rayon::ThreadPool,
) -> Result<(ImageOperator, f64)> {
    let t = Instant::now();
    let camera = pool.install(|| ImageOperator::build(lit, accel, pre, image))?;
    Ok((camera, t.elapsed().as_secs_f64()))
}

/// Writes the image's layers and its PNG preview.
fn write_image(path: &Path, img: &ProbeImage, description: String) -> Result<PathBuf> {
    let rgb = |v: &[glam::Vec3]| -> Vec<(&'static str, Vec<f32>)> {
        vec![
            ("R", v.iter().map(|p| p.x).collect()),
            ("G", v.iter().map(|p| p.y).collect()),
            ("B", v.iter().map(|p| p.z).collect()),
        ]
    };
    let layers = vec![
        Layer { name: "", channels: rgb(&img.beauty) },
        Layer { name: "direct", channels: rgb(&img.direct) },
        Layer { name: "indirect", channels: rgb(&img.indirect) },
        Layer { name: "irradiance", channels: rgb(&img.irradiance) },
        Layer { name: "albedo", channels: rgb(&img.albedo) },
        Layer { name: "unseen", channels: vec![("Y", img.unseen.clone())] },
        Layer { name: "probes", channels: vec![("Y", img.probes.clone())] },
        Layer { name: "hole", channels: vec![("Y", img.hole.clone())] },
    ];
    write_exr_with_attributes(path, img.width, img.height, &layers, &[("lfr.probes", description)])
        .with_context(|| format!("writing {}", path.display()))?;
    let preview = path.with_extension("png");
    write_png(&preview, img.width, img.height, &img.beauty, 1.0)
        .with_context(|| format!("writing {}", preview.display()))?;
    Ok(preview)
}

fn description(
    settings: &PrecomputeSettings,
    scene: &tracer::Scene,
    transport: &str,
    light: Option<glam::Vec3>,
) -> String {
    format!(
        "scene={} probes={} receivers={} overlap={} order={} directions={} relight_rays={} seed={} transport={} light={}",
        scene.source.display(),
        settings.placement.probes,
        settings.surfels.budget,
        settings.placement.overlap,
        settings.transport.order,
        settings.transport.directions,
        settings.relight_rays,
        settings.surfels.seed,
        transport,
        light.map_or("scene".to_string(), |p| format!("point {},{},{}", p.x, p.y, p.z))
    )
    .chars()
    .filter(|c| (*c as u32) < 256)
    .collect()
}

fn image_settings(trace: &TraceArgs, scene: &tracer::Scene, frame: &FrameOptions) -> Result<ImageSettings> {
    let image = ImageSettings {
        width: trace.size.width.unwrap_or(scene.width),
        height: trace.size.height.unwrap_or(scene.height),
        light_samples: frame.light_samples,
        pixel_samples: frame.pixel_samples,
        seed: trace.seed(),
    };
    image.validate()?;
    Ok(image)
}

/// The frame split as the paper's Table 2.
fn print_split(t: &FrameTimes) {
    println!(
        "split       scene relight {:.4} s | probe relight {:.4} s | cluster projection {:.4} s | receiver irradiance {:.4} s | projected bounces {:.4} s ({} bounces) | image {:.4} s | frame with image {:.4} s",
        t.direct_s,
        t.probe_relight_s,
        t.cluster_projection_s,
        t.receiver_irradiance_s,
        t.projected_bounces_s,
        t.iterations,
        t.image_s,
        t.frame_s + t.image_s
    );
}

fn run_relight(args: &RelightArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        anyhow::bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let (cpca_settings, intensity) = args.frame.validated()?;
    if args.bounces > 10_000 {
        anyhow::bail!("bounces: must be at most 10000 (0: to convergence), got {}", args.bounces);
    }
    if args.bounce_loop == Some(BounceLoop::Projected) && cpca_settings.is_none() {
        anyhow::bail!("bounce-loop: projected runs in CPCA's projected space, which --cpca=off turns off");
    }
    let position = args.light_position.as_deref().map(|v| point_option("light-position", v)).transpose()?;
    if intensity.is_some() && position.is_none() {
        anyhow::bail!("light-intensity: needs --light-position");
    }
    if let Some(reference) = &args.reference {
        if !reference.is_file() {
            anyhow::bail!("reference: {} is not a file", reference.display());
        }
    }
    let mut plan = OutputPlan::new();
    plan.file(&args.out, "--out").file(&preview_of(&args.out), "the PNG preview beside --out");
    if let Some(json) = &args.json {
        plan.file(json, "--json");
    }
    if cpca_settings.is_some() {
        plan.file(&cpca_path(&args.pre.cache), "the CPCA cache beside --cache");
    }
    if let Some(reference) = &args.reference {
        plan.input(reference, "--reference");
    }
    let (settings, mut plan) = check_common(&args.trace, &args.pre, plan)?;
    let scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    let image = image_settings(&args.trace, &scene, &args.frame)?;
    let threads = args.trace.run.thread_count()?;
    let projected = args.bounce_loop.unwrap_or(BounceLoop::Projected) == BounceLoop::Projected;
    check_memory("the probes relight", &frame_estimate(&settings, cpca_settings.as_ref(), projected, &image, threads))?;
    let pool = tracer::render::thread_pool(threads)?;
    let bar = spinner(args.trace.quiet, "relight");
    let (mut pre, from_cache, s) = obtain(&scene, &settings, &args.pre.cache, Stale::Refuse, &pool, &bar)?;
    args.frame.apply(&mut pre, &pool)?;
    let light = position.map(|p| (p, intensity.unwrap_or(glam::Vec3::splat((0.5 * pre.scale as f32).powi(2)))));
    let lit = lit_scene(&scene, args.frame.no_scene_lights, light);
    let accel = tracer::Accel::build(&lit)?;
    bar.set_message("compressing the transport (CPCA)");
    let key = CacheKey::of(&scene, &settings);
    let (op, cpca) = operator(&pre, cpca_settings, &pool, &args.pre.cache, &key)?;
    bar.set_message("relighting");
    let max_bounces = args.trace.size.max_bounces.unwrap_or(scene.max_bounces).max(1) as usize;
    let (bounces, tolerance) =
        if args.bounces == 0 { (max_bounces, defaults::BOUNCE_TOLERANCE) } else { (args.bounces as usize, 0.0) };
    // The bounces' matrix in CPCA's projected space depends on the albedo, not the light:
    // formed once per run, as `lfr compare` does.
    let mut projected_report = None;
    let projected = match (&op, args.bounce_loop.unwrap_or(BounceLoop::Projected)) {
        (Operator::Cpca(c), BounceLoop::Projected) => {
            let size: usize = c.clusters.iter().map(|c| c.rank).sum();
            if size > MAX_PROJECTED {
                bar.suspend(|| {
                    eprintln!(
                        "note: bounce-loop: {size} projected values (over {MAX_PROJECTED}): the bounces run in full"
                    )
                });
                None
            } else {
                bar.set_message("forming the projected bounce");
                let t = Instant::now();
                let albedo = pool.install(|| surfel_albedo(&lit, &pre.surfels));
                let projected = pool.install(|| ProjectedBounce::build(c, &pre.table, &albedo))?;
                projected_report = Some(ProjectedReport {
                    size: projected.size,
                    bytes: projected.bytes(),
                    build_s: t.elapsed().as_secs_f64(),
                });
                Some(projected)
            }
        }
        _ => None,
    };
    bar.set_message("tracing the camera's lookups");
    let (camera, image_operator_s) = image_operator(&lit, &accel, &pre, &image, &pool)?;
    bar.set_message("relighting");
    let (out, img, times) = relit_frame(
        &lit,
        &accel,
        &pre,
        &op,
        projected.as_ref(),
        None,
        bounces,
        tolerance,
        image.light_samples,
        &image,
        Some(&camera),
        &pool,
    )?;
    let reference = args.reference.as_deref().map(|p| compare_indirect(p, &img)).transpose()?;
    if args.brute_force_rays > 0 {
        let Some(path) = args.reference.as_deref() else {
            anyhow::bail!("brute-force-rays: needs --reference");
        };
        bar.set_message("brute-force surfel radiosity");
        let t = Instant::now();
        let (e, img) = pool.install(|| -> Result<_> {
            let gathers = probes::gather::Gathers::build(
                &accel,
                &pre.surfels,
                &pre.transports,
                args.brute_force_rays,
                pre.scale as f32,
            );
            let albedo = surfel_albedo(&lit, &pre.surfels);
            let direct = direct_irradiance(&lit, &accel, &pre.surfels, image.light_samples, image.seed, pre.scale as f32)?;
            let e = gathers.indirect(&albedo, &direct, bounces, tolerance);
            let sender: Vec<glam::Vec3> =
                albedo.iter().zip(&direct).map(|(a, d)| *a * *d / std::f32::consts::PI).collect();
            let (via, exact) = probes::gather::one_bounce_split(
                &lit,
                &accel,
                &pre.surfels,
                &pre.transports,
                &sender,
                64,
                17,
                64,
                pre.scale as f32,
            );
            bar.suspend(|| println!("one bounce: senders through the lookup / direct light exact at each hit {}", via / exact));
            let at_pixels = probes::gather::pixel_gather(
                &lit,
                &accel,
                &pre.surfels,
                &sender,
                (image.width, image.height),
                256,
                pre.scale as f32,
            );
            let [via, exact, shading, valid] = probes::gather::pixel_gather_split(
                &lit,
                &accel,
                &pre.surfels,
                &pre.transports,
                &sender,
                (image.width, image.height),
                64,
                image.light_samples.min(4),
                pre.scale as f32,
            );
            bar.suspend(|| {
                println!(
                    "one bounce at the pixels (64 rays): senders through the lookup / direct light exact at each secondary hit {:.4} {:.4} {:.4}; exact about the shading normal / about the geometric {:.4} {:.4} {:.4}",
                    via.x / exact.x,
                    via.y / exact.y,
                    via.z / exact.z,
                    shading.x / exact.x,
                    shading.y / exact.y,
                    shading.z / exact.z
                );
                println!(
                    "            senders through the lookup with hidden senders dropped beside the others / exact {:.4} {:.4} {:.4}",
                    valid.x / exact.x,
                    valid.y / exact.y,
                    valid.z / exact.z
                )
            });
            let reference = read_indirect(path, image.width, image.height)?;
            let (a, b): (f64, f64) = at_pixels
                .iter()
                .zip(&reference.pixels)
                .fold((0.0, 0.0), |(a, b), (p, r)| (a + p.x as f64, b + r[0] as f64));
            let from_receivers: f64 = img.indirect.iter().map(|p| p.x as f64).sum();
            bar.suspend(|| {
                println!(
                    "one bounce at the pixels with the direct light exact at each secondary hit / reference (R): {:.4}",
                    exact.x / b
                )
            });
            bar.suspend(|| {
                println!(
                    "one bounce gathered at the pixels (256 rays, senders' direct radiance) / reference (R): {:.4}; the probes' image / it {:.4}",
                    a / b,
                    from_receivers / a
                )
            });
            let img = render_image(&lit, &accel, &pre, &e, &image)?;
            Ok((e, img))
        })?;
        let r = compare_indirect(path, &img)?;
        let probes_mean: f64 = out.irradiance.iter().map(|v| v.element_sum() as f64).sum();
        let brute_mean: f64 = e.iter().map(|v| v.element_sum() as f64).sum();
        bar.suspend(|| {
            println!(
                "brute force {} rays per receiver, {:.1} s: PSNR {:.2} dB, mean ratio {:.3} {:.3} {:.3}; probes' receiver irradiance / brute force's {:.3}",
                args.brute_force_rays,
                t.elapsed().as_secs_f64(),
                r.indirect_psnr_db,
                r.indirect_mean_ratio[0],
                r.indirect_mean_ratio[1],
                r.indirect_mean_ratio[2],
                probes_mean / brute_mean.max(1e-30)
            )
        });
    }
    bar.set_message("writing the image");
    let transport = if cpca.is_some() { "cpca" } else { "dense" };
    write_image(&args.out, &img, description(&settings, &scene, transport, position))?;
    bar.finish_and_clear();
    let n = img.indirect.len().max(1) as f32;
    let report = RelightReport {
        precompute: precompute_report(&scene, &args.pre.cache, &pre, from_cache, s),
        cpca,
        width: img.width,
        height: img.height,
        light_position: position.map(|p| p.to_array()),
        light_intensity: light.map(|l| l.1.to_array()),
        image_operator_s,
        image_operator_bytes: camera.bytes(),
        bounce_loop: if projected.is_some() { "projected" } else { "full" },
        projected: projected_report,
        times,
        clamped_channels: out.clamped,
        lookup_holes: img.lookups.holes,
        lookup_nearest: img.lookups.nearest,
        misses: img.misses,
        mean_indirect: (img.indirect.iter().fold(glam::Vec3::ZERO, |a, v| a + *v) / n).to_array(),
        reference,
    };
    print_precompute(&report.precompute);
    if let Some(c) = &report.cpca {
        println!(
            "cpca        {} clusters, {:.1} coefficients per receiver on average, largest cluster error {:.2e} (tolerance {}), {} B per receiver{} {} {:.2} s",
            c.clusters,
            c.mean_coefficients,
            c.max_cluster_error,
            c.tolerance,
            c.bytes_per_receiver.round(),
            if c.fp16 { " (fp16)" } else { "" },
            if c.from_cache { "read from the cache in" } else { "compressed in" },
            c.compress_s
        );
    }
    if let Some(p) = &report.projected {
        println!(
            "bounces     after the first in CPCA's projected space: R = {}, M formed in {:.2} s ({:.1} MB; once per run)",
            p.size,
            p.build_s,
            p.bytes as f64 / 1e6
        );
    }
    let t = &report.times;
    println!(
        "camera      primary rays and their lookups kept in {:.4} s ({:.1} MB; once per camera)",
        report.image_operator_s,
        report.image_operator_bytes as f64 / 1e6
    );
    println!(
        "frame       {:.4} s: direct light at the senders {:.4} s, {} bounces {:.4} s ({} channels clamped); image {}x{} {:.4} s ({} lookup holes, {} misses)",
        t.frame_s,
        t.direct_s,
        t.iterations,
        t.bounces_s,
        report.clamped_channels,
        img.width,
        img.height,
        t.image_s,
        report.lookup_holes,
        report.misses
    );
    print_split(t);
    if let Some(r) = &report.reference {
        println!(
            "reference   indirect layer against {}: PSNR {:.2} dB, relative MSE {:.4e}, mean ratio {:.3} {:.3} {:.3}",
            r.path,
            r.indirect_psnr_db,
            r.indirect_relative_mse,
            r.indirect_mean_ratio[0],
            r.indirect_mean_ratio[1],
            r.indirect_mean_ratio[2]
        );
        println!(
            "            pixels without a covering probe (hidden receivers) {:.2} %, holding {:.2} % of the reference's indirect light",
            100.0 * r.pixels_without_probes,
            100.0 * r.reference_share_without_probes
        );
        if let Some([dr, dg, db]) = r.direct_mean_ratio {
            println!("            direct layer mean ratio {dr:.3} {dg:.3} {db:.3}");
        }
    }
    println!("wrote {} and {}", args.out.display(), preview_of(&args.out).display());
    if let Some(json) = &args.json {
        write_json(json, &report)?;
    }
    Ok(())
}

#[derive(Serialize)]
struct AnimateFrame {
    frame: u32,
    light_position: [f32; 3],
    /// Scene relight (direct light at the senders).
    direct_s: f64,
    bounces_s: f64,
    probe_relight_s: f64,
    cluster_projection_s: f64,
    receiver_irradiance_s: f64,
    /// The image through the camera's kept lookups.
    image_s: f64,
    frame_s: f64,
    mean_indirect: [f32; 3],
}

#[derive(Serialize)]
struct AnimateReport {
    precompute: PrecomputeReport,
    cpca: Option<CpcaReport>,
    bounces_per_frame: u32,
    /// Seconds to trace the camera's primary rays and keep their lookups (once).
    image_operator_s: f64,
    frames: Vec<AnimateFrame>,
    mean_frame_s: f64,
    worst_frame_s: f64,
}

fn run_animate(args: &AnimateArgs) -> Result<()> {
    let (cpca_settings, intensity) = args.frame.validated()?;
    let from = point_option("light-from", &args.light_from)?;
    let to = point_option("light-to", &args.light_to)?;
    if !(1..=100_000).contains(&args.frames) {
        anyhow::bail!("frames: must be between 1 and 100000, got {}", args.frames);
    }
    if !(1..=1000).contains(&args.bounces_per_frame) {
        anyhow::bail!("bounces-per-frame: must be between 1 and 1000, got {}", args.bounces_per_frame);
    }
    let names: Vec<(PathBuf, PathBuf)> = (0..args.frames)
        .map(|f| {
            let exr = args.out_dir.join(format!("frame_{f:04}.exr"));
            let png = exr.with_extension("png");
            (exr, png)
        })
        .collect();
    let timings = args.out_dir.join("timings.json");
    let mut plan = OutputPlan::new();
    for (exr, png) in &names {
        plan.file(exr, "a frame").file(png, "a frame's PNG preview");
    }
    plan.file(&timings, "the timings");
    if cpca_settings.is_some() {
        plan.file(&cpca_path(&args.pre.cache), "the CPCA cache beside --cache");
    }
    let (settings, mut plan) = check_common(&args.trace, &args.pre, plan)?;
    let scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    let image = image_settings(&args.trace, &scene, &args.frame)?;
    let threads = args.trace.run.thread_count()?;
    // Animate runs one bounce a frame through the full loop: no projected bounce.
    check_memory("the probes animation", &frame_estimate(&settings, cpca_settings.as_ref(), false, &image, threads))?;
    let pool = tracer::render::thread_pool(threads)?;
    let bar = spinner(args.trace.quiet, "animate");
    let (mut pre, from_cache, s) = obtain(&scene, &settings, &args.pre.cache, Stale::Refuse, &pool, &bar)?;
    args.frame.apply(&mut pre, &pool)?;
    let key = CacheKey::of(&scene, &settings);
    let (op, cpca) = operator(&pre, cpca_settings, &pool, &args.pre.cache, &key)?;
    let intensity = intensity.unwrap_or(glam::Vec3::splat((0.5 * pre.scale as f32).powi(2)));
    let accel = tracer::Accel::build(&scene)?;
    // The camera is fixed: its lookups are traced once (the scene lit as in the first frame;
    // only the point light moves, which the kept lookups do not depend on).
    bar.set_message("tracing the camera's lookups");
    let first = lit_scene(&scene, args.frame.no_scene_lights, Some((from, intensity)));
    let (camera, image_operator_s) = image_operator(&first, &accel, &pre, &image, &pool)?;
    let mut previous: Option<Vec<glam::Vec3>> = None;
    let mut frames = Vec::new();
    for (f, (exr, _)) in names.iter().enumerate() {
        bar.set_message(format!("frame {} of {}", f + 1, args.frames));
        let t = if args.frames > 1 { f as f32 / (args.frames - 1) as f32 } else { 0.0 };
        let position = from.lerp(to, t);
        let lit = lit_scene(&scene, args.frame.no_scene_lights, Some((position, intensity)));
        let (out, img, times) = relit_frame(
            &lit,
            &accel,
            &pre,
            &op,
            None,
            previous.as_deref(),
            args.bounces_per_frame as usize,
            0.0,
            image.light_samples,
            &image,
            Some(&camera),
            &pool,
        )?;
        write_image(
            exr,
            &img,
            description(&settings, &scene, if cpca.is_some() { "cpca" } else { "dense" }, Some(position)),
        )?;
        let n = img.indirect.len().max(1) as f32;
        frames.push(AnimateFrame {
            frame: f as u32,
            light_position: position.to_array(),
            direct_s: times.direct_s,
            bounces_s: times.bounces_s,
            probe_relight_s: times.probe_relight_s,
            cluster_projection_s: times.cluster_projection_s,
            receiver_irradiance_s: times.receiver_irradiance_s,
            image_s: times.image_s,
            frame_s: times.frame_s,
            mean_indirect: (img.indirect.iter().fold(glam::Vec3::ZERO, |a, v| a + *v) / n).to_array(),
        });
        previous = Some(out.irradiance);
    }
    bar.finish_and_clear();
    let mean = frames.iter().map(|f| f.frame_s).sum::<f64>() / frames.len() as f64;
    let worst = frames.iter().map(|f| f.frame_s).fold(0.0, f64::max);
    let report = AnimateReport {
        precompute: precompute_report(&scene, &args.pre.cache, &pre, from_cache, s),
        cpca,
        bounces_per_frame: args.bounces_per_frame,
        image_operator_s,
        frames,
        mean_frame_s: mean,
        worst_frame_s: worst,
    };
    print_precompute(&report.precompute);
    println!("camera      primary rays and their lookups kept once in {:.4} s", report.image_operator_s);
    println!(
        "| frame | light | scene relight s | probe relight s | cluster projection s | receiver irradiance s | bounces s | frame s | image s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for f in &report.frames {
        let p = f.light_position;
        println!(
            "| {} | {:.4e}, {:.4e}, {:.4e} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} |",
            f.frame,
            p[0],
            p[1],
            p[2],
            f.direct_s,
            f.probe_relight_s,
            f.cluster_projection_s,
            f.receiver_irradiance_s,
            f.bounces_s,
            f.frame_s,
            f.image_s
        );
    }
    println!(
        "frames      mean {:.4} s, worst {:.4} s (direct light and {} bounce(s) each, image excluded)",
        mean, worst, args.bounces_per_frame
    );
    write_json(&timings, &report)?;
    println!("wrote {} frames and {}", report.frames.len(), timings.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compare::probes_method::ProbesMethod;
    use clap::Parser;

    /// `lfr probes relight`'s precompute and frame flags, alone.
    #[derive(Parser)]
    struct RelightFlags {
        #[command(flatten)]
        pre: PrecomputeOptions,
        #[command(flatten)]
        frame: FrameOptions,
    }

    #[test]
    fn relight_and_compare_run_the_same_defaults() {
        let seed = 7;
        let cli = RelightFlags::try_parse_from(["relight", "--cache", "c.probes"]).unwrap();
        let method = ProbesMethod::parse("probes", seed).unwrap().unwrap();
        assert_eq!(cli.pre.settings(seed), method.precompute);
        let (cpca, intensity) = cli.frame.validated().unwrap();
        assert_eq!(cpca, method.cpca);
        assert!(cpca.is_some() && intensity.is_none());
        assert_eq!(cli.frame.pixel_samples, method.pixel_samples);
        assert_eq!(cli.frame.light_samples, method.light_samples);
        assert_eq!(cli.frame.relight_miss_weight, method.miss_weight);
        assert_eq!(cli.frame.drop_hidden_senders, method.drop_hidden_senders);
    }

    #[test]
    fn cpca_is_on_unless_turned_off() {
        for (flags, expected) in [(&[][..], true), (&["--cpca"][..], true), (&["--cpca=off"][..], false)] {
            let mut argv = vec!["relight", "--cache", "c.probes"];
            argv.extend_from_slice(flags);
            assert_eq!(RelightFlags::try_parse_from(argv).unwrap().frame.cpca, expected, "{flags:?}");
        }
        assert!(RelightFlags::try_parse_from(["relight", "--cache", "c", "--cpca=perhaps"]).is_err());
    }
}
