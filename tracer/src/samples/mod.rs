//! Sample dumps: the tracer's samples written through `sampleio` for the reconstructions and
//! for external tools. One file per kind (`lens_time.rs`, ...); this module holds what every
//! kind shares: the camera block of the header and the streaming driver that traces rows in
//! parallel and writes them in pixel-major order, so that memory stays bounded by one batch
//! of rows and the file is identical for any thread count.

pub mod guide;
pub mod lens_time;
pub mod light;
pub mod secondary;

use std::path::Path;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use sampleio::{HeaderSpec, SampleWriter};

use crate::accel::Accel;
use crate::camera::{Camera, FovAxis};
use crate::error::RenderError;
use crate::integrator::Integrator;
use crate::lights::LightSampler;
use crate::render::RenderSettings;
use crate::scene::Scene;

/// The path integrator the dumps share, at the dump's resolution and path length.
pub fn integrator<'a>(
    scene: &'a Scene,
    accel: &'a Accel,
    lights: &'a LightSampler,
    settings: &RenderSettings,
) -> Integrator<'a> {
    Integrator::new(scene, accel, lights, settings.max_bounces, settings.width, settings.height)
}

/// What a dump wrote.
#[derive(Clone, Debug)]
pub struct DumpReport {
    pub samples: u64,
    pub bytes: u64,
    pub record_size: usize,
    pub fields: Vec<String>,
    pub seconds: f64,
    /// Path contributions that were NaN or infinite and were dropped (`TracedRay::dropped`).
    pub dropped_contributions: u64,
}

impl DumpReport {
    pub fn bytes_per_sample(&self) -> f64 {
        self.bytes as f64 / self.samples.max(1) as f64
    }
}

fn to_f64(v: glam::Vec3) -> [f64; 3] {
    [v.x as f64, v.y as f64, v.z as f64]
}

/// The header's camera block: pose, projection, circle of confusion and the matrices between
/// pixels, camera space and world space (camera space: X right, Y down, Z forward).
pub fn camera_header(camera: &Camera, width: u32, height: u32) -> sampleio::Camera {
    let (focal, centre) = camera.pixel_projection(width, height);
    let (c1, c2) = camera.circle_of_confusion(width, height);
    let (fx, fy, cx, cy) = (focal.x as f64, focal.y as f64, centre.x as f64, centre.y as f64);
    let down = -camera.up;
    let p = camera.position;
    let row = |axis: glam::Vec3| [axis.x as f64, axis.y as f64, axis.z as f64, -(axis.dot(p) as f64)];
    sampleio::Camera {
        position: to_f64(camera.position),
        forward: to_f64(camera.forward),
        up: to_f64(camera.up),
        right: to_f64(camera.right),
        fov_deg: camera.fov_deg as f64,
        fov_axis: match camera.fov_axis {
            FovAxis::X => sampleio::FovAxis::X,
            FovAxis::Y => sampleio::FovAxis::Y,
            FovAxis::Smaller => sampleio::FovAxis::Smaller,
            FovAxis::Larger => sampleio::FovAxis::Larger,
        },
        aperture_radius: camera.aperture_radius as f64,
        focus_distance: camera.focus_distance as f64,
        coc: sampleio::Coc { c1: c1 as f64, c2: c2 as f64 },
        shutter: [camera.shutter[0] as f64, camera.shutter[1] as f64],
        pixel_to_camera: [
            [1.0 / fx, 0.0, -cx / fx, 0.0],
            [0.0, 1.0 / fy, -cy / fy, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
        world_to_camera: [row(camera.right), row(down), row(camera.forward), [0.0, 0.0, 0.0, 1.0]],
    }
}

/// Traces every pixel's samples with `sample_pixel` (which appends `spp` records of
/// `values_per_sample` values for pixel (x, y)) in parallel batches of rows and streams them
/// into `path` in pixel-major order.
pub fn write_samples<F>(
    path: &Path,
    spec: HeaderSpec,
    settings: &RenderSettings,
    values_per_sample: usize,
    sample_pixel: F,
) -> Result<DumpReport, RenderError>
where
    F: Fn(u32, u32, &mut Vec<f32>) + Sync,
{
    settings.validate()?;
    let output_error =
        |e: sampleio::SampleError| RenderError::Output { path: path.to_path_buf(), message: e.to_string() };
    let mut writer = SampleWriter::create(path, spec).map_err(output_error)?;
    let record_size = writer.header().record_size as usize;
    let fields = writer.header().fields.iter().map(|f| f.name.clone()).collect();
    let pool = crate::render::thread_pool(settings.threads)?;
    let bar = if settings.progress {
        let bar = ProgressBar::new(settings.height as u64);
        bar.set_style(
            ProgressStyle::with_template("dump [{elapsed_precise}] {wide_bar} {pos}/{len} rows (eta {eta})")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar
    } else {
        ProgressBar::hidden()
    };
    let start = Instant::now();
    // Enough rows per batch to keep every thread busy, few enough to bound memory (~64 MiB).
    let row_values = settings.width as usize * settings.spp as usize * values_per_sample;
    let rows_per_batch = ((16 << 20) / row_values.max(1)).clamp(1, 64) as u32;
    let mut y0 = 0;
    while y0 < settings.height {
        let y1 = (y0 + rows_per_batch).min(settings.height);
        let rows: Vec<Vec<f32>> = pool.install(|| {
            (y0..y1)
                .into_par_iter()
                .map(|y| {
                    let mut values = Vec::with_capacity(row_values);
                    for x in 0..settings.width {
                        sample_pixel(x, y, &mut values);
                    }
                    values
                })
                .collect()
        });
        for row in rows {
            debug_assert_eq!(row.len(), row_values);
            for sample in row.chunks_exact(values_per_sample) {
                writer.push(sample).map_err(output_error)?;
            }
            bar.inc(1);
        }
        y0 = y1;
    }
    let samples = writer.pushed();
    let final_path = writer.finish().map_err(output_error)?;
    bar.finish_and_clear();
    let bytes = std::fs::metadata(&final_path).map(|m| m.len()).unwrap_or(0);
    let seconds = start.elapsed().as_secs_f64();
    Ok(DumpReport { samples, bytes, record_size, fields, seconds, dropped_contributions: 0 })
}
