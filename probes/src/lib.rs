//! Sparse radiance probes: Silvennoinen & Lehtinen 2017, "Real-time Global Illumination by
//! Precomputed Local Reconstruction from Sparse Radiance Probes" (ACM TOG 36(6) 230; text in
//! `shared/papers/sparse-radiance-probes-2017.txt`; reference page `docs/probes.md`).
//!
//! Paper → code:
//! - ✓ Eq. 3, probe radiance as real SH of order 7, and the clamped-cosine measurement of
//!   Eq. 7 in the SH domain: `sh`.
//! - ✓ Eq. 10, the spatial weight w: `kernel`.
//! - ✓ Section 5 ("receivers … the sample points of a light map's texels; any other set of
//!   receivers can be used just as well"): world-space surface elements that are receivers and
//!   senders, `surfels`; a shading point's weighted surfels, `lookup`.
//! - ✓ Section 4.1, "Probe Locations and Radii": voxelisation and flood fill, `voxel`;
//!   candidates next to surfaces, kernel-density removal to the target count and the one support
//!   radius for a mean overlap of N_overlap, `placement`; coverage statistics, `placement`; all
//!   of it in one call with timings, `layout`.
//! - ✓ Eq. 2's visibility V_i by exact rays, and a survey of the directions no covering probe
//!   sees: `visibility`.
//! - ✓ Eq. 2 and 4–7, the visibility-aware local transport and the irradiance transport vector
//!   α_x per receiver, and Eq. 1's spatial-only baseline: `transport` (phase 4, dense).
//! - Not in the paper: the near field, the hits nearer than a share of the support radius left
//!   out of α_x and gathered from their senders directly each bounce: `near_field`.
//! - ✓ Section 4.2, "Probe Transport": relight rays and the per-frame probe SH λ: `relight`;
//!   our extension, the SH fitted to the rays that hit a surface instead of projected with the
//!   escaped ones read as zero (the paper's projection darkens every probe that sees the sky):
//!   `relight::RelightTable::fit` (docs/probes.md, "Choices beyond the paper").
//! - ✓ Section 4.2, receiver irradiance (dense, Eq. 7 per receiver) and the feedback loop of
//!   bounces: `frame`.
//! - ✓ Section 4.2, "Scene relight": direct irradiance at the senders through the tracer's light
//!   model: `direct`.
//! - ✓ Eq. 11, CPCA compression and the per-frame cluster projection (f32 or fp16): `cpca`;
//!   our extension, the bounces after the first run in the clusters' projected space (one
//!   R × R product each, R = Σ ranks): `projected_bounce`.
//! - ✓ The image from the receivers at the camera's hits: `image` (traced and looked up per
//!   frame, the oracle) and `image_operator` (the lookups kept per camera: one weighted sum
//!   per pixel a frame); the whole precompute as one
//!   value, `precompute`, and its cache keyed by geometry and settings, `cache`.
//! - — Brute-force surfel radiosity, the oracle of the probes' reconstruction (same receivers
//!   and senders, no probes): `gather`.
//! - The one set of defaults of every front end: `defaults`; the one relight pipeline of every
//!   front end (cache or build, CPCA cache or compress, the projected bounce, the camera's
//!   lookups, a relit frame, its memory): `pipeline`.
//! - ✓ `lfr compare` method `probes`: declared in the root crate's scene-level method table
//!   (`src/compare/scene_methods.rs`) over `pipeline`.

pub mod cache;
pub mod cpca;
pub mod defaults;
pub mod direct;
pub mod error;
pub mod frame;
pub mod gather;
pub mod geometry;
pub mod image;
pub mod image_operator;
pub mod kernel;
pub mod layout;
pub mod lookup;
pub mod memory;
pub mod near_field;
pub mod pipeline;
pub mod placement;
pub mod precompute;
pub mod projected_bounce;
pub mod relight;
pub mod sh;
#[cfg(test)]
mod stiff_cases;
pub mod surfels;
#[cfg(test)]
mod test_scenes;
pub mod transport;
pub mod visibility;
pub mod voxel;

pub use error::ProbesError;
