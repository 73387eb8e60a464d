//! What the tests of every lfr crate share; a dev-dependency only, never linked into the product.
//! One module per concept, each with the one copy the test binaries use:
//!
//! - [`skip`](mod@skip): a case that cannot run on this machine is never a silent pass.
//! - [`scenes`]: inline TOML scenes (the furnace, a lamp over a floor, emissive polygons), the
//!   project's and the shared scenes' folders, renders at a given size, seed and thread count,
//!   an EXR channel.
//! - [`sample_camera`]: the camera of the hand-written sample files.
//! - [`embree_discs`]: Embree's oriented discs holding ILFR's splats, the second implementation
//!   of the splat hierarchy's every-hit query (its test and its benchmark).

pub mod embree_discs;
pub mod sample_camera;
pub mod scenes;
pub mod skip;

pub use skip::{current_case, in_ci, skip, skip_line, skip_unless_unprivileged, CI_VARIABLE, UNPRIVILEGED_VARIABLE};
