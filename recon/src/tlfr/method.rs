//! `tlfr`, `tlfr-nn` (`nearest`) and `tlfr-bw` (`bandwidth`) as `lfr compare` methods: reads the
//! effect's `lens-time` file, measures R on its pattern, indexes the samples and integrates N =
//! `recon_rays` reconstruction locations per pixel (effects `dof`, `motion`, `dof-motion`;
//! `tlfr` also `soft-shadow` with the light samples, `shadows`).

use std::time::Instant;

use sampleio::SampleFile;

use super::bandwidth::ViewBandwidth;
use super::bounds::ScreenArea;
use super::dispersion::measure_radius;
use super::fused::{Entries, Fused};
use super::global_illumination::{indirect_pixel_means, smooth_indirect, split_sample, GiMode};
use super::hierarchy::{reorder, Hierarchy};
use super::integrate::{integrate_adaptive, Reconstruct};
use super::lens::LensModel;
use super::nearest::reconstruct_nearest;
use super::query::{max_reach, reconstruct, Scene};
use super::reconstruction::Reconstruction;
use super::reprojection::{near_limit, LensTimeSample};
use super::same_surface::window_half_width;
use super::samples::{dropped_warning, read_lens_time, refocus};
use super::settings::{Kernel, TlfrSettings, DEFAULT_BANDWIDTH_SCALE, RADIUS_TRIALS};
use crate::baselines::box_filter::average;
use crate::error::Error;
use crate::image::Image;
use crate::method::{Effect, Input, Inputs, Method, MethodError, Output, Stats};

/// A TLFR method of `lfr compare`: the same reconstruction, finishing each location with
/// `value`, optionally with the bandwidth extension; `tlfr` also takes soft shadows.
#[derive(Clone, Copy, Debug)]
pub struct TlfrMethod {
    name: &'static str,
    /// Another value per location than the tent filter (through `query`), or `None`: the tent.
    value: Option<Reconstruct>,
    bandwidth_scale: Option<f32>,
    gi: GiMode,
    kernel: Kernel,
}

/// `tlfr`: the paper's reconstruction (effects `dof`, `motion`, `dof-motion`, `soft-shadow`).
/// Bytes a TLFR reconstruction holds per input sample at its peak (the file's records, the
/// reprojection samples, the hierarchy and its order). Measured with `lfr reconstruct` on
/// `monkeys-defocus-motion.toml` lens-time files from 49 k to 786 k samples: peak RSS grew by
/// 250-320 B a sample over a fixed ~46 MB; rounded up.
pub const BYTES_PER_SAMPLE: u64 = 384;

pub const TLFR: TlfrMethod = TlfrMethod {
    name: "tlfr",
    value: None,
    bandwidth_scale: None,
    gi: GiMode::Split { radius: super::global_illumination::DEFAULT_GI_RADIUS },
    kernel: Kernel::Fused,
};

/// `tlfr-nn`: the same reconstruction with the nearest sample's radiance instead of the filter
/// (`nearest`); effects `dof`, `motion`, `dof-motion`.
pub const TLFR_NEAREST: TlfrMethod = TlfrMethod {
    name: "tlfr-nn",
    value: Some(reconstruct_nearest),
    bandwidth_scale: None,
    gi: GiMode::Whole,
    kernel: Kernel::Oracle,
};

/// `tlfr-bw`: the reconstruction with the bandwidth extension (Figure 14, `bandwidth`): each
/// sample also weighted by a Gaussian in lens distance matched to its BRDF's bandwidth; effects
/// `dof`, `motion`, `dof-motion`.
pub const TLFR_BANDWIDTH: TlfrMethod = TlfrMethod {
    name: "tlfr-bw",
    value: None,
    bandwidth_scale: Some(DEFAULT_BANDWIDTH_SCALE),
    gi: GiMode::Whole,
    kernel: Kernel::Oracle,
};

impl TlfrMethod {
    /// This method with the bandwidth extension's scale set to `scale` (its default when `None`).
    pub fn with_bandwidth_scale(self, scale: Option<f32>) -> TlfrMethod {
        TlfrMethod { bandwidth_scale: scale.or(self.bandwidth_scale), ..self }
    }

    /// This method evaluating its locations with `kernel`.
    pub fn with_kernel(self, kernel: Kernel) -> TlfrMethod {
        TlfrMethod { kernel, ..self }
    }

    /// This method treating full global illumination as `gi` says (`global_illumination`).
    pub fn with_gi(self, gi: GiMode) -> TlfrMethod {
        TlfrMethod { gi, ..self }
    }
}

