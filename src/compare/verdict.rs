//! The two verdicts of a comparison, read off a baseline's curve (PSNR against wall time; the
//! baseline is path tracing, [`PATH_TRACING`], or any method named as one, [`Baseline`]):
//!
//! - **equal-time PSNR gain** = method PSNR − baseline PSNR at the method's total time;
//! - **equal-quality speedup** = baseline time to reach the method's PSNR / method's total time,
//!   with the range its repeated timings allow, and whether that is a clear difference
//!   (`timing::Difference`).
//!
//! The curve is interpolated piecewise linearly in (log time, PSNR). PSNR is itself logarithmic
//! in the MSE, so this is the log-log interpolation of error against time. Beyond its measured
//! ends the curve is extended with the slope path tracing has asymptotically, MSE ∝ 1/time,
//! i.e. 10 dB per decade of time, and the result is marked as extrapolated.

use super::results::{Run, Verdict};
use super::timing::{self, Difference};

/// A point on the path-tracing curve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurvePoint {
    pub seconds: f64,
    pub psnr_db: f64,
}

/// PSNR gained per decade of time by unbiased Monte Carlo (MSE ∝ 1/time).
pub const PT_DB_PER_DECADE: f64 = 10.0;

/// A value read off the curve, and whether it lies outside the measured range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    pub value: f64,
    pub extrapolated: bool,
}

/// The PT curve: points with positive finite time and finite PSNR, sorted by time, with the
/// PSNR made non-decreasing (a later, longer render that measured lower because of noise in
/// the estimate must not make the inverse ambiguous: we keep the running maximum).
pub fn monotone_curve(points: &[CurvePoint]) -> Vec<CurvePoint> {
    let mut curve: Vec<CurvePoint> =
        points.iter().copied().filter(|p| p.seconds.is_finite() && p.seconds > 0.0 && p.psnr_db.is_finite()).collect();
    curve.sort_by(|a, b| a.seconds.total_cmp(&b.seconds));
    let mut best = f64::NEG_INFINITY;
    for point in &mut curve {
        best = best.max(point.psnr_db);
        point.psnr_db = best;
    }
    curve
}

/// PT PSNR at `seconds`.
pub fn psnr_at_time(curve: &[CurvePoint], seconds: f64) -> Option<Reading> {
    let (first, last) = (curve.first()?, curve.last()?);
    if !(seconds.is_finite() && seconds > 0.0) {
        return None;
    }
    let log_t = seconds.log10();
    if seconds < first.seconds {
        return Some(Reading {
            value: first.psnr_db - PT_DB_PER_DECADE * (first.seconds.log10() - log_t),
            extrapolated: true,
        });
    }
    if seconds > last.seconds {
        return Some(Reading {
            value: last.psnr_db + PT_DB_PER_DECADE * (log_t - last.seconds.log10()),
            extrapolated: true,
        });
    }
    for pair in curve.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        if seconds <= b.seconds {
            let span = b.seconds.log10() - a.seconds.log10();
            let f = if span > 0.0 { (log_t - a.seconds.log10()) / span } else { 1.0 };
            return Some(Reading { value: a.psnr_db + f * (b.psnr_db - a.psnr_db), extrapolated: false });
        }
    }
    Some(Reading { value: last.psnr_db, extrapolated: false })
}

