//! Reconstructions and baselines. Every method reads its input through `sampleio` and never
//! reaches into the tracer. The methods arrive with their issues (guided filter, temporal light
//! field, indirect light field); this crate is the place they live.

pub use sampleio;
