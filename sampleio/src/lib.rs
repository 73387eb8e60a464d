//! The lfr sample format: a documented, versioned binary layout of the samples the tracer
//! emits and the reconstructions read.
//!
//! The format itself (header, field list, chunked little-endian data with checksums) is the
//! subject of the samples issue and is not written yet; this crate only fixes its place in the
//! dependency graph: `sampleio` depends on nothing of ours, `tracer` and `recon` depend on it.

/// Version of the sample format this crate reads and writes.
pub const FORMAT_VERSION: u32 = 0;
