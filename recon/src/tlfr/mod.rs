//! Temporal light field reconstruction (Lehtinen, Aila, Chen, Laine, Durand 2011, "Temporal
//! Light Field Reconstruction for Rendering Distribution Effects"; the text is in
//! `shared/papers/temporal-light-field-reconstruction-2011.txt`, the design in
//! `docs/tlfr-design.md`). The pieces below run end to end as the methods `tlfr`, `tlfr-nn` and
//! `tlfr-bw` (and `lfr reconstruct`).
//!
//! Paper → code:
//! - Eq. 4, `C(z) = C1/z + C2`, and the refocus / aperture change of Section 6: `lens`.
//! - Eq. 2–3, reprojection of a sample to (û, v̂, t̂), guarded where z'(t̂) nears zero or
//!   changes sign (Section 5's "in front of the camera"): `reprojection`.
//! - Eq. 5, SAMESURFACE with δ = sqrt(1/N) and the 0.1-pixel crossing tolerance, extended to
//!   motion, for samples and for nodes through their bounding planes: `same_surface`.
//! - Section 4 "Node bounds", Eq. 6 and Appendix A: planes linear in (t, u) and (t, v) bounding
//!   a sample's or a node's reprojected positions over its time span, and their merging; a
//!   sample nearing the camera plane cut into time segments bounded one by one (not in the
//!   paper): `bounds`.
//! - Section 4 "Construction" and "Query": quadtree leaves of at most 32 samples of one surface,
//!   the BVH built bottom-up over them, the traversal returning the leaves near a location, and
//!   which time segment of a sample takes a query time: `hierarchy`.
//! - Section 3.3, "Determining visibility": valid triangles, coverage, the tent filter:
//!   `coverage`.
//! - Section 3 steps 1–4 and Figure 7, RECONSTRUCT at one location: leaves from `hierarchy`,
//!   grouped into surfaces leaf by leaf through one representative sample each: `query` (the
//!   oracle), and the same as one SIMD pass per sample over structure-of-arrays entries with
//!   the surfaces' coverage and tent sums taken from per-leaf sums: `fused` (what `tlfr` runs,
//!   on the camera and the light side).
//! - Not in the paper: `tlfr-nn`, steps 1–3 with the nearest sample's radiance instead of the
//!   filter: `nearest`.
//! - Eq. 1, N locations per pixel over pixel × lens × time: `integrate` (also for soft
//!   shadows); the methods `tlfr`, `tlfr-nn` and `tlfr-bw`, and the preparation before the
//!   first location that `lfr-bench tlfr` times (`prepare`): `method`, which makes the method's
//!   output from either reconstruction's `reconstruction::Reconstruction`.
//! - Not in the paper: fewer locations in a pixel whose first ones all saw one surface and
//!   agree (`integrate::AdaptiveRule`), and the clock of each location's stages for
//!   `lfr-bench tlfr` (`query::StageClock`).
//! - The synthetic scenes of the tests and the `tlfr` bench: `test_scenes`.
//! - Section 3, the input: `lens-time` files read through `sampleio`: `samples`.
//! - Section 3.3, "Determining R": dispersion of the input pattern under random reprojections:
//!   `dispersion`.
//! - Section 6 "Bandwidth information and view-dependent effects", Figure 14: each sample
//!   weighted by a Gaussian in lens distance matched to its BRDF's bandwidth: `bandwidth`
//!   (method `tlfr-bw`).
//! - Not in the paper: full global illumination with each sample's `direct` part through the
//!   reconstruction and the rest filtered per pixel (`gi=split`):
//!   `global_illumination`.
//! - Section 5 and Appendix B, soft shadows: the light's samples as a second camera
//!   (`light_space`) and the two reconstructions per location (`shadows`).

pub mod bandwidth;
pub mod bounds;
pub mod coverage;
pub mod dispersion;
pub mod fused;
pub mod global_illumination;
pub mod hierarchy;
pub mod integrate;
pub mod lens;
pub mod light_space;
pub mod method;
pub mod nearest;
pub mod query;
pub mod reconstruction;
pub mod reprojection;
pub mod same_surface;
pub mod samples;
pub mod settings;
pub mod shadows;
pub mod test_scenes;
