//! HDR-FLIP (Andersson et al., "Visualizing Errors in Rendered High Dynamic Range Images",
//! Eurographics 2021): NVIDIA's perceptual error metric for rendered HDR images. It tone-maps
//! reference and test over a range of exposures derived from the reference, applies the
//! LDR-FLIP colour and feature (edge and point) differences at each exposure under a viewing
//! model (67 pixels per degree by default), and keeps the per-pixel maximum. The mean of that
//! error map lies in [0, 1]; lower is better, 0 for identical images.
//!
//! Computed by NVIDIA's reference implementation, the `flip_evaluator` Python package
//! (`pip install flip-evaluator`), with default parameters and linear-sRGB HDR input. When the
//! package is missing the metric is simply not reported.

use crate::error::Error;
use crate::image::Image;
use crate::python;

/// The tool named in errors.
const TOOL: &str = "HDR-FLIP";

const SCRIPT: &str = include_str!("flip_metric.py");

/// Whether `flip_evaluator` (and numpy) can be imported.
pub fn available() -> bool {
    python::module_available("numpy").is_ok() && python::module_available("flip_evaluator").is_ok()
}

/// The mean HDR-FLIP error of each of `tests` against `reference`, in the order of `tests`, all
/// computed in one Python process; `Ok(None)` when `flip_evaluator` is not installed. Non-finite
/// test values are replaced by 0 and negative ones clamped to 0 (HDR-FLIP expects nonnegative
/// linear input). An all-black reference is an error: FLIP derives its exposure range from it.
pub fn hdr_flip_many(reference: &Image, tests: &[&Image]) -> Result<Option<Vec<f64>>, Error> {
    if !available() {
        return Ok(None);
    }
    for (index, test) in tests.iter().enumerate() {
        reference
            .check_same_size(test)
            .map_err(|e| Error::size_mismatch("HDR-FLIP test image", format!("{TOOL}: test image {index}: {e}")))?;
    }
    if tests.is_empty() {
        return Ok(Some(Vec::new()));
    }
    if reference.width == 0 || reference.height == 0 {
        return Err(Error::external(TOOL, format!("empty reference image ({}x{})", reference.width, reference.height)));
    }
    let dir = tempfile::Builder::new()
        .prefix("lfr-flip-")
        .tempdir()
        .map_err(|e| Error::external(TOOL, format!("cannot create a temporary directory: {e}")))?;
    // Removed on interrupt too (dropping `dir` removes it otherwise).
    let _registration = sampleio::interrupt::remove_on_interrupt(dir.path());
    let bridge = |error: Error| Error::external(TOOL, error.to_string());
    let reference_path = dir.path().join("reference.f32");
    python::write_image_f32(&reference_path, reference).map_err(bridge)?;
    let mut test_paths = Vec::with_capacity(tests.len());
    for (index, test) in tests.iter().enumerate() {
        let path = dir.path().join(format!("test{index}.f32"));
        python::write_image_f32(&path, test).map_err(bridge)?;
        test_paths.push(path);
    }
    let args = serde_json::json!({
        "width": reference.width,
        "height": reference.height,
        "reference": reference_path,
        "tests": test_paths,
    });
    let result = python::run_script(SCRIPT, &args, dir.path()).map_err(bridge)?;
    let errors = result.get("mean_errors").and_then(serde_json::Value::as_array).ok_or_else(|| {
        Error::external(TOOL, format!("the metric script's result has no `mean_errors` list: {result}"))
    })?;
    if errors.len() != tests.len() {
        return Err(Error::external(
            TOOL,
            format!("expected {} mean errors, got {}: {result}", tests.len(), errors.len()),
        ));
    }
    errors
        .iter()
        .map(|e| e.as_f64().ok_or_else(|| Error::external(TOOL, format!("mean error {e} is not a number"))))
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIZE: u32 = 48;

    fn gradient() -> Image {
        let mut image = Image::new(SIZE, SIZE);
        for y in 0..SIZE {
            for x in 0..SIZE {
                let t = x as f32 / (SIZE - 1) as f32;
                image.set(x, y, [0.1 + 0.8 * t, 0.3, 0.9 - 0.6 * t]);
            }
        }
        image
    }

    fn skipped() -> bool {
        if available() {
            return false;
        }
        let reason = python::module_available("flip_evaluator").err().map(|e| e.to_string()).unwrap_or_default();
        testkit::skip(&format!("flip_evaluator is not installed ({reason})"));
        true
    }

    #[test]
    fn identical_is_zero_and_different_is_large_in_order() {
        if skipped() {
            return;
        }
        let reference = gradient();
        // A checkerboard of bright and dark squares.
        let mut checker = Image::new(SIZE, SIZE);
        for y in 0..SIZE {
            for x in 0..SIZE {
                let v = if (x / 4 + y / 4) % 2 == 0 { 4.0 } else { 0.0 };
                checker.set(x, y, [v, v * 0.5, v * 0.25]);
            }
        }
        // A mildly perturbed copy: between the two.
        let mut slight = reference.clone();
        for (i, p) in slight.pixels.iter_mut().enumerate() {
            let factor = if i % 7 == 0 { 1.1 } else { 1.0 };
            *p = p.map(|c| c * factor);
        }
        let errors = hdr_flip_many(&reference, &[&reference, &checker, &slight, &reference]).unwrap().unwrap();
        eprintln!("flip test: {errors:?}");
        assert_eq!(errors.len(), 4);
        assert!(errors.iter().all(|e| (0.0..=1.0).contains(e)), "{errors:?}");
        assert!(errors[0] < 1e-6, "{errors:?}");
        assert!(errors[3] < 1e-6, "{errors:?}");
        assert!(errors[1] > 0.1, "{errors:?}");
        assert!(errors[2] > 1e-4 && errors[2] < errors[1], "{errors:?}");
    }

    #[test]
    fn invalid_test_values_are_sanitised() {
        if skipped() {
            return;
        }
        let reference = gradient();
        let mut broken = reference.clone();
        broken.set(5, 5, [f32::NAN, f32::INFINITY, -3.0]);
        let mut zeroed = reference.clone();
        zeroed.set(5, 5, [0.0, 0.0, 0.0]);
        let errors = hdr_flip_many(&reference, &[&broken, &zeroed]).unwrap().unwrap();
        assert!(errors[0].is_finite() && errors[0] > 0.0, "{errors:?}");
        assert!((errors[0] - errors[1]).abs() < 1e-9, "{errors:?}");
    }

    #[test]
    fn mismatched_sizes_and_black_references_are_errors() {
        if skipped() {
            return;
        }
        let reference = gradient();
        let small = Image::new(4, 4);
        let error = hdr_flip_many(&reference, &[&reference, &small]).unwrap_err().to_string();
        assert!(error.contains("test image 1"), "{error}");
        let black = Image::new(8, 8);
        let error = hdr_flip_many(&black, &[&black]).unwrap_err().to_string();
        assert!(error.contains("all-black"), "{error}");
        assert_eq!(hdr_flip_many(&reference, &[]).unwrap(), Some(Vec::new()));
    }
}
