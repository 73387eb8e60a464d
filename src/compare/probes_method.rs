//! The tracer-side method `probes` of `lfr compare`: sparse radiance probes
//! (crate `probes`, docs/probes.md) for `--effect indirect`. The `recon` crate must not use
//! the tracer, so this method is not in `recon::registry`: the harness recognises its name here
//! and runs it once, after the registry's methods, on the comparison's scene.
//!
//! A run precomputes (or reads the precompute from `CACHE_DIR/probes/`, keyed by geometry and
//! settings as `lfr probes precompute` does), then relights one frame with the scene's own
//! lights, bounces to convergence, and renders the image from the receivers. `preprocess_s` is
//! the precompute's (and CPCA's) build time, also when read from the cache (its build time is
//! kept beside it; `precompute_from_cache` says which); `recon_s` is one relit frame to the
//! image (direct light at the senders, the bounces, the image), the median of `--repeats`
//! frames. The image's primary rays and lookups depend on the camera, not the light: they are
//! traced once per run (`probes::image_operator`, not cached on disk) and their time is added to
//! `preprocess_s` (stat `image_operator_s`); a frame's image is one weighted sum per pixel. The
//! first frame's split as the paper's Table 2 is in the stats and notes. The options are the ablations: `probes=N`, `order=0..7`, `cpca=on|off`,
//! `reconstruction=visibility|spatial` (Eq. 2 or the spatial-only Eq. 1), and the
//! precompute's sizes.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use probes::cache::CacheKey;
use probes::cpca::{CpcaSettings, Precision};
use probes::defaults;
use probes::image::ImageSettings;
use probes::memory::MemoryEstimate;
use probes::placement::PlacementSettings;
use probes::precompute::PrecomputeSettings;
use probes::surfels::SurfelSettings;
use probes::transport::{Reconstruction, TransportSettings};
use recon::Image;

/// The method's name on `--methods`.
pub const NAME: &str = "probes";

/// The most projected values (Σ CPCA ranks) for `bounces=projected`: its matrix is 12 R² bytes
/// and takes about R² × (probes × coefficients) operations to form.
pub const MAX_PROJECTED: usize = 4096;

/// One `probes[:key=value...]` of `--methods`.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbesMethod {
    /// As given (options in the order written): the run's `method`.
    pub name: String,
    pub precompute: PrecomputeSettings,
    pub cpca: Option<CpcaSettings>,
    /// Weight of missed relight rays in the probes' SH fit (1: the paper's projection).
    pub miss_weight: f64,
    pub light_samples: u32,
    pub pixel_samples: u32,
    /// The bounces stop when the largest change falls under this share of the largest
    /// irradiance (0: every bounce up to the comparison's max_bounces − 1).
    pub tolerance: f32,
    /// Keep the camera's lookups once (true, the default) or trace and look them up every frame
    /// (`image=lookups`: the frame as before, for A/B timings; the same image bit for bit).
    pub kept_lookups: bool,
    /// Run the bounces after the first in CPCA's projected space (`probes::projected_bounce`;
    /// the default with CPCA) or all through the relight rays and receivers (`bounces=full`).
    pub projected_bounces: bool,
    /// Drop hidden senders from the relight rays' hits beside valid ones (`hidden_senders=drop`;
    /// the default keeps the table as built: docs/probes.md, Sponza +0.6 dB, Cornell −0.14 dB).
    pub drop_hidden_senders: bool,
}

