//! Reconstruction rays drawn from the primary hit's own BSDF: paper Eq. 3, L(p → c) ≈
//! (1/N) Σ_j f_r(ω_j → c) cos θ_j / p(ω_j) · RECONSTRUCT(p, ω_j), for glossy files, whose
//! records carry o's BSDF (`samples::PrimaryShading`, design gaps G1, G2). The BSDF is the
//! tracer's own (`shading::Bsdf`), so the weights are those the tracer's `weight` field holds.
//!
//! Choice the paper leaves open (it says only "BRDF-sampled"): the N directions are split
//! between the lobes in fixed numbers, n_s = round(N·P_s) from the specular lobe (GGX visible
//! normals) and n_d = N − n_s from the diffuse lobe (cosine), with P_s the probability the
//! tracer's one-sample mixture uses for this ωo, and each direction weighted by
//! f·cos / ((n_s/N) p_s + (n_d/N) p_d) — Veach's multi-sample MIS with the balance heuristic,
//! unbiased for any split. Each lobe gets its own Owen-scrambled Sobol' sequence, of which a hit
//! takes the points from `first` on (a prefix at `first` = 0; the final gather gives hit k of a
//! pixel `first` = k·N of sequences scrambled per pixel where all its directions come from one
//! lobe ([`single_lobe`]), so that the pixel's hits share one stratification, as the cosine rays
//! of `directions` do), so both sets stay
//! stratified; a random lobe choice per ray would add noise for nothing. When both lobes
//! exist and N ≥ 2, each gets at least one direction; with N = 1 the lobe is chosen by a hash
//! with probability P_s and the one-sample mixture weight is used.
//!
//! A direction below the geometric normal at o (or below the shading horizon) has weight 0
//! and no ray, as the tracer never traces it; it still counts as a sample of the estimate.

use glam::Vec3;

use super::disc::Ray;
use super::samples::PrimaryShading;
use shading::sampling::{hash_u32, sobol_2d_scrambled, to_unit_float};

/// One direction of the estimate: its weight f·cos/p and, unless it points below the surface,
/// the ray to reconstruct.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightedRay {
    pub ray: Option<Ray>,
    pub weight: [f32; 3],
}

/// How many of `per_hit` directions go to the specular lobe, and the lobe fractions the
/// mixture density uses.
fn lobe_split(specular_probability: f32, per_hit: u32, scramble: u32) -> (u32, [f32; 2]) {
    let p = specular_probability.clamp(0.0, 1.0);
    if p <= 0.0 || p >= 1.0 || per_hit >= 2 {
        let n_spec = if p <= 0.0 {
            0
        } else if p >= 1.0 {
            per_hit
        } else {
            ((per_hit as f32 * p).round() as u32).clamp(1, per_hit - 1)
        };
        let fraction = n_spec as f32 / per_hit as f32;
        return (n_spec, [fraction, 1.0 - fraction]);
    }
    // One ray, both lobes: the one-sample mixture.
    let u = to_unit_float(hash_u32(scramble ^ 0x1319_8a2e));
    ((u < p) as u32, [p, 1.0 - p])
}

/// Whether all `per_hit` directions of the hit come from one lobe (a pure metal, a Lambertian
/// surface, or a view from below): only then are a pixel's hits given consecutive blocks of one
/// sequence. With both lobes each hit's lobe takes a prefix of its block, and the prefixes of
/// aligned blocks of a scrambled (0, 2)-sequence all lie in the same strip of the square (the
/// points k·N of the sequence share their leading digits), so the pixel's specular directions
/// would cluster: measured 3× the error of one set per hit (`pipeline.rs`,
/// `glossy_hits_of_a_pixel_share_one_stratified_set_per_lobe`).
pub fn single_lobe(primary: &PrimaryShading, normal: [f32; 3], per_hit: u32) -> bool {
    let frame = shading::Frame::new(Vec3::from(normal));
    let wo = frame.to_local(Vec3::from(primary.to_eye));
    if wo.z <= 0.0 || per_hit < 2 {
        return true;
    }
    let (n_spec, _) = lobe_split(primary.bsdf.specular_probability(wo), per_hit, 0);
    n_spec == 0 || n_spec == per_hit
}

