//! How far the running long step is, for the caller's progress bar.
//!
//! A long loop (the tracer's tiles and sample pieces, ILFR's gather, TLFR's integration over
//! locations, the reconstructions' preprocessing) calls [`begin`] with the stage, its count of
//! work units and their name, and [`advance`] once per finished unit; a command polls
//! [`snapshot`] from another thread and draws it (`lfr compare`'s bar, `lfr reconstruct`'s).
//! Process-wide, not passed through the signatures: one long step runs at a time in a command,
//! progress never changes a result, and the hot loops pay one relaxed atomic add per unit.
//! Concurrent steps (the tests) only mix their displayed counts. It lives here, below the
//! tracer and the reconstructions, so that both report to the same bar.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

static STAGE: Mutex<Option<Stage>> = Mutex::new(None);
static DONE: AtomicU64 = AtomicU64::new(0);

#[derive(Clone, Debug)]
struct Stage {
    name: &'static str,
    unit: &'static str,
    total: u64,
    started: Instant,
}

/// A stage of the running step: its name, units (`unit`: "rows", "tiles", ...) done of its
/// total, seconds since it began.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    pub stage: &'static str,
    pub unit: &'static str,
    pub done: u64,
    pub total: u64,
    pub elapsed_s: f64,
}

impl Snapshot {
    /// Seconds left at the rate so far; `None` before the first row.
    pub fn eta_s(&self) -> Option<f64> {
        (self.done > 0).then(|| self.elapsed_s * (self.total.saturating_sub(self.done)) as f64 / self.done as f64)
    }
}

/// Starts stage `name` of `total` units called `unit` (replaces the previous stage).
pub fn begin(name: &'static str, total: u64, unit: &'static str) {
    let mut stage = STAGE.lock().unwrap_or_else(|e| e.into_inner());
    DONE.store(0, Ordering::Relaxed);
    *stage = Some(Stage { name, unit, total, started: Instant::now() });
}

/// `units` more units of the current stage are done.
#[inline]
pub fn advance(units: u64) {
    DONE.fetch_add(units, Ordering::Relaxed);
}

/// The current stage, if one has begun since the last [`end`].
pub fn snapshot() -> Option<Snapshot> {
    let stage = STAGE.lock().unwrap_or_else(|e| e.into_inner()).clone()?;
    Some(Snapshot {
        stage: stage.name,
        unit: stage.unit,
        done: DONE.load(Ordering::Relaxed).min(stage.total),
        total: stage.total,
        elapsed_s: stage.started.elapsed().as_secs_f64(),
    })
}

/// No stage runs any more.
pub fn end() {
    *STAGE.lock().unwrap_or_else(|e| e.into_inner()) = None;
}

/// "gather 37/96 rows, 12 s left" for a bar's message; empty when no stage runs.
pub fn describe() -> String {
    match snapshot() {
        None => String::new(),
        Some(s) => match s.eta_s() {
            Some(eta) => format!("{} {}/{} {}, {:.0} s left", s.stage, s.done, s.total, s.unit, eta.ceil()),
            None => format!("{} {}/{} {}", s.stage, s.done, s.total, s.unit),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_counts_its_rows_and_estimates_the_rest() {
        begin("gather", 8, "rows");
        advance(2);
        advance(0);
        let s = snapshot().expect("a stage runs");
        assert_eq!((s.stage, s.done, s.total), ("gather", 2, 8));
        // Three times as many rows left as done: three times the time so far.
        let eta = s.eta_s().unwrap();
        assert!((eta - 3.0 * s.elapsed_s).abs() <= 1e-9 * (1.0 + eta), "{eta} vs {}", s.elapsed_s);
        advance(100);
        assert_eq!(snapshot().unwrap().done, 8, "never past the total");
        assert!(describe().starts_with("gather 8/8 rows"));
        end();
        assert_eq!(snapshot(), None);
        assert_eq!(describe(), "");
        assert_eq!(Snapshot { stage: "x", unit: "rows", done: 0, total: 5, elapsed_s: 1.0 }.eta_s(), None);
    }
}
