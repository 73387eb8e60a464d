//! The frame loop: pixels in 16×16 tiles, tiles in parallel on a rayon pool whose threads all
//! run with flush-to-zero and denormals-are-zero (Embree's recommendation). Every sample's
//! random numbers depend only on (seed, pixel, sample index), and each pixel is accumulated by
//! one thread in sample order, so the image is bit-identical for any thread count. Within a
//! tile, each sample index's paths advance together as a wavefront (`render_tile`).

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use crate::accel::{Accel, Hit};
use crate::error::RenderError;
use crate::integrator::{
    preload_vertices, Integrator, NoRecording, PathSample, PathState, RayRecorder, RecordedRay, ShadowTest,
};
use crate::lights::LightSampler;
use crate::limits::{MAX_IMAGE_SIDE, MAX_SPP, MAX_THREADS};
use crate::sampler::Sampler;
use crate::scene::Scene;

const TILE: u32 = 16;

/// How to trace an image or a sample dump: size, samples per pixel, seed, path length,
/// threads and progress; the scene gives what the command line does not.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub seed: u32,
    pub max_bounces: u32,
    /// Worker threads; 0 = all cores.
    pub threads: usize,
    pub progress: bool,
}

impl RenderSettings {
    /// Checks that every one of `pixels` lies inside the image, naming the first that does not.
    pub fn check_inside(&self, pixels: &[(u32, u32)]) -> Result<(), RenderError> {
        match pixels.iter().find(|&&(x, y)| x >= self.width || y >= self.height) {
            Some(&(x, y)) => Err(RenderError::Settings(format!(
                "pixel ({x}, {y}) is outside the {}x{} image",
                self.width, self.height
            ))),
            None => Ok(()),
        }
    }

    /// The scene's own resolution, spp and bounce limit.
    pub fn from_scene(scene: &Scene) -> RenderSettings {
        RenderSettings {
            width: scene.width,
            height: scene.height,
            spp: scene.spp,
            seed: 0,
            max_bounces: scene.max_bounces,
            threads: 0,
            progress: false,
        }
    }

    /// Checks the sizes against `crate::limits`; the error names the option.
    pub fn validate(&self) -> Result<(), RenderError> {
        let (width, height) = (self.width, self.height);
        if !(1..=MAX_IMAGE_SIDE).contains(&width) || !(1..=MAX_IMAGE_SIDE).contains(&height) {
            return Err(RenderError::Settings(format!(
                "--width and --height must be in 1..={MAX_IMAGE_SIDE}, got {width}x{height}"
            )));
        }
        if !(1..=MAX_SPP).contains(&self.spp) {
            return Err(RenderError::Settings(format!("--spp must be in 1..={MAX_SPP}, got {}", self.spp)));
        }
        if self.threads > MAX_THREADS {
            return Err(RenderError::Settings(format!(
                "--threads must be at most {MAX_THREADS} (0 = all cores), got {}",
                self.threads
            )));
        }
        Ok(())
    }
}

/// Per-pixel results, row-major from the top-left, all linear.
#[derive(Clone, Debug, Default)]
pub struct RenderedImage {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// Mean radiance.
    pub beauty: Vec<Vec3>,
    pub direct: Vec<Vec3>,
    pub indirect: Vec<Vec3>,
    /// Mean first-hit albedo, normal and position over the samples that hit a surface.
    pub albedo: Vec<Vec3>,
    pub normal: Vec<Vec3>,
    pub position: Vec<Vec3>,
    /// Mean camera-space depth of the first hit; 0 where no sample hit anything.
    pub depth: Vec<f32>,
    /// Variance of the beauty mean (sample variance / spp), per channel.
    pub variance: Vec<Vec3>,
    /// Samples whose radiance was NaN or infinite and was dropped.
    pub invalid_samples: u64,
    /// Variance values beyond f32's range (radiance above about 1.8e19), stored as `f32::MAX`
    /// instead of becoming infinite.
    pub clamped_variances: u64,
    /// Contributions to a path that were NaN or infinite and were dropped
    /// (`TracedRay::dropped`): the image is then darker than the scene says.
    pub dropped_contributions: u64,
    pub rays: u64,
    pub seconds: f64,
}

