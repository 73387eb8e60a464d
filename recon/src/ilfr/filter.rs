//! The 4D reconstruction filter on the nearest apparent surface, paper Section 2.4 and Figure 6,
//! and the ambient-occlusion threshold of Section 3.3 (design: docs/ilfr-design.md §2 "4D
//! filter", §3 #14).
//!
//! Paper → code:
//! - "For a diffuse surface … we evaluate a spatial filter (tent in our implementation) at the
//!   intersection of the reconstruction ray and the splat, and take a weighted average among all
//!   samples": [`tent_weight`] w_i = max(0, 1 − s_i/r_i) and the diffuse branch of
//!   [`filter_radiance`], L = Σ w_i L_i / Σ w_i over the members that give radiance (§2.5).
//! - "We perform reconstruction by evaluating the transformed filters at the stuv origin, and
//!   picking the sample whose filter has the largest magnitude … an anisotropic nearest
//!   neighbor filter": [`glossy_weight`] g_i = A_i(d)·min(1, w_i / min(1, r_i/|x_i − p|)) (the vMF
//!   lobe of Eq. 2 towards the reconstruction direction times the tent, the authors' code's
//!   reading of the transformed filter) and the glossy branch of [`filter_radiance`], L =
//!   L_{argmax g}. A surface is glossy when any radiance-giving member has κ ≥ [`GLOSSY_KAPPA`]
//!   (per surface; the authors switch globally).
//! - "thresholding the distance to the closest apparent surface found" (§3.3):
//!   [`filter_visibility`] — each member votes visible when its centre lies deeper than the AO
//!   radius along the ray (z_i > R), weighted by its tent, over all members (back-facing splats
//!   occlude too), as the authors' code does.
//!
//! Sums run in f64, so radiance spikes of 1e6 stay exact enough and finite; every weight is a
//! finite number in [0, 1]; a surface whose weights all vanish (a ray grazing every rim) falls
//! back to the unweighted mean instead of dividing by zero.

use super::surfaces::{Candidate, Surface};
use crate::vector::dot;

/// κ from which a splat counts as glossy and its surface is filtered by nearest neighbour
/// (κ_nn of the design; κ = 1 is a lobe whose half-width at A = 0.5 is 72°).
pub const GLOSSY_KAPPA: f32 = 1.0;

/// What the filter knows about each splat, indexed by the splat's id (its index in the input of
/// the hierarchy, [`Candidate::id`]).
#[derive(Clone, Copy, Debug)]
pub struct SplatShading<'a> {
    /// L_i: the radiance the input ray carried.
    pub radiance: &'a [[f32; 3]],
    /// ω_i, unit: the direction of the input ray (from its primary hit towards h_i).
    pub direction: &'a [[f32; 3]],
    /// κ_i ≥ 0; `None` means 0 for all (a diffuse file).
    pub kappa: Option<&'a [f32]>,
}

impl SplatShading<'_> {
    pub fn kappa_of(&self, id: u32) -> f32 {
        self.kappa.map_or(0.0, |k| k[id as usize])
    }
}

/// Which filter gave a radiance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterMode {
    /// Tent-weighted average.
    Diffuse,
    /// Anisotropic nearest neighbour.
    Glossy,
}

/// A filtered radiance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Filtered {
    pub radiance: [f32; 3],
    pub mode: FilterMode,
    /// Splats that took part (for the glossy filter: the candidates compared).
    pub contributors: u32,
    /// The ray parameter where the ray met the surface: its nearest member's crossing.
    pub distance: f32,
}

