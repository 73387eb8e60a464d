//! Verdicts against the peer: the tool a user would pick instead of a reconstruction, Intel
//! Open Image Denoise on the path-traced frame (the method `oidn`). When `oidn` ran, every other
//! run gets its **equal-quality speedup over OIDN** = OIDN's time to the run's PSNR / the run's
//! total time, OIDN's time read on OIDN's own curve (its runs over the input spp: PSNR against
//! median total time, made non-decreasing as `verdict::monotone_curve` does) by piecewise linear
//! interpolation in (log time, PSNR).
//!
//! Unlike path tracing, a denoiser has no known asymptotic slope, so the curve is never
//! extended: a PSNR below OIDN's cheapest run is **below OIDN's range** (OIDN's cheapest run is
//! already better: the run loses whatever its time) and one above OIDN's best run is **above
//! OIDN's range** (no measured OIDN run reaches it); both give no speedup. The range of the
//! speedup over the repetitions comes from OIDN's curves through its fastest and slowest
//! repetitions, as for path tracing (`verdict::Curves`).

use super::results::Run;
use super::timing::{self, Difference};
use super::verdict::{monotone_curve, CurvePoint, Reading};

/// The runs' method name of the peer.
pub const PEER_METHOD: &str = "oidn";

/// Where a PSNR lies on the peer's measured curve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Position {
    /// On the curve: the peer's time to that PSNR.
    Within(f64),
    /// Below the peer's cheapest run.
    Below,
    /// Above the peer's best run.
    Above,
}

impl Position {
    /// `results.json`'s `oidn_curve_position`.
    pub fn name(self) -> &'static str {
        match self {
            Position::Within(_) => "within",
            Position::Below => "below",
            Position::Above => "above",
        }
    }
}

/// The peer's time to `psnr_db` on `curve` (a monotone curve), never extrapolated.
pub fn time_on_measured_curve(curve: &[CurvePoint], psnr_db: f64) -> Option<Position> {
    let (first, last) = (curve.first()?, curve.last()?);
    if !psnr_db.is_finite() {
        return None;
    }
    if psnr_db < first.psnr_db {
        return Some(Position::Below);
    }
    if psnr_db > last.psnr_db {
        return Some(Position::Above);
    }
    super::verdict::time_to_psnr(curve, psnr_db).map(|Reading { value, .. }| Position::Within(value))
}

/// The peer's curves through its median, fastest and slowest repetitions.
struct PeerCurves {
    median: Vec<CurvePoint>,
    fastest: Vec<CurvePoint>,
    slowest: Vec<CurvePoint>,
}

fn time_range(run: &Run) -> (f64, f64) {
    timing::range(&run.timings).unwrap_or((run.total_s, run.total_s))
}

impl PeerCurves {
    fn of(runs: &[Run]) -> Option<PeerCurves> {
        let curve = |time: &dyn Fn(&Run) -> f64| {
            monotone_curve(
                &runs
                    .iter()
                    .filter(|r| r.method == PEER_METHOD && r.valid)
                    .map(|r| CurvePoint { seconds: time(r), psnr_db: r.psnr_db })
                    .collect::<Vec<_>>(),
            )
        };
        let curves = PeerCurves {
            median: curve(&|r| r.total_s),
            fastest: curve(&|r| time_range(r).0),
            slowest: curve(&|r| time_range(r).1),
        };
        (!curves.median.is_empty()).then_some(curves)
    }
}

/// What one run reads off the peer's curve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeerReading {
    pub position: Position,
    /// The peer's time to the run's PSNR / the run's total time (within the range only).
    pub speedup: Option<f64>,
    /// The speedup's range over both sides' repetitions.
    pub speedup_range: Option<[f64; 2]>,
}

fn read(curves: &PeerCurves, run: &Run) -> Option<PeerReading> {
    let position = time_on_measured_curve(&curves.median, run.psnr_db)?;
    let Position::Within(peer_s) = position else {
        return Some(PeerReading { position, speedup: None, speedup_range: None });
    };
    let speedup = (run.total_s > 0.0).then(|| peer_s / run.total_s);
    let (fastest, slowest) = time_range(run);
    let within = |curve: &[CurvePoint]| match time_on_measured_curve(curve, run.psnr_db) {
        Some(Position::Within(seconds)) => Some(seconds),
        _ => None,
    };
    let speedup_range = match (speedup, within(&curves.fastest), within(&curves.slowest)) {
        (Some(median), Some(fast), Some(slow)) if fastest > 0.0 => {
            let (a, b) = (fast / slowest, slow / fastest);
            Some([a.min(b).min(median), a.max(b).max(median)])
        }
        _ => None,
    };
    Some(PeerReading { position, speedup, speedup_range })
}

/// A method's best showing against the peer.
#[derive(Clone, Debug, PartialEq)]
pub struct PeerVerdict {
    pub method: String,
    pub best_speedup: Option<f64>,
    pub best_speedup_range: Option<[f64; 2]>,
    /// `"faster"`, `"slower"`, `"no clear difference"`; null when every run lies outside the
    /// peer's range.
    pub difference: Option<&'static str>,
    pub sentence: String,
}

