//! Beyond the paper (issue 23): an edge-aware filter of the final gather's per-pixel grain,
//! `ilfr:grain=filter` (the paper's method keeps the grain: `grain=keep`, the default).
//!
//! Why: the error that more reconstruction rays remove is mostly per-pixel grain of the final
//! gather (Eq. 3 with N rays per pixel), not the reconstruction's bias (Cornell 64², 16 spp:
//! 128 → 512 rays lift 32.95 → 37.47 dB). Taking it out with a filter that costs milliseconds
//! buys the PSNR of more rays at the time of fewer (measured in docs/ilfr.md, "Issue 23: the
//! final gather's grain, filtered").
//!
//! What: the pixel's indirect light divided by its primary hits' mean albedo (so textures are
//! not blurred; channels with albedo below 1e-3 are left as they are), one level of the
//! edge-avoiding À-Trous filter (`crate::baselines::atrous`, 5×5 B3 kernel, weights on the
//! primary hits' mean normal, σ_n = 0.2, and mean position, σ_x twice the median distance
//! between adjacent pixels' hits; no colour term), times the albedo again. Pixels whose camera
//! rays all escaped keep their value and are never read by surface pixels. Only for diffuse
//! `indirect` files: a glossy file's light is not albedo times irradiance, and filtering it
//! would blur reflections.

use super::samples::{IndirectSamples, SampleClass};
use crate::baselines::atrous::{atrous, AtrousParams};
use crate::error::Error;
use crate::gif::guide::GuideBuffers;
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

