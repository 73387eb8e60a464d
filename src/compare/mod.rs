//! `lfr compare`: error against run time for path tracing and every requested method, on one
//! scene and effect, against a cached high-spp reference (docs/compare.md).
//!
//! Flow: set the scene up for the effect (`effect`), trace or read the cached reference
//! (`reference`), run the path-tracing ladder, then each method over input spp ×
//! reconstruction rays with its inputs traced by the tracer and timed as `trace_s`; measure
//! every image against the reference (`recon::metrics`, HDR-FLIP through `recon::metrics::flip`), read
//! the verdicts off the PT curve (`verdict`), and write images, plots, `results.json`
//! (`results`) and `report.md` (`report`).

pub mod effect;
pub mod external;
pub mod html;
pub mod images;
pub mod memory;
pub mod out_dir;
pub mod plot;
pub mod probes_method;
pub mod reference;
pub mod reference_check;
pub mod report;
pub mod results;
pub mod timing;
pub mod verdict;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use recon::method::{FrameInput, Input, Inputs, MethodError};
use recon::metrics::{evaluate, ToneMap};
use recon::registry::{self, Registered};

use tracer::limits::{MAX_COMPARE_SIDE, MAX_COMPARE_SPP, MAX_RECON_RAYS, MAX_SPP};

use crate::common::TraceArgs;
use recon::{Effect, Image};
use tracer::output::write_atomically;
use tracer::samples::FieldSelection;
use tracer::Accel;

use effect::{default_ao_radius, prepare_scene, Tracing};
use results::{ReferenceCheckInfo, ReferenceInfo, Results, Run, Skipped, ToneMapInfo, Verdict};
use timing::Difference;
use verdict::{monotone_curve, psnr_at_time, time_to_psnr, CurvePoint};

fn parse_effect(name: &str) -> Result<Effect, String> {
    Effect::from_name(name)
        .ok_or_else(|| format!("unknown effect `{name}`; one of: {}", Effect::ALL.map(|e| e.name()).join(", ")))
}

#[derive(clap::Args)]
pub struct CompareArgs {
    /// The scene, size, seed (default 1 here: the inputs and the ladder use it, the reference two
    /// seeds derived from it), path length (soft-shadow always uses 1, direct light only),
    /// threads and progress.
    #[command(flatten)]
    pub trace: TraceArgs,
    /// indirect, glossy, ao, dof, motion, dof-motion or soft-shadow.
    #[arg(long, value_parser = parse_effect, required_unless_present = "list_methods")]
    pub effect: Option<Effect>,
    /// Output directory (created): results.json, report.md, images/, plots.
    #[arg(long, required_unless_present = "list_methods")]
    pub out: Option<PathBuf>,
    /// List every method with the effects it handles, its options (range, default) and a
    /// description, and exit.
    #[arg(long)]
    pub list_methods: bool,
    /// Methods to compare, comma-separated, each `NAME` or `NAME:key=value:...`
    /// (`lfr compare --list-methods` lists them).
    #[arg(long, value_delimiter = ',', default_value = "box,oidn")]
    pub methods: Vec<String>,
    /// Input samples per pixel of the methods, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,16")]
    pub spp: Vec<u32>,
    /// Reconstruction rays (or locations) per pixel, comma-separated; default: each method's own.
    #[arg(long, value_delimiter = ',')]
    pub recon_rays: Option<Vec<u32>>,
    /// Samples per pixel of the reference (two halves of half as many).
    #[arg(long, default_value_t = 4096)]
    pub reference_spp: u32,
    /// The path-tracing ladder runs 1, 2, 4, ... up to this many spp.
    #[arg(long, default_value_t = 256)]
    pub pt_max_spp: u32,
    /// Ambient-occlusion radius in scene units (default: a tenth of the scene's diagonal).
    #[arg(long)]
    pub ao_radius: Option<f32>,
    /// Thin-lens aperture radius in scene units, replacing the scene's (0 = pinhole).
    #[arg(long)]
    pub aperture_radius: Option<f32>,
    /// Focus distance in scene units, replacing the scene's.
    #[arg(long)]
    pub focus_distance: Option<f32>,
    /// Exposure of the tone map for PSNR/SSIM (default: the reference's 99th-percentile
    /// luminance maps to 1).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Reference cache directory (default: $LFR_CACHE_DIR, $XDG_CACHE_HOME/lfr or ~/.cache/lfr).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// A reference rendered elsewhere: one EXR of `lfr render` or `lfr merge`, or two with
    /// different seeds (two halves, which give its own error), instead of the traced or cached
    /// one (docs/scale-out.md). Its header record must match this comparison's scene and set-up.
    #[arg(long, value_delimiter = ',', num_args = 1..=2, conflicts_with_all = ["no_cache"])]
    pub reference: Option<Vec<PathBuf>>,
    /// Trace the reference even when a cached one exists (and replace it).
    #[arg(long)]
    pub no_cache: bool,
    /// The check of the reference's own error: one pixel per 4×4 block traced with this many
    /// times the reference's spp (1..=64; about this many sixteenths of the reference's time),
    /// or `off` (then only the two halves estimate it: optimistic where rare paths carry the
    /// light). For an expensive reference rendered elsewhere, `off` or 1 keeps it cheap.
    #[arg(long, default_value = reference_check::DEFAULT_FACTOR, value_parser = reference_check::parse_factor)]
    pub reference_check: reference_check::CheckSetting,
    /// Keep the methods' input sample files in OUT/inputs.
    #[arg(long)]
    pub keep_samples: bool,
    /// Time every run up to this many times (runs over 5 s twice, over 30 s once), alternating
    /// over all runs; verdicts use the median and report the spread. 1 = one measurement.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=20))]
    pub repeats: u32,
    /// Write into an --out folder that holds other files than a comparison's (they are kept;
    /// only the comparison's own files are replaced).
    #[arg(long)]
    pub force: bool,
}

/// The methods named on the command line, in order, without repeats.
fn resolve_methods(names: &[String], effect: Effect) -> Result<Vec<Registered>> {
    let mut methods: Vec<Registered> = Vec::new();
    for name in names.iter().map(|n| n.trim()).filter(|n| !n.is_empty()) {
        if methods.iter().any(|m| m.name() == name) {
            continue;
        }
        let Some(method) = registry::find(name).map_err(|e| anyhow::anyhow!("--methods: {e}"))? else {
            let known: Vec<_> = registry::METHODS.iter().map(|m| m.name).collect();
            bail!("--methods: unknown method `{name}`; known: {}", known.join(", "));
        };
        if !method.supports(effect) {
            bail!("--methods: {name} does not handle --effect {}", effect.name());
        }
        methods.push(method);
    }
    Ok(methods)
}

/// Refuses, before anything is traced, a method whose options leave out glossy reflections
/// (`ilfr:grain=filter`) in an indirect comparison of a scene with glossy materials: that
/// scene's indirect light holds glossy reflections (its sample files carry `weight`), which
/// such a method would blur.
fn refuse_narrowed_on_glossy_scene(methods: &[Registered], effect: Effect, glossy_scene: bool) -> Result<()> {
    if effect != Effect::Indirect || !glossy_scene {
        return Ok(());
    }
    match methods.iter().find(|m| m.spec.effects.contains(&Effect::Glossy) && !m.method.handles(Effect::Glossy)) {
        Some(m) => bail!(
            "--methods: {} applies to diffuse indirect light, and this scene has glossy materials, whose \
             reflections it would blur; use {} or a diffuse scene",
            m.name(),
            m.spec.name
        ),
        None => Ok(()),
    }
}