/// The options with their defaults, for `--list-methods` and errors.
pub const OPTIONS: &str = "probes=N (64), receivers=N (20000), overlap=X (10), order=0..7 (7), directions=M (512), \
relight_rays=R (8000), reconstruction=visibility|spatial (visibility: Eq. 2; spatial: Eq. 1), cpca=on|off (on), \
fp16=on|off (off), miss_weight=(0,1] (0.01; 1 = the paper's projection), light_samples=N (16), pixel_samples=N (16), \
tolerance=X (0.001: bounces stop when the largest change and the tail it predicts are under X of the largest irradiance; 0: all), \
image=kept|lookups (kept: the camera's lookups traced once, in preprocess_s; lookups: traced every frame), \
bounces=projected|full (projected: bounces after the first as R x R products in CPCA's projected space, its matrix \
formed once, in preprocess_s; needs cpca=on; full: every bounce through the relight rays), \
hidden_senders=keep|drop (keep; drop: relight hits read no hidden sender beside a valid one)";

fn on_off(key: &str, value: &str) -> Result<bool> {
    match value {
        "on" | "true" | "1" => Ok(true),
        "off" | "false" | "0" => Ok(false),
        _ => bail!("--methods: probes: {key} takes on or off, got `{value}`"),
    }
}

fn number<T: std::str::FromStr>(key: &str, value: &str) -> Result<T> {
    value.parse().map_err(|_| anyhow::anyhow!("--methods: probes: {key} takes a number, got `{value}`"))
}

impl ProbesMethod {
    /// `spec` parsed when it names this method (`probes` or `probes:...`), else `None`.
    pub fn parse(spec: &str, seed: u32) -> Result<Option<ProbesMethod>> {
        let spec = spec.trim();
        let (name, options) = spec.split_once(':').unwrap_or((spec, ""));
        if name != NAME {
            return Ok(None);
        }
        let mut precompute = PrecomputeSettings {
            surfels: SurfelSettings { seed, ..Default::default() },
            placement: PlacementSettings::default(),
            transport: TransportSettings { seed, ..Default::default() },
            relight_rays: defaults::RELIGHT_RAYS,
        };
        let mut cpca = defaults::CPCA;
        let mut fp16 = false;
        let mut method = ProbesMethod {
            name: spec.to_string(),
            precompute,
            cpca: None,
            miss_weight: defaults::MISS_WEIGHT,
            light_samples: defaults::LIGHT_SAMPLES,
            pixel_samples: defaults::PIXEL_SAMPLES,
            tolerance: defaults::BOUNCE_TOLERANCE,
            kept_lookups: true,
            projected_bounces: true,
            drop_hidden_senders: false,
        };
        for option in options.split(':').filter(|o| !o.is_empty()) {
            let Some((key, value)) = option.split_once('=') else {
                bail!("--methods: probes: option `{option}` is not key=value; options: {OPTIONS}");
            };
            match key {
                "probes" => precompute.placement.probes = number(key, value)?,
                "receivers" => precompute.surfels.budget = number(key, value)?,
                "overlap" => precompute.placement.overlap = number(key, value)?,
                "order" => precompute.transport.order = number(key, value)?,
                "directions" => precompute.transport.directions = number(key, value)?,
                "relight_rays" => precompute.relight_rays = number(key, value)?,
                "reconstruction" => {
                    precompute.transport.reconstruction = match value {
                        "visibility" => Reconstruction::VisibilityAware,
                        "spatial" => Reconstruction::SpatialOnly,
                        _ => bail!("--methods: probes: reconstruction takes visibility or spatial, got `{value}`"),
                    }
                }
                "cpca" => cpca = on_off(key, value)?,
                "fp16" => fp16 = on_off(key, value)?,
                "miss_weight" => method.miss_weight = number(key, value)?,
                "light_samples" => method.light_samples = number(key, value)?,
                "pixel_samples" => method.pixel_samples = number(key, value)?,
                "tolerance" => method.tolerance = number(key, value)?,
                "bounces" => {
                    method.projected_bounces = match value {
                        "projected" => true,
                        "full" => false,
                        _ => bail!("--methods: probes: bounces takes projected or full, got `{value}`"),
                    }
                }
                "hidden_senders" => {
                    method.drop_hidden_senders = match value {
                        "drop" => true,
                        "keep" => false,
                        _ => bail!("--methods: probes: hidden_senders takes drop or keep, got `{value}`"),
                    }
                }
                "image" => {
                    method.kept_lookups = match value {
                        "kept" => true,
                        "lookups" => false,
                        _ => bail!("--methods: probes: image takes kept or lookups, got `{value}`"),
                    }
                }
                _ => bail!("--methods: probes: unknown option `{key}`; options: {OPTIONS}"),
            }
        }
        precompute.validate().map_err(|e| anyhow::anyhow!("--methods: probes: {e}"))?;
        if !(method.miss_weight > 0.0 && method.miss_weight <= 1.0) {
            bail!("--methods: probes: miss_weight must be in (0, 1], got {}", method.miss_weight);
        }
        if method.light_samples == 0 || method.light_samples > probes::direct::MAX_SAMPLES {
            bail!(
                "--methods: probes: light_samples must be between 1 and {}, got {}",
                probes::direct::MAX_SAMPLES,
                method.light_samples
            );
        }
        if method.pixel_samples == 0 || method.pixel_samples > probes::image::MAX_PIXEL_SAMPLES {
            bail!(
                "--methods: probes: pixel_samples must be between 1 and {}, got {}",
                probes::image::MAX_PIXEL_SAMPLES,
                method.pixel_samples
            );
        }
        if !(method.tolerance >= 0.0 && method.tolerance < 1.0) {
            bail!("--methods: probes: tolerance must be in [0, 1), got {}", method.tolerance);
        }
        if !cpca {
            // The dense transport has no projected space.
            method.projected_bounces = false;
        }
        if fp16 && !cpca {
            bail!("--methods: probes: fp16 stores the CPCA-compressed transport; it needs cpca=on");
        }
        method.precompute = precompute;
        method.cpca = cpca.then_some(CpcaSettings {
            precision: if fp16 { Precision::F16 } else { Precision::F32 },
            ..Default::default()
        });
        if let Some(c) = &method.cpca {
            c.validate().map_err(|e| anyhow::anyhow!("--methods: probes: {e}"))?;
        }
        Ok(Some(method))
    }
}

