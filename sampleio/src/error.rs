//! The one error type of the crate. Every variant carries the path of the file it is about, and
//! its `Display` starts with that path.

use std::fmt;
use std::io;
use std::path::{Path, PathBuf};

use crate::field::FieldType;

/// Result with [`SampleError`] as the default error.
pub type Result<T, E = SampleError> = std::result::Result<T, E>;

/// Everything that can go wrong reading or writing a sample file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SampleError {
    /// An operating-system error (open, read, write, rename, ...).
    #[error("{}: cannot {op}: {source}", path.display())]
    Io {
        path: PathBuf,
        /// What was being done ("open", "write", "rename into place", ...).
        op: &'static str,
        #[source]
        source: io::Error,
    },

    /// The file does not start with the magic `LFRSAMP\0`.
    #[error("{}: not an lfr sample file (the first 8 bytes are not \"LFRSAMP\\0\")", path.display())]
    NotASampleFile { path: PathBuf },

    /// The preamble names a format version this crate does not read.
    #[error(
        "{}: unsupported sample format version {version} (this reader supports version {})",
        path.display(),
        crate::FORMAT_VERSION
    )]
    UnsupportedVersion { path: PathBuf, version: u32 },

    /// The file is shorter than its preamble and header say it must be.
    #[error("{}: truncated: the file has {actual} bytes, its {what} needs {expected}", path.display())]
    Truncated {
        path: PathBuf,
        /// The part that does not fit ("preamble", "header", "data, chunk table and trailer").
        what: &'static str,
        expected: u64,
        actual: u64,
    },

    /// The header bytes do not match the header CRC stored in the trailer.
    #[error(
        "{}: corrupted header: CRC-32 of the header is {computed:08x}, the trailer says {stored:08x}",
        path.display()
    )]
    CorruptedHeader { path: PathBuf, stored: u32, computed: u32 },

    /// The bytes of data chunk `chunk` do not match its CRC in the chunk table.
    #[error("{}: corrupted data: chunk {chunk} (samples {first_sample}..) fails its CRC-32", path.display())]
    Corrupted { path: PathBuf, chunk: u64, first_sample: u64 },

    /// The chunk table or the trailer is damaged (bad magic, counts that disagree with the
    /// header, chunk-table CRC mismatch).
    #[error("{}: corrupted trailer: {message}", path.display())]
    CorruptedTrailer { path: PathBuf, message: String },

    /// The preamble or header makes a claim that is not allowed (see `docs/sample-format.md`,
    /// "Validation"), or a header given to the writer is not valid.
    #[error("{}: invalid `{field}`: {message}", path.display())]
    Invalid { path: PathBuf, field: String, message: String },

    /// [`SampleFile::column`](crate::SampleFile::column) was asked for a field the file does not have.
    #[error("{}: no field named `{name}` (the file has: {available})", path.display())]
    NoSuchField { path: PathBuf, name: String, available: String },

    /// The writer was given a value its field's type cannot hold (NaN or out of range for an
    /// integer type).
    #[error(
        "{}: sample {sample}, field `{field}` component {component}: {value} cannot be stored as {ty}",
        path.display()
    )]
    ValueOutOfRange { path: PathBuf, sample: u64, field: String, component: u32, value: f32, ty: FieldType },

    /// The writer was given a slice of the wrong length.
    #[error("{}: sample {sample}: expected {expected} {what}, got {actual}", path.display())]
    WrongLength { path: PathBuf, sample: u64, what: &'static str, expected: usize, actual: usize },

    /// More samples were pushed than the header declares.
    #[error("{}: too many samples: the header declares {expected}", path.display())]
    TooManySamples { path: PathBuf, expected: u64 },

    /// `finish` was called before all samples the header declares were pushed.
    #[error("{}: too few samples: the header declares {expected}, {pushed} were written", path.display())]
    TooFewSamples { path: PathBuf, expected: u64, pushed: u64 },

    /// An output path that must not be replaced: a directory, device, FIFO, socket or symbolic
    /// link, or one of the command's own inputs.
    #[error("{}: refusing to write the output here: {reason}", path.display())]
    RefusedOutput { path: PathBuf, reason: String },

    /// An earlier call on this writer failed; the writer produces no file.
    #[error("{}: an earlier error aborted this writer; no file is written", path.display())]
    Aborted { path: PathBuf },

    /// A field a consumer reads is declared with a type or component count it cannot read
    /// ([`Needs::check`](crate::Needs::check)); `problem` says what it is and what is needed
    /// ("is u8×1, TLFR needs f32×3 or f16×3").
    #[error("{}: field `{field}` {problem}", path.display())]
    WrongField { path: PathBuf, field: String, problem: String },

    /// A field a consumer requires is absent ([`Needs::check`](crate::Needs::check)); `problem`
    /// says who needs it as what ("TLFR needs the field `radiance` (f32×3 or f16×3)").
    #[error("{}: {problem}; the file lacks it", path.display())]
    MissingField { path: PathBuf, field: String, problem: String },
}

impl SampleError {
    /// The file this error is about.
    pub fn path(&self) -> &Path {
        match self {
            SampleError::Io { path, .. }
            | SampleError::NotASampleFile { path }
            | SampleError::UnsupportedVersion { path, .. }
            | SampleError::Truncated { path, .. }
            | SampleError::CorruptedHeader { path, .. }
            | SampleError::Corrupted { path, .. }
            | SampleError::CorruptedTrailer { path, .. }
            | SampleError::Invalid { path, .. }
            | SampleError::NoSuchField { path, .. }
            | SampleError::ValueOutOfRange { path, .. }
            | SampleError::WrongLength { path, .. }
            | SampleError::TooManySamples { path, .. }
            | SampleError::TooFewSamples { path, .. }
            | SampleError::RefusedOutput { path, .. }
            | SampleError::Aborted { path }
            | SampleError::WrongField { path, .. }
            | SampleError::MissingField { path, .. } => path,
        }
    }

    pub(crate) fn io(path: &Path, op: &'static str, source: io::Error) -> Self {
        SampleError::Io { path: path.to_path_buf(), op, source }
    }
}

/// A header that breaks a rule of the format, without a file path (see
/// [`Header::validate`](crate::Header::validate)). Readers and writers turn it into
/// [`SampleError::Invalid`] with the path.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InvalidHeader {
    /// The header key (or `fields[i].key`, `camera.key`, ...) the problem is about.
    pub field: String,
    pub message: String,
}

impl InvalidHeader {
    pub(crate) fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        InvalidHeader { field: field.into(), message: message.into() }
    }

    /// Attaches the file path.
    pub fn at(self, path: &Path) -> SampleError {
        SampleError::Invalid { path: path.to_path_buf(), field: self.field, message: self.message }
    }
}

impl fmt::Display for InvalidHeader {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "invalid `{}`: {}", self.field, self.message)
    }
}

impl std::error::Error for InvalidHeader {}
