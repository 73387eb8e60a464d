//! Image output: one multi-layer linear EXR per render and a tone-mapped PNG preview.
//!
//! Files are written to a temporary name beside the target and renamed into place, so a
//! failed or interrupted write never leaves a half-written image under the final name.

use std::path::{Path, PathBuf};

use exr::prelude::*;
use glam::Vec3;

use crate::error::RenderError;
use crate::render::RenderedImage;

/// A named group of channels, e.g. layer `direct` with channels R, G, B → `direct.R`, ...
pub struct Layer<'a> {
    /// Prefix; empty for the beauty channels `R`, `G`, `B`.
    pub name: &'a str,
    pub channels: Vec<(&'a str, Vec<f32>)>,
}

fn rgb_channels(data: &[Vec3]) -> Vec<(&'static str, Vec<f32>)> {
    vec![
        ("R", data.iter().map(|v| v.x).collect()),
        ("G", data.iter().map(|v| v.y).collect()),
        ("B", data.iter().map(|v| v.z).collect()),
    ]
}

fn xyz_channels(data: &[Vec3]) -> Vec<(&'static str, Vec<f32>)> {
    vec![
        ("X", data.iter().map(|v| v.x).collect()),
        ("Y", data.iter().map(|v| v.y).collect()),
        ("Z", data.iter().map(|v| v.z).collect()),
    ]
}

/// The layers of a rendered frame, in the order documented in the README.
pub fn frame_layers(frame: &RenderedImage) -> Vec<Layer<'static>> {
    vec![
        Layer { name: "", channels: rgb_channels(&frame.beauty) },
        Layer { name: "direct", channels: rgb_channels(&frame.direct) },
        Layer { name: "indirect", channels: rgb_channels(&frame.indirect) },
        Layer { name: "albedo", channels: rgb_channels(&frame.albedo) },
        Layer { name: "normal", channels: xyz_channels(&frame.normal) },
        Layer { name: "depth", channels: vec![("Z", frame.depth.clone())] },
        Layer { name: "position", channels: xyz_channels(&frame.position) },
        Layer { name: "variance", channels: rgb_channels(&frame.variance) },
    ]
}

/// A sibling path for writing before the rename.
fn temporary_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(format!(".{}.tmp", std::process::id()));
    path.with_file_name(name)
}

/// The reason of a refused output, without the path `output_error` adds again.
fn refusal(error: &sampleio::SampleError) -> String {
    match error {
        sampleio::SampleError::RefusedOutput { reason, .. } => format!("refusing to write the output here: {reason}"),
        other => other.to_string(),
    }
}

fn output_error(path: &Path, message: impl std::fmt::Display) -> RenderError {
    RenderError::Output { path: path.to_path_buf(), message: message.to_string() }
}

/// Writes `contents` through `write` to a temporary file and renames it onto `path`; refuses a
/// `path` that is not a regular file (`sampleio::check_output_target`: a device node or a
/// symbolic link would be replaced).
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&Path) -> std::result::Result<(), String>,
) -> std::result::Result<(), RenderError> {
    sampleio::check_output_target(path, &[]).map_err(|e| output_error(path, refusal(&e)))?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| output_error(parent, format!("cannot create directory: {e}")))?;
    }
    let tmp = temporary_path(path);
    sampleio::interrupt::remove_stale_temporaries(path);
    let _registration = sampleio::interrupt::remove_on_interrupt(&tmp);
    match write(&tmp) {
        Ok(()) => std::fs::rename(&tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            output_error(path, format!("cannot rename into place: {e}"))
        }),
        Err(message) => {
            let _ = std::fs::remove_file(&tmp);
            Err(output_error(path, message))
        }
    }
}

/// Writes a single-part EXR whose channels are named `layer.channel` (or just `channel` for
/// the unnamed layer), 32-bit float, lossless ZIP compression.
pub fn write_exr(path: &Path, width: u32, height: u32, layers: &[Layer]) -> std::result::Result<(), RenderError> {
    write_exr_with_attributes(path, width, height, layers, &[])
}

/// [`write_exr`] with text attributes (name, value) in the header, e.g. how the image was made;
/// [`read_exr_attributes`] reads them back. Names and values must be Latin-1 text.
pub fn write_exr_with_attributes(
    path: &Path,
    width: u32,
    height: u32,
    layers: &[Layer],
    attributes: &[(&str, String)],
) -> std::result::Result<(), RenderError> {
    let n = width as usize * height as usize;
    let mut channels = SmallVec::<[AnyChannel<FlatSamples>; 4]>::new();
    for layer in layers {
        for (channel, data) in &layer.channels {
            if data.len() != n {
                return Err(output_error(
                    path,
                    format!("layer {}.{} has {} values for {n} pixels", layer.name, channel, data.len()),
                ));
            }
            let name = if layer.name.is_empty() { channel.to_string() } else { format!("{}.{}", layer.name, channel) };
            channels.push(AnyChannel::new(name.as_str(), FlatSamples::F32(data.clone())));
        }
    }
    let mut layer_attributes = LayerAttributes::default();
    for (name, value) in attributes {
        let text = |t: &str| {
            Text::new_or_none(t).ok_or_else(|| output_error(path, format!("attribute {name} is not Latin-1 text")))
        };
        layer_attributes.other.insert(text(name)?, AttributeValue::Text(text(value)?));
    }
    let image = Image::from_layer(exr::prelude::Layer::new(
        (width as usize, height as usize),
        layer_attributes,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(channels),
    ));
    write_atomically(path, |tmp| image.write().to_file(tmp).map_err(|e| e.to_string()))
}

