//! `lfr export`: our samples in the authors' public sample-buffer formats, so their reference
//! code can read them.
//!
//! TLFR 1.3 (`jiawen/temporal-lightfield-reconstruction`, `UVTSampleBuffer`): a text header in
//! `OUT.header` and, in `OUT`, 16 little-endian float32 per sample in (y, x, sample) order:
//! `x, y, z/w, w, u, v, t, r, g, b, a, mv_x, mv_y, mv_w, dwdx, dwdy`. What we write, field by
//! field, and what had to be assumed:
//! - `x, y`: our film position in pixels (window coordinates, not multiplied by w).
//! - `w`: camera-space depth (our `z`). Rays that hit nothing get w = 1e30 (the format has no
//!   miss marker; their reprojection then sees a point at infinity with no defocus).
//! - `z/w`: "as in OpenGL, not used by reconstruction" in their code; we write the depth-buffer
//!   value of an infinite perspective projection with near plane 1e-3: 1 − 2e-3 / w.
//! - `u, v`: our lens coordinates (unit disk, inside [-1, 1]²); 0 for a pinhole camera.
//!   Their reconstruction moves a sample to the lens centre by x − C(w)·u, y − C(w)·v, which
//!   is our convention (u along image +x, v along image +y, C = C1/z + C2).
//! - `t`: our time in [0, 1]; 0 for static scenes.
//! - `r, g, b`: radiance; `a` = 1.
//! - `mv`: the homogeneous screen motion from t = 0 to t = 1 that the paper's Eq. 3 uses,
//!   (fx ΔX + cx ΔZ, fy ΔY + cy ΔZ, ΔZ) from our camera-space motion and the header's
//!   `pixel_to_camera`; zero for static scenes.
//! - `dwdx, dwdy`: our `depth_gradient`.
//! - `CoC coefficients (coc radius = C0/w+C1)`: our C1, C2 (pixels), zero for a pinhole.
//! - Rows are written from our top row (y = 0) down, as our `y` runs; their reader takes the
//!   samples' own (x, y), so only their image display could be flipped, not the reconstruction.
//!
//! ILFR 2.2 (`jtlehtin/indirect-light-field-reconstruction`, README "Sample Buffer Format"): a
//! text header with the CoC coefficients and a 4×4 pixel-to-camera matrix, and 39 float32 per
//! sample: `x, y, w, u, v, t, r, g, b`, then the 3-vectors `pri_mv, pri_normal, albedo,
//! sec_origin, sec_hitpoint, sec_mv, sec_normal, direct, sec_albedo, sec_direct`.
//! - `w` is the angular bandwidth κ (their README: "unintuitive naming (w) ... for historical
//!   reasons"); 0 when our file has no `bandwidth` field (all-diffuse scene).
//! - Vectors are in *their* camera space: pbrt's left-handed x right, y up, z forward, origin at
//!   the lens centre. Ours is (right, down, forward), so y flips. Their README calls normals and
//!   motion vectors camera-space; for `sec_origin` and `sec_hitpoint` it does not say, and we
//!   assume camera space too, so all ten vectors share one frame.
//! - The pixel-to-camera matrix maps (x, y, ·, 1) to the point on the plane z = 1 seen from the
//!   lens centre: rows (1/fx, 0, 0, −cx/fx), (0, −1/fy, 0, cy/fy), (0, 0, 0, 1), (0, 0, 0, 1);
//!   their last row encodes a depth range we do not have.
//! - `sec_albedo` is "path throughput at the secondary hit" in their README; we write the
//!   secondary hit's reflectance (`secondary_albedo`), the throughput of a diffuse bounce there.
//! - A secondary ray that escaped gets `sec_hitpoint` 1e6 scene units away along its direction
//!   (the format has no miss marker), `sec_normal` 0; a camera ray that escaped gets zeros and
//!   only `direct` (the environment).

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use glam::{Mat3, Vec3};
use sampleio::{FieldNeed, Needs, SampleFile, SampleKind};
use tracer::samples::secondary::decode_octahedral;

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum ExportFormat {
    /// Lehtinen et al. 2011 sample buffers, version 1.3 (from `lens-time` samples).
    #[value(name = "tlfr-1.3")]
    Tlfr13,
    /// Lehtinen et al. 2012 sample buffers, version 2.2 (from `indirect` samples).
    #[value(name = "ilfr-2.2")]
    Ilfr22,
}

