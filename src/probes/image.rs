//! The relit frame as `lfr probes relight` and `animate` write it: a multi-layer EXR with the
//! settings in its header, a PNG preview, the image's settings from the flags, and the frame's
//! split as the paper's Table 2.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use probes::image::{ImageSettings, ProbeImage};
use probes::pipeline::FrameTimes;
use probes::precompute::PrecomputeSettings;
use tracer::output::{write_exr_with_attributes, write_png, Layer};

use super::options::FrameOptions;
use crate::common::TraceArgs;

/// Writes the image's layers and its PNG preview.
pub(super) fn write_image(path: &Path, img: &ProbeImage, description: String) -> Result<PathBuf> {
    let rgb = |v: &[glam::Vec3]| -> Vec<(&'static str, Vec<f32>)> {
        vec![
            ("R", v.iter().map(|p| p.x).collect()),
            ("G", v.iter().map(|p| p.y).collect()),
            ("B", v.iter().map(|p| p.z).collect()),
        ]
    };
    let layers = vec![
        Layer { name: "", channels: rgb(&img.beauty) },
        Layer { name: "direct", channels: rgb(&img.direct) },
        Layer { name: "indirect", channels: rgb(&img.indirect) },
        Layer { name: "irradiance", channels: rgb(&img.irradiance) },
        Layer { name: "albedo", channels: rgb(&img.albedo) },
        Layer { name: "unseen", channels: vec![("Y", img.unseen.clone())] },
        Layer { name: "probes", channels: vec![("Y", img.probes.clone())] },
        Layer { name: "hole", channels: vec![("Y", img.hole.clone())] },
    ];
    write_exr_with_attributes(path, img.width, img.height, &layers, &[("lfr.probes", description)])
        .with_context(|| format!("writing {}", path.display()))?;
    let preview = path.with_extension("png");
    write_png(&preview, img.width, img.height, &img.beauty, 1.0)
        .with_context(|| format!("writing {}", preview.display()))?;
    Ok(preview)
}

pub(super) fn description(
    settings: &PrecomputeSettings,
    scene: &tracer::Scene,
    transport: &str,
    light: Option<glam::Vec3>,
) -> String {
    format!(
        "scene={} probes={} receivers={} overlap={} order={} directions={} relight_rays={} seed={} transport={} light={}",
        scene.source.display(),
        settings.placement.probes,
        settings.surfels.budget,
        settings.placement.overlap,
        settings.transport.order,
        settings.transport.directions,
        settings.relight_rays,
        settings.surfels.seed,
        transport,
        light.map_or("scene".to_string(), |p| format!("point {},{},{}", p.x, p.y, p.z))
    )
    .chars()
    .filter(|c| (*c as u32) < 256)
    .collect()
}

pub(super) fn image_settings(trace: &TraceArgs, scene: &tracer::Scene, frame: &FrameOptions) -> Result<ImageSettings> {
    let image = ImageSettings {
        width: trace.size.width.unwrap_or(scene.width),
        height: trace.size.height.unwrap_or(scene.height),
        light_samples: frame.light_samples,
        pixel_samples: frame.pixel_samples,
        seed: trace.seed(),
    };
    image.validate()?;
    Ok(image)
}

/// The frame split as the paper's Table 2.
pub(super) fn print_split(t: &FrameTimes) {
    println!(
        "split       scene relight {:.4} s | probe relight {:.4} s | cluster projection {:.4} s | receiver irradiance {:.4} s | near field {:.4} s | projected bounces {:.4} s ({} bounces) | image {:.4} s | frame with image {:.4} s",
        t.direct_s,
        t.probe_relight_s,
        t.cluster_projection_s,
        t.receiver_irradiance_s,
        t.near_field_s,
        t.projected_bounces_s,
        t.iterations,
        t.image_s,
        t.frame_s + t.image_s
    );
}