/// The spatial tent of a splat at distance `spatial` from its centre on its tangent plane:
/// 1 at the centre, 0 at and beyond the rim (and for a dead splat of radius 0).
#[inline]
pub fn tent_weight(spatial: f32, radius: f32) -> f32 {
    if radius > 0.0 {
        (1.0 - spatial / radius).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The unnormalised vMF lobe of Eq. 2, A(d) = exp(κ(ω·d − 1)) ∈ [0, 1], for a unit ω and d.
#[inline]
pub fn lobe(kappa: f32, direction: [f32; 3], query: [f32; 3]) -> f32 {
    let cosine = dot(direction, query).clamp(-1.0, 1.0);
    (kappa * (cosine - 1.0)).exp().clamp(0.0, 1.0)
}

/// The glossy filter value g_i of a candidate for a reconstruction ray of unit direction
/// `query` (see the module documentation): the lobe times the tent, the tent counting fully once
/// the splat is small against its distance from the ray's origin.
pub fn glossy_weight(c: &Candidate, direction: [f32; 3], kappa: f32, query: [f32; 3]) -> f32 {
    let tent = tent_weight(c.hit.spatial, c.radius);
    // |x_i − p| = t for a unit direction; min(1, r/|x − p|) ∈ (0, 1] for a hit (r > s ≥ 0).
    let distance = c.hit.t.abs();
    let near_field = if distance > c.radius { c.radius / distance } else { 1.0 };
    let spatial = if tent >= near_field { 1.0 } else { tent / near_field };
    lobe(kappa, direction, query) * spatial
}

/// The radiance of `surface` (a range of the sorted `candidates`) towards the ray of unit
/// direction `query`: diffuse tent average or glossy nearest neighbour. `None` when no member
/// gives radiance (cannot happen for a surface from [`super::surfaces::first_surface`]).
pub fn filter_radiance(
    query: [f32; 3],
    candidates: &[Candidate],
    surface: &Surface,
    shading: &SplatShading,
) -> Option<Filtered> {
    let members = || candidates[surface.members.clone()].iter().filter(|c| surface.gives_radiance(c));
    let count = members().count() as u32;
    if count == 0 {
        return None;
    }
    let glossy = members().any(|c| shading.kappa_of(c.id) >= GLOSSY_KAPPA);
    let distance = members().map(|c| c.hit.t).fold(f32::INFINITY, f32::min);
    if glossy {
        // Largest g; ties by the larger tent, then the lower id (deterministic, and meaningful
        // when every lobe underflows to 0).
        let mut best: Option<(f32, f32, u32)> = None;
        for c in members() {
            let g = glossy_weight(c, shading.direction[c.id as usize], shading.kappa_of(c.id), query);
            let key = (g, tent_weight(c.hit.spatial, c.radius), c.id);
            let better = match best {
                None => true,
                Some((bg, bt, bid)) => g > bg || (g == bg && (key.1 > bt || (key.1 == bt && c.id < bid))),
            };
            if better {
                best = Some(key);
            }
        }
        let (_, _, id) = best?;
        return Some(Filtered {
            radiance: shading.radiance[id as usize],
            mode: FilterMode::Glossy,
            contributors: count,
            distance,
        });
    }
    let (mut sum, mut weight) = ([0.0f64; 3], 0.0f64);
    for c in members() {
        let w = tent_weight(c.hit.spatial, c.radius) as f64;
        let l = shading.radiance[c.id as usize];
        for k in 0..3 {
            sum[k] += w * l[k] as f64;
        }
        weight += w;
    }
    if weight <= 0.0 {
        // Every member at its rim: the plain mean.
        sum = [0.0; 3];
        for c in members() {
            let l = shading.radiance[c.id as usize];
            for k in 0..3 {
                sum[k] += l[k] as f64;
            }
        }
        weight = count as f64;
    }
    let radiance = sum.map(|s| (s / weight) as f32);
    Some(Filtered { radiance, mode: FilterMode::Diffuse, contributors: count, distance })
}

/// Ambient visibility through `surface` for the AO radius `ao_radius`: the tent-weighted
/// fraction of its members whose centre lies deeper than `ao_radius` along the ray (1 = the
/// surface is beyond the radius, 0 = within it).
pub fn filter_visibility(candidates: &[Candidate], surface: &Surface, ao_radius: f32) -> f32 {
    let members = &candidates[surface.members.clone()];
    let (mut visible, mut weight) = (0.0f64, 0.0f64);
    for c in members {
        let w = tent_weight(c.hit.spatial, c.radius) as f64;
        if c.hit.depth > ao_radius {
            visible += w;
        }
        weight += w;
    }
    if weight > 0.0 {
        (visible / weight) as f32
    } else if members.is_empty() {
        1.0
    } else {
        members.iter().filter(|c| c.hit.depth > ao_radius).count() as f32 / members.len() as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ilfr::disc::DiscHit;

    fn candidate(id: u32, spatial: f32, radius: f32, t: f32, depth: f32, back_facing: bool) -> Candidate {
        Candidate {
            id,
            centre: [0.0; 3],
            normal: [0.0, 0.0, 1.0],
            radius,
            hit: DiscHit { t, spatial, depth, back_facing },
        }
    }

    fn surface(len: usize, from_back: bool) -> Surface {
        Surface { members: 0..len, radiance_from_back_faces: from_back, merged_surfaces: 0 }
    }

    #[test]
    fn tent_is_one_at_the_centre_and_zero_at_the_rim() {
        assert_eq!(tent_weight(0.0, 2.0), 1.0);
        assert_eq!(tent_weight(1.0, 2.0), 0.5);
        assert_eq!(tent_weight(2.0, 2.0), 0.0);
        assert_eq!(tent_weight(3.0, 2.0), 0.0);
        assert_eq!(tent_weight(0.0, 0.0), 0.0, "a dead splat weighs nothing");
        assert_eq!(lobe(0.0, [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]), 1.0, "κ = 0: every direction");
        assert_eq!(lobe(65504.0, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]), 0.0, "a mirror lobe underflows to 0, not NaN");
    }

    #[test]
    fn diffuse_average_weights_by_the_tent_and_skips_back_faces() {
        // Weights 1, 0.5, 0.25 and a back-facing member that gives no radiance.
        let c = [
            candidate(0, 0.0, 1.0, 1.0, 1.0, false),
            candidate(1, 1.0, 2.0, 1.0, 1.0, false),
            candidate(2, 3.0, 4.0, 1.0, 1.0, false),
            candidate(3, 0.0, 1.0, 1.0, 1.0, true),
        ];
        let radiance = [[1.0, 0.0, 1e6], [2.0, 0.0, 0.0], [4.0, 0.0, 0.0], [1000.0, 1000.0, 1000.0]];
        let direction = [[0.0, 0.0, -1.0]; 4];
        let shading = SplatShading { radiance: &radiance, direction: &direction, kappa: None };
        let f = filter_radiance([0.0, 0.0, -1.0], &c, &surface(4, false), &shading).unwrap();
        // (1·1 + 0.5·2 + 0.25·4) / 1.75 = 3 / 1.75; blue 1e6 / 1.75.
        assert_eq!(f.mode, FilterMode::Diffuse);
        assert_eq!(f.contributors, 3);
        assert!((f.radiance[0] - 3.0 / 1.75).abs() < 1e-6, "{:?}", f.radiance);
        assert_eq!(f.radiance[1], 0.0);
        assert!((f.radiance[2] - 1e6 / 1.75).abs() < 0.1, "{:?}", f.radiance);
        // All back-facing: they give radiance.
        let back = [candidate(3, 0.0, 1.0, 1.0, 1.0, true)];
        let f = filter_radiance([0.0, 0.0, -1.0], &back, &surface(1, true), &shading).unwrap();
        assert_eq!(f.radiance, [1000.0; 3]);
    }

    #[test]
    fn glossy_nearest_neighbour_flips_at_the_bisector() {
        // Two splats with identical geometry (same tent, same distance) whose input directions
        // lie 20° either side of −z in the x–z plane: the winner is the direction nearer to the
        // query, so the result flips exactly where the query crosses −z.
        let angle = 20f32.to_radians();
        let direction = [[angle.sin(), 0.0, -angle.cos()], [-angle.sin(), 0.0, -angle.cos()]];
        let radiance = [[1.0; 3], [2.0; 3]];
        let kappa = [40.0, 40.0];
        let shading = SplatShading { radiance: &radiance, direction: &direction, kappa: Some(&kappa) };
        let c = [candidate(0, 0.2, 1.0, 3.0, 3.0, false), candidate(1, 0.2, 1.0, 3.0, 3.0, false)];
        for (offset_degrees, expected) in [(0.5f32, 1.0), (-0.5, 2.0), (15.0, 1.0), (-30.0, 2.0)] {
            let q = offset_degrees.to_radians();
            let query = [q.sin(), 0.0, -q.cos()];
            let f = filter_radiance(query, &c, &surface(2, false), &shading).unwrap();
            assert_eq!(f.mode, FilterMode::Glossy);
            assert_eq!(f.radiance, [expected; 3], "query {offset_degrees}° from −z");
        }
        // A nearer centre wins when the directions agree: the tent decides.
        let same = [[0.0, 0.0, -1.0]; 2];
        let shading = SplatShading { radiance: &radiance, direction: &same, kappa: Some(&kappa) };
        let c = [candidate(0, 0.9, 1.0, 0.5, 0.5, false), candidate(1, 0.1, 1.0, 0.5, 0.5, false)];
        let f = filter_radiance([0.0, 0.0, -1.0], &c, &surface(2, false), &shading).unwrap();
        assert_eq!(f.radiance, [2.0; 3]);
    }

    #[test]
    fn glossy_weight_counts_the_tent_fully_for_far_small_splats() {
        // r/|x − p| = 0.1: a tent of 0.1 or more counts as 1.
        let c = candidate(0, 0.9, 1.0, 10.0, 10.0, false);
        assert_eq!(glossy_weight(&c, [0.0, 0.0, -1.0], 4.0, [0.0, 0.0, -1.0]), 1.0);
        let c = candidate(0, 0.95, 1.0, 10.0, 10.0, false);
        let g = glossy_weight(&c, [0.0, 0.0, -1.0], 4.0, [0.0, 0.0, -1.0]);
        assert!((g - 0.5).abs() < 1e-5, "{g}");
        // Near field (distance below the radius): the plain tent.
        let c = candidate(0, 0.5, 1.0, 0.5, 0.5, false);
        assert_eq!(glossy_weight(&c, [0.0, 0.0, -1.0], 4.0, [0.0, 0.0, -1.0]), 0.5);
    }

    #[test]
    fn visibility_thresholds_the_depth_of_each_member() {
        let near = [candidate(0, 0.0, 1.0, 0.5, 0.5, false), candidate(1, 0.5, 1.0, 0.5, 0.5, true)];
        assert_eq!(filter_visibility(&near, &surface(2, false), 1.0), 0.0);
        assert_eq!(filter_visibility(&near, &surface(2, false), 0.4), 1.0);
        // Weights 1 (visible) and 0.5 (occluding): 2/3.
        let mixed = [candidate(0, 0.0, 1.0, 2.0, 2.0, false), candidate(1, 0.5, 1.0, 0.5, 0.5, false)];
        assert!((filter_visibility(&mixed, &surface(2, false), 1.0) - 2.0 / 3.0).abs() < 1e-6);
    }
}