#[derive(clap::Args)]
pub struct ExportArgs {
    #[arg(long, value_enum)]
    format: ExportFormat,
    /// Sample file written by `lfr dump`.
    samples: PathBuf,
    /// Output file; its text header goes to OUT.header (`-`, standard output, is refused: the
    /// format is two files).
    out: PathBuf,
}

/// What `--format tlfr-1.3` reads of a `lens-time` file (checked before anything is written):
/// the fields ILFR's lens mode reads, camera rays with depth gradients.
pub const TLFR_1_3_NEEDS: Needs =
    Needs { consumer: "`lfr export --format tlfr-1.3`", fields: recon::needs::ILFR_LENS.fields };

/// What `--format ilfr-2.2` reads of an `indirect` file (checked before anything is written).
pub const ILFR_2_2_NEEDS: Needs = Needs {
    consumer: "`lfr export --format ilfr-2.2`",
    fields: &[
        FieldNeed::real("x", 1),
        FieldNeed::real("y", 1),
        FieldNeed::octahedral("direction"),
        FieldNeed::real("radiance", 3),
        FieldNeed::real("origin", 3),
        FieldNeed::real("hit", 3),
        FieldNeed::octahedral("origin_normal"),
        FieldNeed::octahedral("hit_normal"),
        FieldNeed::real("albedo", 3),
        FieldNeed::real("direct", 3),
        FieldNeed::real("secondary_albedo", 3),
        FieldNeed::real("secondary_direct", 3),
        FieldNeed::optional_real("u", 1),
        FieldNeed::optional_real("v", 1),
        FieldNeed::optional_real("t", 1),
        FieldNeed::optional_real("origin_motion", 3),
        FieldNeed::optional_real("hit_motion", 3),
        FieldNeed::optional_real("bandwidth", 1),
    ],
};

/// A field's values, or `None` when the file leaves the field out.
fn optional_column(file: &SampleFile, name: &str) -> Result<Option<Vec<f32>>> {
    match file.field(name) {
        Some(_) => Ok(Some(file.column(name)?)),
        None => Ok(None),
    }
}

/// A field's values; an error naming the file when it is missing.
fn required_column(file: &SampleFile, name: &str) -> Result<Vec<f32>> {
    optional_column(file, name)?.with_context(|| format!("{}: field `{name}` missing", file.path().display()))
}

/// `OUT.header` beside `OUT`.
fn header_path(out: &Path) -> PathBuf {
    let mut path = out.as_os_str().to_os_string();
    path.push(".header");
    PathBuf::from(path)
}

/// Focal lengths and principal point (fx, fy, cx, cy) in pixels from the header's
/// `pixel_to_camera` matrix.
pub fn pixel_projection(camera: &sampleio::Camera) -> (f64, f64, f64, f64) {
    let m = camera.pixel_to_camera;
    let (fx, fy) = (1.0 / m[0][0], 1.0 / m[1][1]);
    (fx, fy, -m[0][2] * fx, -m[1][2] * fy)
}

/// Streams `count` records of N little-endian float32 each into `out` and the text header into
/// `OUT.header`, both written atomically.
fn write_float_records<const N: usize>(
    out: &Path,
    header_text: &str,
    count: usize,
    record: impl Fn(usize) -> [f32; N],
) -> Result<()> {
    tracer::output::write_atomically(out, |tmp| {
        let write = || -> std::io::Result<()> {
            let mut writer = BufWriter::with_capacity(1 << 20, std::fs::File::create(tmp)?);
            for i in 0..count {
                for value in record(i) {
                    writer.write_all(&value.to_le_bytes())?;
                }
            }
            writer.into_inner().map_err(|e| e.into_error())?.sync_all()
        };
        write().map_err(|e| e.to_string())
    })?;
    tracer::output::write_atomically(&header_path(out), |tmp| {
        std::fs::write(tmp, header_text).map_err(|e| e.to_string())
    })?;
    Ok(())
}

