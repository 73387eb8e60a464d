//! What a TLFR reconstruction gives back, the camera's (`method::reconstruct_file`) and the soft
//! shadows' (`shadows::reconstruct_soft_shadow`) alike: the image, the seconds of its
//! preparation (reading, R, the hierarchies) and of the reconstruction, and its notes. The
//! method's `Output` is made from it in one place, `method.rs`.

use crate::image::Image;

/// A reconstructed image with its timings and notes.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    pub image: Image,
    /// Reading the files, measuring R and building the hierarchies.
    pub preprocess_s: f64,
    /// Integrating the image.
    pub recon_s: f64,
    pub notes: Vec<String>,
}
