//! Demodulation of the indirect light (Bauszat et al. 2011, Section 3.3: the filter smooths
//! the *incident* illumination): reflected light divided by the guide hit's albedo before the
//! filter, multiplied back after it, by the filtered pipeline (`filtered_indirect`) and by each
//! additional eye ray with its own albedo (`eye_rays`).

use crate::image::Image;

/// Albedo below which a channel is not demodulated.
pub const MIN_ALBEDO: f32 = 1e-3;

/// Incident light: reflected light divided by the albedo, per channel. A channel whose albedo
/// is below `MIN_ALBEDO` cannot be demodulated; it gets the grey incident light of the
/// pixel's other channels (their reflected sum over their albedo sum), so that its value in
/// the map is a plausible neighbour for the filter rather than a reflected value near 0 (or,
/// had it been divided, a huge one). Where no channel can be demodulated (black surfaces) the
/// reflected value stays.
pub fn demodulate(reflected: &Image, albedo: &Image) -> Image {
    let pixels = reflected
        .pixels
        .iter()
        .zip(&albedo.pixels)
        .map(|(r, a)| {
            let (mut reflected_sum, mut albedo_sum) = (0.0, 0.0);
            for c in (0..3).filter(|&c| a[c] >= MIN_ALBEDO) {
                reflected_sum += r[c];
                albedo_sum += a[c];
            }
            [0, 1, 2].map(|c| {
                if a[c] >= MIN_ALBEDO {
                    r[c] / a[c]
                } else if albedo_sum > 0.0 {
                    reflected_sum / albedo_sum
                } else {
                    r[c]
                }
            })
        })
        .collect();
    Image::from_pixels(reflected.width, reflected.height, pixels)
}

/// Reflected light at the guide hits from the filtered incident light: `incident × albedo` in
/// the channels `demodulate` divided; elsewhere the unfiltered `reflected` value itself (tiny:
/// the albedo is below `MIN_ALBEDO`; non-finite values become 0).
pub fn remodulate(incident: &Image, albedo: &Image, reflected: &Image) -> Image {
    let pixels = incident
        .pixels
        .iter()
        .zip(&albedo.pixels)
        .zip(&reflected.pixels)
        .map(|((l, a), r)| remodulated(*l, *a, *r))
        .collect();
    Image::from_pixels(incident.width, incident.height, pixels)
}

/// `remodulate` for one pixel.
pub fn remodulated(incident: [f32; 3], albedo: [f32; 3], reflected: [f32; 3]) -> [f32; 3] {
    [0, 1, 2].map(|c| {
        if albedo[c] >= MIN_ALBEDO {
            incident[c] * albedo[c]
        } else if reflected[c].is_finite() {
            reflected[c]
        } else {
            0.0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demodulation_round_trips_and_skips_black_albedo() {
        let reflected = Image::from_pixels(2, 1, vec![[0.5, 0.2, 0.0], [1.0, 1.0, 1.0]]);
        let albedo = Image::from_pixels(2, 1, vec![[0.5, 0.0, 0.25], [1.0, 0.5, 0.1]]);
        let incident = demodulate(&reflected, &albedo);
        // Green cannot be demodulated: it gets red and blue's grey incident light (0.5 / 0.75).
        assert_eq!(incident.pixels[1], [1.0, 2.0, 10.0]);
        assert_eq!(incident.pixels[0][0], 1.0);
        assert!((incident.pixels[0][1] - 0.5 / 0.75).abs() < 1e-6 && incident.pixels[0][2] == 0.0);
        let black = demodulate(&Image::from_pixels(1, 1, vec![[0.01; 3]]), &Image::from_pixels(1, 1, vec![[0.0; 3]]));
        assert_eq!(black.pixels[0], [0.01; 3], "a black surface keeps its reflected value");
        let back = remodulate(&incident, &albedo, &reflected);
        for (a, b) in back.pixels.iter().flatten().zip(reflected.pixels.iter().flatten()) {
            assert!((a - b).abs() < 1e-6);
        }
    }
}
