//! Coverage and filtering of one apparent surface (paper Section 3.3, "Determining
//! visibility"): "a reconstruction location is covered if it is possible to find three
//! reprojected input samples that form a triangle that 1) covers the reconstruction location,
//! and 2) fits inside a circle of radius R. Let us call such triangles valid." Edges of a valid
//! triangle are at most 2R, so only samples within 2R of the location matter.
//!
//! - `enclosing_radius`: the radius of a triangle's smallest enclosing circle (half the longest
//!   edge for a right or obtuse triangle, the circumradius for an acute one). The authors' code
//!   accepts any triangle with edges ≤ 2R, which admits circumradii up to 2R/√3 ≈ 1.155 R; we
//!   use the exact rule (every Delaunay triangle of a pattern of dispersion R still qualifies).
//! - `covers`: the location inside or on the triangle, in f64 relative to the location;
//!   degenerate (collinear) triangles never cover.
//! - `is_covered`: the paper's early-out (samples of the surface within R in all four
//!   quadrants around the location: covered, see below; "one surface only: trivially covered"
//!   is the caller's) and the search over the valid triangles of the samples within 2R.
//! - `tent_filter`: "a circular tent filter" of radius R over the covering surface's samples;
//!   the nearest sample when none lies within R.
//!
//! The quadrant early-out: with a sample within R in each open quadrant around the location,
//! the four samples in angular order form a quadrilateral whose consecutive angular gaps are
//! below π, so it contains the location; an inner diagonal splits it into two triangles, one
//! containing the location. All their vertices lie within R of the location, so the circle of
//! radius R around it encloses the triangle, and its smallest enclosing circle is no larger:
//! the triangle is valid.

/// A reprojected sample on the screen, pixels.
pub type Point = [f32; 2];

/// The radius of the smallest circle enclosing the triangle (a, b, c).
pub fn enclosing_radius(a: Point, b: Point, c: Point) -> f32 {
    let d = |p: Point, q: Point| (p[0] as f64 - q[0] as f64).powi(2) + (p[1] as f64 - q[1] as f64).powi(2);
    let mut squares = [d(b, c), d(a, c), d(a, b)];
    squares.sort_by(f64::total_cmp);
    let [s0, s1, s2] = squares;
    if s2 >= s0 + s1 {
        // Right or obtuse (or degenerate): the longest edge is a diameter.
        return (0.5 * s2.sqrt()) as f32;
    }
    // Acute: the circumradius abc / (4 · area).
    let area2 = ((b[0] as f64 - a[0] as f64) * (c[1] as f64 - a[1] as f64)
        - (b[1] as f64 - a[1] as f64) * (c[0] as f64 - a[0] as f64))
        .abs();
    ((s0 * s1 * s2).sqrt() / (2.0 * area2)) as f32
}

/// Whether the triangle (a, b, c) contains `location` (edges inclusive). Degenerate triangles
/// (twice the area at most 1e-7 of the longest edge squared) contain nothing.
pub fn covers(a: Point, b: Point, c: Point, location: Point) -> bool {
    let rel = |p: Point| [p[0] as f64 - location[0] as f64, p[1] as f64 - location[1] as f64];
    let (a, b, c) = (rel(a), rel(b), rel(c));
    let cross = |p: [f64; 2], q: [f64; 2]| p[0] * q[1] - p[1] * q[0];
    let area2 = cross([b[0] - a[0], b[1] - a[1]], [c[0] - a[0], c[1] - a[1]]);
    let longest = [(a, b), (b, c), (c, a)]
        .iter()
        .map(|(p, q)| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
        .fold(0.0f64, f64::max);
    if area2.abs() <= 1e-7 * longest || longest == 0.0 {
        return false;
    }
    // The origin (the location) against each edge, oriented by the triangle's winding.
    let sides = [cross(a, b), cross(b, c), cross(c, a)];
    if area2 > 0.0 {
        sides.iter().all(|&s| s >= 0.0)
    } else {
        sides.iter().all(|&s| s <= 0.0)
    }
}

/// Statistics of the coverage searches.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CoverageStats {
    /// Decided by the quadrant early-out.
    pub quadrant_accepts: u64,
    /// Decided by searching triangles.
    pub triangle_searches: u64,
    /// Triangles tested (those whose edges are all at most 2R).
    pub triangles_tested: u64,
}

