//! Supersampling by additional eye rays and the composite of the filtered path-tracing
//! pipeline (Bauszat, Eisemann, Magnor 2011, Section 3.2 and the last paragraph of 3.1):
//!
//! | paper | here |
//! |---|---|
//! | "the first sample is always sent through the center of the pixel" (the guide ray) | `GuideInput::guide`, its filtered incident light remodulated with its own albedo |
//! | "for the following pixel samples the indirect lighting is taken from the filtered indirect illumination map using a geometry-aware lookup" | `composite`: each `EyeRay` takes the incident light of `most_similar_guide` times its own albedo |
//! | Eq. 3, `S_i = s_N,i · s_D,i` over the four neighbouring guide rays i = 0..3 | `most_similar_guide` |
//! | Eq. 4, `s_N,i = 1 − ‖N_a − N_i‖ / max_j ‖N_a − N_j‖` | `normal_distance`, normalised in `most_similar_guide` |
//! | Eq. 5, `s_D,i = 1 − |D_a − D_i| / max_j |D_a − D_j|` | `most_similar_guide` |
//! | "for all samples, the guide ray and the following samples, the direct lighting is estimated as in the default path tracing pipeline" | `EyeRay::direct`, `GuideInput::direct` |
//! | Section 4, "a simple box reconstruction filter" | `composite` averages a pixel's eye rays with equal weights |
//! | (for measurement) the naive reuse of the pixel's own guide ray | `Lookup::OwnPixel` |
//!
//! Choices the paper leaves open, and why:
//! - The four neighbours are the guide rays (pixel centres) at the corners of the cell of the
//!   pixel-centre grid that contains the eye ray's film position, clamped at the image border
//!   (fewer than four distinct neighbours there).
//! - Neighbours whose guide ray escaped have no indirect estimate and are not candidates. An
//!   eye ray with no candidate (the paper's Figure 3b: geometry smaller than a pixel, seen by
//!   no guide ray) gets no indirect light, and is counted (`Composite::unmatched_eye_rays`).
//! - When every candidate is equally far (max = 0 in Eq. 4 or 5), that similarity is 1 for all.
//!   Ties in S (e.g. two candidates, one closer in normal, the other in depth: both S = 0) go to
//!   the candidate whose pixel centre is nearest the eye ray's film position.
//! - The map holds *incident* light (`modulation::demodulate`), so the eye ray's own
//!   albedo multiplies it: texture detail between guide rays is kept. The guide ray itself is
//!   remodulated as `modulation::remodulated` does (its channels without albedo keep
//!   their unfiltered value).
//! - Non-finite eye-ray values are treated as a miss (normal, depth) or as 0 (albedo, direct)
//!   and counted in `Composite::sanitised_values`.

use rayon::prelude::*;

use crate::error::Error;
use crate::gif::modulation::remodulated;
use crate::guide::{EyeRay, EyeRays, GuideBuffers};
use crate::image::Image;

/// The reconstructed image, split as the tracer splits it.
#[derive(Clone, Debug)]
pub struct Composite {
    /// Indirect light: box mean over the pixel's eye rays of albedo × filtered incident light.
    pub indirect: Image,
    /// Emitted and directly reflected light: box mean over the pixel's eye rays.
    pub direct: Image,
    /// `direct + indirect`.
    pub beauty: Image,
    /// Eye rays that hit geometry while none of their neighbouring guide rays did.
    pub unmatched_eye_rays: usize,
    /// Non-finite eye-ray values replaced (see the module notes).
    pub sanitised_values: usize,
}

fn is_hit(normal: [f32; 3], depth: f32) -> bool {
    normal != [0.0; 3] && normal.iter().all(|c| c.is_finite()) && depth.is_finite() && depth > 0.0
}