/// PT time to reach `psnr_db`.
pub fn time_to_psnr(curve: &[CurvePoint], psnr_db: f64) -> Option<Reading> {
    let (first, last) = (curve.first()?, curve.last()?);
    if !psnr_db.is_finite() {
        return None;
    }
    if psnr_db <= first.psnr_db {
        // Faster than the cheapest render: extrapolate below it (or exactly it).
        let decades = (first.psnr_db - psnr_db) / PT_DB_PER_DECADE;
        return Some(Reading { value: first.seconds / 10f64.powf(decades), extrapolated: psnr_db < first.psnr_db });
    }
    if psnr_db > last.psnr_db {
        let decades = (psnr_db - last.psnr_db) / PT_DB_PER_DECADE;
        return Some(Reading { value: last.seconds * 10f64.powf(decades), extrapolated: true });
    }
    for pair in curve.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        if psnr_db <= b.psnr_db {
            let rise = b.psnr_db - a.psnr_db;
            let f = if rise > 0.0 { (psnr_db - a.psnr_db) / rise } else { 0.0 };
            let log_t = a.seconds.log10() + f * (b.seconds.log10() - a.seconds.log10());
            return Some(Reading { value: 10f64.powf(log_t), extrapolated: false });
        }
    }
    Some(Reading { value: last.seconds, extrapolated: false })
}

/// The method whose curve a comparison's verdicts read: path tracing, or any other run's
/// method name (a baseline such as a denoiser), with how the sentences name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Baseline<'a> {
    /// The runs' `method`.
    pub method: &'a str,
    /// In sentences: "path tracing needs 1.2 s for that".
    pub name: &'a str,
    /// Before "curve": "the PT curve extrapolated".
    pub short: &'a str,
}

/// Path tracing's ladder: the comparison's verdicts (`results.json`'s `speedup`,
/// `equal_time_psnr_gain_db` and `verdicts`).
pub const PATH_TRACING: Baseline<'static> = Baseline { method: "pt", name: "path tracing", short: "PT" };

/// What a run reads off a baseline's curves.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Readings {
    /// Run PSNR − the baseline's PSNR at the run's time.
    pub equal_time_psnr_gain_db: Option<f64>,
    /// The baseline's time to the run's PSNR / the run's time (median repetitions).
    pub speedup: Option<f64>,
    /// The speedup's range over the repetitions (see [`Curves::read`]).
    pub speedup_range: Option<[f64; 2]>,
    /// Whether either reading lies beyond the curve's measured ends.
    pub extrapolated: bool,
    /// Whether the speedup's reading (the baseline's time to the run's PSNR) does.
    pub speedup_extrapolated: bool,
    /// For a run with a precompute: one frame without it against the baseline.
    pub per_frame_speedup: Option<f64>,
    /// For a run with a precompute: the frames after which it has paid for itself.
    pub break_even_frames: Option<f64>,
}

/// A baseline's curves: through its median, fastest and slowest repetitions.
pub struct Curves {
    median: Vec<CurvePoint>,
    fastest: Vec<CurvePoint>,
    slowest: Vec<CurvePoint>,
}

/// The fastest and slowest repetition of a run (its total when it has no list).
fn time_range(run: &Run) -> (f64, f64) {
    timing::range(&run.timings).unwrap_or((run.total_s, run.total_s))
}

impl Curves {
    /// The curves of `baseline`'s valid runs in `runs`.
    pub fn of(runs: &[Run], baseline: &Baseline) -> Curves {
        let curve = |time: &dyn Fn(&Run) -> f64| {
            monotone_curve(
                &runs
                    .iter()
                    .filter(|r| r.method == baseline.method && r.valid)
                    .map(|r| CurvePoint { seconds: time(r), psnr_db: r.psnr_db })
                    .collect::<Vec<_>>(),
            )
        };
        Curves {
            median: curve(&|r| r.total_s),
            fastest: curve(&|r| time_range(r).0),
            slowest: curve(&|r| time_range(r).1),
        }
    }

