//! The lfr sample format: a documented, versioned binary layout of the samples the tracer
//! emits and the reconstructions (and external tools) read.
//!
//! The normative description is `docs/sample-format.md`; in brief, a file is (all
//! little-endian):
//!
//! | part | bytes |
//! |---|---|
//! | preamble: magic `LFRSAMP\0`, u32 version (1), u32 header length H | 16 |
//! | header: UTF-8 JSON, space-padded so the data starts at a multiple of 64 | H |
//! | data: `sample_count` records of `record_size` bytes, pixel-major | `sample_count * record_size` |
//! | chunk table: u32 CRC-32 per chunk of `chunk_samples` records | `4 * chunks` |
//! | trailer: magic `LFRTAIL\0`, u64 sample count, u32 header CRC, u32 table CRC, u64 chunks | 32 |
//!
//! The header lists the fields a record holds (name, type `f32`/`f16`/`u32`/`u16`/`u8`, 1 to 4
//! components, byte offset), so a file carries only the fields its scene needs; the data is a
//! plain array of structs that numpy maps with one structured dtype (`docs/tools/read_samples.py`).
//!
//! Writing streams one sample at a time into a temporary file renamed into place when complete:
//!
//! ```
//! use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleFile, SampleKind, SampleWriter};
//! # fn main() -> sampleio::Result<()> {
//! # let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("samples.lfrs");
//! let spec = HeaderSpec::new(SampleKind::LensTime, 2, 1, 2)
//!     .field(FieldSpec::new("x", FieldType::F32, 1).unit("px"))
//!     .field(FieldSpec::new("radiance", FieldType::F16, 3).meaning("RGB radiance"));
//! let mut writer = SampleWriter::create(&path, spec)?;
//! for i in 0..4 {
//!     writer.push(&[0.5 + (i / 2) as f32, 1.0, 0.5, 0.25])?;
//! }
//! writer.finish()?;
//!
//! let file = SampleFile::open(&path)?;
//! let radiance = file.field("radiance").unwrap();
//! assert_eq!(file.value(3, radiance, 2), 0.25);
//! assert_eq!(file.column("x")?, [0.5, 0.5, 1.5, 1.5]);
//! assert_eq!(file.pixel_samples(1, 0), 2..4);
//! # Ok(())
//! # }
//! ```
//!
//! Reading maps the file into memory and checks every claim of the header against the file's
//! length before touching data, then the CRCs; damaged, truncated or absurd files give a
//! [`SampleError`] naming the file, never a panic. `sampleio` depends on nothing of ours.

mod error;
mod field;
mod header;
pub mod interrupt;
mod needs;
mod output;
mod positional_writer;
mod reader;
mod writer;

pub use error::{InvalidHeader, Result, SampleError};
pub use field::{layout, Field, FieldSpec, FieldType, MAX_COMPONENTS, MAX_FIELD_NAME_LEN};
pub use header::{
    Camera, Coc, FovAxis, Header, HeaderSpec, LightGeometry, SampleKind, SampleOrder, DATA_ALIGN,
    DEFAULT_CHUNK_SAMPLES, FORMAT_NAME, FORMAT_VERSION, MAGIC, MAX_DIMENSION, MAX_FIELDS, MAX_HEADER_LEN,
    MAX_RECORD_SIZE, MAX_SPP, PREAMBLE_LEN, TRAILER_LEN, TRAILER_MAGIC,
};
pub use needs::{FieldNeed, Needs, OCTAHEDRAL, REAL};
pub use output::{check_free_space, check_output_target, free_space, human_bytes};
pub use positional_writer::PositionalWriter;
pub use reader::SampleFile;
pub use writer::{encode_record, encode_records, Durability, SampleWriter, UnencodableValue};
