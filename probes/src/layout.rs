//! The precompute's first stage in one call: receivers (surfels), probe placement, the support
//! radius and the coverage it gives, with timings and a memory estimate for the stages to come.
//! What `lfr probes stats` reports.

use std::time::Instant;

use glam::DVec3;
use tracer::{Accel, Scene};

use crate::geometry::{seed_points, Geometry};
use crate::placement::{coverage, place, support_radius, Coverage, Placement, PlacementSettings};
use crate::relight::probes_inside;
use crate::sh;
use crate::surfels::{SurfelSettings, Surfels};
use crate::ProbesError;

/// The steps [`Layout::build`] reports to its progress callback, in order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    Surfels,
    Placement,
    Radius,
    Coverage,
}

/// Seconds per step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timings {
    pub surfels_s: f64,
    pub placement_s: f64,
    pub radius_s: f64,
    pub coverage_s: f64,
}

/// Receivers, probes and their radius.
#[derive(Clone, Debug)]
pub struct Layout {
    pub surfels: Surfels,
    pub placement: Placement,
    /// The support radius r of every probe.
    pub radius: f64,
    pub coverage: Coverage,
    /// Probes dropped because their rays saw mostly back faces (inside geometry).
    pub probes_inside: usize,
    /// The scene's largest extent.
    pub scale: f64,
    pub timings: Timings,
}

impl Layout {
    /// Checks every setting first, then builds; `progress` hears each step as it starts.
    pub fn build(
        scene: &Scene,
        surfel_settings: &SurfelSettings,
        placement_settings: &PlacementSettings,
        progress: &mut dyn FnMut(Step),
    ) -> Result<Layout, ProbesError> {
        surfel_settings.validate()?;
        placement_settings.validate()?;
        let geometry = Geometry::from_scene(scene)?;
        let mut timings = Timings::default();

        progress(Step::Surfels);
        let t = Instant::now();
        let surfels = Surfels::from_geometry(scene, &geometry, surfel_settings)?;
        timings.surfels_s = t.elapsed().as_secs_f64();

        progress(Step::Placement);
        let t = Instant::now();
        let mut placement = place(&geometry, &seed_points(scene), placement_settings)?;
        // Probe validity: drop probes that see mostly back faces (a leaky flood fill).
        let accel = Accel::build(scene).map_err(|e| ProbesError::Tracer(e.to_string()))?;
        let inside = probes_inside(&accel, &placement.probes, 256, geometry.scale() as f32);
        let before = placement.probes.len();
        let mut flags = inside.iter();
        placement.probes.retain(|_| !flags.next().copied().unwrap_or(false));
        let probes_inside = before - placement.probes.len();
        if placement.probes.is_empty() {
            return Err(ProbesError::NoCandidates { voxel: placement.voxel });
        }
        timings.placement_s = t.elapsed().as_secs_f64();

        progress(Step::Radius);
        let t = Instant::now();
        let receivers: Vec<DVec3> = surfels.positions();
        let radius = support_radius(&placement.probes, &receivers, placement_settings.overlap)?;
        timings.radius_s = t.elapsed().as_secs_f64();

        progress(Step::Coverage);
        let t = Instant::now();
        let coverage = coverage(&placement.probes, &receivers, radius);
        timings.coverage_s = t.elapsed().as_secs_f64();

        Ok(Layout { surfels, placement, radius, coverage, probes_inside, scale: geometry.scale(), timings })
    }

    /// Bytes of the uncompressed irradiance transport α_x at order 7 in f32: one 64-vector
    /// per covering probe per receiver.
    pub fn dense_transport_bytes(&self) -> f64 {
        self.coverage.mean * self.coverage.receivers as f64 * sh::coefficient_count(sh::MAX_ORDER) as f64 * 4.0
    }

    /// Bytes of the surfels themselves (position, normal, area, mesh, triangle).
    pub fn surfel_bytes(&self) -> f64 {
        (self.surfels.surfels.len() * std::mem::size_of::<crate::surfels::Surfel>()) as f64
    }
}
