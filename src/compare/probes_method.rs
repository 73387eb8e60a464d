//! The tracer-side method `probes` of `lfr compare`: sparse radiance probes (crate `probes`,
//! docs/probes.md) for `--effect indirect`. The `recon` crate must not use the tracer, so this
//! method is declared in the harness's table of scene-level methods (`scene_methods`) with its
//! options as data ([`OPTIONS`], parsed by `recon::options` into the same errors as every other
//! method's), and runs after the registry's methods on the comparison's scene.
//!
//! A run goes through `probes::pipeline`, as `lfr probes relight` does: it precomputes (or reads
//! the precompute from `CACHE_DIR/probes/`, keyed by geometry and settings), relights one frame
//! with the scene's own lights, bounces to convergence, and renders the image from the
//! receivers. `preprocess_s` is the precompute's (and CPCA's) build time, also when read from
//! the cache (its build time is kept beside it; `precompute_from_cache` says which); `recon_s`
//! is one relit frame to the image (direct light at the senders, the bounces, the image), the
//! median of `--repeats` frames. The image's primary rays and lookups depend on the camera, not
//! the light: they are traced once per run (`probes::image_operator`, not cached on disk) and
//! their time is added to `preprocess_s` (stat `image_operator_s`); a frame's image is one
//! weighted sum per pixel. The first frame's split as the paper's Table 2 is in the stats and
//! notes.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use probes::cache::CacheKey;
use probes::cpca::{CpcaSettings, Precision};
use probes::defaults;
use probes::image::ImageSettings;
use probes::memory::MemoryEstimate;
use probes::pipeline::{
    frame_estimate, image_operator, obtain, operator, projected_bounce, relit_frame, Bounces, FrameSettings,
    FrameTimes, Obtained, Stale,
};
use probes::placement::PlacementSettings;
use probes::precompute::PrecomputeSettings;
use probes::surfels::{Sides, SurfelSettings};
use probes::transport::{Reconstruction, TransportSettings};
use recon::options::{OptionKind, OptionSpec, Options};
use recon::Image;

/// The method's name on `--methods`.
pub const NAME: &str = "probes";

const ON_OFF: OptionKind = OptionKind::Choice(&["on", "off"]);

