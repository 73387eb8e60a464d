//! `scene_toml`: the input bytes are a TOML scene description. It is parsed in memory
//! (`description::parse`, named as a file in a folder that does not exist, so every file it
//! references fails to load: nothing is read from disk) and, when it parses, validated. Neither
//! may panic; every error must name the description file.

#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use tracer::scene::description;

const PATH: &str = "/nonexistent-lfr-fuzz/scene.toml";

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    match description::parse(text, Path::new(PATH)) {
        Ok(mut scene) => {
            if let Err(e) = scene.validate() {
                assert!(e.to_string().starts_with(PATH), "{e}");
            }
        }
        Err(e) => assert!(e.to_string().starts_with(PATH), "{e}"),
    }
});
