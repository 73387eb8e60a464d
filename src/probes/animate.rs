//! `lfr probes animate`: a point light moved along a line over frames, one bounce per frame fed
//! back from the last (the paper's feedback), every frame through `probes::pipeline` from the
//! same cache; EXR and PNG per frame and a timing table.

use std::path::PathBuf;

use anyhow::Result;
use probes::cache::CacheKey;
use probes::pipeline::{
    cpca_path, frame_estimate, image_operator, operator, relit_frame, Bounces, CpcaReport, FrameSettings, Obtained,
    Stale,
};
use serde::Serialize;

use super::image::{description, image_settings, write_image};
use super::options::{FrameOptions, PrecomputeOptions};
use super::precompute::{precompute_report, print_precompute, PrecomputeReport};
use super::{check_common, check_memory, lit_scene, obtain, point_option, spinner};
use crate::common::{write_json, TraceArgs};
use crate::outputs::OutputPlan;

#[derive(clap::Args)]
pub(super) struct AnimateArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[command(flatten)]
    pre: PrecomputeOptions,
    #[command(flatten)]
    frame: FrameOptions,
    /// The point light's position in the first frame.
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "X,Y,Z", allow_negative_numbers = true)]
    light_from: Vec<f32>,
    /// The point light's position in the last frame (straight line between).
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "X,Y,Z", allow_negative_numbers = true)]
    light_to: Vec<f32>,
    /// Number of frames.
    #[arg(long, default_value_t = 8)]
    frames: u32,
    /// Bounces per frame, each frame starting from the last one's indirect light (the paper's
    /// feedback).
    #[arg(long, default_value_t = 1)]
    bounces_per_frame: u32,
    /// Folder for frame_NNNN.exr, frame_NNNN.png and timings.json.
    #[arg(long)]
    out_dir: PathBuf,
}

#[derive(Serialize)]
struct AnimateFrame {
    frame: u32,
    light_position: [f32; 3],
    /// Scene relight (direct light at the senders).
    direct_s: f64,
    bounces_s: f64,
    probe_relight_s: f64,
    cluster_projection_s: f64,
    receiver_irradiance_s: f64,
    /// The image through the camera's kept lookups.
    image_s: f64,
    frame_s: f64,
    mean_indirect: [f32; 3],
}

#[derive(Serialize)]
struct AnimateReport {
    precompute: PrecomputeReport,
    cpca: Option<CpcaReport>,
    bounces_per_frame: u32,
    /// Seconds to trace the camera's primary rays and keep their lookups (once).
    image_operator_s: f64,
    frames: Vec<AnimateFrame>,
    mean_frame_s: f64,
    worst_frame_s: f64,
}

