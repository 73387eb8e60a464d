//! The filtered path-tracing pipeline of Bauszat, Eisemann and Magnor 2011 (Section 3), with the
//! filter pluggable so that the guided filter and its baselines run on identical inputs:
//!
//! | paper | here |
//! |---|---|
//! | 3.1 separation of direct and indirect light | the harness's `Input::Guide`: indirect light only, estimated at the guide hit |
//! | 3.2 one guide ray per pixel through its centre, normal and depth recorded | `GuideInput::guide` |
//! | 3.3 filtering the *incident* indirect illumination | `demodulate` (divide by the guide hit's albedo), `FilteredIndirect::filter_indirect`, `remodulate` |
//! | 4 radius 24–32 px (at ~800 px) | `scaled_radius`: the radius scales with the image |
//! | 3.2 additional eye rays with the geometry-aware lookup (Eq. 3–5), direct light per eye ray, box filter, composite | `FilteredIndirect::reconstruct` → `eye_rays::composite` |
//!
//! Methods: `gif` (guided image filter, normal + depth guide, `guided_filter`), `gif-normal`
//! and `gif-grey` (the 3-channel normal and 1-channel grey-normal guides of the paper's
//! Figure 5), `bilateral` (cross-bilateral on normal and depth, `baselines/bilateral.rs`), `atrous`
//! (edge-avoiding À-Trous, `baselines/atrous.rs`) and `atrous-sn` (À-Trous with the extra range term on
//! the secondary-hit normal, as the indirect light field paper's comparison used it).
//!
//! Non-negativity: the guided filter's output is clamped at 0. Its local linear model can
//! undershoot beside guide edges, most with the fast filter (`subsample`), whose coefficients
//! are fitted on block means and applied to the full-resolution guide; the other filters are
//! convex combinations and never do.
//!
//! Demodulation: the filter smooths the light arriving at the surface, not the texture that
//! reflects it. Where a channel's albedo is below `modulation::MIN_ALBEDO` the incident light cannot be
//! recovered: the map gets the pixel's grey incident light from its other channels (a sensible
//! neighbour for the filter), and the pixel's own output keeps its unfiltered reflected value
//! (tiny anyway). An earlier version kept the reflected value in the map and passed the
//! *filtered* value through: on Sponza's saturated banners (sRGB texels of 0 in a channel) the
//! neighbours' incident light then came out as bright coloured speckle.

use std::time::Instant;

use crate::baselines::atrous::{atrous, AtrousParams};
use crate::baselines::bilateral::{cross_bilateral, BilateralParams};
use crate::error::Error;
use crate::gif::eye_rays::{composite, Composite, GuideLight, Lookup};
use crate::gif::guided_filter::{guided_filter, GuideKind, GuidedFilterParams};
use crate::gif::modulation::{demodulate, remodulate};
use crate::image::Image;
use crate::method::{GuideInput, Input, Inputs, Method, MethodError, Output, Stats};
use crate::options::Options;

/// The image size the paper's radii (24–32 pixels) refer to: its figures are about 800 pixels
/// wide.
pub const PAPER_IMAGE_SIZE: f32 = 800.0;

/// A window radius given for an 800-pixel image, scaled to this image's larger side (at least
/// 1): the filter's footprint is a fixed fraction of the image, as in the paper. Measured on
/// the Cornell box at 128²: radius 24 unscaled gives 15.8 dB, radius 8 gives 21.3 dB.
pub fn scaled_radius(radius_at_800: u32, width: u32, height: u32) -> u32 {
    let scale = width.max(height) as f32 / PAPER_IMAGE_SIZE;
    ((radius_at_800 as f32 * scale).round() as u32).max(1)
}

/// Which filter the pipeline runs.
#[derive(Clone, Debug)]
pub enum Filter {
    Guided(GuidedFilterParams),
    Bilateral(BilateralParams),
    Atrous(AtrousParams),
}

/// A filter of the incident indirect light, as a `Method`.
#[derive(Clone, Debug)]
pub struct FilteredIndirect {
    /// The variant's name (`gif`, `atrous-sn`, …), for messages.
    pub name: String,
    pub filter: Filter,
    /// How the additional eye rays find their indirect light.
    pub lookup: Lookup,
}

impl FilteredIndirect {
    pub fn gif() -> FilteredIndirect {
        FilteredIndirect {
            name: "gif".into(),
            filter: Filter::Guided(GuidedFilterParams::default()),
            lookup: Lookup::GeometryAware,
        }
    }

