//! From a shading point to weighted surfels: how the image (and, later, each relight ray's hit)
//! reads the receivers. Not in the paper, whose light-map texels are read by texture filtering;
//! this is the surfel counterpart (design note, "Receivers").
//!
//! The weight of surfel s at shading point (x, n) is
//! `tent(‖x − x_s‖ / 1.5h) · max(0, (n·n_s − cos 35°) / (1 − cos 35°)) · exp(−(n_s·(x − x_s))² / 2σ²)`
//! with `σ = h/4`, normalised to sum 1. Where no surfel qualifies, the nearest surfel with
//! `n·n_s > 0` within `2h` takes weight 1; otherwise the point is a *hole* (no surfel, E = 0),
//! counted by [`LookupStats`].

use glam::Vec3;

use crate::surfels::{Surfels, CLUSTER_COS};

/// Support of the tent, in cells.
const TENT_RADIUS: f64 = 1.5;
/// Reach of the nearest-surfel fallback, in cells.
const FALLBACK_RADIUS: f64 = 2.0;

/// How a lookup was answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Found {
    /// Normalised weights over the surfels in reach.
    Weighted,
    /// No weight: the nearest facing surfel within 2h.
    Nearest,
    /// Nothing: no facing surfel within 2h.
    Hole,
}

/// Counts of lookup outcomes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LookupStats {
    pub weighted: u64,
    pub nearest: u64,
    pub holes: u64,
}

impl LookupStats {
    pub fn add(&mut self, found: Found) {
        match found {
            Found::Weighted => self.weighted += 1,
            Found::Nearest => self.nearest += 1,
            Found::Hole => self.holes += 1,
        }
    }

    pub fn total(&self) -> u64 {
        self.weighted + self.nearest + self.holes
    }
}

/// The weighted surfels of shading point `x` with unit normal `n`, written to `out` as
/// (surfel index, weight) in surfel order; the weights sum to 1 unless the answer is a hole.
pub fn lookup(surfels: &Surfels, x: Vec3, n: Vec3, out: &mut Vec<(u32, f32)>) -> Found {
    out.clear();
    let h = surfels.h;
    let xd = x.as_dvec3();
    let nd = n.as_dvec3();
    let sigma = 0.25 * h;
    let c = surfels.cell_of(xd);
    let reach = FALLBACK_RADIUS.ceil() as i64;
    let mut total = 0.0f64;
    let mut weights: Vec<(u32, f64)> = Vec::new();
    let mut nearest: Option<(f64, u32)> = None;
    for dz in -reach..=reach {
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let cell = [c[0] + dx, c[1] + dy, c[2] + dz];
                let first = surfels.cell_start(cell);
                for (k, s) in surfels.in_cell(cell).iter().enumerate() {
                    let index = first + k as u32;
                    let offset = xd - s.position.as_dvec3();
                    let distance = offset.length() / h;
                    let ns = s.normal.as_dvec3();
                    let facing = nd.dot(ns);
                    if facing > 0.0 && distance < FALLBACK_RADIUS && !matches!(nearest, Some((d, _)) if d <= distance) {
                        nearest = Some((distance, index));
                    }
                    if distance >= TENT_RADIUS || facing <= CLUSTER_COS {
                        continue;
                    }
                    let plane = ns.dot(offset);
                    let weight = (1.0 - distance / TENT_RADIUS)
                        * ((facing - CLUSTER_COS) / (1.0 - CLUSTER_COS))
                        * (-(plane * plane) / (2.0 * sigma * sigma)).exp();
                    if weight > 0.0 {
                        weights.push((index, weight));
                        total += weight;
                    }
                }
            }
        }
    }
    if total > 0.0 {
        weights.sort_unstable_by_key(|&(i, _)| i);
        out.extend(weights.iter().map(|&(i, w)| (i, (w / total) as f32)));
        Found::Weighted
    } else if let Some((_, index)) = nearest {
        out.push((index, 1.0));
        Found::Nearest
    } else {
        Found::Hole
    }
}