impl RenderedImage {
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// One line per kind of value this frame dropped or clamped (none for a clean frame),
    /// for the commands to print as warnings.
    pub fn warnings(&self) -> Vec<String> {
        value_warnings(self.dropped_contributions, self.invalid_samples, self.clamped_variances)
    }
}

/// The warnings of everything that traces light (a render, the guide buffers, a sample dump):
/// one line per kind of value dropped or clamped, none when all counts are zero.
pub fn value_warnings(dropped_contributions: u64, invalid_samples: u64, clamped_values: u64) -> Vec<String> {
    let mut warnings = Vec::new();
    if dropped_contributions > 0 {
        warnings.push(format!(
            "{dropped_contributions} path contributions were NaN or infinite (e.g. an emitter too bright for f32) and \
             were dropped; the image is darker than the scene"
        ));
    }
    if invalid_samples > 0 {
        warnings.push(format!("{invalid_samples} samples had non-finite radiance and were dropped"));
    }
    if clamped_values > 0 {
        warnings.push(format!(
            "{clamped_values} values exceed the f32 range (e.g. the variance of radiance above ~1.8e19) and were \
             stored as {:e}",
            f32::MAX
        ));
    }
    warnings
}

/// Per-pixel accumulator in double precision.
#[derive(Clone, Copy, Default)]
struct PixelSum {
    sum: [f64; 3],
    sum_sq: [f64; 3],
    direct: [f64; 3],
    indirect: [f64; 3],
    albedo: Vec3,
    normal: Vec3,
    position: Vec3,
    depth: f64,
    hits: u32,
    invalid: u32,
}

impl PixelSum {
    /// `sums` (one of this pixel's sums) over its valid samples of `spp`; zero when none is.
    fn mean(&self, spp: u32, sums: [f64; 3]) -> Vec3 {
        let valid = (spp - self.invalid) as f64;
        if valid > 0.0 {
            Vec3::new((sums[0] / valid) as f32, (sums[1] / valid) as f32, (sums[2] / valid) as f32)
        } else {
            Vec3::ZERO
        }
    }

    /// Adds one sample (dropping it, and counting it invalid, when its radiance is not finite).
    fn add(&mut self, sample: &PathSample) {
        let radiance = sample.radiance();
        if !radiance.is_finite() {
            self.invalid += 1;
            return;
        }
        for c in 0..3 {
            let v = radiance[c] as f64;
            self.sum[c] += v;
            self.sum_sq[c] += v * v;
            self.direct[c] += sample.direct[c] as f64;
            self.indirect[c] += sample.indirect[c] as f64;
        }
        if let Some(first) = sample.first_hit {
            self.hits += 1;
            self.albedo += first.albedo;
            self.normal += first.normal;
            self.position += first.position;
            self.depth += first.depth as f64;
        }
    }
}

struct TileResult {
    x0: u32,
    y0: u32,
    width: u32,
    pixels: Vec<PixelSum>,
    rays: u64,
}

/// Renders one tile as a wavefront ([`trace_pixels`] over the tile's pixels, row by row).
fn render_tile<R: RayRecorder>(
    integrator: &Integrator,
    settings: &RenderSettings,
    samples: std::ops::Range<u32>,
    x0: u32,
    y0: u32,
    recorder: &mut R,
) -> TileResult {
    let x1 = (x0 + TILE).min(settings.width);
    let y1 = (y0 + TILE).min(settings.height);
    let tile: Vec<(u32, u32)> = (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).collect();
    let (pixels, rays) = trace_pixels(integrator, settings, samples, &tile, recorder);
    TileResult { x0, y0, width: x1 - x0, pixels, rays }
}

