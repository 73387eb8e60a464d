//! What the subcommands share: the embedded default scene and how a scene is loaded, the
//! scene-and-tracing options every tracing subcommand flattens into its own, and JSON output.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use tracer::limits::MAX_THREADS;
use tracer::scene::input::FileAccess;
use tracer::{RenderSettings, Scene};

/// The embedded default scene (scenes/cornell.toml).
pub const DEFAULT_SCENE: &str = include_str!("../scenes/cornell.toml");
pub const DEFAULT_SCENE_NAME: &str = "<embedded>/cornell.toml";

/// What every command that computes shares: the seed of its random numbers and its worker
/// threads. Flattened into `TraceArgs`, the benchmarks' `SceneListArgs` and `reconstruct`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct RunArgs {
    /// Seed of every random number, the reconstructions' too (default 0; `compare`,
    /// `lfr-bench filters` and `lfr-bench ilfr` 1).
    #[arg(long)]
    pub seed: Option<u32>,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
}

impl RunArgs {
    /// The seed, `default` unless given.
    pub fn seed_or(&self, default: u32) -> u32 {
        self.seed.unwrap_or(default)
    }

    /// The number of worker threads this asks for, 0 resolved to all cores, validated against
    /// `tracer::limits::MAX_THREADS`.
    pub fn thread_count(&self) -> Result<usize> {
        if self.threads > MAX_THREADS {
            anyhow::bail!("--threads must be at most {MAX_THREADS} (0 = all cores), got {}", self.threads);
        }
        Ok(match self.threads {
            0 => std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
            n => n,
        })
    }

    /// A plain rayon pool of these threads for the reconstructions (the tracer's own pools
    /// also set FTZ/DAZ: `tracer::render::thread_pool`).
    pub fn worker_pool(&self) -> Result<rayon::ThreadPool> {
        let threads = self.thread_count()?;
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("starting the worker threads")
    }
}

/// The scene and how to trace it: what `render`, `dump`, `filter`, `compare` and
/// `lfr-bench filters` take.
#[derive(clap::Args, Clone, Debug)]
pub struct TraceArgs {
    /// Scene file (.toml, .gltf, .glb, .obj, .ply); the embedded Cornell box when omitted.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    #[command(flatten)]
    pub size: SizeArgs,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub lighting: LightingArgs,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
    /// Let the scene's file references (meshes, textures, material libraries, glTF buffers and
    /// images) name files outside the referencing file's folder and the shared scenes folder.
    #[arg(long)]
    pub allow_outside_scene_dir: bool,
}

/// Lighting and camera choices on top of any scene file (docs/scene-format.md, "Default
/// lighting"). Flattened into `TraceArgs`: `render`, `dump`, `filter`, `compare` and
/// `lfr-bench filters`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct LightingArgs {
    /// Constant environment radiance, one value (grey) or R,G,B; replaces the scene's. With
    /// --environment or --sun the default lighting of a scene without lights is not added.
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "V|R,G,B", allow_negative_numbers = true)]
    pub environment: Option<Vec<f32>>,
    /// Adds a sun (directional light) shining from X,Y,Z: the direction from the scene towards
    /// the sun, any length.
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "X,Y,Z", allow_negative_numbers = true)]
    pub sun: Option<Vec<f32>>,
    /// The sun's irradiance on a surface facing it, one value or R,G,B (default 2.5; needs --sun).
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "V|R,G,B", allow_negative_numbers = true)]
    pub sun_irradiance: Option<Vec<f32>>,
    /// Use the file's camera N (0-based, glTF perspective cameras in file order) instead of the
    /// first.
    #[arg(long, value_name = "N")]
    pub camera: Option<usize>,
}

/// A colour option's value: one number (grey) or three, finite and non-negative.
fn colour_option(name: &str, values: &[f32]) -> Result<glam::Vec3> {
    let colour = match values {
        [v] => glam::Vec3::splat(*v),
        [r, g, b] => glam::Vec3::new(*r, *g, *b),
        _ => anyhow::bail!("{name} takes one value or three (R,G,B), got {}", values.len()),
    };
    if !colour.is_finite() || colour.min_element() < 0.0 {
        anyhow::bail!("{name} must be finite and non-negative, got {values:?}");
    }
    Ok(colour)
}

