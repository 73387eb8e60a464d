//! Section 4.1, "Probe Locations and Radii": candidates in empty voxels next to surfaces, a
//! kernel density estimate with the weight w of Eq. 10 at radius ρ, greedy removal from the
//! densest regions down to the target count, and one support radius r for all probes chosen so
//! that receivers are covered by N_overlap probes on average. Coverage statistics beside it.
//!
//! Decisions (design note, "Probe placement"):
//! - The target is an explicit probe count N; the spacing ρ is the largest for which a regular
//!   grid of spacing ρ over the scene's bounds has at least N points (the paper's rule read
//!   backwards), taken at the middle of its interval so that no extent is an integer multiple
//!   of it; the voxel size is ρ/8.
//! - Candidates are reached empty voxels with a solid 6-neighbour holding a triangle that faces
//!   the candidate ([`CandidateRule::FrontFacing`], an extension: the paper's rule,
//!   [`CandidateRule::Paper`], accepts any solid neighbour and wastes probes behind single-sided
//!   walls).
//! - The density works in integer voxel offsets with the kernel in 32-bit fixed point, so the
//!   removal order is exact, independent of thread count and of the scene's scale; ties go to
//!   the candidate with the lower voxel index.
//! - The radius is the bisection point of the mean number of probes strictly within r over the
//!   receivers ("best satisfies the overlap constraint on average").

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::DVec3;
use rayon::prelude::*;

use crate::geometry::Geometry;
use crate::kernel;
use crate::voxel::VoxelGrid;
use crate::ProbesError;

/// Voxels per probe spacing ρ (the kernel density's radius in voxels).
pub const VOXELS_PER_SPACING: i64 = 8;
/// The most probes accepted.
pub const MAX_PROBES: usize = 100_000;

/// Which empty voxels may hold a probe.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CandidateRule {
    /// A solid neighbour holding a triangle that faces the candidate (default; extension).
    FrontFacing,
    /// Any solid neighbour (the paper's "empty voxels with non-empty neighbors").
    Paper,
}

/// How probes are placed and how far they reach.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlacementSettings {
    /// The number of probes.
    pub probes: usize,
    /// N_overlap: the mean number of probes covering a receiver.
    pub overlap: f64,
    pub rule: CandidateRule,
}

impl Default for PlacementSettings {
    fn default() -> Self {
        PlacementSettings {
            probes: crate::defaults::PROBES,
            overlap: crate::defaults::OVERLAP,
            rule: CandidateRule::FrontFacing,
        }
    }
}

impl PlacementSettings {
    pub fn validate(&self) -> Result<(), ProbesError> {
        if self.probes == 0 || self.probes > MAX_PROBES {
            return Err(ProbesError::parameter(
                "probes",
                format!("must be between 1 and {MAX_PROBES}, got {}", self.probes),
            ));
        }
        if !(self.overlap >= 1.0 && self.overlap <= 1000.0) {
            return Err(ProbesError::parameter("overlap", format!("must be between 1 and 1000, got {}", self.overlap)));
        }
        Ok(())
    }
}

/// Placed probes and how they were found.
#[derive(Clone, Debug)]
pub struct Placement {
    /// Probe positions (voxel centres), in increasing voxel order.
    pub probes: Vec<DVec3>,
    /// The spacing ρ (kernel radius of the density estimate).
    pub spacing: f64,
    pub voxel: f64,
    pub dims: [usize; 3],
    pub solid_voxels: usize,
    pub reached_voxels: usize,
    pub candidates: usize,
    /// Seed points (camera, point and spot lights) that started a fill in an empty voxel.
    pub seeds_used: usize,
    /// The voxel grid with its flood fill (receiver validity reads it).
    pub grid: VoxelGrid,
}

/// The spacing ρ for `count` probes over bounds of size `extent`: the middle (geometric mean)
/// of the interval of spacings whose grid `∏ max(1, ⌈e_i / ρ⌉)` has at least `count` points and
/// is the largest such interval.
pub fn spacing_for_count(extent: DVec3, count: usize) -> f64 {
    let e = [extent.x, extent.y, extent.z];
    let points = |rho: f64| -> f64 { e.iter().map(|&x| (x / rho).ceil().max(1.0)).product() };
    // The breakpoints e_i / k where a factor changes, largest first.
    let mut breaks: Vec<f64> = Vec::new();
    for &x in &e {
        if x > 0.0 {
            for k in 1..=(count + 1) {
                breaks.push(x / k as f64);
            }
        }
    }
    breaks.sort_by(|a, b| b.total_cmp(a));
    breaks.dedup();
    let mut upper = e.iter().copied().fold(0.0, f64::max) * 2.0;
    for &b in &breaks {
        // The grid is constant for ρ in (b, upper) when b is the next breakpoint below.
        let mid = (b * upper).sqrt();
        if points(mid) >= count as f64 {
            return mid;
        }
        upper = b;
    }
    upper * 0.5
}

