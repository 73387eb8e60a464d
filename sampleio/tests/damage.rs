//! Damaged, truncated and foreign files: every one gives an error naming the file, never a panic.

mod common;

use std::path::Path;

use common::{parts, small_header_value, with_header, write_small};
use sampleio::{SampleError, SampleFile};

fn open_bytes(dir: &Path, bytes: &[u8]) -> Result<SampleFile, SampleError> {
    let path = dir.join("damaged.lfrs");
    std::fs::write(&path, bytes).unwrap();
    let result = SampleFile::open(&path);
    if let Err(e) = &result {
        assert_eq!(e.path(), path);
        assert!(e.to_string().starts_with(&path.display().to_string()), "{e}");
    }
    result
}

#[test]
fn the_small_file_is_valid() {
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = write_small(dir.path(), "ok.lfrs");
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(file.len(), 12);
    let (data, table, trailer) = parts(&bytes);
    assert_eq!(file.data_offset(), data);
    assert_eq!(table - data, 12 * file.header().record_size as usize);
    assert_eq!(trailer - table, 4 * 3);
}

#[test]
fn every_truncation_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = write_small(dir.path(), "ok.lfrs");
    for len in 0..bytes.len() {
        match open_bytes(dir.path(), &bytes[..len]) {
            Err(SampleError::Truncated { actual, expected, .. }) => {
                assert_eq!(actual, len as u64);
                assert!(expected > actual);
            }
            other => panic!("length {len}: expected Truncated, got {other:?}"),
        }
    }
}

#[test]
fn every_flipped_byte_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = write_small(dir.path(), "ok.lfrs");
    let (data, table, trailer) = parts(&bytes);
    let chunk_bytes = 5 * (table - data) / 12;
    for i in 0..bytes.len() {
        for mask in [0x01u8, 0x80, 0xff] {
            let mut damaged = bytes.clone();
            damaged[i] ^= mask;
            let result = open_bytes(dir.path(), &damaged);
            let what = format!("byte {i} ^ {mask:#04x}: {result:?}");
            match i {
                0..=7 => assert!(matches!(result, Err(SampleError::NotASampleFile { .. })), "{what}"),
                8..=11 => assert!(matches!(result, Err(SampleError::UnsupportedVersion { .. })), "{what}"),
                12..=15 => assert!(result.is_err(), "{what}"),
                _ if i < data => assert!(matches!(result, Err(SampleError::CorruptedHeader { .. })), "{what}"),
                _ if i < table => {
                    let want = ((i - data) / chunk_bytes) as u64;
                    assert!(matches!(result, Err(SampleError::Corrupted { chunk, .. }) if chunk == want), "{what}");
                    // Without the data checksums the file opens; `verify` still finds the damage.
                    let path = dir.path().join("damaged.lfrs");
                    let file = SampleFile::open_unchecked(&path).unwrap();
                    assert!(matches!(file.verify(), Err(SampleError::Corrupted { chunk, .. }) if chunk == want));
                }
                _ if (trailer + 16..trailer + 20).contains(&i) => {
                    assert!(matches!(result, Err(SampleError::CorruptedHeader { .. })), "{what}")
                }
                _ => assert!(matches!(result, Err(SampleError::CorruptedTrailer { .. })), "{what}"),
            }
        }
    }
}

#[test]
fn foreign_files() {
    let dir = tempfile::tempdir().unwrap();
    assert!(matches!(open_bytes(dir.path(), b""), Err(SampleError::Truncated { .. })));
    assert!(matches!(open_bytes(dir.path(), b"LFR"), Err(SampleError::Truncated { .. })));
    assert!(matches!(open_bytes(dir.path(), b"P6\n3 2\n255\n"), Err(SampleError::NotASampleFile { .. })));
    assert!(matches!(open_bytes(dir.path(), &[0u8; 4096]), Err(SampleError::NotASampleFile { .. })));
    let missing = dir.path().join("missing.lfrs");
    let e = SampleFile::open(&missing).unwrap_err();
    assert!(matches!(e, SampleError::Io { .. }));
    assert!(e.to_string().contains("missing.lfrs"), "{e}");
}

#[test]
fn wrong_magic_version_and_kind() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = write_small(dir.path(), "ok.lfrs");

    let mut b = bytes.clone();
    b[6] = b'Q';
    assert!(matches!(open_bytes(dir.path(), &b), Err(SampleError::NotASampleFile { .. })));

    for version in [0u32, 2, u32::MAX] {
        let mut b = bytes.clone();
        b[8..12].copy_from_slice(&version.to_le_bytes());
        let e = open_bytes(dir.path(), &b).unwrap_err();
        assert!(matches!(e, SampleError::UnsupportedVersion { version: v, .. } if v == version), "{e}");
        assert!(e.to_string().contains(&format!("version {version}")), "{e}");
    }

    let mut h = small_header_value(&bytes);
    h["kind"] = "volume".into();
    let e = open_bytes(dir.path(), &with_header(&bytes, &h)).unwrap_err();
    assert!(matches!(&e, SampleError::Invalid { message, .. } if message.contains("unknown sample kind")), "{e}");

    // Every known kind is accepted.
    for kind in ["lens-time", "light", "indirect", "ao"] {
        let mut h = small_header_value(&bytes);
        h["kind"] = kind.into();
        let file = open_bytes(dir.path(), &with_header(&bytes, &h)).unwrap();
        assert_eq!(file.header().kind.name(), kind);
    }

    // The JSON version must agree with the preamble.
    let mut h = small_header_value(&bytes);
    h["version"] = 2.into();
    let e = open_bytes(dir.path(), &with_header(&bytes, &h)).unwrap_err();
    assert!(matches!(&e, SampleError::Invalid { field, .. } if field == "version"), "{e}");
}

#[test]
fn trailing_bytes_are_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let (_, mut bytes) = write_small(dir.path(), "ok.lfrs");
    bytes.extend_from_slice(&[0; 7]);
    let e = open_bytes(dir.path(), &bytes).unwrap_err();
    assert!(matches!(&e, SampleError::Invalid { field, .. } if field == "file_size"), "{e}");
}

#[test]
fn misaligned_or_oversized_header_length() {
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = write_small(dir.path(), "ok.lfrs");
    for h in [1u32, 47, 48 + 1, (16 << 20) + 48, u32::MAX - 15] {
        let mut b = bytes.clone();
        b[12..16].copy_from_slice(&h.to_le_bytes());
        let e = open_bytes(dir.path(), &b).unwrap_err();
        assert!(matches!(&e, SampleError::Invalid { field, .. } if field == "header_length"), "H = {h}: {e}");
    }
    // Aligned and within the limit, but longer than the file.
    let mut b = bytes.clone();
    b[12..16].copy_from_slice(&((16u32 << 20) - 16).to_le_bytes());
    assert!(matches!(open_bytes(dir.path(), &b), Err(SampleError::Truncated { .. })));
}