    pub fn bilateral() -> FilteredIndirect {
        FilteredIndirect {
            name: "bilateral".into(),
            filter: Filter::Bilateral(BilateralParams::default()),
            lookup: Lookup::GeometryAware,
        }
    }

    pub fn atrous() -> FilteredIndirect {
        FilteredIndirect {
            name: "atrous".into(),
            filter: Filter::Atrous(AtrousParams::default()),
            lookup: Lookup::GeometryAware,
        }
    }

    /// The guided filter with the full normal as guide (Figure 5b).
    pub fn gif_normal() -> FilteredIndirect {
        FilteredIndirect {
            name: "gif-normal".into(),
            filter: Filter::Guided(GuidedFilterParams { guide: GuideKind::Normal, ..GuidedFilterParams::default() }),
            lookup: Lookup::GeometryAware,
        }
    }

    /// The guided filter with a grey version of the normal as guide (Figure 5a).
    pub fn gif_grey() -> FilteredIndirect {
        FilteredIndirect {
            name: "gif-grey".into(),
            filter: Filter::Guided(GuidedFilterParams {
                guide: GuideKind::GreyNormal,
                ..GuidedFilterParams::default()
            }),
            lookup: Lookup::GeometryAware,
        }
    }

    /// À-Trous with the range term on the secondary-hit normal.
    pub fn atrous_secondary_normal() -> FilteredIndirect {
        FilteredIndirect {
            name: "atrous-sn".into(),
            filter: Filter::Atrous(AtrousParams { use_secondary_normal: true, ..AtrousParams::default() }),
            lookup: Lookup::GeometryAware,
        }
    }

    /// Every variant, in the order reports list them.
    pub fn all() -> Vec<FilteredIndirect> {
        vec![
            FilteredIndirect::gif(),
            FilteredIndirect::gif_normal(),
            FilteredIndirect::gif_grey(),
            FilteredIndirect::bilateral(),
            FilteredIndirect::atrous(),
            FilteredIndirect::atrous_secondary_normal(),
        ]
    }
}

impl FilteredIndirect {
    /// Filters the guide input's indirect light at the guide hits (reflected light, one value
    /// per pixel centre); returns the image and the sanitised count.
    pub fn filter_indirect(&self, input: &GuideInput) -> Result<(Image, usize), Error> {
        let (incident, sanitised) = self.filter_incident(input)?;
        Ok((remodulate(&incident, &input.albedo, &input.indirect), sanitised))
    }

    /// The whole pipeline: filters the incident light at the guide hits, then composites the
    /// guide ray and the additional eye rays of every pixel (`eye_rays::composite`).
    pub fn reconstruct(&self, input: &GuideInput) -> Result<(Composite, usize), Error> {
        let (incident, sanitised) = self.filter_incident(input)?;
        let light = GuideLight {
            guide: &input.guide,
            albedo: &input.albedo,
            direct: &input.direct,
            reflected: &input.indirect,
        };
        let composite = composite(light, &incident, &input.eye_rays, self.lookup)?;
        Ok((composite, sanitised))
    }

    /// The filtered incident light at the guide hits (see `demodulate`).
    pub fn filter_incident(&self, input: &GuideInput) -> Result<(Image, usize), Error> {
        let incident = demodulate(&input.indirect, &input.albedo);
        let (filtered, sanitised) = match &self.filter {
            Filter::Guided(params) => {
                let params = GuidedFilterParams {
                    radius: scaled_radius(params.radius, input.indirect.width, input.indirect.height),
                    ..*params
                };
                let (mut filtered, report) = guided_filter(&incident, &input.guide, &params)?;
                // The local linear model can undershoot next to edges of the guide (the fast
                // filter's upsampled coefficients more often: 13 of 480 pixels of the furnace
                // test, down to −0.5 % of the light); light is not negative.
                for value in filtered.pixels.iter_mut().flatten() {
                    *value = value.max(0.0);
                }
                (filtered, report.sanitised_values)
            }
            Filter::Bilateral(params) => {
                cross_bilateral(&incident, &input.guide, params).map(|(i, r)| (i, r.sanitised_values))?
            }
            Filter::Atrous(params) => atrous(&incident, &input.guide, params).map(|(i, r)| (i, r.sanitised_values))?,
        };
        Ok((filtered, sanitised))
    }
}

