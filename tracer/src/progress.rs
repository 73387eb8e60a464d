//! Progress of a long traced step: an indicatif bar of its own when the settings ask for one
//! (`lfr render`, `lfr dump`), and always the process-wide stage of `shading::progress`, which a
//! command that draws one bar over many steps (`lfr compare`) shows with the time left.

use indicatif::{ProgressBar, ProgressStyle};

/// One traced step's progress: `total` units called `unit`.
pub struct StepProgress {
    bar: ProgressBar,
}

impl StepProgress {
    /// Starts stage `stage` of `total` units; with `show`, also draws a bar labelled `stage`.
    pub fn begin(show: bool, stage: &'static str, total: u64, unit: &'static str) -> StepProgress {
        shading::progress::begin(stage, total, unit);
        let bar = if show {
            let bar = ProgressBar::new(total);
            bar.set_style(
                ProgressStyle::with_template(&format!(
                    "{stage} [{{elapsed_precise}}] {{wide_bar}} {{pos}}/{{len}} {unit} (eta {{eta}})"
                ))
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            bar
        } else {
            ProgressBar::hidden()
        };
        StepProgress { bar }
    }

    /// `units` more units are done.
    #[inline]
    pub fn advance(&self, units: u64) {
        shading::progress::advance(units);
        self.bar.inc(units);
    }

    /// The step is over: the bar is cleared and the stage ended (as when it is dropped on an
    /// early return).
    pub fn finish(self) {}
}

impl Drop for StepProgress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
        shading::progress::end();
    }
}
