//! Beyond the paper: an edge-aware filter of the final gather's per-pixel grain,
//! `ilfr:grain=filter` (the paper's method keeps the grain: `grain=keep`, the default).
//!
//! Why: the error that more reconstruction rays remove is mostly per-pixel grain of the final
//! gather (Eq. 3 with N rays per pixel), not the reconstruction's bias (Cornell 64², 16 spp:
//! 128 → 512 rays lift 32.95 → 37.47 dB). Taking it out with a filter that costs milliseconds
//! buys the PSNR of more rays at the time of fewer (measured in docs/history/ilfr.md, "the
//! final gather's grain, filtered").
//!
//! What: the pixel's indirect light divided by its primary hits' mean albedo (so textures are
//! not blurred; channels with albedo below 1e-3 are left as they are), three levels of an
//! edge-avoiding À-Trous filter (5×5 B3 kernel, steps 1, 2, 4; the `crate::baselines::atrous`
//! weights on the primary hits' mean normal, σ_n = 0.2, and mean position, σ_x = 2³ times the
//! median distance between adjacent pixels' hits), times the albedo again, with one term more:
//! a luminance term in units of the centre pixel's own standard error,
//! exp(−|Y_p − Y_q| / (σ_l √Var_p)), σ_l = 2, where Var_p is the variance of the pixel's
//! gathered irradiance estimated from the spread of its reconstruction rays
//! (`gather::gather_with_spread`), blurred over 3×3 pixels and carried through the levels as
//! Σ w² Var / (Σ w)² (the variance-guided filter of Schied et al., "Spatiotemporal
//! Variance-Guided Filtering", HPG 2017, without its temporal part). Grain, whose differences
//! are a few standard errors, is averaged; a real edge in the light (a shadow, a contact
//! shadow's gradient) whose step is many standard errors is kept; the term is scale-free (a
//! ratio of the light to its own error), so no exposure-dependent constant enters. Where a
//! pixel's variance is unknown (fewer than two supported rays) its term is off. Pixels whose
//! camera rays all escaped keep their value and are never read by surface pixels. Only for
//! diffuse `indirect` files: a glossy file's light is not albedo times irradiance, and
//! filtering it would blur reflections. Chosen by measurement against one level without the
//! luminance term and other levels and σ_l: docs/history/ilfr.md, "the final gather's
//! grain, filtered".

use rayon::prelude::*;

use super::robust::luminance;
use super::samples::{IndirectSamples, SampleClass};
use crate::baselines::atrous::{AtrousParams, B3};
use crate::error::Error;
use crate::guide::GuideBuffers;
use crate::image::Image;

/// Albedo below which a channel is not divided (its light stays as gathered).
const MIN_ALBEDO: f32 = 1e-3;

/// The guide (mean normal and position of each pixel's primary hits) and the mean albedo.
fn pixel_guide(samples: &IndirectSamples, albedo: &[[f32; 3]]) -> (GuideBuffers, Vec<[f32; 3]>) {
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1) as usize);
    let pixel_count = width as usize * height as usize;
    let mut guide = GuideBuffers {
        width,
        height,
        normal: vec![[0.0; 3]; pixel_count],
        depth: vec![0.0; pixel_count],
        position: vec![[0.0; 3]; pixel_count],
        secondary_normal: None,
    };
    let mut mean_albedo = vec![[0.0f32; 3]; pixel_count];
    for (pixel, pixel_albedo) in mean_albedo.iter_mut().enumerate() {
        let hits = || (pixel * spp..(pixel + 1) * spp).filter(|&i| samples.class[i] != SampleClass::CameraMiss);
        let count = hits().count();
        if count == 0 {
            continue;
        }
        let mean = |values: &[[f32; 3]]| -> [f32; 3] {
            let sum = hits().fold([0.0f64; 3], |s, i| std::array::from_fn(|c| s[c] + values[i][c] as f64));
            std::array::from_fn(|c| (sum[c] / count as f64) as f32)
        };
        let normal = mean(&samples.primary_normal);
        let length = normal.iter().map(|v| v * v).sum::<f32>().sqrt();
        if !length.is_finite() || length <= 1e-6 {
            continue; // opposite normals cancel: no direction to guide by, the pixel stays out
        }
        guide.normal[pixel] = normal.map(|v| v / length);
        guide.position[pixel] = mean(&samples.primary_hit);
        guide.depth[pixel] = 1.0; // only marks a surface pixel: the filter's terms use the position
        *pixel_albedo = mean(albedo);
    }
    (guide, mean_albedo)
}

