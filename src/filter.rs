//! `lfr filter`: the filtered path-tracing pipeline of Bauszat, Eisemann and Magnor 2011 end to
//! end on a scene. The tracer casts one guide ray per pixel centre and estimates the indirect
//! light at its hit with `spp` paths, plus `spp − 1` additional eye rays per pixel with their
//! direct light; the chosen filter smooths the incident indirect light at the guide hits; the
//! eye rays take theirs by the geometry-aware lookup; the box-filtered composite is written as
//! one multi-layer EXR with a PNG preview beside it.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use recon::gif::filtered_indirect::{FilterOptions, FilteredIndirect};
use recon::Image;
use tracer::output::{write_exr, write_png, Layer};
use tracer::Accel;

use crate::common::TraceArgs;
use crate::convert::{guide_input, rgb_channels};
use crate::outputs::{preview_of, OutputPlan};

#[derive(clap::Args)]
pub struct FilterArgs {
    #[command(flatten)]
    trace: TraceArgs,
    /// Eye rays and indirect paths per pixel.
    #[arg(long, default_value_t = 4)]
    spp: u32,
    /// gif, gif-normal, gif-grey, bilateral, atrous or atrous-sn.
    #[arg(long, default_value = "gif")]
    filter: String,
    /// Window radius at an 800-pixel image, scaled with the image (gif*, bilateral).
    #[arg(long)]
    radius: Option<u32>,
    /// ε of the normal channels (gif*).
    #[arg(long)]
    epsilon_normal: Option<f32>,
    /// ε of the depth channel (gif).
    #[arg(long)]
    epsilon_depth: Option<f32>,
    /// Subsampling factor of the fast guided filter (gif*; 1 = the exact filter).
    #[arg(long)]
    subsample: Option<u32>,
    /// À-Trous iterations (atrous*).
    #[arg(long)]
    iterations: Option<u32>,
    /// Output EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
}

/// The filter `args` names, with its overrides applied; errors for options it does not take.
fn chosen_filter(args: &FilterArgs) -> Result<FilteredIndirect> {
    let Some(method) = FilteredIndirect::named(&args.filter) else {
        let names: Vec<String> = FilteredIndirect::all().into_iter().map(|f| f.name).collect();
        bail!("--filter {}: unknown filter; choose one of {}", args.filter, names.join(", "));
    };
    for (option, value) in [("epsilon-normal", args.epsilon_normal), ("epsilon-depth", args.epsilon_depth)] {
        if let Some(value) = value {
            if !(value.is_finite() && value > 0.0) {
                bail!("--{option} must be positive and finite, got {value}");
            }
        }
    }
    let options = FilterOptions {
        radius: args.radius,
        epsilon_normal: args.epsilon_normal,
        epsilon_depth: args.epsilon_depth,
        subsample: args.subsample,
        iterations: args.iterations,
        lookup: None,
    };
    method.with_options(&options).map_err(|e| anyhow::anyhow!("--filter {}: {e}", args.filter))
}

pub fn run(args: &FilterArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let method = chosen_filter(args)?;
    let trace = &args.trace;
    let preview = preview_of(&args.out);
    let mut plan = OutputPlan::new();
    plan.file(&args.out, "--out").file(&preview, "the PNG preview beside --out");
    plan.scene_file(trace.scene.as_deref()).check()?;
    let scene = trace.load_scene()?;
    plan.scene(&scene).check()?;
    let settings = trace.settings(&scene, args.spp)?;
    // The guide buffers, the filter's planes and the composite: about two renders' worth.
    let (width, height) = (settings.width, settings.height);
    tracer::memory::check(&format!("filtering {width}x{height}"), 2 * tracer::memory::render_bytes(width, height))?;
    let accel = Accel::build(&scene)?;
    let trace_start = Instant::now();
    let buffers = tracer::samples::guide::guide_buffers(&scene, &accel, &settings)?;
    let trace_s = trace_start.elapsed().as_secs_f64();
    let input = guide_input(&buffers);
    let pool = trace.run.worker_pool()?;
    let filter_start = Instant::now();
    let (composite, sanitised) = pool.install(|| method.reconstruct(&input)).map_err(anyhow::Error::msg)?;
    let filter_s = filter_start.elapsed().as_secs_f64();

    let (width, height) = (settings.width, settings.height);
    let vec3 = |image: &Image| image.pixels.iter().map(|p| glam::Vec3::from_array(*p)).collect::<Vec<_>>();
    let layers = vec![
        Layer { name: "", channels: rgb_channels(&composite.beauty) },
        Layer { name: "direct", channels: rgb_channels(&composite.direct) },
        Layer { name: "indirect", channels: rgb_channels(&composite.indirect) },
        Layer { name: "indirect_unfiltered", channels: rgb_channels(&input.indirect) },
        Layer { name: "albedo", channels: rgb_channels(&input.albedo) },
        Layer { name: "depth", channels: vec![("Z", buffers.depth.clone())] },
    ];
    write_exr(&args.out, width, height, &layers).with_context(|| format!("writing {}", args.out.display()))?;
    write_png(&preview, width, height, &vec3(&composite.beauty), 1.0)
        .with_context(|| format!("writing {}", preview.display()))?;
    println!(
        "filtered {} at {width}x{height}, {} spp with {}: tracing {trace_s:.3} s, filtering and composite {filter_s:.3} s",
        scene.source.display(),
        args.spp,
        method.name,
    );
    for warning in buffers.warnings() {
        eprintln!("warning: {warning}");
    }
    if sanitised > 0 {
        eprintln!("warning: {sanitised} non-finite indirect values were replaced by 0 before filtering");
    }
    if composite.unmatched_eye_rays > 0 {
        eprintln!(
            "note: {} eye ray{} hit geometry no neighbouring guide ray hit; {} no indirect light",
            composite.unmatched_eye_rays,
            if composite.unmatched_eye_rays == 1 { "" } else { "s" },
            if composite.unmatched_eye_rays == 1 { "it got" } else { "they got" }
        );
    }
    println!("wrote {} and {}", args.out.display(), preview.display());
    Ok(())
}