/// The `per_hit` weighted rays of a primary hit at `origin` with unit shading `normal` (facing
/// the camera): rays start at origin + offset·normal. `scramble` seeds the directions; each
/// lobe's directions are its sequence's points `first`, `first` + 1, … (see the module
/// documentation), and with one ray the lobe is drawn by a hash of `scramble` and `first`.
pub fn bsdf_rays(
    primary: &PrimaryShading,
    origin: [f32; 3],
    normal: [f32; 3],
    (first, per_hit): (u32, u32),
    scramble: u32,
    offset: f32,
) -> impl Iterator<Item = WeightedRay> + '_ {
    let frame = shading::Frame::new(Vec3::from(normal));
    let wo = frame.to_local(Vec3::from(primary.to_eye));
    let bsdf = &primary.bsdf;
    let (n_spec, fractions) =
        if wo.z > 0.0 { lobe_split(bsdf.specular_probability(wo), per_hit, scramble ^ first) } else { (0, [0.0, 1.0]) };
    let start = [0, 1, 2].map(|a| origin[a] + offset * normal[a]);
    let geometric = Vec3::from(primary.geometric_normal);
    let (spec_scramble, diffuse_scramble) = (hash_u32(scramble ^ 0x4528_21e6), hash_u32(scramble ^ 0x38d0_1377));
    (0..per_hit).map(move |j| {
        let local = if j < n_spec {
            let (u, v) = sobol_2d_scrambled(first.wrapping_add(j), spec_scramble);
            bsdf.sample_specular(wo, [u, v])
        } else {
            let (u, v) = sobol_2d_scrambled(first.wrapping_add(j - n_spec), diffuse_scramble);
            shading::sample_cosine_hemisphere([u, v])
        };
        let world = frame.to_world(local).normalize_or_zero();
        let [p_spec, p_diffuse] = bsdf.lobe_pdfs(wo, local);
        let mixture = fractions[0] * p_spec + fractions[1] * p_diffuse;
        let above = wo.z > 0.0 && local.z > 0.0 && world.dot(geometric) > 0.0 && mixture > 0.0;
        let weight = if above { bsdf.eval(wo, local) / mixture } else { Vec3::ZERO };
        if !(above && weight.is_finite()) {
            return WeightedRay { ray: None, weight: [0.0; 3] };
        }
        WeightedRay {
            ray: Some(Ray { time: 0.0, origin: start, direction: world.to_array() }),
            weight: weight.to_array(),
        }
    })
}

