//! Maps from the unit square to the disk and the hemisphere.

use glam::{Vec2, Vec3};

/// Shirley and Chiu's concentric map from [0, 1)² to the unit disk: equal areas map to equal
/// areas and strata stay compact.
pub fn concentric_disk(square: Vec2) -> Vec2 {
    let offset = 2.0 * square - Vec2::ONE;
    if offset.x == 0.0 && offset.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if offset.x.abs() > offset.y.abs() {
        (offset.x, std::f32::consts::FRAC_PI_4 * (offset.y / offset.x))
    } else {
        (offset.y, std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (offset.x / offset.y))
    };
    Vec2::new(r * theta.cos(), r * theta.sin())
}

/// Cosine-weighted hemisphere direction about +z (Malley's method), density cos θ / π.
pub fn sample_cosine_hemisphere(u: [f32; 2]) -> Vec3 {
    let d = concentric_disk(Vec2::new(u[0], u[1]));
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn concentric_disk_stays_inside_the_unit_disk() {
        for i in 0..=20 {
            for j in 0..=20 {
                let p = concentric_disk(Vec2::new(i as f32 / 20.0, j as f32 / 20.0));
                assert!(p.length() <= 1.0 + 1e-6);
            }
        }
    }

    #[test]
    fn the_concentric_map_covers_the_disk_evenly() {
        let n = 64;
        let (mut inner, mut total) = (0, 0);
        for i in 0..n {
            for j in 0..n {
                let p = concentric_disk(Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32));
                assert!(p.length_squared() <= 1.0 + 1e-6);
                total += 1;
                if p.length_squared() <= 0.25 {
                    inner += 1;
                }
            }
        }
        // Area-preserving: a quarter of the points within radius 1/2.
        assert!((inner as f32 / total as f32 - 0.25).abs() < 0.01);
    }

    #[test]
    fn cosine_directions_have_the_cosine_moments() {
        // E[cos θ] = 2/3 and E[cos² θ] = 1/2 under the density cos θ / π.
        let n = 1 << 14;
        let (mut m1, mut m2) = (0.0f64, 0.0f64);
        for i in 0..n {
            let [_, u0, u1] = crate::test_points::hammersley(i, n);
            let w = sample_cosine_hemisphere([u0, u1]);
            assert!((w.length() - 1.0).abs() < 1e-5 && w.z >= 0.0);
            m1 += w.z as f64;
            m2 += (w.z * w.z) as f64;
        }
        assert!((m1 / n as f64 - 2.0 / 3.0).abs() < 1e-3, "{}", m1 / n as f64);
        assert!((m2 / n as f64 - 0.5).abs() < 1e-3, "{}", m2 / n as f64);
    }
}
