//! Textures: 8-bit RGBA texels, sRGB or linear, sampled bilinearly with wrapping and an
//! optional `KHR_texture_transform`.

use std::path::Path;

use glam::{Mat3, Vec2, Vec3, Vec4};

use crate::error::SceneError;

/// A reference from a material to a texture, with its UV transform.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into `Scene::textures`.
    pub index: u32,
    /// UV transform (`KHR_texture_transform`): uv' = M · (u, v, 1).
    pub transform: Option<Mat3>,
}

impl TextureRef {
    pub fn new(index: u32) -> Self {
        TextureRef { index, transform: None }
    }

    pub fn apply(&self, uv: Vec2) -> Vec2 {
        match &self.transform {
            None => uv,
            Some(m) => {
                let p = *m * Vec3::new(uv.x, uv.y, 1.0);
                Vec2::new(p.x, p.y)
            }
        }
    }
}

/// An RGBA8 image. `srgb` says whether RGB is sRGB-encoded (colour data) or linear
/// (roughness/metallic data); alpha is always linear.
#[derive(Clone, Debug)]
pub struct Texture {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub srgb: bool,
    pub texels: Vec<[u8; 4]>,
}

fn srgb_table() -> &'static [f32; 256] {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = [0.0f32; 256];
        for (i, v) in t.iter_mut().enumerate() {
            let c = i as f32 / 255.0;
            *v = if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) };
        }
        t
    })
}

impl Texture {
    /// Loads a PNG or JPEG file. A missing or unreadable file is an error naming it.
    pub fn load(path: &Path, srgb: bool, referenced_from: &Path, field: &str) -> Result<Texture, SceneError> {
        let img = image::open(path).map_err(|e| {
            SceneError::new(referenced_from, field, format!("cannot read texture {}: {e}", path.display()))
        })?;
        let rgba = img.to_rgba8();
        Ok(Texture::from_rgba8(path.display().to_string(), rgba.width(), rgba.height(), srgb, rgba.into_raw()))
    }

    pub fn from_rgba8(name: String, width: u32, height: u32, srgb: bool, raw: Vec<u8>) -> Texture {
        let texels = raw.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        Texture { name, width, height, srgb, texels }
    }

    /// A 1x1 texture of one colour (tests, fallbacks).
    pub fn constant(rgba: [u8; 4], srgb: bool) -> Texture {
        Texture { name: "constant".into(), width: 1, height: 1, srgb, texels: vec![rgba] }
    }

    /// Texel (x, y) with 0 <= x < width and 0 <= y < height, decoded to linear.
    #[inline]
    fn texel(&self, x: usize, y: usize) -> Vec4 {
        let t = self.texels[y * self.width as usize + x];
        let a = t[3] as f32 / 255.0;
        if self.srgb {
            let lut = srgb_table();
            Vec4::new(lut[t[0] as usize], lut[t[1] as usize], lut[t[2] as usize], a)
        } else {
            Vec4::new(t[0] as f32 / 255.0, t[1] as f32 / 255.0, t[2] as f32 / 255.0, a)
        }
    }

    /// Bilinear lookup with repeat wrapping; (0,0) is the top-left corner of the image as
    /// stored (glTF and, after the loader flips v, OBJ conventions).
    pub fn sample(&self, uv: Vec2) -> Vec4 {
        if self.texels.is_empty() {
            return Vec4::ONE;
        }
        let u = if uv.x.is_finite() { uv.x } else { 0.0 };
        let v = if uv.y.is_finite() { uv.y } else { 0.0 };
        // Keep coordinates in a range where f32 keeps sub-texel precision.
        let u = u - u.floor();
        let v = v - v.floor();
        let (w, h) = (self.width as usize, self.height as usize);
        let x = u * w as f32 - 0.5;
        let y = v * h as f32 - 0.5;
        let fx = x - x.floor();
        let fy = y - y.floor();
        // x.floor() is in [-1, w - 1] (u < 1 up to rounding): wrap without a division.
        let wrap = |i: f32, n: usize| -> usize {
            let i = i as isize;
            if i < 0 {
                n - 1
            } else if i as usize >= n {
                0
            } else {
                i as usize
            }
        };
        let x0 = wrap(x.floor(), w);
        let y0 = wrap(y.floor(), h);
        let x1 = if x0 + 1 == w { 0 } else { x0 + 1 };
        let y1 = if y0 + 1 == h { 0 } else { y0 + 1 };
        let a = self.texel(x0, y0).lerp(self.texel(x1, y0), fx);
        let b = self.texel(x0, y1).lerp(self.texel(x1, y1), fx);
        a.lerp(b, fy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_decoding_matches_the_standard_curve() {
        let t = Texture::constant([128, 255, 0, 255], true);
        let c = t.sample(Vec2::new(0.3, 0.7));
        // sRGB 128/255 is 0.2158605 linear.
        assert!((c.x - 0.215_860_5).abs() < 1e-5);
        assert_eq!(c.y, 1.0);
        assert_eq!(c.z, 0.0);
    }

    /// Straightforward bilinear lookup with `rem_euclid` wrapping: the reference for `sample`.
    fn reference_sample(t: &Texture, uv: Vec2) -> Vec4 {
        let x = (uv.x - uv.x.floor()) * t.width as f32 - 0.5;
        let y = (uv.y - uv.y.floor()) * t.height as f32 - 0.5;
        let texel = |i: i64, j: i64| {
            let i = i.rem_euclid(t.width as i64) as usize;
            let j = j.rem_euclid(t.height as i64) as usize;
            t.texel(i, j)
        };
        let (x0, y0) = (x.floor() as i64, y.floor() as i64);
        let (fx, fy) = (x - x.floor(), y - y.floor());
        let a = texel(x0, y0).lerp(texel(x0 + 1, y0), fx);
        let b = texel(x0, y0 + 1).lerp(texel(x0 + 1, y0 + 1), fx);
        a.lerp(b, fy)
    }

    #[test]
    fn fast_wrapping_matches_the_reference_lookup() {
        let raw: Vec<u8> = (0..3 * 2 * 4).map(|i| (i * 37 % 256) as u8).collect();
        let t = Texture::from_rgba8("t".into(), 3, 2, true, raw);
        for i in -50..50 {
            for j in -20..20 {
                let uv = Vec2::new(i as f32 * 0.0731, j as f32 * 0.1173);
                let (a, b) = (t.sample(uv), reference_sample(&t, uv));
                assert!((a - b).abs().max_element() < 1e-5, "{uv}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn bilinear_interpolates_between_texel_centres_and_wraps() {
        let t = Texture::from_rgba8("ramp".into(), 2, 1, false, vec![0, 0, 0, 255, 255, 0, 0, 255]);
        // Texel centres at u = 0.25 and 0.75.
        assert!((t.sample(Vec2::new(0.25, 0.5)).x - 0.0).abs() < 1e-6);
        assert!((t.sample(Vec2::new(0.75, 0.5)).x - 1.0).abs() < 1e-6);
        assert!((t.sample(Vec2::new(0.5, 0.5)).x - 0.5).abs() < 1e-6);
        // u = 0 sits halfway between the last texel (wrapped) and the first.
        assert!((t.sample(Vec2::new(0.0, 0.5)).x - 0.5).abs() < 1e-6);
        assert!((t.sample(Vec2::new(1.25, 0.5)).x - 0.0).abs() < 1e-6);
        assert!(t.sample(Vec2::new(f32::NAN, 0.5)).is_finite());
    }
}
