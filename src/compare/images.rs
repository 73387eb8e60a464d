//! The images a comparison writes: each result as a linear EXR (one named layer, the effect's)
//! and a PNG preview through the comparison's tone map, and its false-colour error map.

use std::path::Path;

use anyhow::{Context, Result};
use recon::metrics::{error_map, ToneMap};
use recon::Image;
use tracer::output::{write_atomically, write_exr, Layer};

use crate::convert::rgb_channels;

use super::plot;

/// Error maps show the per-pixel RMS difference of tone-mapped values on [0, ERROR_MAP_MAX].
pub const ERROR_MAP_MAX: f32 = 0.25;

/// Writes `image` as `stem.exr` (layer `layer`) and `stem.png` in `dir`.
pub fn write_image(dir: &Path, stem: &str, layer: &str, image: &Image, tone: &ToneMap) -> Result<()> {
    let exr = dir.join(format!("{stem}.exr"));
    write_exr(&exr, image.width, image.height, &[Layer { name: layer, channels: rgb_channels(image) }])
        .with_context(|| format!("writing {}", exr.display()))?;
    let png = dir.join(format!("{stem}.png"));
    let bytes: Vec<u8> =
        image.pixels.iter().flat_map(|p| p.map(|v| (tone.apply(v) * 255.0 + 0.5).clamp(0.0, 255.0) as u8)).collect();
    write_atomically(&png, |tmp| {
        image::save_buffer_with_format(
            tmp,
            &bytes,
            image.width,
            image.height,
            image::ColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| e.to_string())
    })
    .with_context(|| format!("writing {}", png.display()))?;
    Ok(())
}

/// Writes the false-colour error map of `image` against `reference` as `stem.png`.
pub fn write_error_map(dir: &Path, stem: &str, reference: &Image, image: &Image, tone: &ToneMap) -> Result<()> {
    let errors = error_map(reference, image, tone)?;
    plot::false_colour(&errors, image.width, image.height, ERROR_MAP_MAX, &dir.join(format!("{stem}.png")))
}