/// The directional albedo of `bsdf` towards `wo` (local) by the BSDF's own one-sample mixture
/// (`Bsdf::sample`) over `n` directions: the tests' independent estimate of what the gather's
/// lobe split must average to.
#[cfg(test)]
pub(crate) fn mixture_albedo(bsdf: &shading::Bsdf, wo: Vec3, n: u32) -> Vec3 {
    let mut sum = Vec3::ZERO;
    for i in 0..n {
        let (u, v) = sobol_2d_scrambled(i, 99);
        let u_lobe = to_unit_float(hash_u32(i ^ 0x51ed_270b));
        if let Some(s) = bsdf.sample(wo, u_lobe, [u, v]) {
            sum += s.weight;
        }
    }
    sum / n as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn primary(bsdf: shading::Bsdf, to_eye: [f32; 3]) -> PrimaryShading {
        PrimaryShading { bsdf, geometric_normal: [0.0, 0.0, 1.0], to_eye }
    }

    fn view(theta: f32) -> [f32; 3] {
        [theta.sin(), 0.0, theta.cos()]
    }

    /// Under constant incident radiance 1 the gather's mean weight is the directional albedo,
    /// which the tracer's one-sample mixture estimates independently.
    #[test]
    fn the_mean_weight_is_the_directional_albedo() {
        for (roughness, metallic, specular) in
            [(0.3f32, 1.0f32, 1.0f32), (0.6, 0.0, 1.0), (1e-3, 0.5, 1.0), (1.0, 0.0, 0.0)]
        {
            let bsdf = shading::Bsdf::new(Vec3::new(0.9, 0.6, 0.3), metallic, roughness, specular);
            for theta in [0.1f32, 0.8, 1.4] {
                let p = primary(bsdf, view(theta));
                let n = 1 << 14;
                let mut sum = [0.0f64; 3];
                for r in bsdf_rays(&p, [0.0; 3], [0.0, 0.0, 1.0], (0, n), 7, 0.0) {
                    for (total, w) in sum.iter_mut().zip(r.weight) {
                        *total += w as f64;
                    }
                }
                let mean = Vec3::new(sum[0] as f32, sum[1] as f32, sum[2] as f32) / n as f32;
                let wo = Vec3::from(view(theta));
                let reference = mixture_albedo(&bsdf, wo, 1 << 16);
                assert!(
                    (mean - reference).abs().max_element() < 0.01,
                    "r {roughness} m {metallic} θ {theta}: {mean} vs {reference}"
                );
            }
        }
    }

    #[test]
    fn a_lambertian_hit_gets_cosine_rays_weighted_by_its_albedo() {
        let bsdf = shading::Bsdf::new(Vec3::new(0.2, 0.5, 0.8), 0.0, 1.0, 0.0);
        let p = primary(bsdf, view(0.4));
        for r in bsdf_rays(&p, [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], (0, 64), 3, 0.5) {
            let ray = r.ray.expect("every cosine direction is above the surface");
            assert_eq!(ray.origin, [1.0, 2.0, 3.5]);
            assert!((Vec3::from(r.weight) - Vec3::new(0.2, 0.5, 0.8)).abs().max_element() < 1e-5, "{:?}", r.weight);
        }
    }

    #[test]
    fn directions_below_the_geometric_normal_weigh_nothing() {
        // The shading normal leans 60° away from the geometric one: about a quarter of the cosine
        // lobe about it lies below the geometric surface.
        let bsdf = shading::Bsdf::new(Vec3::splat(0.5), 0.0, 1.0, 0.0);
        let mut p = primary(bsdf, view(0.0));
        let shading_normal = view(std::f32::consts::FRAC_PI_3);
        p.to_eye = shading_normal;
        let rays: Vec<_> = bsdf_rays(&p, [0.0; 3], shading_normal, (0, 1024), 5, 0.0).collect();
        let below = rays.iter().filter(|r| r.ray.is_none()).count();
        assert!(below > 100 && below < 500, "{below}");
        for r in &rays {
            match r.ray {
                Some(ray) => assert!(ray.direction[2] > 0.0),
                None => assert_eq!(r.weight, [0.0; 3]),
            }
        }
    }

    #[test]
    fn a_mirror_sends_its_rays_to_the_reflection_and_stays_finite() {
        let bsdf = shading::Bsdf::new(Vec3::ONE, 1.0, 0.0, 1.0);
        let p = primary(bsdf, view(0.5));
        let mirror = Vec3::new(-0.5f32.sin(), 0.0, 0.5f32.cos());
        let rays: Vec<_> = bsdf_rays(&p, [0.0; 3], [0.0, 0.0, 1.0], (0, 16), 1, 0.0).collect();
        for r in &rays {
            let ray = r.ray.expect("a mirror reflects above the surface");
            assert!((Vec3::from(ray.direction) - mirror).length() < 1e-3);
            assert!(r.weight.iter().all(|w| w.is_finite() && *w > 0.9 && *w <= 1.0 + 1e-3), "{:?}", r.weight);
        }
    }

    #[test]
    fn a_view_from_below_the_surface_or_a_nan_view_reflects_nothing() {
        // ωo below the shading horizon (a shading normal bent past the viewer) or not a number:
        // no ray and weight 0, as the tracer draws no direction there.
        let bsdf = shading::Bsdf::new(Vec3::splat(0.8), 0.5, 0.4, 1.0);
        for to_eye in [[0.0, 0.6, -0.8], [f32::NAN, 0.0, 1.0]] {
            let p = primary(bsdf, to_eye);
            for r in bsdf_rays(&p, [0.0; 3], [0.0, 0.0, 1.0], (0, 16), 2, 0.0) {
                assert_eq!((r.ray, r.weight), (None, [0.0; 3]), "{to_eye:?}");
            }
        }
    }

    #[test]
    fn the_split_gives_each_lobe_a_ray_and_one_ray_picks_by_probability() {
        assert_eq!(lobe_split(0.0, 8, 1), (0, [0.0, 1.0]));
        assert_eq!(lobe_split(1.0, 8, 1), (8, [1.0, 0.0]));
        assert_eq!(lobe_split(0.1, 4, 1).0, 1, "at least one specular ray");
        assert_eq!(lobe_split(0.9, 4, 1).0, 3, "at least one diffuse ray");
        assert_eq!(lobe_split(0.3, 10, 1), (3, [0.3, 0.7]));
        let specular = (0..10_000u32).filter(|&s| lobe_split(0.3, 1, s).0 == 1).count();
        assert!((specular as f32 / 10_000.0 - 0.3).abs() < 0.02, "{specular}");
        assert_eq!(lobe_split(0.3, 1, 5).1, [0.3, 0.7]);
    }
}