/// The record's form of a verdict against the peer (`results.json`).
impl From<PeerVerdict> for super::results::PeerVerdict {
    fn from(v: PeerVerdict) -> super::results::PeerVerdict {
        super::results::PeerVerdict {
            method: v.method,
            best_speedup: v.best_speedup,
            best_speedup_range: v.best_speedup_range,
            difference: v.difference,
            summary: v.sentence,
        }
    }
}

/// Reads every run other than the peer's own off the peer's curve, writing
/// `speedup_over_oidn`, its range and `oidn_curve_position` into the runs, and returns each
/// method's verdict against the peer (path tracing's included, first); nothing when the peer
/// did not run.
pub fn verdicts_against_peer(runs: &mut [Run]) -> Vec<PeerVerdict> {
    let Some(curves) = PeerCurves::of(runs) else { return Vec::new() };
    let readings: Vec<Option<PeerReading>> =
        runs.iter().map(|r| (r.method != PEER_METHOD && r.valid).then(|| read(&curves, r)).flatten()).collect();
    for (run, reading) in runs.iter_mut().zip(&readings) {
        if let Some(reading) = reading {
            run.speedup_over_oidn = reading.speedup;
            run.speedup_over_oidn_range = reading.speedup_range;
            run.oidn_curve_position = Some(reading.position.name());
        }
    }
    let mut names: Vec<&str> = Vec::new();
    for run in runs.iter().filter(|r| r.method != PEER_METHOD) {
        if !names.contains(&run.method.as_str()) {
            names.push(&run.method);
        }
    }
    names.sort_by_key(|name| *name != "pt");
    names
        .into_iter()
        .map(|method| {
            let mine: Vec<(&Run, PeerReading)> = runs
                .iter()
                .zip(&readings)
                .filter(|(r, _)| r.method == method)
                .filter_map(|(r, x)| x.map(|x| (r, x)))
                .collect();
            summarise(method, &mine, &curves)
        })
        .collect()
}

fn display_name(method: &str) -> &str {
    if method == "pt" {
        "path tracing"
    } else {
        method
    }
}

fn summarise(method: &str, mine: &[(&Run, PeerReading)], curves: &PeerCurves) -> PeerVerdict {
    let best = mine
        .iter()
        .filter(|(_, x)| x.speedup.is_some())
        .max_by(|a, b| a.1.speedup.unwrap_or(0.0).total_cmp(&b.1.speedup.unwrap_or(0.0)));
    let name = display_name(method);
    let (cheapest, best_peer) = (curves.median.first(), curves.median.last());
    // The run of highest PSNR above OIDN's best run, named whatever else is said: a quality OIDN
    // did not reach at the input counts it ran (a larger `--pt-max-spp` would read it).
    let above =
        mine.iter().filter(|(_, x)| x.position == Position::Above).max_by(|a, b| a.0.psnr_db.total_cmp(&b.0.psnr_db));
    let above_text = |run: &Run| {
        format!(
            "{name} reaches {:.2} dB ({} in {:.3} s), above OIDN's range: OIDN's best run here reaches {:.2} dB \
             (a larger --pt-max-spp runs OIDN on more of the ladder)",
            run.psnr_db,
            run_label(run),
            run.total_s,
            best_peer.map_or(f64::NAN, |p| p.psnr_db)
        )
    };
    let sentence = match best {
        Some((run, x)) => {
            let speedup = x.speedup.unwrap_or(0.0);
            let ratio = if speedup >= 1.0 {
                format!("{speedup:.2}× faster")
            } else {
                format!("{:.2}× slower", 1.0 / speedup.max(1e-12))
            };
            let judged = match (Difference::of(speedup, x.speedup_range.map(|[lo, hi]| (lo, hi))), x.speedup_range) {
                (Difference::Unclear, Some([lo, hi])) => {
                    format!("no clear difference ({ratio} by the median times; the repetitions allow {lo:.2}× to {hi:.2}×)")
                }
                (Difference::WithinNoise, _) => format!("no clear difference ({ratio} by the median times)"),
                _ => ratio,
            };
            let within = format!(
                "against OIDN: {name} at its best within OIDN's range ({}) reaches {:.2} dB in {:.3} s; OIDN needs {:.3} s for that: {judged}",
                run_label(run),
                run.psnr_db,
                run.total_s,
                speedup * run.total_s
            );
            match above {
                Some((run, _)) => format!("{within}; {}", above_text(run)),
                None => within,
            }
        }
        None if above.is_some() => format!("against OIDN: {}", above_text(above.unwrap().0)),
        None if !mine.is_empty() => format!(
            "against OIDN: every run of {name} lies below OIDN's range: OIDN's cheapest run reaches {:.2} dB in {:.3} s, \
             more than {name} reaches at any time measured",
            cheapest.map_or(f64::NAN, |p| p.psnr_db),
            cheapest.map_or(f64::NAN, |p| p.seconds)
        ),
        None => format!("against OIDN: {name} has no valid run"),
    };
    PeerVerdict {
        method: method.to_string(),
        best_speedup: best.and_then(|(_, x)| x.speedup),
        best_speedup_range: best.and_then(|(_, x)| x.speedup_range),
        difference: best
            .map(|(_, x)| Difference::of(x.speedup.unwrap_or(0.0), x.speedup_range.map(|[lo, hi]| (lo, hi))).name()),
        sentence,
    }
}