/// A scalar field at the surfels interpolated at (x, n); 0 at a hole.
pub fn interpolate(surfels: &Surfels, values: &[f32], x: Vec3, n: Vec3) -> (f32, Found) {
    let mut out = Vec::new();
    let found = lookup(surfels, x, n, &mut out);
    let v: f64 = out.iter().map(|&(i, w)| w as f64 * values[i as usize] as f64).sum();
    (v as f32, found)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{scene_of, unit_quad};
    use shading::sampling::{hash_u32, to_unit_float};

    fn quad_surfels(budget: usize) -> Surfels {
        let scene = scene_of(vec![unit_quad()], Vec3::new(0.5, 0.5, 2.0));
        Surfels::build(&scene, &SurfelSettings { budget, ..Default::default() }).unwrap()
    }

    #[test]
    fn weights_sum_to_one_and_reproduce_a_linear_field_on_a_plane() {
        let s = quad_surfels(4000);
        let field = |p: Vec3| 3.0 * p.x - 2.0 * p.y + 1.0;
        let values: Vec<f32> = s.surfels.iter().map(|x| field(x.position)).collect();
        let gradient = 13f64.sqrt();
        let mut out = Vec::new();
        let mut stats = LookupStats::default();
        let mut worst = 0.0f64;
        let mut state = 7u32;
        for _ in 0..500 {
            state = hash_u32(state);
            let x = 0.1 + 0.8 * to_unit_float(state);
            state = hash_u32(state);
            let y = 0.1 + 0.8 * to_unit_float(state);
            let p = Vec3::new(x, y, 0.0);
            let found = lookup(&s, p, Vec3::Z, &mut out);
            stats.add(found);
            assert_eq!(found, Found::Weighted);
            let sum: f64 = out.iter().map(|&(_, w)| w as f64).sum();
            assert!((sum - 1.0).abs() < 1e-5, "weights sum to {sum}");
            assert!(out.iter().all(|&(i, w)| w > 0.0 && s.surfels[i as usize].normal.z > 0.0));
            let (v, _) = interpolate(&s, &values, p, Vec3::Z);
            worst = worst.max((v as f64 - field(p) as f64).abs() / (gradient * s.h));
        }
        assert_eq!(stats.total(), 500);
        // A weighted mean reproduces a linear field up to the offset of its weights' centroid:
        // a fraction of a cell, never more.
        assert!(worst < 0.25, "largest error {worst} h·|∇f|");
    }

    #[test]
    fn the_back_side_reads_only_back_side_surfels() {
        let s = quad_surfels(1000);
        let mut out = Vec::new();
        assert_eq!(lookup(&s, Vec3::new(0.4, 0.6, 0.0), -Vec3::Z, &mut out), Found::Weighted);
        assert!(!out.is_empty() && out.iter().all(|&(i, _)| s.surfels[i as usize].normal.z < 0.0));
    }

    #[test]
    fn oblique_normals_fall_back_and_far_points_are_holes() {
        let s = quad_surfels(1000);
        let mut out = Vec::new();
        let mut stats = LookupStats::default();
        // 50° from the surfels' normal: no weight, but the nearest facing surfel.
        let n = Vec3::new(50f32.to_radians().sin(), 0.0, 50f32.to_radians().cos());
        let found = lookup(&s, Vec3::new(0.5, 0.5, 0.0), n, &mut out);
        stats.add(found);
        assert_eq!(found, Found::Nearest);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].1, 1.0);
        // Far above the quad: nothing in reach.
        let found = lookup(&s, Vec3::new(0.5, 0.5, 0.5), Vec3::Z, &mut out);
        stats.add(found);
        assert_eq!(found, Found::Hole);
        assert!(out.is_empty());
        assert_eq!(stats, LookupStats { weighted: 0, nearest: 1, holes: 1 });
        assert_eq!(interpolate(&s, &vec![1.0; s.surfels.len()], Vec3::new(0.5, 0.5, 0.5), Vec3::Z).0, 0.0);
    }
}
