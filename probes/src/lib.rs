//! Sparse radiance probes: Silvennoinen & Lehtinen 2017, "Real-time Global Illumination by
//! Precomputed Local Reconstruction from Sparse Radiance Probes" (ACM TOG 36(6) 230; text in
//! `shared/papers/sparse-radiance-probes-2017.txt`, design in `docs/probes-design.md`).
//! Issue 25, landed in phases.
//!
//! Paper → code:
//! - ✓ Eq. 3, probe radiance as real SH of order 7, and the clamped-cosine measurement of
//!   Eq. 7 in the SH domain: `sh`.
//! - ✓ Eq. 10, the spatial weight w: `kernel`.
//! - ✓ Section 5 ("receivers … the sample points of a light map's texels; any other set of
//!   receivers can be used just as well"): world-space surface elements that are receivers and
//!   senders, `surfels`; a shading point's weighted surfels, `lookup`.
//! - ✗ Section 4.1, probe placement and radius (phase 3).
//! - ✗ Eq. 2, 4–7, the visibility-aware local transport per receiver (phase 4).
//! - ✗ Eq. 11, CPCA compression (phase 5); Section 4.2, relight rays, cluster projection,
//!   receiver irradiance and bounces (phase 4).

#![forbid(unsafe_code)]
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod error;
pub mod geometry;
pub mod kernel;
pub mod lookup;
pub mod sh;
pub mod surfels;
#[cfg(test)]
mod test_scenes;

pub use error::ProbesError;
