//! The crate's one error type: every variant names the field or input at fault.

use std::path::PathBuf;

/// What is wrong with a precompute cache file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CacheProblem {
    /// It cannot be read (missing, unreadable).
    Io,
    /// It does not start with the cache's magic bytes: some other file.
    NotACache,
    /// A cache of another format version.
    Version,
    /// Shorter than its header says.
    Truncated,
    /// Its checksum or contents do not add up.
    Corrupt,
    /// Built for other geometry.
    OtherGeometry,
    /// Built with other settings.
    OtherSettings,
}

impl std::fmt::Display for CacheProblem {
    /// In words, for messages (`{:?}` would print the variant's name).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            CacheProblem::Io => "it cannot be read",
            CacheProblem::NotACache => "it is not a probes cache",
            CacheProblem::Version => "it has another format version",
            CacheProblem::Truncated => "it is truncated",
            CacheProblem::Corrupt => "it is corrupt",
            CacheProblem::OtherGeometry => "it was built for other geometry",
            CacheProblem::OtherSettings => "it was built with other settings",
        })
    }
}

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
    /// A precompute cache that cannot be used: the file and why.
    #[error("probes cache {}: {message}", path.display())]
    Cache { path: PathBuf, problem: CacheProblem, message: String },
    /// A size the machine cannot hold, refused before the work.
    #[error("{what}: an estimated {estimate} exceeds the limit of {limit}")]
    TooLarge { what: &'static str, estimate: String, limit: String },
}

impl ProbesError {
    pub(crate) fn parameter(field: &'static str, message: impl Into<String>) -> ProbesError {
        ProbesError::Parameter { field, message: message.into() }
    }
}