/// Whether `samples` can have their grain filtered: a diffuse `indirect` file with `albedo`;
/// the error names the file and the field. Checked before any long work.
pub fn check_input(samples: &IndirectSamples) -> Result<&[[f32; 3]], Error> {
    let content = |message: &str| Error::sample_content(&samples.path, message);
    let albedo = samples.albedo.as_ref().ok_or_else(|| content("grain=filter needs the field `albedo`"))?;
    if samples.weight.is_some() {
        return Err(content(
            "grain=filter applies to diffuse indirect light (albedo × irradiance); this file has `weight` \
             (a glossy scene), whose reflections it would blur",
        ));
    }
    Ok(albedo)
}

/// The filter's levels (steps 1, 2, 4 pixels: a 29-pixel footprint).
pub const LEVELS: u32 = 3;
/// σ_l of the luminance term, in standard errors of the centre pixel's estimate.
pub const SIGMA_LUMINANCE: f32 = 2.0;
/// Weights below e^-80 count as zero.
const MAX_EXPONENT: f32 = 80.0;

/// The gathered `image` of `samples` (a diffuse `indirect` file, [`check_input`]) with its
/// per-pixel grain filtered out; `variance` is each pixel's variance of its gathered
/// irradiance's luminance (`gather_with_spread`; +inf or NaN where unknown, which turns the
/// pixel's luminance term off). See the module documentation.
pub fn filter_grain(samples: &IndirectSamples, image: &Image, variance: &[f32]) -> Result<Image, Error> {
    let albedo = check_input(samples)?;
    let (width, height) = (image.width as usize, image.height as usize);
    if (image.width, image.height) != (samples.width, samples.height) || variance.len() != width * height {
        return Err(Error::size_mismatch(
            "image",
            format!(
                "{}x{} image and {} variances for {}x{} samples",
                image.width,
                image.height,
                variance.len(),
                samples.width,
                samples.height
            ),
        ));
    }
    let (guide, mean_albedo) = pixel_guide(samples, albedo);
    // Divided by the albedo; a non-finite value becomes 0, an unknown variance +inf.
    let mut current: Vec<[f32; 3]> = image
        .pixels
        .iter()
        .zip(&mean_albedo)
        .map(|(value, albedo)| {
            std::array::from_fn(|c| {
                let v = if albedo[c] > MIN_ALBEDO { value[c] / albedo[c] } else { value[c] };
                if v.is_finite() {
                    v
                } else {
                    0.0
                }
            })
        })
        .collect();
    let mut current_variance: Vec<f32> =
        variance.iter().map(|&v| if v >= 0.0 && v.is_finite() { v } else { f32::INFINITY }).collect();
    // σ_x: 2^LEVELS times the median spacing of adjacent pixels' hits (the baseline's rule); no
    // spacing (one pixel, or all hits in one point): the position term is off.
    let inverse_sigma_position =
        crate::baselines::atrous::default_sigma_position(&guide, LEVELS).map_or(0.0, |sigma| 1.0 / sigma);
    // σ_n: the À-Trous baseline's default.
    let inverse_sigma_normal = 1.0 / AtrousParams::default().sigma_normal;
    let surface: Vec<bool> = guide.depth.iter().map(|&d| d != 0.0).collect();
    for level in 0..LEVELS {
        let step = 1isize << level;
        let weight_variance = blurred_variance(&current_variance, &surface, width, height);
        let mut next = current.clone();
        let mut next_variance = current_variance.clone();
        next.par_chunks_mut(width).zip(next_variance.par_chunks_mut(width)).enumerate().for_each(
            |(y, (row, row_variance))| {
                for x in 0..width {
                    let p = y * width + x;
                    if !surface[p] {
                        continue;
                    }
                    let centre = luminance(current[p]);
                    // |ΔY| / (σ_l √var + a relative floor), 0 where the variance is unknown.
                    let scale = SIGMA_LUMINANCE * weight_variance[p].sqrt() + 1e-4 * centre.abs() + f32::MIN_POSITIVE;
                    let inverse_scale = if scale.is_finite() { 1.0 / scale } else { 0.0 };
                    let (mut sum, mut weights, mut variance_sum) = ([0.0f64; 3], 0.0f64, 0.0f64);
                    for (b, &hy) in B3.iter().enumerate() {
                        let yy = y as isize + (b as isize - 2) * step;
                        if !(0..height as isize).contains(&yy) {
                            continue;
                        }
                        for (a, &hx) in B3.iter().enumerate() {
                            let xx = x as isize + (a as isize - 2) * step;
                            if !(0..width as isize).contains(&xx) {
                                continue;
                            }
                            let q = yy as usize * width + xx as usize;
                            if !surface[q] {
                                continue;
                            }
                            let squared = |u: [f32; 3], v: [f32; 3], inverse: f32| -> f32 {
                                (0..3).map(|c| ((u[c] - v[c]) * inverse).powi(2)).sum()
                            };
                            let exponent = squared(guide.normal[p], guide.normal[q], inverse_sigma_normal)
                                + squared(guide.position[p], guide.position[q], inverse_sigma_position)
                                + (centre - luminance(current[q])).abs() * inverse_scale;
                            // `<` is false for NaN: such a tap does not count.
                            let counts = exponent < MAX_EXPONENT;
                            if !counts {
                                continue;
                            }
                            let w = (hx * hy) as f64 * (-exponent as f64).exp();
                            for c in 0..3 {
                                sum[c] += w * current[q][c] as f64;
                            }
                            weights += w;
                            variance_sum += w * w * current_variance[q] as f64;
                        }
                    }
                    // The centre tap always counts (exponent 0), so `weights` > 0.
                    row[x] = sum.map(|v| (v / weights) as f32);
                    row_variance[x] = (variance_sum / (weights * weights)) as f32;
                }
            },
        );
        current = next;
        current_variance = next_variance;
    }
    let pixels = current
        .iter()
        .zip(&mean_albedo)
        .zip(&image.pixels)
        .zip(&surface)
        .map(|(((value, albedo), gathered), &surface)| {
            if !surface {
                return *gathered;
            }
            std::array::from_fn(|c| if albedo[c] > MIN_ALBEDO { value[c] * albedo[c] } else { value[c] })
        })
        .collect();
    Ok(Image::from_pixels(image.width, image.height, pixels))
}