impl Method for TlfrMethod {
    fn input(&self) -> Input {
        Input::Samples
    }

    fn default_recon_rays(&self, _effect: Effect) -> Vec<u32> {
        vec![32, 128]
    }

    fn reads_light_samples(&self, effect: Effect) -> bool {
        effect == Effect::SoftShadow
    }

    fn sample_needs(&self, effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        use crate::needs::{TLFR, TLFR_GI_SPLIT, TLFR_LIGHT, TLFR_SOFT_SHADOW};
        Some(match (effect, self.gi) {
            (Effect::SoftShadow, _) => vec![&TLFR, &TLFR_SOFT_SHADOW, &TLFR_LIGHT],
            (_, GiMode::Whole) => vec![&TLFR],
            (_, GiMode::Split { .. }) => vec![&TLFR, &TLFR_GI_SPLIT],
        })
    }

    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError> {
        let path = inputs.samples(self.name)?;
        let settings = TlfrSettings {
            locations: recon_rays,
            seed: inputs.seed,
            bandwidth_scale: self.bandwidth_scale,
            gi: self.gi,
            kernel: self.kernel,
            ..TlfrSettings::default()
        };
        let reconstruction = if inputs.effect == Effect::SoftShadow {
            let light_path = inputs.light_samples(self.name)?;
            super::shadows::reconstruct_soft_shadow(path, light_path, &settings)?
        } else {
            reconstruct_file_with(self.value, path, &settings)?
        };
        let Reconstruction { image, preprocess_s, recon_s, notes } = reconstruction;
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
        Ok(Output { image, preprocess_s, recon_s, external_peak_rss_mb: None, notes, stats: Stats::new() })
    }
}

/// Reconstructs the image of a `lens-time` file.
pub fn reconstruct_file(path: &std::path::Path, settings: &TlfrSettings) -> Result<Reconstruction, MethodError> {
    reconstruct_file_with(None, path, settings)
}

/// A `lens-time` file made ready for queries (`prepare`): its samples in the hierarchy's order,
/// the hierarchy, R, and the times of reading, measuring R and building.
pub struct Prepared {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub samples: Vec<LensTimeSample>,
    pub radiance: Vec<[f32; 3]>,
    pub lens: LensModel,
    pub hierarchy: Hierarchy,
    pub radius: f32,
    pub z_near: f32,
    pub has_lens: bool,
    pub has_time: bool,
    pub view_bandwidth: Option<ViewBandwidth>,
    /// The entries as the fused kernel reads them (`Kernel::Fused` without the bandwidth
    /// extension).
    pub entries: Option<Entries>,
    /// The per-pixel mean of the file's samples (a pixel's value where no location found any;
    /// of their direct parts with `gi=split`).
    pub box_image: Image,
    /// With `gi=split`: the filtered indirect parts, added to the reconstruction of the direct.
    pub indirect: Option<Image>,
    /// Samples read (usable ones) and dropped.
    pub input_samples: usize,
    pub dropped: usize,
    pub notes: Vec<String>,
    /// Seconds: reading the file (and the box image), measuring R, building the hierarchy and
    /// putting the samples in its order.
    pub read_s: f64,
    pub radius_s: f64,
    pub hierarchy_s: f64,
}

impl Prepared {
    /// The fused kernel's view of these samples for the scene `scene` (`self.scene(N)`), when
    /// the entries were prepared.
    pub fn fused<'a>(&'a self, scene: &'a Scene<'a>) -> Option<Fused<'a>> {
        self.entries.as_ref().map(|entries| Fused { scene, entries, has_lens: self.has_lens, has_time: self.has_time })
    }

    /// The query's view of these samples for `locations` per pixel.
    pub fn scene(&self, locations: u32) -> Scene<'_> {
        Scene {
            samples: &self.samples,
            radiance: &self.radiance,
            lens: &self.lens,
            hierarchy: &self.hierarchy,
            radius: self.radius,
            z_near: self.z_near,
            delta: window_half_width(locations.max(1)),
            view_bandwidth: self.view_bandwidth.as_ref(),
        }
    }
}

