//! What identifies a scene as traced: SHA-256 over the scene file's bytes, the loaded geometry
//! (positions, triangles, material indices, motion) and the loaded materials, lights,
//! environment and camera — everything the command line may change after loading (the lens in
//! `compare`, lighting and camera options). Textures' pixels are not included (documented in
//! docs/compare.md). Used by the compare reference cache key and by the render record that
//! `lfr merge` checks shards against.

use sha2::{Digest, Sha256};
use tracer::Scene;

/// Feeds the scene's identity into `hash`.
pub fn hash_scene(hash: &mut Sha256, scene_text: &[u8], scene: &Scene) {
    hash.update((scene_text.len() as u64).to_le_bytes());
    hash.update(scene_text);
    for mesh in &scene.meshes {
        hash.update((mesh.positions.len() as u64).to_le_bytes());
        for p in &mesh.positions {
            for c in p.to_array() {
                hash.update(c.to_le_bytes());
            }
        }
        for t in &mesh.indices {
            for i in t {
                hash.update(i.to_le_bytes());
            }
        }
        hash.update(mesh.material.to_le_bytes());
        for c in mesh.motion.to_array() {
            hash.update(c.to_le_bytes());
        }
    }
    // Debug output of f32 is exact (shortest round-trip) and stable, so these are canonical.
    let loaded = format!("{:?}|{:?}|{:?}|{:?}", scene.materials, scene.lights, scene.environment, scene.camera);
    hash.update((loaded.len() as u64).to_le_bytes());
    hash.update(loaded.as_bytes());
}

/// The scene's identity as 64 hex digits.
pub fn scene_sha256(scene_text: &[u8], scene: &Scene) -> String {
    let mut hash = Sha256::new();
    hash_scene(&mut hash, scene_text, scene);
    hex(&hash.finalize())
}

pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The bytes of the scene file (a regular file of at most `limits::MAX_MODEL_BYTES`, like every
/// input: never a device read until memory runs out), or of the embedded default scene. Read
/// after the scene was loaded, so that its own errors come first.
pub fn scene_text(path: Option<&std::path::Path>) -> anyhow::Result<Vec<u8>> {
    match path {
        Some(path) => Ok(tracer::scene::input::read_input(path, tracer::limits::MAX_MODEL_BYTES, path, "scene")?),
        None => Ok(crate::common::DEFAULT_SCENE.as_bytes().to_vec()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn default_scene() -> Scene {
        crate::common::load_scene(None, tracer::scene::input::FileAccess::Confined, &Default::default()).unwrap()
    }

    #[test]
    fn the_identity_follows_what_was_traced() {
        let text = crate::common::DEFAULT_SCENE.as_bytes();
        let scene = default_scene();
        let base = scene_sha256(text, &scene);
        assert_eq!(base.len(), 64);
        assert_eq!(base, scene_sha256(text, &default_scene()), "stable");
        let mut moved = default_scene();
        moved.meshes[0].positions[0].x += 1e-3;
        let mut lit = default_scene();
        lit.environment += glam::Vec3::splat(0.5);
        let mut lens = default_scene();
        lens.camera.aperture_radius += 0.01;
        for (what, other) in [("geometry", moved), ("environment", lit), ("lens", lens)] {
            assert_ne!(scene_sha256(text, &other), base, "{what} changes the identity");
        }
        assert_ne!(scene_sha256(b"other text", &scene), base);
    }
}
