//! `lfr render`: path traces a scene into a multi-layer EXR and a PNG preview beside it.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use tracer::Accel;

use crate::common::{check_outputs, scene_inputs, TraceArgs};

#[derive(clap::Args)]
pub struct RenderArgs {
    #[command(flatten)]
    trace: TraceArgs,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    spp: Option<u32>,
    /// Output EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
}

pub fn run(args: &RenderArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        anyhow::bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let trace = &args.trace;
    let preview = args.out.with_extension("png");
    check_outputs(&[&args.out, &preview], &scene_inputs(trace.scene.as_deref()))?;
    let load_start = Instant::now();
    let scene = trace.load_scene()?;
    let settings = trace.settings(&scene, args.spp.unwrap_or(scene.spp))?;
    let accel = Accel::build(&scene)?;
    let setup = load_start.elapsed().as_secs_f64();
    let frame = tracer::render(&scene, &accel, &settings)?;
    let preview = tracer::output::write_frame(&args.out, &frame).with_context(|| "writing the image")?;
    println!(
        "rendered {} ({} triangles) at {}x{}, {} spp in {:.3} s (scene and BVH {:.3} s): {} rays, {:.2} Mrays/s",
        scene.source.display(),
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