/// `probes`' options as data, in the order its canonical name lists them. The defaults are
/// `probes::defaults` and `lfr probes relight`'s (test
/// `the_declared_defaults_are_the_methods_defaults`).
pub const OPTIONS: &[OptionSpec] = &[
    OptionSpec {
        key: "probes",
        kind: OptionKind::Count { min: 1, max: probes::placement::MAX_PROBES as u32 },
        default: "64",
        help: "number of probes",
    },
    OptionSpec {
        key: "receivers",
        kind: OptionKind::Count { min: 1, max: probes::surfels::MAX_RECEIVERS as u32 },
        default: "20000",
        help: "receiver budget (surfels; the count comes close to it)",
    },
    OptionSpec {
        key: "sides",
        kind: OptionKind::Choice(&["valid", "seeing", "all"]),
        default: "valid",
        help: "valid: receivers only on the sides that are not hidden, the budget spent on their area; seeing: nor on those whose test rays all escape; all: every side",
    },
    OptionSpec {
        key: "overlap",
        kind: OptionKind::Interval { min: 1.0, min_open: false, max: 1000.0, max_open: false },
        default: "10",
        help: "mean number of probes covering a receiver (sets the support radius)",
    },
    OptionSpec {
        key: "order",
        kind: OptionKind::Count { min: 0, max: probes::sh::MAX_ORDER as u32 },
        default: "7",
        help: "SH order of the probes",
    },
    OptionSpec {
        key: "directions",
        kind: OptionKind::Count { min: 1, max: probes::transport::MAX_DIRECTIONS },
        default: "512",
        help: "directions per receiver of the transport",
    },
    OptionSpec {
        key: "relight_rays",
        kind: OptionKind::Count { min: 1, max: probes::relight::MAX_RAYS },
        default: "8000",
        help: "relight rays per probe (at least 4 per SH coefficient)",
    },
    OptionSpec {
        key: "reconstruction",
        kind: OptionKind::Choice(&["visibility", "spatial"]),
        default: "visibility",
        help: "visibility: Eq. 2; spatial: the spatial-only Eq. 1",
    },
    OptionSpec { key: "cpca", kind: ON_OFF, default: "on", help: "compress the transport with CPCA (Eq. 11)" },
    OptionSpec { key: "fp16", kind: ON_OFF, default: "on", help: "store the CPCA-compressed transport in fp16 (with cpca=on)" },
    OptionSpec {
        key: "miss_weight",
        kind: OptionKind::Interval { min: 0.0, min_open: true, max: 1.0, max_open: false },
        default: "0.01",
        help: "weight of missed relight rays in the probes' SH fit (1: the paper's projection)",
    },
    OptionSpec {
        key: "light_samples",
        kind: OptionKind::Count { min: 1, max: probes::direct::MAX_SAMPLES },
        default: "16",
        help: "shadow rays per sender for the direct light",
    },
    OptionSpec {
        key: "pixel_samples",
        kind: OptionKind::Count { min: 1, max: probes::image::MAX_PIXEL_SAMPLES },
        default: "16",
        help: "primary rays per pixel (--recon-rays sets it when the spec does not)",
    },
    OptionSpec {
        key: "tolerance",
        kind: OptionKind::Interval { min: 0.0, min_open: false, max: 1.0, max_open: true },
        default: "0.001",
        help: "bounces stop when the largest change and the tail it predicts are under this share of the largest \
               irradiance (0: all)",
    },
    OptionSpec {
        key: "image",
        kind: OptionKind::Choice(&["kept", "lookups"]),
        default: "kept",
        help: "kept: the camera's lookups traced once, in preprocess_s; lookups: traced every frame (the same image)",
    },
    OptionSpec {
        key: "bounces",
        kind: OptionKind::Choice(&["projected", "full"]),
        default: "projected",
        help: "projected: bounces after the first as R x R products in CPCA's projected space (needs cpca=on); full: \
               every bounce through the relight rays",
    },
    OptionSpec {
        key: "near_field",
        kind: ON_OFF,
        default: "on",
        help: "gather the hits nearer than near_radius from their senders directly, the rest through the probes",
    },
    OptionSpec {
        key: "near_radius",
        kind: OptionKind::Interval { min: 0.0, min_open: true, max: 4.0, max_open: false },
        default: "0.25",
        help: "the near field's radius, a share of the probes' support radius (needs near_field=on)",
    },
    OptionSpec {
        key: "hidden_senders",
        kind: OptionKind::Choice(&["drop", "keep"]),
        default: "drop",
        help: "drop: relight hits read no hidden sender beside a valid one",
    },
];

/// The method's one line for `--list-methods` and reports.
pub const DESCRIPTION: &str =
    "sparse radiance probes (Silvennoinen and Lehtinen 2017), precomputed on the scene and relit per frame by the harness";

/// One `probes[:key=value...]` of `--methods`.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbesMethod {
    /// Its canonical name (the options given, in [`OPTIONS`]' order): the run's `method`.
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
    /// Drop hidden senders from the relight rays' hits beside valid ones (`hidden_senders=drop`,
    /// the default; `keep` keeps the table as built: docs/probes.md).
    pub drop_hidden_senders: bool,
}

