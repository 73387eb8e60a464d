//! The tracer's integration tests, one binary (one link) with a module per file; `common` is
//! `testkit::scenes`, the scenes and helpers the root crate's tests share. `progress.rs` stays a binary of its own: the progress stage it
//! watches is process-wide, so no other test may trace beside it.

use testkit::scenes as common;

mod analytic;
mod light_sampling;
mod nonfinite;
mod ply;
mod regression;
mod samples_lens_time;
mod samples_light;
mod samples_secondary;
mod samples_selection;
mod samples_stiff;
mod scale;
mod surfaces;
mod wavefront;
