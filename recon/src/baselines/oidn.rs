//! Intel Open Image Denoise (OIDN 2.5, CPU) as a baseline: the learned denoiser production
//! renderers ship, run on the path-traced frame with its first-hit albedo and normal through the
//! `pyoidn` Python binding (`hdr=True`, quality "high" by default).
//!
//! **Timing.** The script calls `pyoidn.denoise` once, untimed, on the same inputs as a warm-up:
//! device creation and weight loading are one-time costs an application amortises over many
//! frames. It then times a second, identical call with `time.perf_counter`; that is `recon_s`.
//! Python start-up, module import and the transfer of the buffers through files are excluded,
//! and `preprocess_s` is 0. `external_peak_rss_mb` is the Python process's peak resident memory.
//!
//! **Box pixel filter.** OIDN is trained on images whose pixels are independent estimates, i.e.
//! rendered with a box pixel filter, and `Input::Image` is traced that way. With a wider filter
//! (e.g. a Gaussian) every sample is spread over neighbouring pixels, the noise becomes spatially
//! correlated, looks like image structure to the network, and OIDN removes little of it (33.7 →
//! 34.4 dB PSNR in one measurement), against a large gain with the box filter.
//!
//! **Input sanitising.** OIDN requires HDR colour ≥ 0, albedo in [0, 1] and normals in [-1, 1];
//! non-finite colour and normal values become 0, negative colour 0, and albedo and normals are
//! clamped. The number of values changed is reported in the notes.

use std::time::Instant;

use crate::error::Error;
use crate::image::Image;
use crate::method::{Effect, Input, Inputs, Method, MethodError, Output, Stats};
use crate::python;

const SCRIPT: &str = include_str!("oidn_denoise.py");

/// The tool named in errors.
const TOOL: &str = "oidn";

/// The qualities `pyoidn.denoise` accepts.
pub const QUALITIES: [&str; 4] = ["high", "balanced", "fast", "default"];

/// Intel Open Image Denoise through `pyoidn`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Oidn {
    /// OIDN filter quality: "high" (default), "balanced", "fast" or "default".
    pub quality: String,
}

impl Default for Oidn {
    fn default() -> Self {
        Oidn { quality: "high".to_string() }
    }
}

/// How many values of each buffer `sanitize` changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sanitized {
    pub color: usize,
    pub albedo: usize,
    pub normal: usize,
}

impl Sanitized {
    pub fn total(&self) -> usize {
        self.color + self.albedo + self.normal
    }
}

fn sanitize_image(image: &Image, fix: impl Fn(f32) -> f32) -> (Image, usize) {
    let mut changed = 0;
    let pixels = image
        .pixels
        .iter()
        .map(|pixel| {
            pixel.map(|value| {
                let fixed = fix(value);
                // NaN != NaN, so compare bit patterns: a fixed NaN always counts.
                if fixed.to_bits() != value.to_bits() {
                    changed += 1;
                }
                fixed
            })
        })
        .collect();
    (Image { width: image.width, height: image.height, pixels }, changed)
}

/// Copies of `color`, `albedo` and `normal` within OIDN's input ranges: colour non-finite or
/// negative → 0; albedo non-finite → 0, else clamped to [0, 1]; normal non-finite → 0, else
/// clamped to [-1, 1]. `-0.0` counts as valid and is kept.
pub fn sanitize(color: &Image, albedo: &Image, normal: &Image) -> (Image, Image, Image, Sanitized) {
    let finite_or_zero = |v: f32| if v.is_finite() { v } else { 0.0 };
    let (color, color_changed) = sanitize_image(color, |v| if v.is_finite() && v >= 0.0 { v } else { 0.0 });
    let (albedo, albedo_changed) = sanitize_image(albedo, |v| finite_or_zero(v).clamp(0.0, 1.0));
    let (normal, normal_changed) = sanitize_image(normal, |v| finite_or_zero(v).clamp(-1.0, 1.0));
    let counts = Sanitized { color: color_changed, albedo: albedo_changed, normal: normal_changed };
    (color, albedo, normal, counts)
}

fn number(value: &serde_json::Value, key: &str) -> Result<f64, Error> {
    value
        .get(key)
        .and_then(serde_json::Value::as_f64)
        .ok_or_else(|| Error::external(TOOL, format!("the denoise script's result has no number `{key}`: {value}")))
}

impl Method for Oidn {
    fn input(&self) -> Input {
        Input::Image
    }

