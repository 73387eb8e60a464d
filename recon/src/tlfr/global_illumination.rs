//! Not in the paper: TLFR on full global illumination. The paper's samples
//! carry noise-free shading; a path-traced sample's radiance carries the noise of its path
//! beyond the first hit, which reprojection does not average away. With `gi=split` each sample's
//! radiance is cut in two (`split_sample`): its `direct` part (emission seen by the camera and
//! the light the first hit reflects straight from emitters, the tracer's `direct` field), whose
//! only noise is the distribution effect's, goes through the reconstruction; the rest, the light
//! of longer paths, is averaged per pixel (`indirect_pixel_means`) and smoothed across pixels of
//! similar depth (`smooth_indirect`), then added. Measured in docs/history/tlfr.md ("Full global
//! illumination").

use crate::image::Image;

/// How TLFR treats the light of paths longer than one bounce.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GiMode {
    /// The whole radiance of each sample goes through the reconstruction (the paper).
    #[default]
    Whole,
    /// The direct part through the reconstruction, the rest per pixel, smoothed over a window of
    /// `radius` pixels (0: the pixel's own mean).
    Split { radius: u32 },
}

/// `gi_radius`'s default (docs/history/tlfr.md, "Full global illumination").
pub const DEFAULT_GI_RADIUS: u32 = 3;

/// Relative inverse-depth difference at which a neighbour's weight in `smooth_indirect` has
/// fallen to e^(−1/2).
pub const DEPTH_TOLERANCE: f32 = 0.05;

/// A sample's radiance as (direct part, the rest): `direct` and `radiance − direct`. The two add
/// back to `radiance` up to one rounding per channel.
pub fn split_sample(radiance: [f32; 3], direct: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    (direct, [radiance[0] - direct[0], radiance[1] - direct[1], radiance[2] - direct[2]])
}

/// Per pixel: the mean of the indirect parts of its samples, and the mean inverse depth of their
/// first hits (0 for a miss), the guide of `smooth_indirect`. Sample `i` of `indirect` and
/// `depth` belongs to pixel `pixel_of[i]`. A pixel without samples is 0 with inverse depth 0.
pub fn indirect_pixel_means(
    (width, height): (u32, u32),
    pixel_of: impl Iterator<Item = usize>,
    indirect: &[[f32; 3]],
    depth: &[f32],
) -> (Image, Vec<f32>) {
    let pixels = (width * height) as usize;
    let mut sums = vec![[0.0f64; 3]; pixels];
    let mut inverse_depth = vec![0.0f64; pixels];
    let mut counts = vec![0u32; pixels];
    for ((pixel, value), z) in pixel_of.zip(indirect).zip(depth) {
        for (sum, value) in sums[pixel].iter_mut().zip(value) {
            *sum += *value as f64;
        }
        inverse_depth[pixel] += if z.is_finite() { 1.0 / *z as f64 } else { 0.0 };
        counts[pixel] += 1;
    }
    let mut image = Image::new(width, height);
    let mut guide = vec![0.0f32; pixels];
    for p in 0..pixels {
        let n = counts[p].max(1) as f64;
        image.pixels[p] = sums[p].map(|s| (s / n) as f32);
        // A first hit at depth 0 (or below f32's smallest normal) has an infinite inverse
        // depth: the guide saturates at f32::MAX so that `smooth_indirect` stays finite.
        guide[p] = (inverse_depth[p] / n).clamp(0.0, f32::MAX as f64) as f32;
    }
    (image, guide)
}

