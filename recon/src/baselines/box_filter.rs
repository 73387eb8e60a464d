//! `box`: the plain per-pixel average of the input samples — what path tracing at the input
//! sample count gives, read back through `sampleio`. Every reconstruction must beat it at
//! equal input; it also checks the harness, since its error must match the path-tracing
//! ladder's at the same spp.
//!
//! Per-sample value by effect (docs/sample-format.md defines the fields):
//! - `indirect`, `glossy` (`indirect` samples): `weight · radiance`, with `albedo` in place of
//!   `weight` when the file has no `weight` field (all-diffuse scenes, where they are equal);
//! - `ao` (`ao` samples): 1 when the camera ray escaped (no `origin_normal`) or the secondary
//!   ray reached at least the AO radius, else 0;
//! - `dof`, `motion`, `dof-motion`, `soft-shadow` (`lens-time` samples): `radiance`.
//!
//! Non-finite sample values are skipped and counted (the tracer never writes them; a file
//! from elsewhere might), and the pixel is averaged over its remaining samples.

use std::time::Instant;

use rayon::prelude::*;
use sampleio::{Field, SampleFile, SampleKind};

use crate::error::Error;
use crate::image::Image;
use crate::method::{Effect, Input, Inputs, Method, MethodError, Output, Stats};

#[derive(Debug)]
pub struct BoxFilter;

impl Method for BoxFilter {
    fn input(&self) -> Input {
        Input::Samples
    }

    fn sample_needs(&self, effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        Some(vec![crate::needs::box_filter(effect.sample_kind())])
    }

    fn run(&self, inputs: &Inputs, _recon_rays: u32) -> Result<Output, MethodError> {
        let path = inputs.samples("box")?;
        let start = Instant::now();
        let file = SampleFile::open(path)?;
        let preprocess_s = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let (image, skipped) = average(&file, inputs.effect, inputs.ao_radius)?;
        let mut notes = Vec::new();
        if skipped > 0 {
            notes.push(crate::method::warning(format!(
                "{}: {skipped} samples with non-finite values were skipped",
                path.display()
            )));
        }
        if (image.width, image.height) != (inputs.width, inputs.height) {
            let message = format!(
                "{}: samples are {}x{}, the comparison is {}x{}",
                path.display(),
                image.width,
                image.height,
                inputs.width,
                inputs.height
            );
            return Err(Error::size_mismatch("samples", message).into());
        }
        Ok(Output {
            image,
            preprocess_s,
            recon_s: start.elapsed().as_secs_f64(),
            external_peak_rss_mb: None,
            notes,
            stats: Stats::new(),
        })
    }
}

/// The per-pixel mean of `file`'s samples for `effect`, and the number of skipped samples.
pub fn average(file: &SampleFile, effect: Effect, ao_radius: f32) -> Result<(Image, u64), MethodError> {
    let header = file.header();
    let expected = effect.sample_kind();
    if header.kind != expected {
        let message = format!(
            "effect {} needs `{}` samples, the file holds `{}`",
            effect.name(),
            expected.name(),
            header.kind.name()
        );
        return Err(Error::sample_content(file.path(), message).into());
    }
    file.check_needs(crate::needs::box_filter(expected))?;
    let required = |name: &str| -> Result<&Field, Error> {
        file.field(name).ok_or_else(|| {
            Error::sample_content(file.path(), format!("`{}` samples lack the field `{name}`", expected.name()))
        })
    };
    let estimator = match expected {
        SampleKind::Indirect => {
            let weight = match file.field("weight") {
                Some(field) => field,
                None => required("albedo")?,
            };
            Estimator::Weighted { weight, radiance: required("radiance")? }
        }
        SampleKind::Ao => {
            if !(ao_radius.is_finite() && ao_radius > 0.0) {
                return Err(
                    Error::parameter("ao_radius", format!("the AO radius must be positive, got {ao_radius}")).into()
                );
            }
            Estimator::Visibility {
                distance: required("distance")?,
                origin_normal: required("origin_normal")?,
                radius: ao_radius,
            }
        }
        SampleKind::LensTime | SampleKind::Light => Estimator::Radiance { radiance: required("radiance")? },
    };
    let (width, height, spp) = (header.width, header.height, header.spp as usize);
    let record_size = header.record_size as usize;
    let rows: Vec<(Vec<[f32; 3]>, u64)> = (0..height)
        .into_par_iter()
        .map(|y| {
            let mut skipped = 0;
            let row = (0..width)
                .map(|x| {
                    let (mut sum, mut count) = ([0.0f64; 3], 0u32);
                    for record in file.pixel_records(x, y).chunks_exact(record_size.max(1)) {
                        let value = estimator.value(record);
                        if value.iter().all(|v| v.is_finite()) {
                            for c in 0..3 {
                                sum[c] += value[c] as f64;
                            }
                            count += 1;
                        } else {
                            skipped += 1;
                        }
                    }
                    let n = count.max(1) as f64;
                    debug_assert!(count as usize <= spp);
                    [(sum[0] / n) as f32, (sum[1] / n) as f32, (sum[2] / n) as f32]
                })
                .collect();
            (row, skipped)
        })
        .collect();
    let skipped = rows.iter().map(|r| r.1).sum();
    let pixels = rows.into_iter().flat_map(|r| r.0).collect();
    Ok((Image::from_pixels(width, height, pixels), skipped))
}

