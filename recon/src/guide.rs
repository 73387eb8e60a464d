//! Per-pixel guide buffers the edge-aware filters read (guided image filter, cross-bilateral,
//! À-Trous): one guide ray per pixel through its centre (docs/sample-format.md, `guide`).

/// Geometry seen through each pixel's centre, row-major from the top-left.
#[derive(Clone, Debug, PartialEq)]
pub struct GuideBuffers {
    pub width: u32,
    pub height: u32,
    /// World-space shading normal facing the camera; zero where the guide ray escaped.
    pub normal: Vec<[f32; 3]>,
    /// Camera-space depth along the view axis; 0 where the guide ray escaped.
    pub depth: Vec<f32>,
    /// World-space hit position; zero where the guide ray escaped.
    pub position: Vec<[f32; 3]>,
    /// Optional: the mean normal at the secondary hits of the pixel's indirect samples (the
    /// extra range term of À-Trous used in the indirect light field paper's comparison).
    pub secondary_normal: Option<Vec<[f32; 3]>>,
}

impl GuideBuffers {
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether every buffer has `width * height` entries.
    pub fn is_consistent(&self) -> bool {
        let n = self.pixel_count();
        self.normal.len() == n
            && self.depth.len() == n
            && self.position.len() == n
            && self.secondary_normal.as_ref().map_or(true, |s| s.len() == n)
    }
}

/// An additional eye ray (supersampling, Bauszat et al. 2011 Section 3.2): a hit at a jittered
/// position inside its pixel whose indirect light comes from the filtered map by the
/// geometry-aware lookup, and whose direct light was estimated for it alone.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EyeRay {
    /// Film position in pixels from the image's top-left corner (pixel (x, y) covers
    /// [x, x + 1) × [y, y + 1)).
    pub film: [f32; 2],
    /// Shading normal facing the camera; zero for a miss.
    pub normal: [f32; 3],
    /// Camera-space depth; 0 for a miss.
    pub depth: f32,
    /// Reflectance at the hit; zero for a miss.
    pub albedo: [f32; 3],
    /// Emitted plus directly reflected light (the environment for a miss).
    pub direct: [f32; 3],
}

/// The additional eye rays of an image: `per_pixel` rays for each pixel, pixels row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EyeRays {
    pub per_pixel: u32,
    pub rays: Vec<EyeRay>,
}

impl EyeRays {
    /// The eye rays of pixel `index` (row-major).
    pub fn of_pixel(&self, index: usize) -> &[EyeRay] {
        let n = self.per_pixel as usize;
        &self.rays[index * n..(index + 1) * n]
    }
}