/// Places `settings.probes` probes in `geometry` (voxelised with the flood fill seeded from the
/// grid boundary and `seeds`).
pub fn place(geometry: &Geometry, seeds: &[DVec3], settings: &PlacementSettings) -> Result<Placement, ProbesError> {
    settings.validate()?;
    let spacing = spacing_for_count(geometry.hi - geometry.lo, settings.probes);
    let voxel = spacing / VOXELS_PER_SPACING as f64;
    let grid = VoxelGrid::build(geometry, voxel, seeds)?;
    let candidates = candidates(&grid, settings.rule);
    if candidates.is_empty() {
        return Err(ProbesError::NoCandidates { voxel });
    }
    let kept = thin(&grid, &candidates, settings.probes);
    Ok(Placement {
        probes: kept.iter().map(|&i| grid.centre(grid.coords(i))).collect(),
        spacing,
        voxel,
        dims: grid.dims,
        solid_voxels: grid.solid_count(),
        reached_voxels: grid.reached_count(),
        candidates: candidates.len(),
        seeds_used: grid.seeds_used,
        grid,
    })
}

/// Candidate voxels (indices, increasing) under `rule`.
pub fn candidates(grid: &VoxelGrid, rule: CandidateRule) -> Vec<usize> {
    (0..grid.solid.len())
        .into_par_iter()
        .filter(|&i| {
            if !grid.reached[i] {
                return false;
            }
            let c = grid.coords(i);
            (0..6).any(|d| {
                grid.neighbour(c, d).is_some_and(|n| {
                    let j = grid.index(n);
                    // The neighbour in direction d sees the candidate in the opposite direction.
                    grid.solid[j] && (rule == CandidateRule::Paper || grid.facing[j] & (1 << (d ^ 1)) != 0)
                })
            })
        })
        .collect()
}

/// Greedy removal of the densest candidate (kernel w at radius ρ = 8 voxels, fixed point) until
/// `target` remain; returns the kept voxel indices in increasing order.
pub fn thin(grid: &VoxelGrid, candidates: &[usize], target: usize) -> Vec<usize> {
    if candidates.len() <= target {
        return candidates.to_vec();
    }
    let r = VOXELS_PER_SPACING;
    let mut offsets: Vec<([i64; 3], i64)> = Vec::new();
    for z in -r..=r {
        for y in -r..=r {
            for x in -r..=r {
                let d2 = x * x + y * y + z * z;
                if d2 > 0 && d2 < r * r {
                    let w = kernel::w((d2 as f64).sqrt() / r as f64);
                    offsets.push(([x, y, z], (w * 4_294_967_296.0).round() as i64));
                }
            }
        }
    }
    let mut slot = vec![u32::MAX; grid.solid.len()];
    for (k, &i) in candidates.iter().enumerate() {
        slot[i] = k as u32;
    }
    let neighbours: Vec<Vec<(u32, i64)>> = candidates
        .par_iter()
        .map(|&i| {
            let c = grid.coords(i);
            offsets
                .iter()
                .filter_map(|&(o, w)| {
                    let n = [c[0] as i64 + o[0], c[1] as i64 + o[1], c[2] as i64 + o[2]];
                    if (0..3).any(|a| n[a] < 0 || n[a] >= grid.dims[a] as i64) {
                        return None;
                    }
                    let j = slot[grid.index([n[0] as usize, n[1] as usize, n[2] as usize])];
                    (j != u32::MAX).then_some((j, w))
                })
                .collect()
        })
        .collect();
    let mut density: Vec<i64> = neighbours.iter().map(|n| n.iter().map(|&(_, w)| w).sum()).collect();
    let mut alive = vec![true; candidates.len()];
    let mut heap: BinaryHeap<(i64, Reverse<u32>)> =
        density.iter().enumerate().map(|(k, &d)| (d, Reverse(k as u32))).collect();
    let mut remaining = candidates.len();
    while remaining > target {
        let Some((d, Reverse(k))) = heap.pop() else { break };
        let k = k as usize;
        if !alive[k] || density[k] != d {
            continue;
        }
        alive[k] = false;
        remaining -= 1;
        for &(j, w) in &neighbours[k] {
            let j = j as usize;
            if alive[j] {
                density[j] -= w;
                heap.push((density[j], Reverse(j as u32)));
            }
        }
    }
    candidates.iter().zip(&alive).filter(|(_, &a)| a).map(|(&i, _)| i).collect()
}