fn normal_distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Eq. 3–5: the index (row-major) of the neighbouring guide ray most similar to an eye ray
/// that hit geometry with `normal` and `depth` at `film`; `None` when no neighbour hit.
pub fn most_similar_guide(guide: &GuideBuffers, film: [f32; 2], normal: [f32; 3], depth: f32) -> Option<usize> {
    let (width, height) = (guide.width as i64, guide.height as i64);
    if width == 0 || height == 0 {
        return None;
    }
    // The cell of the pixel-centre grid around `film`: centres at (x + 0.5, y + 0.5).
    let (fx, fy) = (film[0] - 0.5, film[1] - 0.5);
    let (fx, fy) = (if fx.is_finite() { fx } else { 0.0 }, if fy.is_finite() { fy } else { 0.0 });
    let x0 = (fx.floor() as i64).clamp(0, width - 1);
    let y0 = (fy.floor() as i64).clamp(0, height - 1);
    let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
    // At most four candidates, kept on the stack: this runs once per eye ray.
    // Each: (distance² to the film position, pixel index, normal distance, depth distance).
    let mut candidates = [(0.0f32, 0usize, 0.0f32, 0.0f32); 4];
    let mut count = 0;
    for y in [y0, y1] {
        for x in [x0, x1] {
            let index = (y * width + x) as usize;
            if candidates[..count].iter().any(|c| c.1 == index) || !is_hit(guide.normal[index], guide.depth[index]) {
                continue;
            }
            let distance = (x as f32 - fx).powi(2) + (y as f32 - fy).powi(2);
            let normal_gap = normal_distance(normal, guide.normal[index]);
            candidates[count] = (distance, index, normal_gap, (depth - guide.depth[index]).abs());
            count += 1;
        }
    }
    let candidates = &mut candidates[..count];
    // Nearest first, so that ties in S go to the nearest guide ray.
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let max_normal = candidates.iter().fold(0.0f32, |m, c| m.max(c.2));
    let max_depth = candidates.iter().fold(0.0f32, |m, c| m.max(c.3));
    let similarity = |distance: f32, max: f32| if max > 0.0 { 1.0 - distance / max } else { 1.0 };
    let mut best: Option<(f32, usize)> = None;
    for &(_, index, normal_gap, depth_gap) in candidates.iter() {
        let s = similarity(normal_gap, max_normal) * similarity(depth_gap, max_depth);
        if best.map_or(true, |(best_s, _)| s > best_s) {
            best = Some((s, index));
        }
    }
    best.map(|(_, index)| index)
}

/// An eye ray with its non-finite values replaced; returns it and how many were replaced.
fn sanitised(ray: &EyeRay) -> (EyeRay, usize) {
    let mut count = 0;
    let mut clean = *ray;
    if !(ray.normal.iter().all(|c| c.is_finite()) && ray.depth.is_finite()) {
        clean.normal = [0.0; 3];
        clean.depth = 0.0;
        count += 1;
    }
    for value in clean.albedo.iter_mut().chain(clean.direct.iter_mut()) {
        if !value.is_finite() {
            *value = 0.0;
            count += 1;
        }
    }
    (clean, count)
}

/// Where an additional eye ray takes its indirect light from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Lookup {
    /// The most similar of the four neighbouring guide rays (Eq. 3–5).
    #[default]
    GeometryAware,
    /// The guide ray of the eye ray's own pixel, whatever it hit: the naive reuse the paper's
    /// lookup replaces (kept to measure what the lookup gains).
    OwnPixel,
}

/// What the guide rays saw: their hits, the albedo there, the direct light and the noisy
/// (unfiltered) indirect light reflected there.
#[derive(Clone, Copy, Debug)]
pub struct GuideLight<'a> {
    pub guide: &'a GuideBuffers,
    pub albedo: &'a Image,
    pub direct: &'a Image,
    pub reflected: &'a Image,
}

