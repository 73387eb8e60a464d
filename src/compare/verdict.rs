//! The two verdicts of a comparison, read off the path-tracing curve (PSNR against wall time):
//!
//! - **equal-time PSNR gain** = method PSNR − PT PSNR at the method's total time;
//! - **equal-quality speedup** = PT time to reach the method's PSNR / method's total time.
//!
//! The PT curve is interpolated piecewise linearly in (log time, PSNR). PSNR is itself
//! logarithmic in the MSE, so this is the log-log interpolation of error against time. Beyond
//! the ladder's ends the curve is extended with the slope path tracing has asymptotically, MSE ∝
//! 1/time, i.e. 10 dB per decade of time, and the result is marked as extrapolated.

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

#[cfg(test)]
mod tests {
    use super::*;

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
}