/// Every channel of an image: (width, height, [(name, values)]).
pub type Channels = (u32, u32, Vec<(String, Vec<f32>)>);

/// Reads every channel of a single-part float EXR.
pub fn read_exr(path: &Path) -> std::result::Result<Channels, RenderError> {
    let image = read_all_flat_layers_from_file(path).map_err(|e| output_error(path, e))?;
    let layer = image.layer_data.first().ok_or_else(|| output_error(path, "no layers"))?;
    let size = layer.size;
    let channels =
        layer.channel_data.list.iter().map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect())).collect();
    Ok((size.0 as u32, size.1 as u32, channels))
}

/// The text attributes of a single-part EXR's header (those [`write_exr_with_attributes`] wrote,
/// and any other text attribute).
pub fn read_exr_attributes(path: &Path) -> std::result::Result<Vec<(String, String)>, RenderError> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| output_error(path, e))?;
    let header = meta.headers.first().ok_or_else(|| output_error(path, "no header"))?;
    let mut found: Vec<(String, String)> = header
        .own_attributes
        .other
        .iter()
        .chain(&header.shared_attributes.other)
        .filter_map(|(name, value)| match value {
            AttributeValue::Text(text) => Some((name.to_string(), text.to_string())),
            _ => None,
        })
        .collect();
    found.sort();
    Ok(found)
}

/// Linear to sRGB-encoded 8-bit after exposure and clamping.
pub fn tonemap_srgb8(value: f32, exposure: f32) -> u8 {
    let v = value * exposure;
    let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
    let encoded = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (encoded * 255.0 + 0.5) as u8
}

/// Writes a PNG preview: exposure, clamp to [0, 1], sRGB encoding.
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[Vec3],
    exposure: f32,
) -> std::result::Result<(), RenderError> {
    let mut bytes = Vec::with_capacity(pixels.len() * 3);
    for p in pixels {
        bytes.extend_from_slice(&[
            tonemap_srgb8(p.x, exposure),
            tonemap_srgb8(p.y, exposure),
            tonemap_srgb8(p.z, exposure),
        ]);
    }
    write_atomically(path, |tmp| {
        image::save_buffer_with_format(
            tmp,
            &bytes,
            width,
            height,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| e.to_string())
    })
}

/// Writes the frame's EXR and, beside it, the PNG preview (same name, `.png`).
pub fn write_frame(path: &Path, frame: &RenderedImage) -> std::result::Result<PathBuf, RenderError> {
    write_exr(path, frame.width, frame.height, &frame_layers(frame))?;
    let preview = path.with_extension("png");
    write_png(&preview, frame.width, frame.height, &frame.beauty, 1.0)?;
    Ok(preview)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_round_trips_named_layers() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.exr");
        let layers = vec![
            Layer { name: "", channels: vec![("R", vec![1.0, 2.0]), ("G", vec![3.0, 4.0]), ("B", vec![5.0, 6.0])] },
            Layer { name: "depth", channels: vec![("Z", vec![7.5, f32::INFINITY])] },
        ];
        write_exr(&path, 2, 1, &layers).unwrap();
        let (w, h, channels) = read_exr(&path).unwrap();
        assert_eq!((w, h), (2, 1));
        let get = |name: &str| channels.iter().find(|(n, _)| n == name).unwrap().1.clone();
        assert_eq!(get("R"), vec![1.0, 2.0]);
        assert_eq!(get("depth.Z"), vec![7.5, f32::INFINITY]);
        // No temporary file is left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn text_attributes_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.exr");
        let layers = vec![Layer { name: "", channels: vec![("R", vec![1.0]), ("G", vec![2.0]), ("B", vec![3.0])] }];
        let attributes = [("lfr.render", r#"{"spp": 4}"#.to_string()), ("lfr.note", "x".to_string())];
        write_exr_with_attributes(&path, 1, 1, &layers, &attributes).unwrap();
        let read = read_exr_attributes(&path).unwrap();
        assert!(read.contains(&("lfr.render".into(), r#"{"spp": 4}"#.into())), "{read:?}");
        assert!(read.contains(&("lfr.note".into(), "x".into())), "{read:?}");
        // A plain image has none of ours.
        write_exr(&path, 1, 1, &layers).unwrap();
        assert!(read_exr_attributes(&path).unwrap().iter().all(|(n, _)| !n.starts_with("lfr.")));
        // Text EXR cannot hold is refused, and nothing is written.
        let bad = dir.path().join("b.exr");
        assert!(write_exr_with_attributes(&bad, 1, 1, &layers, &[("lfr.x", "日本".into())]).is_err());
        assert!(!bad.exists());
    }

    #[test]
    fn failed_write_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("y.exr");
        let layers = vec![Layer { name: "", channels: vec![("R", vec![1.0])] }];
        assert!(write_exr(&path, 2, 2, &layers).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn tonemap_is_monotone_and_clamps_non_finite() {
        assert_eq!(tonemap_srgb8(0.0, 1.0), 0);
        assert_eq!(tonemap_srgb8(1.0, 1.0), 255);
        assert_eq!(tonemap_srgb8(f32::NAN, 1.0), 0);
        assert_eq!(tonemap_srgb8(1e30, 1.0), 255);
        assert!(tonemap_srgb8(0.2, 1.0) < tonemap_srgb8(0.21, 1.0));
    }
}
