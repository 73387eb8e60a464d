//! `results.json`: the machine-readable outcome of `lfr compare`. The schema is
//! `docs/compare.schema.json`, described field by field in `docs/compare.md`; bump
//! `SCHEMA` when a field changes meaning or disappears.

use serde::Serialize;

pub const SCHEMA: &str = "lfr-compare/3";

#[derive(Clone, Debug, Serialize)]
pub struct Results {
    pub schema: &'static str,
    pub lfr_version: &'static str,
    pub scene: String,
    pub effect: String,
    pub width: u32,
    pub height: u32,
    pub seed: u32,
    pub threads: usize,
    pub max_bounces: u32,
    /// Scene units; only for `ao`.
    pub ao_radius: Option<f32>,
    pub tone_map: ToneMapInfo,
    pub reference: ReferenceInfo,
    /// Whether HDR-FLIP was computed (the Python package `flip-evaluator` was present).
    pub flip_available: bool,
    /// Whether each run's peak memory is its own (false: the process's since start).
    pub peak_rss_per_run: bool,
    /// Speedups within this relative distance of 1 are "no clear difference" whatever the
    /// repetitions' spread (`timing::BETWEEN_RUNS_NOISE`, docs/compare.md).
    pub between_runs_noise: f64,
    /// The winner at each time budget, in words (`compare::budget`).
    pub headline: String,
    /// The winners behind the headline: by PSNR and by HDR-FLIP, per span of budgets.
    pub budgets: Vec<Span>,
    pub runs: Vec<Run>,
    pub skipped: Vec<Skipped>,
    pub verdicts: Vec<Verdict>,
    /// When `oidn` ran: every other method's verdict against it (path tracing's first).
    pub verdicts_against_oidn: Vec<PeerVerdict>,
    pub total_seconds: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct ToneMapInfo {
    pub exposure: f32,
    pub gamma: f32,
    /// `"auto"` (99th-percentile luminance of the reference → 1) or `"given"` (--exposure).
    pub exposure_source: &'static str,
}

#[derive(Clone, Debug, Serialize)]
pub struct ReferenceInfo {
    pub spp: u32,
    /// Wall time of the reference render when it was made (also when read from the cache).
    pub seconds: f64,
    /// The two seeds of the two half renders; never the inputs' seed.
    pub seeds: [u32; 2],
    pub cache_key: String,
    pub from_cache: bool,
    /// The files of an external reference (`--reference`); empty when traced or cached.
    pub external: Vec<String>,
    /// PSNR of the reference itself against the truth, measured at the check's pixels
    /// (`check`): PSNR(check, reference) + 10·log10((k + 1) / k), k = check spp / reference spp.
    /// Method PSNRs near it are limited by the reference. With `--reference-check off`, the
    /// halves' estimate (null for one external image).
    pub estimated_psnr_db: Option<f64>,
    /// The older estimate from the reference's two halves, PSNR(half A, half B) + 6.02 dB:
    /// optimistic where rare paths carry the light. Null for an external reference given as one
    /// image.
    pub halves_psnr_db: Option<f64>,
    /// Null with `--reference-check off`.
    pub check: Option<ReferenceCheckInfo>,
    pub image: String,
}

/// "1 pixel", "920 pixels".
pub fn pixels_text(count: usize) -> String {
    format!("{count} pixel{}", if count == 1 { "" } else { "s" })
}

/// The independent check of the reference's error: a sparse, stratified set of pixels (one per
/// 4 × 4 block) traced with `--reference-check` (default 4) times the reference's spp and a
/// seed of its own.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceCheckInfo {
    /// `[low, high]` dB around `estimated_psnr_db`: the PSNR at the checked pixels' mean squared
    /// error plus and minus two standard errors.
    pub psnr_interval_db: [f64; 2],
    pub pixels: usize,
    pub spp: u32,
    pub seed: u32,
    /// Wall time of the check's render when it was made (also when read from the cache).
    pub seconds: f64,
    pub from_cache: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct Run {
    /// `pt` for the path-tracing ladder, else the method's registry name.
    pub method: String,
    pub input_spp: u32,
    /// Reconstruction rays or locations per pixel; 0 when the method has none.
    pub recon_rays: u32,
    pub trace_s: f64,
    pub preprocess_s: f64,
    pub recon_s: f64,
    /// The median repetition's `trace_s + preprocess_s + recon_s` (for two repetitions, the
    /// faster one).
    pub total_s: f64,
    /// Total seconds of every repetition, in the order they ran (the runs' repetitions
    /// alternate: all runs once, then all again). For a method, repetition i pairs its
    /// reconstruction's i-th timing with its input trace's i-th (or last) timing.
    pub timings: Vec<f64>,
    /// (slowest − fastest) / median of `timings`; 0 for one repetition.
    pub timing_spread: f64,
    pub psnr_db: f64,
    pub rel_mse: f64,
    pub ssim: f64,
    pub flip: Option<f64>,
    pub peak_rss_mb: Option<f64>,
    pub nonfinite_pixels: usize,
    /// False when the output had non-finite pixels: its metrics then include worst-case
    /// values for them, and it takes no part in the verdicts.
    pub valid: bool,
    /// Method PSNR − PT PSNR at `total_s` (null for `pt` runs).
    pub equal_time_psnr_gain_db: Option<f64>,
    /// PT time to reach `psnr_db` / `total_s` (null for `pt` runs).
    pub speedup: Option<f64>,
    /// The speedups the repetitions allow: [PT's fastest time / this run's slowest, PT's slowest
    /// / this run's fastest] (null for `pt` runs).
    pub speedup_range: Option<[f64; 2]>,
    /// Whether the PT curve had to be extended beyond its measured range for the verdicts.
    pub verdict_extrapolated: bool,
    /// When `oidn` ran: OIDN's time to reach `psnr_db` on its own curve / `total_s`, null outside
    /// OIDN's measured range (`compare::peer`) and for `oidn`'s own runs.
    pub speedup_over_oidn: Option<f64>,
    /// The range of `speedup_over_oidn` over the repetitions.
    pub speedup_over_oidn_range: Option<[f64; 2]>,
    /// When `oidn` ran: `"within"`, `"below"` (OIDN's cheapest run is better) or `"above"` (no
    /// OIDN run reaches this PSNR) OIDN's curve; null for `oidn`'s own runs.
    pub oidn_curve_position: Option<&'static str>,
    /// Methods with a precompute (`probes`): whether it was read from the cache (its
    /// `preprocess_s` is then the build time kept beside the cache); null for the others.
    pub precompute_from_cache: Option<bool>,
    /// Methods with a precompute: PT time to reach `psnr_db` / `recon_s` (one frame without
    /// the precompute); null for the others or without a PT curve.
    pub per_frame_speedup: Option<f64>,
    /// Methods with a precompute: the frames after which precompute + frames costs less than
    /// path tracing each frame to `psnr_db`, `preprocess_s / (PT time − recon_s)`; null for
    /// the others, or when a frame is not faster than path tracing.
    pub break_even_frames: Option<f64>,
    /// Relative paths in the output directory.
    pub image: String,
    pub preview: String,
    pub error_map: String,
    pub notes: Vec<String>,
    /// The method's statistics as named numbers (`recon::method::Stats`; empty for most).
    pub stats: recon::method::Stats,
}

/// A method's best showing against OIDN (`compare::peer`).
#[derive(Clone, Debug, Serialize)]
pub struct PeerVerdict {
    pub method: String,
    /// The valid run with the highest equal-quality speedup over OIDN (null when every run lies
    /// outside OIDN's range).
    pub best_speedup: Option<f64>,
    pub best_speedup_range: Option<[f64; 2]>,
    /// `"faster"`, `"slower"` or `"no clear difference"`; null without a speedup.
    pub difference: Option<&'static str>,
    pub summary: String,
}

/// The headline's winners (`compare::budget`), as the record keeps them.
/// One run named in the headline.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Entry {
    pub method: String,
    pub input_spp: u32,
    pub recon_rays: u32,
    pub total_s: f64,
    pub psnr_db: f64,
    pub flip: Option<f64>,
}