fn run_label(run: &Run) -> String {
    let rays = if run.recon_rays > 0 { format!(" × {} rays", run.recon_rays) } else { String::new() };
    format!("{} spp{rays}", run.input_spp)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(method: &str, spp: u32, total_s: f64, psnr_db: f64) -> Run {
        Run::example(method, spp, total_s, psnr_db)
    }

    /// OIDN: 30 dB in 0.1 s, 34 dB in 1 s. A method at 32 dB in 0.25 s: OIDN's time to 32 dB,
    /// by hand, is halfway in log time between 0.1 and 1 s: 10^(−1 + 0.5) = 0.316 s, so the
    /// speedup is 0.316 / 0.25 = 1.265.
    #[test]
    fn the_speedup_over_oidn_is_read_on_oidns_curve_in_log_time() {
        let mut runs = vec![
            run("pt", 1, 0.05, 20.0),
            run("oidn", 1, 0.1, 30.0),
            run("oidn", 16, 1.0, 34.0),
            run("ilfr+oidn", 4, 0.25, 32.0),
            run("slow", 4, 1.0, 31.0),
            run("great", 4, 0.5, 36.0),
            run("poor", 4, 0.01, 25.0),
            run("slow", 16, 3.0, 35.0),
        ];
        let verdicts = verdicts_against_peer(&mut runs);
        let expected = 10f64.powf(-0.5) / 0.25;
        assert!((runs[3].speedup_over_oidn.unwrap() - expected).abs() < 1e-12, "{:?}", runs[3].speedup_over_oidn);
        assert_eq!(runs[3].oidn_curve_position, Some("within"));
        // 31 dB: a quarter of the way in log time, 10^(−0.75) = 0.178 s against 1 s.
        assert!((runs[4].speedup_over_oidn.unwrap() - 10f64.powf(-0.75)).abs() < 1e-12);
        // Outside OIDN's range: no speedup, the position said.
        assert_eq!((runs[5].speedup_over_oidn, runs[5].oidn_curve_position), (None, Some("above")));
        assert_eq!((runs[6].speedup_over_oidn, runs[6].oidn_curve_position), (None, Some("below")));
        assert_eq!((runs[0].speedup_over_oidn, runs[0].oidn_curve_position), (None, Some("below")));
        assert_eq!(runs[1].oidn_curve_position, None, "OIDN is not read against itself");
        // One verdict per method, path tracing first.
        let methods: Vec<&str> = verdicts.iter().map(|v| v.method.as_str()).collect();
        assert_eq!(methods, ["pt", "ilfr+oidn", "slow", "great", "poor"]);
        assert!(verdicts[1].sentence.contains("1.26× faster"), "{}", verdicts[1].sentence);
        assert!(verdicts[2].sentence.contains("slower"), "{}", verdicts[2].sentence);
        // A method with runs both within and above OIDN's range says both.
        assert!(verdicts[2].sentence.contains("slow reaches 35.00 dB (16 spp in 3.000 s), above OIDN's range"));
        assert!(!verdicts[1].sentence.contains("above"), "{}", verdicts[1].sentence);
        assert!(verdicts[3].sentence.contains("above OIDN's range") && verdicts[3].best_speedup.is_none());
        assert!(verdicts[4].sentence.contains("below OIDN's range"), "{}", verdicts[4].sentence);
        assert!(verdicts[0].sentence.contains("path tracing"), "{}", verdicts[0].sentence);
    }

    #[test]
    fn without_oidn_there_is_no_verdict_against_it() {
        let mut runs = vec![run("pt", 1, 0.05, 20.0), run("ilfr", 4, 0.25, 32.0)];
        assert!(verdicts_against_peer(&mut runs).is_empty());
        assert_eq!(runs[1].speedup_over_oidn, None);
        assert_eq!(runs[1].oidn_curve_position, None);
    }

    #[test]
    fn the_measured_curve_is_never_extended() {
        let curve =
            monotone_curve(&[CurvePoint { seconds: 0.1, psnr_db: 30.0 }, CurvePoint { seconds: 1.0, psnr_db: 34.0 }]);
        assert_eq!(time_on_measured_curve(&curve, 29.99), Some(Position::Below));
        assert_eq!(time_on_measured_curve(&curve, 34.01), Some(Position::Above));
        assert_eq!(time_on_measured_curve(&curve, 30.0), Some(Position::Within(0.1)));
        assert_eq!(time_on_measured_curve(&curve, f64::NAN), None);
        assert_eq!(time_on_measured_curve(&[], 30.0), None);
    }
}
