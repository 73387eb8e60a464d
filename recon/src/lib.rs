//! Reconstructions and baselines. Every method reads its input through `sampleio` and never
//! reaches into the tracer. `method` holds the trait and registry `lfr compare` runs them
//! through; `metrics` the error measures every comparison reports.

pub mod atrous;
pub mod bilateral;
pub mod box_filter;
pub mod eye_rays;
pub mod filtered_indirect;
pub mod flip;
pub mod guide;
pub mod guided_filter;
pub mod ilfr;
pub mod image;
pub mod lcg;
pub mod method;
pub mod metrics;
pub mod octahedral;
pub mod oidn;
pub mod python;
pub mod tlfr;

pub use image::Image;
pub use method::{Effect, Method};
pub use sampleio;