/// The gathered `image` of `samples` (a diffuse `indirect` file, [`check_input`]) with its
/// per-pixel grain filtered out.
pub fn filter_grain(samples: &IndirectSamples, image: &Image) -> Result<Image, Error> {
    let albedo = check_input(samples)?;
    if (image.width, image.height) != (samples.width, samples.height) {
        return Err(Error::size_mismatch(
            "image",
            format!("{}x{} image for {}x{} samples", image.width, image.height, samples.width, samples.height),
        ));
    }
    let (guide, mean_albedo) = pixel_guide(samples, albedo);
    let divided: Vec<[f32; 3]> = image
        .pixels
        .iter()
        .zip(&mean_albedo)
        .map(|(value, albedo)| {
            std::array::from_fn(|c| if albedo[c] > MIN_ALBEDO { value[c] / albedo[c] } else { value[c] })
        })
        .collect();
    let params = AtrousParams { iterations: 1, ..AtrousParams::default() };
    let (filtered, _) = atrous(&Image::from_pixels(image.width, image.height, divided), &guide, &params)?;
    let pixels = filtered
        .pixels
        .iter()
        .zip(&mean_albedo)
        .zip(&image.pixels)
        .zip(&guide.depth)
        .map(|(((value, albedo), gathered), &depth)| {
            if depth == 0.0 {
                return *gathered;
            }
            std::array::from_fn(|c| if albedo[c] > MIN_ALBEDO { value[c] * albedo[c] } else { value[c] })
        })
        .collect();
    Ok(Image::from_pixels(image.width, image.height, pixels))
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
        let filtered = filter_grain(&s, &gathered).unwrap();
        for (f, g) in filtered.pixels.iter().zip(&gathered.pixels) {
            for c in 0..3 {
                assert!((f[c] - g[c]).abs() <= 1e-5 * g[c].max(1e-3), "{f:?} vs {g:?}");
            }
        }
    }

    /// Independent grain on one plane: the variance about the true value falls at least
    /// threefold (one 5×5 B3 level averages Σh² ≈ 0.08 of the pixels' variance on a plane),
    /// and the mean stays.
    #[test]
    fn grain_on_a_plane_falls_at_least_threefold() {
        let (width, height) = (48, 40);
        let s =
            samples(width, height, |x, y| Some(([x as f32 * 0.01, y as f32 * 0.01, 0.0], [0.0, 0.0, 1.0], [0.5; 3])));
        let mut rng = Lcg(7);
        let truth = 0.25f32;
        let gathered = image(width, height, |_, _| [truth * (1.0 + 0.5 * (rng.uniform() - 0.5)); 3]);
        let filtered = filter_grain(&s, &gathered).unwrap();
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
        let filtered = filter_grain(&s, &gathered).unwrap();
        for y in 0..height {
            let floor_pixel = filtered.pixels[(y * width + 9) as usize][0];
            let wall_pixel = filtered.pixels[(y * width + 10) as usize][0];
            assert!((floor_pixel - 0.01).abs() < 1e-6, "floor next to the crease: {floor_pixel}");
            assert!((wall_pixel - 10.0).abs() < 1e-3, "wall next to the crease: {wall_pixel}");
        }
    }

    /// Camera misses keep their value and are not read by surface pixels; one 1e4 spike moves
    /// a neighbour by at most its kernel weight (3/8 · 3/8 of the window at most, renormalised
    /// over the taps that count) and nothing is non-finite.
    #[test]
    fn misses_keep_their_value_and_a_spike_stays_bounded() {
        let (width, height) = (16, 12);
        let s = samples(width, height, |x, y| if x < 4 { None } else { floor(x, y).map(|(p, n, _)| (p, n, [0.5; 3])) });
        let gathered = image(width, height, |x, y| {
            if x < 4 {
                [3.0; 3]
            } else if (x, y) == (9, 6) {
                [1e4; 3]
            } else {
                [0.1; 3]
            }
        });
        let filtered = filter_grain(&s, &gathered).unwrap();
        for y in 0..height {
            for x in 0..width {
                let value = filtered.pixels[(y * width + x) as usize];
                assert!(value.iter().all(|v| v.is_finite()));
                if x < 4 {
                    assert_eq!(value, [3.0; 3], "a miss keeps its value");
                } else if (x, y) != (9, 6) {
                    let bound = 0.1 + 1e4 * (3.0 / 8.0) * (3.0 / 8.0) / (1.0 - (3.0 / 8.0) * (3.0 / 8.0));
                    assert!(value[0] >= 0.1 - 1e-6 && value[0] <= bound, "({x}, {y}): {}", value[0]);
                }
            }
        }
        // The miss's 3.0 never reaches the surface pixels next to it.
        assert!((filtered.pixels[(6 * width + 4) as usize][0] - 0.1).abs() < 1e-6);
    }

    /// A 1×1 image (no neighbour, no pixel spacing: the position term is off) and an image of
    /// camera misses only come back unchanged; a pixel at 1e9 scale keeps its finite value.
    #[test]
    fn a_single_pixel_and_an_all_miss_image_come_back_unchanged() {
        let single = samples(1, 1, |_, _| Some(([1e9, -1e9, 3e8], [0.0, 1.0, 0.0], [0.4, 0.5, 0.6])));
        let gathered = image(1, 1, |_, _| [0.2, 0.3, 0.4]);
        let filtered = filter_grain(&single, &gathered).unwrap();
        for c in 0..3 {
            assert!((filtered.pixels[0][c] - gathered.pixels[0][c]).abs() <= 1e-6, "{:?}", filtered.pixels);
        }
        let misses = samples(5, 3, |_, _| None);
        let gathered = image(5, 3, |x, y| [x as f32, y as f32, 1.0]);
        assert_eq!(filter_grain(&misses, &gathered).unwrap().pixels, gathered.pixels);
    }

    /// Non-finite gathered values and a scene at 1e-6 scale: the output stays finite, and on
    /// the tiny plane constant light comes back (the position term is scale-free).
    #[test]
    fn non_finite_values_and_a_tiny_scene_stay_finite() {
        let tiny = samples(9, 7, |x, y| Some(([x as f32 * 1e-8, y as f32 * 1e-8, 1e-6], [0.0, 0.0, 1.0], [0.5; 3])));
        let constant = filter_grain(&tiny, &image(9, 7, |_, _| [0.3; 3])).unwrap();
        assert!(constant.pixels.iter().all(|p| p.iter().all(|v| (v - 0.3).abs() < 1e-6)), "{:?}", constant.pixels);
        let bad = image(9, 7, |x, y| match (x, y) {
            (2, 2) => [f32::NAN; 3],
            (5, 3) => [f32::INFINITY; 3],
            _ => [0.3; 3],
        });
        let filtered = filter_grain(&tiny, &bad).unwrap();
        assert!(filtered.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())), "{:?}", filtered.pixels);
    }

    #[test]
    fn a_glossy_file_is_refused_naming_the_file() {
        let mut s = samples(4, 4, floor);
        s.weight = Some(vec![[1.0; 3]; 16]);
        let error = filter_grain(&s, &image(4, 4, |_, _| [1.0; 3])).unwrap_err().to_string();
        assert!(error.contains(&s.path) && error.contains("weight"), "{error}");
    }
}
