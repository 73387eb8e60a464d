//! The scenes the integration tests build and render: the tracer's own (`tracer/tests`) and the
//! command's (`tests/` at the workspace root).

use std::path::{Path, PathBuf};

use glam::Vec3;
use tracer::scene::description;
use tracer::{Accel, RenderSettings, RenderedImage, Scene};

/// Parses a TOML scene description given inline (paths relative to the project root).
pub fn scene_from_toml(text: &str) -> Scene {
    let mut scene =
        description::parse(text, &project_root().join("scenes/inline-test.toml")).expect("test scene parses");
    scene.validate().expect("test scene is valid");
    scene
}

/// An inline scene description built from the pieces the tests repeat, so that each test
/// states only what its scene is: `[render]`, the camera, diffuse and emitting materials,
/// polygons and spheres; anything else as raw TOML.
#[derive(Clone, Debug)]
pub struct SceneToml {
    text: String,
}

impl SceneToml {
    /// `[render]` with the path length and, if given, a uniform environment.
    pub fn new(max_bounces: u32, environment: Option<[f32; 3]>) -> SceneToml {
        let mut text = format!("[render]\nmax_bounces = {max_bounces}\n");
        if let Some(rgb) = environment {
            text += &format!("environment = {rgb:?}\n");
        }
        SceneToml { text }
    }

    /// `[render]` with a uniform environment and the scene format's default path length.
    pub fn lit_by_environment(environment: [f32; 3]) -> SceneToml {
        SceneToml { text: format!("[render]\nenvironment = {environment:?}\n") }
    }

    /// A pinhole camera at `position` looking at `look_at` with a `fov`-degree field of view;
    /// `extra` lines (`up = ...`, `aperture_radius = ...`) are added to its table.
    pub fn camera(mut self, position: [f32; 3], look_at: [f32; 3], fov: f32, extra: &str) -> SceneToml {
        self.text += &format!("[camera]\nposition = {position:?}\nlook_at = {look_at:?}\nfov = {fov:?}\n{extra}");
        self
    }

    /// A Lambertian material (`specular = 0`) of albedo `base_color`.
    pub fn diffuse(mut self, name: &str, base_color: [f32; 3]) -> SceneToml {
        self.text += &format!("[[material]]\nname = {name:?}\nbase_color = {base_color:?}\nspecular = 0\n");
        self
    }

    /// A black emitter of radiance `emission`; `extra` lines are added to its table.
    pub fn emitter(mut self, name: &str, emission: [f32; 3], extra: &str) -> SceneToml {
        self.text += &format!(
            "[[material]]\nname = {name:?}\nbase_color = [0, 0, 0]\nspecular = 0\nemission = {emission:?}\n{extra}"
        );
        self
    }

    /// A polygon of `material` through `points`; `extra` lines (`motion = ...`) are added.
    pub fn polygon(mut self, material: &str, points: &[[f32; 3]], extra: &str) -> SceneToml {
        self.text += &format!("[[mesh]]\nshape = \"polygon\"\nmaterial = {material:?}\npoints = {points:?}\n{extra}");
        self
    }

    /// A sphere of `material`; `extra` lines (`subdivisions = ...`) are added.
    pub fn sphere(mut self, material: &str, center: [f32; 3], radius: f32, extra: &str) -> SceneToml {
        self.text += &format!(
            "[[mesh]]\nshape = \"sphere\"\nmaterial = {material:?}\ncenter = {center:?}\nradius = {radius:?}\n{extra}"
        );
        self
    }

    /// Any other TOML, appended as it is.
    pub fn raw(mut self, toml: &str) -> SceneToml {
        self.text += toml;
        self.text += "\n";
        self
    }

    pub fn text(&self) -> &str {
        &self.text
    }

    /// The scene, parsed and validated.
    pub fn scene(&self) -> Scene {
        scene_from_toml(&self.text)
    }
}

/// A camera a millionth in front of a 2×2 wall at z = 0 (default material), looking at it, in a
/// white environment; `lens` adds camera lines (`aperture_radius = ...`). The stiff case of a
/// depth near zero.
pub fn camera_a_millionth_from_a_wall(lens: &str) -> Scene {
    SceneToml::lit_by_environment([1.0; 3])
        .camera([0.0, 0.0, 1e-6], [0.0, 0.0, -1.0], 90.0, lens)
        .raw("[[mesh]]\nshape = \"polygon\"\npoints = [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]")
        .scene()
}

/// The white furnace: a white (albedo 1) Lambertian sphere beside an open (concave) box in a
/// uniform environment (0.5, 1, 2), seen from (0, 0, 6); every hit looks like the environment,
/// however many bounces it takes.
pub fn furnace() -> SceneToml {
    SceneToml::new(1000, Some([0.5, 1.0, 2.0]))
        .camera([0.0, 0.0, 6.0], [0.0; 3], 50.0, "")
        .diffuse("white", [1.0; 3])
        .sphere("white", [-0.8, 0.0, 0.0], 1.0, "")
        .raw("[[mesh]]\nshape = \"box\"\nmin = [0.5, -1, -1]\nmax = [2.0, 1, 1]\nmaterial = \"white\"")
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
    SceneToml::new(0, None)
        .camera(
            [0.0; 3],
            [0.0, 0.0, 1.0],
            40.0,
            &format!("aperture_radius = {aperture:?}\nfocus_distance = {focus:?}\n"),
        )
        .emitter("lamp", [emission; 3], "two_sided_emission = true\n")
        .polygon("lamp", points, &format!("motion = {motion:?}\n"))
        .text()
        .to_string()
}

/// [`emissive_polygon_toml`] parsed.
pub fn emissive_polygon(aperture: f32, focus: f32, emission: f32, points: &[[f32; 3]], motion: [f32; 3]) -> Scene {
    scene_from_toml(&emissive_polygon_toml(aperture, focus, emission, points, motion))
}

/// The 1 × 1 lamp 2 above the floor of the soft-shadow and light-sample tests.
pub const LAMP: [[f32; 3]; 4] = [[-0.5, 2.0, -0.5], [0.5, 2.0, -0.5], [0.5, 2.0, 0.5], [-0.5, 2.0, 0.5]];

/// The 10 × 10 floor at height 0 of the soft-shadow and light-sample tests.
pub const FLOOR: [[f32; 3]; 4] = [[-5.0, 0.0, -5.0], [-5.0, 0.0, 5.0], [5.0, 0.0, 5.0], [5.0, 0.0, -5.0]];

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

pub fn render(scene: &Scene, width: u32, height: u32, spp: u32, seed: u32) -> RenderedImage {
    render_with_threads(scene, width, height, spp, seed, 0)
}

pub fn render_with_threads(
    scene: &Scene,
    width: u32,
    height: u32,
    spp: u32,
    seed: u32,
    threads: usize,
) -> RenderedImage {
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
