//! Apparent surfaces along a reconstruction ray, paper Section 2.3.2, Figure 5 and Section 2.5
//! (design: docs/ilfr-design.md §2 "Apparent surfaces", "Back-facing splats", "Small surfaces";
//! §3 #11, #12, #15, #16).
//!
//! Paper → code:
//! - "the samples are sorted according to distance from the ray origin": [`prepare_candidates`]
//!   — the splats the ray hits ([`super::bvh::DiscBvh::collect_hits`]), sorted by the depth of
//!   their centres z_i = d·(h_i − p), ties by index.
//! - "grouped into apparent surfaces … adding the next sample to the open surface as long as it
//!   does not conflict with any of the samples already in the surface": [`group_end`].
//! - "Visibility conflicts are detected by computing the intersection of the st plane and the
//!   event line formed by connecting the two endpoints h_i and h_j. If the intersection point
//!   lies within the positive halfspaces of both samples, a conflict is declared" (Figure 5):
//!   [`conflicts`] with [`ConflictTest::EventLine`]; the authors' code's active test
//!   ("facing / coplanar") as [`ConflictTest::FacingOrCoplanar`]; the default,
//!   [`ConflictTest::EventLineOffPlane`], asks the event line only of pairs whose connecting line
//!   leaves both tangent planes by more than [`COPLANAR_DEGREES`], so that neighbours of one
//!   noisy surface never fragment it while stacked surfaces stay apart (docs/history/ilfr.md, "The conflict test").
//! - §2.5 two-sided splats: "back-facing splats contribute to \[visibility\] similarly to
//!   front-facing splats … contribute to radiance only if all splats of the first surface are
//!   back-facing": the flipped normal n̂ in [`conflicts`] and [`Surface::radiance_from_back_faces`]
//!   / [`Surface::gives_radiance`]; the code's near-field rule (a back-facing splat whose centre is
//!   nearer to the st plane than its radius is dropped) in [`prepare_candidates`], switchable.
//! - §2.5 one- and two-sample surfaces ("we empirically reduce the splat size … for
//!   single-sample surfaces and … for two-sample surfaces"): [`first_surface`] — a surface of fewer
//!   than 4 splats that is not the last is kept only if the ray passes inside the convex hull of
//!   its splats' footprints with radii × 0.5, 0.6, 0.7 (1, 2, 3 splats; the code's constants),
//!   else it is merged into the next ([`inside_footprint_hull`]); switchable
//!   ([`SurfaceParams::merge_small_surfaces`], off for ambient occlusion by default).
//!
//! Footprints are orthographic projections along the ray onto the st plane (ellipses; the code
//! projects centrally onto the uv plane). For one splat this is exact and equals "the ray passes
//! within scale·r of the centre on the tangent plane", whichever projection; for two or three the
//! ellipses are represented by inscribed 32-gons joined with the exact one-splat test, so the hull
//! is at most 0.5 % of a radius smaller than the exact one.

use std::ops::Range;

use super::bvh::{DiscBvh, SplatHit};
use super::disc::{DiscHit, Ray};
use crate::vector::{cross, dot, length, normalize, sub};

/// Which visibility-conflict test groups splats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConflictTest {
    /// The paper's: the event line through both centres meets the st plane inside both positive
    /// half-spaces.
    EventLine,
    /// The authors' code's: same surface if both (flipped) normals point towards the other
    /// centre, or both away (within sin 2°), or either centre is within min(r_a, r_b) of the
    /// other's tangent plane.
    FacingOrCoplanar,
    /// Ours: the paper's event-line test, asked only when the event line leaves both
    /// tangent planes by more than [`COPLANAR_DEGREES`]; a pair closer to coplanar is one
    /// surface. The event line of two neighbours side by side across the ray on one noisy
    /// surface crosses the st plane far away, on a side that normal noise picks, so the plain
    /// test fragments such surfaces; stacked surfaces stay apart at any spacing.
    EventLineOffPlane,
}

