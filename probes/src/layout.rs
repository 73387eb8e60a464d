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
use crate::surfels::{Sides, Surfel, SurfelSettings, Surfels};
use crate::transport::{mostly_back_faces, side_hits, SIDE_TEST_RAYS};
use crate::ProbesError;

/// The steps [`Layout::build`] reports to its progress callback, in order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    Placement,
    Surfels,
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

        progress(Step::Placement);
        let t = Instant::now();
        let mut placement = place(&geometry, &seed_points(scene), placement_settings)?;
        let accel = Accel::build(scene).map_err(|e| ProbesError::Tracer(e.to_string()))?;
        let scale = geometry.scale() as f32;
        let probes_inside = drop_probes_inside(&accel, &mut placement.probes, scale);
        if placement.probes.is_empty() {
            return Err(ProbesError::NoCandidates { voxel: placement.voxel });
        }
        timings.placement_s = t.elapsed().as_secs_f64();

        progress(Step::Surfels);
        let t = Instant::now();
        let surfels = match surfel_settings.sides {
            Sides::All => Surfels::from_geometry(scene, &geometry, surfel_settings)?,
            Sides::Valid | Sides::Seeing => {
                let (grid, seed) = (&placement.grid, surfel_settings.seed);
                // `seeing` also drops the sides none of whose test rays hits anything.
                let drop_sky_only = surfel_settings.sides == Sides::Seeing;
                let hidden = |i: u32, s: &Surfel| {
                    side_hits(&accel, grid, s.position, s.normal, i, seed, SIDE_TEST_RAYS, scale)
                        .map_or(true, |(hits, back)| (drop_sky_only && hits == 0) || mostly_back_faces(hits, back))
                };
                Surfels::from_geometry_valid(scene, &geometry, surfel_settings, &hidden)?
            }
        };
        timings.surfels_s = t.elapsed().as_secs_f64();

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

/// Probe validity: drops the probes that see mostly back faces (inside geometry, where a leaky
/// flood fill put them) and returns how many were dropped; the others keep their order.
fn drop_probes_inside(accel: &Accel, probes: &mut Vec<DVec3>, scale: f32) -> usize {
    let inside = probes_inside(accel, probes, 256, scale);
    let before = probes.len();
    let mut flags = inside.iter();
    probes.retain(|_| !flags.next().copied().unwrap_or(false));
    before - probes.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A probe placed inside a closed box (as a leaky flood fill would) is dropped, counted,
    /// and the others are kept in order; the layout then carries on with them.
    #[test]
    fn probes_inside_geometry_are_dropped_and_counted() {
        use crate::test_scenes::{room, scene_of};
        let boxed = tracer::scene::shapes::axis_aligned_box("box", glam::Vec3::splat(0.2), glam::Vec3::splat(0.5), 0);
        let scene = scene_of(vec![room(glam::Vec3::ZERO, glam::Vec3::ONE), boxed], glam::Vec3::splat(0.8));
        let accel = Accel::build(&scene).unwrap();
        let mut probes = vec![DVec3::splat(0.8), DVec3::splat(0.35), DVec3::new(0.1, 0.9, 0.5), DVec3::splat(0.3)];
        assert_eq!(drop_probes_inside(&accel, &mut probes, 1.0), 2);
        assert_eq!(probes, vec![DVec3::splat(0.8), DVec3::new(0.1, 0.9, 0.5)]);
        assert_eq!(drop_probes_inside(&accel, &mut probes, 1.0), 0, "nothing more to drop");
    }
}
