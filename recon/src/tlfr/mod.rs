//! Temporal light field reconstruction (Lehtinen, Aila, Chen, Laine, Durand 2011, "Temporal
//! Light Field Reconstruction for Rendering Distribution Effects"; the text is in
//! `shared/papers/temporal-light-field-reconstruction-2011.txt`, the design in
//! `docs/tlfr-design.md`). Issue 6, in progress: the pieces below are in and run end to end as
//! the method `tlfr`; the paper's hierarchy (Section 4, Appendix A), soft shadows (Section 5),
//! the bandwidth extension (Figure 14) and `lfr reconstruct` are not yet.
//!
//! Paper → code:
//! - Eq. 4, `C(z) = C1/z + C2`, and the refocus / aperture change of Section 6: `lens`.
//! - Eq. 2–3, reprojection of a sample to (û, v̂, t̂), guarded where z'(t̂) nears zero or
//!   changes sign (Section 5's "in front of the camera"): `reprojection`.
//! - Eq. 5, SAMESURFACE with δ = sqrt(1/N) and the 0.1-pixel crossing tolerance, extended to
//!   motion: `same_surface`.
//! - Section 3.3, "Determining visibility": valid triangles, coverage, the tent filter:
//!   `coverage`.
//! - Section 3 steps 1–4, RECONSTRUCT at one location: `query` (candidates from `index`, an
//!   interim uniform grid over conservative per-sample bounds in place of Section 4's BVH).
//! - Eq. 1, N locations per pixel over pixel × lens × time: `integrate`; the method: `method`.
//! - Section 3, the input: `lens-time` files read through `sampleio`: `samples`.
//! - Section 3.3, "Determining R": dispersion of the input pattern under random reprojections:
//!   `dispersion`.

pub mod coverage;
pub mod dispersion;
pub mod index;
pub mod integrate;
pub mod lens;
pub mod light_space;
pub mod method;
pub mod query;
pub mod reprojection;
pub mod same_surface;
pub mod samples;
pub mod shadows;
