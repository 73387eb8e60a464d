//! The reader: maps a sample file into memory, validates every claim of its preamble and header
//! against the actual file length before touching the data, checks the CRCs and hands out
//! records and values.

use std::fs::File;
use std::ops::Range;
use std::path::{Path, PathBuf};

use memmap2::Mmap;

use crate::error::{Result, SampleError};
use crate::field::Field;
use crate::header::{
    Header, DATA_ALIGN, FORMAT_VERSION, MAGIC, MAX_HEADER_LEN, PREAMBLE_LEN, TRAILER_LEN, TRAILER_MAGIC,
};
use crate::needs::Needs;

/// An open, validated sample file.
#[derive(Debug)]
pub struct SampleFile {
    path: PathBuf,
    map: Mmap,
    header: Header,
    /// Byte offset of the data area (a multiple of 64).
    data_start: usize,
    /// Byte length of the data area.
    data_len: usize,
    record_size: usize,
}

/// Where the parts of a file lie, once the preamble and header are validated against its length.
struct Layout {
    header: Header,
    data_start: usize,
    data_len: usize,
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    u64::from(u32_at(bytes, at)) | (u64::from(u32_at(bytes, at + 4)) << 32)
}

/// Validates preamble, header, file size and trailer of `bytes` (the whole file). Every offset
/// used to index `bytes` is checked against `bytes.len()` first; nothing is allocated from a
/// size the file claims.
fn parse(path: &Path, bytes: &[u8]) -> Result<Layout> {
    let len = bytes.len() as u64;
    let truncated = |what, expected| SampleError::Truncated { path: path.to_path_buf(), what, expected, actual: len };

    // Preamble.
    let magic_seen = &bytes[..bytes.len().min(MAGIC.len())];
    if magic_seen != &MAGIC[..magic_seen.len()] {
        return Err(SampleError::NotASampleFile { path: path.to_path_buf() });
    }
    if len < PREAMBLE_LEN {
        return Err(truncated("preamble", PREAMBLE_LEN));
    }
    let version = u32_at(bytes, 8);
    if version != FORMAT_VERSION {
        return Err(SampleError::UnsupportedVersion { path: path.to_path_buf(), version });
    }
    let header_len = u64::from(u32_at(bytes, 12));
    let invalid = |field: &str, message: String| SampleError::Invalid {
        path: path.to_path_buf(),
        field: field.to_string(),
        message,
    };
    if header_len > MAX_HEADER_LEN {
        return Err(invalid("header_length", format!("{header_len} bytes exceeds the limit of {MAX_HEADER_LEN}")));
    }
    let data_start = PREAMBLE_LEN + header_len;
    if data_start % DATA_ALIGN != 0 {
        return Err(invalid(
            "header_length",
            format!("{header_len}: the data area would start at byte {data_start}, not a multiple of {DATA_ALIGN}"),
        ));
    }
    if len < data_start {
        return Err(truncated("header", data_start));
    }
    // Both fit in the file, hence in usize.
    let header_bytes = &bytes[PREAMBLE_LEN as usize..data_start as usize];
    let header_crc = crc32fast::hash(header_bytes);

    // If the file ends in a trailer, check the header's CRC before interpreting the header, so
    // that a damaged header is reported as such rather than as whatever the damage claims.
    if len >= data_start + TRAILER_LEN {
        let trailer = &bytes[bytes.len() - TRAILER_LEN as usize..];
        if trailer[..8] == TRAILER_MAGIC && u32_at(trailer, 16) != header_crc {
            return Err(SampleError::CorruptedHeader {
                path: path.to_path_buf(),
                stored: u32_at(trailer, 16),
                computed: header_crc,
            });
        }
    }

    // Header.
    let header = Header::from_json(header_bytes).map_err(|e| e.at(path))?;
    header.validate().map_err(|e| e.at(path))?;

    // Sizes: the file length is fully determined by the header.
    let chunk_count = header.chunk_count();
    let data_len = header.data_len().ok_or_else(|| invalid("sample_count", "data size overflows".into()))?;
    let expected = data_start
        .checked_add(data_len)
        .and_then(|n| n.checked_add(chunk_count.checked_mul(4)?))
        .and_then(|n| n.checked_add(TRAILER_LEN))
        .ok_or_else(|| invalid("sample_count", "file size overflows 64 bits".into()))?;
    if len < expected {
        return Err(truncated("data, chunk table and trailer", expected));
    }
    if len > expected {
        return Err(invalid(
            "file_size",
            format!("the file has {len} bytes, {} more than its header accounts for ({expected})", len - expected),
        ));
    }

    // Everything below is inside the file, whose length fits usize.
    let data_start = data_start as usize;
    let data_len = data_len as usize;
    let table_start = data_start + data_len;
    let trailer_start = bytes.len() - TRAILER_LEN as usize;
    let table = &bytes[table_start..trailer_start];
    let trailer = &bytes[trailer_start..];
    let damaged = |message: String| SampleError::CorruptedTrailer { path: path.to_path_buf(), message };
    if trailer[..8] != TRAILER_MAGIC {
        return Err(damaged("the trailer does not start with \"LFRTAIL\\0\"".into()));
    }
    let stored_count = u64_at(trailer, 8);
    if stored_count != header.sample_count {
        return Err(damaged(format!("the trailer says {stored_count} samples, the header {}", header.sample_count)));
    }
    if u32_at(trailer, 16) != header_crc {
        return Err(SampleError::CorruptedHeader {
            path: path.to_path_buf(),
            stored: u32_at(trailer, 16),
            computed: header_crc,
        });
    }
    let stored_chunks = u64_at(trailer, 24);
    if stored_chunks != chunk_count {
        return Err(damaged(format!("the trailer says {stored_chunks} chunks, the header implies {chunk_count}")));
    }
    let table_crc = crc32fast::hash(table);
    if u32_at(trailer, 20) != table_crc {
        return Err(damaged(format!(
            "chunk table CRC-32 is {table_crc:08x}, the trailer says {:08x}",
            u32_at(trailer, 20)
        )));
    }
    Ok(Layout { header, data_start, data_len })
}