/// Refuses a comparison whose images would not fit in memory, before anything is traced: one
/// render at a time (`tracer::memory::RENDER_BYTES_PER_PIXEL`), the reference and its halves,
/// every run's image and its FLIP copy, and the frames and guide buffers kept per input spp;
/// with `probes` methods, the largest of their precomputes, compressions and images
/// (`probes::memory`: they run one at a time, beside the images kept).
fn check_memory(
    args: &CompareArgs,
    methods: &[Registered],
    probe_methods: &[probes_method::ProbesMethod],
    (width, height): (u32, u32),
    threads: usize,
) -> Result<()> {
    let ladder_runs = ladder(args.pt_max_spp, &args.spp).len() as u64;
    let rays = args.recon_rays.as_ref().map_or(3, Vec::len) as u64;
    let method_runs = (methods.len() + probe_methods.len()) as u64 * args.spp.len() as u64 * rays;
    let inputs = args.spp.len() as u64;
    let per_pixel = tracer::memory::RENDER_BYTES_PER_PIXEL + 3 * 12 + 24 * (ladder_runs + method_runs) + 100 * inputs;
    let images = width as u64 * height as u64 * per_pixel;
    let what = format!("a comparison at {width}x{height} with {} runs", ladder_runs + method_runs);
    let largest_probes = probe_methods
        .iter()
        .map(|method| (method, probes_method::memory_estimate(method, (width, height), threads)))
        .max_by_key(|(_, estimate)| estimate.total());
    match largest_probes {
        None => tracer::memory::check(&what, images)?,
        Some((method, estimate)) => {
            let what = estimate.describe(&format!("{what}, its images and {}", method.name));
            tracer::memory::check(&what, images + estimate.total())?
        }
    }
    Ok(())
}

/// A measured image before its verdicts.
struct Measured {
    run: Run,
    image: Image,
    /// The trace whose timings are this run's trace times.
    trace: TraceKey,
    /// A second trace whose timings add to them (soft shadows' light samples, for the methods
    /// that read them).
    light_trace: Option<TraceKey>,
    /// (preprocess, reconstruct) seconds of each repetition; empty for path tracing.
    parts: Vec<[f64; 2]>,
    /// The method's statistics of each repetition (they hold stage times): the run reports the
    /// median repetition's, so that its stage times belong to its `recon_s`.
    stats: Vec<recon::method::Stats>,
}

impl Measured {
    /// Sets the run's times to its median repetition and records every repetition
    /// (`timing`); repetition i pairs `trace_times[i]` (or the last) with `parts[i]`.
    fn settle_timings(&mut self, trace_times: &[f64]) {
        let count = trace_times.len().max(self.parts.len()).max(1);
        let repetition = |i: usize| -> (f64, f64, f64) {
            let trace = trace_times.get(i.min(trace_times.len().saturating_sub(1))).copied().unwrap_or(0.0);
            let [pre, recon] = self.parts.get(i.min(self.parts.len().saturating_sub(1))).copied().unwrap_or([0.0; 2]);
            (trace, pre, recon)
        };
        let totals: Vec<f64> = (0..count).map(repetition).map(|(t, p, r)| t + p + r).collect();
        let median = timing::median_index(&totals).unwrap_or(0);
        let (trace, pre, recon) = repetition(median);
        if let Some(stats) = self.stats.get(median.min(self.stats.len().saturating_sub(1))) {
            self.run.stats = stats.clone();
        }
        let run = &mut self.run;
        (run.trace_s, run.preprocess_s, run.recon_s, run.total_s) = (trace, pre, recon, trace + pre + recon);
        run.timing_spread = timing::relative_spread(&totals);
        run.timings = totals;
    }
}

/// A trace that the methods' runs share: the ladder's image at some spp (also the `Frame`
/// input), the input samples or the guide buffers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum TraceKey {
    Pt(u32),
    /// The input samples at an spp with the fields of one selection (an index into the
    /// selections the methods read, `input_selections`).
    Samples(u32, usize),
    /// The light samples that soft shadows' samples pair with (traced with `Samples`).
    LightSamples(u32, usize),
    Guide(u32),
}

/// The fields `method` reads of its sample files for `effect` (all when it does not say).
fn input_fields(method: &Registered, effect: Effect) -> FieldSelection {
    match method.sample_needs(effect) {
        Some(needs) => FieldSelection::reading(&needs),
        None => FieldSelection::All,
    }
}

/// The distinct field selections of the methods that read samples, in the methods' order: each
/// is traced once per input spp, and each method pays for the one it reads.
fn input_selections(methods: &[&Registered], effect: Effect) -> Vec<FieldSelection> {
    let mut selections: Vec<FieldSelection> = Vec::new();
    for method in methods.iter().filter(|m| m.input() == Input::Samples) {
        let fields = input_fields(method, effect);
        if !selections.contains(&fields) {
            selections.push(fields);
        }
    }
    selections
}

/// The trace times of a run that reads `key` and, when given, `light` too: repetition by
/// repetition (both are traced in the same repetitions), the sum.
fn trace_times(traces: &BTreeMap<TraceKey, Vec<f64>>, key: TraceKey, light: Option<TraceKey>) -> Vec<f64> {
    let mut times = traces[&key].clone();
    if let Some(extra) = light.and_then(|light| traces.get(&light)) {
        for (time, extra) in times.iter_mut().zip(extra) {
            *time += extra;
        }
    }
    times
}

impl TraceKey {
    fn label(self) -> String {
        match self {
            TraceKey::Pt(spp) => format!("path tracing, {spp} spp"),
            TraceKey::Samples(spp, selection) => format!("input samples, {spp} spp, fields {}", selection + 1),
            TraceKey::LightSamples(spp, selection) => format!("light samples, {spp} spp, fields {}", selection + 1),
            TraceKey::Guide(spp) => format!("guide buffers, {spp} spp"),
        }
    }
}

/// A timed unit that the repetitions run again.
enum Job {
    /// A trace, and the ladder run it belongs to (`usize::MAX`: none).
    Trace(TraceKey, usize),
    /// A method's reconstruction (index into the available methods) and its measured run.
    Method { method: usize, spp: u32, recon_rays: u32, measured: usize },
}

fn rays_label(recon_rays: u32) -> String {
    if recon_rays > 0 {
        format!(" × {recon_rays} rays")
    } else {
        String::new()
    }
}

fn not_deterministic(pass: u32) -> String {
    format!(
        "{}repetition {} gave a different image from the first with the same seed (not deterministic)",
        recon::method::WARNING,
        pass + 1
    )
}

/// The comparison's progress bar over every timed run (hidden with --quiet).
fn progress_bar(show: bool) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(0);
    let style = indicatif::ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} runs, ETA {eta}: {msg}",
    )
    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
    bar.set_style(style);
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// Scores images against the reference and writes them.
struct Scoring<'a> {
    dir: &'a Path,
    reference: &'a Image,
    tone: ToneMap,
    layer: &'static str,
    /// The reference's own PSNR (its check's estimate, else the halves'), if known.
    reference_psnr_db: Option<f64>,
    /// Lines are printed around it.
    bar: &'a indicatif::ProgressBar,
}

/// How close to the reference's own PSNR a run may score before its note says the reference's
/// error is at least half of what is measured: the measured MSE is the run's plus the
/// reference's, so a run as good as the reference reads 10·log10 2 ≈ 3 dB below it.
const REFERENCE_LIMITED_DB: f64 = 3.010_299_956_639_812; // 10·log10 2

/// The note of a run whose PSNR is within [`REFERENCE_LIMITED_DB`] of the reference's own.
fn reference_limited_note(psnr_db: f64, reference_psnr_db: f64) -> Option<String> {
    (psnr_db.is_finite() && psnr_db >= reference_psnr_db - REFERENCE_LIMITED_DB).then(|| {
        format!(
            "{}limited by the reference: {psnr_db:.2} dB is within {REFERENCE_LIMITED_DB:.1} dB of the reference's own \
             {reference_psnr_db:.2} dB, so the reference's error is at least half of the error measured; raise \
             --reference-spp to tell this run apart from better ones",
            recon::method::WARNING
        )
    })
}

