//! Conversions between the tracer's types and the reconstructions': the one place the harness
//! and the subcommands turn tracer output into `recon` input and `recon` images into EXR
//! layers (`recon` never sees the tracer).

use glam::Vec3;
use recon::method::GuideInput;
use recon::Image;

/// A tracer buffer of per-pixel vectors as a `recon` image.
pub fn image_from_vec3(width: u32, height: u32, values: &[Vec3]) -> Image {
    Image::from_pixels(width, height, values.iter().map(|v| v.to_array()).collect())
}

/// The tracer's guide buffers as the reconstructions' `GuideInput`.
pub fn guide_input(buffers: &tracer::samples::guide::GuideBuffers) -> GuideInput {
    let (width, height) = (buffers.width, buffers.height);
    let arrays = |values: &[Vec3]| values.iter().map(|v| v.to_array()).collect::<Vec<_>>();
    GuideInput {
        guide: recon::guide::GuideBuffers {
            width,
            height,
            normal: arrays(&buffers.normal),
            depth: buffers.depth.clone(),
            position: arrays(&buffers.position),
            secondary_normal: Some(arrays(&buffers.secondary_normal)),
        },
        albedo: image_from_vec3(width, height, &buffers.albedo),
        indirect: image_from_vec3(width, height, &buffers.indirect),
        direct: image_from_vec3(width, height, &buffers.direct),
        eye_rays: recon::guide::EyeRays {
            per_pixel: buffers.eye_rays_per_pixel,
            rays: buffers
                .eye_rays
                .iter()
                .map(|ray| recon::guide::EyeRay {
                    film: ray.film.to_array(),
                    normal: ray.normal.to_array(),
                    depth: ray.depth,
                    albedo: ray.albedo.to_array(),
                    direct: ray.direct.to_array(),
                })
                .collect(),
        },
    }
}

/// The image's R, G and B channels, for an EXR layer.
pub fn rgb_channels(image: &Image) -> Vec<(&'static str, Vec<f32>)> {
    ["R", "G", "B"].iter().enumerate().map(|(c, name)| (*name, image.pixels.iter().map(|p| p[c]).collect())).collect()
}
