//! The peak memory of a precompute and of a relit frame, estimated from the settings alone
//! (an estimated memory above the machine's is refused before any long
//! work). The CLI compares [`MemoryEstimate::total`] with `tracer::memory::available_bytes`
//! after the scene is read (so the scene's meshes and textures are already out of the measured
//! available memory) and before the precompute, the cache read or a frame.
//!
//! Every term is an upper estimate of a structure the code holds at the precompute's or the
//! frame's peak, from counts known up front:
//! - receivers: the budget × [`RECEIVER_OVERSHOOT`] (the surfel count is close to the budget,
//!   not equal: Sponza 100k → 129,490, 40k → 55,244);
//! - the dense transport (`transport::Transport`): per receiver N_overlap probes (the support
//!   radius is chosen for that mean) × (coefficients × 4 B + a 4 B probe index) plus the
//!   vectors' headers, and with the near field (`near_field`) one 8 B entry per direction;
//! - the surfels and the area samples they are clustered from;
//! - the voxel grid: [`VOXELS_PER_PROBE`] voxels a probe (the probe spacing's grid has about
//!   one point per probe, `VOXELS_PER_SPACING`³ voxels each, padded and rounded up per axis),
//!   at most `voxel::MAX_VOXELS`, × [`BYTES_PER_VOXEL`];
//! - the relight table: the rays' SH, and per probe and ray a sender range and up to
//!   `relight::MAX_SENDERS` (sender, weight) reads, plus the fit's coefficients² per probe;
//! - with CPCA: the compressed transport (at most the dense one) and per worker thread one
//!   cluster's dense matrix in f64 (the cluster limit × the cluster's probes × coefficients;
//!   the probes a cluster of nearby receivers reads are taken as at most
//!   [`CLUSTER_PROBES_PER_OVERLAP`] × N_overlap: a guess, not a bound);
//! - the projected bounce: 12 R² bytes with R at most the limit on projected values;
//! - the image: the tracer's per-pixel render bytes and the kept lookups per primary ray.
//!
//! Calibration (docs/probes.md, "Memory"): against the peak RSS of `lfr probes precompute` on
//! Cornell (29 probes, M = 512, 2 threads; `/usr/bin/time -f %M`) the estimate is 1.5× the
//! measurement at a 1,500 receiver budget (100 MiB measured) and 1.65× at 20,000 (224 MiB); for
//! `relight --cpca` at 20,000 and 128² it is 3–4× (168–224 MiB measured), most of it the projected
//! bounce's bound (192 MiB at R = 4,096 where Cornell's R is 776). It is meant to be above the
//! measurement, as it must be to refuse only what cannot fit, and within a small factor.

use crate::cpca::CpcaSettings;
use crate::precompute::PrecomputeSettings;
use crate::relight::MAX_SENDERS;
use crate::sh;

/// Surfels per receiver of the budget, at most (the measured overshoot is 1.3–1.4).
pub const RECEIVER_OVERSHOOT: f64 = 1.5;
/// Voxels per probe of the placement's grid (8³ per probe spacing, × 4 for the rounding up and
/// the padding of thin axes).
pub const VOXELS_PER_PROBE: u64 = 4 * 512;
/// A voxel's flags (solid, facing, reached) and its share of the flood fill's queue.
pub const BYTES_PER_VOXEL: u64 = 3 + 8;
/// The probes a CPCA cluster reads, in units of the overlap (a guess: a cluster's receivers
/// are neighbours, so they share most of their probes).
pub const CLUSTER_PROBES_PER_OVERLAP: f64 = 4.0;
/// The process without the probes' data: the binary, Embree's BVH of a small scene, the thread
/// stacks, the allocator's slack (measured: a Cornell precompute at a 1,500 receiver budget
/// peaks at 100 MB RSS, of which the probes' structures and the cache's bytes are about 25 MB).
pub const BASE_BYTES: u64 = 96 << 20;
/// Bytes a primary ray's kept lookups take in `image_operator` (its hit and about 8 weighted
/// receivers; measured 8.1 MB at 128² × 4 rays per pixel = 31 B, rounded up).
pub const IMAGE_OPERATOR_BYTES_PER_RAY: u64 = 128;

/// The estimate, by part (bytes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MemoryEstimate {
    pub receivers: u64,
    pub base: u64,
    pub surfels: u64,
    pub transport: u64,
    pub voxels: u64,
    pub relight_table: u64,
    pub transport_scratch: u64,
    pub cache: u64,
    pub cpca: u64,
    pub projected: u64,
    pub image: u64,
}

impl MemoryEstimate {
    /// The precompute's peak (layout, the dense transport, the relight rays), and what a
    /// cache read of it holds.
    pub fn precompute(settings: &PrecomputeSettings, threads: usize) -> MemoryEstimate {
        let receivers = (settings.surfels.budget as f64 * RECEIVER_OVERSHOOT).ceil() as u64;
        let nc = sh::coefficient_count(settings.transport.order) as u64;
        let overlap = settings.placement.overlap;
        let probes = settings.placement.probes as u64;
        // With the near field, its list: at most one (sender, weight) entry per direction (a hit
        // reads up to 4 senders, but neighbouring hits read the same ones), and an offset.
        let near = settings.transport.near.map_or(0, |_| settings.transport.directions as u64 * 8 + 4);
        let per_receiver = (overlap * (nc * 4 + 4) as f64).ceil() as u64 + 64 + near;
        let surfel = std::mem::size_of::<crate::surfels::Surfel>() as u64;
        let samples = (settings.surfels.samples_per_cell.ceil() as u64) * receivers * 32;
        let rays = settings.relight_rays as u64;
        let transport = receivers * per_receiver;
        let relight_table = rays * nc * 4 + probes * rays * (8 + MAX_SENDERS as u64 * 8) + probes * nc * nc * 4;
        MemoryEstimate {
            receivers,
            base: BASE_BYTES,
            surfels: receivers * surfel + samples,
            transport,
            voxels: (probes * VOXELS_PER_PROBE).min(crate::voxel::MAX_VOXELS as u64) * BYTES_PER_VOXEL,
            relight_table,
            transport_scratch: threads.max(1) as u64 * settings.transport.directions as u64 * (nc * 8 + 64),
            cache: 2 * (transport + relight_table + receivers * surfel),
            ..MemoryEstimate::default()
        }
    }