/// The mean number of probes strictly within `r` of a receiver.
pub fn mean_overlap(probes: &[DVec3], receivers: &[DVec3], r: f64) -> f64 {
    let r2 = r * r;
    let total: u64 =
        receivers.par_iter().map(|x| probes.iter().filter(|p| p.distance_squared(*x) < r2).count() as u64).sum();
    total as f64 / receivers.len().max(1) as f64
}

/// The support radius: the smallest r (to 1e-12 relative) whose mean overlap reaches
/// `overlap`, clamped to the probe count. Bisection on the step function [`mean_overlap`].
pub fn support_radius(probes: &[DVec3], receivers: &[DVec3], overlap: f64) -> Result<f64, ProbesError> {
    if probes.is_empty() || receivers.is_empty() {
        return Err(ProbesError::parameter("probes", "a support radius needs at least one probe and one receiver"));
    }
    let target = overlap.min(probes.len() as f64);
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for p in probes.iter().chain(receivers) {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    // Every probe is within the diagonal of every receiver: the mean reaches the probe count.
    let mut upper = (hi - lo).length() * 1.0001 + f64::MIN_POSITIVE;
    let mut lower = 0.0;
    for _ in 0..200 {
        if upper - lower <= 1e-12 * upper {
            break;
        }
        let mid = 0.5 * (lower + upper);
        if mean_overlap(probes, receivers, mid) >= target {
            upper = mid;
        } else {
            lower = mid;
        }
    }
    Ok(upper)
}

/// How many probes cover each receiver.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coverage {
    pub receivers: usize,
    pub min: usize,
    pub mean: f64,
    pub max: usize,
    /// Receivers with no probe within r.
    pub uncovered: usize,
}

