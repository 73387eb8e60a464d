//! Helpers shared by the integration tests: the tracer's own (`tracer/tests`) and, through
//! `#[path]`, the command's (`tests/` at the workspace root), so there is one copy.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use glam::Vec3;
use tracer::scene::description;
use tracer::{Accel, Frame, RenderSettings, Scene};

/// Parses a TOML scene description given inline (paths relative to the project root).
pub fn scene_from_toml(text: &str) -> Scene {
    let mut scene =
        description::parse(text, &project_root().join("scenes/inline-test.toml")).expect("test scene parses");
    scene.validate().expect("test scene is valid");
    scene
}

/// A camera at the origin looking along +z (40° field of view, lens radius `aperture`, focus at
/// `focus`) at one two-sided emissive polygon of radiance `emission` moving by `motion` over the
/// shutter, in a black void; paths end at their first hit. The text, for tests that write it to
/// a file.
pub fn emissive_polygon_toml(
    aperture: f32,
    focus: f32,
    emission: f32,
    points: &[[f32; 3]],
    motion: [f32; 3],
) -> String {
    format!(
        r#"
        [render]
        max_bounces = 0
        [camera]
        position = [0, 0, 0]
        look_at = [0, 0, 1]
        fov = 40
        aperture_radius = {aperture:?}
        focus_distance = {focus:?}
        [[material]]
        name = "lamp"
        base_color = [0, 0, 0]
        specular = 0
        emission = [{emission:?}, {emission:?}, {emission:?}]
        two_sided_emission = true
        [[mesh]]
        shape = "polygon"
        material = "lamp"
        points = {points:?}
        motion = {motion:?}
        "#
    )
}

/// [`emissive_polygon_toml`] parsed.
pub fn emissive_polygon(aperture: f32, focus: f32, emission: f32, points: &[[f32; 3]], motion: [f32; 3]) -> Scene {
    scene_from_toml(&emissive_polygon_toml(aperture, focus, emission, points, motion))
}

/// The square 0.5 wide at depth 4 of the lens-time tests.
pub const SQUARE_AT_DEPTH_4: [[f32; 3]; 4] =
    [[-0.25, -0.25, 4.0], [0.25, -0.25, 4.0], [0.25, 0.25, 4.0], [-0.25, 0.25, 4.0]];

/// The workspace root (where `scenes/` is), whichever crate's test includes this file.
pub fn project_root() -> PathBuf {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    manifest.ancestors().find(|dir| dir.join("scenes/cornell.toml").is_file()).unwrap_or(&manifest).to_path_buf()
}

/// The third-party scene folder: $LFR_SCENES or ../shared/scenes. Panics (fails the test) when
/// it is missing: these tests must never be skipped silently.
pub fn shared_scenes() -> PathBuf {
    let dir = match std::env::var_os("LFR_SCENES") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => project_root().join("../shared/scenes"),
    };
    assert!(dir.join("README.md").is_file(), "the shared scenes are missing at {} (set LFR_SCENES)", dir.display());
    dir
}

pub fn render(scene: &Scene, width: u32, height: u32, spp: u32, seed: u32) -> Frame {
    render_with_threads(scene, width, height, spp, seed, 0)
}

pub fn render_with_threads(scene: &Scene, width: u32, height: u32, spp: u32, seed: u32, threads: usize) -> Frame {
    let accel = Accel::build(scene).expect("accelerator builds");
    let mut settings = RenderSettings::from_scene(scene);
    settings.width = width;
    settings.height = height;
    settings.spp = spp;
    settings.seed = seed;
    settings.threads = threads;
    tracer::render(scene, &accel, &settings).expect("render succeeds")
}

pub fn mean(values: &[Vec3]) -> Vec3 {
    values.iter().copied().sum::<Vec3>() / values.len() as f32
}

/// Channel `name` of an EXR file.
pub fn exr_channel(path: &Path, name: &str) -> Vec<f32> {
    let (_, _, channels) = tracer::output::read_exr(path).expect("EXR reads");
    channels.into_iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("no channel {name}")).1
}
