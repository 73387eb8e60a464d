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

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use sampleio::{SampleFile, SampleKind};

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum ExportFormat {
    /// Lehtinen et al. 2011 sample buffers, version 1.3 (from `lens-time` samples).
    #[value(name = "tlfr-1.3")]
    Tlfr13,
}

#[derive(clap::Args)]
pub struct ExportArgs {
    #[arg(long, value_enum)]
    format: ExportFormat,
    /// Sample file written by `lfr dump`.
    samples: PathBuf,
    /// Output file; TLFR's text header goes to OUT.header.
    out: PathBuf,
}

pub fn run(args: &ExportArgs) -> Result<()> {
    let file = SampleFile::open(&args.samples)?;
    match args.format {
        ExportFormat::Tlfr13 => write_tlfr_1_3(&file, &args.out)?,
    }
    println!("wrote {} samples to {} ({:?})", file.len(), args.out.display(), args.format);
    Ok(())
}

/// Miss depth written for rays that hit nothing.
pub const TLFR_MISS_DEPTH: f32 = 1e30;

/// Writes a TLFR 1.3 binary sample buffer and its `.header`.
pub fn write_tlfr_1_3(file: &SampleFile, out: &Path) -> Result<()> {
    let header = file.header();
    if header.kind != SampleKind::LensTime {
        bail!("{}: TLFR 1.3 needs lens-time samples, this file holds {:?}", file.path().display(), header.kind);
    }
    let camera =
        header.camera.as_ref().with_context(|| format!("{}: no camera in the header", file.path().display()))?;
    let column = |name: &str| -> Result<Option<Vec<f32>>> {
        match file.field(name) {
            Some(_) => Ok(Some(file.column(name)?)),
            None => Ok(None),
        }
    };
    let required = |name: &str| -> Result<Vec<f32>> {
        column(name)?.with_context(|| format!("{}: field `{name}` missing", file.path().display()))
    };
    let (x, y, z, radiance, gradient) =
        (required("x")?, required("y")?, required("z")?, required("radiance")?, required("depth_gradient")?);
    let (u, v, t, motion) = (column("u")?, column("v")?, column("t")?, column("motion")?);
    let m = camera.pixel_to_camera;
    let (fx, fy) = (1.0 / m[0][0], 1.0 / m[1][1]);
    let (cx, cy) = (-m[0][2] * fx, -m[1][2] * fy);

    let header_text = format!(
        "Version 1.3\nWidth {}\nHeight {}\nSamples per pixel {}\nMotion model: affine\nCoC coefficients (coc radius = C0/w+C1): {},{}\nEncoding = binary\nx,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy\n",
        header.width, header.height, header.spp, camera.coc.c1 as f32, camera.coc.c2 as f32
    );
    let mut header_path = out.as_os_str().to_os_string();
    header_path.push(".header");
    let header_path = PathBuf::from(header_path);

    tracer::output::write_atomically(out, |tmp| {
        let write = || -> std::io::Result<()> {
            let mut writer = BufWriter::with_capacity(1 << 20, std::fs::File::create(tmp)?);
            for i in 0..file.len() {
                let w = if z[i].is_finite() { z[i] } else { TLFR_MISS_DEPTH };
                let (dx, dy, dz) = match &motion {
                    Some(mv) => (mv[3 * i] as f64, mv[3 * i + 1] as f64, mv[3 * i + 2] as f64),
                    None => (0.0, 0.0, 0.0),
                };
                let entry: [f32; 16] = [
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
                ];
                for value in entry {
                    writer.write_all(&value.to_le_bytes())?;
                }
            }
            writer.into_inner().map_err(|e| e.into_error())?.sync_all()
        };
        write().map_err(|e| e.to_string())
    })?;
    tracer::output::write_atomically(&header_path, |tmp| std::fs::write(tmp, &header_text).map_err(|e| e.to_string()))?;
    Ok(())
}