impl SampleFile {
    /// Opens, validates and checksums a sample file: preamble, header, file size, trailer,
    /// chunk table and every data chunk.
    pub fn open(path: impl AsRef<Path>) -> Result<SampleFile> {
        let file = Self::open_unchecked(path)?;
        file.verify()?;
        Ok(file)
    }

    /// Like [`open`](Self::open), but skips the data CRCs (the O(size) part). The preamble,
    /// header, file size, trailer and chunk-table CRC are still checked.
    // The crate's only `unsafe`: mapping the file.
    #[allow(unsafe_code)]
    pub fn open_unchecked(path: impl AsRef<Path>) -> Result<SampleFile> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|e| SampleError::io(path, "open", e))?;
        // SAFETY: `Mmap::map` is unsafe because the mapped bytes may change, or disappear, if
        // the file is modified or truncated by anyone while mapped. We open the file read-only
        // and never write through the map; concurrent modification by another process is out
        // of scope (sample files are written once to a temporary name and renamed into place,
        // never modified). Every slice taken from the map is bounds-checked against its actual
        // length, which `parse` compares with the size the header implies before any data is
        // read.
        let map = unsafe { Mmap::map(&file) }.map_err(|e| SampleError::io(path, "map into memory", e))?;
        let layout = parse(path, &map)?;
        let record_size = layout.header.record_size as usize;
        let file = SampleFile {
            path: path.to_path_buf(),
            map,
            header: layout.header,
            data_start: layout.data_start,
            data_len: layout.data_len,
            record_size,
        };
        Ok(file)
    }

    fn table_start(&self) -> usize {
        self.data_start + self.data_len
    }

    /// Checks the CRC of every data chunk against the chunk table.
    pub fn verify(&self) -> Result<()> {
        let chunk_bytes = self.header.chunk_samples as usize * self.record_size;
        let table = &self.map[self.table_start()..];
        for (c, chunk) in self.data().chunks(chunk_bytes).enumerate() {
            if crc32fast::hash(chunk) != u32_at(table, 4 * c) {
                return Err(SampleError::Corrupted {
                    path: self.path.clone(),
                    chunk: c as u64,
                    first_sample: c as u64 * u64::from(self.header.chunk_samples),
                });
            }
        }
        Ok(())
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The validated header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The fields, in header order.
    pub fn fields(&self) -> &[Field] {
        &self.header.fields
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.data_len / self.record_size
    }

    /// Whether the file holds no samples (never true for a valid v1 file).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Byte offset of the data area in the file (a multiple of 64).
    pub fn data_offset(&self) -> usize {
        self.data_start
    }

    /// The whole data area: `len()` records of `header().record_size` bytes.
    pub fn data(&self) -> &[u8] {
        &self.map[self.data_start..self.data_start + self.data_len]
    }

    /// Checks this file's fields against what a consumer reads ([`Needs::check`]): call it
    /// before reading, so that a field of the wrong type or component count is an error naming
    /// the file and the field instead of a read past the field's end.
    pub fn check_needs(&self, needs: &Needs) -> Result<()> {
        needs.check(&self.path, self.fields())
    }

    /// The field called `name`.
    pub fn field(&self, name: &str) -> Option<&Field> {
        self.header.field(name)
    }

    /// The raw bytes of sample `sample`.
    ///
    /// # Panics
    /// If `sample >= len()`.
    pub fn record(&self, sample: usize) -> &[u8] {
        assert!(sample < self.len(), "{}: sample {sample} out of range (len {})", self.path.display(), self.len());
        let start = self.data_start + sample * self.record_size;
        &self.map[start..start + self.record_size]
    }

    /// Component `component` of `field` of sample `sample`, converted to f32 (exact except for
    /// u32 values above 2^24; see [`value_f64`](Self::value_f64)).
    ///
    /// # Panics
    /// If `sample >= len()`, `component >= field.components`, or `field` lies outside this
    /// file's records (a field of another file).
    pub fn value(&self, sample: usize, field: &Field, component: usize) -> f32 {
        field.ty.decode(self.component_bytes(sample, field, component))
    }

    /// Like [`value`](Self::value), as f64, exact for every type.
    pub fn value_f64(&self, sample: usize, field: &Field, component: usize) -> f64 {
        field.ty.decode_f64(self.component_bytes(sample, field, component))
    }

    fn component_bytes(&self, sample: usize, field: &Field, component: usize) -> &[u8] {
        assert!(
            component < field.components as usize,
            "{}: component {component} of field `{}` out of range ({} components)",
            self.path.display(),
            field.name,
            field.components
        );
        &self.record(sample)[field.component_range(component)]
    }

    /// All values of field `name`, as f32, components interleaved: `len() * components` values.
    pub fn column(&self, name: &str) -> Result<Vec<f32>> {
        let field = self.field(name).ok_or_else(|| SampleError::NoSuchField {
            path: self.path.clone(),
            name: name.to_string(),
            available: self.header.fields.iter().map(|f| f.name.as_str()).collect::<Vec<_>>().join(", "),
        })?;
        let size = field.ty.size();
        let (start, len) = (field.offset as usize, field.byte_len());
        let mut out = Vec::with_capacity(self.len() * field.components as usize);
        for record in self.data().chunks_exact(self.record_size) {
            out.extend(record[start..start + len].chunks_exact(size).map(|b| field.ty.decode(b)));
        }
        Ok(out)
    }

    /// The records of pixel (x, y)'s samples, `spp` of `header().record_size` bytes each, in
    /// sample order (read their fields with [`Field::decode_from`]).
    ///
    /// # Panics
    /// If `x >= width` or `y >= height`.
    pub fn pixel_records(&self, x: u32, y: u32) -> &[u8] {
        let samples = self.pixel_samples(x, y);
        &self.data()[samples.start * self.record_size..samples.end * self.record_size]
    }

    /// The sample indices of pixel (x, y): `(y * width + x) * spp ..` plus `spp`.
    ///
    /// # Panics
    /// If `x >= width` or `y >= height`.
    pub fn pixel_samples(&self, x: u32, y: u32) -> Range<usize> {
        let h = &self.header;
        assert!(
            x < h.width && y < h.height,
            "{}: pixel ({x}, {y}) outside the {}x{} image",
            self.path.display(),
            h.width,
            h.height
        );
        let start = h.sample_index(x, y, 0) as usize;
        start..start + h.spp as usize
    }
}
