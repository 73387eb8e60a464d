//! Reading `lens-time` sample files (docs/sample-format.md) into the records the
//! reconstruction works on, through `sampleio` only.
//!
//! Fields a file omits because its scene does not need them take their neutral values: no
//! `u`, `v` (pinhole) → 0; no `t` (static) → 0.5, the shutter's middle; no `motion` → 0. A miss
//! keeps z = +∞. Samples with a non-finite position, lens or time coordinate, motion or
//! radiance, or a depth that is NaN or not positive, cannot be reprojected; they are dropped and
//! counted (the tracer never writes them; a file from elsewhere might). The optional `bandwidth`
//! (κ of the BRDF at the hit, for the bandwidth extension) is kept as the file's f16 when
//! present; a NaN or negative κ also drops its sample. The optional `direct` (emission plus the
//! first hit's direct light, for `gi=split`, `global_illumination`) is kept when present; a
//! non-finite one drops its sample too.

use half::f16;
use sampleio::{SampleFile, SampleKind};

use super::lens::LensModel;
use super::reprojection::LensTimeSample;
use crate::error::Error;

/// A lens-time file in memory.
#[derive(Clone, Debug)]
pub struct LensTimeSamples {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub lens: LensModel,
    /// The usable samples, in file order (pixel-major).
    pub samples: Vec<LensTimeSample>,
    /// `radiance[i]` belongs to `samples[i]`.
    pub radiance: Vec<[f32; 3]>,
    /// κ of `samples[i]` when the file has `bandwidth` (glossy scenes); 0 for diffuse and misses.
    pub kappa: Option<Vec<f16>>,
    /// The direct part of `radiance[i]` when the file has `direct`.
    pub direct: Option<Vec<[f32; 3]>>,
    /// `samples[i]` is record `file_index[i]` of the file.
    pub file_index: Vec<u32>,
    /// Samples dropped for non-finite or impossible values.
    pub dropped: usize,
    /// Whether the file has lens coordinates (a camera with an aperture) and time (motion).
    pub has_lens: bool,
    pub has_time: bool,
}

/// Reads a `lens-time` file; the error names the file and the missing or wrong part.
pub fn read_lens_time(file: &SampleFile) -> Result<LensTimeSamples, Error> {
    let content = |message: String| Error::sample_content(file.path(), message);
    let header = file.header();
    if header.kind != SampleKind::LensTime {
        return Err(content(format!("TLFR reads `lens-time` samples, the file holds `{}`", header.kind.name())));
    }
    file.check_needs(&crate::needs::TLFR)?;
    let camera = header.camera.as_ref().ok_or_else(|| content("the header has no `camera` block".to_string()))?;
    let lens = LensModel::from_camera(camera).map_err(|e| content(e.to_string()))?;
    let required = |name: &str| file.field(name).ok_or_else(|| content(format!("`lens-time` samples lack `{name}`")));
    let (x, y, z, radiance) = (required("x")?, required("y")?, required("z")?, required("radiance")?);
    let (u, v) = (file.field("u"), file.field("v"));
    if u.is_some() != v.is_some() {
        return Err(content("the file has only one of the lens fields `u`, `v`".to_string()));
    }
    let (t, motion) = (file.field("t"), file.field("motion"));
    let bandwidth = file.field("bandwidth");
    let mut kappa = bandwidth.map(|_| Vec::with_capacity(file.len()));
    let direct_field = file.field("direct");
    if direct_field.is_some() {
        // Declared as `gi=split` reads it: a `direct` of another shape is an error naming it.
        file.check_needs(&crate::needs::TLFR_GI_SPLIT)?;
    }
    let mut direct = direct_field.map(|_| Vec::with_capacity(file.len()));
    let mut samples = Vec::with_capacity(file.len());
    let mut radiances = Vec::with_capacity(file.len());
    let mut file_index = Vec::with_capacity(file.len());
    let mut dropped = 0;
    for i in 0..file.len() {
        let value = |field: &sampleio::Field, c: usize| file.value(i, field, c);
        let sample = LensTimeSample {
            x: value(x, 0),
            y: value(y, 0),
            u: u.map_or(0.0, |f| value(f, 0)),
            v: v.map_or(0.0, |f| value(f, 0)),
            t: t.map_or(0.5, |f| value(f, 0)),
            z: value(z, 0),
            motion: motion.map_or([0.0; 3], |f| [value(f, 0), value(f, 1), value(f, 2)]),
        };
        let colour = [value(radiance, 0), value(radiance, 1), value(radiance, 2)];
        let finite = [sample.x, sample.y, sample.u, sample.v, sample.t].iter().all(|c| c.is_finite())
            && sample.motion.iter().all(|c| c.is_finite())
            && colour.iter().all(|c| c.is_finite());
        let depth_ok = sample.z > 0.0 && (sample.z.is_finite() || sample.z == f32::INFINITY);
        let sample_kappa = bandwidth.map_or(0.0, |f| value(f, 0));
        let sample_direct = direct_field.map_or([0.0; 3], |f| [value(f, 0), value(f, 1), value(f, 2)]);
        let direct_ok = sample_direct.iter().all(|c| c.is_finite());
        if finite && depth_ok && direct_ok && (0.0..=1.0).contains(&sample.t) && sample_kappa >= 0.0 {
            if let Some(kappa) = kappa.as_mut() {
                kappa.push(f16::from_f32(sample_kappa));
            }
            if let Some(direct) = direct.as_mut() {
                direct.push(sample_direct);
            }
            samples.push(sample);
            radiances.push(colour);
            file_index.push(i as u32);
        } else {
            dropped += 1;
        }
    }
    Ok(LensTimeSamples {
        width: header.width,
        height: header.height,
        spp: header.spp,
        lens,
        samples,
        radiance: radiances,
        kappa,
        direct,
        file_index,
        dropped,
        has_lens: u.is_some(),
        has_time: t.is_some(),
    })
}

