//! `lfr probes`: sparse radiance probes (Silvennoinen & Lehtinen 2017; the crate `probes` holds
//! the method and its relight pipeline, `probes::pipeline`; docs/probes.md). One file per
//! subcommand over that pipeline: `stats` builds the receivers and places the probes, and prints
//! the placement, the coverage it gives and the memory the precompute will need; `precompute`
//! writes the cache; `relight` renders one relit frame from it (building it first when there is
//! none), optionally with a light moved; `animate` moves a point light along a line, one bounce
//! per frame with the paper's feedback, and times every frame. `options` holds the flags they
//! share, `image` the written frame.

mod animate;
mod image;
mod options;
mod precompute;
mod relight;
mod stats;

use std::path::Path;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use probes::memory::MemoryEstimate;
use probes::pipeline::{Obtained, Stale};
use probes::precompute::PrecomputeSettings;

use crate::common::TraceArgs;
use crate::outputs::OutputPlan;
use animate::{run_animate, AnimateArgs};
use options::PrecomputeOptions;
use precompute::{run_precompute, PrecomputeArgs};
use relight::{run_relight, RelightArgs};
use stats::{run_stats, StatsArgs};

#[derive(clap::Args)]
pub struct ProbesArgs {
    #[command(subcommand)]
    command: ProbesCommand,
}

#[derive(clap::Subcommand)]
enum ProbesCommand {
    /// Receivers, probe placement, support radius, coverage and memory of a scene.
    Stats(StatsArgs),
    /// Build the precompute (receivers, probes, transport, relight rays) and write its cache.
    Precompute(PrecomputeArgs),
    /// One relit frame from the cache (built and written first when the file does not exist):
    /// a multi-layer EXR (beauty, direct, indirect, irradiance, albedo, unseen, probes, hole)
    /// and a PNG preview.
    Relight(RelightArgs),
    /// A point light moved along a line over frames (one bounce per frame, fed back), every
    /// frame from the same cache: EXR and PNG per frame and a timing table.
    Animate(AnimateArgs),
}

pub fn run(args: &ProbesArgs) -> Result<()> {
    match &args.command {
        ProbesCommand::Stats(stats) => run_stats(stats),
        ProbesCommand::Precompute(a) => run_precompute(a),
        ProbesCommand::Relight(a) => run_relight(a),
        ProbesCommand::Animate(a) => run_animate(a),
    }
}

/// A point option: three finite numbers.
fn point_option(name: &str, values: &[f32]) -> Result<glam::Vec3> {
    match values {
        [x, y, z] if [x, y, z].iter().all(|v| v.is_finite()) => Ok(glam::Vec3::new(*x, *y, *z)),
        _ => anyhow::bail!("{name}: takes a finite point X,Y,Z, got {values:?}"),
    }
}

/// The precompute of `scene` from `cache` (`probes::pipeline::obtain`) with `bar` showing its
/// steps and their counts (`shading::progress`), and its notes printed above the bar.
pub(crate) fn obtain(
    scene: &tracer::Scene,
    settings: &PrecomputeSettings,
    cache: &Path,
    stale: Stale,
    pool: &rayon::ThreadPool,
    bar: &ProgressBar,
) -> Result<Obtained> {
    let message = std::sync::Mutex::new(String::from("precompute"));
    let step = |name: &str| {
        *message.lock().unwrap_or_else(|e| e.into_inner()) = name.to_string();
        bar.set_message(name.to_string());
    };
    let mut note = |text: String| bar.suspend(|| eprintln!("note: {text}"));
    crate::common::with_changing_progress(bar, &message, None, || {
        probes::pipeline::obtain(scene, settings, cache, stale, pool, &step, &mut note)
    })
    .with_context(|| format!("precompute on {}", scene.source.display()))
}

/// The progress bar of the long steps.
fn spinner(quiet: bool, what: &'static str) -> ProgressBar {
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new_spinner() };
    bar.set_style(
        ProgressStyle::with_template(&format!("{{spinner}} probes {what}: {{msg}} [{{elapsed_precise}}]"))
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// Checks the precompute settings and the outputs in `plan` with the cache (read when it holds
/// this precompute, else written) among them, all before the scene is read; returns the
/// settings and the plan, to be checked again with the scene's files once it is loaded.
fn check_common(
    trace: &TraceArgs,
    pre: &PrecomputeOptions,
    mut plan: OutputPlan,
) -> Result<(PrecomputeSettings, OutputPlan)> {
    let settings = pre.settings(trace.seed());
    settings.validate()?;
    trace.run.thread_count()?;
    plan.file(&pre.cache, "the precompute cache (--cache)").scene_file(trace.scene.as_deref()).check()?;
    Ok((settings, plan))
}

/// Refuses the run when its estimated peak memory (`probes::memory`) is over what the machine
/// has available (`tracer::memory`; `LFR_MEMORY_AVAILABLE` replaces the measurement). Called
/// after the scene is read (its memory is then out of the measured available memory) and
/// before the precompute, the cache read or any frame.
fn check_memory(what: &str, estimate: &MemoryEstimate) -> Result<()> {
    tracer::memory::check(&estimate.describe(what), estimate.total())?;
    Ok(())
}

/// `scene` lit for a frame: its own lights unless --no-scene-lights, plus a point light at
/// `light` when given.
fn lit_scene(scene: &tracer::Scene, no_scene_lights: bool, light: Option<(glam::Vec3, glam::Vec3)>) -> tracer::Scene {
    let mut lit = scene.clone();
    if no_scene_lights {
        lit.lights.clear();
        lit.environment = glam::Vec3::ZERO;
        for m in &mut lit.materials {
            m.emission = glam::Vec3::ZERO;
            m.emission_texture = None;
        }
    }
    if let Some((position, intensity)) = light {
        lit.lights.push(tracer::scene::PunctualLight::Point { position, intensity });
    }
    lit
}
