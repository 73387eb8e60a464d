//! Textures: 8-bit RGBA texels, sRGB or linear, sampled bilinearly with wrapping and an
//! optional `KHR_texture_transform`, with a mip-map chain for filtered (trilinear) lookups.
//!
//! Each coarser level halves both sides (down to 1) and averages the box of finer texels that
//! each coarse texel covers, in linear space for sRGB colour (averaging encoded values would
//! darken edges), then re-encodes to 8 bits. Odd sides partition the finer texels into boxes of
//! two or three, so every texel of a level counts towards the next.

use std::path::Path;

use glam::{Mat3, Vec2, Vec3, Vec4};

use crate::error::SceneError;

/// How a texture coordinate outside [0, 1] maps into the image along one axis (glTF sampler
/// `wrapS`/`wrapT`). Applied to the coordinate before the lookup, which itself repeats: within
/// half a texel of a clamped or mirrored edge, bilinear filtering still blends in the opposite
/// edge's texels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Wrap {
    #[default]
    Repeat,
    ClampToEdge,
    MirroredRepeat,
}

impl Wrap {
    /// The coordinate `x` mapped as this mode says (unchanged for `Repeat`: the lookup repeats).
    #[inline]
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Wrap::Repeat => x,
            Wrap::ClampToEdge => x.clamp(0.0, 1.0),
            Wrap::MirroredRepeat => {
                let m = x.rem_euclid(2.0);
                if m > 1.0 {
                    2.0 - m
                } else {
                    m
                }
            }
        }
    }
}

/// A reference from a material to a texture, with its UV transform.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into `Scene::textures`.
    pub index: u32,
    /// UV transform (`KHR_texture_transform`): uv' = M · (u, v, 1).
    transform: Option<Mat3>,
    /// ½ log2 of the transform's area scale, computed once (see [`TextureRef::half_log2_scale`]).
    half_log2_scale: f32,
    /// Wrap modes along u and v, applied after the transform.
    wrap: [Wrap; 2],
}

impl TextureRef {
    pub fn new(index: u32) -> Self {
        TextureRef { index, transform: None, half_log2_scale: 0.0, wrap: [Wrap::Repeat; 2] }
    }

    /// A reference through the uv transform `transform` (`None`: uv as stored).
    pub fn with_transform(index: u32, transform: Option<Mat3>) -> Self {
        let half_log2_scale = match &transform {
            None => 0.0,
            Some(m) => {
                let area = (m.x_axis.x * m.y_axis.y - m.y_axis.x * m.x_axis.y).abs();
                if area > 0.0 && area.is_finite() {
                    0.5 * area.log2()
                } else {
                    0.0
                }
            }
        };
        TextureRef { index, transform, half_log2_scale, wrap: [Wrap::Repeat; 2] }
    }

    /// This reference with the wrap modes `wrap` along u and v.
    pub fn with_wrap(mut self, wrap: [Wrap; 2]) -> Self {
        self.wrap = wrap;
        self
    }

    pub fn wrap(&self) -> [Wrap; 2] {
        self.wrap
    }

    /// The uv transform, if any.
    pub fn transform(&self) -> Option<&Mat3> {
        self.transform.as_ref()
    }

    /// log2 of how much the transform scales lengths in uv (½ log2 of its area scale), added
    /// to a lookup's level of detail.
    #[inline]
    pub fn half_log2_scale(&self) -> f32 {
        self.half_log2_scale
    }