/// Traces samples `samples` of each of `pixels` as a wavefront: for each sample index, the
/// paths of all the pixels advance together, one ray at a time: every live path's closest-hit
/// ray is traced, then every hit is shaded, then every shadow ray is traced. Each phase runs one
/// kind of work over independent paths, so the vertex data of all hits can be loaded ahead of
/// shading with their cache misses overlapping (`preload_vertices`), which a single path's
/// chain of dependent loads does not allow. Returns each pixel's sums and the rays traced.
///
/// Each path takes the same steps as `Integrator::trace_ray`, and its random numbers depend
/// only on (seed, pixel, sample index), so a pixel's sums are bit-identical to tracing its
/// paths one at a time, whatever other pixels share the wavefront.
fn trace_pixels<R: RayRecorder>(
    integrator: &Integrator,
    settings: &RenderSettings,
    samples: std::ops::Range<u32>,
    pixel_list: &[(u32, u32)],
    recorder: &mut R,
) -> (Vec<PixelSum>, u64) {
    let pixel_count = pixel_list.len();
    let mut pixels = vec![PixelSum::default(); pixel_count];
    let mut rays = 0u64;
    let mut paths: Vec<PathState> = Vec::with_capacity(pixel_count);
    let mut live: Vec<(usize, RecordedRay)> = Vec::with_capacity(pixel_count);
    let mut hits: Vec<Option<Hit>> = Vec::with_capacity(pixel_count);
    let mut shadows: Vec<(usize, ShadowTest)> = Vec::with_capacity(pixel_count);
    for index in samples {
        paths.clear();
        for &(px, py) in pixel_list {
            let mut sampler = Sampler::new(settings.seed, px, py, index);
            let camera_sample = integrator.camera_sample(px, py, &mut sampler);
            paths.push(integrator.start_path(&integrator.camera_path_start(&camera_sample), sampler));
        }
        loop {
            live.clear();
            for (i, path) in paths.iter_mut().enumerate() {
                if let Some(ray) = integrator.next_ray(path, recorder) {
                    live.push((i, ray));
                }
            }
            if live.is_empty() {
                break;
            }
            hits.clear();
            hits.extend(
                live.iter()
                    .map(|(_, ray)| integrator.accel.intersect(ray.origin, ray.direction, 0.0, ray.t_max, ray.time)),
            );
            shadows.clear();
            preload_vertices(integrator.scene, &hits);
            for ((i, _), hit) in live.iter().zip(&hits) {
                if let Some(test) = integrator.shade(&mut paths[*i], hit.as_ref(), recorder) {
                    shadows.push((*i, test));
                }
            }
            for (i, test) in &shadows {
                let occluded = integrator.is_occluded(test);
                integrator.resolve_shadow(&mut paths[*i], test, occluded);
            }
        }
        for (acc, path) in pixels.iter_mut().zip(&paths) {
            integrator.count_dropped(&path.traced);
            let sample = PathSample::from(path.traced);
            rays += sample.rays as u64;
            acc.add(&sample);
        }
    }
    (pixels, rays)
}

fn tiles(settings: &RenderSettings) -> Vec<(u32, u32)> {
    let mut tiles = Vec::new();
    for y in (0..settings.height).step_by(TILE as usize) {
        for x in (0..settings.width).step_by(TILE as usize) {
            tiles.push((x, y));
        }
    }
    tiles
}

/// A rayon pool whose workers run with FTZ/DAZ set.
pub fn thread_pool(threads: usize) -> Result<rayon::ThreadPool, RenderError> {
    if threads > MAX_THREADS {
        return Err(RenderError::Settings(format!(
            "--threads must be at most {MAX_THREADS} (0 = all cores), got {threads}"
        )));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .start_handler(|_| embree3::enable_ftz_and_daz())
        .build()
        .map_err(|e| RenderError::Settings(format!("cannot start {threads} threads: {e}")))
}

/// One of `count` disjoint parts of a render (`lfr render --shard I/N [--shard-by samples]`).
///
/// By tiles: tile t, counted row by row, belongs to shard t mod `count`, so every shard gets
/// tiles from the whole image (equal work on any scene) and the shards together cover it once.
/// A pixel's value depends only on the seed, the pixel and its sample indices, so the pixels of
/// a shard are bit for bit those of the whole render.
///
/// By samples: every shard covers every pixel with its own contiguous range of sample indices
/// ([`Shard::sample_range`]), the ranges together 0..spp once; each sample is the one the whole
/// render draws, so the merged means differ from one process's only by the order of the sums
/// (float rounding). For references: N machines each trace all pixels at spp/N.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
    pub by: ShardBy,
}

