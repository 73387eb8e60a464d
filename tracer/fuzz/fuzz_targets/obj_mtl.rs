//! `obj_mtl`: the input is an OBJ text and a material library, separated by the first line
//! `#MTL` (no such line: no library). The OBJ is loaded in memory (`obj::load_from_bytes`),
//! every `mtllib` answered with the library's bytes, texture maps named in a folder that does not
//! exist; when it loads, the scene is validated. Neither may panic; every error must name the
//! file it is about: the OBJ, or a material library one of its `mtllib NAME` lines names
//! (`/nonexistent-lfr-fuzz/NAME`).

#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use tracer::scene::obj::{load_from_bytes, ObjOptions};
use tracer::Scene;

const PATH: &str = "/nonexistent-lfr-fuzz/model.obj";
const FOLDER: &str = "/nonexistent-lfr-fuzz/";

fuzz_target!(|data: &[u8]| {
    let separator = b"\n#MTL\n";
    let (obj, mtl) = match data.windows(separator.len()).position(|w| w == separator) {
        Some(at) => (&data[..at + 1], Some(&data[at + separator.len()..])),
        None => (data, None),
    };
    let read_mtl = |name: &Path| match mtl {
        Some(bytes) => Ok(bytes.to_vec()),
        None => Err(tracer::error::SceneError::new(PATH, "mtllib", format!("{}: file not found", name.display()))),
    };
    let mut scene = Scene::empty(PATH);
    match load_from_bytes(Path::new(PATH), obj, &mut scene, &ObjOptions::default(), &read_mtl) {
        Ok(()) => {
            if let Err(e) = scene.validate() {
                assert!(e.to_string().starts_with(PATH), "{e}");
            }
        }
        Err(e) => {
            // The libraries the OBJ names, as tobj reads `mtllib` (the rest of the line after the
            // first space, trimmed).
            let text = String::from_utf8_lossy(obj);
            let libraries: Vec<std::path::PathBuf> = text
                .lines()
                .filter(|line| line.split_whitespace().next() == Some("mtllib"))
                .map(|line| Path::new(FOLDER).join(line.split_once(' ').unwrap_or_default().1.trim()))
                .collect();
            assert!(e.file == Path::new(PATH) || libraries.contains(&e.file), "{e} (libraries {libraries:?})");
            assert!(e.to_string().starts_with(&e.file.display().to_string()), "{e}");
        }
    }
});
