//! The auxiliary images a denoiser reads beside the colour (first-hit albedo and normal), made
//! from the very samples a reconstruction read, so that a pipeline (`crate::pipeline`) needs
//! no second render.
//!
//! [`AuxiliaryMode::Integrated`] (the default) is each pixel's mean over its samples. For depth
//! of field and motion blur the samples spread over the lens and the shutter, so the mean is the
//! lens- and time-integrated albedo and normal, blurred as the colour is: a pinhole's sharp
//! auxiliaries inside bokeh make OIDN draw edges that the colour does not have (RenderKit/oidn#22,
//! gkjohnson/three-gpu-pathtracer#829). [`AuxiliaryMode::Centre`] takes each pixel's sample nearest
//! the lens centre and mid-shutter instead: a pinhole-like, sharp auxiliary from the same
//! samples, kept to measure the difference (docs/compare.md, "Pipelines").
//!
//! Fields by sample kind (`crate::needs::auxiliary`): `lens-time` samples `albedo` and `normal`;
//! `indirect` samples `albedo` and `origin_normal` (the primary hit o); `ao` samples
//! `origin_normal` with albedo 1 (ambient occlusion is a visibility). A camera ray that escaped
//! has albedo 0 and no normal (0, 0, 0), as the path tracer's frame has. Non-finite albedo
//! values count as 0.

use std::path::Path;

use rayon::prelude::*;
use sampleio::{Field, SampleFile, SampleKind};

use crate::error::Error;
use crate::image::Image;
use crate::method::{Effect, MethodError};

/// How a pixel's samples make its auxiliary values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AuxiliaryMode {
    /// The mean over the pixel's samples (lens- and time-integrated).
    #[default]
    Integrated,
    /// The sample nearest the lens centre and mid-shutter (the first such sample on ties).
    Centre,
}

impl AuxiliaryMode {
    pub fn name(self) -> &'static str {
        match self {
            AuxiliaryMode::Integrated => "integrated",
            AuxiliaryMode::Centre => "centre",
        }
    }
}

/// A denoiser's auxiliary images.
#[derive(Clone, Debug, PartialEq)]
pub struct Auxiliary {
    pub albedo: Image,
    pub normal: Image,
}

/// One sample's auxiliary values and its distance from the lens centre and mid-shutter.
struct Reader<'a> {
    albedo: Option<&'a Field>,
    normal: &'a Field,
    lens: Option<(&'a Field, &'a Field)>,
    time: Option<&'a Field>,
}

impl Reader<'_> {
    fn albedo(&self, record: &[u8]) -> [f32; 3] {
        match self.albedo {
            Some(field) => field.decode_array_from::<3>(record).map(|v| if v.is_finite() { v } else { 0.0 }),
            None => [1.0; 3],
        }
    }

    fn normal(&self, record: &[u8]) -> [f32; 3] {
        let q = [self.normal.decode_from(record, 0), self.normal.decode_from(record, 1)];
        crate::octahedral::decode(q).unwrap_or([0.0; 3])
    }

    /// Squared distance from (u, v, t) = (0, 0, ½), the centre of the lens and the shutter.
    fn off_centre(&self, record: &[u8]) -> f32 {
        let lens = self.lens.map_or(0.0, |(u, v)| {
            let (u, v) = (u.decode_from(record, 0), v.decode_from(record, 0));
            u * u + v * v
        });
        let time = self.time.map_or(0.0, |t| (t.decode_from(record, 0) - 0.5).powi(2));
        let distance = lens + time;
        if distance.is_finite() {
            distance
        } else {
            f32::INFINITY
        }
    }
}

/// The auxiliary images of a guide-buffer input (`Input::Guide`: one ray through each pixel's
/// centre): its first-hit albedo and normal, as the filter that reads it sees them. There is no
/// lens or shutter to integrate over: guide buffers exist for `indirect` and `glossy` only.
pub fn from_guide(guide: &crate::method::GuideInput) -> Auxiliary {
    let (width, height) = (guide.guide.width, guide.guide.height);
    Auxiliary { albedo: guide.albedo.clone(), normal: Image::from_pixels(width, height, guide.guide.normal.clone()) }
}