    pub fn apply(&self, uv: Vec2) -> Vec2 {
        let uv = match &self.transform {
            None => uv,
            Some(m) => {
                let p = *m * Vec3::new(uv.x, uv.y, 1.0);
                Vec2::new(p.x, p.y)
            }
        };
        match self.wrap {
            [Wrap::Repeat, Wrap::Repeat] => uv,
            [u, v] => Vec2::new(u.apply(uv.x), v.apply(uv.y)),
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
    /// The finest level, row by row from the top.
    pub texels: Vec<[u8; 4]>,
    /// Levels 1, 2, … down to 1 × 1 (empty for a 1 × 1 texture).
    coarser: Vec<MipLevel>,
}

#[derive(Clone, Debug)]
struct MipLevel {
    width: u32,
    height: u32,
    texels: Vec<[u8; 4]>,
}

/// One level's texels, borrowed.
#[derive(Clone, Copy)]
struct Level<'a> {
    width: usize,
    height: usize,
    texels: &'a [[u8; 4]],
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

/// Linear value in [0, 1] to the nearest 8-bit sRGB code.
fn encode_srgb(linear: f32) -> u8 {
    let c = linear.clamp(0.0, 1.0);
    let encoded = if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
    (encoded * 255.0).round().clamp(0.0, 255.0) as u8
}

/// `code / 255` for every 8-bit code, so that decoding looks values up instead of dividing.
const UNORM_TABLE: [f32; 256] = {
    let mut table = [0.0f32; 256];
    let mut code = 0;
    while code < 256 {
        table[code] = code as f32 / 255.0;
        code += 1;
    }
    table
};

/// Decodes one 8-bit texel to linear RGBA.
#[inline]
fn decode(texel: [u8; 4], srgb: bool) -> Vec4 {
    decode_with(texel, if srgb { srgb_table() } else { &UNORM_TABLE })
}

/// Decodes one 8-bit texel with `rgb_table` for the colour channels (alpha is always linear).
#[inline]
fn decode_with(texel: [u8; 4], rgb_table: &[f32; 256]) -> Vec4 {
    Vec4::new(
        rgb_table[texel[0] as usize],
        rgb_table[texel[1] as usize],
        rgb_table[texel[2] as usize],
        UNORM_TABLE[texel[3] as usize],
    )
}

/// `x.floor()` without a libm call (the baseline x86-64 target has no rounding instruction):
/// exact for every finite value, since a float of magnitude 2²³ or more is already an integer.
#[inline]
fn floor_exact(x: f32) -> f32 {
    if x.abs() < 8_388_608.0 {
        let truncated = x as i32 as f32;
        if truncated > x {
            truncated - 1.0
        } else {
            truncated
        }
    } else {
        x
    }
}

fn encode(linear: Vec4, srgb: bool) -> [u8; 4] {
    let unorm = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    if srgb {
        [encode_srgb(linear.x), encode_srgb(linear.y), encode_srgb(linear.z), unorm(linear.w)]
    } else {
        [unorm(linear.x), unorm(linear.y), unorm(linear.z), unorm(linear.w)]
    }
}

/// The box of finer indices [start, end) that coarse index `i` of `coarse` covers out of `fine`.
#[inline]
fn covered(i: usize, coarse: usize, fine: usize) -> std::ops::Range<usize> {
    i * fine / coarse..(i + 1) * fine / coarse
}

/// The next coarser level: sides halved (at least 1), each texel the linear mean of the box
/// of texels it covers (colour weighted by alpha).
fn downsample(fine: Level, srgb: bool) -> MipLevel {
    use rayon::prelude::*;
    let width = (fine.width / 2).max(1);
    let height = (fine.height / 2).max(1);
    let mut texels = vec![[0u8; 4]; width * height];
    texels.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let rows = covered(y, height, fine.height);
        for (x, out) in row.iter_mut().enumerate() {
            let columns = covered(x, width, fine.width);
            // Colour weighted by alpha, so that the colour of cut-out (transparent) texels
            // does not bleed into the visible ones; alpha itself plainly averaged.
            let mut weighted = Vec4::ZERO;
            let mut plain = Vec4::ZERO;
            for fy in rows.clone() {
                for fx in columns.clone() {
                    let texel = decode(fine.texels[fy * fine.width + fx], srgb);
                    weighted += texel * texel.w;
                    plain += texel;
                }
            }
            let count = (rows.len() * columns.len()) as f32;
            let colour = if weighted.w > 0.0 { weighted / weighted.w } else { plain / count };
            *out = encode(colour.truncate().extend(plain.w / count), srgb);
        }
    });
    MipLevel { width: width as u32, height: height as u32, texels }
}

