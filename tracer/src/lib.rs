//! The lfr path tracer: scene loading (TOML, OBJ, glTF), an Embree 3 accelerator, a
//! unidirectional path tracer with next-event estimation and MIS, and image output.
//!
//! Data flow: `scene::Scene::load` → `accel::Accel::build` → `render::render` → `output`.

// `!(x > 0.0)` is used on purpose throughout: unlike `x <= 0.0` it also rejects NaN.

pub mod accel;
/// The BSDF lives in the workspace crate `shading`, shared with `recon` (docs/ilfr-design.md, G4).
pub use shading as bsdf;
pub mod camera;
pub mod error;
pub mod integrator;
pub mod lights;
pub mod limits;
pub mod memory;
pub mod output;
pub mod progress;
pub mod render;
pub mod sampler;
pub mod samples;
pub mod scene;
pub mod texture;

pub use accel::Accel;
pub use camera::Camera;
pub use error::{RenderError, SceneError};
pub use render::{render, RenderSettings, RenderedImage};
pub use scene::Scene;