/// Whether the surface whose reprojected samples are `points` covers `location`, with radius
/// `radius`: the quadrant early-out, then a search over the valid triangles of the samples
/// within 2R. At most `max_candidates` samples (the nearest) enter the cubic search.
pub fn is_covered(
    points: &[Point],
    location: Point,
    radius: f32,
    max_candidates: usize,
    stats: &mut CoverageStats,
) -> bool {
    let r2 = radius * radius;
    let offset = |p: &Point| [p[0] - location[0], p[1] - location[1]];
    let mut quadrants = [false; 4];
    for p in points {
        let [dx, dy] = offset(p);
        if dx * dx + dy * dy <= r2 {
            // Open quadrants; a sample on an axis counts for neither side.
            if dx > 0.0 && dy > 0.0 {
                quadrants[0] = true;
            } else if dx < 0.0 && dy > 0.0 {
                quadrants[1] = true;
            } else if dx < 0.0 && dy < 0.0 {
                quadrants[2] = true;
            } else if dx > 0.0 && dy < 0.0 {
                quadrants[3] = true;
            }
        }
    }
    if quadrants.iter().all(|&q| q) {
        stats.quadrant_accepts += 1;
        return true;
    }
    stats.triangle_searches += 1;
    let mut near: Vec<(f32, Point)> = points
        .iter()
        .map(|p| {
            let [dx, dy] = offset(p);
            (dx * dx + dy * dy, *p)
        })
        .filter(|(d2, _)| *d2 <= 4.0 * r2)
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    near.truncate(max_candidates.clamp(3, 31));
    // An edge of a valid triangle is at most twice its enclosing radius, so at most 2R: pairs
    // farther apart (by a margin above f64's and f32's roundings) are never tested together.
    let limit = 4.0 * (radius as f64).powi(2) * (1.0 + 1e-5);
    let edges: Vec<u32> = near
        .iter()
        .map(|(_, p)| {
            near.iter().enumerate().fold(0u32, |bits, (k, (_, q))| {
                let d = (p[0] as f64 - q[0] as f64).powi(2) + (p[1] as f64 - q[1] as f64).powi(2);
                bits | (u32::from(d <= limit) << k)
            })
        })
        .collect();
    // Nearest first, so that the valid triangles (small ones near the location) come early.
    for i in 0..near.len() {
        for j in i + 1..near.len() {
            if edges[i] >> j & 1 == 0 {
                continue;
            }
            let mut third = edges[i] & edges[j] & !((2u32 << j) - 1);
            while third != 0 {
                let k = third.trailing_zeros() as usize;
                third &= third - 1;
                stats.triangles_tested += 1;
                let (a, b, c) = (near[i].1, near[j].1, near[k].1);
                if covers(a, b, c, location) && enclosing_radius(a, b, c) <= radius {
                    return true;
                }
            }
        }
    }
    false
}

