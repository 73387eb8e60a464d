//! The stages of `lfr compare`, in the order `compare::run` calls them; each hands the next
//! what it made:
//!
//! 1. `plan` — every argument and the scene checked, the methods resolved; nothing traced.
//! 2. `reference` — the image every run is measured against, its tone map and its own error.
//! 3. `inputs` — the path-tracing ladder and the methods' inputs, each trace timed.
//! 4. `execute` — every run (path tracing's are the ladder's traces), measured as it finishes,
//!    and the repetitions of the timings.
//! 5. `score` — HDR-FLIP and the verdicts against path tracing: the comparison's record.
//!
//! `measure` is not a stage: the image measure that `execute` applies to each run as it
//! finishes and `score` gathers.
//! 6. `write` — the plot, the reports and `results.json`.

pub mod execute;
pub mod inputs;
pub mod measure;
pub mod plan;
pub mod reference;
pub mod score;
pub mod write;