impl ProbesMethod {
    /// `spec` parsed when it names this method (`probes` or `probes:...`), else `None`. Errors
    /// are `recon::Error::Option`'s: "`SPEC`: what is wrong".
    pub fn parse(spec: &str, seed: u32) -> Result<Option<ProbesMethod>> {
        let spec = spec.trim();
        let (name, text) = spec.split_once(':').unwrap_or((spec, ""));
        if name != NAME {
            return Ok(None);
        }
        let known_elsewhere =
            |key: &str| recon::registry::METHODS.iter().any(|m| m.options.iter().any(|o| o.key == key));
        let options = Options::parse(NAME, text, OPTIONS, known_elsewhere)?;
        let canonical = if options.is_empty() { NAME.to_string() } else { format!("{NAME}:{}", options.canonical()) };
        let bad = |message: String| recon::Error::Option { spec: canonical.clone(), message };
        let count = |key: &str, default: usize| options.count(key).map_or(default, |n| n as usize);
        let word = |key: &str, default: &'static str| options.choice(key).unwrap_or(default);
        // The number as written (an f32's shortest decimal), not the f32 widened: `0.01` is 0.01.
        let real = |key: &str, default: f64| {
            options.real(key).map_or(default, |x| x.to_string().parse().unwrap_or(f64::from(x)))
        };
        let spatial = word("reconstruction", "visibility") == "spatial";
        let precompute = PrecomputeSettings {
            surfels: SurfelSettings {
                seed,
                budget: count("receivers", defaults::RECEIVERS),
                sides: match word("sides", "valid") {
                    "all" => Sides::All,
                    "seeing" => Sides::Seeing,
                    _ => Sides::Valid,
                },
                ..Default::default()
            },
            placement: PlacementSettings {
                probes: count("probes", defaults::PROBES),
                overlap: real("overlap", defaults::OVERLAP),
                ..Default::default()
            },
            transport: TransportSettings {
                seed,
                order: count("order", defaults::ORDER),
                directions: options.count("directions").unwrap_or(defaults::DIRECTIONS),
                reconstruction: if spatial { Reconstruction::SpatialOnly } else { Reconstruction::VisibilityAware },
                // The spatial-only baseline traces no hits: no near field unless asked (then refused).
                near: (word("near_field", if defaults::NEAR_FIELD && !spatial { "on" } else { "off" }) == "on")
                    .then(|| real("near_radius", defaults::NEAR_RADIUS)),
            },
            relight_rays: options.count("relight_rays").unwrap_or(defaults::RELIGHT_RAYS),
        };
        precompute.validate().map_err(|e| bad(e.to_string()))?;
        let cpca = word("cpca", if defaults::CPCA { "on" } else { "off" }) == "on";
        // fp16 by default where there is a CPCA transport to store; asked for without one, refused.
        let fp16 = word("fp16", if defaults::FP16 && cpca { "on" } else { "off" }) == "on";
        if fp16 && !cpca {
            return Err(bad("fp16 stores the CPCA-compressed transport; it needs cpca=on".into()).into());
        }
        let cpca = cpca.then_some(CpcaSettings {
            precision: if fp16 { Precision::F16 } else { Precision::F32 },
            ..Default::default()
        });
        if let Some(c) = &cpca {
            c.validate().map_err(|e| bad(e.to_string()))?;
        }
        Ok(Some(ProbesMethod {
            precompute,
            // The dense transport has no projected space.
            projected_bounces: cpca.is_some() && word("bounces", "projected") == "projected",
            cpca,
            miss_weight: real("miss_weight", defaults::MISS_WEIGHT),
            light_samples: options.count("light_samples").unwrap_or(defaults::LIGHT_SAMPLES),
            pixel_samples: options.count("pixel_samples").unwrap_or(defaults::PIXEL_SAMPLES),
            tolerance: options.real("tolerance").unwrap_or(defaults::BOUNCE_TOLERANCE),
            kept_lookups: word("image", "kept") == "kept",
            drop_hidden_senders: word("hidden_senders", if defaults::DROP_HIDDEN_SENDERS { "drop" } else { "keep" })
                == "drop",
            name: canonical,
        }))
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
/// relit frame's estimate (`probes::pipeline::frame_estimate`: the precompute or its cache read,
/// CPCA and the projected bounce when the method uses them, the image with its lookups).
pub fn memory_estimate(method: &ProbesMethod, (width, height): (u32, u32), threads: usize) -> MemoryEstimate {
    let image = ImageSettings { width, height, light_samples: 0, pixel_samples: method.pixel_samples, seed: 0 };
    frame_estimate(&method.precompute, method.cpca.as_ref(), method.projected_bounces, &image, threads)
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
    let step = |name: &str| bar.set_message(format!("{}: {name}", method.name));
    let mut note = |text: String| bar.suspend(|| eprintln!("note: {text}"));
    let Obtained { precompute: mut pre, from_cache, seconds } =
        obtain(scene, &method.precompute, &file, Stale::Replace, &pool, &step, &mut note)
            .with_context(|| format!("precompute on {}", scene.source.display()))?;
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
    stats.insert("hidden_sides_dropped".into(), pre.surfels.stats.dropped as f64);
    stats.insert("receiver_cell".into(), pre.surfels.h);
    stats.insert("probes".into(), pre.probes.len() as f64);
    stats.insert(
        "dense_bytes_per_receiver".into(),
        pre.dense_transport_bytes() as f64 / pre.surfels.surfels.len().max(1) as f64,
    );
    if let Some(near) = &pre.near {
        stats.insert("near_field_hits".into(), near.hits as f64);
        stats.insert(
            "near_field_bytes_per_receiver".into(),
            pre.near_field_bytes() as f64 / pre.surfels.surfels.len().max(1) as f64,
        );
    }
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
    let (op, cpca) = operator(&pre, method.cpca, &pool, &file, &key, &mut note)?;
    if let Some(c) = &cpca {
        let cpca_file = probes::pipeline::cpca_path(&file);
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
        // What a frame reads per receiver: the compressed far field and the near field's list.
        stats.insert(
            "transport_bytes_per_receiver".into(),
            c.bytes_per_receiver + pre.near_field_bytes() as f64 / pre.surfels.surfels.len().max(1) as f64,
        );
    }
    // The camera is fixed for the comparison: its primary rays and lookups are traced once and
    // kept (a per-camera cost like the precompute's, so it goes to preprocess_s, not to the
    // frame); every frame's image is then one weighted sum per pixel.
    let (camera, image_operator_s) = if method.kept_lookups {
        bar.set_message(format!("{}: tracing the camera's lookups", method.name));
        let (camera, seconds) = image_operator(scene, accel, &pre, &image_settings, &pool)?;
        preprocess_s += seconds;
        stats.insert("image_operator_s".into(), seconds);
        stats.insert("image_operator_bytes".into(), camera.bytes() as f64);
        stats.insert("image_operator_weights_per_hit".into(), camera.mean_weights_per_hit());
        (Some(camera), seconds)
    } else {
        (None, 0.0)
    };
    let specular = probes::image::specular_share(scene, accel, width, height);
    stats.insert("specular_share".into(), specular);
    if let Some(text) = probes::pipeline::specular_warning(specular) {
        notes.push(recon::method::warning(text));
    }
    // The bounces' matrix in CPCA's projected space depends on the albedo, not the light: formed
    // once per run (not cached) and charged to preprocess_s like the camera's lookups.
    let projected = if method.projected_bounces {
        bar.set_message(format!("{}: forming the projected bounce", method.name));
        let mut note = |text: String| notes.push(format!("bounces=projected: {text}"));
        let projected = projected_bounce(&op, scene, &pre, &pool, &mut note)?;
        if let Some((_, report)) = &projected {
            preprocess_s += report.build_s;
            stats.insert("projected_bounce_s".into(), report.build_s);
            stats.insert("projected_size".into(), report.size as f64);
            stats.insert("projected_bounce_bytes".into(), report.bytes as f64);
        }
        projected
    } else {
        None
    };
    let bounces = probes::pipeline::indirect_bounces(max_bounces);
    let mut timings = Vec::new();
    let mut first: Option<(Vec<glam::Vec3>, FrameTimes, u64)> = None;
    let frame_settings =
        FrameSettings { bounces, start: None, tolerance: method.tolerance, light_samples: method.light_samples };
    for frame in 0..frames.max(1) {
        bar.set_message(format!("{}: relit frame {}", method.name, frame + 1));
        let (out, img, times) = relit_frame(
            scene,
            accel,
            &pre,
            &Bounces::of(&op, projected.as_ref().map(|(p, _)| p)),
            &frame_settings,
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
    stats.insert("near_field_s".into(), times.near_field_s);
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
        assert_eq!(m.cpca.map(|c| c.precision), Some(Precision::F16), "fp16 by default (docs/probes.md)");
        let f32 = ProbesMethod::parse("probes:fp16=off", 3).unwrap().unwrap();
        assert_eq!(f32.cpca.map(|c| c.precision), Some(Precision::F32));
        assert_eq!(ProbesMethod::parse("probes:cpca=off", 3).unwrap().unwrap().cpca, None, "no fp16 without CPCA");
        assert_eq!(m.pixel_samples, 16, "Cornell's edges need 16 rays per pixel (docs/probes.md)");
        let m = ProbesMethod::parse("probes:miss_weight=1:probes=29:cpca=off:order=2:reconstruction=spatial", 1)
            .unwrap()
            .unwrap();
        assert_eq!(m.name, "probes:probes=29:order=2:reconstruction=spatial:cpca=off:miss_weight=1", "canonical order");
        assert_eq!(ProbesMethod::parse(&m.name, 1).unwrap().unwrap(), m, "the canonical name parses back");
        assert_eq!(m.precompute.placement.probes, 29);
        assert_eq!(m.precompute.transport.order, 2);
        assert_eq!(m.precompute.transport.reconstruction, Reconstruction::SpatialOnly);
        assert_eq!(m.precompute.transport.near, None, "the spatial-only baseline has no near field by default");
        assert!(ProbesMethod::parse("probes:reconstruction=spatial:near_field=on", 1).is_err());
        assert_eq!(m.cpca, None);
        assert_eq!(m.miss_weight, 1.0);
        assert!(m.drop_hidden_senders && !m.projected_bounces, "the dense transport has no projected space");
        let m = ProbesMethod::parse("probes:hidden_senders=keep:bounces=full:image=lookups:tolerance=0.01", 1)
            .unwrap()
            .unwrap();
        assert!(!m.drop_hidden_senders && !m.projected_bounces && !m.kept_lookups && m.tolerance == 0.01);
        assert_eq!(ProbesMethod::parse("probes:tolerance=0", 1).unwrap().unwrap().tolerance, 0.0, "0: every bounce");
        // Every error in recon's one format: "`SPEC`: what is wrong", naming the option.
        for (bad, names) in [
            ("probes:order=8", "`probes:order=8`"),
            ("probes:probes=0", "`probes:probes=0`"),
            ("probes:cpca=maybe", "cpca must be one of on, off"),
            ("probes:fp16=on:cpca=off", "fp16"),
            ("probes:miss_weight=0", "miss_weight must be a number in (0, 1]"),
            ("probes:colour=red", "unknown option `colour`"),
            ("probes:radius=8", "radius does not apply to probes"),
            ("probes:reconstruction=magic", "reconstruction"),
            ("probes:order", "`order` is not key=value"),
            ("probes:pixel_samples=0", "pixel_samples"),
            ("probes:tolerance=1", "tolerance must be a number in [0, 1)"),
            ("probes:tolerance=-0.1", "tolerance"),
            ("probes:image=cached", "image"),
            ("probes:bounces=some", "bounces"),
            ("probes:hidden_senders=maybe", "hidden_senders"),
            ("probes:relight_rays=16", "relight_rays"),
            ("probes:order=2:order=3", "given twice"),
        ] {
            let error = ProbesMethod::parse(bad, 1).err().unwrap().to_string();
            assert!(error.contains(names), "{bad}: {error}");
        }
    }

    /// The defaults written in [`OPTIONS`] (what `--list-methods` shows) are the ones the
    /// method runs with: every option given at its declared default builds the same method
    /// as none.
    #[test]
    fn the_declared_defaults_are_the_methods_defaults() {
        let plain = ProbesMethod::parse(NAME, 5).unwrap().unwrap();
        let every: Vec<String> = OPTIONS.iter().map(|o| format!("{}={}", o.key, o.default)).collect();
        let spelled = ProbesMethod::parse(&format!("{NAME}:{}", every.join(":")), 5).unwrap().unwrap();
        assert_eq!(ProbesMethod { name: plain.name.clone(), ..spelled }, plain);
        for option in OPTIONS {
            let one = ProbesMethod::parse(&format!("{NAME}:{}={}", option.key, option.default), 5).unwrap().unwrap();
            assert_eq!(ProbesMethod { name: plain.name.clone(), ..one }, plain, "{}", option.key);
        }
    }
}