/// Probes within `r` per receiver: min, mean, max and the receivers with none.
pub fn coverage(probes: &[DVec3], receivers: &[DVec3], r: f64) -> Coverage {
    let r2 = r * r;
    let counts: Vec<usize> =
        receivers.par_iter().map(|x| probes.iter().filter(|p| p.distance_squared(*x) < r2).count()).collect();
    Coverage {
        receivers: counts.len(),
        min: counts.iter().copied().min().unwrap_or(0),
        mean: counts.iter().sum::<usize>() as f64 / counts.len().max(1) as f64,
        max: counts.iter().copied().max().unwrap_or(0),
        uncovered: counts.iter().filter(|&&c| c == 0).count(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::seed_points;
    use crate::layout::Layout;
    use crate::surfels::{SurfelSettings, Surfels};
    use crate::test_scenes::{cornell, room, scaled, scene_of};
    use glam::Vec3;
    use tracer::scene::shapes::{axis_aligned_box, polygon};
    use tracer::Scene;

    fn placed(scene: &Scene, probes: usize, rule: CandidateRule) -> Result<Placement, ProbesError> {
        let geometry = Geometry::from_scene(scene)?;
        place(&geometry, &seed_points(scene), &PlacementSettings { probes, rule, ..Default::default() })
    }

    fn inside(p: DVec3, lo: f64, hi: f64) -> bool {
        p.cmpgt(DVec3::splat(lo)).all() && p.cmplt(DVec3::splat(hi)).all()
    }

    #[test]
    fn spacing_is_the_middle_of_the_largest_grid_interval() {
        // Extents 3 × 2 × 1: spacings in [1, 1.5) give 3 · 2 · 1 = 6 grid points, 1.5 and above
        // give 4; the middle of [1, 1.5) is √1.5.
        let rho = spacing_for_count(DVec3::new(3.0, 2.0, 1.0), 6);
        assert!((rho - 1.5f64.sqrt()).abs() < 1e-12, "{rho}");
        // A flat extent counts as one layer.
        let rho = spacing_for_count(DVec3::new(4.0, 0.0, 4.0), 16);
        assert!((1.0..4.0 / 3.0).contains(&rho), "{rho}");
        assert!(spacing_for_count(DVec3::new(1.0, 1.0, 1.0), 1) > 1.0);
    }

    #[test]
    fn a_closed_room_gets_probes_only_inside_when_the_camera_is_inside() {
        let lo = Vec3::splat(0.0);
        let hi = Vec3::splat(1.0);
        let inner = scene_of(vec![room(lo, hi)], Vec3::splat(0.5));
        let p = placed(&inner, 20, CandidateRule::FrontFacing).unwrap();
        assert_eq!(p.probes.len(), 20);
        assert!(p.probes.iter().all(|&q| inside(q, 0.0, 1.0)), "a probe outside the room");
        assert_eq!(p.seeds_used, 1);
        // The paper's rule also takes the outer side of the walls (reached from the boundary).
        let paper = placed(&inner, 20, CandidateRule::Paper).unwrap();
        assert!(paper.probes.iter().any(|&q| !inside(q, 0.0, 1.0)), "the paper's rule has no outside probe");
        assert!(paper.probes.iter().any(|&q| inside(q, 0.0, 1.0)), "the paper's rule has no inside probe");
        // Camera outside, nothing seeds the inside: the flood fill never enters the room.
        let outer = scene_of(vec![room(lo, hi)], Vec3::splat(3.0));
        assert!(matches!(placed(&outer, 20, CandidateRule::FrontFacing), Err(ProbesError::NoCandidates { .. })));
        let paper = placed(&outer, 20, CandidateRule::Paper).unwrap();
        assert!(paper.probes.iter().all(|&q| !inside(q, 0.0, 1.0)), "a probe inside the unreached room");
        // A point light inside seeds it as the camera does.
        let mut lit = outer.clone();
        lit.lights.push(tracer::scene::PunctualLight::Point { position: Vec3::splat(0.3), intensity: Vec3::ONE });
        let p = placed(&lit, 20, CandidateRule::FrontFacing).unwrap();
        assert!(p.probes.iter().all(|&q| inside(q, 0.0, 1.0)));
    }

    #[test]
    fn walls_thinner_than_a_voxel_and_solid_blocks_keep_probes_out() {
        // A room split by a zero-thickness wall at x = 0.5 (facing the camera's half) with a
        // closed block (outward-facing) floating in the camera's half. (A block standing on the
        // floor has a bottom face coplanar with the floor that faces out of the room: the
        // voxels under it are front-facing candidates, rightly by the rule.)
        let wall = polygon(
            "wall",
            &[Vec3::new(0.5, 0.0, 0.0), Vec3::new(0.5, 0.0, 1.0), Vec3::new(0.5, 1.0, 1.0), Vec3::new(0.5, 1.0, 0.0)],
            0,
        );
        assert!(wall_normal(&wall).x < 0.0);
        let block = axis_aligned_box("block", Vec3::new(0.1, 0.2, 0.3), Vec3::new(0.35, 0.5, 0.6), 0);
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), wall, block], Vec3::new(0.2, 0.6, 0.8));
        for probes in [8, 40, 200] {
            let p = placed(&scene, probes, CandidateRule::FrontFacing).unwrap();
            assert_eq!(p.probes.len(), probes);
            for q in &p.probes {
                assert!(q.x < 0.5 && inside(*q, 0.0, 1.0), "{probes} probes: one at {q} beyond the wall");
                let in_block = q.x > 0.1 && q.x < 0.35 && q.y > 0.2 && q.y < 0.5 && q.z > 0.3 && q.z < 0.6;
                assert!(!in_block, "{probes} probes: one at {q} inside the block");
            }
        }
    }

    fn wall_normal(m: &tracer::scene::Mesh) -> Vec3 {
        let [a, b, c] = m.indices[0].map(|i| m.positions[i as usize]);
        (b - a).cross(c - a)
    }

    #[test]
    fn thinning_matches_a_quadratic_second_implementation() {
        // Recompute every density from scratch at each step from voxel coordinates (no offset
        // table, no heap, no incremental update) and remove the densest, ties to the lowest
        // index. The kernel is rounded to the same fixed point, so ties are ties in both.
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::new(1.0, 0.6, 0.8))], Vec3::splat(0.3));
        let geometry = Geometry::from_scene(&scene).unwrap();
        let grid = VoxelGrid::build(&geometry, 1.0 / 10.0, &seed_points(&scene)).unwrap();
        let cands = candidates(&grid, CandidateRule::FrontFacing);
        assert!(cands.len() > 200, "{} candidates", cands.len());
        let target = 25;
        let fast = thin(&grid, &cands, target);
        let mut alive: Vec<usize> = cands.clone();
        let r = VOXELS_PER_SPACING as f64;
        while alive.len() > target {
            let density = |i: usize| -> i64 {
                let c = grid.coords(i);
                alive
                    .iter()
                    .filter(|&&j| j != i)
                    .map(|&j| {
                        let d = grid.coords(j);
                        let d2: f64 = (0..3).map(|a| (c[a] as f64 - d[a] as f64).powi(2)).sum();
                        (kernel::w(d2.sqrt() / r) * 4_294_967_296.0).round() as i64
                    })
                    .sum()
            };
            let densities: Vec<i64> = alive.iter().map(|&i| density(i)).collect();
            let best = (0..alive.len()).max_by(|&a, &b| densities[a].cmp(&densities[b]).then(b.cmp(&a))).unwrap();
            alive.remove(best);
        }
        assert_eq!(fast, alive);
    }

    #[test]
    fn the_radius_reaches_the_target_overlap() {
        let scene = cornell();
        let receivers =
            Surfels::build(&scene, &SurfelSettings { budget: 4000, ..Default::default() }).unwrap().positions();
        let p = placed(&scene, 30, CandidateRule::FrontFacing).unwrap();
        let r = support_radius(&p.probes, &receivers, 10.0).unwrap();
        let at = mean_overlap(&p.probes, &receivers, r);
        let below = mean_overlap(&p.probes, &receivers, r * (1.0 - 1e-9));
        assert!(at >= 10.0 && below < 10.0, "mean {below} just below r, {at} at r");
        assert!(at - 10.0 < 0.05, "mean overlap {at}");
        let c = coverage(&p.probes, &receivers, r);
        assert_eq!(c.mean, at);
        assert!(c.min <= 10 && c.max >= 10 && c.receivers == receivers.len());
        // Fewer probes than the overlap: every receiver sees all of them.
        let few = &p.probes[..4];
        let r = support_radius(few, &receivers, 10.0).unwrap();
        assert_eq!(coverage(few, &receivers, r).min, 4);
        assert!(support_radius(&[], &receivers, 10.0).is_err());
    }

    #[test]
    fn bad_settings_are_refused_before_work() {
        let scene = cornell();
        let geometry = Geometry::from_scene(&scene).unwrap();
        for (settings, field) in [
            (PlacementSettings { probes: 0, ..Default::default() }, "probes:"),
            (PlacementSettings { probes: MAX_PROBES + 1, ..Default::default() }, "probes:"),
            (PlacementSettings { overlap: f64::NAN, ..Default::default() }, "overlap:"),
            (PlacementSettings { overlap: 0.5, ..Default::default() }, "overlap:"),
        ] {
            let err = place(&geometry, &[], &settings).unwrap_err();
            assert!(err.to_string().starts_with(field), "{err}");
        }
    }

    fn layout(scene: &Scene) -> Layout {
        Layout::build(
            scene,
            &SurfelSettings { budget: 3000, ..Default::default() },
            &PlacementSettings { probes: 27, ..Default::default() },
            &mut |_| {},
        )
        .unwrap()
    }

    #[test]
    fn the_layout_is_the_same_for_any_thread_count() {
        let scene = cornell();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| layout(&scene))
        };
        let (a, b) = (run(1), run(2));
        let bits = |l: &Layout| -> Vec<u64> {
            let mut v: Vec<u64> = l.placement.probes.iter().flat_map(|p| p.to_array().map(f64::to_bits)).collect();
            v.extend(l.surfels.surfels.iter().flat_map(|s| {
                [s.position.to_array(), s.normal.to_array()]
                    .concat()
                    .into_iter()
                    .map(|x| x.to_bits() as u64)
                    .chain([s.area.to_bits() as u64])
            }));
            v.push(l.radius.to_bits());
            v
        };
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(a.coverage, b.coverage);
    }

    #[test]
    fn placement_is_scale_invariant() {
        let scene = cornell();
        let reference = layout(&scene);
        for s in [1e-3f32, 1e3] {
            let other = layout(&scaled(&scene, s));
            let s = s as f64;
            assert_eq!(other.placement.probes.len(), reference.placement.probes.len());
            assert_eq!(other.placement.candidates, reference.placement.candidates, "scale {s}");
            assert_eq!(other.placement.dims, reference.placement.dims);
            for (a, b) in reference.placement.probes.iter().zip(&other.placement.probes) {
                assert!((*b / s - *a).length() < 1e-4 * reference.scale, "scale {s}: {} vs {a}", *b / s);
            }
            assert!(
                (other.radius / s / reference.radius - 1.0).abs() < 1e-3,
                "radius {} vs {}",
                other.radius / s,
                reference.radius
            );
        }
    }
}
