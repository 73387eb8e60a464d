//! Indirect light field reconstruction (Lehtinen, Aila, Laine, Durand 2012, "Reconstructing the
//! Indirect Light Field for Global Illumination"; the text is in
//! `shared/papers/indirect-light-field-reconstruction-2012.txt`, the design in
//! `docs/ilfr-design.md`, results in `docs/ilfr.md`). Every slice of the design's
//! implementation order has landed.
//!
//! Paper → code:
//! - ✓ Section 2.1, the input tuple {L, o, h, n_o, n_h, κ} from `indirect` / `ao` files read
//!   through `sampleio`, with sample classes and octahedral decoding: `samples`.
//! - ✓ Section 2.2, "Sampling Rate": the k-th nearest neighbour (k = 12) inside the vMF lobe of
//!   Eq. 2 (A_i(ω_j) ≥ 0.5), under the metric that counts offsets along the normal α = 3 times:
//!   `neighbours` (kd-tree and the ordered walk), `splats` (radius, relaxation, fallbacks).
//! - ✓ Section 2.3, the splats as oriented discs (`disc`: ray–disc intersection, exact disc
//!   boxes) in our own BVH (`bvh`: binned SAH, every disc along a ray walked on a 4-wide
//!   collapse of it over compact disc records, refit). Embree's
//!   oriented-disc points, the alternative, are measured against it in
//!   `benches/ilfr_discs.rs` and checked hit for hit in `tests/ilfr_embree_discs.rs`: 1.2–1.5×
//!   faster walks, 20× slower refits; we keep ours (docs/ilfr-design.md, "Slice 7"). Motion
//!   boxes are not built yet (Section 3.4 with moving geometry).
//! - ✓ Section 2.3.1, consistent visibility, shrinking splats that block input rays, with a
//!   deterministic parallel minimum and a refit: `shrink`.
//! - ✓ Section 2.3.2 and Figure 5, apparent surfaces by the event-line conflict test (and the
//!   authors' facing/coplanar test); Section 2.5, back-facing splats and one- to three-sample
//!   surfaces: `surfaces`.
//! - ✓ Section 2.4 and Figure 6, the diffuse tent average and the glossy anisotropic nearest
//!   neighbour (largest transformed filter value); Section 3.3, the AO distance threshold:
//!   `filter`. RECONSTRUCT(p, ω) — all-hits walk, grouping, filter, no-support fallback (sky
//!   samples for radiance, visible for AO): `reconstruct`.
//! - ✓ Eq. 1 and Eq. 3, the final gather at Lambertian primary hits (cosine-distributed,
//!   Owen-scrambled Sobol' directions, albedo-weighted, normalised by the supported rays) and
//!   ambient occlusion (Section 3.3): `gather`; at glossy primary hits, directions and weights
//!   f·cos/p from o's own BSDF (read from the file, the tracer's `shading::Bsdf`), split between
//!   the lobes with multi-sample MIS: `bsdf_rays`.
//! - Beyond the paper: splats far brighter than their neighbours in the lobe keep a
//!   bounded radiance and share the excess with them, power kept (`robust`); for indirect light
//!   and glossy reflections a blocked input ray trims only the 45° wedges of a splat towards
//!   it, as far as a straight edge through the crossing needs, so that trimmed rim splats leave
//!   no holes (`shrink::Trim::Wedges`, `disc::half_plane_wedge_radii`, `bvh`); the final gather's
//!   directions of a pixel's primary hits (cosine rays, and each BSDF lobe's at glossy hits)
//!   are consecutive blocks of one scrambled Sobol' sequence per pixel (`gather`,
//!   `directions`, `bsdf_rays`); ambient occlusion skips §2.5's small-surface
//!   rule by default, which on Sponza turned more real occluders visible than it spared
//!   spurious ones (`surfaces::SurfaceParams::merge_small_surfaces`, `choices`); on request
//!   (`ilfr:grain=filter`), an edge-aware filter of the final gather's per-pixel grain in
//!   diffuse indirect light (`grain`).
//! - Beyond the paper, a cheaper final gather (`ilfr:variant=nearest-splat`, `ilfr:variant=records`;
//!   `ilfr:variant=paper` is the paper's; `variant=auto` picks per effect, `choices::variant_for`):
//!   each splat's radiance filtered once over its jury
//!   (`prefilter`), and a reconstruction ray reads the nearest splat it meets within 0.7 of its
//!   radius, else the nearest at all (`reconstruct::RayModel::NearestSplat`, by the ordered walk
//!   `bvh::DiscBvh::nearest_hit`, whose oracle is the all-hits walk); and the final gather at a
//!   subset of the Lambertian primary hits, interpolated to the others where the records' error
//!   estimate allows and gathered in full where not (irradiance caching: `cache`). The sizing's
//!   walk also finds each splat's jury, so that the robust radiance walks the kd-tree only for
//!   its outliers (`splats::size_splats_with_juries`, the same radiance bit for bit).
//! - Beyond the paper, the final gather of Eq. 3 at a sparse grid of pixels (`ilfr:gather=sparse`,
//!   with `stride` and `grid_rays`), the mean radiance of the other pixels' Lambertian hits
//!   interpolated from the grid with geometry-aware weights and multiplied by their own albedo,
//!   and a full gather where the interpolation's error estimate (too little similar geometry
//!   among the corners, or corners that disagree beyond their noise) says so: `sparse`.
//! - ✓ Section 4, recursive filtering: at every secondary hit 16 rays reconstruct the incident
//!   light, and the sample's radiance becomes `secondary_direct` + the reflected mean before the
//!   final gather (cosine rays × `secondary_albedo` in diffuse files; h's own BSDF through
//!   `bsdf_rays` in glossy files): `recursive`, switched on by the method name `ilfr-recursive`.
//! - ✓ Section 3.4, motion and defocus from primary rays: the camera rays of a `lens-time` file
//!   as input rays (hit normals from the depth gradient; moving splats from its `motion`, the
//!   hierarchy's boxes swept over the shutter, `disc::Disc::centre_at`), reconstruction rays
//!   through pixel, lens and shutter: `lens`.
//! - ✓ The `Method`s `ilfr` (effects `indirect`, `glossy`, `ao`), `ilfr-recursive` (`indirect`,
//!   `glossy`, with Section 4) and `ilfr-dof` (`dof`, `motion`, `dof-motion`; Section 3.4) for
//!   `lfr compare`, one type described by data (`method::IlfrMethod`); the choices the paper
//!   leaves open and their defaults per effect (`choices`); the pipeline they share, read,
//!   sizing, hierarchy, shrinking, recursive passes and gather, with the time split and counts in
//!   their notes (`pipeline::reconstruct_samples`, `pipeline::run_ilfr`, `pipeline::run_lens`).

pub mod bsdf_rays;
pub mod bvh;
pub mod cache;
pub mod choices;
pub mod directions;
pub mod disc;
pub mod filter;
pub mod gather;
pub mod grain;
pub mod lens;
pub mod method;
pub mod neighbours;
pub mod pipeline;
pub mod prefilter;
pub mod ray_order;
pub mod reconstruct;
pub mod recursive;
pub mod robust;
pub mod samples;
pub mod shrink;
pub mod sparse;
pub mod splats;
pub mod surfaces;

/// The most items (splats, input rays, discs) one rayon job of a per-item parallel loop takes.
/// Rayon's adaptive splitting cuts a loop into a few pieces per thread and splits a piece again
/// only when it is stolen before it starts; a piece under way cannot be shared, so a thread
/// that runs out of work idles while the other finishes its last large piece. Pieces of at most
/// this many items keep that idle tail short (a few hundred microseconds), at a cost per job
/// that is small beside 1024 k-NN walks or ray walks.
pub(crate) const PARALLEL_ITEMS: usize = 1024;