/// Refocusing after the fact (paper Section 6): every sample keeps its lens
/// coordinate, but is seen through the lens focused at `focus_distance` with radius
/// `aperture_radius`: moved to the lens centre with the file's C(z), then off it with the new
/// C'(z) = c1'/z + c2' (`LensModel::refocused`), before anything is built on the samples.
pub fn refocus(samples: &mut LensTimeSamples, focus_distance: f32, aperture_radius: f32) -> Result<(), Error> {
    let new_lens = samples.lens.refocused(focus_distance, aperture_radius)?;
    for sample in &mut samples.samples {
        let shift = new_lens.coc(sample.z) - samples.lens.coc(sample.z);
        sample.x += sample.u * shift;
        sample.y += sample.v * shift;
    }
    samples.lens = new_lens;
    Ok(())
}

/// The warning for `dropped` of `total` samples of the file at `path` that
/// `read_lens_time` could not use (non-finite or impossible values).
pub fn dropped_warning(path: &std::path::Path, dropped: usize, total: usize) -> String {
    crate::method::warning(format!(
        "{}: {dropped} of {total} samples have a non-finite or impossible position, lens, time, depth, motion or \
         radiance and were dropped{}",
        path.display(),
        if dropped == total { "; the image is black" } else { "" }
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleWriter};

    fn camera() -> sampleio::Camera {
        let fx = 50.0;
        sampleio::Camera {
            position: [0.0; 3],
            forward: [0.0, 0.0, 1.0],
            up: [0.0, -1.0, 0.0],
            right: [1.0, 0.0, 0.0],
            fov_deg: 40.0,
            fov_axis: sampleio::FovAxis::Y,
            aperture_radius: 0.0,
            focus_distance: 1.0,
            coc: sampleio::Coc { c1: 0.0, c2: 0.0 },
            shutter: [0.0, 1.0],
            pixel_to_camera: [
                [1.0 / fx, 0.0, -1.0 / fx, 0.0],
                [0.0, 1.0 / fx, -1.0 / fx, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            world_to_camera: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        }
    }

    fn write(dir: &std::path::Path, kind: SampleKind, fields: &[(&str, u32)], rows: &[Vec<f32>]) -> std::path::PathBuf {
        let mut spec = HeaderSpec::new(kind, 2, 1, 2);
        for (name, components) in fields {
            spec = spec.field(FieldSpec::new(*name, FieldType::F32, *components));
        }
        spec.camera = Some(camera());
        let path = dir.join("samples.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        for row in rows {
            writer.push(row).unwrap();
        }
        writer.finish().unwrap()
    }

    #[test]
    fn a_static_pinhole_file_gets_neutral_lens_and_time() {
        let dir = tempfile::tempdir().unwrap();
        let fields = [("x", 1), ("y", 1), ("z", 1), ("radiance", 3)];
        let rows = vec![
            vec![0.25, 0.5, 2.0, 1.0, 2.0, 3.0],
            vec![0.75, 0.5, f32::INFINITY, 0.5, 0.5, 0.5],
            vec![1.25, 0.5, f32::NAN, 1.0, 1.0, 1.0],
            vec![1.75, 0.5, 3.0, f32::INFINITY, 0.0, 0.0],
        ];
        let path = write(dir.path(), SampleKind::LensTime, &fields, &rows);
        let loaded = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap();
        assert_eq!((loaded.width, loaded.height, loaded.spp), (2, 1, 2));
        assert!(!loaded.has_lens && !loaded.has_time && loaded.lens.is_pinhole());
        assert_eq!(loaded.dropped, 2, "NaN depth and infinite radiance");
        assert_eq!(loaded.samples.len(), 2);
        assert_eq!((loaded.samples[0].u, loaded.samples[0].t, loaded.samples[0].motion), (0.0, 0.5, [0.0; 3]));
        assert_eq!(loaded.samples[1].z, f32::INFINITY, "a miss keeps its infinite depth");
        assert_eq!(loaded.radiance[0], [1.0, 2.0, 3.0]);
        assert!((loaded.lens.fx - 50.0).abs() < 1e-4);
    }

    #[test]
    fn lens_time_and_motion_are_read_when_present() {
        let dir = tempfile::tempdir().unwrap();
        let fields = [("x", 1), ("y", 1), ("u", 1), ("v", 1), ("t", 1), ("z", 1), ("motion", 3), ("radiance", 3)];
        let row = |x: f32, t: f32| vec![x, 0.5, 0.1, -0.2, t, 2.0, 0.5, 0.0, -0.25, 1.0, 1.0, 1.0];
        let rows = vec![row(0.2, 0.3), row(0.7, 1.5), row(1.2, 0.0), row(1.7, 1.0)];
        let path = write(dir.path(), SampleKind::LensTime, &fields, &rows);
        let loaded = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap();
        assert!(loaded.has_lens && loaded.has_time);
        assert!(loaded.kappa.is_none(), "no `bandwidth` field");
        assert_eq!(loaded.dropped, 1, "t = 1.5 is outside the shutter");
        assert_eq!(
            loaded.samples[0],
            LensTimeSample { x: 0.2, y: 0.5, u: 0.1, v: -0.2, t: 0.3, z: 2.0, motion: [0.5, 0.0, -0.25] }
        );
    }

    #[test]
    fn bandwidth_is_kept_and_bad_values_drop_their_sample() {
        let dir = tempfile::tempdir().unwrap();
        let fields = [("x", 1), ("y", 1), ("z", 1), ("radiance", 3), ("bandwidth", 1)];
        let row = |kappa: f32| vec![0.5, 0.5, 2.0, 1.0, 1.0, 1.0, kappa];
        let rows = vec![row(0.0), row(90.5), row(f32::NAN), row(-1.0)];
        let path = write(dir.path(), SampleKind::LensTime, &fields, &rows);
        let loaded = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap();
        assert_eq!(loaded.dropped, 2, "NaN and negative κ");
        assert_eq!(loaded.kappa, Some(vec![f16::from_f32(0.0), f16::from_f32(90.5)]));
        assert_eq!(loaded.samples.len(), 2);
    }

    #[test]
    fn direct_is_kept_and_a_non_finite_one_drops_its_sample() {
        let dir = tempfile::tempdir().unwrap();
        let fields = [("x", 1), ("y", 1), ("z", 1), ("radiance", 3), ("direct", 3)];
        let row = |d: f32| vec![0.5, 0.5, 2.0, 1.0, 1.0, 1.0, d, 0.5, 0.25];
        let rows = vec![row(0.75), row(f32::NAN), row(1.0), row(f32::INFINITY)];
        let path = write(dir.path(), SampleKind::LensTime, &fields, &rows);
        let loaded = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap();
        assert_eq!(loaded.dropped, 2, "NaN and infinite direct");
        assert_eq!(loaded.direct, Some(vec![[0.75, 0.5, 0.25], [1.0, 0.5, 0.25]]));
        assert_eq!(loaded.file_index, [0, 2]);
        let path = write(dir.path(), SampleKind::LensTime, &fields[..4], &vec![row(0.0)[..6].to_vec(); 4]);
        assert_eq!(read_lens_time(&SampleFile::open(&path).unwrap()).unwrap().direct, None);
    }

    #[test]
    fn refocusing_moves_samples_as_the_new_lens_would_have_seen_them() {
        let dir = tempfile::tempdir().unwrap();
        let fields = [("x", 1), ("y", 1), ("u", 1), ("v", 1), ("z", 1), ("radiance", 3)];
        let rows = vec![vec![0.5, 0.5, 0.5, -0.25, 2.0, 1.0, 1.0, 1.0]; 4];
        let mut path = write(dir.path(), SampleKind::LensTime, &fields, &rows);
        let mut loaded = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap();
        // The file is a pinhole (coc 0): refocus to distance 4 with radius 0.1, fx = 50:
        // C'(2) = 50·0.1·(1/4 − 1/2) = −1.25 px.
        refocus(&mut loaded, 4.0, 0.1).unwrap();
        let s = loaded.samples[0];
        assert!((s.x - (0.5 + 0.5 * -1.25)).abs() < 1e-6 && (s.y - (0.5 + 0.25 * 1.25)).abs() < 1e-6);
        // Back to a pinhole restores the positions.
        refocus(&mut loaded, 4.0, 0.0).unwrap();
        assert!((loaded.samples[0].x - 0.5).abs() < 1e-6 && (loaded.samples[0].y - 0.5).abs() < 1e-6);
        assert!(refocus(&mut loaded, -1.0, 0.1).is_err());
        path.pop();
    }

    #[test]
    fn other_kinds_and_missing_fields_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(dir.path(), SampleKind::Ao, &[("distance", 1)], &[vec![1.0], vec![1.0], vec![1.0], vec![1.0]]);
        let error = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
        assert!(error.contains("lens-time") && error.contains("samples.lfrs"), "{error}");
        let path = write(dir.path(), SampleKind::LensTime, &[("x", 1), ("y", 1), ("z", 1)], &vec![vec![0.0; 3]; 4]);
        let error = read_lens_time(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
        assert!(error.contains("`radiance`"), "{error}");
    }
}