    /// Adds CPCA's compression (its output and the clusters being compressed) and, when
    /// `projected_limit` is given, the largest projected bounce matrix that may be formed.
    pub fn with_cpca(
        mut self,
        settings: &PrecomputeSettings,
        cpca: &CpcaSettings,
        threads: usize,
        projected_limit: Option<usize>,
    ) -> MemoryEstimate {
        let nc = sh::coefficient_count(settings.transport.order) as f64;
        let cluster_probes =
            (CLUSTER_PROBES_PER_OVERLAP * settings.placement.overlap).min(settings.placement.probes as f64);
        let cluster = cpca.cluster_limit as f64 * cluster_probes * nc * 8.0;
        self.cpca = self.transport + (threads.max(1) as f64 * cluster).ceil() as u64;
        if let Some(limit) = projected_limit {
            let r = (limit as u64).min(self.receivers * cpca.max_coefficients as u64);
            self.projected = 12 * r * r;
        }
        self
    }

    /// Adds a `width` × `height` image at `pixel_samples` primary rays per pixel with its kept
    /// lookups.
    pub fn with_image(mut self, width: u32, height: u32, pixel_samples: u32) -> MemoryEstimate {
        let pixels = width as u64 * height as u64;
        self.image =
            tracer::memory::render_bytes(width, height) + pixels * pixel_samples as u64 * IMAGE_OPERATOR_BYTES_PER_RAY;
        self
    }

    pub fn total(&self) -> u64 {
        self.base
            + self.surfels
            + self.transport
            + self.voxels
            + self.relight_table
            + self.transport_scratch
            + self.cache
            + self.cpca
            + self.projected
            + self.image
    }

    /// What is estimated, for the refusal's message.
    pub fn describe(&self, what: &str) -> String {
        let mb = |b: u64| b as f64 / (1u64 << 20) as f64;
        format!(
            "{what} (about {} receivers: dense transport {:.0} MiB, relight table {:.0} MiB, voxels {:.0} MiB, cache \
             bytes {:.0} MiB, CPCA {:.0} MiB, projected bounce {:.0} MiB, image {:.0} MiB)",
            self.receivers,
            mb(self.transport),
            mb(self.relight_table),
            mb(self.voxels),
            mb(self.cache),
            mb(self.cpca),
            mb(self.projected),
            mb(self.image)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::placement::PlacementSettings;
    use crate::surfels::SurfelSettings;
    use crate::transport::TransportSettings;

    fn settings(budget: usize, probes: usize, order: usize) -> PrecomputeSettings {
        PrecomputeSettings {
            surfels: SurfelSettings { budget, ..Default::default() },
            placement: PlacementSettings { probes, ..Default::default() },
            transport: TransportSettings { order, ..Default::default() },
            relight_rays: 8000,
        }
    }

    #[test]
    fn the_transport_term_is_receivers_times_overlap_times_coefficients() {
        // Independent arithmetic: 1.5 × 100k receivers, 10 probes each, 64 f32 + a u32 index,
        // plus 64 B of headers per receiver.
        let e = MemoryEstimate::precompute(&settings(100_000, 160, 7), 2);
        assert_eq!(e.receivers, 150_000);
        assert_eq!(e.transport, 150_000 * (10 * (64 * 4 + 4) + 64));
        // The dense transport must dominate the design's 600 B per receiver target's scale.
        assert!(e.transport / e.receivers > 2000);
    }

    #[test]
    fn the_estimate_grows_with_every_size_setting() {
        let base = MemoryEstimate::precompute(&settings(20_000, 29, 7), 2).total();
        assert!(MemoryEstimate::precompute(&settings(40_000, 29, 7), 2).total() > base);
        assert!(MemoryEstimate::precompute(&settings(20_000, 290, 7), 2).total() > base);
        assert!(MemoryEstimate::precompute(&settings(20_000, 29, 2), 2).total() < base);
        let s = settings(20_000, 29, 7);
        let cpca = MemoryEstimate::precompute(&s, 2).with_cpca(&s, &CpcaSettings::default(), 2, Some(4096));
        assert!(cpca.total() > base);
        assert_eq!(cpca.projected, 12 * 4096 * 4096);
        let image = MemoryEstimate::precompute(&s, 2).with_image(128, 128, 4);
        assert_eq!(image.total() - base, 128 * 128 * (tracer::memory::RENDER_BYTES_PER_PIXEL + 4 * 128));
    }

    #[test]
    fn the_voxels_are_capped_at_the_grids_limit() {
        let e = MemoryEstimate::precompute(&settings(1000, crate::placement::MAX_PROBES, 7), 1);
        assert_eq!(e.voxels, crate::voxel::MAX_VOXELS as u64 * BYTES_PER_VOXEL);
    }
}