    fn available(&self) -> Result<(), Error> {
        python::module_available("numpy")?;
        python::module_available("pyoidn")
    }

    fn run(&self, inputs: &Inputs, _recon_rays: u32) -> Result<Output, MethodError> {
        let frame = inputs.image("oidn")?;
        self.denoise(&frame.color, &frame.albedo, &frame.normal, inputs.effect)
    }
}

/// Ambient occlusion is a grey visibility in [0, 1]; OIDN, trained on colour images, returns
/// slightly coloured pixels and values above 1 for it. The denoised visibility is the mean of
/// its channels clamped to [0, 1] (a non-finite mean stays as it is, for the harness to count).
pub fn as_visibility(image: &mut Image) {
    for pixel in &mut image.pixels {
        let mean = (pixel[0] + pixel[1] + pixel[2]) / 3.0;
        *pixel = [if mean.is_finite() { mean.clamp(0.0, 1.0) } else { mean }; 3];
    }
}

impl Oidn {
    /// Denoises `color` (the image of `effect`) with its first-hit `albedo` and `normal`: the
    /// `oidn` method on a path-traced frame, and the last stage of a pipeline (`crate::pipeline`)
    /// on a reconstruction's image. For ambient occlusion the result is a grey visibility
    /// ([`as_visibility`]).
    pub fn denoise(
        &self,
        color: &Image,
        albedo: &Image,
        normal: &Image,
        effect: Effect,
    ) -> Result<Output, MethodError> {
        let (width, height) = (color.width, color.height);
        if width == 0 || height == 0 {
            return Err(Error::external(TOOL, format!("empty frame ({width}x{height})")).into());
        }
        for (name, image) in [("albedo", albedo), ("normal", normal)] {
            color.check_same_size(image).map_err(|e| Error::size_mismatch(name, format!("{TOOL}: {name}: {e}")))?;
        }
        if !QUALITIES.contains(&self.quality.as_str()) {
            let message =
                format!("{TOOL}: unknown quality `{}` (expected one of {})", self.quality, QUALITIES.join(", "));
            return Err(Error::parameter("quality", message).into());
        }
        self.available().map_err(MethodError::Unavailable)?;

        let started = Instant::now();
        let (color, albedo, normal, sanitized) = sanitize(color, albedo, normal);
        let dir = tempfile::Builder::new()
            .prefix("lfr-oidn-")
            .tempdir()
            .map_err(|e| Error::external(TOOL, format!("cannot create a temporary directory: {e}")))?;
        // Removed on interrupt too (dropping `dir` removes it otherwise).
        let _registration = sampleio::interrupt::remove_on_interrupt(dir.path());
        let bridge = |error: Error| Error::external(TOOL, error.to_string());
        let path = |name: &str| dir.path().join(format!("{name}.f32"));
        for (name, image) in [("color", &color), ("albedo", &albedo), ("normal", &normal)] {
            python::write_image_f32(&path(name), image).map_err(bridge)?;
        }
        let args = serde_json::json!({
            "width": width,
            "height": height,
            "color": path("color"),
            "albedo": path("albedo"),
            "normal": path("normal"),
            "output": path("output"),
            "quality": self.quality,
        });
        let result = python::run_script(SCRIPT, &args, dir.path()).map_err(bridge)?;
        let mut image = python::read_image_f32(&path("output"), width, height).map_err(bridge)?;
        if effect == Effect::Ao {
            as_visibility(&mut image);
        }
        let wall_s = started.elapsed().as_secs_f64();

        let recon_s = number(&result, "seconds")?;
        let peak_rss_mb = number(&result, "peak_rss_mb")?;
        let version = result.get("oidn_version").and_then(serde_json::Value::as_str).unwrap_or("unknown version");
        let mut notes = vec![format!(
            "oidn: OIDN {version} (pyoidn, CPU), quality {}, HDR with albedo and normal; time is the warm \
             OIDN execute call (a second pyoidn.denoise after an untimed warm-up that creates the device and \
             loads the weights); Python start-up and file transfer are excluded ({wall_s:.2} s wall in all)",
            self.quality
        )];
        if sanitized.total() > 0 {
            notes.push(format!(
                "oidn: sanitised {} input values for OIDN ({} colour non-finite or negative → 0, {} albedo \
                 outside [0, 1], {} normal non-finite or outside [-1, 1])",
                sanitized.total(),
                sanitized.color,
                sanitized.albedo,
                sanitized.normal
            ));
        }
        let nonfinite = image.nonfinite_pixels();
        if nonfinite > 0 {
            notes.push(format!("oidn: the denoised image has {nonfinite} non-finite pixels"));
        }
        Ok(Output {
            image,
            preprocess_s: 0.0,
            recon_s,
            external_peak_rss_mb: Some(peak_rss_mb),
            notes,
            stats: Stats::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::method::{Effect, ImageInput, InputData};

    const SIZE: u32 = 64;

    /// `Some(reason)` when pyoidn (or numpy, or Python) is missing.
    fn skip_reason() -> Option<Error> {
        Oidn::default().available().err()
    }

    /// A horizontal grey gradient 0.2..0.8 with albedo 0.5 and normal (0, 0, 1).
    fn smooth_frame() -> ImageInput {
        let mut color = Image::new(SIZE, SIZE);
        for y in 0..SIZE {
            for x in 0..SIZE {
                let v = 0.2 + 0.6 * x as f32 / (SIZE - 1) as f32;
                color.set(x, y, [v; 3]);
            }
        }
        let albedo = Image::from_pixels(SIZE, SIZE, vec![[0.5; 3]; (SIZE * SIZE) as usize]);
        let normal = Image::from_pixels(SIZE, SIZE, vec![[0.0, 0.0, 1.0]; (SIZE * SIZE) as usize]);
        ImageInput { color, albedo, normal }
    }

    /// `reference * (1 + 0.5 * n)` with `n` uniform in [-1, 1] from a deterministic LCG.
    fn noisy(reference: &Image) -> Image {
        let mut state: u64 = 0x2545_f491_4f6c_dd1d;
        let mut uniform = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let pixels = reference
            .pixels
            .iter()
            .map(|p| {
                let factor = 1.0 + 0.5 * uniform();
                p.map(|c| c * factor)
            })
            .collect();
        Image::from_pixels(reference.width, reference.height, pixels)
    }

    fn mse(a: &Image, b: &Image) -> f64 {
        let sum: f64 = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
            .sum();
        sum / (a.pixels.len() * 3) as f64
    }

    fn inputs(frame: &ImageInput) -> Inputs<'_> {
        Inputs {
            effect: Effect::Indirect,
            width: frame.color.width,
            height: frame.color.height,
            spp: 4,
            data: InputData::Image(frame),
            ao_radius: 1.0,
            seed: 0,
            threads: 0,
        }
    }

    /// Ambient occlusion out of OIDN is a grey visibility: each pixel the mean of its channels,
    /// clamped to [0, 1]; a non-finite pixel stays non-finite for the harness to count.
    #[test]
    fn ambient_occlusion_comes_out_grey_and_within_zero_to_one() {
        let mut image =
            Image::from_pixels(4, 1, vec![[0.9, 1.2, 1.2], [0.2, 0.3, 0.1], [-0.3, 0.0, 0.0], [f32::NAN, 0.5, 0.5]]);
        as_visibility(&mut image);
        assert_eq!(image.pixels[0], [1.0; 3]);
        assert!(image.pixels[1].iter().all(|&v| (v - 0.2).abs() < 1e-7), "{:?}", image.pixels[1]);
        assert_eq!(image.pixels[2], [0.0; 3]);
        assert!(image.pixels[3].iter().all(|v| v.is_nan()));
    }

    #[test]
    fn denoising_removes_most_of_the_noise() {
        if let Some(reason) = skip_reason() {
            testkit::skip(&format!("pyoidn is not installed ({reason})"));
            return;
        }
        let smooth = smooth_frame();
        let reference = smooth.color.clone();
        let frame = ImageInput { color: noisy(&reference), ..smooth };
        let output = Oidn::default().run(&inputs(&frame), 0).unwrap();
        assert_eq!((output.image.width, output.image.height), (SIZE, SIZE));
        assert_eq!(output.image.nonfinite_pixels(), 0);
        let before = mse(&frame.color, &reference);
        let after = mse(&output.image, &reference);
        eprintln!("oidn test: mse {before:.3e} -> {after:.3e}, {:.4} s", output.recon_s);
        assert!(after < 0.25 * before, "mse before {before}, after {after}");
        assert!(output.recon_s > 0.0);
        assert_eq!(output.preprocess_s, 0.0);
        assert!(output.external_peak_rss_mb.unwrap() > 0.0);
        assert!(output.notes.iter().any(|n| n.contains("warm")), "{:?}", output.notes);
        assert!(!output.notes.iter().any(|n| n.contains("sanitised")), "{:?}", output.notes);
    }

    #[test]
    fn invalid_colour_values_are_sanitised_and_counted() {
        if let Some(reason) = skip_reason() {
            testkit::skip(&format!("pyoidn is not installed ({reason})"));
            return;
        }
        let mut frame = smooth_frame();
        frame.color.set(3, 4, [f32::NAN, 0.5, 0.5]);
        frame.color.set(10, 20, [0.5, f32::NEG_INFINITY, -0.25]);
        frame.color.set(63, 63, [-1.0, -2.0, f32::INFINITY]);
        frame.albedo.set(0, 0, [1.5, -0.5, f32::NAN]);
        frame.normal.set(1, 1, [f32::NAN, 2.0, 0.0]);
        let output = Oidn::default().run(&inputs(&frame), 0).unwrap();
        assert_eq!(output.image.nonfinite_pixels(), 0);
        let note = output.notes.iter().find(|n| n.contains("sanitised")).expect("a sanitising note");
        assert!(note.contains("sanitised 11 input values"), "{note}");
        assert!(note.contains("6 colour"), "{note}");
        assert!(output.image.pixels.iter().flatten().all(|&c| c >= 0.0), "OIDN HDR output is nonnegative");
    }

    #[test]
    fn sanitize_counts_every_changed_value() {
        let mut color = Image::new(2, 1);
        color.set(0, 0, [f32::NAN, -0.0, -1.0]);
        color.set(1, 0, [f32::INFINITY, 2.0, 0.5]);
        let mut albedo = Image::new(2, 1);
        albedo.set(0, 0, [1.0, 1.25, f32::NEG_INFINITY]);
        let mut normal = Image::new(2, 1);
        normal.set(1, 0, [-3.0, f32::NAN, 1.0]);
        let (c, a, n, counts) = sanitize(&color, &albedo, &normal);
        assert_eq!(counts, Sanitized { color: 3, albedo: 2, normal: 2 });
        assert_eq!(counts.total(), 7);
        assert_eq!(c.pixels, vec![[0.0, -0.0, 0.0], [0.0, 2.0, 0.5]]);
        assert_eq!(a.pixels, vec![[1.0, 1.0, 0.0], [0.0, 0.0, 0.0]]);
        assert_eq!(n.pixels, vec![[0.0, 0.0, 0.0], [-1.0, 0.0, 1.0]]);
    }

    #[test]
    fn missing_image_fails_and_bad_quality_is_rejected() {
        let frame = smooth_frame();
        let mut without = inputs(&frame);
        without.data = InputData::Samples { samples: std::path::Path::new("samples.lfrs"), light_samples: None };
        match Oidn::default().run(&without, 0) {
            Err(MethodError::Failed(error)) => assert!(error.to_string().contains("path-traced image"), "{error}"),
            other => panic!("expected a failure, got {other:?}"),
        }
        let oidn = Oidn { quality: "ultra".to_string() };
        match oidn.run(&inputs(&frame), 0) {
            Err(MethodError::Failed(error)) => {
                let message = error.to_string();
                assert!(message.contains("ultra"), "{message}")
            }
            other => panic!("expected a failure, got {other:?}"),
        }
    }

    #[test]
    fn unavailable_interpreter_is_named() {
        // Uses the explicit-interpreter check: `LFR_PYTHON` is process-global and tests run in
        // parallel, and `module_available` caches per interpreter.
        let python = "/nonexistent/lfr-oidn-test-python";
        let error = python::module_available_with(python, "pyoidn").unwrap_err().to_string();
        assert!(error.contains(python), "{error}");
    }

    #[test]
    fn describes_itself() {
        let oidn = crate::registry::find("oidn").unwrap().unwrap();
        assert_eq!(oidn.name(), "oidn");
        assert_eq!(Oidn::default().quality, "high");
        let fast = crate::registry::find("oidn:quality=fast").unwrap().unwrap();
        assert_eq!(format!("{:?}", fast.method), format!("{:?}", Oidn { quality: "fast".into() }));
        let description = crate::registry::spec("oidn").unwrap().description;
        assert!(description.contains("Open Image Denoise 2.5"));
        assert!(description.contains("pyoidn"));
        assert_eq!(oidn.input(), Input::Image);
        assert!(Effect::ALL.iter().all(|&e| oidn.supports(e)));
    }
}