/// How one sample becomes a value of the effect's image.
enum Estimator<'a> {
    Weighted { weight: &'a Field, radiance: &'a Field },
    Visibility { distance: &'a Field, origin_normal: &'a Field, radius: f32 },
    Radiance { radiance: &'a Field },
}

impl Estimator<'_> {
    /// The value of the sample whose record is `record`.
    fn value(&self, record: &[u8]) -> [f32; 3] {
        let vec3 = |field: &Field| field.decode_array_from::<3>(record);
        match self {
            Estimator::Weighted { weight, radiance } => {
                let (w, l) = (vec3(weight), vec3(radiance));
                [w[0] * l[0], w[1] * l[1], w[2] * l[2]]
            }
            Estimator::Visibility { distance, origin_normal, radius } => {
                let camera_ray_hit =
                    origin_normal.decode_from(record, 0) != 0.0 || origin_normal.decode_from(record, 1) != 0.0;
                let distance = distance.decode_from(record, 0);
                let visible = !camera_ray_hit || distance >= *radius;
                [visible as u32 as f32; 3]
            }
            Estimator::Radiance { radiance } => vec3(radiance),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleWriter};

    fn write(dir: &std::path::Path, spec: HeaderSpec, samples: &[Vec<f32>]) -> std::path::PathBuf {
        let path = dir.join("samples.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        for sample in samples {
            writer.push(sample).unwrap();
        }
        writer.finish().unwrap()
    }

    #[test]
    fn indirect_average_uses_weight_or_albedo() {
        let dir = tempfile::tempdir().unwrap();
        // 2x1 pixels, 2 spp: fields radiance, albedo (no weight).
        let spec = HeaderSpec::new(SampleKind::Indirect, 2, 1, 2)
            .field(FieldSpec::new("radiance", FieldType::F32, 3))
            .field(FieldSpec::new("albedo", FieldType::F16, 3));
        let samples = [
            vec![1.0, 2.0, 3.0, 0.5, 0.5, 0.5],
            vec![3.0, 2.0, 1.0, 0.25, 0.5, 1.0],
            vec![8.0, 8.0, 8.0, 1.0, 0.0, 0.5],
            vec![f32::NAN, 0.0, 0.0, 1.0, 1.0, 1.0],
        ];
        let path = write(dir.path(), spec, &samples);
        let file = SampleFile::open(&path).unwrap();
        let (image, skipped) = average(&file, Effect::Indirect, 1.0).unwrap();
        assert_eq!(skipped, 1);
        // Pixel 0: (0.5, 1.0, 1.5) and (0.75, 1.0, 1.0) → mean (0.625, 1.0, 1.25).
        assert_eq!(image.get(0, 0), [0.625, 1.0, 1.25]);
        // Pixel 1: the NaN sample is skipped, the other is (8, 0, 4).
        assert_eq!(image.get(1, 0), [8.0, 0.0, 4.0]);

        let spec = HeaderSpec::new(SampleKind::Indirect, 1, 1, 1)
            .field(FieldSpec::new("radiance", FieldType::F32, 3))
            .field(FieldSpec::new("albedo", FieldType::F16, 3))
            .field(FieldSpec::new("weight", FieldType::F16, 3));
        let dir = tempfile::tempdir().unwrap();
        let path = write(dir.path(), spec, &[vec![2.0, 2.0, 2.0, 0.5, 0.5, 0.5, 2.0, 1.0, 0.0]]);
        let (image, _) = average(&SampleFile::open(&path).unwrap(), Effect::Glossy, 1.0).unwrap();
        assert_eq!(image.get(0, 0), [4.0, 2.0, 0.0], "weight takes precedence over albedo");
    }

    #[test]
    fn ambient_occlusion_thresholds_the_distance() {
        let dir = tempfile::tempdir().unwrap();
        let spec = HeaderSpec::new(SampleKind::Ao, 1, 1, 4)
            .field(FieldSpec::new("distance", FieldType::F32, 1))
            .field(FieldSpec::new("origin_normal", FieldType::U16, 2));
        let samples = [
            vec![0.5, 100.0, 200.0],           // occluded at radius 1
            vec![f32::INFINITY, 100.0, 200.0], // escaped: visible
            vec![1.0, 100.0, 200.0],           // exactly the radius: visible
            vec![0.0, 0.0, 0.0],               // camera ray escaped: visible
        ];
        let path = write(dir.path(), spec, &samples);
        let (image, skipped) = average(&SampleFile::open(&path).unwrap(), Effect::Ao, 1.0).unwrap();
        assert_eq!(skipped, 0);
        assert_eq!(image.get(0, 0), [0.75; 3]);
        assert!(average(&SampleFile::open(&path).unwrap(), Effect::Ao, 0.0).is_err());
    }

    #[test]
    fn wrong_kind_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let spec = HeaderSpec::new(SampleKind::Ao, 1, 1, 1)
            .field(FieldSpec::new("distance", FieldType::F32, 1))
            .field(FieldSpec::new("origin_normal", FieldType::U16, 2));
        let path = write(dir.path(), spec, &[vec![1.0, 1.0, 1.0]]);
        let error = average(&SampleFile::open(&path).unwrap(), Effect::Dof, 1.0).unwrap_err().to_string();
        assert!(error.contains("lens-time") && error.contains("samples.lfrs"), "{error}");
    }
}
