//! `lfr compare`: error against run time for path tracing and every requested method, on one
//! scene and effect, against a cached high-spp reference (docs/compare.md).
//!
//! [`run`] is a pipeline of stages (`stages`): plan → reference → inputs → execute → score →
//! write. The parts they use: what each effect means for the tracer and its image layer
//! (`effect`), the cached reference (`reference`), its check (`reference_check`), a reference
//! rendered elsewhere (`external`), the scene-level methods (`scene_methods`: `probes`, on the
//! tracer's side, `probes_method`),
//! the output folder (`out_dir`), peak memory (`memory`), repeated timings (`timing`), the
//! verdicts (`verdict`), the images (`images`), and the record and its reports (`results`,
//! `report`, `html`, `plot`).

pub mod budget;
pub mod effect;
pub mod external;
pub mod html;
pub mod images;
pub mod memory;
pub mod out_dir;
pub mod peer;
pub mod plot;
pub mod probes_method;
pub mod reference;
pub mod reference_check;
pub mod report;
pub mod results;
pub mod scene_methods;
pub mod stages;
pub mod timing;
pub mod verdict;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use recon::registry;
use recon::Effect;
use tracer::Accel;

use crate::common::TraceArgs;

use stages::plan::Plan;
use stages::{execute, inputs, measure, reference as reference_stage, score, write};

fn parse_effect(name: &str) -> Result<Effect, String> {
    Effect::from_name(name)
        .ok_or_else(|| format!("unknown effect `{name}`; one of: {}", Effect::ALL.map(|e| e.name()).join(", ")))
}

#[derive(clap::Args)]
pub struct CompareArgs {
    /// The scene, size, seed (default 1 here: the inputs and the ladder use it, the reference two
    /// seeds derived from it), path length (soft-shadow always uses 1, direct light only),
    /// threads and progress.
    #[command(flatten)]
    pub trace: TraceArgs,
    /// indirect, glossy, ao, dof, motion, dof-motion or soft-shadow; without it, from the scene:
    /// dof-motion (aperture and motion), dof, motion, glossy (a glossy material), else indirect.
    #[arg(long, value_parser = parse_effect)]
    pub effect: Option<Effect>,
    /// Output directory (created): results.json, report.md, images/, plots.
    #[arg(long, required_unless_present = "list_methods")]
    pub out: Option<PathBuf>,
    /// List every method with the effects it handles, its options (range, default) and a
    /// description, and exit.
    #[arg(long)]
    pub list_methods: bool,
    /// Methods to compare, comma-separated, each `NAME` or `NAME:key=value:...`
    /// (`lfr compare --list-methods` lists them).
    #[arg(long, value_delimiter = ',', default_value = "box,oidn")]
    pub methods: Vec<String>,
    /// Input samples per pixel of the methods, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,16")]
    pub spp: Vec<u32>,
    /// Reconstruction rays (or locations) per pixel, comma-separated; default: each method's own.
    #[arg(long, value_delimiter = ',')]
    pub recon_rays: Option<Vec<u32>>,
    /// Samples per pixel of the reference (two halves of half as many).
    #[arg(long, default_value_t = 4096)]
    pub reference_spp: u32,
    /// The path-tracing ladder runs 1, 2, 4, ... up to this many spp.
    #[arg(long, default_value_t = 256)]
    pub pt_max_spp: u32,
    /// Ambient-occlusion radius in scene units (default: a tenth of the scene's diagonal).
    #[arg(long)]
    pub ao_radius: Option<f32>,
    /// Thin-lens aperture radius in scene units, replacing the scene's (0 = pinhole).
    #[arg(long)]
    pub aperture_radius: Option<f32>,
    /// Focus distance in scene units, replacing the scene's.
    #[arg(long)]
    pub focus_distance: Option<f32>,
    /// Exposure of the tone map for PSNR/SSIM (default: the reference's 99th-percentile
    /// luminance maps to 1).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Reference cache directory (default: $LFR_CACHE_DIR, $XDG_CACHE_HOME/lfr or ~/.cache/lfr).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// A reference rendered elsewhere: one EXR of `lfr render` or `lfr merge`, or two with
    /// different seeds (two halves, which give its own error), instead of the traced or cached
    /// one (docs/scale-out.md). Its header record must match this comparison's scene and set-up.
    #[arg(long, value_delimiter = ',', num_args = 1..=2, conflicts_with_all = ["no_cache"])]
    pub reference: Option<Vec<PathBuf>>,
    /// Trace the reference even when a cached one exists (and replace it).
    #[arg(long)]
    pub no_cache: bool,
    /// The check of the reference's own error: one pixel per 4×4 block traced with this many
    /// times the reference's spp (1..=64; about this many sixteenths of the reference's time),
    /// or `off` (then only the two halves estimate it: optimistic where rare paths carry the
    /// light). For an expensive reference rendered elsewhere, `off` or 1 keeps it cheap.
    #[arg(long, default_value = reference_check::DEFAULT_FACTOR, value_parser = reference_check::parse_factor)]
    pub reference_check: reference_check::CheckSetting,
    /// Keep the methods' input sample files in OUT/inputs.
    #[arg(long)]
    pub keep_samples: bool,
    /// Time every run up to this many times (runs over 5 s twice, over 30 s once), alternating
    /// over all runs; verdicts use the median and report the spread. 1 = one measurement.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=20))]
    pub repeats: u32,
    /// Write into an --out folder that holds other files than a comparison's (they are kept;
    /// only the comparison's own files are replaced).
    #[arg(long)]
    pub force: bool,
}