/// What a [`Shard`] splits: the image's tiles or each pixel's samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ShardBy {
    #[default]
    Tiles,
    Samples,
}

impl ShardBy {
    pub fn name(self) -> &'static str {
        match self {
            ShardBy::Tiles => "tiles",
            ShardBy::Samples => "samples",
        }
    }

    /// `tiles` or `samples`.
    pub fn parse(text: &str) -> Result<ShardBy, String> {
        [ShardBy::Tiles, ShardBy::Samples]
            .into_iter()
            .find(|by| by.name() == text)
            .ok_or_else(|| format!("expected `tiles` or `samples`, got `{text}`"))
    }
}

/// The most shards a render may be split into.
pub const MAX_SHARDS: u32 = 1 << 20;

impl Shard {
    /// The whole image.
    pub const WHOLE: Shard = Shard { index: 0, count: 1, by: ShardBy::Tiles };

    /// `I/N` with 0 ≤ I < N ≤ [`MAX_SHARDS`], by tiles (see [`Shard::by`] for samples).
    pub fn parse(text: &str) -> Result<Shard, String> {
        let (index, count) = text.split_once('/').ok_or_else(|| format!("expected I/N (e.g. 0/4), got `{text}`"))?;
        let number = |part: &str, what: &str| {
            part.trim().parse::<u32>().map_err(|_| format!("{what} `{part}` in `{text}` is not a whole number"))
        };
        let (index, count) = (number(index, "the shard index")?, number(count, "the shard count")?);
        if count == 0 || count > MAX_SHARDS {
            return Err(format!("the shard count must be in 1..={MAX_SHARDS}, got {count}"));
        }
        if index >= count {
            return Err(format!("the shard index must be in 0..{count} (counted from 0), got {index}"));
        }
        Ok(Shard { index, count, by: ShardBy::Tiles })
    }

    /// The same shard, splitting `by`.
    pub fn by(self, by: ShardBy) -> Shard {
        Shard { by, ..self }
    }

    /// Whether pixel (x, y) of an image `width` pixels wide belongs to this shard (every pixel
    /// does when splitting by samples).
    pub fn covers(self, width: u32, x: u32, y: u32) -> bool {
        if self.by == ShardBy::Samples {
            return true;
        }
        let tiles_across = width.div_ceil(TILE);
        let tile = (y / TILE) as u64 * tiles_across as u64 + (x / TILE) as u64;
        tile % self.count as u64 == self.index as u64
    }

    /// The sample indices this shard traces of each pixel of an `spp` render: all of them by
    /// tiles; by samples, shard i of n gets ⌊i·spp/n⌋..⌊(i+1)·spp/n⌋ (empty where n > spp).
    pub fn sample_range(self, spp: u32) -> std::ops::Range<u32> {
        match self.by {
            ShardBy::Tiles => 0..spp,
            ShardBy::Samples => {
                let at = |i: u32| (i as u64 * spp as u64 / self.count as u64) as u32;
                at(self.index)..at(self.index + 1)
            }
        }
    }
}

/// Renders the scene; the accelerator is built by the caller so it can be reused.
pub fn render(scene: &Scene, accel: &Accel, settings: &RenderSettings) -> Result<RenderedImage, RenderError> {
    render_shard(scene, accel, settings, Shard::WHOLE)
}

/// Renders only the tiles of `shard`; the other pixels stay zero.
pub fn render_shard(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    shard: Shard,
) -> Result<RenderedImage, RenderError> {
    render_shard_with_lights(scene, accel, settings, &LightSampler::new(scene), shard)
}

/// [`render`] with the light sampler `lights` (built for `scene`): the tests compare light
/// sampling strategies with it (`crate::lights::LightStrategy`).
pub fn render_with_lights(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    lights: &LightSampler,
) -> Result<RenderedImage, RenderError> {
    render_shard_with_lights(scene, accel, settings, lights, Shard::WHOLE)
}

