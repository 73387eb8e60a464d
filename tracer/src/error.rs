//! Errors that name the file and the field at fault.

use std::fmt;
use std::path::{Path, PathBuf};

/// A problem with an input file: which file, which field, what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    pub file: PathBuf,
    pub field: String,
    pub message: String,
}

impl SceneError {
    pub fn new(file: impl AsRef<Path>, field: impl Into<String>, message: impl Into<String>) -> Self {
        SceneError { file: file.as_ref().to_path_buf(), field: field.into(), message: message.into() }
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}: {}", self.file.display(), self.field, self.message)
    }
}

impl std::error::Error for SceneError {}

/// Errors from rendering and writing images.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("{0}")]
    Settings(String),
    #[error("embree: {0}")]
    Embree(String),
    #[error("{path}: {message}")]
    Output { path: PathBuf, message: String },
}
