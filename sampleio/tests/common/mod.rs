//! Helpers shared by the integration tests: a small valid file with mixed field types, and a
//! way to assemble a file around any header text so that invalid claims can be tested with
//! otherwise valid checksums.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleKind, SampleWriter, MAGIC, TRAILER_MAGIC};

/// 3x2 pixels, 2 spp, chunks of 5 samples (12 samples: chunks of 5, 5, 2), every type.
pub fn small_spec() -> HeaderSpec {
    let mut spec = HeaderSpec::new(SampleKind::LensTime, 3, 2, 2)
        .field(FieldSpec::new("x", FieldType::F32, 1).meaning("pixel x").unit("px"))
        .field(FieldSpec::new("id", FieldType::U8, 1).meaning("object id"))
        .field(FieldSpec::new("radiance", FieldType::F16, 3).meaning("RGB radiance").unit("W/(m^2 sr)"))
        .field(FieldSpec::new("count", FieldType::U16, 2))
        .field(FieldSpec::new("seed", FieldType::U32, 1));
    spec.chunk_samples = 5;
    spec.scene = Some("test".into());
    spec.seed = Some(7);
    spec
}

/// The values of sample `i` of [`small_spec`].
pub fn small_values(i: usize) -> Vec<f32> {
    let f = i as f32;
    vec![f + 0.5, (i % 256) as f32, 0.25 * f, -f, if i == 3 { f32::NAN } else { 1.0 }, f * 3.0, 65535.0, 1e6 + f]
}

/// Writes the small file at `dir/name` and returns its path and bytes.
pub fn write_small(dir: &Path, name: &str) -> (PathBuf, Vec<u8>) {
    let path = dir.join(name);
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    for i in 0..12 {
        w.push(&small_values(i)).unwrap();
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    (path, bytes)
}

/// Byte offsets of the parts of a valid file: (data start, table start, trailer start).
pub fn parts(bytes: &[u8]) -> (usize, usize, usize) {
    let h = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[16..16 + h]).unwrap();
    let data = 16 + h;
    let n = header["sample_count"].as_u64().unwrap() as usize;
    let rs = header["record_size"].as_u64().unwrap() as usize;
    (data, data + n * rs, bytes.len() - 32)
}

/// Assembles a file from header text (padded here), data bytes and the chunk size, with a
/// correct chunk table and trailer for whatever it is given; `sample_count` goes into the
/// trailer.
pub fn assemble(
    header_json: &[u8],
    data: &[u8],
    record_size: usize,
    chunk_samples: usize,
    sample_count: u64,
) -> Vec<u8> {
    let mut header = header_json.to_vec();
    while (16 + header.len()) % 64 != 0 {
        header.push(b' ');
    }
    let mut out = Vec::new();
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&1u32.to_le_bytes());
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(data);
    let chunk_bytes = (record_size * chunk_samples).max(1);
    let table: Vec<u8> = data.chunks(chunk_bytes).flat_map(|c| crc32fast::hash(c).to_le_bytes()).collect();
    out.extend_from_slice(&table);
    out.extend_from_slice(&TRAILER_MAGIC);
    out.extend_from_slice(&sample_count.to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(&header).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(&table).to_le_bytes());
    out.extend_from_slice(&((table.len() / 4) as u64).to_le_bytes());
    out
}

/// The header of the small file as a JSON value, to be edited.
pub fn small_header_value(bytes: &[u8]) -> serde_json::Value {
    let (data, _, _) = parts(bytes);
    serde_json::from_slice(&bytes[16..data]).unwrap()
}

/// Reassembles the small file with an edited header (same data).
pub fn with_header(bytes: &[u8], header: &serde_json::Value) -> Vec<u8> {
    let (data, table, _) = parts(bytes);
    let rs = header["record_size"].as_u64().unwrap_or(0) as usize;
    let chunk = header["chunk_samples"].as_u64().unwrap_or(65536) as usize;
    let count = header["sample_count"].as_u64().unwrap_or(0);
    assemble(&serde_json::to_vec_pretty(header).unwrap(), &bytes[data..table], rs, chunk, count)
}