/// How far (degrees) the line between two splat centres may leave a splat's tangent plane and
/// still count as lying in it, for [`ConflictTest::EventLineOffPlane`]: the spread of shading
/// normals between neighbouring samples of one surface.
pub const COPLANAR_DEGREES: f32 = 10.0;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceParams {
    pub conflict_test: ConflictTest,
    /// Drop back-facing splats whose centre is nearer to the st plane than their radius.
    pub backface_near_field_cull: bool,
    /// Footprint scale of the small-surface test for surfaces of 1, 2, 3 splats.
    pub small_surface_scale: [f32; 3],
    /// Whether the small-surface rule (§2.5) runs; off, every surface counts whatever its size
    /// (ambient occlusion's default: docs/history/ilfr.md, "ambient occlusion (Deliver 4)").
    pub merge_small_surfaces: bool,
}

impl Default for SurfaceParams {
    fn default() -> Self {
        SurfaceParams {
            conflict_test: ConflictTest::EventLineOffPlane,
            backface_near_field_cull: true,
            small_surface_scale: [0.5, 0.6, 0.7],
            merge_small_surfaces: true,
        }
    }
}

/// A splat the ray hits, with what grouping needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Index of the disc in the input of the hierarchy.
    pub id: u32,
    pub centre: [f32; 3],
    /// Unit, as stored (not flipped).
    pub normal: [f32; 3],
    pub radius: f32,
    pub hit: DiscHit,
}

impl Candidate {
    /// The normal turned to face the ray (n̂ of the design).
    fn facing_normal(&self) -> [f32; 3] {
        if self.hit.back_facing {
            self.normal.map(|c| -c)
        } else {
            self.normal
        }
    }
}

/// Turns the walk's hits (of a ray at `time`) into candidates, moving splats placed where they
/// are at that time: drops near-field back-facing splats when asked (`dropped` counts them),
/// then sorts by (depth, index). `out` is cleared first.
pub fn prepare_candidates(
    bvh: &DiscBvh,
    hits: &[SplatHit],
    time: f32,
    params: &SurfaceParams,
    out: &mut Vec<Candidate>,
) -> usize {
    out.clear();
    let mut dropped = 0;
    for h in hits {
        let (centre, normal) = bvh.placed_at(h.slot, time);
        let radius = h.radius;
        if params.backface_near_field_cull && h.hit.back_facing && h.hit.depth < radius {
            dropped += 1;
            continue;
        }
        out.push(Candidate { id: h.id, centre, normal, radius, hit: h.hit });
    }
    sort_by_depth(out);
    dropped
}

/// Sorts by (depth, index). Ids are unique, so this is a strict total order and any sort gives
/// the same sequence; the few candidates of a ray (about 10) go through an insertion sort, which
/// costs a fraction of the general sort's set-up, longer lists through the general sort.
fn sort_by_depth(candidates: &mut [Candidate]) {
    let before = |a: &Candidate, b: &Candidate| a.hit.depth.total_cmp(&b.hit.depth).then(a.id.cmp(&b.id));
    if candidates.len() > 24 {
        candidates.sort_unstable_by(before);
        return;
    }
    for i in 1..candidates.len() {
        let next = candidates[i];
        let mut j = i;
        while j > 0 && before(&next, &candidates[j - 1]).is_lt() {
            candidates[j] = candidates[j - 1];
            j -= 1;
        }
        candidates[j] = next;
    }
}

/// Whether splats `a` and `b` (both hit by `ray`) belong to different surfaces.
pub fn conflicts(ray: &Ray, a: &Candidate, b: &Candidate, test: ConflictTest) -> bool {
    let e = sub(b.centre, a.centre);
    let (na, nb) = (a.facing_normal(), b.facing_normal());
    match test {
        ConflictTest::EventLine => {
            let along = dot(ray.direction, e);
            let parallel = along.abs() <= 1e-7 * length(e);
            if parallel {
                return false;
            }
            // q = h_a + λe on the st plane: d·(q − p) = z_a + λ(d·e) = 0.
            let lambda = -a.hit.depth / along;
            // n̂_a·(q − h_a) = λ n̂_a·e and n̂_b·(q − h_b) = (λ − 1) n̂_b·e.
            let eta = 1e-3 * a.radius.min(b.radius);
            lambda * dot(na, e) > eta && (lambda - 1.0) * dot(nb, e) > eta
        }
        ConflictTest::EventLineOffPlane => {
            let limit = COPLANAR_DEGREES.to_radians().sin() * length(e);
            let in_a_plane = dot(na, e).abs() <= limit || dot(nb, e).abs() <= limit;
            !in_a_plane && conflicts(ray, a, b, ConflictTest::EventLine)
        }
        ConflictTest::FacingOrCoplanar => {
            let l = length(e);
            let coincident = l <= 0.0;
            if coincident {
                return false;
            }
            let (towards_b, towards_a) = (dot(na, e) / l, -dot(nb, e) / l);
            let slack = (2.0f32).to_radians().sin();
            let both_towards = towards_b + slack >= 0.0 && towards_a + slack >= 0.0;
            let both_away = towards_b - slack <= 0.0 && towards_a - slack <= 0.0;
            let near_plane = dot(a.normal, e).abs() < a.radius.min(b.radius);
            !(both_towards || both_away || near_plane)
        }
    }
}

