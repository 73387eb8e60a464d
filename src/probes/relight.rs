//! `lfr probes relight`: one relit frame through `probes::pipeline` (the precompute from its
//! cache or built, CPCA, the projected bounce, the camera's lookups), written as a multi-layer
//! EXR and a PNG preview, and its indirect layer compared with a path-traced reference when
//! given; `--brute-force-rays` adds the brute-force surfel radiosity of the same receivers as a
//! diagnosis.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use probes::cache::CacheKey;
use probes::defaults;
use probes::direct::direct_irradiance;
use probes::frame::surfel_albedo;
use probes::image::{render_image, ProbeImage};
use probes::pipeline::{
    cpca_path, frame_estimate, image_operator, indirect_bounces, operator, projected_bounce, relit_frame, Bounces,
    CpcaReport, FrameSettings, FrameTimes, Obtained, ProjectedReport, Stale,
};
use serde::Serialize;

use super::image::{description, image_settings, print_split, write_image};
use super::options::{FrameOptions, PrecomputeOptions};
use super::precompute::{precompute_report, print_precompute, PrecomputeReport};
use super::{check_common, check_memory, lit_scene, obtain, point_option, spinner};
use crate::common::{write_json, TraceArgs};
use crate::outputs::{preview_of, OutputPlan};

/// How `relight` runs the bounces after the first with the CPCA transport.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum BounceLoop {
    /// In CPCA's projected space (`probes::projected_bounce`).
    Projected,
    /// Every bounce through the relight rays and the cluster projection (`probes::frame`).
    Full,
}

#[derive(clap::Args)]
pub(super) struct RelightArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[command(flatten)]
    pre: PrecomputeOptions,
    #[command(flatten)]
    frame: FrameOptions,
    /// Add a point light at X,Y,Z (with --light-intensity).
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "X,Y,Z", allow_negative_numbers = true)]
    light_position: Option<Vec<f32>>,
    /// Bounces of indirect light (0: to convergence, at most --max-bounces − 1 or the scene's,
    /// as the path tracer's indirect light).
    #[arg(long, default_value_t = 0)]
    bounces: u32,
    /// With --cpca, how the bounces after the first run: `projected` (the default: R × R
    /// products in CPCA's projected space, `probes::projected_bounce`, the matrix formed once
    /// per run; the full loop when R is over the limit) or `full` (every bounce through the
    /// relight rays and the cluster projection). The dense transport runs them in full.
    #[arg(long, value_enum)]
    bounce_loop: Option<BounceLoop>,
    /// Output EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
    /// A path-traced EXR of the same scene, size and lights (`lfr render`): the indirect layer
    /// is compared with it (PSNR, relative MSE, mean ratio).
    #[arg(long)]
    reference: Option<PathBuf>,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Diagnosis: also solve the same receivers and senders by brute-force surfel radiosity
    /// (this many cosine rays per receiver, no probes) and compare it with --reference.
    #[arg(long, default_value_t = 0)]
    brute_force_rays: u32,
}

#[derive(Serialize)]
struct RelightReport {
    precompute: PrecomputeReport,
    cpca: Option<CpcaReport>,
    width: u32,
    height: u32,
    light_position: Option<[f32; 3]>,
    light_intensity: Option<[f32; 3]>,
    /// Seconds to trace the camera's primary rays and keep their lookups (once per camera).
    image_operator_s: f64,
    image_operator_bytes: usize,
    /// How the bounces after the first ran: `projected` or `full`.
    bounce_loop: &'static str,
    /// The projected bounces' matrix, when they ran projected.
    projected: Option<ProjectedReport>,
    times: FrameTimes,
    clamped_channels: u64,
    lookup_holes: u64,
    lookup_nearest: u64,
    misses: u64,
    mean_indirect: [f32; 3],
    /// The share of the pixels on metallic or glossy surfaces, whose indirect light the probes
    /// do not carry (`probes::image::specular_share`).
    specular_share: f64,
    reference: Option<ReferenceReport>,
}