/// Settings that override a variant's defaults: from `lfr filter`'s flags, or from a
/// `--methods` entry `NAME:key=value:...` with keys `radius`, `eps_normal`, `eps_depth`,
/// `subsample`, `iterations`, `lookup`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FilterOptions {
    /// Window radius at an 800-pixel image (guided and cross-bilateral filters).
    pub radius: Option<u32>,
    /// ε of the normal channels (guided filter).
    pub epsilon_normal: Option<f32>,
    /// ε of the depth channel (guided filter with the normal + depth guide).
    pub epsilon_depth: Option<f32>,
    /// Subsampling factor of the fast guided filter (1 = exact).
    pub subsample: Option<u32>,
    /// À-Trous iterations.
    pub iterations: Option<u32>,
    /// The additional eye rays' lookup (`lookup=own-pixel` measures the naive reuse).
    pub lookup: Option<Lookup>,
}

impl FilterOptions {
    /// The filter options of a `--methods` spec, parsed and range-checked by the registry
    /// (`crate::options`): keys `radius`, `eps_normal`, `eps_depth`, `subsample`, `iterations`,
    /// `lookup`.
    pub fn from_options(options: &Options) -> FilterOptions {
        FilterOptions {
            radius: options.count("radius"),
            epsilon_normal: options.real("eps_normal"),
            epsilon_depth: options.real("eps_depth"),
            subsample: options.count("subsample"),
            iterations: options.count("iterations"),
            lookup: options.choice("lookup").map(|word| match word {
                "own-pixel" => Lookup::OwnPixel,
                _ => Lookup::GeometryAware,
            }),
        }
    }
}

impl FilteredIndirect {
    /// The variant called `name` (no options).
    pub fn named(name: &str) -> Option<FilteredIndirect> {
        FilteredIndirect::all().into_iter().find(|f| f.name == name)
    }

    /// This variant with `options` applied and checked (options that do not apply to it are
    /// errors: `lfr filter` passes its flags here).
    pub fn with_options(mut self, options: &FilterOptions) -> Result<FilteredIndirect, Error> {
        let name = self.name.clone();
        let misplaced =
            |option: &'static str| Err(Error::parameter(option, format!("{option} does not apply to {name}")));
        if options.radius == Some(0) {
            return Err(Error::parameter("radius", "radius must be at least 1"));
        }
        if options.subsample == Some(0) {
            return Err(Error::parameter("subsample", "subsample must be at least 1"));
        }
        for (option, value) in [("eps_normal", options.epsilon_normal), ("eps_depth", options.epsilon_depth)] {
            if let Some(value) = value {
                if !(value.is_finite() && value > 0.0) {
                    return Err(Error::parameter(option, format!("{option} must be positive and finite, got {value}")));
                }
            }
        }
        match &mut self.filter {
            Filter::Guided(params) => {
                if options.iterations.is_some() {
                    return misplaced("iterations");
                }
                if options.epsilon_depth.is_some() && params.guide != GuideKind::NormalDepth {
                    return misplaced("eps_depth");
                }
                params.radius = options.radius.unwrap_or(params.radius);
                params.epsilon_normal = options.epsilon_normal.unwrap_or(params.epsilon_normal);
                params.epsilon_depth = options.epsilon_depth.unwrap_or(params.epsilon_depth);
                params.subsample = options.subsample.unwrap_or(params.subsample);
            }
            Filter::Bilateral(params) => {
                if options.epsilon_normal.is_some() || options.epsilon_depth.is_some() || options.subsample.is_some() {
                    return misplaced("eps_normal/eps_depth/subsample");
                }
                if options.iterations.is_some() {
                    return misplaced("iterations");
                }
                if let Some(radius) = options.radius {
                    *params = BilateralParams::with_radius(radius);
                }
            }
            Filter::Atrous(params) => {
                if options.epsilon_normal.is_some()
                    || options.epsilon_depth.is_some()
                    || options.radius.is_some()
                    || options.subsample.is_some()
                {
                    return misplaced("radius/eps_normal/eps_depth/subsample");
                }
                params.iterations = options.iterations.unwrap_or(params.iterations);
                params.validate()?;
            }
        }
        self.lookup = options.lookup.unwrap_or(self.lookup);
        Ok(self)
    }
}

impl Method for FilteredIndirect {
    fn input(&self) -> Input {
        Input::Guide
    }

    /// A screen-space filter guided by first-hit geometry: a reflection on a glossy surface
    /// has no edge in its guide, so it is averaged away.
    fn blurs_glossy_reflections(&self) -> bool {
        true
    }