    /// `run`'s readings. The speedup uses the median repetitions; its range pairs the run's
    /// slowest repetition with the baseline's fastest curve and the other way round.
    pub fn read(&self, run: &Run) -> Readings {
        let at_time = psnr_at_time(&self.median, run.total_s);
        let to_psnr = time_to_psnr(&self.median, run.psnr_db);
        let speedup = to_psnr.filter(|_| run.total_s > 0.0).map(|r| r.value / run.total_s);
        let (fastest, slowest) = time_range(run);
        let speedup_range = match (time_to_psnr(&self.fastest, run.psnr_db), time_to_psnr(&self.slowest, run.psnr_db)) {
            (Some(fast), Some(slow)) if fastest > 0.0 => speedup.map(|median| {
                // Ordered and holding the median's speedup: the two pairings can cross where
                // the baseline's slowest repetitions are not monotone in spp (a slow outlier
                // at the cheapest rung leaves the slow curve, which then extrapolates there).
                let (a, b) = (fast.value / slowest, slow.value / fastest);
                [a.min(b).min(median), a.max(b).max(median)]
            }),
            _ => None,
        };
        let mut readings = Readings {
            equal_time_psnr_gain_db: at_time.map(|r| run.psnr_db - r.value),
            speedup,
            speedup_range,
            extrapolated: at_time.is_some_and(|r| r.extrapolated) || to_psnr.is_some_and(|r| r.extrapolated),
            speedup_extrapolated: to_psnr.is_some_and(|r| r.extrapolated),
            per_frame_speedup: None,
            break_even_frames: None,
        };
        if run.precompute_from_cache.is_some() {
            // One frame without its precompute, and the frames that pay for the precompute.
            readings.per_frame_speedup = to_psnr.filter(|_| run.recon_s > 0.0).map(|r| r.value / run.recon_s);
            readings.break_even_frames =
                to_psnr.filter(|r| r.value > run.recon_s).map(|r| run.preprocess_s / (r.value - run.recon_s));
        }
        readings
    }
}

/// Each method's verdict against `baseline` (every method but the baseline, in the order of
/// their first run), with each run's readings (`None` for the baseline's runs and invalid
/// ones); `runs` are left as they are, so that verdicts against several baselines can be read
/// from the same runs. A method's best run is its highest speedup; a range that holds 1, or a
/// speedup within `timing::BETWEEN_RUNS_NOISE` of 1, is no clear difference.
pub fn against(runs: &[Run], baseline: &Baseline) -> (Vec<Verdict>, Vec<Option<Readings>>) {
    let curves = Curves::of(runs, baseline);
    let readings: Vec<Option<Readings>> =
        runs.iter().map(|r| (r.method != baseline.method && r.valid).then(|| curves.read(r))).collect();
    let mut names: Vec<&str> = Vec::new();
    for run in runs.iter().filter(|r| r.method != baseline.method) {
        if !names.contains(&run.method.as_str()) {
            names.push(&run.method);
        }
    }
    let verdicts = names
        .into_iter()
        .map(|method| {
            let mine: Vec<(&Run, Option<&Readings>)> =
                runs.iter().zip(&readings).filter(|(r, _)| r.method == method).map(|(r, x)| (r, x.as_ref())).collect();
            summarise(method, &mine, baseline)
        })
        .collect();
    (verdicts, readings)
}

/// The verdicts against path tracing ([`against`] [`PATH_TRACING`]), each valid run's readings
/// written into its verdict fields (`results.json`'s `speedup`, `equal_time_psnr_gain_db`, ...).
pub fn verdicts_against_path_tracing(runs: &mut [Run]) -> Vec<Verdict> {
    let (verdicts, readings) = against(runs, &PATH_TRACING);
    for (run, readings) in runs.iter_mut().zip(readings) {
        if let Some(readings) = readings {
            run.equal_time_psnr_gain_db = readings.equal_time_psnr_gain_db;
            run.speedup = readings.speedup;
            run.speedup_range = readings.speedup_range;
            run.verdict_extrapolated = readings.extrapolated;
            run.per_frame_speedup = readings.per_frame_speedup;
            run.break_even_frames = readings.break_even_frames;
        }
    }
    verdicts
}