#[derive(Serialize)]
struct ReferenceReport {
    path: String,
    /// PSNR of the indirect layer under the display transform of `lfr compare` (exposure from
    /// the reference's 99th percentile).
    indirect_psnr_db: f64,
    indirect_relative_mse: f64,
    /// Mean indirect radiance of this image over the reference's, per channel.
    indirect_mean_ratio: [f64; 3],
    /// Pixels whose receivers have no transport (hidden, or no probe in range: the `probes`
    /// layer below one half), and the share of the reference's indirect light in them.
    pixels_without_probes: f64,
    reference_share_without_probes: f64,
    /// Mean direct radiance of this image over the reference's (when it has a direct layer).
    direct_mean_ratio: Option<[f64; 3]>,
}

/// The `indirect.R,G,B` layer of a path-traced EXR, `width` × `height`.
fn read_indirect(path: &Path, width: u32, height: u32) -> Result<recon::Image> {
    let (w, h, channels) = tracer::output::read_exr(path).with_context(|| format!("reading {}", path.display()))?;
    if (w, h) != (width, height) {
        anyhow::bail!("reference {}: {w}x{h}, the image is {width}x{height}", path.display());
    }
    let find = |name: &str| -> Result<&Vec<f32>> {
        channels
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v)
            .ok_or_else(|| anyhow::anyhow!("reference {}: no channel {name}", path.display()))
    };
    let (r, g, b) = (find("indirect.R")?, find("indirect.G")?, find("indirect.B")?);
    Ok(recon::Image { width, height, pixels: (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect() })
}

fn compare_indirect(path: &Path, img: &ProbeImage) -> Result<ReferenceReport> {
    let reference = read_indirect(path, img.width, img.height)?;
    let test = recon::Image {
        width: img.width,
        height: img.height,
        pixels: img.indirect.iter().map(|v| v.to_array()).collect(),
    };
    let tone = recon::metrics::ToneMap::auto(&reference);
    let psnr = recon::metrics::psnr_db(&reference, &test, &tone).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let rel = recon::metrics::relative_mse(&reference, &test).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let mut ratio = [0.0; 3];
    for (c, r) in ratio.iter_mut().enumerate() {
        let a: f64 = test.pixels.iter().map(|p| p[c] as f64).sum();
        let b: f64 = reference.pixels.iter().map(|p| p[c] as f64).sum();
        *r = if b > 0.0 { a / b } else { f64::NAN };
    }
    // The direct layer's mean ratio too (the pixels' albedo, normals and lights checked).
    let direct_mean_ratio = match tracer::output::read_exr(path) {
        Ok((_, _, channels)) => {
            let layer = |name: &str| channels.iter().find(|(n, _)| n == name).map(|(_, v)| v);
            match (layer("direct.R"), layer("direct.G"), layer("direct.B")) {
                (Some(r), Some(g), Some(b)) => {
                    let mut out = [0.0; 3];
                    for (c, values) in [r, g, b].into_iter().enumerate() {
                        let a: f64 = img.direct.iter().map(|v| v[c] as f64).sum();
                        let b: f64 = values.iter().map(|&v| v as f64).sum();
                        out[c] = if b > 0.0 { a / b } else { f64::NAN };
                    }
                    Some(out)
                }
                _ => None,
            }
        }
        Err(_) => None,
    };
    let without: Vec<bool> = img.probes.iter().map(|&p| p < 0.5).collect();
    let luminance = |p: &[f32; 3]| (p[0] + p[1] + p[2]) as f64;
    let total: f64 = reference.pixels.iter().map(luminance).sum();
    let share: f64 = reference.pixels.iter().zip(&without).filter(|(_, &w)| w).map(|(p, _)| luminance(p)).sum();
    Ok(ReferenceReport {
        pixels_without_probes: without.iter().filter(|&&w| w).count() as f64 / without.len().max(1) as f64,
        reference_share_without_probes: if total > 0.0 { share / total } else { 0.0 },
        path: path.display().to_string(),
        indirect_psnr_db: psnr,
        indirect_relative_mse: rel,
        indirect_mean_ratio: ratio,
        direct_mean_ratio,
    })
}

