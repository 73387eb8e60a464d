//! `tlfr` as a `lfr compare` method: reads the effect's `lens-time` file, measures R on its
//! pattern, indexes the samples and integrates N = `recon_rays` reconstruction locations per
//! pixel (effects `dof`, `motion`, `dof-motion`; soft shadows need the light samples, not yet).

use std::time::Instant;

use sampleio::SampleFile;

use super::dispersion::measure_radius;
use super::index::SampleGrid;
use super::integrate::integrate;
use super::query::Scene;
use super::reprojection::{near_limit, LensTimeSample};
use super::same_surface::window_half_width;
use super::samples::read_lens_time;
use crate::box_filter::average;
use crate::method::{Effect, Input, Inputs, Method, MethodError, Output};

/// Random reprojections for measuring R.
pub const RADIUS_TRIALS: u32 = 32;

pub struct Tlfr;

impl Method for Tlfr {
    fn name(&self) -> &str {
        "tlfr"
    }

    fn description(&self) -> &'static str {
        "temporal light field reconstruction (Lehtinen et al. 2011), grid index in place of the paper's hierarchy"
    }

    fn supports(&self, effect: Effect) -> bool {
        matches!(effect, Effect::Dof | Effect::Motion | Effect::DofMotion)
    }

    fn input(&self) -> Input {
        Input::Samples
    }

    fn default_recon_rays(&self) -> Vec<u32> {
        vec![32, 128]
    }

    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError> {
        let path = inputs.samples.as_ref().ok_or_else(|| MethodError::Failed("tlfr needs a sample file".into()))?;
        let start = Instant::now();
        let file = SampleFile::open(path)?;
        let loaded = read_lens_time(&file).map_err(MethodError::Failed)?;
        let (width, height) = (loaded.width, loaded.height);
        if (width, height) != (inputs.width, inputs.height) {
            return Err(MethodError::Failed(format!(
                "{}: samples are {width}x{height}, the comparison is {}x{}",
                path.display(),
                inputs.width,
                inputs.height
            )));
        }
        let (box_image, _) = average(&file, inputs.effect, inputs.ao_radius)?;
        drop(file);
        let z_near = near_limit(loaded.samples.iter().map(|s| s.z));
        let radius = measure_radius(&loaded.samples, width, height, loaded.spp, RADIUS_TRIALS)
            .filter(|r| r.is_finite() && *r > 0.0)
            .unwrap_or(1.0);
        let margin = 16.0 * radius + 2.0;
        let grid = SampleGrid::build(
            &loaded.samples,
            &loaded.lens,
            loaded.has_lens,
            z_near,
            (width, height),
            margin,
            2.0 * radius,
        );
        let preprocess_s = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let locations = recon_rays.max(1);
        let scene = Scene {
            samples: &loaded.samples,
            radiance: &loaded.radiance,
            lens: &loaded.lens,
            grid: &grid,
            radius,
            z_near,
            delta: window_half_width(locations),
        };
        let fallback = |x: u32, y: u32| box_image.pixels[(y * width + x) as usize];
        let (image, stats) =
            integrate(&scene, (width, height), locations, (loaded.has_lens, loaded.has_time), 0, fallback);
        let recon_s = start.elapsed().as_secs_f64();
        let per_location = |n: u64| 100.0 * n as f64 / stats.locations.max(1) as f64;
        let bytes =
            std::mem::size_of::<LensTimeSample>() as f64 + 12.0 + 4.0 * grid.entries_per_sample(loaded.samples.len());
        let mut notes = vec![
            format!(
                "R = {radius:.3} px measured on the input pattern ({:.2}/sqrt(spp); paper: about 2)",
                radius * (loaded.spp as f32).sqrt()
            ),
            format!(
                "{} locations: {:.1}% one surface, {:.1}% quadrant accepts, {:.1}% triangle searches, {:.2}% widened, {:.3}% dropped",
                stats.locations,
                per_location(stats.one_surface),
                per_location(stats.coverage.quadrant_accepts),
                per_location(stats.coverage.triangle_searches),
                per_location(stats.widened),
                per_location(stats.dropped)
            ),
            format!("{bytes:.0} bytes per sample in memory (record, radiance, grid entries)"),
        ];
        if loaded.dropped > 0 {
            notes.push(format!("{} samples with non-finite or impossible values were dropped", loaded.dropped));
        }
        if grid.unplaced > 0 {
            notes.push(format!("{} samples are never in front of the camera and were not indexed", grid.unplaced));
        }
        Ok(Output { image, preprocess_s, recon_s, external_peak_rss_mb: None, notes })
    }
}
