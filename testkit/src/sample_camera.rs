//! The camera of the hand-written sample files in the sample-field tests (`recon/tests` and the
//! root `tests/`).

use sampleio::{Camera, Coc, FovAxis};

/// A 40° camera at the origin looking along +z, lens radius 0.1 focused at 2.
pub fn camera() -> Camera {
    Camera {
        position: [0.0; 3],
        forward: [0.0, 0.0, 1.0],
        up: [0.0, -1.0, 0.0],
        right: [1.0, 0.0, 0.0],
        fov_deg: 40.0,
        fov_axis: FovAxis::Y,
        aperture_radius: 0.1,
        focus_distance: 2.0,
        coc: Coc { c1: 2.0, c2: -1.0 },
        shutter: [0.0, 1.0],
        pixel_to_camera: [[0.02, 0.0, -0.04, 0.0], [0.0, 0.02, -0.04, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        world_to_camera: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
    }
}