/// Combines the filtered incident light at the guide hits (`incident`, e.g. the guided
/// filter's output on the demodulated map) with the guide rays' direct light and the
/// additional eye rays into the final pixels (box filter over each pixel's eye rays), looking
/// up the eye rays' indirect light as `lookup` says.
pub fn composite(
    guide_light: GuideLight,
    incident: &Image,
    eye_rays: &EyeRays,
    lookup: Lookup,
) -> Result<Composite, Error> {
    let GuideLight { guide, albedo: guide_albedo, direct: guide_direct, reflected: guide_reflected } = guide_light;
    let (width, height) = (guide.width, guide.height);
    let count = guide.pixel_count();
    if !guide.is_consistent() {
        return Err(Error::size_mismatch(
            "guide buffers",
            format!("the guide buffers do not all have {width}x{height} entries"),
        ));
    }
    for (name, image) in [
        ("albedo", guide_albedo),
        ("direct", guide_direct),
        ("reflected indirect", guide_reflected),
        ("filtered incident", incident),
    ] {
        if (image.width, image.height) != (width, height) || image.pixels.len() != count {
            let message = format!("the {name} image is {}x{}, the guide {width}x{height}", image.width, image.height);
            return Err(Error::size_mismatch(name, message));
        }
    }
    let per_pixel = eye_rays.per_pixel as usize;
    if eye_rays.rays.len() != count * per_pixel {
        let message = format!(
            "{} eye rays for {count} pixels at {per_pixel} per pixel (expected {})",
            eye_rays.rays.len(),
            count * per_pixel
        );
        return Err(Error::size_mismatch("eye rays", message));
    }
    let weight = 1.0 / (per_pixel + 1) as f32;
    let pixels: Vec<([f32; 3], [f32; 3], usize, usize)> = (0..count)
        .into_par_iter()
        .map(|index| {
            let mut indirect =
                remodulated(incident.pixels[index], guide_albedo.pixels[index], guide_reflected.pixels[index]);
            let mut direct = guide_direct.pixels[index];
            let (mut unmatched, mut replaced) = (0, 0);
            for ray in eye_rays.of_pixel(index) {
                let (ray, count) = sanitised(ray);
                replaced += count;
                direct = [0, 1, 2].map(|c| direct[c] + ray.direct[c]);
                if !is_hit(ray.normal, ray.depth) {
                    continue;
                }
                let source = match lookup {
                    Lookup::GeometryAware => most_similar_guide(guide, ray.film, ray.normal, ray.depth),
                    Lookup::OwnPixel => Some(index).filter(|&i| is_hit(guide.normal[i], guide.depth[i])),
                };
                match source {
                    Some(source) => {
                        let light = incident.pixels[source];
                        indirect = [0, 1, 2].map(|c| indirect[c] + ray.albedo[c] * light[c]);
                    }
                    None => unmatched += 1,
                }
            }
            (indirect.map(|v| v * weight), direct.map(|v| v * weight), unmatched, replaced)
        })
        .collect();
    let indirect: Vec<[f32; 3]> = pixels.iter().map(|p| p.0).collect();
    let direct: Vec<[f32; 3]> = pixels.iter().map(|p| p.1).collect();
    let beauty = indirect.iter().zip(&direct).map(|(i, d)| [0, 1, 2].map(|c| i[c] + d[c])).collect();
    Ok(Composite {
        indirect: Image::from_pixels(width, height, indirect),
        direct: Image::from_pixels(width, height, direct),
        beauty: Image::from_pixels(width, height, beauty),
        unmatched_eye_rays: pixels.iter().map(|p| p.2).sum(),
        sanitised_values: pixels.iter().map(|p| p.3).sum(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A guide of two walls: the left half faces +z at depth 2, the right half faces +x at
    /// depth 5 (a crease seen through a silhouette).
    fn two_walls(width: u32, height: u32) -> GuideBuffers {
        let n = (width * height) as usize;
        let left = |i: usize| (i as u32 % width) < width / 2;
        GuideBuffers {
            width,
            height,
            normal: (0..n).map(|i| if left(i) { [0.0, 0.0, 1.0] } else { [1.0, 0.0, 0.0] }).collect(),
            depth: (0..n).map(|i| if left(i) { 2.0 } else { 5.0 }).collect(),
            position: vec![[0.0; 3]; n],
            secondary_normal: None,
        }
    }

    #[test]
    fn the_lookup_picks_the_neighbour_on_the_same_surface() {
        let guide = two_walls(8, 4);
        // Film x = 3.9 lies between the centres of pixels 3 (left wall) and 4 (right wall).
        let left = most_similar_guide(&guide, [3.9, 1.5], [0.0, 0.0, 1.0], 2.1).unwrap();
        assert_eq!(left % 8, 3, "a left-wall eye ray must take a left-wall guide, got pixel {left}");
        let right = most_similar_guide(&guide, [3.6, 1.5], [1.0, 0.0, 0.0], 4.9).unwrap();
        assert_eq!(right % 8, 4, "a right-wall eye ray must take a right-wall guide, got pixel {right}");
    }

    #[test]
    fn ties_go_to_the_nearest_guide_ray() {
        let n = 16;
        let guide = GuideBuffers {
            width: 4,
            height: 4,
            normal: vec![[0.0, 0.0, 1.0]; n],
            depth: vec![3.0; n],
            position: vec![[0.0; 3]; n],
            secondary_normal: None,
        };
        // All four neighbours are identical (max = 0 in Eq. 4 and 5): the nearest wins.
        assert_eq!(most_similar_guide(&guide, [1.6, 2.4], [0.0, 0.0, 1.0], 3.0), Some(2 * 4 + 1));
        assert_eq!(most_similar_guide(&guide, [2.4, 1.6], [0.0, 0.0, 1.0], 3.0), Some(4 + 2));
        // At the border the cell is clamped to the image.
        assert_eq!(most_similar_guide(&guide, [0.1, 0.1], [0.0, 0.0, 1.0], 3.0), Some(0));
        assert_eq!(most_similar_guide(&guide, [3.9, 3.9], [0.0, 0.0, 1.0], 3.0), Some(15));
    }

    #[test]
    fn escaped_guide_rays_are_not_candidates() {
        let mut guide = two_walls(4, 1);
        for i in 0..2 {
            guide.normal[i] = [0.0; 3];
            guide.depth[i] = 0.0;
        }
        // Near pixel 1 (escaped); only pixel 2 hit among the neighbours 1 and 2.
        assert_eq!(most_similar_guide(&guide, [1.7, 0.5], [0.0, 0.0, 1.0], 2.0), Some(2));
        // Between pixels 0 and 1, both escaped: nothing to take.
        assert_eq!(most_similar_guide(&guide, [0.9, 0.5], [0.0, 0.0, 1.0], 2.0), None);
        let one = GuideBuffers { width: 1, height: 1, ..two_walls(1, 1) };
        assert_eq!(most_similar_guide(&one, [0.5, 0.5], [0.0, 0.0, 1.0], 2.0), Some(0));
    }

    fn eye_ray(film: [f32; 2], normal: [f32; 3], depth: f32, albedo: f32, direct: f32) -> EyeRay {
        EyeRay { film, normal, depth, albedo: [albedo; 3], direct: [direct; 3] }
    }

    #[test]
    fn composite_box_filters_direct_and_remodulates_with_each_rays_albedo() {
        // One pixel, incident light 2 at the guide hit of albedo 0.5; two extra eye rays on the
        // same surface with albedos 0.25 and 1.0, and one that escaped.
        let guide = GuideBuffers { width: 1, height: 1, ..two_walls(1, 1) };
        let image = |v: f32| Image::from_pixels(1, 1, vec![[v; 3]]);
        let eye_rays = EyeRays {
            per_pixel: 3,
            rays: vec![
                eye_ray([0.2, 0.3], [0.0, 0.0, 1.0], 2.0, 0.25, 1.0),
                eye_ray([0.7, 0.8], [0.0, 0.0, 1.0], 2.0, 1.0, 3.0),
                eye_ray([0.5, 0.5], [0.0; 3], 0.0, 0.0, 8.0),
            ],
        };
        let (albedo, direct, reflected) = (image(0.5), image(4.0), image(1.0));
        let light = GuideLight { guide: &guide, albedo: &albedo, direct: &direct, reflected: &reflected };
        let result = composite(light, &image(2.0), &eye_rays, Lookup::GeometryAware).unwrap();
        let expected_indirect = (0.5 * 2.0 + 0.25 * 2.0 + 1.0 * 2.0 + 0.0) / 4.0;
        let expected_direct = (4.0 + 1.0 + 3.0 + 8.0) / 4.0;
        assert!((result.indirect.pixels[0][0] - expected_indirect).abs() < 1e-6);
        assert!((result.direct.pixels[0][0] - expected_direct).abs() < 1e-6);
        assert!((result.beauty.pixels[0][1] - expected_indirect - expected_direct).abs() < 1e-6);
        assert_eq!(result.unmatched_eye_rays, 0);
    }

    #[test]
    fn without_eye_rays_the_composite_is_the_remodulated_guide() {
        let guide = two_walls(5, 3);
        let incident = Image::from_pixels(5, 3, (0..15).map(|i| [i as f32, 1.0, 0.5]).collect());
        let albedo = Image::from_pixels(5, 3, vec![[0.5, 0.0, 1.0]; 15]);
        let direct = Image::from_pixels(5, 3, vec![[0.1; 3]; 15]);
        let reflected = Image::from_pixels(5, 3, vec![[0.3, 0.02, 0.4]; 15]);
        let light = GuideLight { guide: &guide, albedo: &albedo, direct: &direct, reflected: &reflected };
        let result = composite(light, &incident, &EyeRays::default(), Lookup::GeometryAware).unwrap();
        for (i, p) in result.indirect.pixels.iter().enumerate() {
            // Albedo 0 in green: below MIN_ALBEDO, the unfiltered reflected value stays.
            assert_eq!(*p, [0.5 * i as f32, 0.02, 0.5]);
        }
        assert_eq!(result.direct.pixels, direct.pixels);
    }

    #[test]
    fn a_silhouette_pixel_mixes_the_two_surfaces_by_coverage() {
        // Pixel 3 of a row sits on the left wall at its centre, but half of its eye rays see the
        // right wall: the right wall's incident light (4) must reach them, not the left's (1).
        let guide = two_walls(8, 1);
        let incident = Image::from_pixels(8, 1, (0..8).map(|x| if x < 4 { [1.0; 3] } else { [4.0; 3] }).collect());
        let albedo = Image::from_pixels(8, 1, vec![[1.0; 3]; 8]);
        let direct = Image::from_pixels(8, 1, vec![[0.0; 3]; 8]);
        let mut rays = vec![EyeRay::default(); 8 * 3];
        for (x, chunk) in rays.chunks_mut(3).enumerate() {
            for (k, ray) in chunk.iter_mut().enumerate() {
                let film = [x as f32 + 0.25 + 0.25 * k as f32, 0.5];
                // Pixel 3: its two extra eye rays at x = 3.5 and 3.75 see the right wall.
                let right = x >= 4 || (x == 3 && k >= 1);
                *ray = if right {
                    eye_ray(film, [1.0, 0.0, 0.0], 5.0, 1.0, 0.0)
                } else {
                    eye_ray(film, [0.0, 0.0, 1.0], 2.0, 1.0, 0.0)
                };
            }
        }
        let light = GuideLight { guide: &guide, albedo: &albedo, direct: &direct, reflected: &incident };
        let result = composite(light, &incident, &EyeRays { per_pixel: 3, rays }, Lookup::GeometryAware).unwrap();
        assert!((result.indirect.pixels[3][0] - (1.0 + 1.0 + 4.0 + 4.0) / 4.0).abs() < 1e-6, "{:?}", result.indirect);
        assert_eq!(result.indirect.pixels[2][0], 1.0);
        assert_eq!(result.indirect.pixels[5][0], 4.0);
    }

    #[test]
    fn the_own_pixel_lookup_bleeds_across_the_silhouette() {
        // As `a_silhouette_pixel_mixes_the_two_surfaces_by_coverage`, but the eye rays of pixel 3
        // that see the right wall take the left wall's light from their own pixel's guide ray.
        let guide = two_walls(4, 1);
        let incident = Image::from_pixels(4, 1, vec![[1.0; 3], [1.0; 3], [4.0; 3], [4.0; 3]]);
        let ones = Image::from_pixels(4, 1, vec![[1.0; 3]; 4]);
        let zeros = Image::from_pixels(4, 1, vec![[0.0; 3]; 4]);
        let mut rays = vec![eye_ray([0.5, 0.5], [0.0, 0.0, 1.0], 2.0, 1.0, 0.0); 4];
        rays[1] = eye_ray([1.9, 0.5], [1.0, 0.0, 0.0], 5.0, 1.0, 0.0); // pixel 1, right wall
        for (k, ray) in rays.iter_mut().enumerate() {
            ray.film[0] = ray.film[0].max(k as f32 + 0.5).min(k as f32 + 0.99);
            if k >= 2 {
                *ray = eye_ray([k as f32 + 0.5, 0.5], [1.0, 0.0, 0.0], 5.0, 1.0, 0.0);
            }
        }
        let rays = EyeRays { per_pixel: 1, rays };
        let light = GuideLight { guide: &guide, albedo: &ones, direct: &zeros, reflected: &incident };
        let aware = composite(light, &incident, &rays, Lookup::GeometryAware).unwrap();
        let naive = composite(light, &incident, &rays, Lookup::OwnPixel).unwrap();
        assert_eq!(aware.indirect.pixels[1][0], (1.0 + 4.0) / 2.0, "the right-wall eye ray takes pixel 2's light");
        assert_eq!(naive.indirect.pixels[1][0], 1.0, "the naive lookup takes its own pixel's light");
        assert_eq!(aware.indirect.pixels[3], naive.indirect.pixels[3]);
    }

    #[test]
    fn unmatched_and_nonfinite_eye_rays_are_counted_not_propagated() {
        let mut guide = two_walls(2, 1);
        guide.normal = vec![[0.0; 3]; 2];
        guide.depth = vec![0.0; 2];
        let image = |v: f32| Image::from_pixels(2, 1, vec![[v; 3]; 2]);
        let rays = vec![
            eye_ray([0.5, 0.5], [0.0, 0.0, 1.0], 2.0, 0.5, 1.0),
            eye_ray([1.5, 0.5], [f32::NAN, 0.0, 1.0], 2.0, f32::INFINITY, f32::NAN),
        ];
        let (zeros, ones) = (image(0.0), image(1.0));
        let light = GuideLight { guide: &guide, albedo: &zeros, direct: &zeros, reflected: &zeros };
        let result = composite(light, &ones, &EyeRays { per_pixel: 1, rays }, Lookup::GeometryAware).unwrap();
        assert_eq!(result.unmatched_eye_rays, 1);
        assert_eq!(result.sanitised_values, 1 + 3 + 3);
        assert_eq!(result.beauty.nonfinite_pixels(), 0);
    }

    #[test]
    fn mismatched_sizes_are_errors() {
        let guide = two_walls(2, 2);
        let image = |w: u32, h: u32| Image::from_pixels(w, h, vec![[0.0; 3]; (w * h) as usize]);
        let none = EyeRays::default();
        let (small, right) = (image(2, 1), image(2, 2));
        let light = GuideLight { guide: &guide, albedo: &small, direct: &right, reflected: &right };
        assert!(composite(light, &right, &none, Lookup::GeometryAware).is_err());
        let light = GuideLight { albedo: &right, ..light };
        assert!(composite(light, &small, &none, Lookup::GeometryAware).is_err());
        let short = EyeRays { per_pixel: 2, rays: vec![EyeRay::default(); 7] };
        let error = composite(light, &right, &short, Lookup::GeometryAware).unwrap_err().to_string();
        assert!(error.contains("7 eye rays"), "{error}");
    }
}