pub fn run(args: &ExportArgs) -> Result<()> {
    let mut plan = crate::outputs::OutputPlan::new();
    plan.file(&args.out, "the output").file(&header_path(&args.out), "the text header beside the output");
    plan.input(&args.samples, "the sample file").check()?;
    let file = SampleFile::open(&args.samples)?;
    match args.format {
        ExportFormat::Tlfr13 => write_tlfr_1_3(&file, &args.out)?,
        ExportFormat::Ilfr22 => write_ilfr_2_2(&file, &args.out)?,
    }
    let format = match args.format {
        ExportFormat::Tlfr13 => "TLFR 1.3",
        ExportFormat::Ilfr22 => "ILFR 2.2",
    };
    println!("wrote {} samples to {} ({format})", file.len(), args.out.display());
    Ok(())
}

/// `v` with six decimals, without the sign of a value that rounds to zero (`-0.000000` reads as
/// a mistake in a text header).
fn fixed6(v: impl Into<f64>) -> String {
    let text = format!("{:.6}", v.into());
    match text.strip_prefix('-') {
        Some(rest) if rest.bytes().all(|b| b == b'0' || b == b'.') => rest.to_string(),
        _ => text,
    }
}

/// Miss depth written for rays that hit nothing.
pub const TLFR_MISS_DEPTH: f32 = 1e30;

/// Writes a TLFR 1.3 binary sample buffer and its `.header`.
pub fn write_tlfr_1_3(file: &SampleFile, out: &Path) -> Result<()> {
    let header = file.header();
    if header.kind != SampleKind::LensTime {
        bail!(
            "{}: TLFR 1.3 needs lens-time samples, this file holds {} samples",
            file.path().display(),
            header.kind.name()
        );
    }
    file.check_needs(&TLFR_1_3_NEEDS)?;
    let camera =
        header.camera.as_ref().with_context(|| format!("{}: no camera in the header", file.path().display()))?;
    let column = |name: &str| optional_column(file, name);
    let required = |name: &str| required_column(file, name);
    let (x, y, z, radiance, gradient) =
        (required("x")?, required("y")?, required("z")?, required("radiance")?, required("depth_gradient")?);
    let (u, v, t, motion) = (column("u")?, column("v")?, column("t")?, column("motion")?);
    let (fx, fy, cx, cy) = pixel_projection(camera);

    let header_text = format!(
        "Version 1.3\nWidth {}\nHeight {}\nSamples per pixel {}\nMotion model: affine\nCoC coefficients (coc radius = C0/w+C1): {},{}\nEncoding = binary\nx,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy\n",
        header.width, header.height, header.spp, camera.coc.c1 as f32, camera.coc.c2 as f32
    );

    write_float_records(out, &header_text, file.len(), |i| {
        let w = if z[i].is_finite() { z[i] } else { TLFR_MISS_DEPTH };
        let (dx, dy, dz) = match &motion {
            Some(mv) => (mv[3 * i] as f64, mv[3 * i + 1] as f64, mv[3 * i + 2] as f64),
            None => (0.0, 0.0, 0.0),
        };
        [
            x[i],
            y[i],
            1.0 - 2e-3 / w,
            w,
            u.as_ref().map_or(0.0, |u| u[i]),
            v.as_ref().map_or(0.0, |v| v[i]),
            t.as_ref().map_or(0.0, |t| t[i]),
            radiance[3 * i],
            radiance[3 * i + 1],
            radiance[3 * i + 2],
            1.0,
            (fx * dx + cx * dz) as f32,
            (fy * dy + cy * dz) as f32,
            dz as f32,
            gradient[2 * i],
            gradient[2 * i + 1],
        ]
    })
}