impl LightingArgs {
    /// Checks every value (before any work): colours of one or three finite, non-negative
    /// numbers, a sun direction of three finite numbers, not zero, and no --sun-irradiance
    /// without --sun. Returns (environment, sun direction and irradiance).
    #[allow(clippy::type_complexity)]
    pub fn validated(&self) -> Result<(Option<glam::Vec3>, Option<(glam::Vec3, glam::Vec3)>)> {
        let environment = self.environment.as_deref().map(|v| colour_option("--environment", v)).transpose()?;
        let irradiance = match &self.sun_irradiance {
            Some(v) => colour_option("--sun-irradiance", v)?,
            None => glam::Vec3::splat(tracer::scene::DEFAULT_SUN_IRRADIANCE),
        };
        let sun = match self.sun.as_deref() {
            None if self.sun_irradiance.is_some() => anyhow::bail!("--sun-irradiance needs --sun (the direction)"),
            None => None,
            Some([x, y, z]) => {
                let towards = glam::Vec3::new(*x, *y, *z);
                if !towards.is_finite() || towards.length_squared() == 0.0 || !towards.normalize().is_finite() {
                    anyhow::bail!("--sun must be a finite, non-zero direction, got {:?}", [x, y, z]);
                }
                Some((towards, irradiance))
            }
            Some(values) => anyhow::bail!("--sun takes a direction X,Y,Z, got {} values", values.len()),
        };
        Ok((environment, sun))
    }

    /// Applies these choices to a loaded `scene`: the camera, then the environment and sun;
    /// a scene still without any emitter gets the default lighting, with a notice on stderr.
    pub fn apply(&self, scene: &mut Scene) -> Result<()> {
        let (environment, sun) = self.validated()?;
        if let Some(index) = self.camera {
            scene
                .select_file_camera(index)
                .map_err(|why| anyhow::anyhow!("--camera {index}: {}: {why}", scene.source.display()))?;
            scene.camera.validate(&scene.source)?;
        }
        if let Some(environment) = environment {
            scene.environment = environment;
        }
        if let Some((towards, irradiance)) = sun {
            scene.add_sun(towards, irradiance);
        }
        if environment.is_none() && sun.is_none() {
            let emissive_only = scene.has_emitter();
            if scene.apply_default_lighting() {
                let what = if emissive_only {
                    "the model has no lights of its own besides emissive surfaces, which stay lit"
                } else {
                    "the scene has no lights"
                };
                eprintln!(
                    "notice: {}: {what}; using the default lighting (environment {}, a sun of irradiance {} from behind \
                     the camera's left shoulder; --environment and --sun choose others, --environment 0 keeps the \
                     file's own light only)",
                    scene.source.display(),
                    tracer::scene::DEFAULT_ENVIRONMENT,
                    tracer::scene::DEFAULT_SUN_IRRADIANCE
                );
            }
        }
        Ok(())
    }
}

/// The image size and path length, each the scene's unless given (or a command's own default:
/// the benchmarks). Shared by `TraceArgs` and `SceneListArgs`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SizeArgs {
    /// Image width (default: the scene's; `lfr-bench tracer` 256, `lfr-bench ilfr` 128, `lfr-bench filters` 1024).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the scene's; `lfr-bench tracer` 256, `lfr-bench ilfr` 128, `lfr-bench filters` 768).
    #[arg(long)]
    pub height: Option<u32>,
    /// Maximum number of bounces (default: the scene's).
    #[arg(long)]
    pub max_bounces: Option<u32>,
}

impl SizeArgs {
    /// These sizes with `width` and `height` where none was given.
    pub fn or(&self, width: u32, height: u32) -> SizeArgs {
        SizeArgs {
            width: Some(self.width.unwrap_or(width)),
            height: Some(self.height.unwrap_or(height)),
            ..self.clone()
        }
    }

    /// Settings for `scene` at `spp` (the scene's size and path length where not given),
    /// validated against `tracer::limits`.
    pub fn settings(
        &self,
        scene: &Scene,
        spp: u32,
        run: &RunArgs,
        seed: u32,
        progress: bool,
    ) -> Result<RenderSettings> {
        let settings = RenderSettings {
            width: self.width.unwrap_or(scene.width),
            height: self.height.unwrap_or(scene.height),
            spp,
            seed,
            max_bounces: self.max_bounces.unwrap_or(scene.max_bounces),
            threads: run.threads,
            progress,
        };
        settings.validate()?;
        Ok(settings)
    }
}

/// The benchmarks' scenes: several at one size (`lfr-bench tracer`, `lfr-bench ilfr`).
#[derive(clap::Args, Clone, Debug)]
pub struct SceneListArgs {
    /// Scene files, comma-separated; the embedded Cornell box and scenes/sponza.toml when
    /// omitted.
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<PathBuf>,
    #[command(flatten)]
    pub size: SizeArgs,
    #[command(flatten)]
    pub run: RunArgs,
    /// Let the scenes' file references name files outside the referencing file's folder and
    /// the shared scenes folder.
    #[arg(long)]
    pub allow_outside_scene_dir: bool,
}

