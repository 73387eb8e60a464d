//! Repeated timings: one wall-clock measurement on a shared machine is not a fact (rerunning the
//! same comparison once moved path tracing's 256-spp time from 4.16 s to 2.68 s and flipped a
//! verdict). Every timed run of `lfr compare` is therefore repeated, the repetitions of all runs
//! alternating (pass 1 runs everything, pass 2 everything again, …) so that a slow phase of the
//! machine hits every method alike. A run's time is the median repetition; its spread, the range
//! of the repetitions over that median, says how far the verdicts can be trusted.

/// Repetitions of a run whose first measurement took `first_seconds`, at most `max`: all of
/// them for runs under [`SHORT_RUN_S`], two for runs under [`LONG_RUN_S`], one beyond (a long
/// run is less disturbed by short slow phases and costs too much to repeat).
pub fn repetitions(first_seconds: f64, max: u32) -> u32 {
    let max = max.max(1);
    if first_seconds < SHORT_RUN_S {
        max
    } else if first_seconds < LONG_RUN_S {
        max.min(2)
    } else {
        1
    }
}

/// Runs shorter than this are repeated as often as `--repeats` says.
pub const SHORT_RUN_S: f64 = 5.0;
/// Runs longer than this are measured once.
pub const LONG_RUN_S: f64 = 30.0;

/// The index of the median repetition of `totals`: the middle one of an odd count, the faster
/// of the two middle ones of an even count (so that a run's time is always one measured
/// repetition, whose parts add up to it). `None` for no repetitions.
pub fn median_index(totals: &[f64]) -> Option<usize> {
    let mut order: Vec<usize> = (0..totals.len()).collect();
    order.sort_by(|&a, &b| totals[a].total_cmp(&totals[b]).then(a.cmp(&b)));
    order.get(totals.len().saturating_sub(1) / 2).copied()
}

/// (slowest − fastest) / median: 0 for one repetition.
pub fn relative_spread(totals: &[f64]) -> f64 {
    let Some(median) = median_index(totals).map(|i| totals[i]) else {
        return 0.0;
    };
    let (lo, hi) = totals.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| (lo.min(t), hi.max(t)));
    if median > 0.0 && hi >= lo {
        (hi - lo) / median
    } else {
        0.0
    }
}

/// The fastest and the slowest repetition.
pub fn range(totals: &[f64]) -> Option<(f64, f64)> {
    let lo = totals.iter().copied().min_by(f64::total_cmp)?;
    let hi = totals.iter().copied().max_by(f64::total_cmp)?;
    Some((lo, hi))
}

/// How a speedup compares with 1 once the spread of the timings is taken into account.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Difference {
    Faster,
    Slower,
    /// The range of speedups the repetitions allow contains 1.
    Unclear,
    /// The range excludes 1, but the speedup lies within [`BETWEEN_RUNS_NOISE`] of 1.
    WithinNoise,
}

/// How far (relative) the same `lfr compare` command's speedups move between processes on a
/// shared machine, beyond what one process's alternating repetitions can see: measured at 5-15 %
/// (max/min of the same configuration's ratio over four processes, docs/compare.md "Where `box`
/// stands"). A speedup within this distance of 1 is no clear difference whatever the spread.
pub const BETWEEN_RUNS_NOISE: f64 = 0.10;

/// Whether `speedup` lies within [`BETWEEN_RUNS_NOISE`] of 1 (either way).
pub fn within_between_runs_noise(speedup: f64) -> bool {
    speedup <= 1.0 + BETWEEN_RUNS_NOISE && speedup * (1.0 + BETWEEN_RUNS_NOISE) >= 1.0
}

impl Difference {
    /// `range` is the (lowest, highest) speedup the repetitions allow; `speedup` the median's.
    pub fn of(speedup: f64, range: Option<(f64, f64)>) -> Difference {
        match range {
            Some((lo, hi)) if lo <= 1.0 && 1.0 <= hi => Difference::Unclear,
            _ if within_between_runs_noise(speedup) => Difference::WithinNoise,
            _ if speedup >= 1.0 => Difference::Faster,
            _ => Difference::Slower,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Difference::Faster => "faster",
            Difference::Slower => "slower",
            Difference::Unclear | Difference::WithinNoise => "no clear difference",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_runs_are_repeated_most_and_long_ones_once() {
        assert_eq!(repetitions(0.01, 3), 3);
        assert_eq!(repetitions(SHORT_RUN_S + 1.0, 3), 2);
        assert_eq!(repetitions(SHORT_RUN_S + 1.0, 1), 1);
        assert_eq!(repetitions(LONG_RUN_S * 2.0, 5), 1);
        // `--repeats 0` is refused by the CLI; here it still means one measurement.
        assert_eq!(repetitions(0.01, 0), 1);
    }

    #[test]
    fn the_median_is_a_measured_repetition() {
        assert_eq!(median_index(&[]), None);
        assert_eq!(median_index(&[2.0]), Some(0));
        assert_eq!(median_index(&[3.0, 1.0, 2.0]), Some(2));
        // Even counts take the faster middle one.
        assert_eq!(median_index(&[4.0, 1.0, 3.0, 2.0]), Some(3));
        assert_eq!(median_index(&[5.0, 4.0]), Some(1));
        // Ties keep the first.
        assert_eq!(median_index(&[1.0, 1.0, 1.0]), Some(1));
    }

    #[test]
    fn spread_is_the_range_over_the_median() {
        assert_eq!(relative_spread(&[]), 0.0);
        assert_eq!(relative_spread(&[2.0]), 0.0);
        assert!((relative_spread(&[1.0, 2.0, 4.0]) - 1.5).abs() < 1e-12);
        assert_eq!(range(&[3.0, 1.0, 2.0]), Some((1.0, 3.0)));
        assert_eq!(range(&[]), None);
    }

    #[test]
    fn a_speedup_whose_range_holds_one_is_no_clear_difference() {
        assert_eq!(Difference::of(1.23, Some((0.9, 1.5))), Difference::Unclear);
        assert_eq!(Difference::of(1.23, Some((1.1, 1.5))), Difference::Faster);
        assert_eq!(Difference::of(0.5, Some((0.4, 0.6))), Difference::Slower);
        assert_eq!(Difference::of(1.2, None), Difference::Faster);
        assert_eq!(Difference::of(0.8, None), Difference::Slower);
    }

    /// Within 10 % of 1 either way (1.1× faster, 1.1× slower) a speedup is no clear difference
    /// even when tight repetitions exclude 1; just outside it is judged.
    #[test]
    fn a_speedup_within_the_between_runs_noise_is_no_clear_difference() {
        for speedup in [1.0, 1.05, 1.1, 1.0 / 1.1, 0.95] {
            let tight = Difference::of(speedup, Some((speedup * 0.99, speedup * 1.01)));
            assert_eq!(tight.name(), "no clear difference", "{speedup}");
            assert_eq!(tight == Difference::WithinNoise, speedup != 1.0, "{speedup}: only 1 lies in the range");
            assert_eq!(Difference::of(speedup, None), Difference::WithinNoise, "{speedup}");
        }
        assert_eq!(Difference::of(1.11, Some((1.105, 1.12))), Difference::Faster);
        assert_eq!(Difference::of(1.0 / 1.11, Some((0.89, 0.905))), Difference::Slower);
        assert!(!within_between_runs_noise(f64::NAN));
        assert_eq!(Difference::of(f64::NAN, None), Difference::Slower);
    }
}
