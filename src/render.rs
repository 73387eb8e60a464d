//! `lfr render`: path traces a scene into a multi-layer EXR and a PNG preview beside it, whole or
//! as one of N disjoint tile sets (`--shard I/N`) or sample ranges (`--shard I/N --shard-by
//! samples`) that `lfr merge` assembles (docs/scale-out.md).
//! Every EXR records how it was made in its header (`lfr.render`, a [`RenderRecord`]).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use tracer::render::{Shard, ShardBy};
use tracer::{Accel, RenderSettings, RenderedImage};

use crate::common::TraceArgs;
use crate::outputs::{preview_of, OutputPlan};

#[derive(clap::Args)]
pub struct RenderArgs {
    #[command(flatten)]
    trace: TraceArgs,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    spp: Option<u32>,
    /// Render only shard I of N (counted from 0), for `lfr merge`: one of N disjoint tile sets,
    /// or with `--shard-by samples` every pixel at one of N disjoint ranges of its samples.
    #[arg(long, value_parser = Shard::parse)]
    shard: Option<Shard>,
    /// What `--shard` splits: `tiles` (bit for bit when merged) or `samples` (equal within float
    /// rounding when merged; for references that need many samples everywhere).
    #[arg(long, value_parser = ShardBy::parse, default_value = "tiles", requires = "shard")]
    shard_by: ShardBy,
    /// Output EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
}

/// The EXR header attribute that holds the [`RenderRecord`] as JSON.
pub const RECORD_ATTRIBUTE: &str = "lfr.render";

/// How an image was rendered: what `lfr merge` checks its shards against, and what an external
/// reference given to `lfr compare --reference` is checked against.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderRecord {
    /// `lfr-render/1`.
    pub schema: String,
    pub lfr_version: String,
    /// `crate::fingerprint::scene_sha256` of the scene as traced.
    pub scene_sha256: String,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub seed: u32,
    pub max_bounces: u32,
    /// [index, count]; [0, 1] for a whole image.
    pub shard: [u32; 2],
    /// What the shard splits: `tiles` or `samples` (absent in records of lfr before 0.1's
    /// sample shards: tiles).
    #[serde(default = "tiles")]
    pub shard_by: String,
    /// The sample indices traced of each pixel: 0..spp except for a shard by samples.
    #[serde(default)]
    pub samples: Option<[u32; 2]>,
    pub rays: u64,
    pub invalid_samples: u64,
    pub clamped_variances: u64,
    pub dropped_contributions: u64,
    /// Wall time of the render (for a merged image, the sum over its shards).
    pub seconds: f64,
}

pub const RECORD_SCHEMA: &str = "lfr-render/1";

fn tiles() -> String {
    ShardBy::Tiles.name().into()
}

impl RenderRecord {
    fn new(scene_sha256: String, settings: &RenderSettings, shard: Shard, frame: &RenderedImage) -> RenderRecord {
        RenderRecord {
            schema: RECORD_SCHEMA.into(),
            lfr_version: env!("CARGO_PKG_VERSION").into(),
            scene_sha256,
            width: settings.width,
            height: settings.height,
            spp: settings.spp,
            seed: settings.seed,
            max_bounces: settings.max_bounces,
            shard: [shard.index, shard.count],
            shard_by: shard.by.name().into(),
            samples: Some(shard.sample_range(settings.spp)).map(|r| [r.start, r.end]),
            rays: frame.rays,
            invalid_samples: frame.invalid_samples,
            clamped_variances: frame.clamped_variances,
            dropped_contributions: frame.dropped_contributions,
            seconds: frame.seconds,
        }
    }

    /// The header attribute.
    pub fn attribute(&self) -> Result<(&'static str, String)> {
        Ok((RECORD_ATTRIBUTE, serde_json::to_string(self)?))
    }

    /// Reads the record of an EXR `lfr render` or `lfr merge` wrote; `None` when it has none.
    pub fn read(path: &std::path::Path) -> Result<Option<RenderRecord>> {
        let attributes = tracer::output::read_exr_attributes(path)?;
        let Some((_, json)) = attributes.iter().find(|(name, _)| name == RECORD_ATTRIBUTE) else {
            return Ok(None);
        };
        let record: RenderRecord = serde_json::from_str(json).with_context(|| {
            format!("{}: the header attribute {RECORD_ATTRIBUTE} is not a render record", path.display())
        })?;
        anyhow::ensure!(
            record.schema == RECORD_SCHEMA,
            "{}: {RECORD_ATTRIBUTE}: schema `{}`, this lfr reads `{RECORD_SCHEMA}`",
            path.display(),
            record.schema
        );
        Ok(Some(record))
    }
}

/// Writes `frame` as the EXR and PNG preview with its record.
pub fn write_recorded(path: &std::path::Path, frame: &RenderedImage, record: &RenderRecord) -> Result<PathBuf> {
    let layers = tracer::output::frame_layers(frame);
    tracer::output::write_exr_with_attributes(path, frame.width, frame.height, &layers, &[record.attribute()?])
        .with_context(|| "writing the image")?;
    let preview = preview_of(path);
    tracer::output::write_png(&preview, frame.width, frame.height, &frame.beauty, 1.0)
        .with_context(|| "writing the preview")?;
    Ok(preview)
}

pub fn run(args: &RenderArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        anyhow::bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let trace = &args.trace;
    let mut plan = OutputPlan::new();
    plan.file(&args.out, "--out").file(&preview_of(&args.out), "the PNG preview beside --out");
    plan.scene_file(trace.scene.as_deref()).check()?;
    let load_start = Instant::now();
    let scene = trace.load_scene()?;
    plan.scene(&scene).check()?;
    let scene_text = crate::fingerprint::scene_text(trace.scene.as_deref())?;
    let settings = trace.settings(&scene, args.spp.unwrap_or(scene.spp))?;
    let shard = args.shard.unwrap_or(Shard::WHOLE).by(args.shard_by);
    if shard.by == ShardBy::Samples && shard.count > settings.spp {
        anyhow::bail!(
            "--shard {}/{} --shard-by samples: a {}-spp render splits into at most {} sample shards",
            shard.index,
            shard.count,
            settings.spp,
            settings.spp
        );
    }
    let (width, height) = (settings.width, settings.height);
    tracer::memory::check(&format!("a {width}x{height} render"), tracer::memory::render_bytes(width, height))?;
    let accel = Accel::build(&scene)?;
    let setup = load_start.elapsed().as_secs_f64();
    let frame = tracer::render::render_shard(&scene, &accel, &settings, shard)?;
    let record = RenderRecord::new(crate::fingerprint::scene_sha256(&scene_text, &scene), &settings, shard, &frame);
    let preview = write_recorded(&args.out, &frame, &record)?;
    println!(
        "rendered {}{} ({} triangles) at {}x{}, {} spp in {:.3} s (scene and BVH {:.3} s): {} rays, {:.2} Mrays/s",
        scene.source.display(),
        if shard == Shard::WHOLE {
            String::new()
        } else {
            format!(", shard {}/{} by {}", shard.index, shard.count, shard.by.name())
        },
        accel.triangle_count,
        frame.width,
        frame.height,
        frame.spp,
        frame.seconds,
        setup,
        frame.rays,
        frame.rays as f64 / frame.seconds.max(1e-9) / 1e6,
    );
    for warning in frame.warnings() {
        eprintln!("warning: {warning}");
    }
    println!("wrote {} and {}", args.out.display(), preview.display());
    Ok(())
}