impl Level<'_> {
    /// Bilinear lookup with repeat wrapping; (0,0) is the top-left corner of the image as
    /// stored (glTF and, after the loader flips v, OBJ conventions).
    #[inline]
    fn bilinear(&self, uv: Vec2, srgb: bool) -> Vec4 {
        let u = if uv.x.is_finite() { uv.x } else { 0.0 };
        let v = if uv.y.is_finite() { uv.y } else { 0.0 };
        // Keep coordinates in a range where f32 keeps sub-texel precision.
        let u = u - floor_exact(u);
        let v = v - floor_exact(v);
        let (w, h) = (self.width, self.height);
        let x = u * w as f32 - 0.5;
        let y = v * h as f32 - 0.5;
        let (floor_x, floor_y) = (floor_exact(x), floor_exact(y));
        let fx = x - floor_x;
        let fy = y - floor_y;
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
        let x0 = wrap(floor_x, w);
        let y0 = wrap(floor_y, h);
        let x1 = if x0 + 1 == w { 0 } else { x0 + 1 };
        let y1 = if y0 + 1 == h { 0 } else { y0 + 1 };
        let table = if srgb { srgb_table() } else { &UNORM_TABLE };
        let texel = |x: usize, y: usize| decode_with(self.texels[y * w + x], table);
        let a = texel(x0, y0).lerp(texel(x1, y0), fx);
        let b = texel(x0, y1).lerp(texel(x1, y1), fx);
        a.lerp(b, fy)
    }
}

impl Texture {
    /// Loads a PNG or JPEG file. A missing or unreadable file is an error naming it.
    pub fn load(path: &Path, srgb: bool, referenced_from: &Path, field: &str) -> Result<Texture, SceneError> {
        crate::scene::input::check_input(path, crate::limits::MAX_MODEL_BYTES, referenced_from, field)?;
        let img = image::open(path).map_err(|e| {
            SceneError::new(referenced_from, field, format!("cannot read texture {}: {e}", path.display()))
        })?;
        let rgba = img.to_rgba8();
        Ok(Texture::from_rgba8(path.display().to_string(), rgba.width(), rgba.height(), srgb, rgba.into_raw()))
    }

    /// A texture from rows of RGBA8 texels (top row first); builds its mip-map chain.
    pub fn from_rgba8(name: String, width: u32, height: u32, srgb: bool, raw: Vec<u8>) -> Texture {
        let texels = raw.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        Texture::from_texels(name, width, height, srgb, texels)
    }

    fn from_texels(name: String, width: u32, height: u32, srgb: bool, texels: Vec<[u8; 4]>) -> Texture {
        let mut texture = Texture { name, width, height, srgb, texels, coarser: Vec::new() };
        if texture.texels.len() == (width as usize) * (height as usize) {
            let mut level = texture.level(0);
            while level.width > 1 || level.height > 1 {
                let next = downsample(level, srgb);
                texture.coarser.push(next);
                level = texture.level(texture.coarser.len());
            }
        }
        texture
    }

    /// The same image decoded the other way (sRGB or linear); its mip levels are rebuilt.
    pub fn with_encoding(&self, srgb: bool) -> Texture {
        Texture::from_texels(self.name.clone(), self.width, self.height, srgb, self.texels.clone())
    }

    /// A 1x1 texture of one colour (tests, fallbacks).
    pub fn constant(rgba: [u8; 4], srgb: bool) -> Texture {
        Texture::from_texels("constant".into(), 1, 1, srgb, vec![rgba])
    }

    /// Number of mip levels, the finest included.
    pub fn level_count(&self) -> usize {
        1 + self.coarser.len()
    }

