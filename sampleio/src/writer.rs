//! The streaming writer: samples go out one at a time, in pixel-major order, through a buffered
//! temporary file beside the destination that is renamed into place only once complete.

use std::ffi::OsString;
use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::{Result, SampleError};
use crate::field::FieldType;
use crate::header::{Header, HeaderSpec, FORMAT_VERSION, MAGIC, MAX_HEADER_LEN, TRAILER_MAGIC};

/// Buffer between the writer and the file.
const BUFFER_BYTES: usize = 1 << 20;

/// Writes one sample file. Create it with [`SampleWriter::create`], push exactly
/// `header().sample_count` samples, then [`finish`](Self::finish).
///
/// The writer holds one record and the CRC state of the current chunk (plus 4 bytes per finished
/// chunk), never the samples. Any error aborts it: later calls fail with
/// [`SampleError::Aborted`] and no file is produced. Dropping a writer that was not finished
/// removes its temporary file.
#[derive(Debug)]
pub struct SampleWriter {
    path: PathBuf,
    tmp: PathBuf,
    /// Removes `tmp` if the process is interrupted while writing.
    _interrupt: crate::interrupt::Registered,
    out: Option<BufWriter<File>>,
    header: Header,
    /// CRC-32 of the header text, for the trailer.
    header_crc: u32,
    /// The record `push` assembles; bytes no field covers stay zero.
    record: Vec<u8>,
    pushed: u64,
    in_chunk: u32,
    chunk_hasher: crc32fast::Hasher,
    chunk_crcs: Vec<u32>,
    aborted: bool,
    finished: bool,
}

/// `<dir>/<name>.<pid>.tmp` for `<dir>/<name>`.
fn temporary_path(path: &Path) -> Option<PathBuf> {
    let mut name: OsString = path.file_name()?.to_owned();
    name.push(format!(".{}.tmp", std::process::id()));
    Some(path.with_file_name(name))
}

/// A value a field's type cannot hold: NaN, an infinity or a value out of an integer type's
/// range (`encode_record`).
#[derive(Clone, Debug, PartialEq)]
pub struct UnencodableValue {
    pub field: String,
    pub component: u32,
    pub value: f32,
    pub ty: FieldType,
}

impl UnencodableValue {
    /// The error naming the file and the sample.
    pub fn at(self, path: &Path, sample: u64) -> SampleError {
        let UnencodableValue { field, component, value, ty } = self;
        SampleError::ValueOutOfRange { path: path.to_path_buf(), sample, field, component, value, ty }
    }
}

/// Encodes one sample's values (one per component, fields in header order) into `record`
/// (`header.record_size` bytes, little-endian at the fields' offsets): f16 by rounding to
/// nearest, integers by rounding to the nearest integer (ties away from zero) with a range
/// check; float fields store NaN and infinities as given. Bytes no field covers are left as
/// they are. `values` must hold `header.values_per_sample()` values and `record` the record
/// size (the caller checks; extra values are ignored).
pub fn encode_record(header: &Header, values: &[f32], record: &mut [u8]) -> std::result::Result<(), UnencodableValue> {
    let mut first = 0usize;
    for field in &header.fields {
        // A field's components, or as many as `values` still holds.
        let end = (first + field.components as usize).min(values.len());
        let field_values = &values[first.min(end)..end];
        let start = field.offset as usize;
        let bytes = &mut record[start..start + field_values.len() * field.ty.size()];
        for (component, (value, out)) in field_values.iter().zip(bytes.chunks_exact_mut(field.ty.size())).enumerate() {
            if !field.ty.encode(*value, out) {
                let (component, value, ty) = (component as u32, *value, field.ty);
                return Err(UnencodableValue { field: field.name.clone(), component, value, ty });
            }
        }
        if field_values.len() < field.components as usize {
            return Ok(());
        }
        first = end;
    }
    Ok(())
}