impl Scoring<'_> {
    #[allow(clippy::too_many_arguments)]
    fn measure(
        &self,
        method: &str,
        input_spp: u32,
        recon_rays: u32,
        times: (f64, f64, f64),
        peak_rss_mb: Option<f64>,
        image: Image,
        (notes, stats): (Vec<String>, recon::method::Stats),
    ) -> Result<Measured> {
        self.reference.check_same_size(&image).with_context(|| {
            format!("{method} at {input_spp} spp returned an image of the wrong size for this comparison")
        })?;
        let metrics = evaluate(self.reference, &image, &self.tone)?;
        // Method names with options (`gif:radius=8`) become `gif_radius-8` in file names.
        let file_name = method.replace(':', "_").replace('=', "-");
        let stem = if recon_rays > 0 {
            format!("{file_name}-{input_spp}spp-{recon_rays}rays")
        } else {
            format!("{file_name}-{input_spp}spp")
        };
        let images = self.dir.join("images");
        images::write_image(&images, &stem, self.layer, &image, &self.tone)?;
        images::write_error_map(&images, &format!("{stem}-error"), self.reference, &image, &self.tone)?;
        let (trace_s, preprocess_s, recon_s) = times;
        let mut notes = notes;
        if let Some(reference_psnr_db) = self.reference_psnr_db {
            notes.extend(reference_limited_note(metrics.psnr_db, reference_psnr_db));
        }
        if metrics.nonfinite_pixels > 0 {
            notes.push(format!(
                "INVALID: {} pixels are NaN or infinite; they are scored as worst-case errors and the run is left out of the verdicts",
                metrics.nonfinite_pixels
            ));
        }
        self.bar.suspend(|| {
            eprintln!(
                "  {method:>10} {input_spp:>5} spp{}: {:>8.3} s, {:6.2} dB, relMSE {:.3e}, SSIM {:.4}{}",
                rays_label(recon_rays),
                trace_s + preprocess_s + recon_s,
                metrics.psnr_db,
                metrics.rel_mse,
                metrics.ssim,
                if metrics.nonfinite_pixels > 0 { " (INVALID: non-finite pixels)" } else { "" }
            )
        });
        Ok(Measured {
            run: Run {
                method: method.to_string(),
                input_spp,
                recon_rays,
                trace_s,
                preprocess_s,
                recon_s,
                total_s: trace_s + preprocess_s + recon_s,
                timings: vec![trace_s + preprocess_s + recon_s],
                timing_spread: 0.0,
                psnr_db: metrics.psnr_db,
                rel_mse: metrics.rel_mse,
                ssim: metrics.ssim,
                flip: None,
                peak_rss_mb,
                nonfinite_pixels: metrics.nonfinite_pixels,
                valid: metrics.nonfinite_pixels == 0,
                equal_time_psnr_gain_db: None,
                speedup: None,
                speedup_range: None,
                verdict_extrapolated: false,
                precompute_from_cache: None,
                per_frame_speedup: None,
                break_even_frames: None,
                image: format!("images/{stem}.exr"),
                preview: format!("images/{stem}.png"),
                error_map: format!("images/{stem}-error.png"),
                notes,
                stats,
            },
            image,
            trace: TraceKey::Pt(input_spp),
            light_trace: None,
            parts: Vec::new(),
            stats: Vec::new(),
        })
    }
}

/// The ladder's sample counts: powers of two up to `max`, plus every input spp.
fn ladder(max: u32, input_spp: &[u32]) -> Vec<u32> {
    let mut spp: Vec<u32> = std::iter::successors(Some(1u32), |s| s.checked_mul(2)).take_while(|&s| s <= max).collect();
    spp.extend_from_slice(input_spp);
    spp.sort_unstable();
    spp.dedup();
    spp
}

/// The PT curve of the runs' times picked by `time` (the median, the fastest or the slowest
/// repetition).
fn pt_curve(runs: &[Run], time: impl Fn(&Run) -> f64) -> Vec<CurvePoint> {
    monotone_curve(
        &runs
            .iter()
            .filter(|r| r.method == "pt" && r.valid)
            .map(|r| CurvePoint { seconds: time(r), psnr_db: r.psnr_db })
            .collect::<Vec<_>>(),
    )
}

/// The fastest and slowest repetition of a run (its total when it has no list).
fn time_range(run: &Run) -> (f64, f64) {
    timing::range(&run.timings).unwrap_or((run.total_s, run.total_s))
}

/// Fills in each run's verdicts from the PT curve and sums up each method. The speedup uses
/// the median repetitions; its range pairs the method's slowest repetition with path tracing's
/// fastest curve and the other way round, and a range that holds 1 — or a speedup within
/// `timing::BETWEEN_RUNS_NOISE` of 1 — is no clear difference.
fn verdicts(runs: &mut [Run]) -> Vec<Verdict> {
    let curve = pt_curve(runs, |r| r.total_s);
    let fast_curve = pt_curve(runs, |r| time_range(r).0);
    let slow_curve = pt_curve(runs, |r| time_range(r).1);
    for run in runs.iter_mut().filter(|r| r.method != "pt" && r.valid) {
        let at_time = psnr_at_time(&curve, run.total_s);
        let to_psnr = time_to_psnr(&curve, run.psnr_db);
        run.equal_time_psnr_gain_db = at_time.map(|r| run.psnr_db - r.value);
        run.speedup = to_psnr.filter(|_| run.total_s > 0.0).map(|r| r.value / run.total_s);
        let (fastest, slowest) = time_range(run);
        run.speedup_range = match (time_to_psnr(&fast_curve, run.psnr_db), time_to_psnr(&slow_curve, run.psnr_db)) {
            (Some(pt_fast), Some(pt_slow)) if fastest > 0.0 => run.speedup.map(|median| {
                // Ordered and holding the median's speedup: the two pairings can cross where
                // path tracing's slowest repetitions are not monotone in spp (a slow outlier
                // at the cheapest rung leaves the slow curve, which then extrapolates there).
                let (a, b) = (pt_fast.value / slowest, pt_slow.value / fastest);
                [a.min(b).min(median), a.max(b).max(median)]
            }),
            _ => None,
        };
        run.verdict_extrapolated = at_time.is_some_and(|r| r.extrapolated) || to_psnr.is_some_and(|r| r.extrapolated);
        if run.precompute_from_cache.is_some() {
            // One frame without its precompute, and the frames that pay for the precompute.
            run.per_frame_speedup = to_psnr.filter(|_| run.recon_s > 0.0).map(|r| r.value / run.recon_s);
            run.break_even_frames =
                to_psnr.filter(|r| r.value > run.recon_s).map(|r| run.preprocess_s / (r.value - run.recon_s));
        }
    }
    let mut names: Vec<String> = Vec::new();
    for run in runs.iter().filter(|r| r.method != "pt") {
        if !names.contains(&run.method) {
            names.push(run.method.clone());
        }
    }
    names
        .into_iter()
        .map(|method| {
            let mine: Vec<&Run> = runs.iter().filter(|r| r.method == method).collect();
            let valid: Vec<&&Run> = mine.iter().filter(|r| r.valid && r.speedup.is_some()).collect();
            let best = valid.iter().max_by(|a, b| a.speedup.unwrap_or(0.0).total_cmp(&b.speedup.unwrap_or(0.0)));
            let best_gain = valid.iter().filter_map(|r| r.equal_time_psnr_gain_db).max_by(f64::total_cmp);
            let best_psnr = valid.iter().map(|r| r.psnr_db).max_by(f64::total_cmp);
            let best_frame = valid
                .iter()
                .filter(|r| r.per_frame_speedup.is_some())
                .max_by(|a, b| a.per_frame_speedup.unwrap_or(0.0).total_cmp(&b.per_frame_speedup.unwrap_or(0.0)));
            let difference =
                best.map(|run| Difference::of(run.speedup.unwrap_or(0.0), run.speedup_range.map(|[lo, hi]| (lo, hi))));
            let summary = match best {
                Some(run) => {
                    let speedup = run.speedup.unwrap_or(0.0);
                    // The sentence gives path tracing's time to this PSNR: it says "extrapolated"
                    // only when that reading is (the run's flag also covers its equal-time PSNR).
                    let extrapolated = time_to_psnr(&curve, run.psnr_db).is_some_and(|r| r.extrapolated);
                    let rays = if run.recon_rays > 0 { format!(" with {} reconstruction rays", run.recon_rays) } else { String::new() };
                    let ratio = if speedup >= 1.0 { format!("{speedup:.2}× faster") } else { format!("{:.2}× slower", 1.0 / speedup.max(1e-12)) };
                    let judged = match (difference, run.speedup_range) {
                        (Some(Difference::Unclear), Some([lo, hi])) => format!(
                            "no clear difference ({ratio} by the median times; the repeated timings allow a speedup of {lo:.2}× to {hi:.2}×)"
                        ),
                        (Some(Difference::WithinNoise), _) => format!(
                            "no clear difference ({ratio} by the median times, within the {:.0} % by which the same command's speedups move between runs)",
                            100.0 * timing::BETWEEN_RUNS_NOISE
                        ),
                        _ => ratio,
                    };
                    format!(
                        "{method} at its best ({} input spp{rays}) reaches {:.2} dB in {:.3} s; path tracing needs {:.3} s for that: {judged}{}",
                        run.input_spp,
                        run.psnr_db,
                        run.total_s,
                        speedup * run.total_s,
                        if extrapolated { " (PT curve extrapolated at 10 dB per decade)" } else { "" }
                    )
                }
                None if mine.iter().any(|r| !r.valid) => {
                    format!("{method}: no valid run (non-finite output pixels); no verdict")
                }
                None => format!("{method}: no verdict (no path-tracing curve)"),
            };
            let summary = match best_frame.and_then(|r| r.per_frame_speedup.map(|s| (s, r))) {
                Some((speedup, run)) => format!(
                    "{summary}; after a precompute of {:.2} s one frame takes {:.4} s: {speedup:.1}× faster than path tracing to {:.2} dB, {}",
                    run.preprocess_s,
                    run.recon_s,
                    run.psnr_db,
                    match run.break_even_frames {
                        Some(n) => format!("the precompute pays for itself after {n:.1} frames"),
                        None => "the precompute never pays for itself".to_string(),
                    }
                ),
                None => summary,
            };
            Verdict {
                method,
                best_speedup: best.and_then(|r| r.speedup),
                best_speedup_range: best.and_then(|r| r.speedup_range),
                difference: difference.map(|d| d.name()),
                best_speedup_input_spp: best.map(|r| r.input_spp),
                best_speedup_recon_rays: best.map(|r| r.recon_rays),
                best_equal_time_psnr_gain_db: best_gain,
                best_psnr_db: best_psnr,
                best_per_frame_speedup: best_frame.and_then(|r| r.per_frame_speedup),
                break_even_frames: best_frame.and_then(|r| r.break_even_frames),
                summary,
            }
        })
        .collect()
}

