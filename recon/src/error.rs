//! The one error type of the crate, after `sampleio::SampleError`: each variant says what it is
//! about (a sample file and its field, a parameter, a method option, a missing input, two
//! buffers, a file, the Python bridge, an external tool). Its `Display` is the message the
//! command line shows; variants whose message names its subject itself (a parameter, two
//! buffers, an input, the interpreter) display the message alone.

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

    /// A step run on the samples of one file (splat sizing, the splat hierarchy, shrinking,
    /// the gather) failed; `error` says what it is about, and the message names the file first.
    #[error("{}: {error}", path.display())]
    InFile { path: PathBuf, error: Box<Error> },

    /// A setting outside what the method accepts, or a value handed to a function outside what
    /// it accepts (discs, rays, guide planes, a camera block); the message names it.
    #[error("{message}")]
    Parameter { name: &'static str, message: String },

    /// A `NAME:key=value` method option that does not parse or does not apply.
    #[error("`{spec}`: {message}")]
    Option { spec: String, message: String },

    /// The inputs of a method run lack what the method reads (`input`: "samples", "light
    /// samples", "guide buffers", "guide secondary_normal", "frame").
    #[error("{message}")]
    MissingInput { input: &'static str, message: String },

    /// Buffers that must have one size do not; the message names them and their sizes.
    #[error("{message}")]
    SizeMismatch { what: &'static str, message: String },

    /// A file other than a sample file (a script or an image handed to Python) cannot be
    /// written or read.
    #[error("cannot {op} {}: {source}", path.display())]
    Io {
        path: PathBuf,
        /// What was being done: "write image", "read image", "write Python script".
        op: &'static str,
        source: std::io::Error,
    },

    /// The Python interpreter of the bridge (`crate::python`) cannot be run, cannot import a
    /// module, or a script it ran failed or answered nothing usable; the message names the
    /// interpreter.
    #[error("{message}")]
    Python { interpreter: String, message: String },

    /// An external program a bridge runs (Python with OIDN or FLIP) failed or is missing.
    #[error("{tool}: {message}")]
    External { tool: &'static str, message: String },
}

impl Error {
    /// A [`Error::SampleContent`] of the file at `path`.
    pub fn sample_content(path: impl Into<PathBuf>, message: impl Into<String>) -> Error {
        Error::SampleContent { path: path.into(), message: message.into() }
    }

    /// `self`, prefixed by the sample file at `path` it came from ([`Error::InFile`]).
    pub fn in_file(self, path: impl Into<PathBuf>) -> Error {
        Error::InFile { path: path.into(), error: Box::new(self) }
    }

    /// A [`Error::Parameter`] about the setting `name`.
    pub fn parameter(name: &'static str, message: impl Into<String>) -> Error {
        Error::Parameter { name, message: message.into() }
    }

    /// A [`Error::MissingInput`] about the input `input`.
    pub fn missing_input(input: &'static str, message: impl Into<String>) -> Error {
        Error::MissingInput { input, message: message.into() }
    }

    /// A [`Error::SizeMismatch`] about the buffers `what`.
    pub fn size_mismatch(what: &'static str, message: impl Into<String>) -> Error {
        Error::SizeMismatch { what, message: message.into() }
    }

    /// A [`Error::Python`] of the interpreter `interpreter`.
    pub fn python(interpreter: impl Into<String>, message: impl Into<String>) -> Error {
        Error::Python { interpreter: interpreter.into(), message: message.into() }
    }

    /// A [`Error::External`] of the tool `tool`.
    pub fn external(tool: &'static str, message: impl Into<String>) -> Error {
        Error::External { tool, message: message.into() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_their_subject_first() {
        let content = Error::sample_content("/tmp/a.lfrs", "field `x` has 2 components, 1 expected");
        assert_eq!(content.to_string(), "/tmp/a.lfrs: field `x` has 2 components, 1 expected");
        let wrapped = Error::parameter("k", "splat sizing: k must be at least 1").in_file("/tmp/a.lfrs");
        assert_eq!(wrapped.to_string(), "/tmp/a.lfrs: splat sizing: k must be at least 1");
        assert!(matches!(wrapped, Error::InFile { error, .. } if matches!(*error, Error::Parameter { name: "k", .. })));
        assert_eq!(Error::external("oidn", "empty frame (0x0)").to_string(), "oidn: empty frame (0x0)");
        let io = Error::Io {
            path: "/tmp/x.f32".into(),
            op: "read image",
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "gone"),
        };
        assert_eq!(io.to_string(), "cannot read image /tmp/x.f32: gone");
    }
}
