//! A linear RGB image, row-major from the top-left: what every reconstruction returns and
//! every metric compares. Deliberately minimal; file formats live with the callers.

use std::fmt;

#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    /// `width * height` linear RGB values, row-major from the top-left.
    pub pixels: Vec<[f32; 3]>,
}

/// Two images that should have the same size do not.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SizeMismatch {
    pub expected: (u32, u32),
    pub found: (u32, u32),
}

impl fmt::Display for SizeMismatch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "image size mismatch: expected {}x{}, found {}x{}",
            self.expected.0, self.expected.1, self.found.0, self.found.1
        )
    }
}

impl std::error::Error for SizeMismatch {}

impl Image {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Image {
        Image { width, height, pixels: vec![[0.0; 3]; width as usize * height as usize] }
    }

    /// An image from per-pixel values; panics if the count is not `width * height`.
    pub fn from_pixels(width: u32, height: u32, pixels: Vec<[f32; 3]>) -> Image {
        assert_eq!(pixels.len(), width as usize * height as usize, "pixel count must be width * height");
        Image { width, height, pixels }
    }

    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    #[inline]
    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    #[inline]
    pub fn set(&mut self, x: u32, y: u32, value: [f32; 3]) {
        let width = self.width as usize;
        self.pixels[y as usize * width + x as usize] = value;
    }

    /// Errors unless `other` has this image's size.
    pub fn check_same_size(&self, other: &Image) -> Result<(), SizeMismatch> {
        if (self.width, self.height) == (other.width, other.height) {
            Ok(())
        } else {
            Err(SizeMismatch { expected: (self.width, self.height), found: (other.width, other.height) })
        }
    }

    /// Pixels with a NaN or infinite channel.
    pub fn nonfinite_pixels(&self) -> usize {
        self.pixels.iter().filter(|p| !p.iter().all(|c| c.is_finite())).count()
    }
}

/// Rec. 709 luminance of a linear RGB value.
#[inline]
pub fn luminance(rgb: [f32; 3]) -> f32 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn size_mismatch_is_reported_with_both_sizes() {
        let a = Image::new(4, 3);
        let b = Image::new(3, 4);
        let error = a.check_same_size(&b).unwrap_err();
        assert_eq!(error.to_string(), "image size mismatch: expected 4x3, found 3x4");
        assert!(a.check_same_size(&Image::new(4, 3)).is_ok());
    }

    #[test]
    fn nonfinite_pixels_are_counted_once_per_pixel() {
        let mut image = Image::new(3, 1);
        image.set(0, 0, [f32::NAN, f32::INFINITY, 0.0]);
        image.set(2, 0, [0.0, 0.0, f32::NEG_INFINITY]);
        assert_eq!(image.nonfinite_pixels(), 2);
    }
}