/// What one run gives the harness.
pub struct ProbesRun {
    pub image: Image,
    pub preprocess_s: f64,
    pub precompute_from_cache: bool,
    /// The median frame's seconds, and every frame's.
    pub recon_s: f64,
    pub timings: Vec<f64>,
    pub stats: recon::method::Stats,
    pub notes: Vec<String>,
}

/// The precompute's cache file in the comparison's cache folder, named by its key.
pub fn cache_path(cache_dir: &Path, key: &CacheKey) -> PathBuf {
    // Eight bytes of each digest: other settings of the same scene get other files.
    let hex: String =
        key.geometry.iter().take(8).chain(key.settings.iter().take(8)).map(|b| format!("{b:02x}")).collect();
    cache_dir.join("probes").join(format!("{hex}.lfrprobe"))
}

/// The build seconds kept beside a cache file (`FILE.seconds`): written when it is built,
/// read back when it is reused.
fn seconds_path(file: &Path) -> PathBuf {
    let mut name = file.as_os_str().to_os_string();
    name.push(".seconds");
    PathBuf::from(name)
}

fn read_seconds(file: &Path) -> Option<f64> {
    std::fs::read_to_string(seconds_path(file)).ok()?.trim().parse().ok().filter(|s: &f64| s.is_finite() && *s >= 0.0)
}

fn write_seconds(file: &Path, seconds: f64) -> Result<()> {
    let path = seconds_path(file);
    std::fs::write(&path, format!("{seconds}\n")).with_context(|| format!("writing {}", path.display()))
}

/// What `run` holds at its peak for `method` at `width` x `height` on `threads` workers: a
/// relit frame's estimate (`crate::probes::frame_estimate`: the precompute or its cache read,
/// CPCA and the projected bounce when the method uses them, the image with its lookups).
pub fn memory_estimate(method: &ProbesMethod, (width, height): (u32, u32), threads: usize) -> MemoryEstimate {
    let image = ImageSettings { width, height, light_samples: 0, pixel_samples: method.pixel_samples, seed: 0 };
    crate::probes::frame_estimate(&method.precompute, method.cpca.as_ref(), method.projected_bounces, &image, threads)
}