/// Every method the harness runs: the registry's methods and pipelines, and the scene-level
/// methods the harness builds itself because they need the tracer (`scene_methods`).
pub fn method_listing() -> String {
    format!("{}{}", registry::listing(), scene_methods::listing())
}

/// Runs the comparison `args` asks for, stage by stage (`stages`).
pub fn run(args: &CompareArgs) -> Result<()> {
    if args.list_methods {
        print!("{}", method_listing());
        return Ok(());
    }
    let start = Instant::now();
    let plan = Plan::new(args)?;
    let accel = Accel::build(&plan.scene)?;
    let tracing = plan.tracing(&accel);
    let source = reference_stage::Source::open(&plan, &tracing)?;
    out_dir::open(plan.dir, args.force)?;
    let measure = reference_stage::settle(&plan, &tracing, source)?;
    let bar = execute::progress_bar(plan.progress);
    bar.set_length(execute::first_pass_steps(&plan));
    let scorer = measure::Scorer::new(&plan, &measure, &bar);
    let traced = inputs::Traced::trace(&plan, &tracing, &bar)?;
    let executed = execute::execute(&plan, &tracing, &accel, traced, &scorer, &bar)?;
    let results = score::score(&plan, &measure, executed, start);
    write::write(plan.dir, &results)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name the listing gives at the start of a line is a method the harness builds (the
    /// registry's `find` or the harness's `probes`), and every registry method, pipeline and
    /// `probes` is listed.
    #[test]
    fn the_method_listing_names_every_method_the_harness_runs() {
        let listing = method_listing();
        let listed: Vec<&str> = listing.lines().filter(|line| !line.starts_with(' ')).collect();
        for name in &listed {
            let built = registry::find(name).map(|m| m.is_some()).unwrap_or(false)
                || probes_method::ProbesMethod::parse(name, 1).map(|m| m.is_some()).unwrap_or(false);
            assert!(built, "listed but not runnable: {name}");
        }
        let mut expected: Vec<String> = registry::METHODS.iter().map(|m| m.name.to_string()).collect();
        expected.extend(registry::PIPELINES.iter().map(|p| p.name()));
        expected.extend(scene_methods::SCENE_METHODS.iter().map(|m| m.name.to_string()));
        for name in &expected {
            assert!(listed.contains(&name.as_str()), "not listed: {name}");
        }
    }
}
