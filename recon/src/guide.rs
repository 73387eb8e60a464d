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
