//! Beyond the paper: each splat's radiance filtered once over its neighbours, so that a
//! reconstruction ray can read one splat instead of filtering every splat of the surface it meets
//! ([`super::reconstruct::RayModel::NearestSplat`]).
//!
//! The paper's diffuse filter (§2.4) averages, per reconstruction ray, the radiance of the
//! surface's splats weighted by their tents at the ray's crossing. Evaluated once per splat at
//! its own centre instead, over the splat and its jury (its nearest neighbours in its lobe under
//! the sizing metric, [`super::splats::Juries`]):
//!
//! L̃_i = Σ_j w_j L_j / Σ_j w_j, j ∈ {i} ∪ jury(i), w_j = max(0, 1 − |h_j − h_i| / r_j),
//!
//! counting only neighbours of the same apparent surface as i: normals within
//! [`PrefilterParams::max_normal_degrees`] of each other, and the line between the centres within
//! [`super::surfaces::COPLANAR_DEGREES`] of either tangent plane (the grouping rule of the default
//! conflict test, [`super::surfaces::ConflictTest::EventLineOffPlane`], for pairs side by side).
//! A splat of radius 0 (shrunk away) gives nothing; one without a neighbour that counts keeps its
//! own radiance. Sums run in f64; each value is a pure function of the input.

use rayon::prelude::*;

use super::splats::{Juries, SplatPoints};
use super::surfaces::COPLANAR_DEGREES;
use crate::vector::{dot, length, sub};

/// Which neighbours a splat's filtered radiance takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrefilterParams {
    /// Neighbours whose normal differs by more than this (degrees) lie on another surface.
    pub max_normal_degrees: f32,
}

impl Default for PrefilterParams {
    fn default() -> Self {
        PrefilterParams { max_normal_degrees: 45.0 }
    }
}

/// Whether splats at `a` and `b` (unit normals `na`, `nb`) lie side by side on one surface:
/// normals within `min_cosine`, and the line between them within [`COPLANAR_DEGREES`] of either
/// tangent plane.
#[inline]
pub fn same_surface(a: [f32; 3], na: [f32; 3], b: [f32; 3], nb: [f32; 3], min_cosine: f32) -> bool {
    if dot(na, nb) < min_cosine {
        return false;
    }
    let d = sub(b, a);
    let limit = COPLANAR_DEGREES.to_radians().sin() * length(d);
    dot(d, na).abs() <= limit || dot(d, nb).abs() <= limit
}