/// The circular tent filter of radius `radius` around `location` over a surface's samples:
/// Σ wᵢ Lᵢ / Σ wᵢ with wᵢ = max(0, 1 − |pᵢ − location| / R); the nearest sample's value when
/// no sample lies within R; `None` for no samples. The result is a convex combination of the
/// inputs, so it stays within their range. Distances are compared squared and the square root
/// is only taken for the samples the tent reaches (about a quarter of those within 2R; the
/// filter was 17 % of a location's time with a root per sample); the weights are those of
/// the straightforward form (the test's oracle) bit for bit.
pub fn tent_filter(points: &[Point], values: &[[f32; 3]], location: Point, radius: f32) -> Option<[f32; 3]> {
    let mut sum = [0.0f64; 3];
    let mut weight_sum = 0.0f64;
    let mut nearest: Option<(f32, usize)> = None;
    // Slightly above R², so that every sample whose weight is positive in the straightforward
    // form (where √d² / R < 1 although d² ≥ fl(R²)) still gets it.
    let reach_squared = radius * radius * (1.0 + 1e-5);
    for (i, p) in points.iter().enumerate() {
        let squared = (p[0] - location[0]).powi(2) + (p[1] - location[1]).powi(2);
        if nearest.map_or(true, |(d, _)| squared < d) {
            nearest = Some((squared, i));
        }
        if squared > reach_squared || squared.is_nan() {
            continue;
        }
        let w = (1.0 - squared.sqrt() / radius).max(0.0) as f64;
        if w > 0.0 {
            weight_sum += w;
            for c in 0..3 {
                sum[c] += w * values[i][c] as f64;
            }
        }
    }
    if weight_sum > 0.0 {
        Some(sum.map(|s| (s / weight_sum) as f32))
    } else {
        nearest.map(|(_, i)| values[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enclosing_circles_of_known_triangles() {
        // Right isosceles, legs 1: half the hypotenuse.
        assert!((enclosing_radius([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]) - 0.5f32.sqrt()).abs() < 1e-6);
        // Equilateral, side 1: the circumradius 1/√3.
        let h = 3.0f32.sqrt() / 2.0;
        assert!((enclosing_radius([0.0, 0.0], [1.0, 0.0], [0.5, h]) - 1.0 / 3.0f32.sqrt()).abs() < 1e-6);
        // Obtuse with sides 1, 1, 1.9: half the longest side, not the (larger) circumradius.
        let apex = [0.95, (1.0f32 - 0.95 * 0.95).sqrt()];
        assert!((enclosing_radius([0.0, 0.0], [1.9, 0.0], apex) - 0.95).abs() < 1e-5);
        // Collinear: half the span.
        assert!((enclosing_radius([0.0, 0.0], [1.0, 0.0], [3.0, 0.0]) - 1.5).abs() < 1e-6);
    }

    #[test]
    fn containment_is_edge_inclusive_and_rejects_degenerate_triangles() {
        let (a, b, c) = ([0.0, 0.0], [2.0, 0.0], [0.0, 2.0]);
        assert!(covers(a, b, c, [0.5, 0.5]) && covers(c, b, a, [0.5, 0.5]), "either winding");
        assert!(covers(a, b, c, [1.0, 0.0]) && covers(a, b, c, [1.0, 1.0]) && covers(a, b, c, [0.0, 0.0]));
        assert!(!covers(a, b, c, [1.01, 1.0]) && !covers(a, b, c, [-0.01, 0.5]));
        assert!(!covers([0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [1.0, 0.0]), "collinear");
        assert!(!covers([1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [1.0, 1.0]), "coincident");
    }

    /// A jittered grid of spacing `s` over [0, size]², optionally only where `keep` holds.
    fn grid(size: f32, s: f32, keep: impl Fn(Point) -> bool) -> Vec<Point> {
        let n = (size / s) as usize;
        let mut state = 17u32;
        let mut jitter = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            ((state >> 8) as f32 / (1u32 << 24) as f32 - 0.5) * 0.3 * s
        };
        let mut points = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let p = [i as f32 * s + jitter(), j as f32 * s + jitter()];
                if keep(p) {
                    points.push(p);
                }
            }
        }
        points
    }

    #[test]
    fn a_full_surface_covers_and_a_boundary_does_not_bloat() {
        let radius = 0.5;
        let mut stats = CoverageStats::default();
        let full = grid(8.0, 0.5, |_| true);
        // Cell centres (every corner within R: the quadrant early-out) and an off-centre point.
        for location in [[4.25, 3.75], [2.25, 6.25], [5.1, 5.35]] {
            assert!(is_covered(&full, location, radius, 64, &mut stats), "{location:?}");
        }
        assert!(stats.quadrant_accepts >= 2);
        // The surface ends at x = 4: locations beyond its last column by more than the sample
        // spacing are not covered (no bloat by R), locations inside are.
        let half = grid(8.0, 0.5, |p| p[0] <= 4.0);
        assert!(is_covered(&half, [3.3, 4.1], radius, 64, &mut stats));
        assert!(!is_covered(&half, [4.6, 4.1], radius, 64, &mut stats));
        assert!(!is_covered(&half, [6.0, 4.1], radius, 64, &mut stats));
    }

    #[test]
    fn collinear_samples_cover_nothing() {
        let line: Vec<Point> = (0..20).map(|i| [i as f32 * 0.3, 2.0]).collect();
        let mut stats = CoverageStats::default();
        assert!(!is_covered(&line, [3.0, 2.0], 0.5, 64, &mut stats));
        assert!(stats.triangles_tested > 0);
        assert!(!is_covered(&[], [0.0, 0.0], 0.5, 64, &mut stats));
    }

    /// The tent filter as first written, a root per sample: the oracle of `tent_filter`.
    fn tent_filter_oracle(points: &[Point], values: &[[f32; 3]], location: Point, radius: f32) -> Option<[f32; 3]> {
        let mut sum = [0.0f64; 3];
        let mut weight_sum = 0.0f64;
        let mut nearest: Option<(f32, usize)> = None;
        for (i, p) in points.iter().enumerate() {
            let distance = ((p[0] - location[0]).powi(2) + (p[1] - location[1]).powi(2)).sqrt();
            if nearest.map_or(true, |(d, _)| distance < d) {
                nearest = Some((distance, i));
            }
            let w = (1.0 - distance / radius).max(0.0) as f64;
            if w > 0.0 {
                weight_sum += w;
                for c in 0..3 {
                    sum[c] += w * values[i][c] as f64;
                }
            }
        }
        if weight_sum > 0.0 {
            Some(sum.map(|s| (s / weight_sum) as f32))
        } else {
            nearest.map(|(_, i)| values[i])
        }
    }

    /// The squared-distance tent filter gives the oracle's value bit for bit on random
    /// surfaces, samples on the tent's rim included.
    #[test]
    fn the_tent_filter_matches_its_oracle_bit_for_bit() {
        let mut rng = crate::lcg::Lcg(11);
        for trial in 0..2000 {
            let radius = 0.1 + 2.0 * rng.uniform();
            let n = 1 + (rng.uniform() * 60.0) as usize;
            let location = [rng.uniform() * 4.0, rng.uniform() * 4.0];
            let mut points: Vec<Point> = (0..n)
                .map(|_| {
                    [
                        location[0] + (rng.uniform() - 0.5) * 5.0 * radius,
                        location[1] + (rng.uniform() - 0.5) * 5.0 * radius,
                    ]
                })
                .collect();
            // A few exactly on the rim, along an axis.
            if trial % 3 == 0 {
                points.push([location[0] + radius, location[1]]);
                points.push([location[0], location[1] - radius]);
            }
            let values: Vec<[f32; 3]> = points.iter().map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
            assert_eq!(
                tent_filter(&points, &values, location, radius),
                tent_filter_oracle(&points, &values, location, radius),
                "trial {trial}"
            );
        }
    }

    #[test]
    fn the_tent_filter_weights_by_distance_and_falls_back_to_the_nearest() {
        let points = [[0.0, 0.0], [0.5, 0.0], [3.0, 0.0]];
        let values = [[1.0; 3], [3.0; 3], [100.0; 3]];
        // Weights at location (0, 0), R = 1: 1 and 0.5 → (1 + 1.5) / 1.5.
        let v = tent_filter(&points, &values, [0.0, 0.0], 1.0).unwrap();
        assert!((v[0] - 2.5 / 1.5).abs() < 1e-6);
        // Nothing within R of (2.2, 0): the nearest sample (3, 0) is at 0.8 > R = 0.5.
        assert_eq!(tent_filter(&points, &values, [2.2, 0.0], 0.5), Some([100.0; 3]));
        assert_eq!(tent_filter(&[], &[], [0.0, 0.0], 1.0), None);
        // Convexity with a huge spike: within the inputs' range.
        let spike = tent_filter(&points, &[[1.0; 3], [1e30; 3], [0.0; 3]], [0.2, 0.0], 1.0).unwrap();
        assert!(spike[0].is_finite() && spike[0] <= 1e30 && spike[0] >= 0.0);
    }
}
