//! Reconstructions and baselines. Every method reads its input through `sampleio` and never
//! reaches into the tracer.
//!
//! One folder per technique: `tlfr/` (temporal light field reconstruction), `ilfr/` (indirect
//! light field reconstruction), `gif/` (filtered path tracing with the guided image filter),
//! `baselines/` (box average, cross-bilateral, À-Trous, Intel Open Image Denoise) and
//! `metrics/` (PSNR, relative MSE, SSIM, error maps, HDR-FLIP). `method` is the interface the
//! comparison harness runs them through, `progress` how far the running one is, `registry` the one list of the methods with their
//! effects and options (parsed by `options`). `image`, `guide` (the per-pixel guide buffers),
//! `octahedral`, `python`, `vector` (the maths on `[f32; 3]` records) and `lcg` are the
//! shared pieces below them (`lcg` generates test data only).

pub mod auxiliary;
pub mod baselines;
pub mod error;
pub mod gif;
pub mod guide;
pub mod ilfr;
pub mod image;
pub mod lcg;
pub mod method;
pub mod metrics;
pub mod needs;
pub mod octahedral;
pub mod options;
pub mod pipeline;
pub mod python;
pub mod registry;
pub mod tlfr;
pub mod vector;

pub use error::Error;
pub use image::Image;
pub use method::{Effect, Method};
pub use sampleio;
/// How far the running reconstruction is (shared with the tracer: `shading::progress`).
pub use shading::progress;