    fn level(&self, index: usize) -> Level<'_> {
        match index.checked_sub(1) {
            None => Level { width: self.width as usize, height: self.height as usize, texels: &self.texels },
            Some(i) => {
                let m = &self.coarser[i];
                Level { width: m.width as usize, height: m.height as usize, texels: &m.texels }
            }
        }
    }

    /// The largest linear value of each RGB channel over the finest level's texels (1 for an
    /// empty texture, which samples as 1).
    pub fn max_rgb(&self) -> Vec3 {
        if self.texels.is_empty() {
            return Vec3::ONE;
        }
        let table = if self.srgb { srgb_table() } else { &UNORM_TABLE };
        let mut peak = [0u8; 3];
        for texel in &self.texels {
            for c in 0..3 {
                peak[c] = peak[c].max(texel[c]);
            }
        }
        // Both decodings increase with the byte, so the largest byte decodes to the largest value.
        Vec3::new(table[peak[0] as usize], table[peak[1] as usize], table[peak[2] as usize])
    }

    /// log2 of the texel count's square root: the level of detail of a footprint one unit of
    /// uv wide is `log2(width in uv) + half_log2_texels()`.
    pub fn half_log2_texels(&self) -> f32 {
        0.5 * ((self.width.max(1) as f32) * (self.height.max(1) as f32)).log2()
    }

    /// Bilinear lookup in the finest level with repeat wrapping; (0,0) is the top-left corner
    /// of the image as stored (glTF and, after the loader flips v, OBJ conventions).
    pub fn sample(&self, uv: Vec2) -> Vec4 {
        self.sample_filtered(uv, 0.0)
    }

    /// Trilinear lookup at level of detail `lod` (0 = finest; each unit halves the
    /// resolution): bilinear in the two nearest levels, blended. `lod` ≤ 0 or NaN is the
    /// finest level, beyond the coarsest the coarsest.
    pub fn sample_filtered(&self, uv: Vec2, lod: f32) -> Vec4 {
        if self.texels.is_empty() {
            return Vec4::ONE;
        }
        let coarsest = self.coarser.len();
        if !(lod > 0.0) || coarsest == 0 {
            return self.level(0).bilinear(uv, self.srgb);
        }
        if lod >= coarsest as f32 {
            return self.level(coarsest).bilinear(uv, self.srgb);
        }
        let finer = lod as usize;
        let blend = lod - finer as f32;
        let a = self.level(finer).bilinear(uv, self.srgb);
        let b = self.level(finer + 1).bilinear(uv, self.srgb);
        a.lerp(b, blend)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_exact_is_floor_for_every_finite_value() {
        let mut values = vec![0.0f32, -0.0, 0.5, -0.5, 1.0, -1.0, 2.5, -2.5, 1e-30, -1e-30, 8_388_607.5, -8_388_607.5];
        values.extend([8_388_608.0, -8_388_608.0, 3e9, -3e9, f32::MAX, f32::MIN, f32::MIN_POSITIVE]);
        // Every float just below and above a few integers, and a hashed sweep of bit patterns.
        for n in [-3.0f32, -1.0, 0.0, 1.0, 255.0, 4096.0] {
            values.extend([n.next_down(), n, n.next_up()]);
        }
        let mut bits = 1u32;
        for _ in 0..100_000 {
            bits = bits.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
            let x = f32::from_bits(bits);
            if x.is_finite() {
                values.push(x);
            }
        }
        for x in values {
            // Equal as numbers (floor(-0.0) may come out as +0.0, which no caller can tell).
            assert_eq!(floor_exact(x), x.floor(), "floor of {x:e}");
        }
    }

    #[test]
    fn decoding_tables_give_the_divisions_they_replace() {
        for code in 0..=255u8 {
            let linear = decode([code, code, code, code], false);
            assert_eq!(linear, Vec4::splat(code as f32 / 255.0));
            assert_eq!(decode([0, 0, 0, code], true).w, code as f32 / 255.0, "alpha is linear in sRGB textures");
        }
    }

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
            decode(t.texels[j * t.width as usize + i], t.srgb)
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

    fn decoded(t: &Texture, level: usize) -> Vec<Vec4> {
        t.level(level).texels.iter().map(|&x| decode(x, t.srgb)).collect()
    }

    #[test]
    fn mip_levels_are_linear_box_means_down_to_one_texel() {
        let raw: Vec<u8> = (0..4 * 2 * 4).map(|i| (i * 53 % 256) as u8).map(|v| v | 1).collect();
        for srgb in [true, false] {
            let mut raw = raw.clone();
            raw.iter_mut().skip(3).step_by(4).for_each(|a| *a = 255);
            let t = Texture::from_rgba8("t".into(), 4, 2, srgb, raw);
            assert_eq!(t.level_count(), 3);
            let fine = decoded(&t, 0);
            let level1 = decoded(&t, 1);
            assert_eq!((t.level(1).width, t.level(1).height), (2, 1));
            for x in 0..2 {
                let box_mean = (fine[2 * x] + fine[2 * x + 1] + fine[4 + 2 * x] + fine[4 + 2 * x + 1]) / 4.0;
                // One 8-bit step of the encoding, in linear terms.
                assert!((level1[x] - box_mean).abs().max_element() < 0.01, "{srgb} {x}: {} vs {box_mean}", level1[x]);
            }
            let mean = fine.iter().copied().sum::<Vec4>() / 8.0;
            let coarsest = decoded(&t, 2);
            assert_eq!(coarsest.len(), 1);
            assert!((coarsest[0] - mean).abs().max_element() < 0.015, "{} vs {mean}", coarsest[0]);
        }
    }

    #[test]
    fn odd_sides_count_every_texel() {
        // 3 × 3 with one bright texel in the last row and column: its weight must reach the
        // single coarser texel (a plain 2 × 2 box would drop it).
        let mut raw = vec![0u8; 9 * 4];
        raw[8 * 4..].copy_from_slice(&[255, 255, 255, 255]);
        raw.iter_mut().skip(3).step_by(4).for_each(|a| *a = 255);
        let t = Texture::from_rgba8("odd".into(), 3, 3, false, raw);
        assert_eq!(t.level_count(), 2);
        let coarsest = decoded(&t, 1);
        assert!((coarsest[0].x - 1.0 / 9.0).abs() < 0.003, "{}", coarsest[0].x);
    }

    #[test]
    fn filtered_lookups_blend_levels_and_clamp_the_level() {
        let raw: Vec<u8> = (0..8 * 8 * 4).map(|i| (i * 97 % 256) as u8).collect();
        let t = Texture::from_rgba8("t".into(), 8, 8, true, raw);
        assert_eq!(t.level_count(), 4);
        let uv = Vec2::new(0.37, 0.81);
        for lod in [0.0, -3.0, f32::NAN, f32::NEG_INFINITY] {
            assert_eq!(t.sample_filtered(uv, lod), t.sample(uv));
        }
        let (l0, l1) = (t.level(0).bilinear(uv, true), t.level(1).bilinear(uv, true));
        assert!((t.sample_filtered(uv, 0.25) - l0.lerp(l1, 0.25)).abs().max_element() < 1e-6);
        let coarsest = decoded(&t, 3)[0];
        for lod in [3.0, 7.5, f32::INFINITY] {
            assert!((t.sample_filtered(Vec2::new(0.9, 0.1), lod) - coarsest).abs().max_element() < 1e-6);
        }
    }

    #[test]
    fn the_other_encoding_rebuilds_the_levels() {
        // Black and white texels: the linear mean is 0.5 whichever way the texels are encoded.
        let raw = [0, 0, 0, 255, 255, 255, 255, 255].to_vec();
        let linear = Texture::from_rgba8("bw".into(), 2, 1, false, raw);
        let srgb = linear.with_encoding(true);
        assert_eq!(srgb.texels, linear.texels);
        for t in [&linear, &srgb] {
            let mean = decoded(t, 1)[0];
            assert!((mean.x - 0.5).abs() < 0.005, "srgb {}: {}", t.srgb, mean.x);
        }
        assert_ne!(srgb.level(1).texels, linear.level(1).texels);
    }

    #[test]
    fn uv_transform_scale_shifts_the_level() {
        let scaled = TextureRef::with_transform(0, Some(Mat3::from_scale(Vec2::new(4.0, 4.0))));
        assert!((scaled.half_log2_scale() - 2.0).abs() < 1e-6);
        assert_eq!(TextureRef::new(0).half_log2_scale(), 0.0);
        let flat = TextureRef::with_transform(0, Some(Mat3::from_scale(Vec2::new(0.0, 1.0))));
        assert_eq!(flat.half_log2_scale(), 0.0);
        let unbounded = TextureRef::with_transform(0, Some(Mat3::from_scale(Vec2::new(f32::INFINITY, 1.0))));
        assert_eq!(unbounded.half_log2_scale(), 0.0);
    }

    #[test]
    fn wrap_modes_map_coordinates_like_gl() {
        // Clamp: the edge beyond [0, 1]; mirror: continuous, period 2, equal to repeat on [0, 1].
        for x in [-2.3f32, -1.0, -0.25, 0.0, 0.4, 1.0, 1.25, 2.6, 7.9] {
            assert_eq!(Wrap::ClampToEdge.apply(x), x.clamp(0.0, 1.0));
            let m = Wrap::MirroredRepeat.apply(x);
            assert!((0.0..=1.0).contains(&m), "{x} -> {m}");
            assert!((Wrap::MirroredRepeat.apply(x + 2.0) - m).abs() < 1e-5);
            assert!((Wrap::MirroredRepeat.apply(-x) - m).abs() < 1e-5, "mirror symmetric about 0");
        }
        assert!((Wrap::MirroredRepeat.apply(1.25) - 0.75).abs() < 1e-6);
        assert_eq!(Wrap::Repeat.apply(1.25), 1.25);
        let reference = TextureRef::new(0).with_wrap([Wrap::ClampToEdge, Wrap::MirroredRepeat]);
        assert_eq!(reference.apply(Vec2::new(1.5, 1.25)), Vec2::new(1.0, 0.75));
    }
}