/// Encodes consecutive samples' values (`header.values_per_sample()` per sample) into
/// consecutive records, as [`encode_record`] does one by one; on a value no field can hold, the
/// index of its sample among these and the value. A record of `f32` fields only, packed in
/// header order, is the values' little-endian bytes, written in one pass.
pub fn encode_records(
    header: &Header,
    values: &[f32],
    records: &mut [u8],
) -> std::result::Result<(), (usize, UnencodableValue)> {
    let per_sample = header.values_per_sample();
    let record_size = header.record_size as usize;
    if per_sample == 0 || record_size == 0 {
        return Ok(());
    }
    if packed_f32(header) {
        for (value, bytes) in values.iter().zip(records.chunks_exact_mut(4)) {
            bytes.copy_from_slice(&value.to_le_bytes());
        }
        return Ok(());
    }
    for (at, (values, record)) in values.chunks_exact(per_sample).zip(records.chunks_exact_mut(record_size)).enumerate()
    {
        encode_record(header, values, record).map_err(|bad| (at, bad))?;
    }
    Ok(())
}

/// Whether every field is `f32` and the record is the fields' components back to back with no
/// padding: then a record's bytes are its values' little-endian bytes in order.
fn packed_f32(header: &Header) -> bool {
    let mut offset = 0u32;
    for field in &header.fields {
        if field.ty != FieldType::F32 || field.offset != offset {
            return false;
        }
        offset = offset.saturating_add(field.components.saturating_mul(4));
    }
    offset == header.record_size
}

/// Whether a finished file is made durable before the writer reports success.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Durability {
    /// The file and its directory are synced to disk before the rename is reported: a file
    /// that outlives the process (what `lfr dump` writes).
    Synced,
    /// Renamed into place from the page cache, not synced: a scratch file the same process reads
    /// back and removes (`lfr compare`'s inputs). A file already at the path (the process's own
    /// earlier scratch file) is removed first. A crash still never leaves a half-written file
    /// under the name; a power cut may lose the file.
    Unsynced,
}

/// What both writers do before the first record: the header validated and laid out, a
/// temporary file beside `path` created and registered for removal on interrupt.
pub(crate) struct Started {
    pub header: Header,
    /// CRC-32 of the header text, for the trailer.
    pub header_crc: u32,
    pub tmp: PathBuf,
    pub registration: crate::interrupt::Registered,
    pub file: File,
    /// The preamble and the padded header text: the file's first bytes, up to the data.
    pub preamble_and_header: Vec<u8>,
}

pub(crate) fn start(path: &Path, header: HeaderSpec) -> Result<Started> {
    crate::check_output_target(path, &[])?;
    let header = header.to_header().map_err(|e| e.at(path))?;
    let header_bytes = header.to_padded_json();
    if header_bytes.len() as u64 > MAX_HEADER_LEN {
        return Err(SampleError::Invalid {
            path: path.to_path_buf(),
            field: "header".into(),
            message: format!("{} bytes of header text exceed {MAX_HEADER_LEN}", header_bytes.len()),
        });
    }
    let tmp = temporary_path(path).ok_or_else(|| SampleError::Invalid {
        path: path.to_path_buf(),
        field: "path".into(),
        message: "the path has no file name".into(),
    })?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| SampleError::io(parent, "create the folder", e))?;
    }
    crate::interrupt::remove_stale_temporaries(path);
    let registration = crate::interrupt::remove_on_interrupt(&tmp);
    let file = File::create(&tmp).map_err(|e| SampleError::io(&tmp, "create", e))?;
    let mut preamble_and_header = Vec::with_capacity(16 + header_bytes.len());
    preamble_and_header.extend_from_slice(&MAGIC);
    preamble_and_header.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    preamble_and_header.extend_from_slice(&(header_bytes.len() as u32).to_le_bytes());
    preamble_and_header.extend_from_slice(&header_bytes);
    Ok(Started { header_crc: crc32fast::hash(&header_bytes), header, tmp, registration, file, preamble_and_header })
}

/// The bytes after the data: the chunk table (one CRC-32 per chunk) and the trailer.
pub(crate) fn end_of_file(header: &Header, header_crc: u32, chunk_crcs: &[u32]) -> Vec<u8> {
    let table: Vec<u8> = chunk_crcs.iter().flat_map(|c| c.to_le_bytes()).collect();
    let mut end = Vec::with_capacity(table.len() + 32);
    end.extend_from_slice(&table);
    end.extend_from_slice(&TRAILER_MAGIC);
    end.extend_from_slice(&header.sample_count.to_le_bytes());
    end.extend_from_slice(&header_crc.to_le_bytes());
    end.extend_from_slice(&crc32fast::hash(&table).to_le_bytes());
    end.extend_from_slice(&(chunk_crcs.len() as u64).to_le_bytes());
    end
}

