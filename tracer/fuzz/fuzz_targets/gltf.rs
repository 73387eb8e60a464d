//! `gltf`: the input bytes are a `.gltf` (JSON) or `.glb` file. It is loaded in memory
//! (`gltf::load_from_bytes`: the GLB binary chunk and `data:` URIs are in the input; other URIs
//! name a folder that does not exist, so nothing is read from disk) and, when it loads,
//! validated. Neither may panic; every error must name the glTF file.

#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use tracer::scene::gltf::load_from_bytes;
use tracer::Scene;

const PATH: &str = "/nonexistent-lfr-fuzz/model.gltf";

fuzz_target!(|data: &[u8]| {
    let mut scene = Scene::empty(PATH);
    match load_from_bytes(Path::new(PATH), data, &mut scene, glam::Mat4::IDENTITY) {
        Ok(_) => {
            if let Err(e) = scene.validate() {
                assert!(e.to_string().starts_with(PATH), "{e}");
            }
        }
        Err(e) => assert!(e.to_string().starts_with(PATH), "{e}"),
    }
});