/// Reads the `lens-time` file at `path`, refocuses it when `settings` say so, measures R on its
/// pattern and builds the hierarchy (everything before the first location).
pub fn prepare(path: &std::path::Path, settings: &TlfrSettings) -> Result<Prepared, MethodError> {
    let start = Instant::now();
    let file = SampleFile::open(path)?;
    let mut loaded = read_lens_time(&file)?;
    let (width, height) = (loaded.width, loaded.height);
    let (mut box_image, _) = average(&file, Effect::Dof, 0.0)?;
    let mut notes = Vec::new();
    let indirect = match settings.gi {
        GiMode::Whole => None,
        GiMode::Split { radius } => {
            file.check_needs(&crate::needs::TLFR_GI_SPLIT)?;
            let direct = loaded.direct.take().ok_or_else(|| {
                Error::sample_content(path, "gi=split needs the `direct` field (lfr dump --fields ...,direct)")
            })?;
            let mut rest = Vec::with_capacity(direct.len());
            for (radiance, direct) in loaded.radiance.iter_mut().zip(&direct) {
                let (direct, indirect) = split_sample(*radiance, *direct);
                *radiance = direct;
                rest.push(indirect);
            }
            let spp = loaded.spp as usize;
            let pixel_of = || loaded.file_index.iter().map(|&i| i as usize / spp);
            let depth: Vec<f32> = loaded.samples.iter().map(|s| s.z).collect();
            let (means, inverse_depth) = indirect_pixel_means((width, height), pixel_of(), &rest, &depth);
            box_image = indirect_pixel_means((width, height), pixel_of(), &loaded.radiance, &depth).0;
            notes.push(format!("gi=split: the direct part reconstructed, the rest filtered over radius {radius} px"));
            Some(smooth_indirect(&means, &inverse_depth, radius))
        }
    };
    drop(file);
    let sample_aperture = loaded.lens.aperture_radius();
    if let Some((focus_distance, aperture_radius)) = settings.refocus {
        refocus(&mut loaded, focus_distance, aperture_radius)?;
        notes.push(format!("refocused to distance {focus_distance} with lens radius {aperture_radius}"));
        if !loaded.has_lens && aperture_radius > 0.0 {
            notes.push(
                "the file has no lens coordinates: the new aperture only blurs, it cannot reveal hidden surfaces"
                    .into(),
            );
        }
    }
    let has_lens = loaded.has_lens || settings.refocus.is_some_and(|(_, a)| a > 0.0);
    let z_near = near_limit(loaded.samples.iter().map(|s| s.z));
    let read_s = start.elapsed().as_secs_f64();
    // Measuring R and building the hierarchy, for the caller's progress bar.
    crate::progress::begin("preprocessing", 2, "steps");
    let start = Instant::now();
    let radius = measure_radius(&loaded.samples, width, height, loaded.spp, RADIUS_TRIALS, settings.seed)
        .filter(|r| r.is_finite() && *r > 0.0)
        .unwrap_or(1.0);
    let radius_s = start.elapsed().as_secs_f64();
    crate::progress::advance(1);
    let start = Instant::now();
    let area = ScreenArea { width: width as f32, height: height as f32, max_reach: max_reach(radius) };
    let (hierarchy, order) = Hierarchy::build(&loaded.samples, &loaded.lens, z_near, &area);
    let (samples, radiance) = (reorder(&loaded.samples, &order), reorder(&loaded.radiance, &order));
    let view_bandwidth = match (settings.bandwidth_scale, &loaded.kappa) {
        (None, _) => None,
        (Some(scale), _) if !(scale.is_finite() && scale > 0.0) => {
            let message = format!("the bandwidth scale must be positive and finite, got {scale}");
            return Err(Error::parameter("bandwidth_scale", message).into());
        }
        (Some(_), None) => {
            notes.push(format!(
                "{}: no `bandwidth` field (no glossy surface): the bandwidth extension changes nothing",
                path.display()
            ));
            None
        }
        (Some(scale), Some(kappa)) => Some(ViewBandwidth {
            kappa: reorder(kappa, &order),
            sample_aperture,
            location_aperture: loaded.lens.aperture_radius(),
            scale,
        }),
    };
    let entries = (settings.kernel == Kernel::Fused && view_bandwidth.is_none())
        .then(|| Entries::new(&samples, &radiance, &loaded.lens, &hierarchy));
    let hierarchy_s = start.elapsed().as_secs_f64();
    crate::progress::end();
    Ok(Prepared {
        width,
        height,
        spp: loaded.spp,
        input_samples: loaded.samples.len(),
        samples,
        radiance,
        lens: loaded.lens,
        hierarchy,
        radius,
        z_near,
        has_lens,
        has_time: loaded.has_time,
        view_bandwidth,
        entries,
        box_image,
        indirect,
        dropped: loaded.dropped,
        notes,
        read_s,
        radius_s,
        hierarchy_s,
    })
}

