//! Small scenes the unit tests share.

use std::path::PathBuf;

use glam::Vec3;
use tracer::scene::shapes::{axis_aligned_box, polygon};
use tracer::scene::Mesh;
use tracer::Scene;

/// A scene of `meshes` with one default material and the camera at `camera`.
pub fn scene_of(meshes: Vec<Mesh>, camera: Vec3) -> Scene {
    let mut scene = Scene::empty("<test>");
    scene.meshes = meshes;
    scene.camera.position = camera;
    scene
}

/// The unit square in the z = 0 plane, facing +z.
pub fn unit_quad() -> Mesh {
    polygon(
        "quad",
        &[Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)],
        0,
    )
}

/// A closed box from `lo` to `hi` whose triangles face inwards (a room seen from inside, like
/// the Cornell box's walls).
pub fn room(lo: Vec3, hi: Vec3) -> Mesh {
    let mut m = axis_aligned_box("room", lo, hi, 0);
    for t in &mut m.indices {
        t.swap(1, 2);
    }
    m.name = "room".into();
    m
}

/// Multiplies every position (and the camera position) by `s`.
pub fn scaled(scene: &Scene, s: f32) -> Scene {
    let mut out = scene.clone();
    for m in &mut out.meshes {
        for p in &mut m.positions {
            *p *= s;
        }
    }
    out.camera.position *= s;
    out
}

/// The project's Cornell box (scenes/cornell.toml, millimetres).
pub fn cornell() -> Scene {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    Scene::load(&root.join("scenes/cornell.toml")).expect("scenes/cornell.toml loads")
}