/// [`render_shard`] with the light sampler `lights`.
pub fn render_shard_with_lights(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    lights: &LightSampler,
    shard: Shard,
) -> Result<RenderedImage, RenderError> {
    settings.validate()?;
    let (width, height) = (settings.width, settings.height);
    let samples = shard.sample_range(settings.spp);
    if shard.by == ShardBy::Samples && shard.count > settings.spp {
        return Err(RenderError::Settings(format!(
            "shard {}/{} by samples of a {}-spp render: use at most {} shards (one sample each)",
            shard.index, shard.count, settings.spp, settings.spp
        )));
    }
    crate::memory::check(&format!("a {width}x{height} render"), crate::memory::render_bytes(width, height))?;
    let integrator = Integrator::new(scene, accel, lights, settings.max_bounces, settings.width, settings.height);
    let tile_list: Vec<(u32, u32)> =
        tiles(settings).into_iter().filter(|&(x, y)| shard.covers(settings.width, x, y)).collect();
    let bar = crate::progress::StepProgress::begin(settings.progress, "render", tile_list.len() as u64, "tiles");
    let pool = thread_pool(settings.threads)?;
    let start = Instant::now();
    let results: Vec<TileResult> = pool.install(|| {
        tile_list
            .par_iter()
            .map(|&(x, y)| {
                let tile = render_tile(&integrator, settings, samples.clone(), x, y, &mut NoRecording);
                bar.advance(1);
                tile
            })
            .collect()
    });
    let seconds = start.elapsed().as_secs_f64();
    bar.finish();
    let mut frame = assemble(settings, samples.len() as u32, results, seconds);
    frame.dropped_contributions = integrator.dropped_contributions();
    Ok(frame)
}

/// The means of one pixel's samples, from [`render_pixels`]: the same values as the pixel's
/// `beauty`, `direct` and `indirect` in a [`render`] of the whole image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelMeans {
    pub beauty: Vec3,
    pub direct: Vec3,
    pub indirect: Vec3,
}

/// Renders only `pixels` (each inside the `settings.width` × `settings.height` image, any
/// order, repeats allowed) at `settings.spp`; bit-identical to those pixels of [`render`] with
/// the same settings, for any thread count. For estimating an image's error at a sparse set of
/// pixels with many more samples than the whole image could afford.
pub fn render_pixels(
    scene: &Scene,
    accel: &Accel,
    settings: &RenderSettings,
    pixels: &[(u32, u32)],
) -> Result<Vec<PixelMeans>, RenderError> {
    settings.validate()?;
    settings.check_inside(pixels)?;
    let lights = LightSampler::new(scene);
    let integrator = Integrator::new(scene, accel, &lights, settings.max_bounces, settings.width, settings.height);
    let group = (TILE * TILE) as usize;
    let bar = crate::progress::StepProgress::begin(settings.progress, "render pixels", pixels.len() as u64, "pixels");
    let pool = thread_pool(settings.threads)?;
    let groups: Vec<Vec<PixelMeans>> = pool.install(|| {
        pixels
            .par_chunks(group)
            .map(|chunk| {
                let (sums, _) = trace_pixels(&integrator, settings, 0..settings.spp, chunk, &mut NoRecording);
                bar.advance(chunk.len() as u64);
                sums.iter()
                    .map(|acc| PixelMeans {
                        beauty: acc.mean(settings.spp, acc.sum),
                        direct: acc.mean(settings.spp, acc.direct),
                        indirect: acc.mean(settings.spp, acc.indirect),
                    })
                    .collect()
            })
            .collect()
    });
    bar.finish();
    Ok(groups.into_iter().flatten().collect())
}