pub(super) fn run_animate(args: &AnimateArgs) -> Result<()> {
    let (cpca_settings, intensity) = args.frame.validated()?;
    let from = point_option("light-from", &args.light_from)?;
    let to = point_option("light-to", &args.light_to)?;
    if !(1..=100_000).contains(&args.frames) {
        anyhow::bail!("frames: must be between 1 and 100000, got {}", args.frames);
    }
    if !(1..=1000).contains(&args.bounces_per_frame) {
        anyhow::bail!("bounces-per-frame: must be between 1 and 1000, got {}", args.bounces_per_frame);
    }
    let names: Vec<(PathBuf, PathBuf)> = (0..args.frames)
        .map(|f| {
            let exr = args.out_dir.join(format!("frame_{f:04}.exr"));
            let png = exr.with_extension("png");
            (exr, png)
        })
        .collect();
    let timings = args.out_dir.join("timings.json");
    let mut plan = OutputPlan::new();
    for (exr, png) in &names {
        plan.file(exr, "a frame").file(png, "a frame's PNG preview");
    }
    plan.file(&timings, "the timings");
    if cpca_settings.is_some() {
        plan.file(&cpca_path(&args.pre.cache), "the CPCA cache beside --cache");
    }
    let (settings, mut plan) = check_common(&args.trace, &args.pre, plan)?;
    let scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    let image = image_settings(&args.trace, &scene, &args.frame)?;
    let threads = args.trace.run.thread_count()?;
    // Animate runs one bounce a frame through the full loop: no projected bounce.
    check_memory("the probes animation", &frame_estimate(&settings, cpca_settings.as_ref(), false, &image, threads))?;
    let pool = tracer::render::thread_pool(threads)?;
    let bar = spinner(args.trace.quiet, "animate");
    let Obtained { precompute: mut pre, from_cache, seconds: s } =
        obtain(&scene, &settings, &args.pre.cache, Stale::Refuse, &pool, &bar)?;
    args.frame.apply(&mut pre, &pool)?;
    let key = CacheKey::of(&scene, &settings);
    let mut note = |text: String| bar.suspend(|| eprintln!("note: {text}"));
    let (op, cpca) = operator(&pre, cpca_settings, &pool, &args.pre.cache, &key, &mut note)?;
    let intensity = intensity.unwrap_or(glam::Vec3::splat((0.5 * pre.scale as f32).powi(2)));
    let accel = tracer::Accel::build(&scene)?;
    // The camera is fixed: its lookups are traced once (the scene lit as in the first frame;
    // only the point light moves, which the kept lookups do not depend on).
    bar.set_message("tracing the camera's lookups");
    let first = lit_scene(&scene, args.frame.no_scene_lights, Some((from, intensity)));
    let (camera, image_operator_s) = image_operator(&first, &accel, &pre, &image, &pool)?;
    let mut previous: Option<Vec<glam::Vec3>> = None;
    let mut frames = Vec::new();
    for (f, (exr, _)) in names.iter().enumerate() {
        bar.set_message(format!("frame {} of {}", f + 1, args.frames));
        let t = if args.frames > 1 { f as f32 / (args.frames - 1) as f32 } else { 0.0 };
        let position = from.lerp(to, t);
        let lit = lit_scene(&scene, args.frame.no_scene_lights, Some((position, intensity)));
        let frame = FrameSettings {
            bounces: args.bounces_per_frame as usize,
            start: previous.as_deref(),
            tolerance: 0.0,
            light_samples: image.light_samples,
        };
        let (out, img, times) =
            relit_frame(&lit, &accel, &pre, &Bounces::of(&op, None), &frame, &image, Some(&camera), &pool)?;
        write_image(
            exr,
            &img,
            description(&settings, &scene, if cpca.is_some() { "cpca" } else { "dense" }, Some(position)),
        )?;
        let n = img.indirect.len().max(1) as f32;
        frames.push(AnimateFrame {
            frame: f as u32,
            light_position: position.to_array(),
            direct_s: times.direct_s,
            bounces_s: times.bounces_s,
            probe_relight_s: times.probe_relight_s,
            cluster_projection_s: times.cluster_projection_s,
            receiver_irradiance_s: times.receiver_irradiance_s,
            image_s: times.image_s,
            frame_s: times.frame_s,
            mean_indirect: (img.indirect.iter().fold(glam::Vec3::ZERO, |a, v| a + *v) / n).to_array(),
        });
        previous = Some(out.irradiance);
    }
    bar.finish_and_clear();
    let mean = frames.iter().map(|f| f.frame_s).sum::<f64>() / frames.len() as f64;
    let worst = frames.iter().map(|f| f.frame_s).fold(0.0, f64::max);
    let report = AnimateReport {
        precompute: precompute_report(&scene, &args.pre.cache, &pre, from_cache, s),
        cpca,
        bounces_per_frame: args.bounces_per_frame,
        image_operator_s,
        frames,
        mean_frame_s: mean,
        worst_frame_s: worst,
    };
    print_precompute(&report.precompute);
    println!("camera      primary rays and their lookups kept once in {:.4} s", report.image_operator_s);
    println!(
        "| frame | light | scene relight s | probe relight s | cluster projection s | receiver irradiance s | bounces s | frame s | image s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for f in &report.frames {
        let p = f.light_position;
        println!(
            "| {} | {:.4e}, {:.4e}, {:.4e} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} |",
            f.frame,
            p[0],
            p[1],
            p[2],
            f.direct_s,
            f.probe_relight_s,
            f.cluster_projection_s,
            f.receiver_irradiance_s,
            f.bounces_s,
            f.frame_s,
            f.image_s
        );
    }
    println!(
        "frames      mean {:.4} s, worst {:.4} s (direct light and {} bounce(s) each, image excluded)",
        mean, worst, args.bounces_per_frame
    );
    write_json(&timings, &report)?;
    println!("wrote {} frames and {}", report.frames.len(), timings.display());
    Ok(())
}
