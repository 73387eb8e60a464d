//! The one error type of the crate, after `sampleio::SampleError`: each variant says what it is
//! about (a sample file and its field, a parameter, a method option, two buffers, an external
//! tool), and its `Display` starts with that.

use std::path::PathBuf;

/// Result with [`Error`] as the default error.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in a reconstruction, a baseline or a metric.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The sample format itself: a file that cannot be opened, read or decoded.
    #[error(transparent)]
    Samples(#[from] sampleio::SampleError),

    /// A sample file that decodes but cannot serve this reconstruction: a missing field, a
    /// field of the wrong shape, a count that disagrees with its size.
    #[error("{}: {message}", path.display())]
    SampleContent { path: PathBuf, message: String },

    /// A setting outside what the method accepts.
    #[error("{message}")]
    Parameter { name: &'static str, message: String },

    /// A `NAME:key=value` method option that does not parse or does not apply.
    #[error("`{spec}`: {message}")]
    Option { spec: String, message: String },

    /// Buffers that must have one size do not.
    #[error("{what}: {message}")]
    SizeMismatch { what: &'static str, message: String },

    /// An external program a bridge runs (Python with OIDN or FLIP) failed or is missing.
    #[error("{tool}: {message}")]
    External { tool: &'static str, message: String },
}