/// Syncs `file` if `durability` asks, closes it and renames `tmp` to `path` (then, if synced,
/// makes the rename durable too: best effort, since not every platform can open a directory).
pub(crate) fn rename_into_place(file: File, tmp: &Path, path: &Path, durability: Durability) -> Result<()> {
    if durability == Durability::Synced {
        file.sync_all().map_err(|e| SampleError::io(tmp, "sync", e))?;
    }
    drop(file);
    if durability == Durability::Unsynced {
        // A scratch file replaces only this process's own earlier scratch file. Removing that
        // first keeps the rename from replacing a file, which on ext4 (`auto_da_alloc`) starts
        // writing the new file's blocks out at once; unsynced, the pages may stay in memory.
        let _ = fs::remove_file(path);
    }
    fs::rename(tmp, path).map_err(|e| SampleError::io(path, "rename into place", e))?;
    if durability == Durability::Synced {
        if let Some(dir) = path.parent() {
            let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
            if let Ok(d) = File::open(dir) {
                let _ = d.sync_all();
            }
        }
    }
    Ok(())
}

impl SampleWriter {
    /// Validates the header, computes the field layout and starts writing to
    /// `<path>.<pid>.tmp` beside `path`.
    pub fn create(path: &Path, header: HeaderSpec) -> Result<SampleWriter> {
        let Started { header, header_crc, tmp, registration, file, preamble_and_header } = start(path, header)?;
        let mut writer = SampleWriter {
            path: path.to_path_buf(),
            tmp,
            _interrupt: registration,
            out: Some(BufWriter::with_capacity(BUFFER_BYTES, file)),
            record: vec![0; header.record_size as usize],
            header_crc,
            header,
            pushed: 0,
            in_chunk: 0,
            chunk_hasher: crc32fast::Hasher::new(),
            chunk_crcs: Vec::new(),
            aborted: false,
            finished: false,
        };
        writer.write(&preamble_and_header)?;
        Ok(writer)
    }

    /// The header being written (with computed offsets and record size).
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The destination path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Samples pushed so far.
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    fn fail(&mut self, e: SampleError) -> SampleError {
        self.aborted = true;
        e
    }

    fn check_open(&mut self) -> Result<()> {
        if self.aborted {
            return Err(SampleError::Aborted { path: self.path.clone() });
        }
        Ok(())
    }

    fn write(&mut self, bytes: &[u8]) -> Result<()> {
        let Some(out) = self.out.as_mut() else {
            return Err(self.fail(SampleError::Aborted { path: self.path.clone() }));
        };
        if let Err(e) = out.write_all(bytes) {
            let e = SampleError::io(&self.tmp, "write", e);
            return Err(self.fail(e));
        }
        Ok(())
    }

    /// Pushes the next sample: one value per component, fields in header order. Values are
    /// converted to the fields' types: f16 by rounding to nearest, integers by rounding to the
    /// nearest integer (ties away from zero) with a range check (NaN, infinities and values
    /// outside the type's range are errors); float fields store NaN and infinities as given.
    pub fn push(&mut self, values: &[f32]) -> Result<()> {
        self.check_open()?;
        let expected = self.header.values_per_sample();
        if values.len() != expected {
            let e = SampleError::WrongLength {
                path: self.path.clone(),
                sample: self.pushed,
                what: "values",
                expected,
                actual: values.len(),
            };
            return Err(self.fail(e));
        }
        let mut record = std::mem::take(&mut self.record);
        if let Err(bad) = encode_record(&self.header, values, &mut record) {
            self.record = record;
            let e = bad.at(&self.path, self.pushed);
            return Err(self.fail(e));
        }
        let result = self.push_checked_record(&record);
        self.record = record;
        result
    }