impl SceneListArgs {
    /// Loads one of [`Self::scene_paths`], confined unless `--allow-outside-scene-dir`.
    pub fn load_scene(&self, path: Option<&Path>) -> Result<Scene> {
        load_scene(path, file_access(self.allow_outside_scene_dir), &LightingArgs::default())
    }

    /// The scenes to run, `None` standing for the embedded default.
    pub fn scene_paths(&self) -> Vec<Option<PathBuf>> {
        if self.scenes.is_empty() {
            vec![None, Some(PathBuf::from("scenes/sponza.toml"))]
        } else {
            self.scenes.iter().cloned().map(Some).collect()
        }
    }
}

/// The value parser of every `--repeats`: a count of timed runs, at least 1 (0 would time
/// nothing and report infinite or empty results).
pub fn repeats_parser() -> clap::builder::RangedI64ValueParser<u32> {
    clap::value_parser!(u32).range(1..)
}

/// The scene file access of `--allow-outside-scene-dir`.
pub fn file_access(allow_outside_scene_dir: bool) -> FileAccess {
    if allow_outside_scene_dir {
        FileAccess::Anywhere
    } else {
        FileAccess::Confined
    }
}

impl TraceArgs {
    /// Loads the scene (the embedded default without `--scene`), confined unless
    /// `--allow-outside-scene-dir`, with the lighting and camera options applied.
    pub fn load_scene(&self) -> Result<Scene> {
        // Bad lighting values are refused before the scene is read.
        self.lighting.validated()?;
        load_scene(self.scene.as_deref(), file_access(self.allow_outside_scene_dir), &self.lighting)
    }

    /// The seed, 0 unless given.
    pub fn seed(&self) -> u32 {
        self.run.seed_or(0)
    }

    /// Settings for `scene` at `spp` from these options (the scene's size and path length where
    /// not given), validated against `tracer::limits`.
    pub fn settings(&self, scene: &Scene, spp: u32) -> Result<RenderSettings> {
        self.size.settings(scene, spp, &self.run, self.seed(), !self.quiet)
    }
}

/// Writes `value` as pretty JSON to `path` through a temporary file (no half-written output);
/// the error names the file. The benchmarks' `--json`.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let json = serde_json::to_vec_pretty(value)?;
    tracer::output::write_atomically(path, |tmp| std::fs::write(tmp, &json).map_err(|e| e.to_string()))
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Loads a scene file, or the embedded default when `path` is `None`; file references inside
/// it are allowed as `access` says (`tracer::scene::input::FileAccess`); `lighting` is applied
/// (and a scene without lights gets the default lighting).
pub fn load_scene(path: Option<&Path>, access: FileAccess, lighting: &LightingArgs) -> Result<Scene> {
    let mut scene = match path {
        Some(p) => Scene::load_with_access(p, access)?,
        None => {
            let mut scene = tracer::scene::description::parse(DEFAULT_SCENE, Path::new(DEFAULT_SCENE_NAME))?;
            scene.validate()?;
            scene
        }
    };
    let source = format!("{}: ", scene.source.display());
    for warning in &scene.warnings {
        // A warning that names its own file (a mesh or material file, or the scene itself) keeps
        // its name; the others get the scene's.
        let prefix = if warning.starts_with(&source) { "" } else { &source };
        eprintln!("warning: {prefix}{warning}");
    }
    lighting.apply(&mut scene)?;
    Ok(scene)
}

/// Runs `work` (a reconstruction or a traced step) while a second thread adds its stage's
/// progress (`recon::progress`: units done and time left) to the bar's `message` five times a
/// second. When `work` returns, whether or not it ended its stage, the bar shows `message` alone
/// again.
pub fn with_stage_progress<T>(bar: &indicatif::ProgressBar, message: &str, work: impl FnOnce() -> T) -> T {
    with_expected_progress(bar, message, None, work)
}

/// [`with_stage_progress`] for a step that may report no stage of its own (an external
/// denoiser): while none runs, the bar shows the seconds so far and, when `expected_s` (the
/// time of a previous run of the same step) is known, about how many are left.
pub fn with_expected_progress<T>(
    bar: &indicatif::ProgressBar,
    message: &str,
    expected_s: Option<f64>,
    work: impl FnOnce() -> T,
) -> T {
    let current = std::sync::Mutex::new(message.to_string());
    with_changing_progress(bar, &current, expected_s, work)
}