pub(super) fn run_relight(args: &RelightArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        anyhow::bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let (cpca_settings, intensity) = args.frame.validated()?;
    if args.bounces > 10_000 {
        anyhow::bail!("bounces: must be at most 10000 (0: to convergence), got {}", args.bounces);
    }
    if args.bounce_loop == Some(BounceLoop::Projected) && cpca_settings.is_none() {
        anyhow::bail!("bounce-loop: projected runs in CPCA's projected space, which --cpca=off turns off");
    }
    let position = args.light_position.as_deref().map(|v| point_option("light-position", v)).transpose()?;
    if intensity.is_some() && position.is_none() {
        anyhow::bail!("light-intensity: needs --light-position");
    }
    if let Some(reference) = &args.reference {
        if !reference.is_file() {
            anyhow::bail!("reference: {} is not a file", reference.display());
        }
    }
    let mut plan = OutputPlan::new();
    plan.file(&args.out, "--out").file(&preview_of(&args.out), "the PNG preview beside --out");
    if let Some(json) = &args.json {
        plan.file(json, "--json");
    }
    if cpca_settings.is_some() {
        plan.file(&cpca_path(&args.pre.cache), "the CPCA cache beside --cache");
    }
    if let Some(reference) = &args.reference {
        plan.input(reference, "--reference");
    }
    let (settings, mut plan) = check_common(&args.trace, &args.pre, plan)?;
    let scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    let image = image_settings(&args.trace, &scene, &args.frame)?;
    let threads = args.trace.run.thread_count()?;
    let projected = args.bounce_loop.unwrap_or(BounceLoop::Projected) == BounceLoop::Projected;
    check_memory("the probes relight", &frame_estimate(&settings, cpca_settings.as_ref(), projected, &image, threads))?;
    let pool = tracer::render::thread_pool(threads)?;
    let bar = spinner(args.trace.quiet, "relight");
    let Obtained { precompute: mut pre, from_cache, seconds: s } =
        obtain(&scene, &settings, &args.pre.cache, Stale::Refuse, &pool, &bar)?;
    args.frame.apply(&mut pre, &pool)?;
    let light = position.map(|p| (p, intensity.unwrap_or(glam::Vec3::splat((0.5 * pre.scale as f32).powi(2)))));
    let lit = lit_scene(&scene, args.frame.no_scene_lights, light);
    let accel = tracer::Accel::build(&lit)?;
    bar.set_message("compressing the transport (CPCA)");
    let key = CacheKey::of(&scene, &settings);
    let mut note = |text: String| bar.suspend(|| eprintln!("note: {text}"));
    let (op, cpca) = operator(&pre, cpca_settings, &pool, &args.pre.cache, &key, &mut note)?;
    let most = indirect_bounces(args.trace.size.max_bounces.unwrap_or(scene.max_bounces));
    let (bounces, tolerance) =
        if args.bounces == 0 { (most, defaults::BOUNCE_TOLERANCE) } else { (args.bounces as usize, 0.0) };
    // The bounces' matrix in CPCA's projected space depends on the albedo, not the light:
    // formed once per run, as `lfr compare` does.
    let projected = if args.bounce_loop.unwrap_or(BounceLoop::Projected) == BounceLoop::Projected {
        bar.set_message("forming the projected bounce");
        projected_bounce(&op, &lit, &pre, &pool, &mut |text| note(format!("bounce-loop: {text}")))?
    } else {
        None
    };
    let specular_share = probes::image::specular_share(&lit, &accel, image.width, image.height);
    if let Some(text) = probes::pipeline::specular_warning(specular_share) {
        bar.suspend(|| eprintln!("warning: {text}"));
    }
    bar.set_message("tracing the camera's lookups");
    let (camera, image_operator_s) = image_operator(&lit, &accel, &pre, &image, &pool)?;
    bar.set_message("relighting");
    let frame = FrameSettings { bounces, start: None, tolerance, light_samples: image.light_samples };
    let (out, img, times) = relit_frame(
        &lit,
        &accel,
        &pre,
        &Bounces::of(&op, projected.as_ref().map(|(p, _)| p)),
        &frame,
        &image,
        Some(&camera),
        &pool,
    )?;
    let reference = args.reference.as_deref().map(|p| compare_indirect(p, &img)).transpose()?;
    if args.brute_force_rays > 0 {
        let Some(path) = args.reference.as_deref() else {
            anyhow::bail!("brute-force-rays: needs --reference");
        };
        bar.set_message("brute-force surfel radiosity");
        let t = Instant::now();
        let (e, img) = pool.install(|| -> Result<_> {
            let gathers = probes::gather::Gathers::build(
                &accel,
                &pre.surfels,
                &pre.transports,
                args.brute_force_rays,
                pre.scale as f32,
            );
            let albedo = surfel_albedo(&lit, &pre.surfels);
            let direct = direct_irradiance(&lit, &accel, &pre.surfels, image.light_samples, image.seed, pre.scale as f32)?;
            let e = gathers.indirect(&albedo, &direct, bounces, tolerance);
            let sender: Vec<glam::Vec3> =
                albedo.iter().zip(&direct).map(|(a, d)| *a * *d / std::f32::consts::PI).collect();
            let (via, exact) = probes::gather::one_bounce_split(
                &lit,
                &accel,
                &pre.surfels,
                &pre.transports,
                &sender,
                64,
                17,
                64,
                pre.scale as f32,
            );
            bar.suspend(|| println!("one bounce: senders through the lookup / direct light exact at each hit {}", via / exact));
            let at_pixels = probes::gather::pixel_gather(
                &lit,
                &accel,
                &pre.surfels,
                &sender,
                (image.width, image.height),
                256,
                pre.scale as f32,
            );
            let [via, exact, shading, valid] = probes::gather::pixel_gather_split(
                &lit,
                &accel,
                &pre.surfels,
                &pre.transports,
                &sender,
                (image.width, image.height),
                64,
                image.light_samples.min(4),
                pre.scale as f32,
            );
            bar.suspend(|| {
                println!(
                    "one bounce at the pixels (64 rays): senders through the lookup / direct light exact at each secondary hit {:.4} {:.4} {:.4}; exact about the shading normal / about the geometric {:.4} {:.4} {:.4}",
                    via.x / exact.x,
                    via.y / exact.y,
                    via.z / exact.z,
                    shading.x / exact.x,
                    shading.y / exact.y,
                    shading.z / exact.z
                );
                println!(
                    "            senders through the lookup with hidden senders dropped beside the others / exact {:.4} {:.4} {:.4}",
                    valid.x / exact.x,
                    valid.y / exact.y,
                    valid.z / exact.z
                )
            });
            let reference = read_indirect(path, image.width, image.height)?;
            let (a, b): (f64, f64) = at_pixels
                .iter()
                .zip(&reference.pixels)
                .fold((0.0, 0.0), |(a, b), (p, r)| (a + p.x as f64, b + r[0] as f64));
            let from_receivers: f64 = img.indirect.iter().map(|p| p.x as f64).sum();
            bar.suspend(|| {
                println!(
                    "one bounce at the pixels with the direct light exact at each secondary hit / reference (R): {:.4}",
                    exact.x / b
                )
            });
            bar.suspend(|| {
                println!(
                    "one bounce gathered at the pixels (256 rays, senders' direct radiance) / reference (R): {:.4}; the probes' image / it {:.4}",
                    a / b,
                    from_receivers / a
                )
            });
            let img = render_image(&lit, &accel, &pre, &e, &image)?;
            Ok((e, img))
        })?;
        let r = compare_indirect(path, &img)?;
        let probes_mean: f64 = out.irradiance.iter().map(|v| v.element_sum() as f64).sum();
        let brute_mean: f64 = e.iter().map(|v| v.element_sum() as f64).sum();
        bar.suspend(|| {
            println!(
                "brute force {} rays per receiver, {:.1} s: PSNR {:.2} dB, mean ratio {:.3} {:.3} {:.3}; probes' receiver irradiance / brute force's {:.3}",
                args.brute_force_rays,
                t.elapsed().as_secs_f64(),
                r.indirect_psnr_db,
                r.indirect_mean_ratio[0],
                r.indirect_mean_ratio[1],
                r.indirect_mean_ratio[2],
                probes_mean / brute_mean.max(1e-30)
            )
        });
    }
    bar.set_message("writing the image");
    let transport = if cpca.is_some() { "cpca" } else { "dense" };
    write_image(&args.out, &img, description(&settings, &scene, transport, position))?;
    bar.finish_and_clear();
    let n = img.indirect.len().max(1) as f32;
    let report = RelightReport {
        precompute: precompute_report(&scene, &args.pre.cache, &pre, from_cache, s),
        cpca,
        width: img.width,
        height: img.height,
        light_position: position.map(|p| p.to_array()),
        light_intensity: light.map(|l| l.1.to_array()),
        image_operator_s,
        image_operator_bytes: camera.bytes(),
        bounce_loop: if projected.is_some() { "projected" } else { "full" },
        projected: projected.as_ref().map(|(_, report)| *report),
        times,
        clamped_channels: out.clamped,
        lookup_holes: img.lookups.holes,
        lookup_nearest: img.lookups.nearest,
        misses: img.misses,
        mean_indirect: (img.indirect.iter().fold(glam::Vec3::ZERO, |a, v| a + *v) / n).to_array(),
        specular_share,
        reference,
    };
    print_precompute(&report.precompute);
    if let Some(c) = &report.cpca {
        println!(
            "cpca        {} clusters, {:.1} coefficients per receiver on average, largest cluster error {:.2e} (tolerance {}), {} B per receiver{} {} {:.2} s",
            c.clusters,
            c.mean_coefficients,
            c.max_cluster_error,
            c.tolerance,
            c.bytes_per_receiver.round(),
            if c.fp16 { " (fp16)" } else { "" },
            if c.from_cache { "read from the cache in" } else { "compressed in" },
            c.compress_s
        );
    }
    if let Some(p) = &report.projected {
        println!(
            "bounces     after the first in CPCA's projected space: R = {}, M formed in {:.2} s ({:.1} MB; once per run)",
            p.size,
            p.build_s,
            p.bytes as f64 / 1e6
        );
    }
    let t = &report.times;
    println!(
        "camera      primary rays and their lookups kept in {:.4} s ({:.1} MB; once per camera)",
        report.image_operator_s,
        report.image_operator_bytes as f64 / 1e6
    );
    println!(
        "frame       {:.4} s: direct light at the senders {:.4} s, {} bounces {:.4} s ({} channels clamped); image {}x{} {:.4} s ({} lookup holes, {} misses)",
        t.frame_s,
        t.direct_s,
        t.iterations,
        t.bounces_s,
        report.clamped_channels,
        img.width,
        img.height,
        t.image_s,
        report.lookup_holes,
        report.misses
    );
    print_split(t);
    if let Some(r) = &report.reference {
        println!(
            "reference   indirect layer against {}: PSNR {:.2} dB, relative MSE {:.4e}, mean ratio {:.3} {:.3} {:.3}",
            r.path,
            r.indirect_psnr_db,
            r.indirect_relative_mse,
            r.indirect_mean_ratio[0],
            r.indirect_mean_ratio[1],
            r.indirect_mean_ratio[2]
        );
        println!(
            "            pixels without a covering probe (hidden receivers) {:.2} %, holding {:.2} % of the reference's indirect light",
            100.0 * r.pixels_without_probes,
            100.0 * r.reference_share_without_probes
        );
        if let Some([dr, dg, db]) = r.direct_mean_ratio {
            println!("            direct layer mean ratio {dr:.3} {dg:.3} {db:.3}");
        }
    }
    println!("wrote {} and {}", args.out.display(), preview_of(&args.out).display());
    if let Some(json) = &args.json {
        write_json(json, &report)?;
    }
    Ok(())
}
