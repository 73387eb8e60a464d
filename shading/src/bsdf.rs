//! The metallic-roughness BSDF: Lambertian diffuse plus a GGX microfacet specular lobe with
//! height-correlated Smith masking-shadowing and Schlick Fresnel, combined as the glTF 2.0
//! specification's appendix B does, except that the diffuse layer is weighted by the Fresnel
//! term at ωo·n instead of ωo·h so that a white dielectric never reflects more than it receives:
//!
//! f = (1 − m)(1 − F_d(ωo·n)) · base/π + [(1 − m) F_d(ωo·h) + m F_m(ωo·h)] · D G₂ / (4 |ωo·n| |ωi·n|)
//!
//! with F_d = s · Schlick(F0, ·), F0 = ((ior − 1)/(ior + 1))² (0.04 by default), for the dielectric (s is the material's specular factor,
//! 1 in glTF, 0 for a pure Lambertian surface) and F_m = Schlick(base, ωo·h) for the metal.
//! The surface is two-sided: callers pass directions in a local frame whose +z is the shading
//! normal flipped towards ωo.
//!
//! Numerical care: D is evaluated as α² / (π (h_x² + h_y² + α² h_z²)²), which stays finite and
//! accurate down to α = 1e-6 (roughness 1e-3), where the textbook form
//! ((n·h)²(α² − 1) + 1) cancels to zero in f32. Specular directions are drawn from the
//! distribution of visible normals (Heitz 2018), so f·cos/pdf = F G₂/G₁ never divides by D.

use std::f32::consts::{FRAC_1_PI, PI};

use glam::Vec3;

/// Smallest GGX alpha used: roughness 1e-3 squared.
pub const MIN_ALPHA: f32 = 1e-6;

/// Shading parameters at one surface point, after texture lookups.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bsdf {
    pub base_color: Vec3,
    pub metallic: f32,
    /// GGX alpha (perceptual roughness squared), clamped to [MIN_ALPHA, 1].
    pub alpha: f32,
    /// Dielectric specular weight (1 for glTF materials, 0 for pure Lambertian).
    pub specular: f32,
    /// Dielectric reflectance at normal incidence, ((ior − 1)/(ior + 1))².
    pub f0: f32,
}

/// A direction drawn from the BSDF.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Incident direction in the local frame.
    pub wi: Vec3,
    /// f(ωo, ωi) · |cos θi| / pdf.
    pub weight: Vec3,
    /// Solid-angle density of `wi` under the mixture that drew it.
    pub pdf: f32,
}

#[inline]
fn schlick_weight(cos_theta: f32) -> f32 {
    let m = (1.0 - cos_theta).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

#[inline]
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// GGX normal distribution for a local half vector (z up).
#[inline]
pub fn ggx_d(h: Vec3, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let denom = h.x * h.x + h.y * h.y + a2 * h.z * h.z;
    if h.z <= 0.0 || denom <= 0.0 {
        return 0.0;
    }
    a2 / (PI * denom * denom)
}

/// Smith Λ for a local direction.
#[inline]
fn smith_lambda(w: Vec3, alpha: f32) -> f32 {
    let cos2 = w.z * w.z;
    if cos2 <= 0.0 {
        return f32::INFINITY;
    }
    let sin2 = (w.x * w.x + w.y * w.y).max(0.0);
    let t = alpha * alpha * sin2 / cos2;
    // (-1 + sqrt(1 + t)) / 2, written without cancellation for small t.
    0.5 * t / (1.0 + (1.0 + t).sqrt())
}

#[inline]
pub fn smith_g1(w: Vec3, alpha: f32) -> f32 {
    1.0 / (1.0 + smith_lambda(w, alpha))
}

#[inline]
pub fn smith_g2(wo: Vec3, wi: Vec3, alpha: f32) -> f32 {
    1.0 / (1.0 + smith_lambda(wo, alpha) + smith_lambda(wi, alpha))
}

/// Samples a visible normal for `wo` (Heitz 2018, "Sampling the GGX Distribution of Visible
/// Normals").
fn sample_visible_normal(wo: Vec3, alpha: f32, u: [f32; 2]) -> Vec3 {
    let vh = Vec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let len2 = vh.x * vh.x + vh.y * vh.y;
    let t1 = if len2 > 0.0 { Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt() } else { Vec3::X };
    let t2 = vh.cross(t1);
    let r = u[0].sqrt();
    let phi = 2.0 * PI * u[1];
    let p1 = r * phi.cos();
    let mut p2 = r * phi.sin();
    let s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
    let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).normalize()
}