pub fn run(args: &CompareArgs) -> Result<()> {
    if args.list_methods {
        print!("{}", registry::listing());
        return Ok(());
    }
    let total_start = Instant::now();
    let (Some(effect), Some(dir)) = (args.effect, args.out.as_deref()) else {
        bail!("--effect and --out are required (or --list-methods)");
    };
    let seed = args.trace.run.seed_or(1);
    if args.spp.is_empty() || args.spp.iter().any(|&s| s == 0 || s > MAX_COMPARE_SPP) {
        bail!("--spp: every input sample count must be in 1..={MAX_COMPARE_SPP}, got {:?}", args.spp);
    }
    if args.reference_spp < 2 || args.reference_spp > MAX_SPP || args.reference_spp % 2 != 0 {
        bail!("--reference-spp must be even (two halves) and in 2..={MAX_SPP}, got {}", args.reference_spp);
    }
    if args.pt_max_spp == 0 || args.pt_max_spp > MAX_COMPARE_SPP {
        bail!("--pt-max-spp must be in 1..={MAX_COMPARE_SPP}, got {}", args.pt_max_spp);
    }
    if let Some(rays) = &args.recon_rays {
        if rays.is_empty() || rays.iter().any(|&r| r == 0 || r > MAX_RECON_RAYS) {
            bail!("--recon-rays: every count must be in 1..={MAX_RECON_RAYS}, got {rays:?}");
        }
    }
    let tone_given = match args.exposure {
        Some(exposure) => Some(ToneMap::with_exposure(exposure).map_err(|e| anyhow::anyhow!("--exposure: {e}"))?),
        None => None,
    };
    // `probes` sits on the tracer (the harness's hook, `probes_method`); the rest are the
    // registry's.
    let mut probe_methods: Vec<probes_method::ProbesMethod> = Vec::new();
    let mut names: Vec<String> = Vec::new();
    for name in &args.methods {
        match probes_method::ProbesMethod::parse(name, seed)? {
            Some(method) => {
                if effect != Effect::Indirect {
                    bail!("--methods: probes handles --effect indirect only, not {}", effect.name());
                }
                if !probe_methods.iter().any(|m| m.name == method.name) {
                    probe_methods.push(method);
                }
            }
            None => names.push(name.clone()),
        }
    }
    let methods = resolve_methods(&names, effect)?;

    // What the comparison removes and writes in OUT against every file it reads, before the
    // scene is read and again with the files it references.
    let cache = reference::cache_dir(args.cache_dir.as_deref());
    let references = args.reference.as_deref().unwrap_or_default();
    let mut plan = crate::outputs::comparison_plan(dir, args.trace.scene.as_deref(), references, &cache);
    plan.check()?;
    let mut scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    let scene_text = crate::fingerprint::scene_text(args.trace.scene.as_deref())?;
    if let Some(radius) = args.aperture_radius {
        if !(radius.is_finite() && radius >= 0.0) {
            bail!("--aperture-radius must be finite and at least 0, got {radius}");
        }
        scene.camera.aperture_radius = radius;
    }
    if let Some(distance) = args.focus_distance {
        if !(distance.is_finite() && distance > 0.0) {
            bail!("--focus-distance must be positive and finite, got {distance}");
        }
        scene.camera.focus_distance = distance;
    }
    let max_bounces = prepare_scene(effect, &mut scene, args.trace.size.max_bounces)?;
    refuse_narrowed_on_glossy_scene(&methods, effect, tracer::samples::secondary::scene_is_glossy(&scene))?;
    let (width, height) =
        (args.trace.size.width.unwrap_or(scene.width), args.trace.size.height.unwrap_or(scene.height));
    if width == 0 || height == 0 || width > MAX_COMPARE_SIDE || height > MAX_COMPARE_SIDE {
        bail!("--width and --height must be in 1..={MAX_COMPARE_SIDE}, got {width}x{height}");
    }
    args.trace.run.thread_count()?;
    let ao_radius = match args.ao_radius {
        Some(r) if !(r.is_finite() && r > 0.0) => bail!("--ao-radius must be positive and finite, got {r}"),
        Some(r) => r,
        None => default_ao_radius(&scene),
    };
    check_memory(args, &methods, &probe_methods, (width, height), args.trace.run.thread_count()?)?;
    // Every check that does not need a traced image comes before the first one is traced.
    reference::check_cache_dir(&cache)?;
    let accel = Accel::build(&scene)?;
    let tracing = Tracing {
        scene: &scene,
        accel: &accel,
        effect,
        width,
        height,
        max_bounces,
        ao_radius,
        threads: args.trace.run.threads,
    };
    let progress = !args.trace.quiet;
    // An external reference is read and checked before anything is written or traced.
    let scene_sha256 = crate::fingerprint::scene_sha256(&scene_text, &scene);
    let external_reference = args
        .reference
        .as_ref()
        .map(|files| external::external_reference(&tracing, &scene_sha256, seed, files))
        .transpose()?;
    let cleared = out_dir::prepare(dir, args.force)?;
    if cleared > 0 {
        eprintln!("compare: removed the previous comparison's {cleared} files and folders from {}", dir.display());
    }
    std::fs::create_dir_all(dir.join("images")).with_context(|| format!("creating {}", dir.display()))?;

    // The reference.
    let reference = match external_reference {
        Some(reference) => {
            eprintln!(
                "compare: {} --effect {} at {width}x{height}; external reference",
                scene.source.display(),
                effect.name()
            );
            reference
        }
        None => {
            eprintln!(
                "compare: {} --effect {} at {width}x{height}; reference {} spp (cache {})",
                scene.source.display(),
                effect.name(),
                args.reference_spp,
                cache.display()
            );
            reference::reference(&tracing, &scene_text, args.reference_spp, seed, &cache, !args.no_cache, progress)?
        }
    };
    eprintln!(
        "  reference: {} spp, {:.1} s{}",
        reference.spp,
        reference.seconds,
        if reference.from_cache {
            " (cached)"
        } else if args.reference.is_some() {
            " (external)"
        } else {
            ""
        }
    );
    let (tone, exposure_source) = match tone_given {
        Some(tone) => (tone, "given"),
        None => (ToneMap::auto(&reference.image), "auto"),
    };
    let layer: &'static str = match effect {
        Effect::Indirect | Effect::Glossy => "indirect",
        Effect::Ao => "ao",
        Effect::SoftShadow => "direct",
        _ => "beauty",
    };
    images::write_image(&dir.join("images"), "reference", layer, &reference.image, &tone)?;
    let halves_psnr_db = match &reference.halves {
        Some((a, b)) => Some(reference::estimated_psnr_db(a, b, &tone)?),
        None => None,
    };
    let checked = match args.reference_check.0 {
        Some(factor) => {
            let check = reference_check::check(
                &tracing,
                &scene_text,
                reference_check::CheckOf { spp: reference.spp, seeds: reference.seeds, factor },
                seed,
                &cache,
                !args.no_cache,
                progress,
            )?;
            let estimate = check.estimate(&reference.image, reference.spp, &tone)?;
            eprintln!(
                "  reference check: {} at {} spp, {:.1} s{}; the reference's own PSNR ≈ {:.1} dB ({:.1}–{:.1}){}",
                results::pixels_text(check.pixels.len()),
                check.spp,
                check.seconds,
                if check.from_cache { " (cached)" } else { "" },
                estimate.psnr_db,
                estimate.interval_db[0],
                estimate.interval_db[1],
                match halves_psnr_db {
                    Some(db) => format!(" ({db:.1} dB from its two halves)"),
                    None => String::new(),
                }
            );
            Some((check, estimate))
        }
        None => {
            eprintln!(
                "  reference check: off; {}",
                match halves_psnr_db {
                    Some(db) => format!("the reference's own PSNR ≈ {db:.1} dB from its two halves (an upper bound)"),
                    None => "the reference's own PSNR is unknown (one image, no halves)".to_string(),
                }
            );
            None
        }
    };
    let estimated_psnr_db = checked.as_ref().map(|(_, estimate)| estimate.psnr_db).or(halves_psnr_db);

    let mut skipped = Vec::new();
    let per_run_peak = memory::reset_peak();
    let bar = progress_bar(progress);
    let context =
        Scoring { dir, reference: &reference.image, tone, layer, reference_psnr_db: estimated_psnr_db, bar: &bar };
    let mut measured: Vec<Measured> = Vec::new();
    // The input traces' timings, one per repetition; the ladder's are its runs' own.
    let mut traces: BTreeMap<TraceKey, Vec<f64>> = BTreeMap::new();
    let mut jobs: Vec<Job> = Vec::new();

    // Which inputs the methods need, and how much there is to do (for the progress bar).
    let available: Vec<&Registered> = methods
        .iter()
        .filter(|method| match method.available() {
            Ok(()) => true,
            Err(reason) => {
                eprintln!("skipping {}: {reason}", method.name());
                skipped.push(Skipped { method: method.name().to_string(), reason: reason.to_string() });
                false
            }
        })
        .collect();
    let rays_of = |method: &Registered| -> Vec<u32> {
        let default_rays = method.default_recon_rays();
        if default_rays == [0] {
            vec![0]
        } else {
            args.recon_rays.clone().unwrap_or(default_rays)
        }
    };
    let needs = |input: Input| available.iter().any(|m| m.input() == input);
    // The ladder holds every input spp whatever the methods, so that each method's input spp has
    // a path-traced image of the same samples beside it.
    let ladder_spp = ladder(args.pt_max_spp, &args.spp);
    let selections = input_selections(&available, effect);
    let input_count = args.spp.len() * (selections.len() + usize::from(needs(Input::Guide)));
    let method_count: usize = available.iter().map(|m| rays_of(m).len() * args.spp.len()).sum();
    bar.set_length((ladder_spp.len() + input_count + method_count + probe_methods.len()) as u64);

    // The path-tracing ladder; its frames are the `Frame` inputs of the methods.
    let mut frames: BTreeMap<u32, FrameInput> = BTreeMap::new();
    for &spp in &ladder_spp {
        let message = format!("path tracing, {spp} spp");
        bar.set_message(message.clone());
        memory::reset_peak();
        let traced = crate::common::with_stage_progress(&bar, &message, || tracing.trace(spp, seed, false))?;
        let peak = memory::peak_rss_mb();
        let image = traced.frame.color.clone();
        let run = context.measure("pt", spp, 0, (traced.seconds, 0.0, 0.0), peak, image, Default::default())?;
        measured.push(Measured { trace: TraceKey::Pt(spp), parts: Vec::new(), ..run });
        traces.insert(TraceKey::Pt(spp), vec![traced.seconds]);
        jobs.push(Job::Trace(TraceKey::Pt(spp), measured.len() - 1));
        if args.spp.contains(&spp) {
            frames.insert(spp, traced.frame);
        }
        bar.inc(1);
    }

    // The other inputs, once per input spp for every method that reads them.
    let inputs_dir = dir.join("inputs");
    // An interrupt removes the input samples too, unless they are to be kept.
    let _inputs_registration = (!args.keep_samples).then(|| sampleio::interrupt::remove_on_interrupt(&inputs_dir));
    let mut samples: BTreeMap<(u32, usize), effect::Dumped> = BTreeMap::new();
    let mut guides: BTreeMap<u32, recon::method::GuideInput> = BTreeMap::new();
    for &spp in &args.spp {
        for (selection, fields) in selections.iter().enumerate() {
            let message = format!("tracing the input samples, {spp} spp");
            bar.set_message(message.clone());
            std::fs::create_dir_all(&inputs_dir).with_context(|| format!("creating {}", inputs_dir.display()))?;
            let dumped = crate::common::with_stage_progress(&bar, &message, || {
                tracing.dump(spp, seed, &inputs_dir, fields, selection)
            })?;
            traces.insert(TraceKey::Samples(spp, selection), vec![dumped.samples_s]);
            if let Some(seconds) = dumped.light_samples_s {
                traces.insert(TraceKey::LightSamples(spp, selection), vec![seconds]);
            }
            samples.insert((spp, selection), dumped);
            jobs.push(Job::Trace(TraceKey::Samples(spp, selection), usize::MAX));
            bar.inc(1);
        }
        if needs(Input::Guide) {
            let message = format!("tracing the guide buffers, {spp} spp");
            bar.set_message(message.clone());
            let (guide, seconds) = crate::common::with_stage_progress(&bar, &message, || tracing.guide(spp, seed))?;
            guides.insert(spp, guide);
            traces.insert(TraceKey::Guide(spp), vec![seconds]);
            jobs.push(Job::Trace(TraceKey::Guide(spp), usize::MAX));
            bar.inc(1);
        }
    }
    let inputs_of = |method: &Registered, spp: u32| -> (Inputs, TraceKey) {
        let (samples, light_samples, frame, guide, key) = match method.input() {
            Input::Samples => {
                let fields = input_fields(method, effect);
                let selection =
                    selections.iter().position(|s| *s == fields).expect("every reader's selection is traced");
                let dumped = &samples[&(spp, selection)];
                let key = TraceKey::Samples(spp, selection);
                (Some(dumped.samples.clone()), dumped.light_samples.clone(), None, None, key)
            }
            Input::Frame => (None, None, Some(&frames[&spp]), None, TraceKey::Pt(spp)),
            Input::Guide => (None, None, None, Some(&guides[&spp]), TraceKey::Guide(spp)),
        };
        let inputs = Inputs {
            effect,
            width,
            height,
            spp,
            samples,
            light_samples,
            frame,
            guide,
            ao_radius,
            seed,
            threads: args.trace.run.threads,
        };
        (inputs, key)
    };

    // The methods.
    'methods: for (index, method) in available.iter().enumerate() {
        // The previous run of this method: how long the next one may take when it reports no
        // stage of its own (OIDN).
        let mut previous_s: Option<f64> = None;
        for &spp in &args.spp {
            let (inputs, key) = inputs_of(method, spp);
            for recon_rays in rays_of(method) {
                let message = format!("{}, {spp} spp{}", method.name(), rays_label(recon_rays));
                bar.set_message(message.clone());
                memory::reset_peak();
                let run = || method.run(&inputs, recon_rays);
                let output = match crate::common::with_expected_progress(&bar, &message, previous_s, run) {
                    Ok(output) => output,
                    Err(MethodError::Unavailable(reason)) => {
                        bar.suspend(|| eprintln!("skipping {}: {reason}", method.name()));
                        skipped.push(Skipped { method: method.name().to_string(), reason: reason.to_string() });
                        measured.retain(|m| m.run.method != method.name());
                        jobs.retain(|job| !matches!(job, Job::Method { method, .. } if *method == index));
                        continue 'methods;
                    }
                    Err(error) => bail!("{} at {spp} spp: {error}", method.name()),
                };
                let own_peak = memory::peak_rss_mb();
                let peak = match (own_peak, output.external_peak_rss_mb) {
                    (Some(a), Some(b)) => Some(a.max(b)),
                    (a, b) => a.or(b),
                };
                let light_trace = match key {
                    TraceKey::Samples(spp, selection) if method.reads_light_samples(effect) => {
                        Some(TraceKey::LightSamples(spp, selection)).filter(|light| traces.contains_key(light))
                    }
                    _ => None,
                };
                let trace_s = trace_times(&traces, key, light_trace)[0];
                previous_s = Some(output.preprocess_s + output.recon_s);
                let run = context.measure(
                    method.name(),
                    spp,
                    recon_rays,
                    (trace_s, output.preprocess_s, output.recon_s),
                    peak,
                    output.image,
                    (output.notes, output.stats),
                )?;
                let stats = vec![run.run.stats.clone()];
                measured.push(Measured {
                    trace: key,
                    light_trace,
                    parts: vec![[output.preprocess_s, output.recon_s]],
                    stats,
                    ..run
                });
                jobs.push(Job::Method { method: index, spp, recon_rays, measured: measured.len() - 1 });
                bar.inc(1);
            }
        }
    }

    // The methods with a precompute, each run once: its `--repeats` frames are timed inside.
    let mut precomputed: Vec<Measured> = Vec::new();
    for method in &probe_methods {
        bar.set_message(method.name.clone());
        memory::reset_peak();
        let out = probes_method::run(
            method,
            &scene,
            &accel,
            (width, height),
            max_bounces,
            seed,
            args.trace.run.threads,
            &cache,
            args.repeats,
            &bar,
        )
        .with_context(|| method.name.clone())?;
        let peak = memory::peak_rss_mb();
        let mut m = context.measure(
            &method.name,
            0,
            method.pixel_samples,
            (0.0, out.preprocess_s, out.recon_s),
            peak,
            out.image,
            (out.notes, out.stats),
        )?;
        m.run.precompute_from_cache = Some(out.precompute_from_cache);
        m.run.timings = out.timings.iter().map(|t| t + out.preprocess_s).collect();
        m.run.timing_spread = timing::relative_spread(&m.run.timings);
        precomputed.push(m);
        bar.inc(1);
    }

    // The repetitions, alternating over every run (module `timing`).
    let first_total = |job: &Job| -> f64 {
        match job {
            Job::Trace(key, _) => traces[key][0],
            Job::Method { measured: m, .. } => measured[*m].run.total_s,
        }
    };
    let repeats: Vec<u32> = jobs.iter().map(|job| timing::repetitions(first_total(job), args.repeats)).collect();
    bar.set_length(bar.position() + repeats.iter().map(|&r| u64::from(r - 1)).sum::<u64>());
    for pass in 1..args.repeats {
        for (job, _) in jobs.iter().zip(&repeats).filter(|(_, &r)| pass < r) {
            match job {
                Job::Trace(key, run) => {
                    let message = format!("repetition {}: {}", pass + 1, key.label());
                    bar.set_message(message.clone());
                    let seconds = crate::common::with_stage_progress(&bar, &message, || -> Result<f64> {
                        Ok(match *key {
                            TraceKey::Pt(spp) => {
                                let traced = tracing.trace(spp, seed, false)?;
                                if traced.frame.color != measured[*run].image {
                                    measured[*run].run.notes.push(not_deterministic(pass));
                                }
                                traced.seconds
                            }
                            TraceKey::Samples(spp, selection) => {
                                let dumped = tracing.dump(spp, seed, &inputs_dir, &selections[selection], selection)?;
                                if let Some(seconds) = dumped.light_samples_s {
                                    let light = TraceKey::LightSamples(spp, selection);
                                    traces.get_mut(&light).expect("traced in pass 1").push(seconds);
                                }
                                dumped.samples_s
                            }
                            TraceKey::LightSamples(..) => unreachable!("traced with the samples"),
                            TraceKey::Guide(spp) => tracing.guide(spp, seed)?.1,
                        })
                    })?;
                    traces.get_mut(key).expect("traced in pass 1").push(seconds);
                }
                &Job::Method { method, spp, recon_rays, measured: m } => {
                    let method = available[method];
                    let message =
                        format!("repetition {}: {}, {spp} spp{}", pass + 1, method.name(), rays_label(recon_rays));
                    bar.set_message(message.clone());
                    let (inputs, _) = inputs_of(method, spp);
                    let first = measured[m].parts.first().map(|[pre, recon]| pre + recon);
                    let run = || method.run(&inputs, recon_rays);
                    let output = crate::common::with_expected_progress(&bar, &message, first, run)
                        .map_err(|e| anyhow::anyhow!("{} at {spp} spp: {e}", method.name()))?;
                    if output.image != measured[m].image {
                        measured[m].run.notes.push(not_deterministic(pass));
                    }
                    measured[m].parts.push([output.preprocess_s, output.recon_s]);
                    measured[m].stats.push(output.stats);
                }
            }
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    for m in &mut measured {
        m.settle_timings(&trace_times(&traces, m.trace, m.light_trace));
    }
    measured.extend(precomputed);
    if args.repeats > 1 {
        eprintln!(
            "  timings: the lines above show each run's first timing; the verdicts and reports use the median of up to \
             {} repetitions per run (results.json `timings`)",
            args.repeats
        );
    }
    if !args.keep_samples && inputs_dir.exists() {
        std::fs::remove_dir_all(&inputs_dir).with_context(|| format!("removing {}", inputs_dir.display()))?;
    }

    // HDR-FLIP, when the Python package is there: one process for every image.
    let flip_available = recon::metrics::flip::available();
    if flip_available {
        let scale = |image: &Image| {
            let pixels = image.pixels.iter().map(|p| p.map(|v| v * tone.exposure)).collect();
            Image::from_pixels(image.width, image.height, pixels)
        };
        let scaled: Vec<Image> = measured.iter().map(|m| scale(&m.image)).collect();
        match recon::metrics::flip::hdr_flip_many(&scale(&reference.image), &scaled.iter().collect::<Vec<_>>()) {
            Ok(Some(values)) => {
                for (m, value) in measured.iter_mut().zip(values) {
                    m.run.flip = Some(value);
                }
            }
            Ok(None) => {}
            Err(error) => {
                eprintln!("warning: HDR-FLIP failed: {error}");
                for m in &mut measured {
                    m.run.notes.push(format!("HDR-FLIP not computed: {error}"));
                }
            }
        }
    }

    let mut runs: Vec<Run> = measured.into_iter().map(|m| m.run).collect();
    let verdicts = verdicts(&mut runs);
    let results = Results {
        schema: results::SCHEMA,
        lfr_version: env!("CARGO_PKG_VERSION"),
        scene: scene.source.display().to_string(),
        effect: effect.name().to_string(),
        width,
        height,
        seed,
        threads: if args.trace.run.threads == 0 { rayon::current_num_threads() } else { args.trace.run.threads },
        max_bounces,
        ao_radius: (effect == Effect::Ao).then_some(ao_radius),
        tone_map: ToneMapInfo { exposure: tone.exposure, gamma: tone.gamma, exposure_source },
        reference: ReferenceInfo {
            spp: reference.spp,
            seconds: reference.seconds,
            seeds: reference.seeds,
            cache_key: reference.key.clone(),
            from_cache: reference.from_cache,
            external: args.reference.iter().flatten().map(|p| p.display().to_string()).collect(),
            estimated_psnr_db,
            halves_psnr_db,
            check: checked.map(|(check, estimate)| ReferenceCheckInfo {
                psnr_interval_db: estimate.interval_db,
                pixels: check.pixels.len(),
                spp: check.spp,
                seed: check.seed,
                seconds: check.seconds,
                from_cache: check.from_cache,
            }),
            image: "images/reference.exr".into(),
        },
        flip_available,
        peak_rss_per_run: per_run_peak,
        between_runs_noise: timing::BETWEEN_RUNS_NOISE,
        runs,
        skipped,
        verdicts,
        total_seconds: total_start.elapsed().as_secs_f64(),
    };

    report::write_plot(dir, &results)?;
    let report_path = dir.join("report.md");
    let markdown = report::markdown(&results);
    write_atomically(&report_path, |tmp| std::fs::write(tmp, &markdown).map_err(|e| e.to_string()))
        .with_context(|| format!("writing {}", report_path.display()))?;
    let html_path = dir.join("report.html");
    let html = html::html(&results);
    write_atomically(&html_path, |tmp| std::fs::write(tmp, &html).map_err(|e| e.to_string()))
        .with_context(|| format!("writing {}", html_path.display()))?;
    let json_path = dir.join("results.json");
    let json = serde_json::to_vec_pretty(&results)?;
    write_atomically(&json_path, |tmp| std::fs::write(tmp, &json).map_err(|e| e.to_string()))
        .with_context(|| format!("writing {}", json_path.display()))?;
    for verdict in &results.verdicts {
        println!("{}", verdict.summary);
    }
    println!(
        "wrote {}, {} and {} in {:.1} s",
        report_path.display(),
        html_path.display(),
        json_path.display(),
        results.total_seconds
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(method: &str, spp: u32, total_s: f64, psnr_db: f64, valid: bool) -> Run {
        let mut run = Run::example(method, spp, total_s, psnr_db);
        run.valid = valid;
        run.nonfinite_pixels = if valid { 0 } else { 3 };
        run
    }

    fn scoring_in(dir: &Path, reference: &Image) -> Result<Measured> {
        let bar = indicatif::ProgressBar::hidden();
        let scoring = Scoring {
            dir,
            reference,
            tone: ToneMap::auto(reference),
            layer: "beauty",
            reference_psnr_db: None,
            bar: &bar,
        };
        let mut image = reference.clone();
        image.set(1, 1, [f32::NAN, 0.0, 0.0]);
        image.set(2, 1, [f32::INFINITY; 3]);
        scoring.measure("nan-maker", 4, 0, (1.0, 0.5, 0.25), Some(10.0), image, Default::default())
    }

    #[test]
    fn nonfinite_outputs_are_counted_flagged_and_never_score_well() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("images")).unwrap();
        let pixels = (0..16).map(|i| [0.1 + 0.05 * i as f32; 3]).collect();
        let reference = Image::from_pixels(4, 4, pixels);
        let measured = scoring_in(dir.path(), &reference).unwrap();
        let run = &measured.run;
        assert_eq!(run.nonfinite_pixels, 2);
        assert!(!run.valid);
        assert!(run.psnr_db.is_finite() && run.psnr_db < 40.0, "{}", run.psnr_db);
        assert!(run.notes.iter().any(|n| n.contains("INVALID")));
        assert_eq!(run.total_s, 1.75);
        assert!(dir.path().join(&run.error_map).is_file() && dir.path().join(&run.image).is_file());
    }

    #[test]
    fn a_wrong_size_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("images")).unwrap();
        let reference = Image::new(4, 4);
        let bar = indicatif::ProgressBar::hidden();
        let scoring = Scoring {
            dir: dir.path(),
            reference: &reference,
            tone: ToneMap::auto(&reference),
            layer: "beauty",
            reference_psnr_db: None,
            bar: &bar,
        };
        let error = scoring
            .measure("shrinker", 1, 0, (0.0, 0.0, 0.0), None, Image::new(3, 4), Default::default())
            .err()
            .unwrap();
        let message = format!("{error:#}");
        assert!(message.contains("shrinker") && message.contains("expected 4x4, found 3x4"), "{message}");
        assert_eq!(std::fs::read_dir(dir.path().join("images")).unwrap().count(), 0, "nothing written");
    }

    /// A run is flagged once the reference's error is at least half of what is measured:
    /// within 3 dB of the reference's own PSNR (the PSNR of MSE_run + MSE_reference with equal
    /// parts is 10·log10 2 below the reference's), and never for a non-finite score.
    #[test]
    fn runs_near_the_reference_s_own_psnr_are_flagged() {
        assert!(reference_limited_note(30.0, 36.5).is_none());
        assert!(reference_limited_note(33.4, 36.5).is_none());
        let note = reference_limited_note(33.6, 36.5).expect("within 3 dB");
        assert!(note.contains("33.60 dB") && note.contains("36.50 dB") && note.contains("--reference-spp"), "{note}");
        assert!(note.starts_with(recon::method::WARNING), "shown in the open: {note}");
        assert!(reference_limited_note(40.0, 36.5).is_some());
        assert!(reference_limited_note(f64::NAN, 36.5).is_none());
        // Equal MSEs read 10·log10 2 below the reference: flagged.
        assert!(reference_limited_note(36.5 - 10.0 * 2f64.log10(), 36.5).is_some());
    }

    #[test]
    fn ladder_is_powers_of_two_plus_inputs() {
        assert_eq!(ladder(16, &[3, 4]), vec![1, 2, 3, 4, 8, 16]);
        assert_eq!(ladder(1, &[]), vec![1]);
    }

    #[test]
    fn verdicts_read_the_pt_curve_and_skip_invalid_runs() {
        // PT: 10 dB per decade through (1 s, 20 dB).
        let mut runs = vec![
            run("pt", 1, 1.0, 20.0, true),
            run("pt", 10, 10.0, 30.0, true),
            run("pt", 100, 100.0, 40.0, true),
            // 30 dB in 1 s: PT needs 10 s → 10× faster, +10 dB at equal time.
            run("fast", 1, 1.0, 30.0, true),
            // Invalid: ignored for the verdicts even though its PSNR looks great.
            run("fast", 2, 1.0, 90.0, false),
            run("broken", 1, 1.0, 99.0, false),
        ];
        let verdicts = verdicts(&mut runs);
        let fast = &runs[3];
        assert!((fast.speedup.unwrap() - 10.0).abs() < 1e-9);
        assert!((fast.equal_time_psnr_gain_db.unwrap() - 10.0).abs() < 1e-9);
        assert!(!fast.verdict_extrapolated);
        assert_eq!(runs[4].speedup, None);
        assert_eq!(verdicts.len(), 2);
        assert_eq!(verdicts[0].method, "fast");
        assert!((verdicts[0].best_speedup.unwrap() - 10.0).abs() < 1e-9);
        assert_eq!(verdicts[0].best_speedup_input_spp, Some(1));
        assert!(verdicts[0].summary.contains("10.00× faster"), "{}", verdicts[0].summary);
        assert_eq!(verdicts[1].best_speedup, None);
        assert!(verdicts[1].summary.contains("no valid run"), "{}", verdicts[1].summary);
    }

    fn timed(mut run: Run, timings: &[f64]) -> Run {
        run.timings = timings.to_vec();
        run.timing_spread = timing::relative_spread(timings);
        run.total_s = timings[timing::median_index(timings).unwrap()];
        run
    }

    #[test]
    fn a_speedup_within_the_timing_spread_is_no_clear_difference() {
        // PT through (1 s, 20 dB) and (10 s, 30 dB), each timed three times with ±10 % noise.
        let pt = [
            timed(run("pt", 1, 0.0, 20.0, true), &[0.9, 1.0, 1.1]),
            timed(run("pt", 10, 0.0, 30.0, true), &[9.0, 10.0, 11.0]),
        ];
        // `box`: path tracing's 20 dB, timed a little faster by chance: the median says 1.05×
        // faster, but the repetitions allow 0.86× to 1.29×.
        let mut runs = pt.to_vec();
        runs.push(timed(run("box", 1, 0.0, 20.0, true), &[0.85, 0.95, 1.05]));
        // Ten times faster whatever the repetitions.
        runs.push(timed(run("fast", 1, 0.0, 30.0, true), &[0.9, 1.0, 1.1]));
        let verdicts = verdicts(&mut runs);
        let (box_run, fast_run) = (&runs[2], &runs[3]);
        assert!((box_run.speedup.unwrap() - 1.0 / 0.95).abs() < 1e-9);
        let [lo, hi] = box_run.speedup_range.unwrap();
        assert!((lo - 0.9 / 1.05).abs() < 1e-9 && (hi - 1.1 / 0.85).abs() < 1e-9, "{lo} {hi}");
        assert_eq!(verdicts[0].difference, Some("no clear difference"));
        assert!(verdicts[0].summary.contains("no clear difference"), "{}", verdicts[0].summary);
        let [lo, hi] = fast_run.speedup_range.unwrap();
        assert!((lo - 9.0 / 1.1).abs() < 1e-9 && (hi - 11.0 / 0.9).abs() < 1e-9, "{lo} {hi}");
        assert_eq!(verdicts[1].difference, Some("faster"));
        assert!(verdicts[1].summary.contains("10.00× faster"), "{}", verdicts[1].summary);
    }

    /// `box` reaches path tracing's PSNR at the ladder's last rung, a little slower: the time to
    /// that PSNR is measured (the rung's), so the sentence does not call it extrapolated, while
    /// the run's equal-time PSNR, read beyond the ladder's last time, is flagged in the table.
    #[test]
    fn the_summary_says_extrapolated_only_when_its_reading_is() {
        let mut runs = vec![
            run("pt", 8, 0.5, 18.0, true),
            run("pt", 16, 1.0, 21.0, true),
            run("box", 16, 1.05, 21.0, true),
            run("better", 16, 1.0, 24.0, true),
        ];
        let verdicts = verdicts(&mut runs);
        assert!(runs[2].verdict_extrapolated, "box's equal-time PSNR lies beyond the ladder");
        assert!((runs[2].speedup.unwrap() - 1.0 / 1.05).abs() < 1e-9);
        assert!(!verdicts[0].summary.contains("extrapolated"), "{}", verdicts[0].summary);
        // 3 dB beyond the last rung: path tracing's time to it is extrapolated.
        assert!(verdicts[1].summary.contains("extrapolated"), "{}", verdicts[1].summary);
    }

    /// Found on soft-shadow.toml at 96×72: path tracing's 1 spp had one slow repetition (11.7 ms
    /// against 6.3-7.3), slower than all of 2 spp's, so the slow curve lost its 1-spp point and
    /// extrapolated below 2 spp; `box` at 1 spp (path tracing's own PSNR) then got the range
    /// [1.17, 0.45], upside down, and the verdict "1.42× faster".
    #[test]
    fn a_slow_outlier_at_the_cheapest_rung_gives_an_ordered_range_holding_the_median() {
        let mut runs = vec![
            timed(run("pt", 1, 0.0, 16.72, true), &[0.0117, 0.00626, 0.00732]),
            timed(run("pt", 2, 0.0, 22.02, true), &[0.00758, 0.00750, 0.00694]),
            timed(run("box", 1, 0.0, 16.72, true), &[0.00516, 0.00536, 0.00499]),
        ];
        let verdicts = verdicts(&mut runs);
        let box_run = &runs[2];
        let [lo, hi] = box_run.speedup_range.unwrap();
        let median = box_run.speedup.unwrap();
        assert!(lo <= median && median <= hi, "{lo} {median} {hi}");
        assert!(lo <= 1.0 && 1.0 <= hi, "the repetitions allow both: {lo} {hi}");
        assert_eq!(verdicts[0].difference, Some("no clear difference"), "{}", verdicts[0].summary);
    }

    #[test]
    fn settled_timings_pair_trace_and_reconstruction_repetitions() {
        let reference = Image::new(2, 2);
        let run = run("ilfr", 4, 0.0, 30.0, true);
        let stats = |gather_s: f64| recon::method::Stats::from([("gather_s".to_string(), gather_s)]);
        let mut measured = Measured {
            run,
            image: reference,
            trace: TraceKey::Samples(4, 0),
            light_trace: None,
            parts: vec![[0.1, 1.0], [0.1, 3.0], [0.1, 2.0]],
            stats: vec![stats(0.9), stats(2.9), stats(1.9)],
        };
        // Two trace repetitions: the third reconstruction pairs with the last trace time.
        measured.settle_timings(&[0.5, 0.7]);
        assert_eq!(measured.run.timings, vec![1.6, 3.8, 2.8]);
        assert_eq!((measured.run.trace_s, measured.run.recon_s, measured.run.total_s), (0.7, 2.0, 2.8));
        assert!((measured.run.timing_spread - 2.2 / 2.8).abs() < 1e-12);
        // The statistics (stage times) are the median repetition's too.
        assert_eq!(measured.run.stats["gather_s"], 1.9);
    }

    /// Soft shadows' light samples count only for the runs that read them, repetition by
    /// repetition.
    #[test]
    fn light_sample_times_add_to_the_runs_that_read_them() {
        let traces = BTreeMap::from([
            (TraceKey::Samples(4, 0), vec![1.0, 2.0, 3.0]),
            (TraceKey::LightSamples(4, 0), vec![0.25, 0.5, 0.75]),
        ]);
        assert_eq!(trace_times(&traces, TraceKey::Samples(4, 0), None), vec![1.0, 2.0, 3.0]);
        let with_light = trace_times(&traces, TraceKey::Samples(4, 0), Some(TraceKey::LightSamples(4, 0)));
        assert_eq!(with_light, vec![1.25, 2.5, 3.75]);
        // Which methods read them: tlfr for soft shadows only; box never.
        let methods = resolve_methods(&["box".into(), "tlfr".into()], Effect::SoftShadow).unwrap();
        assert!(!methods[0].reads_light_samples(Effect::SoftShadow));
        assert!(methods[1].reads_light_samples(Effect::SoftShadow));
        let methods = resolve_methods(&["tlfr".into()], Effect::Dof).unwrap();
        assert!(!methods[0].reads_light_samples(Effect::Dof));
    }

    #[test]
    fn unknown_and_repeated_methods() {
        let error = resolve_methods(&["box".into(), "magic".into()], Effect::Indirect).err().unwrap().to_string();
        assert!(error.contains("magic") && error.contains("box"), "{error}");
        let methods = resolve_methods(&["box".into(), "box".into(), " ".into()], Effect::Indirect).unwrap();
        assert_eq!(methods.len(), 1);
    }

    /// `ilfr:grain=filter` on a glossy scene's indirect light is refused by name before
    /// tracing; plain `ilfr`, and the filter on a diffuse scene, are not.
    #[test]
    fn a_grain_filter_on_a_glossy_scene_is_refused_before_tracing() {
        let methods = resolve_methods(&["ilfr".into(), "ilfr:grain=filter".into()], Effect::Indirect).unwrap();
        let error = refuse_narrowed_on_glossy_scene(&methods, Effect::Indirect, true).unwrap_err().to_string();
        assert!(error.contains("ilfr:grain=filter") && error.contains("glossy"), "{error}");
        assert!(refuse_narrowed_on_glossy_scene(&methods, Effect::Indirect, false).is_ok());
        assert!(refuse_narrowed_on_glossy_scene(&methods[..1], Effect::Indirect, true).is_ok());
    }
}
