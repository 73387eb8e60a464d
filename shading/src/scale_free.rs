//! Normals, areas and unit vectors that hold at any scene scale.
//!
//! The plain (b − a) × (c − a) overflows f32 once the edges pass about 1.3e19 / √2 per pair
//! (its squared length, needed to normalise it, already at edges of about 4e9): a floor 6e9
//! long had a zero normal, so its paths started on the surface and shadowed themselves (a
//! scene at ×1e9 rendered 57 % dark). At ×1e-6 and below the squared length underflows the
//! same way. Scaling both edges by a power of two that brings their largest component near 1
//! is exact, so at ordinary scales the results are bit for bit those of the plain formula.

use glam::Vec3;

/// The power of two that brings `magnitude` (> 0, finite) into [1, 2), and its inverse.
/// Clamped to f32's normal exponents; a subnormal magnitude keeps some scaling.
fn power_of_two_scale(magnitude: f32) -> (f32, f32) {
    let exponent = magnitude.log2().floor().clamp(-126.0, 127.0);
    ((-exponent).clamp(-126.0, 127.0).exp2(), exponent.exp2())
}

/// `v` normalised, for any finite magnitude (`normalize_or_zero` squares it first, so a vector
/// longer than about 1.8e19 or shorter than about 1e-19 became zero). Zero for a zero or
/// non-finite vector; bit for bit `v.normalize_or_zero()` at ordinary magnitudes.
pub fn normalize_any_scale(v: Vec3) -> Vec3 {
    let magnitude = v.abs().max_element();
    if !(magnitude > 0.0) || !magnitude.is_finite() {
        return Vec3::ZERO;
    }
    (v * power_of_two_scale(magnitude).0).normalize_or_zero()
}

/// The unit normal of the triangle (a, b, c) in winding order ((b − a) × (c − a) normalised)
/// and its area. A degenerate or non-finite triangle gives (0, 0).
pub fn triangle_normal_and_area(a: Vec3, b: Vec3, c: Vec3) -> (Vec3, f32) {
    let (edge_b, edge_c) = (b - a, c - a);
    let magnitude = edge_b.abs().max_element().max(edge_c.abs().max_element());
    if !(magnitude > 0.0) || !magnitude.is_finite() {
        return (Vec3::ZERO, 0.0);
    }
    let (scale, unscale) = power_of_two_scale(magnitude);
    let cross = (edge_b * scale).cross(edge_c * scale);
    let length = cross.length();
    if !(length > 0.0) || !length.is_finite() {
        return (Vec3::ZERO, 0.0);
    }
    (cross / length, 0.5 * length * unscale * unscale)
}

/// (b − a) × (c − a) of each of a set of triangles, all scaled by one power of two chosen from
/// `extent` (the largest coordinate magnitude involved), so that their relative lengths (area
/// weights) are kept and neither overflow nor underflow at any scene scale.
pub fn scaled_cross(a: Vec3, b: Vec3, c: Vec3, extent: f32) -> Vec3 {
    let scale = if extent > 0.0 && extent.is_finite() { power_of_two_scale(extent).0 } else { 1.0 };
    ((b - a) * scale).cross((c - a) * scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordinary_triangles_match_the_plain_formula_bit_for_bit() {
        let triangles = [
            (Vec3::new(0.1, 0.2, 0.3), Vec3::new(1.7, -0.4, 0.9), Vec3::new(-0.3, 2.2, 0.05)),
            (Vec3::new(278.0, 548.8, 0.0), Vec3::new(556.0, 548.8, 559.2), Vec3::new(0.0, 548.8, 559.2)),
            (Vec3::new(1e-3, 0.0, 0.0), Vec3::new(0.0, 1e-3, 0.0), Vec3::new(0.0, 0.0, 1e-3)),
        ];
        for (a, b, c) in triangles {
            let cross = (b - a).cross(c - a);
            let (normal, area) = triangle_normal_and_area(a, b, c);
            assert_eq!(normal, cross / cross.length());
            assert_eq!(area, 0.5 * cross.length());
        }
    }

    #[test]
    fn the_normal_holds_from_1e_minus_30_to_1e19_and_the_area_where_f32_holds_it() {
        // A right triangle in the xz-plane with legs 2s (along z) and s (along x): (2s·z) × (s·x)
        // points along +y, area s².
        for s in [1e-30f32, 1e-19, 1e-6, 1.0, 1e9, 1e12, 1e19] {
            let (a, b, c) = (Vec3::new(s, 0.0, 0.0), Vec3::new(s, 0.0, 2.0 * s), Vec3::new(2.0 * s, 0.0, 0.0));
            let (normal, area) = triangle_normal_and_area(a, b, c);
            assert!((normal - Vec3::Y).length() < 1e-6, "scale {s:e}: {normal}");
            let expected = s as f64 * s as f64;
            // The area itself leaves f32's range beyond about 1e±19 (then 0 or +inf).
            let representable = expected < f32::MAX as f64 && expected > f32::MIN_POSITIVE as f64;
            assert!(((area as f64) / expected - 1.0).abs() < 1e-6 || !representable, "{s:e}: {area}");
        }
    }

    #[test]
    fn degenerate_and_non_finite_triangles_have_no_normal() {
        let p = Vec3::new(1.0, 2.0, 3.0);
        assert_eq!(triangle_normal_and_area(p, p, p), (Vec3::ZERO, 0.0));
        assert_eq!(triangle_normal_and_area(p, 2.0 * p, 3.0 * p), (Vec3::ZERO, 0.0));
        assert_eq!(triangle_normal_and_area(p, Vec3::NAN, p), (Vec3::ZERO, 0.0));
        assert_eq!(triangle_normal_and_area(p, Vec3::splat(f32::INFINITY), Vec3::ZERO), (Vec3::ZERO, 0.0));
    }

    #[test]
    fn unit_vectors_at_any_magnitude() {
        let v = Vec3::new(3.0, -4.0, 12.0);
        for s in [1e-35f32, 1e-20, 1e-6, 1.0, 7.3, 1e9, 1e20, 1e37] {
            let unit = normalize_any_scale(v * s);
            assert!((unit - v / 13.0).length() < 1e-6, "{s:e}: {unit}");
        }
        for v in [Vec3::new(0.3, 0.1, -2.0), Vec3::new(278.0, 273.0, 800.0)] {
            assert_eq!(normalize_any_scale(v), v.normalize_or_zero());
        }
        assert_eq!(normalize_any_scale(Vec3::ZERO), Vec3::ZERO);
        assert_eq!(normalize_any_scale(Vec3::new(f32::NAN, 0.0, 1.0)), Vec3::ZERO);
    }

    #[test]
    fn scaled_crosses_keep_their_ratios() {
        let extent = 4e9;
        let small = scaled_cross(Vec3::ZERO, Vec3::new(1e9, 0.0, 0.0), Vec3::new(0.0, 1e9, 0.0), extent);
        let large = scaled_cross(Vec3::ZERO, Vec3::new(2e9, 0.0, 0.0), Vec3::new(0.0, 2e9, 0.0), extent);
        assert!(small.is_finite() && large.is_finite());
        assert!((large.z / small.z - 4.0).abs() < 1e-6);
        assert_eq!(scaled_cross(Vec3::ZERO, Vec3::X, Vec3::Y, 1.5), Vec3::Z);
    }
}
