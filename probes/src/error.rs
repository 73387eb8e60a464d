//! The crate's one error type: every variant names the field or input at fault.

/// What can go wrong while building surfels or placing probes.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum ProbesError {
    /// A setting out of range: the field and what it must be.
    #[error("{field}: {message}")]
    Parameter { field: &'static str, message: String },
    /// The scene has no surface to put receivers on.
    #[error("the scene has no triangles with area: nothing to place receivers or probes on")]
    EmptyScene,
    /// Moving geometry: the precompute is for static scenes.
    #[error("mesh '{mesh}' moves during the shutter; sparse radiance probes need static geometry")]
    MovingGeometry { mesh: String },
    /// Non-finite vertex data.
    #[error("mesh '{mesh}': vertex {vertex} is not finite")]
    NonFinite { mesh: String, vertex: usize },
    /// The flood fill reached no empty voxel next to a surface.
    #[error(
        "no probe candidates: no empty voxel reached by the flood fill lies next to a front-facing surface \
         (voxel size {voxel}); try more probes (a finer voxel grid) or the paper's candidate rule"
    )]
    NoCandidates { voxel: f64 },
    /// The tracer failed (building the accelerator).
    #[error("tracer: {0}")]
    Tracer(String),
    /// A size the machine cannot hold, refused before the work.
    #[error("{what}: an estimated {estimate} exceeds the limit of {limit}")]
    TooLarge { what: &'static str, estimate: String, limit: String },
}

impl ProbesError {
    pub(crate) fn parameter(field: &'static str, message: impl Into<String>) -> ProbesError {
        ProbesError::Parameter { field, message: message.into() }
    }
}