/// The filtered radiance of every splat (see the module documentation): `radius` and `radiance`
/// by splat, `juries` from the sizing's walk over the same `points`.
pub fn prefiltered_radiance(
    points: &SplatPoints,
    radius: &[f32],
    radiance: &[[f32; 3]],
    juries: &Juries,
    params: &PrefilterParams,
) -> Vec<[f32; 3]> {
    let min_cosine = params.max_normal_degrees.to_radians().cos();
    (0..points.position.len())
        .into_par_iter()
        .with_max_len(super::PARALLEL_ITEMS)
        .map(|i| {
            let (hi, ni) = (points.position[i], points.normal[i]);
            let own = if radius[i] > 0.0 { 1.0 } else { 0.0 };
            let mut sum = radiance[i].map(|c| own * c as f64);
            let mut weight = own;
            for &j in juries.of(i) {
                let j = j as usize;
                let (hj, nj) = (points.position[j], points.normal[j]);
                if radius[j] <= 0.0 || !same_surface(hi, ni, hj, nj, min_cosine) {
                    continue;
                }
                let w = (1.0 - length(sub(hj, hi)) / radius[j]).max(0.0) as f64;
                for c in 0..3 {
                    sum[c] += w * radiance[j][c] as f64;
                }
                weight += w;
            }
            if weight > 0.0 {
                sum.map(|s| (s / weight) as f32)
            } else {
                radiance[i]
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ilfr::neighbours::KdTree;
    use crate::ilfr::robust::RobustParams;
    use crate::ilfr::splats::{size_splats_with_juries, SplatParams};
    use crate::lcg::Lcg;

    /// A floor z = 0 (normal +z) and a wall x = 0 (normal +x) meeting at a crease, random points,
    /// radiance `floor` and `wall`; its points, radii (the sizing's) and juries.
    struct Crease {
        position: Vec<[f32; 3]>,
        normal: Vec<[f32; 3]>,
        direction: Vec<[f32; 3]>,
        radiance: Vec<[f32; 3]>,
    }

    fn crease(n: usize, scale: f32, floor: impl Fn([f32; 3]) -> [f32; 3], wall: [f32; 3]) -> Crease {
        let mut rng = Lcg(9);
        let mut c = Crease { position: vec![], normal: vec![], direction: vec![], radiance: vec![] };
        for i in 0..n {
            let (a, b) = (rng.uniform() * 2.0, rng.uniform() * 2.0 - 1.0);
            if i % 2 == 0 {
                let p = [a, b, 0.0];
                c.position.push(p.map(|v| v * scale));
                c.normal.push([0.0, 0.0, 1.0]);
                c.direction.push([0.0, 0.0, -1.0]);
                c.radiance.push(floor(p));
            } else {
                c.position.push([0.0, b * scale, a * scale]);
                c.normal.push([1.0, 0.0, 0.0]);
                c.direction.push([-1.0, 0.0, 0.0]);
                c.radiance.push(wall);
            }
        }
        c
    }

    fn filtered(c: &Crease, dead: &[usize]) -> Vec<[f32; 3]> {
        let points = SplatPoints { position: &c.position, normal: &c.normal, direction: &c.direction, kappa: None };
        let tree = KdTree::build(&c.position);
        let rule = RobustParams::default().jury_rule();
        let (sized, juries) = size_splats_with_juries(&tree, &points, &SplatParams::default(), Some(rule)).unwrap();
        let mut radius = sized.radius;
        for &k in dead {
            radius[k] = 0.0;
        }
        prefiltered_radiance(&points, &radius, &c.radiance, &juries.unwrap(), &PrefilterParams::default())
    }

    /// Constant light on both sides of a crease stays exactly constant (a convex combination of
    /// equal f32 values, summed in f64), at 1e-6, 1 and 1e9 scale; light of the wall never reaches
    /// the floor across the crease, nor the floor's the wall.
    #[test]
    fn constant_light_stays_exact_and_a_crease_keeps_its_sides_apart() {
        for scale in [1e-6f32, 1.0, 1e9] {
            let c = crease(2000, scale, |_| [2.0, 0.5, 1e6], [0.25, 3.0, 0.0]);
            let out = filtered(&c, &[]);
            for (k, l) in out.iter().enumerate() {
                assert_eq!(*l, c.radiance[k], "splat {k} at scale {scale}");
            }
        }
    }

    /// A linear ramp on the floor is kept to within the jury's reach (the splats' radii) times
    /// its slope, and smoothed: noise on it falls.
    #[test]
    fn a_ramp_is_kept_and_noise_on_it_falls() {
        let mut rng = Lcg(4);
        let ramp = |p: [f32; 3]| [1.0 + p[0]; 3];
        let clean = crease(4000, 1.0, ramp, [0.0; 3]);
        let noisy = Crease {
            radiance: clean.radiance.iter().map(|l| l.map(|v| v * (0.5 + rng.uniform()))).collect(),
            ..crease(4000, 1.0, ramp, [0.0; 3])
        };
        let out = filtered(&clean, &[]);
        let denoised = filtered(&noisy, &[]);
        let (mut before, mut after, mut count) = (0.0f64, 0.0f64, 0);
        for k in (0..out.len()).step_by(2) {
            let p = clean.position[k];
            if p[0] < 0.3 || p[0] > 1.7 || p[1].abs() > 0.7 {
                continue; // away from the crease and the edges
            }
            assert!(
                (out[k][0] - clean.radiance[k][0]).abs() < 0.1,
                "splat {k}: {:?} vs {:?}",
                out[k],
                clean.radiance[k]
            );
            before += ((noisy.radiance[k][0] - clean.radiance[k][0]) as f64).powi(2);
            after += ((denoised[k][0] - clean.radiance[k][0]) as f64).powi(2);
            count += 1;
        }
        assert!(count > 500 && after < 0.35 * before, "squared error {before} → {after} over {count} splats");
    }

    /// A dead splat (radius 0) gives nothing to its neighbours; a splat whose neighbours all lie
    /// beyond their radii keeps its own radiance.
    #[test]
    fn dead_splats_give_nothing_and_lone_splats_keep_their_own() {
        let mut c = crease(400, 1.0, |_| [1.0; 3], [1.0; 3]);
        c.radiance[0] = [1e4; 3];
        let out = filtered(&c, &[0]);
        assert!(out.iter().skip(1).all(|l| *l == [1.0; 3]), "the dead bright splat reached a neighbour");
        // Every normal differs from every other: nobody counts as a neighbour.
        let mut rng = Lcg(2);
        c.normal.iter_mut().for_each(|n| *n = rng.unit_vector());
        c.radiance.iter_mut().for_each(|l| *l = [rng.uniform(); 3]);
        let radius = vec![1e-3; c.position.len()];
        let points = SplatPoints { position: &c.position, normal: &c.normal, direction: &c.direction, kappa: None };
        let tree = KdTree::build(&c.position);
        let rule = RobustParams::default().jury_rule();
        let (_, juries) = size_splats_with_juries(&tree, &points, &SplatParams::default(), Some(rule)).unwrap();
        let out = prefiltered_radiance(&points, &radius, &c.radiance, &juries.unwrap(), &PrefilterParams::default());
        assert_eq!(out, c.radiance, "tiny radii: every neighbour's tent is 0");
    }
}