/// A cross-bilateral filter of the per-pixel indirect means `image` over a (2·`radius` + 1)²
/// window: spatial Gaussian of deviation `radius`/2 pixels, times a Gaussian in the relative
/// difference of the pixels' mean inverse depths `inverse_depth` with deviation
/// `DEPTH_TOLERANCE` (surfaces at other depths do not bleed into each other). The weights are
/// normalised, so a constant image stays constant; radius 0 returns `image`.
pub fn smooth_indirect(image: &Image, inverse_depth: &[f32], radius: u32) -> Image {
    if radius == 0 {
        return image.clone();
    }
    let (width, height) = (image.width as i64, image.height as i64);
    let r = radius as i64;
    let spatial = 1.0 / (2.0 * (radius as f32 / 2.0).powi(2));
    let range = 1.0 / (2.0 * DEPTH_TOLERANCE * DEPTH_TOLERANCE);
    let mut out = Image::new(image.width, image.height);
    for y in 0..height {
        for x in 0..width {
            let centre = (y * width + x) as usize;
            let depth = inverse_depth[centre];
            let (mut sum, mut total) = ([0.0f32; 3], 0.0f32);
            for qy in (y - r).max(0)..=(y + r).min(height - 1) {
                for qx in (x - r).max(0)..=(x + r).min(width - 1) {
                    let q = (qy * width + qx) as usize;
                    let other = inverse_depth[q];
                    let scale = depth.max(other);
                    let relative = if scale > 0.0 { (depth - other) / scale } else { 0.0 };
                    let d2 = ((qx - x).pow(2) + (qy - y).pow(2)) as f32;
                    let weight = (-d2 * spatial - relative * relative * range).exp();
                    for (sum, value) in sum.iter_mut().zip(image.pixels[q]) {
                        *sum += weight * value;
                    }
                    total += weight;
                }
            }
            // The centre's own weight is 1, so the total is at least 1.
            out.pixels[centre] = sum.map(|s| s / total);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::lcg::Lcg;

    /// Uniform in [low, high).
    fn uniform(rng: &mut Lcg, low: f32, high: f32) -> f32 {
        low + rng.uniform() * (high - low)
    }

    #[test]
    fn the_parts_of_a_sample_add_back_to_its_radiance() {
        let mut rng = Lcg(5);
        for _ in 0..10_000 {
            let radiance: [f32; 3] = std::array::from_fn(|_| uniform(&mut rng, 0.0, 100.0));
            let direct: [f32; 3] = std::array::from_fn(|c| radiance[c] * rng.uniform());
            let (d, rest) = split_sample(radiance, direct);
            for c in 0..3 {
                let sum = d[c] + rest[c];
                // One rounding of the subtraction: within half an ulp of the radiance's size.
                assert!((sum - radiance[c]).abs() <= radiance[c] * f32::EPSILON, "{sum} vs {}", radiance[c]);
            }
        }
    }

    #[test]
    fn pixel_means_average_each_pixels_samples() {
        let indirect = [[1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [5.0, 5.0, 5.0]];
        let depth = [2.0, f32::INFINITY, 4.0];
        let (image, guide) = indirect_pixel_means((2, 2), [0usize, 0, 3].into_iter(), &indirect, &depth);
        assert_eq!(image.pixels, [[2.0, 2.0, 2.0], [0.0; 3], [0.0; 3], [5.0, 5.0, 5.0]]);
        assert_eq!(guide, [0.25, 0.0, 0.0, 0.25]);
    }

    #[test]
    fn stiff_depths_one_pixel_and_extreme_scales() {
        // One pixel: its mean, unchanged by any radius.
        let (one, guide) =
            indirect_pixel_means((1, 1), [0usize, 0].into_iter(), &[[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]], &[1e-3, 2e-3]);
        assert_eq!(one.pixels, [[2.0, 2.0, 2.0]]);
        assert_eq!(smooth_indirect(&one, &guide, 3).pixels, one.pixels);
        // Depth 0, a subnormal depth and a miss beside ordinary ones: every pixel finite, and the
        // ordinary pixels do not take the zero-depth pixels' light.
        let depth = [0.0, 1e-40, f32::INFINITY, 1.0, 1.0, 1.0];
        let indirect = [[9.0; 3], [9.0; 3], [0.0; 3], [1.0; 3], [1.0; 3], [1.0; 3]];
        let (image, guide) = indirect_pixel_means((6, 1), 0..6usize, &indirect, &depth);
        assert!(guide.iter().all(|g| g.is_finite()), "{guide:?}");
        let smoothed = smooth_indirect(&image, &guide, 3);
        assert!(smoothed.pixels.iter().flatten().all(|v| v.is_finite()), "{:?}", smoothed.pixels);
        assert!((smoothed.pixels[4][0] - 1.0).abs() < 1e-3, "{:?}", smoothed.pixels);
        // The depth test is relative: scenes at 1e-6 and 1e9 scale smooth alike.
        let (noisy, depth) = noisy_plane(9, 5, 4);
        let base = smooth_indirect(&noisy, &depth, 2);
        for scale in [1e-6f32, 1e9] {
            let scaled: Vec<f32> = depth.iter().map(|d| d / scale).collect();
            for (p, q) in smooth_indirect(&noisy, &scaled, 2).pixels.iter().zip(&base.pixels) {
                for c in 0..3 {
                    assert!((p[c] - q[c]).abs() <= 1e-5 * q[c].abs().max(1.0), "scale {scale}: {p:?} vs {q:?}");
                }
            }
        }
    }

    fn noisy_plane(width: u32, height: u32, seed: u64) -> (Image, Vec<f32>) {
        let mut rng = Lcg(seed);
        let mut image = Image::new(width, height);
        for pixel in &mut image.pixels {
            *pixel = std::array::from_fn(|_| 1.0 + uniform(&mut rng, -0.5, 0.5));
        }
        let depth = (0..width * height).map(|_| 0.5 + uniform(&mut rng, -0.001, 0.001)).collect();
        (image, depth)
    }

    #[test]
    fn smoothing_keeps_constants_and_radius_zero_is_the_identity() {
        let mut rng = Lcg(9);
        let (width, height) = (13, 7);
        let depth: Vec<f32> = (0..width * height).map(|_| uniform(&mut rng, 0.0, 2.0)).collect();
        let mut constant = Image::new(width, height);
        constant.pixels.fill([0.3, 1.5, 7.0]);
        for radius in 1..5 {
            let smoothed = smooth_indirect(&constant, &depth, radius);
            for (p, q) in smoothed.pixels.iter().zip(&constant.pixels) {
                for c in 0..3 {
                    assert!((p[c] - q[c]).abs() <= 4.0 * f32::EPSILON * q[c], "radius {radius}: {p:?}");
                }
            }
        }
        let (noisy, depth) = noisy_plane(width, height, 3);
        assert_eq!(smooth_indirect(&noisy, &depth, 0).pixels, noisy.pixels);
    }

    #[test]
    fn smoothing_lowers_noise_on_a_plane_and_does_not_cross_a_depth_step() {
        // White noise on one plane: a window of deviation r/2 averages about π(r/2)²·2 pixels,
        // so the variance must fall by far more than 2 at radius 4.
        let (noisy, depth) = noisy_plane(64, 64, 11);
        let variance = |image: &Image| {
            let n = image.pixels.len() as f64;
            let mean = image.pixels.iter().map(|p| p[0] as f64).sum::<f64>() / n;
            image.pixels.iter().map(|p| (p[0] as f64 - mean).powi(2)).sum::<f64>() / n
        };
        let before = variance(&noisy);
        let after = variance(&smooth_indirect(&noisy, &depth, 4));
        assert!(after < before / 8.0, "variance {before} -> {after}");
        // Two constants on two depths (1 and 2, a relative step of 0.5 = 10 tolerances): each
        // side keeps its own value.
        let (width, height) = (16u32, 8u32);
        let mut image = Image::new(width, height);
        let mut inverse_depth = vec![0.0; (width * height) as usize];
        for y in 0..height {
            for x in 0..width {
                let near = x < width / 2;
                image.pixels[(y * width + x) as usize] = if near { [1.0; 3] } else { [9.0; 3] };
                inverse_depth[(y * width + x) as usize] = if near { 1.0 } else { 0.5 };
            }
        }
        let smoothed = smooth_indirect(&image, &inverse_depth, 4);
        for (p, q) in smoothed.pixels.iter().zip(&image.pixels) {
            assert!((p[0] - q[0]).abs() < 1e-5 * q[0], "{p:?} vs {q:?}");
        }
    }
}