/// The end of the surface that starts at `start`: the greedy grouping of §2.3.2.
pub fn group_end(ray: &Ray, candidates: &[Candidate], start: usize, test: ConflictTest) -> usize {
    let mut end = start + 1;
    while end < candidates.len() {
        let next = &candidates[end];
        if candidates[start..end].iter().any(|member| conflicts(ray, member, next, test)) {
            break;
        }
        end += 1;
    }
    end.min(candidates.len())
}

/// Vertices per footprint ellipse in the hull test.
const FOOTPRINT_VERTICES: usize = 32;

/// (sin φ_k, cos φ_k) of the footprint vertices' angles φ_k = 2πk / [`FOOTPRINT_VERTICES`],
/// computed once.
fn footprint_directions() -> &'static [(f32, f32); FOOTPRINT_VERTICES] {
    static DIRECTIONS: std::sync::OnceLock<[(f32, f32); FOOTPRINT_VERTICES]> = std::sync::OnceLock::new();
    DIRECTIONS.get_or_init(|| {
        std::array::from_fn(|k| (k as f32 * std::f32::consts::TAU / FOOTPRINT_VERTICES as f32).sin_cos())
    })
}

/// Whether the ray passes inside the convex hull of the footprints of `members` (discs with radii
/// × `scale`, projected along the ray onto the st plane); see the module documentation.
pub fn inside_footprint_hull(ray: &Ray, members: &[Candidate], scale: f32) -> bool {
    footprint_hull_test(ray, members, scale, |points| !in_open_half_plane(points))
}

/// [`inside_footprint_hull`] by the vertices' angles: sorted, the origin is outside iff two
/// consecutive ones lie more than π apart. The first implementation, kept as the oracle of the
/// linear test ([`in_open_half_plane`]); both decide alike but where a gap is within rounding of π.
#[cfg(test)]
fn inside_footprint_hull_by_angles(ray: &Ray, members: &[Candidate], scale: f32) -> bool {
    footprint_hull_test(ray, members, scale, |points| {
        let mut angles: Vec<f32> = points.iter().map(|&(x, y)| y.atan2(x)).collect();
        angles.sort_unstable_by(|a, b| a.total_cmp(b));
        let wrap = angles[0] + std::f32::consts::TAU - angles[angles.len() - 1];
        let largest_gap = angles.windows(2).map(|w| w[1] - w[0]).fold(wrap, f32::max);
        largest_gap <= std::f32::consts::PI
    })
}

/// The footprint vertices of `members` in the plane ⟂ the ray (coordinates relative to the
/// ray), handed to `inside` unless a footprint alone decides: within one footprint (the exact
/// tangent-plane distance), a single splat, or a vertex on the ray.
fn footprint_hull_test(
    ray: &Ray,
    members: &[Candidate],
    scale: f32,
    inside: impl FnOnce(&[(f32, f32)]) -> bool,
) -> bool {
    // Within one footprint: exactly the tangent-plane distance.
    if members.iter().any(|c| c.hit.spatial < scale * c.radius) {
        return true;
    }
    if members.len() < 2 {
        return false;
    }
    let d = ray.direction;
    let (u, v) = perpendicular_frame(d);
    // The small surfaces' (≤ 3 splats) vertices fit on the stack.
    let mut stack_points = [(0.0f32, 0.0f32); 3 * FOOTPRINT_VERTICES];
    let mut heap_points = Vec::new();
    let points: &mut [(f32, f32)] = if members.len() <= 3 {
        &mut stack_points[..members.len() * FOOTPRINT_VERTICES]
    } else {
        heap_points.resize(members.len() * FOOTPRINT_VERTICES, (0.0, 0.0));
        &mut heap_points
    };
    let directions = footprint_directions();
    for (m, c) in members.iter().enumerate() {
        let rho = scale * c.radius;
        // Tangents of the disc: t1 ⟂ n and d (projects at full length), t2 = n × t1.
        let normal_cross_ray = cross(c.normal, d);
        let t1 = if length(normal_cross_ray) > 1e-6 { normalize(normal_cross_ray) } else { u };
        let t2 = cross(c.normal, t1);
        let centre = sub(c.centre, ray.origin);
        for (k, &(sin, cos)) in directions.iter().enumerate() {
            let q = [0, 1, 2].map(|a| centre[a] + rho * (cos * t1[a] + sin * t2[a]));
            let (x, y) = (dot(q, u), dot(q, v));
            if x == 0.0 && y == 0.0 {
                return true;
            }
            points[m * FOOTPRINT_VERTICES + k] = (x, y);
        }
    }
    inside(points)
}

