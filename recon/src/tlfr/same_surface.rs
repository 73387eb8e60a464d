//! Visibility consistency (paper Section 3.2, Eq. 5): two samples may be filtered together
//! around a reconstruction location when their reprojected screen positions do not cross as
//! the lens position and the time vary over the location's neighbourhood. The relative order of
//! samples on one non-overlapping surface never changes under reprojection; a visibility change
//! always shows as a crossing.
//!
//! The neighbourhood is δ = sqrt(1/N) wide in each lens dimension (N reconstruction locations
//! per pixel; "the square root accounts for the fact that the lens domain is 2D") and δ/2 either
//! side in time (the authors' code uses the same half-widths), clipped to the domain
//! u, v ∈ [−1, 1], t ∈ [0, 1]. x' depends on (u, t) only and y' on (v, t) only, so the four
//! corners (û ± δ, v̂ ± δ, t̂ ± δ/2) paired as (u₋ v₋ t₋), (u₋ v₋ t₊), (u₊ v₊ t₋), (u₊ v₊ t₊)
//! give x' at all four (u, t) corners and y' at all four (v, t) corners.
//!
//! A difference whose magnitude is below the crossing tolerance (0.1 pixel, "we allow the
//! trajectories to cross for at most 0.1 pixels") counts as no sign; the test fails when the
//! x (or y) differences take both signs. A sample that cannot be seen at one of the corners
//! (depth below the near limit there, `reprojection::reproject` = `None`) fails the test: its
//! trajectory leaves the domain where it could be compared.
//!
//! Nodes of the hierarchy (paper Section 4: "we group the leaf nodes into apparent surfaces")
//! are compared through their bounding planes (`same_surface_bounds`): Xmin against Xmin, Xmax
//! against Xmax over the (u, t) corners, Ymin against Ymin and Ymax against Ymax over the (v, t)
//! corners — the vertices of their bounding rectangles. The hierarchy's leaves are built so that
//! their samples pass the test over the whole domain with the build tolerance of 2 pixels (the
//! authors' code uses the same value; `same_surface_at` with the domain's corners).

use super::bounds::Bounds;
use super::lens::LensModel;
use super::reprojection::{reproject, LensTime, LensTimeSample, Reprojected};

/// The crossing the paper tolerates, pixels.
pub const CROSSING_TOLERANCE_PX: f32 = 0.1;
/// The crossing tolerated between the samples of one leaf of the hierarchy, over the whole
/// domain, pixels.
pub const BUILD_CROSSING_TOLERANCE_PX: f32 = 2.0;

/// δ = sqrt(1/N) for N reconstruction locations per pixel.
pub fn window_half_width(locations_per_pixel: u32) -> f32 {
    (1.0 / locations_per_pixel.max(1) as f32).sqrt()
}

/// The four (û, v̂, t̂) corners of the neighbourhood of `at`.
pub fn corners(at: LensTime, delta: f32) -> [LensTime; 4] {
    let (u0, u1) = ((at.u - delta).max(-1.0), (at.u + delta).min(1.0));
    let (v0, v1) = ((at.v - delta).max(-1.0), (at.v + delta).min(1.0));
    let (t0, t1) = ((at.t - 0.5 * delta).max(0.0), (at.t + 0.5 * delta).min(1.0));
    [
        LensTime { u: u0, v: v0, t: t0 },
        LensTime { u: u0, v: v0, t: t1 },
        LensTime { u: u1, v: v1, t: t0 },
        LensTime { u: u1, v: v1, t: t1 },
    ]
}

/// −1, 0 or +1: the sign of `difference`, 0 within the tolerance.
#[inline]
fn sign(difference: f32, tolerance: f32) -> i8 {
    if difference.abs() < tolerance {
        0
    } else if difference > 0.0 {
        1
    } else {
        -1
    }
}

/// Whether a set of signed differences never takes both signs.
#[inline]
pub fn consistent(differences: impl IntoIterator<Item = f32>, tolerance: f32) -> bool {
    let (mut positive, mut negative) = (false, false);
    for d in differences {
        match sign(d, tolerance) {
            1 => positive = true,
            -1 => negative = true,
            _ => {}
        }
    }
    !(positive && negative)
}

/// Eq. 5 for two samples around `at` with half-width `delta` and crossing `tolerance` (pixels).
pub fn same_surface(
    a: &LensTimeSample,
    b: &LensTimeSample,
    lens: &LensModel,
    at: LensTime,
    delta: f32,
    tolerance: f32,
    z_near: f32,
) -> bool {
    same_surface_at(a, b, lens, corners(at, delta), tolerance, z_near)
}

