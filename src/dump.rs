//! `lfr dump`: writes samples for the reconstructions and external tools
//! (docs/sample-format.md), or guide buffers as an EXR.

use std::path::PathBuf;

use anyhow::Result;
use sampleio::SampleKind;
use tracer::Accel;

use crate::common::{check_outputs, scene_inputs, TraceArgs};

/// What `lfr dump` writes: a sample kind, or guide buffers.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum DumpKind {
    /// Camera samples over pixel, lens and time for the temporal light field (TLFR).
    LensTime,
    /// Rays from a planar area light towards the visible points, for TLFR soft shadows.
    Light,
    /// Secondary rays with their radiance for the indirect light field (ILFR).
    Indirect,
    /// Cosine-weighted secondary rays with their hit distance (ILFR ambient occlusion).
    Ao,
    /// Per-pixel guide buffers for the guided image filter, as a multi-layer EXR.
    Guide,
}

impl DumpKind {
    /// The sample kind; `None` for guide buffers.
    fn sample_kind(self) -> Option<SampleKind> {
        match self {
            DumpKind::LensTime => Some(SampleKind::LensTime),
            DumpKind::Light => Some(SampleKind::Light),
            DumpKind::Indirect => Some(SampleKind::Indirect),
            DumpKind::Ao => Some(SampleKind::Ao),
            DumpKind::Guide => None,
        }
    }
}

#[derive(clap::Args)]
pub struct DumpArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[arg(long, value_enum)]
    kind: DumpKind,
    /// Samples per pixel.
    #[arg(long)]
    spp: u32,
    /// Output sample file (conventionally .lfrs; .exr for guide buffers).
    #[arg(long)]
    out: PathBuf,
    /// With --kind lens-time: also write `albedo`, `normal` and `radiance_without_light` for
    /// the soft-shadow reconstruction (needs a planar area light).
    #[arg(long)]
    soft_shadow: bool,
    /// Write only these fields (comma-separated, e.g. `radiance` or `x,y,z,radiance`), in the
    /// kind's record order; each must be one of the kind's fields for this scene. A selected file
    /// is the full one with the other columns left out (docs/sample-format.md).
    #[arg(long, value_name = "LIST")]
    fields: Option<String>,
}

pub fn run(args: &DumpArgs) -> Result<()> {
    let trace = &args.trace;
    let wants_exr = matches!(args.kind, DumpKind::Guide);
    let extension = args.out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match (wants_exr, extension.as_deref()) {
        (true, Some("exr")) | (false, Some("lfrs")) => {}
        (true, _) => anyhow::bail!("--out {}: guide buffers are written as an .exr file", args.out.display()),
        (false, _) => anyhow::bail!("--out {}: samples are written as an .lfrs file", args.out.display()),
    }
    if args.soft_shadow && !matches!(args.kind, DumpKind::LensTime) {
        anyhow::bail!("--soft-shadow only applies to --kind lens-time");
    }
    check_outputs(&[&args.out], &scene_inputs(trace.scene.as_deref()))?;
    let fields = match &args.fields {
        Some(list) => {
            anyhow::ensure!(
                !matches!(args.kind, DumpKind::Guide),
                "--fields applies to sample files, not --kind guide"
            );
            tracer::samples::FieldSelection::parse_strict(list)?
        }
        None => tracer::samples::FieldSelection::All,
    };
    let scene = trace.load_scene()?;
    let settings = trace.settings(&scene, args.spp)?;
    let accel = Accel::build(&scene)?;
    let report = match args.kind.sample_kind() {
        Some(kind) => tracer::samples::dump(&scene, &accel, &settings, kind, args.soft_shadow, &fields, &args.out)?,
        None => tracer::samples::guide::dump(&scene, &accel, &settings, &args.out)?,
    };
    println!(
        "wrote {} samples of {} to {} in {:.3} s ({:.3} s tracing and writing the records, {:.3} s finishing the file): {} bytes per record, {:.1} bytes per sample with header and checksums; fields: {}",
        report.samples,
        scene.source.display(),
        args.out.display(),
        report.seconds,
        report.trace_seconds,
        report.seconds - report.trace_seconds,
        report.record_size,
        report.bytes_per_sample(),
        report.fields.join(", "),
    );
    if report.dropped_contributions > 0 {
        eprintln!(
            "warning: {} path contributions were NaN or infinite (e.g. an emitter too bright for f32) and were \
             dropped; the samples are darker than the scene",
            report.dropped_contributions
        );
    }
    Ok(())
}