/// Whether every one of `points` (none at the origin) lies in one open half-plane through the
/// origin, i.e. the origin is outside their convex hull: one pass that keeps the narrowest
/// counter-clockwise arc [start, end] (< π) holding the points so far, by the signs of cross
/// products. A point outside it widens it at the end it lies beyond while the arc stays under
/// π; where it cannot (the points then span π or more, a gap of exactly π included), the origin
/// is inside. O(n), without the angles' arctangents and sort.
fn in_open_half_plane(points: &[(f32, f32)]) -> bool {
    let cross = |a: (f32, f32), b: (f32, f32)| a.0 * b.1 - a.1 * b.0;
    let dot = |a: (f32, f32), b: (f32, f32)| a.0 * b.0 + a.1 * b.1;
    let Some(&first) = points.first() else {
        return true;
    };
    let (mut start, mut end) = (first, first);
    for &p in &points[1..] {
        let (from_start, to_end) = (cross(start, p), cross(p, end));
        let degenerate = cross(start, end) == 0.0; // one direction so far
        let within =
            if degenerate { from_start == 0.0 && dot(start, p) > 0.0 } else { from_start >= 0.0 && to_end >= 0.0 };
        if within {
            continue;
        }
        if from_start > 0.0 {
            end = p; // beyond the end, less than π from the start
        } else if to_end > 0.0 {
            start = p; // before the start, less than π from the end
        } else {
            return false;
        }
    }
    true
}

/// The surface a reconstruction uses.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    /// Its splats, a range of the sorted candidates (small surfaces merged into it included).
    pub members: Range<usize>,
    /// No member faces the ray: the back-facing ones give radiance (§2.5).
    pub radiance_from_back_faces: bool,
    /// Surfaces before it that the small-surface rule merged into it.
    pub merged_surfaces: u32,
}

impl Surface {
    /// Whether candidate `c` of this surface gives radiance.
    pub fn gives_radiance(&self, c: &Candidate) -> bool {
        c.hit.back_facing == self.radiance_from_back_faces
    }
}

/// The nearest apparent surface along the ray among the sorted `candidates`
/// ([`prepare_candidates`]), after the small-surface rule; `None` without candidates.
pub fn first_surface(ray: &Ray, candidates: &[Candidate], params: &SurfaceParams) -> Option<Surface> {
    // Surfaces rejected by the small-surface rule are merged into the next, so the chosen surface
    // always starts at the nearest candidate.
    let mut merged_surfaces = 0;
    let mut start = 0;
    while start < candidates.len() {
        let end = group_end(ray, candidates, start, params.conflict_test);
        let size = end;
        let last = end == candidates.len();
        if params.merge_small_surfaces && !last && size <= params.small_surface_scale.len() {
            let scale = params.small_surface_scale[size - 1];
            if !inside_footprint_hull(ray, &candidates[..end], scale) {
                merged_surfaces += 1;
                start = end;
                continue;
            }
        }
        let members = 0..end;
        let radiance_from_back_faces = candidates[members.clone()].iter().all(|c| c.hit.back_facing);
        return Some(Surface { members, radiance_from_back_faces, merged_surfaces });
    }
    None
}

/// Two unit vectors spanning the plane ⟂ the unit `d`.
fn perpendicular_frame(d: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let helper = if d[0].abs() < 0.6 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = normalize(cross(d, helper));
    (u, cross(d, u))
}

#[cfg(test)]
mod tests;
