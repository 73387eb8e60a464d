//! The directions ILFR's gathers draw at a surface point: cosine-distributed reconstruction
//! rays about its normal (the final gather at diffuse primary hits, Eq. 3, ambient occlusion,
//! §3.3, and the recursive pass at secondary hits), and the array normalisation the gathers
//! share. The points are `shading::sampling`'s scrambled Sobol' pairs, mapped to the
//! hemisphere by `shading`'s concentric map (Malley), in `shading::Frame`'s basis: the same
//! numerics as the tracer's.

use glam::Vec3;
use shading::sampling::sobol_2d_scrambled;
use shading::{sample_cosine_hemisphere, Frame};

use super::disc::Ray;
use crate::vector::normalize;

/// `count` rays from `hit` lifted by `offset` along the unit `normal`, cosine-distributed about
/// it: points `first`, …, `first + count − 1` of the 2D Sobol' sequence Owen-scrambled by
/// `scramble`, mapped to the hemisphere (an aligned block of 2^m points of the scrambled
/// sequence is itself a (0, m, 2)-net, so hits that take consecutive blocks of one sequence
/// share one stratification).
pub(super) fn cosine_rays(
    hit: [f32; 3],
    normal: [f32; 3],
    offset: f32,
    (first, count): (u32, u32),
    scramble: u32,
) -> impl Iterator<Item = Ray> {
    let origin = [0, 1, 2].map(|a| hit[a] + offset * normal[a]);
    let frame = Frame::new(Vec3::from(normal));
    let (tangent, bitangent) = (frame.tangent.to_array(), frame.bitangent.to_array());
    (first..first.saturating_add(count)).map(move |j| {
        let (u, v) = sobol_2d_scrambled(j, scramble);
        let local = sample_cosine_hemisphere([u, v]).to_array();
        let direction = [0, 1, 2].map(|a| local[0] * tangent[a] + local[1] * bitangent[a] + local[2] * normal[a]);
        Ray { time: 0.0, origin, direction: normalize(direction) }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_rays_have_the_cosine_moments_about_any_normal() {
        // Under p(ω) = cosθ/π about n: E[cosθ] = 2/3, E[cos²θ] = 1/2, and the mean direction
        // lies along n.
        for normal in [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.6, 0.0, 0.8], [-0.48, 0.6, -0.64]] {
            let n = 4096;
            let (mut c1, mut c2, mut mean) = (0.0f64, 0.0f64, [0.0f64; 3]);
            for ray in cosine_rays([1.0, 2.0, 3.0], normal, 0.5, (0, n), 7) {
                let d = ray.direction;
                assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - 1.0).abs() < 1e-5);
                assert_eq!(ray.origin, [0, 1, 2].map(|a| [1.0, 2.0, 3.0][a] + 0.5 * normal[a]));
                let cos = (d[0] * normal[0] + d[1] * normal[1] + d[2] * normal[2]) as f64;
                assert!(cos >= -1e-6, "{normal:?}: a ray below the surface");
                c1 += cos;
                c2 += cos * cos;
                for a in 0..3 {
                    mean[a] += d[a] as f64;
                }
            }
            let n = n as f64;
            assert!((c1 / n - 2.0 / 3.0).abs() < 1e-3, "{}", c1 / n);
            assert!((c2 / n - 0.5).abs() < 1e-3, "{}", c2 / n);
            for a in 0..3 {
                assert!((mean[a] / n - 2.0 / 3.0 * normal[a] as f64).abs() < 2e-3, "{normal:?}: {mean:?}");
            }
        }
    }
}