/// Runs `method` on `scene` (set up for `--effect indirect`): the precompute from the cache or
/// built, then `frames` relit frames (the first one's image; the frames' times).
#[allow(clippy::too_many_arguments)]
pub fn run(
    method: &ProbesMethod,
    scene: &tracer::Scene,
    accel: &tracer::Accel,
    (width, height): (u32, u32),
    max_bounces: u32,
    seed: u32,
    threads: usize,
    cache_dir: &Path,
    frames: u32,
    bar: &indicatif::ProgressBar,
) -> Result<ProbesRun> {
    // The senders' direct light takes `light_samples`; the image's pixels none (the indirect
    // layer alone is scored).
    let image_settings = ImageSettings { width, height, light_samples: 0, pixel_samples: method.pixel_samples, seed };
    image_settings.validate()?;
    let pool = tracer::render::thread_pool(threads)?;
    let key = CacheKey::of(scene, &method.precompute);
    let file = cache_path(cache_dir, &key);
    if let Some(parent) = file.parent() {
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    let mut notes = Vec::new();
    let (mut pre, from_cache, seconds) =
        crate::probes::obtain(scene, &method.precompute, &file, crate::probes::Stale::Replace, &pool, bar)?;
    let mut preprocess_s = if from_cache {
        read_seconds(&file).unwrap_or_else(|| {
            notes.push(format!(
                "the precompute's build time was not kept beside {}: preprocess_s is its read time",
                file.display()
            ));
            seconds
        })
    } else {
        write_seconds(&file, seconds)?;
        seconds
    };
    let mut stats = recon::method::Stats::new();
    stats.insert("precompute_s".into(), preprocess_s);
    stats.insert("precompute_read_s".into(), if from_cache { seconds } else { 0.0 });
    stats.insert("receivers".into(), pre.surfels.surfels.len() as f64);
    stats.insert("hidden_receivers".into(), pre.hidden as f64);
    stats.insert("probes".into(), pre.probes.len() as f64);
    stats.insert(
        "dense_bytes_per_receiver".into(),
        pre.dense_transport_bytes() as f64 / pre.surfels.surfels.len().max(1) as f64,
    );
    if method.drop_hidden_senders {
        let dropped = pre.drop_hidden_senders()?;
        stats.insert("hidden_sender_reads_dropped".into(), dropped as f64);
    }
    if method.miss_weight < 1.0 {
        let t = Instant::now();
        pool.install(|| pre.table.fit(method.miss_weight))?;
        stats.insert("relight_fit_s".into(), t.elapsed().as_secs_f64());
    }
    bar.set_message(format!("{}: compressing the transport", method.name));
    let (op, cpca) = crate::probes::operator(&pre, method.cpca, &pool, &file, &key)?;
    if let Some(c) = &cpca {
        let cpca_file = crate::probes::cpca_path(&file);
        let compress_s = if c.from_cache {
            read_seconds(&cpca_file).unwrap_or(c.compress_s)
        } else {
            write_seconds(&cpca_file, c.compress_s)?;
            c.compress_s
        };
        preprocess_s += compress_s;
        stats.insert("cpca_s".into(), compress_s);
        stats.insert("cpca_clusters".into(), c.clusters as f64);
        stats.insert("cpca_coefficients".into(), c.mean_coefficients);
        stats.insert("cpca_bytes_per_receiver".into(), c.bytes_per_receiver);
    }
    // The camera is fixed for the comparison: its primary rays and lookups are traced once and
    // kept (a per-camera cost like the precompute's, so it goes to preprocess_s, not to the
    // frame); every frame's image is then one weighted sum per pixel.
    let (camera, image_operator_s) = if method.kept_lookups {
        bar.set_message(format!("{}: tracing the camera's lookups", method.name));
        let (camera, seconds) = crate::probes::image_operator(scene, accel, &pre, &image_settings, &pool)?;
        preprocess_s += seconds;
        stats.insert("image_operator_s".into(), seconds);
        stats.insert("image_operator_bytes".into(), camera.bytes() as f64);
        stats.insert("image_operator_weights_per_hit".into(), camera.mean_weights_per_hit());
        (Some(camera), seconds)
    } else {
        (None, 0.0)
    };
    // The bounces' matrix in CPCA's projected space depends on the albedo, not the light: formed
    // once per run (not cached) and charged to preprocess_s like the camera's lookups.
    let projected = match (&op, method.projected_bounces) {
        (crate::probes::Operator::Cpca(c), true) => {
            let size: usize = c.clusters.iter().map(|c| c.rank).sum();
            if size > MAX_PROJECTED {
                notes.push(format!(
                    "bounces=projected: {size} projected values (over {MAX_PROJECTED}): the bounces run in full"
                ));
                None
            } else {
                bar.set_message(format!("{}: forming the projected bounce", method.name));
                let t = Instant::now();
                let albedo = pool.install(|| probes::frame::surfel_albedo(scene, &pre.surfels));
                let projected =
                    pool.install(|| probes::projected_bounce::ProjectedBounce::build(c, &pre.table, &albedo))?;
                let seconds = t.elapsed().as_secs_f64();
                preprocess_s += seconds;
                stats.insert("projected_bounce_s".into(), seconds);
                stats.insert("projected_size".into(), projected.size as f64);
                stats.insert("projected_bounce_bytes".into(), projected.bytes() as f64);
                Some(projected)
            }
        }
        _ => None,
    };
    let bounces = max_bounces.saturating_sub(1).max(1) as usize;
    let mut timings = Vec::new();
    let mut first: Option<(Vec<glam::Vec3>, crate::probes::FrameTimes, u64)> = None;
    for frame in 0..frames.max(1) {
        bar.set_message(format!("{}: relit frame {}", method.name, frame + 1));
        let (out, img, times) = crate::probes::relit_frame(
            scene,
            accel,
            &pre,
            &op,
            projected.as_ref(),
            None,
            bounces,
            method.tolerance,
            method.light_samples,
            &image_settings,
            camera.as_ref(),
            &pool,
        )?;
        timings.push(times.frame_s + times.image_s);
        // The indirect layer needs no direct light at the pixels: the image traces none.
        match &first {
            None => first = Some((img.indirect, times, out.clamped)),
            Some((indirect, _, _)) => {
                if *indirect != img.indirect {
                    notes
                        .push(format!("frame {} gave a different image from the first (not deterministic)", frame + 1));
                }
            }
        }
    }
    let (indirect, times, clamped) = first.expect("at least one frame");
    let mut sorted = timings.clone();
    sorted.sort_by(f64::total_cmp);
    let recon_s = sorted[(sorted.len() - 1) / 2];
    // The first frame's split, as the paper's Table 2 (scene relight = direct light at the
    // senders; the three bounce stages summed over the bounces).
    stats.insert("direct_s".into(), times.direct_s);
    stats.insert("bounces_s".into(), times.bounces_s);
    stats.insert("probe_relight_s".into(), times.probe_relight_s);
    stats.insert("cluster_projection_s".into(), times.cluster_projection_s);
    stats.insert("receiver_irradiance_s".into(), times.receiver_irradiance_s);
    stats.insert("projected_bounces_s".into(), times.projected_bounces_s);
    notes.push(format!(
        "frame split (first frame): scene relight {:.4} s, probe relight {:.4} s, cluster projection {:.4} s, receiver irradiance {:.4} s, projected bounces {:.4} s; {} bounces; image {:.4} s; the camera's lookups kept once in {:.4} s (in preprocess_s)",
        times.direct_s,
        times.probe_relight_s,
        times.cluster_projection_s,
        times.receiver_irradiance_s,
        times.projected_bounces_s,
        times.iterations,
        times.image_s,
        image_operator_s
    ));
    stats.insert("bounce_iterations".into(), times.iterations as f64);
    stats.insert("image_s".into(), times.image_s);
    stats.insert("clamped_channels".into(), clamped as f64);
    let image = Image::from_pixels(width, height, indirect.iter().map(|v| v.to_array()).collect());
    Ok(ProbesRun { image, preprocess_s, precompute_from_cache: from_cache, recon_s, timings, stats, notes })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn other_settings_of_the_same_geometry_get_other_cache_files() {
        let dir = Path::new("cache");
        let a = CacheKey { geometry: [1; 32], settings: [2; 32] };
        let mut b = a;
        b.settings[0] = 3;
        let mut c = a;
        c.geometry[0] = 4;
        let paths = [cache_path(dir, &a), cache_path(dir, &b), cache_path(dir, &c)];
        assert!(paths[0] != paths[1] && paths[0] != paths[2] && paths[1] != paths[2], "{paths:?}");
        assert!(paths.iter().all(|p| p.starts_with("cache/probes")));
    }

    #[test]
    fn options_parse_into_the_settings_and_bad_ones_are_refused_by_name() {
        assert_eq!(ProbesMethod::parse("box", 1).unwrap(), None);
        assert_eq!(ProbesMethod::parse("probesx", 1).unwrap(), None);
        let m = ProbesMethod::parse("probes", 3).unwrap().unwrap();
        assert_eq!(m.precompute.placement.probes, 64);
        assert_eq!(m.precompute.transport.order, 7);
        assert_eq!(m.precompute.surfels.seed, 3);
        assert!(m.cpca.is_some());
        assert_eq!(m.pixel_samples, 16, "Cornell's edges need 16 rays per pixel (docs/probes.md)");
        let m = ProbesMethod::parse("probes:probes=29:order=2:cpca=off:reconstruction=spatial:miss_weight=1", 1)
            .unwrap()
            .unwrap();
        assert_eq!(m.name, "probes:probes=29:order=2:cpca=off:reconstruction=spatial:miss_weight=1");
        assert_eq!(m.precompute.placement.probes, 29);
        assert_eq!(m.precompute.transport.order, 2);
        assert_eq!(m.precompute.transport.reconstruction, Reconstruction::SpatialOnly);
        assert_eq!(m.cpca, None);
        assert_eq!(m.miss_weight, 1.0);
        assert!(!m.drop_hidden_senders && !m.projected_bounces, "the dense transport has no projected space");
        let m = ProbesMethod::parse("probes:hidden_senders=drop:bounces=full:image=lookups:tolerance=0.01", 1)
            .unwrap()
            .unwrap();
        assert!(m.drop_hidden_senders && !m.projected_bounces && !m.kept_lookups && m.tolerance == 0.01);
        for (bad, names) in [
            ("probes:order=8", "order"),
            ("probes:probes=0", "probes"),
            ("probes:cpca=maybe", "cpca"),
            ("probes:fp16=on:cpca=off", "fp16"),
            ("probes:miss_weight=0", "miss_weight"),
            ("probes:colour=red", "colour"),
            ("probes:reconstruction=magic", "reconstruction"),
            ("probes:order", "order"),
            ("probes:pixel_samples=0", "pixel_samples"),
            ("probes:tolerance=1", "tolerance"),
            ("probes:tolerance=-0.1", "tolerance"),
            ("probes:image=cached", "image"),
            ("probes:bounces=some", "bounces"),
            ("probes:hidden_senders=maybe", "hidden_senders"),
        ] {
            let error = ProbesMethod::parse(bad, 1).err().unwrap().to_string();
            assert!(error.contains(names), "{bad}: {error}");
        }
    }
}