/// The auxiliary images of the samples in `path` for `effect`, made as `mode` says.
pub fn from_samples(path: &Path, effect: Effect, mode: AuxiliaryMode) -> Result<Auxiliary, MethodError> {
    let file = SampleFile::open(path)?;
    let header = file.header();
    let kind = effect.sample_kind();
    if header.kind != kind {
        let message = format!(
            "the denoiser's auxiliary images for effect {} need `{}` samples, the file holds `{}`",
            effect.name(),
            kind.name(),
            header.kind.name()
        );
        return Err(Error::sample_content(file.path(), message).into());
    }
    let needs = crate::needs::auxiliary(kind)
        .ok_or_else(|| Error::sample_content(file.path(), "light samples carry no auxiliary images"))?;
    file.check_needs(needs)?;
    let field = |name: &str| -> Result<&Field, Error> {
        file.field(name).ok_or_else(|| {
            Error::sample_content(file.path(), format!("`{}` samples lack the field `{name}`", kind.name()))
        })
    };
    let reader = Reader {
        albedo: match kind {
            SampleKind::Ao => None,
            _ => Some(field("albedo")?),
        },
        normal: field(if kind == SampleKind::LensTime { "normal" } else { "origin_normal" })?,
        lens: file.field("u").zip(file.field("v")),
        time: file.field("t"),
    };
    let (width, height) = (header.width, header.height);
    let record_size = (header.record_size as usize).max(1);
    let rows: Vec<Vec<([f32; 3], [f32; 3])>> = (0..height)
        .into_par_iter()
        .map(|y| {
            (0..width)
                .map(|x| {
                    let records = file.pixel_records(x, y).chunks_exact(record_size);
                    match mode {
                        AuxiliaryMode::Integrated => {
                            let (mut albedo, mut normal, mut count) = ([0.0f64; 3], [0.0f64; 3], 0u32);
                            for record in records {
                                let (a, n) = (reader.albedo(record), reader.normal(record));
                                for c in 0..3 {
                                    albedo[c] += a[c] as f64;
                                    normal[c] += n[c] as f64;
                                }
                                count += 1;
                            }
                            let n = count.max(1) as f64;
                            (albedo.map(|v| (v / n) as f32), normal.map(|v| (v / n) as f32))
                        }
                        AuxiliaryMode::Centre => records
                            .min_by(|a, b| reader.off_centre(a).total_cmp(&reader.off_centre(b)))
                            .map_or(([0.0; 3], [0.0; 3]), |record| (reader.albedo(record), reader.normal(record))),
                    }
                })
                .collect()
        })
        .collect();
    let (albedo, normal): (Vec<[f32; 3]>, Vec<[f32; 3]>) = rows.into_iter().flatten().unzip();
    Ok(Auxiliary {
        albedo: Image::from_pixels(width, height, albedo),
        normal: Image::from_pixels(width, height, normal),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleWriter};

    #[test]
    fn a_guides_auxiliaries_are_its_own_albedo_and_normal_pixel_for_pixel() {
        let (width, height) = (3, 2);
        let normal: Vec<[f32; 3]> =
            (0..6).map(|i| if i == 4 { [0.0; 3] } else { [0.0, (i % 2) as f32, 1.0] }).collect();
        let albedo: Vec<[f32; 3]> = (0..6).map(|i| [0.1 * i as f32, 0.5, 1.0 - 0.1 * i as f32]).collect();
        let guide = crate::method::GuideInput {
            guide: crate::guide::GuideBuffers {
                width,
                height,
                normal: normal.clone(),
                depth: vec![1.0; 6],
                position: vec![[0.0; 3]; 6],
                secondary_normal: None,
            },
            albedo: Image::from_pixels(width, height, albedo.clone()),
            indirect: Image::from_pixels(width, height, vec![[9.0; 3]; 6]),
            direct: Image::from_pixels(width, height, vec![[7.0; 3]; 6]),
            eye_rays: Default::default(),
        };
        let aux = from_guide(&guide);
        for i in 0..6u32 {
            let (x, y) = (i % width, i / width);
            assert_eq!(aux.albedo.get(x, y), albedo[i as usize]);
            assert_eq!(aux.normal.get(x, y), normal[i as usize], "a miss keeps its zero normal");
        }
    }

    /// The octahedral pair of a unit vector (the encoder of docs/sample-format.md, written here
    /// as a second implementation: the inverse of `crate::octahedral::decode`).
    fn encode(n: [f32; 3]) -> [f32; 2] {
        let l1 = n[0].abs() + n[1].abs() + n[2].abs();
        let (mut x, mut y) = (n[0] / l1, n[1] / l1);
        if n[2] < 0.0 {
            let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
            (x, y) = ((1.0 - y.abs()) * sign(x), (1.0 - x.abs()) * sign(y));
        }
        let q = |v: f32| ((v + 1.0) * 0.5 * 65534.0 + 1.0).round();
        [q(x), q(y)]
    }

    /// A defocused plane seen through a lens: `lens-time` samples whose albedo and normal vary
    /// with the lens position u (albedo u², normal tilted by u), 2 × 1 pixels, 4 spp.
    fn defocused(dir: &Path) -> (std::path::PathBuf, Vec<Vec<f32>>) {
        let spec = HeaderSpec::new(SampleKind::LensTime, 2, 1, 4)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("y", FieldType::F32, 1))
            .field(FieldSpec::new("u", FieldType::F32, 1))
            .field(FieldSpec::new("v", FieldType::F32, 1))
            .field(FieldSpec::new("albedo", FieldType::F16, 3))
            .field(FieldSpec::new("normal", FieldType::U16, 2));
        let mut samples = Vec::new();
        for x in 0..2 {
            for (i, u) in [-0.75f32, 0.1, 0.5, -0.25].into_iter().enumerate() {
                let tilt = 0.5 * u + x as f32 * 0.1;
                let n = [tilt, 0.0, (1.0 - tilt * tilt).sqrt()];
                let q = encode(n);
                let a = u * u;
                samples.push(vec![x as f32 + 0.5, 0.5, u, 0.1 * i as f32, a, 0.5, 0.25, q[0], q[1]]);
            }
        }
        let path = dir.join("defocused.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        for sample in &samples {
            writer.push(sample).unwrap();
        }
        (writer.finish().unwrap(), samples)
    }

    fn f16(v: f32) -> f32 {
        half::f16::from_f32(v).to_f32()
    }

    #[test]
    fn integrated_auxiliaries_are_the_per_sample_average_on_a_defocused_plane() {
        let dir = tempfile::tempdir().unwrap();
        let (path, samples) = defocused(dir.path());
        let aux = from_samples(&path, Effect::Dof, AuxiliaryMode::Integrated).unwrap();
        for x in 0..2usize {
            let pixel = &samples[4 * x..4 * x + 4];
            let mean = |f: &dyn Fn(&Vec<f32>) -> f32| pixel.iter().map(f).sum::<f32>() / 4.0;
            let albedo = aux.albedo.get(x as u32, 0);
            assert!((albedo[0] - mean(&|s| f16(s[4]))).abs() < 1e-6, "{albedo:?}");
            assert!((albedo[1] - 0.5).abs() < 1e-6 && (albedo[2] - 0.25).abs() < 1e-6, "{albedo:?}");
            let normal = aux.normal.get(x as u32, 0);
            // Each sample's normal to the encoding's precision (2/65534 per component).
            let nx = mean(&|s| 0.5 * s[2] + x as f32 * 0.1);
            let nz = mean(&|s| {
                let t = 0.5 * s[2] + x as f32 * 0.1;
                (1.0 - t * t).sqrt()
            });
            assert!((normal[0] - nx).abs() < 1e-4 && normal[1].abs() < 1e-4 && (normal[2] - nz).abs() < 1e-4);
        }
    }

    #[test]
    fn the_centre_auxiliary_is_the_sample_nearest_the_lens_centre() {
        let dir = tempfile::tempdir().unwrap();
        let (path, _) = defocused(dir.path());
        let aux = from_samples(&path, Effect::Dof, AuxiliaryMode::Centre).unwrap();
        // u = 0.1 (v = 0.1) is nearest the centre in both pixels: albedo u² = 0.01.
        for x in 0..2 {
            assert!((aux.albedo.get(x, 0)[0] - f16(0.01)).abs() < 1e-6, "{:?}", aux.albedo.get(x, 0));
            let tilt = 0.05 + x as f32 * 0.1;
            assert!((aux.normal.get(x, 0)[0] - tilt).abs() < 1e-4);
        }
    }

    #[test]
    fn ambient_occlusion_has_unit_albedo_and_misses_have_no_normal() {
        let dir = tempfile::tempdir().unwrap();
        let spec = HeaderSpec::new(SampleKind::Ao, 1, 1, 2)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("origin_normal", FieldType::U16, 2));
        let path = dir.path().join("ao.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        let up = encode([0.0, 0.0, 1.0]);
        writer.push(&[0.5, up[0], up[1]]).unwrap();
        writer.push(&[0.5, 0.0, 0.0]).unwrap(); // the camera ray escaped
        let path = writer.finish().unwrap();
        let aux = from_samples(&path, Effect::Ao, AuxiliaryMode::Integrated).unwrap();
        assert_eq!(aux.albedo.get(0, 0), [1.0; 3]);
        let n = aux.normal.get(0, 0);
        assert!(n[0].abs() < 1e-4 && n[1].abs() < 1e-4 && (n[2] - 0.5).abs() < 1e-4, "{n:?}");
    }

    #[test]
    fn a_file_without_the_fields_is_an_error_naming_it_and_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let spec = HeaderSpec::new(SampleKind::LensTime, 1, 1, 1)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("radiance", FieldType::F32, 3));
        let path = dir.path().join("plain.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        writer.push(&[0.5, 1.0, 1.0, 1.0]).unwrap();
        let path = writer.finish().unwrap();
        let error = from_samples(&path, Effect::Dof, AuxiliaryMode::Integrated).unwrap_err().to_string();
        assert!(error.contains("plain.lfrs") && error.contains("albedo"), "{error}");
        let error = from_samples(&path, Effect::Indirect, AuxiliaryMode::Integrated).unwrap_err().to_string();
        assert!(error.contains("plain.lfrs") && error.contains("indirect"), "{error}");
    }
}