/// A per-frame speedup in words: "3.2× faster", or "2.0× slower" below 1 (never "0.5× faster").
fn per_frame_ratio(speedup: f64) -> String {
    if speedup >= 1.0 {
        format!("{speedup:.1}× faster")
    } else {
        format!("{:.1}× slower", 1.0 / speedup.max(1e-12))
    }
}

/// `method`'s verdict from its runs and their readings against `baseline`.
fn summarise(method: &str, mine: &[(&Run, Option<&Readings>)], baseline: &Baseline) -> Verdict {
    let speedup_of = |(_, x): &&(&Run, &Readings)| x.speedup.unwrap_or(0.0);
    let valid: Vec<(&Run, &Readings)> =
        mine.iter().filter_map(|&(r, x)| x.filter(|x| x.speedup.is_some()).map(|x| (r, x))).collect();
    let best = valid.iter().max_by(|a, b| speedup_of(a).total_cmp(&speedup_of(b)));
    let best_gain = valid.iter().filter_map(|(_, x)| x.equal_time_psnr_gain_db).max_by(f64::total_cmp);
    let best_psnr = valid.iter().map(|(r, _)| r.psnr_db).max_by(f64::total_cmp);
    let best_frame = valid
        .iter()
        .filter(|(_, x)| x.per_frame_speedup.is_some())
        .max_by(|a, b| a.1.per_frame_speedup.unwrap_or(0.0).total_cmp(&b.1.per_frame_speedup.unwrap_or(0.0)));
    let difference =
        best.map(|(_, x)| Difference::of(x.speedup.unwrap_or(0.0), x.speedup_range.map(|[lo, hi]| (lo, hi))));
    let (name, short) = (baseline.name, baseline.short);
    let summary = match best {
        Some((run, x)) => {
            let speedup = x.speedup.unwrap_or(0.0);
            // Either reading beyond the curve's ends: the sentence says which whenever the table
            // stars the run (the time to this PSNR, or only the PSNR at this time).
            let extrapolated = if x.speedup_extrapolated {
                format!(" ({short} curve extrapolated at 10 dB per decade)")
            } else if x.extrapolated {
                format!(
                    " (measured on the {short} curve; its equal-time gain reads the curve beyond its measured range, at \
                     10 dB per decade)"
                )
            } else {
                String::new()
            };
            let rays = if run.recon_rays > 0 {
                format!(" with {} reconstruction rays", run.recon_rays)
            } else {
                String::new()
            };
            let ratio = if speedup >= 1.0 {
                format!("{speedup:.2}× faster")
            } else {
                format!("{:.2}× slower", 1.0 / speedup.max(1e-12))
            };
            let judged = match (difference, x.speedup_range) {
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
                "{method} at its best ({} input spp{rays}) reaches {:.2} dB in {:.3} s; {name} needs {:.3} s for that: {judged}{}",
                run.input_spp,
                run.psnr_db,
                run.total_s,
                speedup * run.total_s,
                extrapolated
            )
        }
        None if mine.iter().any(|(r, _)| !r.valid) => {
            format!("{method}: no valid run (non-finite output pixels); no verdict")
        }
        None => format!("{method}: no verdict (no {} curve)", name.replace(' ', "-")),
    };
    let summary = match best_frame.and_then(|(r, x)| x.per_frame_speedup.map(|s| (s, r, x))) {
        Some((speedup, run, x)) => format!(
            "{summary}; after a precompute of {:.2} s one frame takes {:.4} s: {} than {name} to {:.2} dB, {}",
            run.preprocess_s,
            run.recon_s,
            per_frame_ratio(speedup),
            run.psnr_db,
            match x.break_even_frames {
                Some(n) => format!("the precompute pays for itself after {n:.1} frames"),
                None => "the precompute never pays for itself".to_string(),
            }
        ),
        None => summary,
    };
    Verdict {
        method: method.to_string(),
        best_speedup: best.and_then(|(_, x)| x.speedup),
        best_speedup_range: best.and_then(|(_, x)| x.speedup_range),
        difference: difference.map(|d| d.name()),
        best_speedup_input_spp: best.map(|(r, _)| r.input_spp),
        best_speedup_recon_rays: best.map(|(r, _)| r.recon_rays),
        best_equal_time_psnr_gain_db: best_gain,
        best_psnr_db: best_psnr,
        best_per_frame_speedup: best_frame.and_then(|(_, x)| x.per_frame_speedup),
        break_even_frames: best_frame.and_then(|(_, x)| x.break_even_frames),
        summary,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_per_frame_ratio_below_one_reads_slower() {
        assert_eq!(per_frame_ratio(174.0), "174.0× faster");
        assert_eq!(per_frame_ratio(1.0), "1.0× faster");
        assert_eq!(per_frame_ratio(0.5), "2.0× slower");
    }

    fn run(method: &str, spp: u32, total_s: f64, psnr_db: f64, valid: bool) -> Run {
        let mut run = Run::example(method, spp, total_s, psnr_db);
        run.valid = valid;
        run.nonfinite_pixels = if valid { 0 } else { 3 };
        run
    }

    fn point(seconds: f64, psnr_db: f64) -> CurvePoint {
        CurvePoint { seconds, psnr_db }
    }

    /// An ideal PT curve: 10 dB per decade through (1 s, 20 dB).
    fn ideal() -> Vec<CurvePoint> {
        [0.125, 0.25, 0.5, 1.0, 2.0, 4.0].iter().map(|&t: &f64| point(t, 20.0 + 10.0 * t.log10())).collect()
    }

    #[test]
    fn inverse_readings_agree_on_an_ideal_curve() {
        let curve = monotone_curve(&ideal());
        for seconds in [0.01, 0.2, 1.0, 3.0, 50.0] {
            let psnr = psnr_at_time(&curve, seconds).unwrap();
            let expected = 20.0 + 10.0 * f64::log10(seconds);
            assert!((psnr.value - expected).abs() < 1e-9, "{seconds}: {psnr:?}");
            assert_eq!(psnr.extrapolated, !(0.125..=4.0).contains(&seconds));
            let back = time_to_psnr(&curve, psnr.value).unwrap();
            assert!((back.value / seconds - 1.0).abs() < 1e-9, "{seconds}: {back:?}");
        }
    }

    #[test]
    fn interpolation_is_linear_in_log_time() {
        let curve = monotone_curve(&[point(1.0, 10.0), point(100.0, 30.0)]);
        // log10(10) is halfway between log10(1) and log10(100).
        assert!((psnr_at_time(&curve, 10.0).unwrap().value - 20.0).abs() < 1e-12);
        assert!((time_to_psnr(&curve, 20.0).unwrap().value - 10.0).abs() < 1e-9);
    }

    #[test]
    fn noisy_curves_are_made_monotone_and_bad_points_dropped() {
        let curve = monotone_curve(&[
            point(2.0, 25.0),
            point(1.0, 20.0),
            point(4.0, 24.0),
            point(0.0, 50.0),
            point(f64::NAN, 1.0),
            point(8.0, f64::INFINITY),
        ]);
        assert_eq!(curve, vec![point(1.0, 20.0), point(2.0, 25.0), point(4.0, 25.0)]);
        // 25 dB is first reached at 2 s.
        assert!((time_to_psnr(&curve, 25.0).unwrap().value - 2.0).abs() < 1e-12);
    }

    #[test]
    fn empty_curves_and_bad_queries_give_nothing() {
        assert_eq!(psnr_at_time(&[], 1.0), None);
        assert_eq!(time_to_psnr(&[], 20.0), None);
        let curve = monotone_curve(&ideal());
        assert_eq!(psnr_at_time(&curve, 0.0), None);
        assert_eq!(psnr_at_time(&curve, f64::NAN), None);
        assert_eq!(time_to_psnr(&curve, f64::NAN), None);
        let single = [point(1.0, 20.0)];
        assert_eq!(psnr_at_time(&single, 1.0).unwrap(), Reading { value: 20.0, extrapolated: false });
        assert_eq!(time_to_psnr(&single, 30.0).unwrap(), Reading { value: 10.0, extrapolated: true });
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
        let verdicts = verdicts_against_path_tracing(&mut runs);
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
        let verdicts = verdicts_against_path_tracing(&mut runs);
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
    /// that PSNR is measured (the rung's), so the sentence does not call the curve extrapolated
    /// for the speedup, while it says, as the table's star does, that the run's equal-time PSNR
    /// is read beyond the ladder's last time.
    #[test]
    fn the_summary_says_extrapolated_only_when_its_reading_is() {
        let mut runs = vec![
            run("pt", 8, 0.5, 18.0, true),
            run("pt", 16, 1.0, 21.0, true),
            run("box", 16, 1.05, 21.0, true),
            run("better", 16, 1.0, 24.0, true),
        ];
        let verdicts = verdicts_against_path_tracing(&mut runs);
        assert!(runs[2].verdict_extrapolated, "box's equal-time PSNR lies beyond the ladder");
        assert!((runs[2].speedup.unwrap() - 1.0 / 1.05).abs() < 1e-9);
        assert!(!verdicts[0].summary.contains("curve extrapolated"), "{}", verdicts[0].summary);
        assert!(verdicts[0].summary.contains("equal-time gain reads the curve beyond"), "{}", verdicts[0].summary);
        // 3 dB beyond the last rung: path tracing's time to it is extrapolated.
        assert!(verdicts[1].summary.contains("PT curve extrapolated"), "{}", verdicts[1].summary);
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
        let verdicts = verdicts_against_path_tracing(&mut runs);
        let box_run = &runs[2];
        let [lo, hi] = box_run.speedup_range.unwrap();
        let median = box_run.speedup.unwrap();
        assert!(lo <= median && median <= hi, "{lo} {median} {hi}");
        assert!(lo <= 1.0 && 1.0 <= hi, "the repetitions allow both: {lo} {hi}");
        assert_eq!(verdicts[0].difference, Some("no clear difference"), "{}", verdicts[0].summary);
    }

    /// Any method's runs can be the curve: against OIDN's, a method reaching at 1 s what OIDN
    /// reaches at 10 s is 10× faster, path tracing is judged like any other method, and the runs
    /// keep their verdicts against path tracing.
    #[test]
    fn verdicts_read_any_named_baseline_s_curve() {
        let oidn = Baseline { method: "oidn", name: "OIDN", short: "OIDN" };
        let runs = vec![
            run("oidn", 1, 1.0, 20.0, true),
            run("oidn", 10, 10.0, 30.0, true),
            run("pt", 16, 10.0, 20.0, true),
            run("ilfr", 4, 1.0, 30.0, true),
        ];
        let (verdicts, readings) = against(&runs, &oidn);
        assert_eq!(verdicts.iter().map(|v| v.method.as_str()).collect::<Vec<_>>(), ["pt", "ilfr"]);
        assert!(readings[0].is_none(), "the baseline is not judged against itself");
        assert!((readings[3].unwrap().speedup.unwrap() - 10.0).abs() < 1e-9);
        assert!((readings[2].unwrap().speedup.unwrap() - 0.1).abs() < 1e-9, "path tracing's 20 dB in 10 s");
        assert!(verdicts[1].summary.contains("OIDN needs 10.000 s for that: 10.00× faster"), "{}", verdicts[1].summary);
        assert!(runs.iter().all(|r| r.speedup.is_none()), "the runs' fields are path tracing's");
        let (alone, _) = against(&[run("ilfr", 4, 1.0, 30.0, true)], &oidn);
        assert!(alone[0].summary.contains("no verdict (no OIDN curve)"), "{}", alone[0].summary);
    }
}