/// [`with_expected_progress`] for a step that changes its own message as it goes (the probes'
/// precompute names each of its steps): the bar shows `message`'s current text with the stage.
pub fn with_changing_progress<T>(
    bar: &indicatif::ProgressBar,
    message: &std::sync::Mutex<String>,
    expected_s: Option<f64>,
    work: impl FnOnce() -> T,
) -> T {
    let text = || message.lock().unwrap_or_else(|e| e.into_inner()).clone();
    let finished = std::sync::atomic::AtomicBool::new(false);
    let start = std::time::Instant::now();
    let result = std::thread::scope(|scope| {
        let ticker = scope.spawn(|| {
            while !finished.load(std::sync::atomic::Ordering::Relaxed) {
                let stage = recon::progress::describe();
                let elapsed = start.elapsed().as_secs_f64();
                bar.set_message(step_message(&text(), &stage, elapsed, expected_s));
                std::thread::park_timeout(std::time::Duration::from_millis(200));
            }
        });
        let result = work();
        finished.store(true, std::sync::atomic::Ordering::Relaxed);
        ticker.thread().unpark();
        result
    });
    // The ticker is joined: nothing sets a stale stage after this.
    recon::progress::end();
    bar.set_message(text());
    result
}

/// The bar's message for a step `elapsed` seconds in: its stage when one runs, else the time
/// so far and what is left of `expected_s`; the message alone in its first second.
fn step_message(message: &str, stage: &str, elapsed: f64, expected_s: Option<f64>) -> String {
    if !stage.is_empty() {
        return format!("{message}: {stage}");
    }
    if elapsed < 1.0 {
        return message.to_string();
    }
    match expected_s {
        Some(expected) if expected.is_finite() && expected > elapsed => {
            format!("{message}: {elapsed:.0} s, about {:.0} s left", (expected - elapsed).ceil())
        }
        _ => format!("{message}: {elapsed:.0} s"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stage tests of this module one at a time (they share the process-wide stage).
    static STAGE_TESTS: std::sync::Mutex<()> = std::sync::Mutex::new(());

    /// Runs stage `stage` (`done` of `total` units) until the bar's message names it (at most
    /// 10 s) and returns that message. The stage is begun again on every wait: it is
    /// process-wide, and other tests end theirs.
    fn bar_once_showing(
        bar: &indicatif::ProgressBar,
        stage: &'static str,
        total: u64,
        unit: &'static str,
        done: u64,
    ) -> String {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while !bar.message().contains(stage) && std::time::Instant::now() < deadline {
            recon::progress::begin(stage, total, unit);
            recon::progress::advance(done);
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        bar.message()
    }

    #[test]
    fn a_step_without_a_stage_shows_its_time_and_what_is_left_of_the_expected() {
        assert_eq!(step_message("oidn, 4 spp", "", 0.4, Some(9.0)), "oidn, 4 spp", "nothing in the first second");
        assert_eq!(step_message("oidn, 4 spp", "", 3.2, Some(9.0)), "oidn, 4 spp: 3 s, about 6 s left");
        assert_eq!(step_message("oidn, 4 spp", "", 3.2, None), "oidn, 4 spp: 3 s");
        assert_eq!(step_message("oidn, 4 spp", "", 12.0, Some(9.0)), "oidn, 4 spp: 12 s", "past the expected time");
        assert_eq!(step_message("oidn, 4 spp", "", 2.0, Some(f64::NAN)), "oidn, 4 spp: 2 s");
        let stage = "render 3/64 tiles, 2 s left";
        assert_eq!(step_message("pt, 16 spp", stage, 5.0, Some(1.0)), format!("pt, 16 spp: {stage}"));
    }

    #[test]
    fn a_reconstruction_stage_shows_in_the_bar_while_it_runs() {
        let bar = indicatif::ProgressBar::hidden();
        let _alone = STAGE_TESTS.lock().unwrap_or_else(|e| e.into_inner());
        let seen = with_stage_progress(&bar, "ilfr, 4 spp", || {
            // The ticker updates five times a second.
            bar_once_showing(&bar, "gather", 4, "rows", 1)
        });
        assert!(seen.starts_with("ilfr, 4 spp: gather 1/4 rows"), "{seen}");
        // The stage was left open: the finished run's bar no longer shows it.
        assert_eq!(bar.message(), "ilfr, 4 spp");
    }

    #[test]
    fn a_step_that_renames_itself_shows_its_current_name_with_the_stage() {
        let bar = indicatif::ProgressBar::hidden();
        let message = std::sync::Mutex::new(String::from("layout"));
        let _alone = STAGE_TESTS.lock().unwrap_or_else(|e| e.into_inner());
        let seen = with_changing_progress(&bar, &message, None, || {
            *message.lock().unwrap() = "transport".into();
            bar_once_showing(&bar, "traced", 10, "receivers", 3)
        });
        assert!(seen.starts_with("transport: traced 3/10 receivers"), "{seen}");
        assert_eq!(bar.message(), "transport", "the last name, without the ended stage");
    }
}