/// `reconstruct_file` with another value per location (`nearest::reconstruct_nearest`), through
/// `query`; `None`: the tent filter, through the kernel `settings` name.
pub fn reconstruct_file_with(
    value: Option<Reconstruct>,
    path: &std::path::Path,
    settings: &TlfrSettings,
) -> Result<Reconstruction, MethodError> {
    let prepared = prepare(path, settings)?;
    let preprocess_s = prepared.read_s + prepared.radius_s + prepared.hierarchy_s;
    let build_s = prepared.hierarchy_s;
    let Prepared { width, height, radius, ref samples, ref hierarchy, input_samples, .. } = prepared;
    let mut notes = prepared.notes.clone();
    let start = Instant::now();
    let locations = settings.locations.max(1);
    let scene = prepared.scene(locations);
    let box_image = &prepared.box_image;
    let fallback = |x: u32, y: u32| box_image.pixels[(y * width + x) as usize];
    let n = (locations, settings.adaptive);
    let (mut image, stats) = match (value, prepared.fused(&scene)) {
        (None, Some(fused)) => super::fused::integrate(&fused, (width, height), n, settings.seed, fallback),
        (value, _) => {
            let has = (prepared.has_lens, prepared.has_time);
            let value = value.unwrap_or(reconstruct);
            integrate_adaptive(value, &scene, (width, height), n, has, settings.seed, fallback)
        }
    };
    if value.is_none() && prepared.entries.is_some() {
        notes.push("the fused kernel (one SIMD pass per sample)".into());
    }
    if let Some(indirect) = &prepared.indirect {
        for (pixel, rest) in image.pixels.iter_mut().zip(&indirect.pixels) {
            for c in 0..3 {
                pixel[c] += rest[c];
            }
        }
    }
    let recon_s = start.elapsed().as_secs_f64();
    let per_location = |n: u64| 100.0 * n as f64 / stats.locations.max(1) as f64;
    let record_bytes = std::mem::size_of::<LensTimeSample>() + std::mem::size_of::<[f32; 3]>();
    // Per input sample: a sample split into time segments has a record per segment.
    let kappa_bytes = prepared.view_bandwidth.as_ref().map_or(0, |v| v.kappa.len() * std::mem::size_of::<half::f16>());
    let bytes =
        (samples.len() * record_bytes + kappa_bytes + hierarchy.node_bytes()) as f64 / input_samples.max(1) as f64;
    notes.push(format!(
        "R = {radius:.3} px measured on the input pattern ({:.2}/sqrt(spp); paper: about 2)",
        radius * (prepared.spp as f32).sqrt()
    ));
    notes.push(format!(
        "{} locations ({:.1} per pixel): {:.1}% one surface, {:.1}% quadrant accepts, {:.1}% triangle searches, {:.2}% widened, {:.3}% dropped",
        stats.locations,
        stats.locations as f64 / (width as f64 * height as f64),
        per_location(stats.one_surface),
        per_location(stats.coverage.quadrant_accepts),
        per_location(stats.coverage.triangle_searches),
        per_location(stats.widened),
        per_location(stats.dropped)
    ));
    notes.push(format!(
        "hierarchy: {} leaves ({:.1} entries each), {} nodes, built in {build_s:.3} s; {:.1} leaves per location and pass",
        hierarchy.leaf_count(),
        samples.len() as f64 / hierarchy.leaf_count().max(1) as f64,
        hierarchy.nodes().len(),
        stats.leaves as f64 / stats.locations.max(1) as f64
    ));
    notes.push(format!(
        "{bytes:.1} bytes per sample in memory ({record_bytes} record and radiance{} per entry, {} entries of which {} \
         time segments, {:.1} nodes)",
        if kappa_bytes > 0 { " + 2 κ" } else { "" },
        hierarchy.entry_count(),
        hierarchy.segment_entries(),
        hierarchy.node_bytes() as f64 / input_samples.max(1) as f64
    ));
    if prepared.dropped > 0 {
        notes.push(dropped_warning(path, prepared.dropped, input_samples + prepared.dropped));
    }
    if hierarchy.unplaced > 0 {
        notes.push(format!(
            "{} of {input_samples} samples are never in front of the camera near the image and were not indexed",
            hierarchy.unplaced
        ));
    }
    Ok(Reconstruction { image, preprocess_s, recon_s, notes })
}