/// The variances the luminance term reads: a 3×3 binomial blur over the surface pixels with a
/// known variance (one pixel's estimate from a few rays is itself noisy); +inf where none.
fn blurred_variance(variance: &[f32], surface: &[bool], width: usize, height: usize) -> Vec<f32> {
    const K: [f64; 3] = [0.25, 0.5, 0.25];
    (0..width * height)
        .into_par_iter()
        .map(|p| {
            let (x, y) = (p % width, p / width);
            let (mut sum, mut weights) = (0.0f64, 0.0f64);
            for (b, ky) in K.iter().enumerate() {
                for (a, kx) in K.iter().enumerate() {
                    let (Some(xx), Some(yy)) = ((x + a).checked_sub(1), (y + b).checked_sub(1)) else { continue };
                    if xx >= width || yy >= height {
                        continue;
                    }
                    let q = yy * width + xx;
                    if surface[q] && variance[q].is_finite() {
                        sum += kx * ky * variance[q] as f64;
                        weights += kx * ky;
                    }
                }
            }
            if weights > 0.0 {
                (sum / weights) as f32
            } else {
                f32::INFINITY
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;
    use sampleio::SampleKind;

    /// A `width`×`height` image of primary hits, one per pixel, from `hit(x, y)` = (position,
    /// normal, albedo), `None` for a camera miss.
    fn samples(
        width: u32,
        height: u32,
        hit: impl Fn(u32, u32) -> Option<([f32; 3], [f32; 3], [f32; 3])>,
    ) -> IndirectSamples {
        let mut s = IndirectSamples::empty(
            "floor.lfrs".into(),
            SampleKind::Indirect,
            (width, height, 1),
            (width * height) as usize,
        );
        let mut albedo = Vec::new();
        for y in 0..height {
            for x in 0..width {
                let (class, (position, normal, a)) = match hit(x, y) {
                    Some(h) => (SampleClass::Hit, h),
                    None => (SampleClass::CameraMiss, ([0.0; 3], [0.0; 3], [0.0; 3])),
                };
                s.class.push(class);
                s.primary_hit.push(position);
                s.primary_normal.push(normal);
                albedo.push(a);
            }
        }
        s.albedo = Some(albedo);
        s
    }

    fn image(width: u32, height: u32, mut value: impl FnMut(u32, u32) -> [f32; 3]) -> Image {
        Image::from_pixels(
            width,
            height,
            (0..height).flat_map(|y| (0..width).map(move |x| (x, y))).map(|(x, y)| value(x, y)).collect(),
        )
    }

    /// Every pixel's variance unknown (+inf): the luminance term is off, only the geometry guides.
    fn unknown(width: u32, height: u32) -> Vec<f32> {
        vec![f32::INFINITY; (width * height) as usize]
    }

    /// A floor (z = 0) seen from above, 0.01 apart per pixel, with a checkerboard albedo.
    fn floor(x: u32, y: u32) -> Option<([f32; 3], [f32; 3], [f32; 3])> {
        let albedo = if (x / 3 + y / 3) % 2 == 0 { [0.8, 0.1, 0.5] } else { [0.2, 0.6, 0.05] };
        Some(([x as f32 * 0.01, y as f32 * 0.01, 0.0], [0.0, 0.0, 1.0], albedo))
    }

    /// Constant irradiance under a textured albedo comes back pixel for pixel: the texture is
    /// divided out before the filter and multiplied back after it.
    #[test]
    fn constant_irradiance_under_a_texture_comes_back() {
        let s = samples(24, 20, floor);
        let gathered = image(24, 20, |x, y| floor(x, y).unwrap().2.map(|a| a * 0.7));
        let filtered = filter_grain(&s, &gathered, &unknown(24, 20)).unwrap();
        for (f, g) in filtered.pixels.iter().zip(&gathered.pixels) {
            for c in 0..3 {
                assert!((f[c] - g[c]).abs() <= 1e-5 * g[c].max(1e-3), "{f:?} vs {g:?}");
            }
        }
    }

    /// Independent grain on one plane, with its true variance: the squared error about the true
    /// value falls at least threefold and the mean stays.
    #[test]
    fn grain_on_a_plane_falls_at_least_threefold() {
        let (width, height) = (48, 40);
        let s =
            samples(width, height, |x, y| Some(([x as f32 * 0.01, y as f32 * 0.01, 0.0], [0.0, 0.0, 1.0], [0.5; 3])));
        let mut rng = Lcg(7);
        let truth = 0.25f32;
        // Uniform on truth·(1 ± 0.25) in the light; the irradiance (light / albedo 0.5) has
        // variance (0.5·truth/0.5)²/12.
        let gathered = image(width, height, |_, _| [truth * (1.0 + 0.5 * (rng.uniform() - 0.5)); 3]);
        let variance = vec![(0.5 * truth / 0.5).powi(2) / 12.0; (width * height) as usize];
        let filtered = filter_grain(&s, &gathered, &variance).unwrap();
        let stats = |img: &Image| {
            let n = img.pixels.len() as f64;
            let mean = img.pixels.iter().map(|p| p[0] as f64).sum::<f64>() / n;
            let variance = img.pixels.iter().map(|p| (p[0] as f64 - truth as f64).powi(2)).sum::<f64>() / n;
            (mean, variance)
        };
        let ((mean_before, before), (mean_after, after)) = (stats(&gathered), stats(&filtered));
        assert!(after * 3.0 < before, "variance {before:e} -> {after:e}");
        assert!((mean_after - mean_before).abs() < 0.01 * truth as f64, "{mean_before} -> {mean_after}");
    }

    /// A shadow edge across one plane (irradiance 1 and 0.1, each side with a small known
    /// variance): the luminance term, in units of the estimate's standard error, keeps the edge
    /// — without it (variance unknown) the geometry alone blurs it.
    #[test]
    fn a_shadow_edge_on_a_plane_stays_where_the_variance_says_it_is_real() {
        let (width, height) = (24, 12);
        let s =
            samples(width, height, |x, y| Some(([x as f32 * 0.01, y as f32 * 0.01, 0.0], [0.0, 0.0, 1.0], [0.5; 3])));
        let light = |x: u32| if x < 12 { 0.5 } else { 0.05 }; // irradiance 1 and 0.1 under albedo 0.5
        let gathered = image(width, height, |x, _| [light(x); 3]);
        let known = vec![1e-4f32; (width * height) as usize]; // standard error 0.01
        let kept = filter_grain(&s, &gathered, &known).unwrap();
        let blurred = filter_grain(&s, &gathered, &unknown(width, height)).unwrap();
        for y in 0..height {
            for x in [11, 12] {
                let p = (y * width + x) as usize;
                let relative = (kept.pixels[p][0] - light(x)).abs() / light(x);
                assert!(relative < 1e-3, "({x}, {y}): {} against {}", kept.pixels[p][0], light(x));
            }
            let p = (y * width + 12) as usize;
            assert!(
                blurred.pixels[p][0] > 1.5 * light(12),
                "without variances the edge blurs: {}",
                blurred.pixels[p][0]
            );
        }
    }

    /// A floor meeting a wall at a crease: the floor's pixels next to the crease keep the
    /// floor's light (the normal term weighs the wall's pixels e^-50 per unit normal distance
    /// squared over σ_n²), so a bright wall does not bleed onto a dark floor.
    #[test]
    fn light_does_not_bleed_across_a_crease() {
        let (width, height) = (20, 16);
        // Columns 0..10: the floor (z = 0, normal +z); 10..20: a wall (x = 0.1, normal −x).
        let hit = |x: u32, y: u32| {
            let yy = y as f32 * 0.01;
            Some(if x < 10 {
                ([x as f32 * 0.01, yy, 0.0], [0.0, 0.0, 1.0], [0.5; 3])
            } else {
                ([0.1, yy, (x - 10) as f32 * 0.01], [-1.0, 0.0, 0.0], [0.5; 3])
            })
        };
        let s = samples(width, height, hit);
        let gathered = image(width, height, |x, _| if x < 10 { [0.01; 3] } else { [10.0; 3] });
        let filtered = filter_grain(&s, &gathered, &unknown(width, height)).unwrap();
        for y in 0..height {
            let floor_pixel = filtered.pixels[(y * width + 9) as usize][0];
            let wall_pixel = filtered.pixels[(y * width + 10) as usize][0];
            assert!((floor_pixel - 0.01).abs() < 1e-6, "floor next to the crease: {floor_pixel}");
            assert!((wall_pixel - 10.0).abs() < 1e-3, "wall next to the crease: {wall_pixel}");
        }
    }

    /// Camera misses keep their value and are not read by surface pixels. One 1e4 spike among
    /// smooth pixels whose variances are small: the luminance term keeps it from every
    /// neighbour (none moves by more than 1e-6 relative). With the spike's own huge variance
    /// blurred onto its neighbours (as the gather reports a pixel with one outlier ray), it
    /// spreads, and every value stays a convex combination: within [0.1, 1e4], finite.
    #[test]
    fn misses_keep_their_value_and_a_spike_stays_bounded() {
        let (width, height) = (16, 12);
        let s = samples(width, height, |x, y| if x < 4 { None } else { floor(x, y).map(|(p, n, _)| (p, n, [0.5; 3])) });
        let spike = (9u32, 6u32);
        let gathered = image(width, height, |x, y| {
            if x < 4 {
                [3.0; 3]
            } else if (x, y) == spike {
                [1e4; 3]
            } else {
                [0.1; 3]
            }
        });
        let index = |x: u32, y: u32| (y * width + x) as usize;
        let mut variance = vec![1e-6f32; (width * height) as usize];
        variance[index(spike.0, spike.1)] = f32::INFINITY;
        let robust = filter_grain(&s, &gathered, &variance).unwrap();
        variance[index(spike.0, spike.1)] = 1e8; // one ray of 32 carried 3.2e5
        let spread = filter_grain(&s, &gathered, &variance).unwrap();
        for y in 0..height {
            for x in 0..width {
                let (kept, moved) = (robust.pixels[index(x, y)], spread.pixels[index(x, y)]);
                assert!(kept.iter().chain(&moved).all(|v| v.is_finite()));
                if x < 4 {
                    assert_eq!(kept, [3.0; 3], "a miss keeps its value");
                    assert_eq!(moved, [3.0; 3], "a miss keeps its value");
                } else if (x, y) != spike {
                    assert!((kept[0] - 0.1).abs() <= 1e-7, "({x}, {y}): {}", kept[0]);
                    assert!(moved[0] >= 0.1 - 1e-6 && moved[0] <= 1e4, "({x}, {y}): {}", moved[0]);
                }
            }
        }
        assert!(spread.pixels[index(spike.0 + 1, spike.1)][0] > 1.0, "the spike's variance lets it spread");
        // The miss's 3.0 never reaches the surface pixels next to it.
        assert!((spread.pixels[index(4, 6)][0] - 0.1).abs() < 1e-6);
    }

    /// A 1×1 image (no neighbour, no pixel spacing: the position term is off) and an image of
    /// camera misses only come back unchanged; a pixel at 1e9 scale keeps its finite value.
    #[test]
    fn a_single_pixel_and_an_all_miss_image_come_back_unchanged() {
        let single = samples(1, 1, |_, _| Some(([1e9, -1e9, 3e8], [0.0, 1.0, 0.0], [0.4, 0.5, 0.6])));
        let gathered = image(1, 1, |_, _| [0.2, 0.3, 0.4]);
        let filtered = filter_grain(&single, &gathered, &[0.01]).unwrap();
        for c in 0..3 {
            assert!((filtered.pixels[0][c] - gathered.pixels[0][c]).abs() <= 1e-6, "{:?}", filtered.pixels);
        }
        let misses = samples(5, 3, |_, _| None);
        let gathered = image(5, 3, |x, y| [x as f32, y as f32, 1.0]);
        assert_eq!(filter_grain(&misses, &gathered, &unknown(5, 3)).unwrap().pixels, gathered.pixels);
    }

    /// Non-finite gathered values and a scene at 1e-6 scale: the output stays finite, and on
    /// the tiny plane constant light comes back (the position term is scale-free).
    #[test]
    fn non_finite_values_and_a_tiny_scene_stay_finite() {
        let tiny = samples(9, 7, |x, y| Some(([x as f32 * 1e-8, y as f32 * 1e-8, 1e-6], [0.0, 0.0, 1.0], [0.5; 3])));
        let constant = filter_grain(&tiny, &image(9, 7, |_, _| [0.3; 3]), &vec![1e-3; 63]).unwrap();
        assert!(constant.pixels.iter().all(|p| p.iter().all(|v| (v - 0.3).abs() < 1e-6)), "{:?}", constant.pixels);
        let bad = image(9, 7, |x, y| match (x, y) {
            (2, 2) => [f32::NAN; 3],
            (5, 3) => [f32::INFINITY; 3],
            _ => [0.3; 3],
        });
        let mut variance = vec![1e-3f32; 63];
        variance[10] = f32::NAN;
        variance[11] = -1.0;
        variance[30] = f32::INFINITY;
        let filtered = filter_grain(&tiny, &bad, &variance).unwrap();
        assert!(filtered.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())), "{:?}", filtered.pixels);
        let error = filter_grain(&tiny, &bad, &variance[..62]).unwrap_err().to_string();
        assert!(error.contains("62 variances"), "{error}");
    }

    #[test]
    fn a_glossy_file_is_refused_naming_the_file() {
        let mut s = samples(4, 4, floor);
        s.weight = Some(vec![[1.0; 3]; 16]);
        let error = filter_grain(&s, &image(4, 4, |_, _| [1.0; 3]), &unknown(4, 4)).unwrap_err().to_string();
        assert!(error.contains(&s.path) && error.contains("weight"), "{error}");
    }
}