#[inline]
fn reflect(wo: Vec3, h: Vec3) -> Vec3 {
    2.0 * wo.dot(h) * h - wo
}

impl Bsdf {
    /// glTF parameters with the default dielectric (ior 1.5, F0 = 0.04).
    pub fn new(base_color: Vec3, metallic: f32, roughness: f32, specular: f32) -> Bsdf {
        Bsdf::with_ior(base_color, metallic, roughness, specular, 1.5)
    }

    pub fn with_ior(base_color: Vec3, metallic: f32, roughness: f32, specular: f32, ior: f32) -> Bsdf {
        let roughness = if roughness.is_finite() { roughness.clamp(0.0, 1.0) } else { 1.0 };
        let ior = if ior.is_finite() { ior.max(1.0) } else { 1.5 };
        let r = (ior - 1.0) / (ior + 1.0);
        Bsdf {
            base_color: base_color.max(Vec3::ZERO),
            metallic: metallic.clamp(0.0, 1.0),
            alpha: (roughness * roughness).max(MIN_ALPHA),
            specular: specular.clamp(0.0, 1.0),
            f0: r * r,
        }
    }

    /// Weight of the diffuse lobe before Fresnel: (1 − m) · base.
    #[inline]
    fn diffuse_color(&self) -> Vec3 {
        self.base_color * (1.0 - self.metallic)
    }

    /// (dielectric Fresnel, metal Fresnel) at cos(ωo·h).
    #[inline]
    fn fresnel(&self, cos_oh: f32) -> (f32, Vec3) {
        let w = schlick_weight(cos_oh);
        let f_dielectric = self.specular * (self.f0 + (1.0 - self.f0) * w);
        let f_metal = self.base_color + (Vec3::ONE - self.base_color) * w;
        (f_dielectric, f_metal)
    }

    /// Whether the BSDF has a specular lobe at all.
    #[inline]
    fn has_specular(&self) -> bool {
        self.metallic > 0.0 || self.specular > 0.0
    }

    /// Probability with which `sample` draws from the specular lobe for this ωo: the lobes'
    /// reflectance estimates, clamped to [0.1, 0.9] when both exist; 0 without a specular lobe,
    /// 1 without a diffuse one.
    pub fn specular_probability(&self, wo: Vec3) -> f32 {
        if !self.has_specular() {
            return 0.0;
        }
        let (fd, fm) = self.fresnel(wo.z.abs());
        let spec = (1.0 - self.metallic) * fd + self.metallic * luminance(fm);
        let diff = luminance(self.diffuse_color()) * (1.0 - fd);
        if diff <= 0.0 {
            return 1.0;
        }
        (spec / (spec + diff)).clamp(0.1, 0.9)
    }

    /// Whether the specular lobe reflects more than the diffuse one at normal incidence (a
    /// metal, or a dielectric coat over a dark base): the rule by which a surface counts as
    /// glossy for the sample format's bandwidth κ and for the methods that carry diffuse light
    /// only (the probes).
    pub fn specular_outweighs_diffuse(&self) -> bool {
        let specular = (1.0 - self.metallic) * self.specular * self.f0 + self.metallic * luminance(self.base_color);
        let diffuse = (1.0 - self.metallic) * (1.0 - self.specular * self.f0) * luminance(self.base_color);
        specular > diffuse
    }

    /// Diffuse albedo for the albedo AOV: what the surface reflects at normal incidence.
    pub fn albedo(&self) -> Vec3 {
        let (fd, fm) = self.fresnel(1.0);
        self.diffuse_color() * (1.0 - fd) + Vec3::splat((1.0 - self.metallic) * fd) + fm * self.metallic
    }