/// Traces the same paths as `render` and returns every ray, in a deterministic order (for
/// replaying them against raw Embree in the benchmark).
pub fn record_rays(scene: &Scene, accel: &Accel, settings: &RenderSettings) -> Result<Vec<RecordedRay>, RenderError> {
    settings.validate()?;
    let lights = LightSampler::new(scene);
    let integrator = Integrator::new(scene, accel, &lights, settings.max_bounces, settings.width, settings.height);
    let pool = thread_pool(settings.threads)?;
    let per_tile: Vec<Vec<RecordedRay>> = pool.install(|| {
        tiles(settings)
            .par_iter()
            .map(|&(x, y)| {
                let mut rays = Vec::new();
                render_tile(&integrator, settings, 0..settings.spp, x, y, &mut rays);
                rays
            })
            .collect()
    });
    Ok(per_tile.into_iter().flatten().collect())
}

/// The frame of `results`, each pixel the mean of its `spp` samples (those of its shard).
fn assemble(settings: &RenderSettings, spp: u32, results: Vec<TileResult>, seconds: f64) -> RenderedImage {
    let n = settings.width as usize * settings.height as usize;
    let mut frame = RenderedImage {
        width: settings.width,
        height: settings.height,
        spp,
        beauty: vec![Vec3::ZERO; n],
        direct: vec![Vec3::ZERO; n],
        indirect: vec![Vec3::ZERO; n],
        albedo: vec![Vec3::ZERO; n],
        normal: vec![Vec3::ZERO; n],
        position: vec![Vec3::ZERO; n],
        depth: vec![0.0; n],
        variance: vec![Vec3::ZERO; n],
        invalid_samples: 0,
        clamped_variances: 0,
        dropped_contributions: 0,
        rays: 0,
        seconds,
    };
    for tile in results {
        frame.rays += tile.rays;
        for (i, acc) in tile.pixels.iter().enumerate() {
            let x = tile.x0 + i as u32 % tile.width;
            let y = tile.y0 + i as u32 / tile.width;
            let p = (y * settings.width + x) as usize;
            frame.invalid_samples += acc.invalid as u64;
            let valid = (spp - acc.invalid) as f64;
            if valid > 0.0 {
                let mut mean = [0.0f32; 3];
                let mut variance = [0.0f32; 3];
                for c in 0..3 {
                    let m = acc.sum[c] / valid;
                    mean[c] = m as f32;
                    if valid > 1.0 {
                        let sample_variance = ((acc.sum_sq[c] - valid * m * m) / (valid - 1.0)).max(0.0);
                        let of_the_mean = sample_variance / valid;
                        if of_the_mean > f32::MAX as f64 {
                            frame.clamped_variances += 1;
                        }
                        variance[c] = of_the_mean.min(f32::MAX as f64) as f32;
                    }
                }
                frame.beauty[p] = Vec3::from(mean);
                frame.variance[p] = Vec3::from(variance);
                frame.direct[p] = acc.mean(spp, acc.direct);
                frame.indirect[p] = acc.mean(spp, acc.indirect);
            }
            if acc.hits > 0 {
                let h = acc.hits as f32;
                frame.albedo[p] = acc.albedo / h;
                frame.normal[p] = acc.normal.normalize_or_zero();
                frame.position[p] = acc.position / h;
                frame.depth[p] = (acc.depth / acc.hits as f64) as f32;
            }
        }
    }
    frame
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_shards_partition_every_pixels_samples() {
        for spp in 1..40u32 {
            for count in 1..=spp + 2 {
                let mut next = 0;
                for index in 0..count {
                    let range = Shard { index, count, by: ShardBy::Samples }.sample_range(spp);
                    assert_eq!(range.start, next, "spp {spp}, shard {index}/{count}");
                    assert!(count > spp || !range.is_empty(), "spp {spp}, shard {index}/{count} is empty");
                    next = range.end;
                }
                assert_eq!(next, spp, "spp {spp}, {count} shards");
                let tiles = Shard { index: count - 1, count, by: ShardBy::Tiles };
                assert_eq!(tiles.sample_range(spp), 0..spp);
            }
        }
        assert_eq!(ShardBy::parse("samples"), Ok(ShardBy::Samples));
        assert!(ShardBy::parse("pixels").unwrap_err().contains("`tiles` or `samples`"));
    }
}
