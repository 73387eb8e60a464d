//! Sparse radiance probes: Silvennoinen & Lehtinen 2017, "Real-time Global Illumination by
//! Precomputed Local Reconstruction from Sparse Radiance Probes" (ACM TOG 36(6) 230; text in
//! `shared/papers/sparse-radiance-probes-2017.txt`, design in `docs/probes-design.md`).
//! Issue 25, landed in phases.
//!
//! Paper → code:
//! - ✓ Eq. 3, probe radiance as real SH of order 7, and the clamped-cosine measurement of
//!   Eq. 7 in the SH domain: `sh`.
//! - ✓ Eq. 10, the spatial weight w: `kernel`.
//! - ✗ Receivers and senders (surfels), probe placement and radius (phases 2–3).
//! - ✗ Eq. 2, 4–7, the visibility-aware local transport per receiver (phase 4).
//! - ✗ Eq. 11, CPCA compression (phase 5); Section 4.2, relight rays, cluster projection,
//!   receiver irradiance and bounces (phase 4).

#![forbid(unsafe_code)]
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod kernel;
pub mod sh;
