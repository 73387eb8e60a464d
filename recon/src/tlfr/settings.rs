//! How a temporal light field reconstruction runs: the locations per pixel (N of Eq. 1), an
//! optional refocus, the seed of the locations and the bandwidth extension's scale; shared by
//! the depth-of-field and motion driver (`method`) and the soft-shadow driver (`shadows`).

/// Random reprojections for measuring R.
pub const RADIUS_TRIALS: u32 = 32;

/// σ_view of the bandwidth extension in units of the reflected lobe's deviation 8/κ
/// (`bandwidth`); measured in its test and in `docs/tlfr.md`.
pub const DEFAULT_BANDWIDTH_SCALE: f32 = 0.5;

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
}

impl Default for TlfrSettings {
    fn default() -> Self {
        TlfrSettings { locations: 128, refocus: None, seed: 0, bandwidth_scale: None }
    }
}
