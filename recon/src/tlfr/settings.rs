//! How a temporal light field reconstruction runs: the locations per pixel (N of Eq. 1), an
//! optional refocus, the seed of the locations and the bandwidth extension's scale; shared by
//! the depth-of-field and motion driver (`method`) and the soft-shadow driver (`shadows`).

use super::global_illumination::GiMode;
use super::integrate::AdaptiveRule;

/// Random reprojections for measuring R.
pub const RADIUS_TRIALS: u32 = 32;

/// σ_view of the bandwidth extension in units of the reflected lobe's deviation 8/κ
/// (`bandwidth`); measured in its test and in `docs/tlfr.md`.
pub const DEFAULT_BANDWIDTH_SCALE: f32 = 0.5;

/// The default `AdaptiveRule`: 16 first locations, values within 5 %. Measured on
/// monkeys-defocus-motion (direct light, 128×72, 4 and 16 spp, 32 and 128 locations, dof-motion;
/// docs/history/tlfr.md, "Adaptive locations"): 8 first locations keep the PSNR within 0.02 dB
/// at 16-51 locations per pixel instead of 32-128, 4 lose 0.8-3.7 dB (a surface that crosses
/// the pixel in a small part of the shutter or lens is missed by all of them); 16 keep a
/// margin, within 0.02 dB at 21-57.
/// Spreads from 0.05 to 0.2 stop about as many pixels: the one-surface test decides.
pub const DEFAULT_ADAPTIVE: AdaptiveRule = AdaptiveRule { first: 16, spread: 0.05 };

/// Which code evaluates a location of the plain reconstruction (`tlfr`); the bandwidth
/// extension (`tlfr-bw`) and `tlfr-nn` always run through `query`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Kernel {
    /// One pass per sample over structure-of-arrays entries, in SIMD (`fused`).
    #[default]
    Fused,
    /// The per-location code with separate loops (`query`): the fused kernel's oracle.
    Oracle,
}

/// How `reconstruct_file` runs.
#[derive(Clone, Debug)]
pub struct TlfrSettings {
    /// Reconstruction locations per pixel (N of Eq. 1).
    pub locations: u32,
    /// Refocus after the fact: (focus distance, lens radius), scene units.
    pub refocus: Option<(f32, f32)>,
    /// Seed of the locations.
    pub seed: u32,
    /// The bandwidth extension (Figure 14) with σ_view = `scale` · 8/κ, or off.
    pub bandwidth_scale: Option<f32>,
    /// Fewer locations where a pixel's first ones agree (`integrate::AdaptiveRule`), or N
    /// everywhere. Soft shadows always take N.
    pub adaptive: Option<AdaptiveRule>,
    /// The whole radiance through the reconstruction, or only its `direct` part with the rest
    /// filtered per pixel (`global_illumination`).
    pub gi: GiMode,
    /// The fused kernel or its oracle.
    pub kernel: Kernel,
}

impl Default for TlfrSettings {
    fn default() -> Self {
        TlfrSettings {
            locations: 128,
            refocus: None,
            seed: 0,
            bandwidth_scale: None,
            adaptive: Some(DEFAULT_ADAPTIVE),
            gi: GiMode::Whole,
            kernel: Kernel::Fused,
        }
    }
}