/// Writes an ILFR 2.2 binary sample buffer and its `.header`.
pub fn write_ilfr_2_2(file: &SampleFile, out: &Path) -> Result<()> {
    let header = file.header();
    if header.kind != SampleKind::Indirect {
        bail!(
            "{}: ILFR 2.2 needs indirect samples, this file holds {} samples",
            file.path().display(),
            header.kind.name()
        );
    }
    file.check_needs(&ILFR_2_2_NEEDS)?;
    let camera =
        header.camera.as_ref().with_context(|| format!("{}: no camera in the header", file.path().display()))?;
    let column = |name: &str| optional_column(file, name);
    let required = |name: &str| required_column(file, name);
    let (x, y, direction, radiance) = (required("x")?, required("y")?, required("direction")?, required("radiance")?);
    let (origin, hit, origin_normal, hit_normal) =
        (required("origin")?, required("hit")?, required("origin_normal")?, required("hit_normal")?);
    let (albedo, direct, secondary_albedo, secondary_direct) =
        (required("albedo")?, required("direct")?, required("secondary_albedo")?, required("secondary_direct")?);
    let (u, v, t) = (column("u")?, column("v")?, column("t")?);
    let (origin_motion, hit_motion, bandwidth) =
        (column("origin_motion")?, column("hit_motion")?, column("bandwidth")?);

    // World to their camera space (right, up, forward).
    let w2c = camera.world_to_camera;
    let row = |r: usize| Vec3::new(w2c[r][0] as f32, w2c[r][1] as f32, w2c[r][2] as f32);
    let rotation = Mat3::from_cols(row(0), -row(1), row(2)).transpose();
    let translation = Vec3::new(w2c[0][3] as f32, -(w2c[1][3] as f32), w2c[2][3] as f32);
    let to_camera_point = |p: Vec3| rotation * p + translation;
    let to_camera_vector = |v: Vec3| rotation * v;
    let (fx, fy, cx, cy) = pixel_projection(camera);
    let matrix = [1.0 / fx, 0.0, 0.0, -cx / fx, 0.0, -1.0 / fy, 0.0, cy / fy, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let matrix_text: Vec<String> = matrix.iter().map(|&v| fixed6(v)).collect();
    let header_text = format!(
        "Version 2.2\nWidth {}\nHeight {}\nSamples per pixel {}\nCoC coefficients (coc radius = C0/w+C1): {},{}\nPixel-to-camera matrix: {}\nEncoding = binary\nx,y,w,u,v,t,r,g,b,pri_mv(3d),pri_normal(3d),albedo(3d),sec_origin(3d),sec_hitpoint(3d),sec_mv(3d),sec_normal(3d),direct(3d),sec_albedo(3d),sec_direct(3d)\n",
        header.width,
        header.height,
        header.spp,
        fixed6(camera.coc.c1),
        fixed6(camera.coc.c2),
        matrix_text.join(",")
    );
    let vec3 = |c: &[f32], i: usize| Vec3::new(c[3 * i], c[3 * i + 1], c[3 * i + 2]);
    let octahedral = |c: &[f32], i: usize| decode_octahedral([c[2 * i], c[2 * i + 1]]);

    write_float_records(out, &header_text, file.len(), |i| {
        let n_o = octahedral(&origin_normal, i);
        let camera_ray_hit = n_o != Vec3::ZERO;
        let mut entry = [0.0f32; 39];
        entry[0] = x[i];
        entry[1] = y[i];
        entry[2] = bandwidth.as_ref().map_or(0.0, |b| b[i]);
        entry[3] = u.as_ref().map_or(0.0, |u| u[i]);
        entry[4] = v.as_ref().map_or(0.0, |v| v[i]);
        entry[5] = t.as_ref().map_or(0.0, |t| t[i]);
        entry[6..9].copy_from_slice(&vec3(&radiance, i).to_array());
        let put = |entry: &mut [f32; 39], slot: usize, value: Vec3| {
            entry[9 + 3 * slot..12 + 3 * slot].copy_from_slice(&value.to_array())
        };
        put(&mut entry, 7, vec3(&direct, i));
        if camera_ray_hit {
            let o = vec3(&origin, i);
            let n_h = octahedral(&hit_normal, i);
            let h = if n_h == Vec3::ZERO { o + octahedral(&direction, i) * 1e6 } else { vec3(&hit, i) };
            put(&mut entry, 0, origin_motion.as_ref().map_or(Vec3::ZERO, |m| to_camera_vector(vec3(m, i))));
            put(&mut entry, 1, to_camera_vector(n_o));
            put(&mut entry, 2, vec3(&albedo, i));
            put(&mut entry, 3, to_camera_point(o));
            put(&mut entry, 4, to_camera_point(h));
            put(&mut entry, 5, hit_motion.as_ref().map_or(Vec3::ZERO, |m| to_camera_vector(vec3(m, i))));
            put(&mut entry, 6, to_camera_vector(n_h));
            put(&mut entry, 8, vec3(&secondary_albedo, i));
            put(&mut entry, 9, vec3(&secondary_direct, i));
        }
        entry
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_decimals_never_show_a_negative_zero() {
        assert_eq!(fixed6(-0.0f32), "0.000000");
        assert_eq!(fixed6(-1e-9), "0.000000");
        assert_eq!(fixed6(-0.5), "-0.500000");
        assert_eq!(fixed6(2.0f32), "2.000000");
    }
}