    /// f(ωo, ωi) · |cos θi|, both directions local with ωo in the upper hemisphere.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        if !self.has_specular() {
            // Pure Lambertian: no Fresnel, no half vector.
            return self.diffuse_color() * (FRAC_1_PI * wi.z);
        }
        let h = (wo + wi).normalize_or_zero();
        if h == Vec3::ZERO {
            return Vec3::ZERO;
        }
        let cos_oh = wo.dot(h).max(0.0);
        let (fd, fm) = self.fresnel(cos_oh);
        // The diffuse layer gets what the specular layer does not reflect for this ωo:
        // 1 − F_d(ωo·n). (glTF's 1 − F_d(ωo·h) over-counts at grazing angles: with a smooth
        // coat, diffuse directions have ωo·h near 1 while the coat reflects F(ωo·n) ≈ 0.5.)
        let (fd_normal, _) = self.fresnel(wo.z);
        let diffuse = self.diffuse_color() * ((1.0 - fd_normal) * FRAC_1_PI * wi.z);
        let dv = ggx_d(h, self.alpha) * smith_g2(wo, wi, self.alpha) / (4.0 * wo.z);
        let spec_color = Vec3::splat((1.0 - self.metallic) * fd) + fm * self.metallic;
        diffuse + spec_color * dv
    }

    /// Solid-angle density with which `sample` draws ωi.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let p_spec = self.specular_probability(wo);
        let [pdf_spec, pdf_diffuse] = self.lobe_pdfs(wo, wi);
        if p_spec == 0.0 {
            return pdf_diffuse;
        }
        p_spec * pdf_spec + (1.0 - p_spec) * pdf_diffuse
    }

    /// Solid-angle densities of ωi under each lobe's sampling alone: [specular (visible
    /// normals), diffuse (cosine)], 0 below either horizon. A caller that draws a fixed number
    /// of directions from each lobe weights them with these (multi-sample MIS, balance heuristic).
    pub fn lobe_pdfs(&self, wo: Vec3, wi: Vec3) -> [f32; 2] {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return [0.0; 2];
        }
        let pdf_diffuse = wi.z * FRAC_1_PI;
        if !self.has_specular() {
            return [0.0, pdf_diffuse];
        }
        let h = (wo + wi).normalize_or_zero();
        let pdf_spec =
            if h == Vec3::ZERO { 0.0 } else { smith_g1(wo, self.alpha) * ggx_d(h, self.alpha) / (4.0 * wo.z) };
        [pdf_spec, pdf_diffuse]
    }

    /// A direction from the specular lobe alone (visible normals, reflected), for `lobe_pdfs`;
    /// it may lie below the horizon (then `eval` and both densities are 0).
    pub fn sample_specular(&self, wo: Vec3, u: [f32; 2]) -> Vec3 {
        reflect(wo, sample_visible_normal(wo, self.alpha, u))
    }

    /// Draws ωi for ωo from the lobe mixture.
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: [f32; 2]) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let p_spec = self.specular_probability(wo);
        let wi = if u_lobe < p_spec { self.sample_specular(wo, u) } else { crate::warp::sample_cosine_hemisphere(u) };
        if wi.z <= 0.0 {
            return None;
        }
        let pdf = self.pdf(wo, wi);
        if !(pdf > 0.0) || !pdf.is_finite() {
            return None;
        }
        let weight = self.eval(wo, wi) / pdf;
        if !weight.is_finite() {
            return None;
        }
        Some(BsdfSample { wi, weight, pdf })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_points::hammersley;

    fn direction(theta: f32) -> Vec3 {
        Vec3::new(theta.sin(), 0.0, theta.cos())
    }

    /// At normal incidence a dielectric coat reflects f0 = ((ior − 1)/(ior + 1))² = 0.04 for
    /// ior 1.5, and a metal its base colour: the specular lobe outweighs the diffuse one for a
    /// metal, for a coat over a base darker than 0.04 / 0.96, and for neither otherwise.
    #[test]
    fn the_specular_lobe_outweighs_the_diffuse_one_for_metals_and_coats_over_dark_bases() {
        assert!(Bsdf::new(Vec3::splat(0.9), 1.0, 0.5, 1.0).specular_outweighs_diffuse());
        assert!(!Bsdf::new(Vec3::splat(0.9), 0.0, 0.5, 0.0).specular_outweighs_diffuse());
        assert!(!Bsdf::new(Vec3::splat(0.9), 0.0, 0.5, 1.0).specular_outweighs_diffuse(), "a coat over white");
        let edge = 0.04 / 0.96;
        assert!(Bsdf::new(Vec3::splat(0.9 * edge), 0.0, 0.5, 1.0).specular_outweighs_diffuse());
        assert!(!Bsdf::new(Vec3::splat(1.1 * edge), 0.0, 0.5, 1.0).specular_outweighs_diffuse());
        assert!(!Bsdf::new(Vec3::ZERO, 0.0, 0.5, 0.0).specular_outweighs_diffuse(), "black, no lobe at all");
    }

    /// Directional albedo ∫ f cos dωi by BSDF importance sampling.
    fn albedo_importance(bsdf: &Bsdf, wo: Vec3, n: u32) -> Vec3 {
        let mut sum = Vec3::ZERO;
        for i in 0..n {
            let [u_lobe, u0, u1] = hammersley(i, n);
            if let Some(sample) = bsdf.sample(wo, u_lobe, [u0, u1]) {
                sum += sample.weight;
            }
        }
        sum / n as f32
    }

    /// The same integral by uniform hemisphere sampling: an independent estimator.
    fn albedo_uniform(bsdf: &Bsdf, wo: Vec3, n: u32) -> Vec3 {
        let mut sum = Vec3::ZERO;
        for i in 0..n {
            let [_, u0, u1] = hammersley(i, n);
            let u = [u0, u1];
            let z = u[0];
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = 2.0 * PI * u[1];
            let wi = Vec3::new(r * phi.cos(), r * phi.sin(), z);
            sum += bsdf.eval(wo, wi) * (2.0 * PI);
        }
        sum / n as f32
    }

    #[test]
    fn lambertian_albedo_equals_base_colour() {
        let bsdf = Bsdf::new(Vec3::new(0.2, 0.5, 0.9), 0.0, 1.0, 0.0);
        for theta in [0.0f32, 0.7, 1.4] {
            let a = albedo_importance(&bsdf, direction(theta), 4096);
            assert!((a - bsdf.base_color).abs().max_element() < 1e-4, "{a}");
        }
    }

    #[test]
    fn ggx_white_metal_conserves_energy_and_loses_little_when_smooth() {
        for roughness in [1e-3f32, 0.05, 0.2, 0.5, 0.8, 1.0] {
            let bsdf = Bsdf::new(Vec3::ONE, 1.0, roughness, 1.0);
            for theta in [0.0f32, 0.5, 1.0, 1.3, 1.5] {
                let a = albedo_importance(&bsdf, direction(theta), 8192).x;
                assert!(a.is_finite() && a <= 1.0 + 1e-3, "roughness {roughness} theta {theta}: {a}");
                // Single-scattering GGX loses energy with roughness, most at alpha = 1.
                assert!(a > 0.25, "roughness {roughness} theta {theta}: {a}");
                if roughness <= 0.05 && theta < 1.0 {
                    assert!(a > 0.99, "smooth metal must reflect almost everything: {a}");
                }
            }
        }
    }

    #[test]
    fn roughest_ggx_at_normal_incidence_matches_the_closed_form() {
        // At alpha = 1, D = 1/π and G₂ = 2 cosθi / (1 + cosθi) for ωo = n, so the albedo of a
        // white metal is (1/4π) ∫ G₂ dω = 1 − ln 2.
        let bsdf = Bsdf::new(Vec3::ONE, 1.0, 1.0, 1.0);
        let a = albedo_importance(&bsdf, Vec3::Z, 1 << 15).x;
        assert!((a - (1.0 - std::f32::consts::LN_2)).abs() < 2e-3, "{a}");
        let b = albedo_uniform(&bsdf, Vec3::Z, 1 << 16).x;
        assert!((b - (1.0 - std::f32::consts::LN_2)).abs() < 2e-3, "{b}");
    }

    #[test]
    fn importance_and_uniform_estimators_agree() {
        for (roughness, metallic) in [(0.3f32, 1.0f32), (0.6, 0.0), (1.0, 0.5)] {
            let bsdf = Bsdf::new(Vec3::new(0.9, 0.6, 0.3), metallic, roughness, 1.0);
            for theta in [0.2f32, 1.0] {
                let wo = direction(theta);
                let a = albedo_importance(&bsdf, wo, 1 << 14);
                let b = albedo_uniform(&bsdf, wo, 1 << 16);
                assert!((a - b).abs().max_element() < 0.01, "r {roughness} m {metallic} θ {theta}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn a_fixed_split_between_the_lobes_with_balance_weights_gives_the_albedo() {
        // n_s directions from the specular lobe, n_d from the diffuse one, each weighted
        // f·cos / ((n_s/N) p_s + (n_d/N) p_d): the one-sample mixture estimator's albedo for any
        // split (uniform hemisphere sampling misses the narrow lobe of roughness 0.05).
        for (roughness, metallic) in [(0.3f32, 1.0f32), (0.6, 0.0), (0.05, 0.5)] {
            let bsdf = Bsdf::new(Vec3::new(0.9, 0.6, 0.3), metallic, roughness, 1.0);
            let wo = direction(0.7);
            let expected = albedo_importance(&bsdf, wo, 1 << 16);
            for (n_spec, n_diffuse) in [(1u32 << 13, 1u32 << 13), (1 << 14, 1 << 12)] {
                let n = (n_spec + n_diffuse) as f32;
                let weight = |wi: Vec3| {
                    let [p_spec, p_diffuse] = bsdf.lobe_pdfs(wo, wi);
                    let mixture = (n_spec as f32 * p_spec + n_diffuse as f32 * p_diffuse) / n;
                    if mixture > 0.0 {
                        bsdf.eval(wo, wi) / mixture
                    } else {
                        Vec3::ZERO
                    }
                };
                let mut sum = Vec3::ZERO;
                for i in 0..n_spec {
                    let [_, u0, u1] = hammersley(i, n_spec);
                    sum += weight(bsdf.sample_specular(wo, [u0, u1]));
                }
                for i in 0..n_diffuse {
                    let [_, u0, u1] = hammersley(i, n_diffuse);
                    sum += weight(crate::warp::sample_cosine_hemisphere([u0, u1]));
                }
                let estimate = sum / n;
                assert!(
                    (estimate - expected).abs().max_element() < 0.01,
                    "r {roughness} m {metallic} split {n_spec}/{n_diffuse}: {estimate} vs {expected}"
                );
            }
        }
    }

    #[test]
    fn dielectric_with_white_base_never_exceeds_one() {
        for roughness in [1e-3f32, 0.1, 0.5, 1.0] {
            let bsdf = Bsdf::new(Vec3::ONE, 0.0, roughness, 1.0);
            for theta in [0.0f32, 0.8, 1.45] {
                let a = albedo_importance(&bsdf, direction(theta), 8192);
                assert!(a.max_element() <= 1.0 + 2e-3, "roughness {roughness} theta {theta}: {a}");
            }
        }
    }

    #[test]
    fn pdf_integrates_to_one_over_the_hemisphere() {
        let bsdf = Bsdf::new(Vec3::splat(0.5), 0.3, 0.4, 1.0);
        let wo = direction(0.6);
        let n = 1 << 16;
        let mut sum = 0.0f64;
        for i in 0..n {
            let [_, u0, u1] = hammersley(i, n);
            let u = [u0, u1];
            let z = u[0];
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = 2.0 * PI * u[1];
            sum += bsdf.pdf(wo, Vec3::new(r * phi.cos(), r * phi.sin(), z)) as f64 * 2.0 * PI as f64;
        }
        // Some specular mass reflects below the horizon and is rejected: the integral is <= 1.
        let integral = sum / n as f64;
        assert!(integral <= 1.0 + 5e-3 && integral > 0.95, "{integral}");
    }

    #[test]
    fn near_mirror_is_finite_and_matches_the_mirror_direction() {
        let bsdf = Bsdf::new(Vec3::ONE, 1.0, 1e-3, 1.0);
        let wo = direction(0.5).normalize();
        let s = bsdf.sample(wo, 0.0, [0.3, 0.7]).expect("sample");
        let mirror = Vec3::new(-wo.x, -wo.y, wo.z);
        assert!((s.wi - mirror).length() < 1e-4);
        assert!(s.weight.is_finite() && s.pdf.is_finite());
        assert!(bsdf.eval(wo, mirror).is_finite());
        assert!(ggx_d(Vec3::Z, bsdf.alpha).is_finite());
    }

    #[test]
    fn below_horizon_gives_zero() {
        let bsdf = Bsdf::new(Vec3::ONE, 0.5, 0.5, 1.0);
        let wo = direction(0.3);
        assert_eq!(bsdf.eval(wo, Vec3::new(0.0, 0.0, -1.0)), Vec3::ZERO);
        assert_eq!(bsdf.pdf(Vec3::new(0.0, 0.3, -1.0).normalize(), Vec3::Z), 0.0);
    }
}