    fn run(&self, inputs: &Inputs, _recon_rays: u32) -> Result<Output, MethodError> {
        let input = inputs.guide(&self.name)?;
        let size = (input.indirect.width, input.indirect.height);
        if size != (inputs.width, inputs.height) || input.albedo.check_same_size(&input.indirect).is_err() {
            let message = format!(
                "{}: guide buffers are {}x{}, the comparison is {}x{}",
                self.name, size.0, size.1, inputs.width, inputs.height
            );
            return Err(Error::size_mismatch("guide buffers", message).into());
        }
        let start = Instant::now();
        let (composite, sanitised) = self.reconstruct(input)?;
        let mut notes = vec![format!(
            "{} eye rays per pixel: the guide ray through its centre and {} more with the geometry-aware lookup",
            input.eye_rays.per_pixel + 1,
            input.eye_rays.per_pixel
        )];
        if sanitised > 0 {
            notes.push(format!("{sanitised} non-finite input values were replaced by 0 before filtering"));
        }
        if composite.unmatched_eye_rays > 0 {
            notes.push(format!(
                "{} eye rays hit geometry that no neighbouring guide ray hit and got no indirect light",
                composite.unmatched_eye_rays
            ));
        }
        if composite.sanitised_values > 0 {
            notes.push(format!("{} non-finite eye-ray values were replaced", composite.sanitised_values));
        }
        Ok(Output {
            image: composite.indirect,
            preprocess_s: 0.0,
            recon_s: start.elapsed().as_secs_f64(),
            external_peak_rss_mb: None,
            notes,
            stats: Stats::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::guide::GuideBuffers;

    fn flat_input(width: u32, height: u32, albedo: [f32; 3], noisy: impl Fn(u32, u32) -> [f32; 3]) -> GuideInput {
        let n = (width * height) as usize;
        let indirect = (0..n as u32).map(|i| noisy(i % width, i / width)).collect();
        GuideInput {
            guide: GuideBuffers {
                width,
                height,
                normal: vec![[0.0, 0.0, 1.0]; n],
                depth: vec![2.0; n],
                position: (0..n as u32).map(|i| [(i % width) as f32 * 0.01, (i / width) as f32 * 0.01, 0.0]).collect(),
                secondary_normal: Some(vec![[0.0, 1.0, 0.0]; n]),
            },
            albedo: Image::from_pixels(width, height, vec![albedo; n]),
            indirect: Image::from_pixels(width, height, indirect),
            direct: Image::from_pixels(width, height, vec![[0.0; 3]; n]),
            eye_rays: crate::guide::EyeRays::default(),
        }
    }

    #[test]
    fn options_apply_to_their_variant_and_misplaced_ones_are_errors() {
        // Parsing and ranges are the registry's (`crate::registry` tests); here what the
        // options do to each variant.
        let set = |f: fn(&mut FilterOptions)| {
            let mut options = FilterOptions::default();
            f(&mut options);
            options
        };
        let tuned = set(|o| (o.radius, o.epsilon_normal, o.epsilon_depth) = (Some(8), Some(0.001), Some(0.002)));
        let gif = FilteredIndirect::gif().with_options(&tuned).unwrap();
        let Filter::Guided(params) = gif.filter else { panic!("gif is the guided filter") };
        assert_eq!((params.radius, params.epsilon_normal, params.epsilon_depth), (8, 0.001, 0.002));
        assert_eq!(params.subsample, 1, "the exact filter unless asked");
        let fast = FilteredIndirect::gif().with_options(&set(|o| o.subsample = Some(2))).unwrap();
        let Filter::Guided(params) = fast.filter else { panic!("gif is the guided filter") };
        assert_eq!(params.subsample, 2);
        let naive = FilteredIndirect::bilateral().with_options(&set(|o| o.lookup = Some(Lookup::OwnPixel))).unwrap();
        assert_eq!(naive.lookup, Lookup::OwnPixel);
        assert_eq!(FilteredIndirect::gif().lookup, Lookup::GeometryAware);
        let atrous =
            FilteredIndirect::atrous_secondary_normal().with_options(&set(|o| o.iterations = Some(4))).unwrap();
        let Filter::Atrous(params) = atrous.filter else { panic!("atrous-sn is À-Trous") };
        assert!(params.use_secondary_normal && params.iterations == 4);
        for (variant, options, needle) in [
            (FilteredIndirect::atrous(), set(|o| o.subsample = Some(2)), "does not apply"),
            (FilteredIndirect::bilateral(), set(|o| o.subsample = Some(2)), "does not apply"),
            (FilteredIndirect::gif(), set(|o| o.iterations = Some(3)), "does not apply"),
            (FilteredIndirect::gif_normal(), set(|o| o.epsilon_depth = Some(0.01)), "does not apply"),
            (FilteredIndirect::bilateral(), set(|o| o.epsilon_normal = Some(0.1)), "does not apply"),
            (FilteredIndirect::atrous(), set(|o| o.radius = Some(4)), "does not apply"),
            (FilteredIndirect::atrous(), set(|o| o.iterations = Some(99)), "iteration"),
            (FilteredIndirect::gif(), set(|o| o.radius = Some(0)), "at least 1"),
            (FilteredIndirect::gif(), set(|o| o.epsilon_normal = Some(f32::INFINITY)), "positive"),
        ] {
            let name = variant.name.clone();
            let error = variant
                .with_options(&options)
                .err()
                .unwrap_or_else(|| panic!("{name} {options:?} must fail"))
                .to_string();
            assert!(error.contains(needle), "{name} {options:?}: {error}");
        }
    }

    #[test]
    fn radii_scale_with_the_image() {
        assert_eq!(scaled_radius(24, 800, 600), 24);
        assert_eq!(scaled_radius(24, 1600, 1200), 48);
        assert_eq!(scaled_radius(24, 256, 256), 8);
        assert_eq!(scaled_radius(24, 1, 1), 1);
    }

    /// On a flat, evenly lit wall every filter must remove most of the noise of the incident
    /// light and keep its mean (the filters are normalised).
    #[test]
    fn every_filter_denoises_a_flat_wall() {
        let mut state = 12345u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f32 / u32::MAX as f32
        };
        let noise: Vec<f32> = (0..64 * 48).map(|_| next()).collect();
        let input = flat_input(64, 48, [0.5, 0.5, 0.5], |x, y| {
            let u = noise[(y * 64 + x) as usize];
            [0.5 * (0.2 + 1.6 * u); 3] // incident light 1 ± 0.8
        });
        let truth = 0.5;
        let mse = |image: &Image| {
            image.pixels.iter().map(|p| ((p[0] - truth) as f64).powi(2)).sum::<f64>() / image.pixel_count() as f64
        };
        let noisy_mse = mse(&input.indirect);
        for method in FilteredIndirect::all() {
            let (image, sanitised) = method.filter_indirect(&input).unwrap();
            assert_eq!(sanitised, 0);
            let filtered_mse = mse(&image);
            assert!(filtered_mse < 0.1 * noisy_mse, "{}: MSE {noisy_mse} → {filtered_mse}", method.name);
            let mean = image.pixels.iter().map(|p| p[0] as f64).sum::<f64>() / image.pixel_count() as f64;
            assert!((mean - truth as f64).abs() < 0.02, "{}: mean {mean}", method.name);
        }
    }

    /// A checkerboard of white and pure-red texels under uniform incident light: the red
    /// texels' green and blue must stay dark after filtering (no speckle from neighbours).
    #[test]
    fn channels_without_albedo_do_not_take_the_neighbours_light() {
        let (width, height) = (32u32, 32u32);
        let n = (width * height) as usize;
        let red = |i: usize| ((i as u32 % width) + (i as u32 / width)) % 2 == 0;
        let albedo: Vec<[f32; 3]> = (0..n).map(|i| if red(i) { [0.8, 0.0, 0.0] } else { [0.8; 3] }).collect();
        let mut input = flat_input(width, height, [0.8; 3], |_, _| [0.0; 3]);
        input.albedo = Image::from_pixels(width, height, albedo.clone());
        input.indirect = Image::from_pixels(width, height, albedo.iter().map(|a| a.map(|v| 2.0 * v)).collect());
        for method in FilteredIndirect::all() {
            let (image, _) = method.filter_indirect(&input).unwrap();
            for (i, p) in image.pixels.iter().enumerate() {
                let expected = albedo[i].map(|v| 2.0 * v);
                for c in 0..3 {
                    assert!((p[c] - expected[c]).abs() < 1e-3, "{} pixel {i}: {p:?} vs {expected:?}", method.name);
                }
            }
        }
    }

    #[test]
    fn nonfinite_indirect_is_sanitised_not_propagated() {
        let input = flat_input(8, 8, [0.5; 3], |x, _| if x == 3 { [f32::NAN, f32::INFINITY, 1.0] } else { [0.5; 3] });
        for method in FilteredIndirect::all() {
            let (image, sanitised) = method.filter_indirect(&input).unwrap();
            assert!(sanitised >= 16, "{}: {sanitised}", method.name);
            assert_eq!(image.nonfinite_pixels(), 0, "{}", method.name);
        }
    }
}
