//! Shading and sampling numerics shared by the tracer and the reconstructions: the
//! metallic-roughness BSDF (`bsdf.rs`), the shading frame (`frame.rs`), the square-to-disk and
//! hemisphere maps (`warp.rs`), scale-free normals, areas and unit vectors (`scale_free.rs`), and
//! hashing, Owen scrambling, Sobol' and Halton points (`sampling.rs`); and how far the running
//! long step is (`progress.rs`), which the tracer's and the reconstructions' loops report to the
//! same progress bar.
//!
//! The tracer draws secondary rays with it; ILFR's final gather (paper Eq. 3) draws its
//! reconstruction rays from the primary hit's BSDF and weights them with the same code, so the
//! two cannot drift apart (docs/ilfr-design.md, gap G4). `recon` never depends on the tracer;
//! both depend on this crate.

mod bsdf;
mod frame;
pub mod progress;
pub mod sampling;
mod scale_free;
mod warp;

pub use bsdf::*;
pub use frame::Frame;
pub use scale_free::{normalize_any_scale, scaled_cross, triangle_normal_and_area};
pub use warp::{concentric_disk, sample_cosine_hemisphere};

#[cfg(test)]
pub(crate) mod test_points {
    /// Point i of an n-point 3D Hammersley set: (radical inverse base 3, (i + ½)/n, radical
    /// inverse base 2 + ½/n). Deterministic and well stratified, for the quadrature tests; the
    /// half-cell shifts keep points off the square's edges, where the disk map puts them on
    /// the horizon.
    pub fn hammersley(i: u32, n: u32) -> [f32; 3] {
        let shifted = (radical_inverse(i, 2) as f64 + 0.5 / n as f64).min(1.0 - 1e-7);
        [radical_inverse(i, 3), (i as f32 + 0.5) / n as f32, shifted as f32]
    }

    use crate::sampling::radical_inverse;
}