/// Eq. 5 for two samples over the (û, v̂, t̂) corners `corners`, paired as `corners` makes them
/// (all four (u, t) and all four (v, t) combinations).
pub fn same_surface_at(
    a: &LensTimeSample,
    b: &LensTimeSample,
    lens: &LensModel,
    corners: [LensTime; 4],
    tolerance: f32,
    z_near: f32,
) -> bool {
    let mut positions: [(Reprojected, Reprojected); 4] = [(ORIGIN, ORIGIN); 4];
    for (slot, corner) in positions.iter_mut().zip(corners) {
        match (reproject(a, lens, corner, z_near), reproject(b, lens, corner, z_near)) {
            (Some(pa), Some(pb)) => *slot = (pa, pb),
            _ => return false,
        }
    }
    consistent(positions.iter().map(|(pa, pb)| pa.x - pb.x), tolerance)
        && consistent(positions.iter().map(|(pa, pb)| pa.y - pb.y), tolerance)
}

const ORIGIN: Reprojected = Reprojected { x: 0.0, y: 0.0, z: 0.0 };

/// Eq. 5 for two nodes through their bounding planes around `at`: each of the four plane pairs
/// (Xmin, Xmax over the (u, t) corners; Ymin, Ymax over the (v, t) corners) must be consistent.
pub fn same_surface_bounds(a: &Bounds, b: &Bounds, at: LensTime, delta: f32, tolerance: f32) -> bool {
    let window = corners(at, delta);
    let x = |pa: &super::bounds::Plane, pb: &super::bounds::Plane| {
        consistent(window.iter().map(|c| pa.at(c.t, c.u) - pb.at(c.t, c.u)), tolerance)
    };
    let y = |pa: &super::bounds::Plane, pb: &super::bounds::Plane| {
        consistent(window.iter().map(|c| pa.at(c.t, c.v) - pb.at(c.t, c.v)), tolerance)
    };
    x(&a.x_min, &b.x_min) && x(&a.x_max, &b.x_max) && y(&a.y_min, &b.y_min) && y(&a.y_max, &b.y_max)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens() -> LensModel {
        // C(z) = −8/z + 2: in focus at 4.
        LensModel { c1: -8.0, c2: 2.0, fx: 80.0, fy: 80.0, cx: 32.0, cy: 24.0 }
    }

    /// A static sample whose lens-centre position is `centre` at depth `z`, seen from (u, v).
    fn static_sample(centre: [f32; 2], z: f32, u: f32, v: f32) -> LensTimeSample {
        let c = lens().coc(z);
        LensTimeSample { x: centre[0] + u * c, y: centre[1] + v * c, u, v, t: 0.5, z, motion: [0.0; 3] }
    }

    #[test]
    fn defocus_crossings_are_found_around_the_lens_position() {
        // Same lens-centre position; C(2) = −2 and C(10) = +1.2, so x'_a − x'_b = −3.2·û: they
        // cross at û = 0.
        let a = static_sample([20.0, 10.0], 2.0, 0.3, 0.1);
        let b = static_sample([20.0, 10.0], 10.0, -0.7, 0.4);
        let delta = window_half_width(128);
        let at = |u: f32| LensTime { u, v: 0.6, t: 0.5 };
        assert!(!same_surface(&a, &b, &lens(), at(0.0), delta, CROSSING_TOLERANCE_PX, 1e-3));
        assert!(same_surface(&a, &b, &lens(), at(0.5), delta, CROSSING_TOLERANCE_PX, 1e-3));
        // Within a window of δ = 1/64 the crossing is at most 0.05 px: tolerated.
        let small = window_half_width(4096);
        assert!(same_surface(&a, &b, &lens(), at(0.0), small, CROSSING_TOLERANCE_PX, 1e-3));
        // The y differences cross at v̂ = 0 in the same way.
        let at_v = LensTime { u: 0.6, v: 0.0, t: 0.5 };
        assert!(!same_surface(&a, &b, &lens(), at_v, delta, CROSSING_TOLERANCE_PX, 1e-3));
    }

    #[test]
    fn motion_crossings_are_found_around_the_time() {
        // Pinhole; a at x = 10 + 20 t (depth 1, moving right), b still at x = 15: they cross at
        // t = 0.25.
        let pinhole = LensModel { c1: 0.0, c2: 0.0, ..lens() };
        let a = LensTimeSample { x: 10.0, y: 5.0, u: 0.0, v: 0.0, t: 0.0, z: 1.0, motion: [20.0 / 80.0, 0.0, 0.0] };
        let b = LensTimeSample { x: 15.0, y: 5.0, u: 0.0, v: 0.0, t: 0.9, z: 1.0, motion: [0.0; 3] };
        let delta = window_half_width(128);
        let at = |t: f32| LensTime { u: 0.0, v: 0.0, t };
        assert!(!same_surface(&a, &b, &pinhole, at(0.25), delta, CROSSING_TOLERANCE_PX, 1e-3));
        assert!(same_surface(&a, &b, &pinhole, at(0.8), delta, CROSSING_TOLERANCE_PX, 1e-3));
        assert!(same_surface(&a, &b, &pinhole, at(0.1), delta, CROSSING_TOLERANCE_PX, 1e-3));
        // Samples of one plane moving together never cross.
        let c = LensTimeSample { x: 12.0, y: 9.0, t: 0.6, ..a };
        for t in [0.0f32, 0.3, 0.7, 1.0] {
            assert!(same_surface(&a, &c, &pinhole, at(t), delta, CROSSING_TOLERANCE_PX, 1e-3));
        }
    }

    #[test]
    fn a_sample_leaving_through_the_camera_plane_is_not_the_same_surface() {
        let a = LensTimeSample { x: 20.0, y: 20.0, u: 0.0, v: 0.0, t: 0.0, z: 1.0, motion: [0.0, 0.0, -2.0] };
        let b = LensTimeSample { x: 30.0, y: 20.0, u: 0.0, v: 0.0, t: 0.0, z: 1.0, motion: [0.0, 0.0, -2.0] };
        let delta = window_half_width(128);
        let at = |t: f32| LensTime { u: 0.0, v: 0.0, t };
        assert!(same_surface(&a, &b, &lens(), at(0.2), delta, CROSSING_TOLERANCE_PX, 1e-3));
        assert!(!same_surface(&a, &b, &lens(), at(0.5), delta, CROSSING_TOLERANCE_PX, 1e-3));
    }

    #[test]
    fn nodes_are_compared_through_their_planes() {
        use crate::tlfr::bounds::Plane;
        // Node a: x in [10 + 20t, 12 + 20t] (moving right); node b: x in [15, 17] still; both
        // at y in [0, 1]: their planes cross around t = 0.25.
        let band = |time: f32, lo: f32, hi: f32| {
            (Plane { time, lens: 0.0, constant: lo }, Plane { time, lens: 0.0, constant: hi })
        };
        let node = |(x_min, x_max): (Plane, Plane)| {
            let (y_min, y_max) = band(0.0, 0.0, 1.0);
            Bounds { x_min, x_max, y_min, y_max, span: [0.0, 1.0] }
        };
        let (a, b) = (node(band(20.0, 10.0, 12.0)), node(band(0.0, 15.0, 17.0)));
        let delta = window_half_width(128);
        let at = |t: f32| LensTime { u: 0.0, v: 0.0, t };
        assert!(!same_surface_bounds(&a, &b, at(0.25), delta, CROSSING_TOLERANCE_PX));
        assert!(same_surface_bounds(&a, &b, at(0.8), delta, CROSSING_TOLERANCE_PX));
        assert!(same_surface_bounds(&a, &b, at(0.05), delta, CROSSING_TOLERANCE_PX));
        // Lens: slopes +5 and −3 in u at equal constants cross at û = 0 (Xmax against Xmax too).
        let lens_band =
            |lens: f32| (Plane { time: 0.0, lens, constant: 20.0 }, Plane { time: 0.0, lens, constant: 21.0 });
        let (c, d) = (node(lens_band(5.0)), node(lens_band(-3.0)));
        let at_u = |u: f32| LensTime { u, v: 0.0, t: 0.5 };
        assert!(!same_surface_bounds(&c, &d, at_u(0.0), delta, CROSSING_TOLERANCE_PX));
        assert!(same_surface_bounds(&c, &d, at_u(0.5), delta, CROSSING_TOLERANCE_PX));
        // A crossing of 8·δ ≈ 0.7 px is tolerated with the build tolerance of 2 px.
        assert!(same_surface_bounds(&c, &d, at_u(0.0), delta, BUILD_CROSSING_TOLERANCE_PX));
        assert!(same_surface_bounds(&a, &a, at(0.25), delta, CROSSING_TOLERANCE_PX));
    }

    #[test]
    fn corners_stay_inside_the_domain() {
        for corner in corners(LensTime { u: 0.99, v: -0.99, t: 0.999 }, 0.2) {
            assert!((-1.0..=1.0).contains(&corner.u) && (-1.0..=1.0).contains(&corner.v));
            assert!((0.0..=1.0).contains(&corner.t));
        }
        assert_eq!(window_half_width(0), 1.0);
        assert!(consistent([0.05, -0.05, 3.0], 0.1) && !consistent([0.2, -0.2], 0.1));
    }
}