/// The winners from `from_s` up to `to_s` seconds of budget (`to_s` null: any larger budget).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Span {
    pub from_s: f64,
    pub to_s: Option<f64>,
    /// The highest PSNR within the budget.
    pub by_psnr: Entry,
    /// The lowest HDR-FLIP within the budget (null without FLIP).
    pub by_flip: Option<Entry>,
    /// Whether the PSNR winner lies within [`super::budget::REFERENCE_LIMITED_DB`] of the reference's own PSNR.
    pub reference_limited: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct Skipped {
    pub method: String,
    pub reason: String,
}

/// A method's best showing over its runs.
#[derive(Clone, Debug, Serialize)]
pub struct Verdict {
    pub method: String,
    /// The valid run with the highest equal-quality speedup.
    pub best_speedup: Option<f64>,
    /// That run's `speedup_range`.
    pub best_speedup_range: Option<[f64; 2]>,
    /// `"faster"`, `"slower"` or `"no clear difference"` (the range holds 1, or the speedup lies
    /// within `between_runs_noise` of 1); null without a verdict.
    pub difference: Option<&'static str>,
    pub best_speedup_input_spp: Option<u32>,
    pub best_speedup_recon_rays: Option<u32>,
    pub best_equal_time_psnr_gain_db: Option<f64>,
    pub best_psnr_db: Option<f64>,
    /// Methods with a precompute: the best `per_frame_speedup` over the valid runs, and that
    /// run's `break_even_frames`; null for the others.
    pub best_per_frame_speedup: Option<f64>,
    pub break_even_frames: Option<f64>,
    pub summary: String,
}

#[cfg(test)]
impl Run {
    /// A valid run with these numbers and nothing else measured, for tests.
    pub fn example(method: &str, input_spp: u32, total_s: f64, psnr_db: f64) -> Run {
        Run {
            method: method.into(),
            input_spp,
            recon_rays: 0,
            trace_s: total_s,
            preprocess_s: 0.0,
            recon_s: 0.0,
            total_s,
            timings: vec![total_s],
            timing_spread: 0.0,
            psnr_db,
            rel_mse: 0.0,
            ssim: 1.0,
            flip: None,
            peak_rss_mb: None,
            nonfinite_pixels: 0,
            valid: true,
            equal_time_psnr_gain_db: None,
            speedup: None,
            speedup_range: None,
            verdict_extrapolated: false,
            speedup_over_oidn: None,
            speedup_over_oidn_range: None,
            oidn_curve_position: None,
            precompute_from_cache: None,
            per_frame_speedup: None,
            break_even_frames: None,
            image: String::new(),
            preview: String::new(),
            error_map: String::new(),
            notes: Vec::new(),
            stats: Default::default(),
        }
    }
}