    /// Pushes the next sample as a raw record of exactly `record_size` bytes, laid out as the
    /// header's field offsets say (little-endian).
    pub fn push_record(&mut self, record: &[u8]) -> Result<()> {
        self.check_open()?;
        if record.len() != self.record.len() {
            let e = SampleError::WrongLength {
                path: self.path.clone(),
                sample: self.pushed,
                what: "record bytes",
                expected: self.record.len(),
                actual: record.len(),
            };
            return Err(self.fail(e));
        }
        self.push_checked_record(record)
    }

    /// Pushes the next `records.len() / record_size` samples as raw records, back to back, as
    /// [`encode_record`] lays them out: what `push_record` does for each, in one call, so that
    /// records encoded on several threads cost the writing thread only the copy and the checksum.
    pub fn push_records(&mut self, records: &[u8]) -> Result<()> {
        self.check_open()?;
        let size = self.record.len();
        if size == 0 || records.len() % size != 0 {
            let e = SampleError::WrongLength {
                path: self.path.clone(),
                sample: self.pushed,
                what: "record bytes (a whole number of records)",
                expected: size * (records.len() / size.max(1) + 1),
                actual: records.len(),
            };
            return Err(self.fail(e));
        }
        let count = (records.len() / size) as u64;
        if count > self.header.sample_count - self.pushed {
            let e = SampleError::TooManySamples { path: self.path.clone(), expected: self.header.sample_count };
            return Err(self.fail(e));
        }
        self.write(records)?;
        // Each chunk's checksum covers exactly its records.
        let mut rest = records;
        while !rest.is_empty() {
            let in_this_chunk = (self.header.chunk_samples - self.in_chunk) as usize;
            let take = (rest.len() / size).min(in_this_chunk);
            let (now, later) = rest.split_at(take * size);
            self.chunk_hasher.update(now);
            self.pushed += take as u64;
            self.in_chunk += take as u32;
            if self.in_chunk == self.header.chunk_samples {
                self.end_chunk();
            }
            rest = later;
        }
        Ok(())
    }

    fn push_checked_record(&mut self, record: &[u8]) -> Result<()> {
        if self.pushed == self.header.sample_count {
            let e = SampleError::TooManySamples { path: self.path.clone(), expected: self.header.sample_count };
            return Err(self.fail(e));
        }
        self.write(record)?;
        self.chunk_hasher.update(record);
        self.pushed += 1;
        self.in_chunk += 1;
        if self.in_chunk == self.header.chunk_samples {
            self.end_chunk();
        }
        Ok(())
    }

    fn end_chunk(&mut self) {
        let hasher = std::mem::take(&mut self.chunk_hasher);
        self.chunk_crcs.push(hasher.finalize());
        self.in_chunk = 0;
    }

    /// Checks that every sample was pushed, writes the chunk table and trailer, syncs the file
    /// to disk and renames it into place. Returns the final path. On error the temporary file
    /// is removed and nothing is left at `path`.
    pub fn finish(mut self) -> Result<PathBuf> {
        self.check_open()?;
        if self.pushed != self.header.sample_count {
            return Err(SampleError::TooFewSamples {
                path: self.path.clone(),
                expected: self.header.sample_count,
                pushed: self.pushed,
            });
        }
        if self.in_chunk > 0 {
            self.end_chunk();
        }
        debug_assert_eq!(self.chunk_crcs.len() as u64, self.header.chunk_count());
        let end = end_of_file(&self.header, self.header_crc, &self.chunk_crcs);
        self.write(&end)?;

        let out = self.out.take().expect("the writer is open until finished");
        let file = out.into_inner().map_err(|e| SampleError::io(&self.tmp, "write", e.into_error()))?;
        rename_into_place(file, &self.tmp, &self.path, Durability::Synced)?;
        self.finished = true;
        Ok(self.path.clone())
    }
}

impl Drop for SampleWriter {
    fn drop(&mut self) {
        if self.finished {
            return;
        }
        if let Some(out) = self.out.take() {
            // Discard the buffered bytes instead of flushing them into a file about to go.
            let (file, _) = out.into_parts();
            drop(file);
        }
        let _ = fs::remove_file(&self.tmp);
    }
}
