//! Helpers shared by the `sampleio` fuzz targets (`fuzz_targets/*.rs`, described in
//! `docs/fuzzing.md`): a per-process scratch directory for the files the targets write, an
//! accessor workout for any file `SampleFile` accepted, and independent decoders and checks
//! that do not go through `sampleio`'s own code.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use sampleio::{FieldType, Header, SampleError, SampleFile};

/// The per-process scratch directory: `$SAMPLEIO_FUZZ_TMP/sampleio-fuzz-<pid>`, where
/// `SAMPLEIO_FUZZ_TMP` defaults to `/dev/shm` (tmpfs: the writer's `sync_all` costs nothing
/// there) or else the system temporary directory. Removed when the process exits through
/// `exit` (as libFuzzer does at the end of a run), left behind when it aborts on a finding.
pub fn scratch_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = scratch_path();
        std::fs::create_dir_all(&dir).expect("cannot create the fuzz scratch directory");
        register_cleanup();
        dir
    })
}

fn scratch_path() -> PathBuf {
    let base = std::env::var_os("SAMPLEIO_FUZZ_TMP").map(PathBuf::from).unwrap_or_else(|| {
        let shm = Path::new("/dev/shm");
        if shm.is_dir() {
            shm.to_path_buf()
        } else {
            std::env::temp_dir()
        }
    });
    base.join(format!("sampleio-fuzz-{}", std::process::id()))
}

/// A file named `name` in the scratch directory.
pub fn scratch_file(name: &str) -> PathBuf {
    scratch_dir().join(name)
}

extern "C" fn remove_scratch_dir() {
    let _ = std::fs::remove_dir_all(scratch_path());
}

#[allow(unsafe_code)]
fn register_cleanup() {
    extern "C" {
        fn atexit(callback: extern "C" fn()) -> i32;
    }
    // SAFETY: `atexit` from the C library, given a plain `extern "C"` function without
    // arguments; libFuzzer ends the process with `exit`, which runs it.
    unsafe {
        atexit(remove_scratch_dir);
    }
}

/// Whether the known findings of `docs/fuzzing.md` are asserted (the default), or stepped around
/// (`SAMPLEIO_FUZZ_LENIENT=1`, for fuzzing a `sampleio` older than commit b471fc5, which fixed
/// both, without stopping on them):
///
/// - F1: header `f64` numbers (camera, light, extra) came back up to 2 units in the last place
///   off (serde_json parsed them without its `float_roundtrip` feature); lenient accepts up to
///   [`F64_ULPS`];
/// - F2: `HeaderSpec::to_header` multiplied `width * height * spp` before validating them (a
///   panic with overflow checks on); lenient skips specs whose product overflows u64.
///
/// The files in `sampleio/fuzz/regressions/` reproduce them on such a `sampleio`.
pub fn strict() -> bool {
    static STRICT: OnceLock<bool> = OnceLock::new();
    *STRICT.get_or_init(|| std::env::var_os("SAMPLEIO_FUZZ_LENIENT").is_none_or(|v| v == "0"))
}

/// Whether to print what each input builds (`SAMPLEIO_FUZZ_DEBUG=1`), for triage.
pub fn debug() -> bool {
    static DEBUG: OnceLock<bool> = OnceLock::new();
    *DEBUG.get_or_init(|| std::env::var_os("SAMPLEIO_FUZZ_DEBUG").is_some_and(|v| v != "0"))
}

/// Every error of `sampleio` names its file first (`error.rs`: "its `Display` starts with
/// that path") and `path()` is that file.
pub fn check_error(e: &SampleError, path: &Path) {
    let text = e.to_string();
    assert!(text.starts_with(&path.display().to_string()), "error does not start with the path: {text}");
    assert_eq!(e.path(), path, "error path: {text}");
}

/// Decodes component bytes independently of `sampleio` (little-endian, `half` for f16).
pub fn decode(ty: FieldType, b: &[u8]) -> f64 {
    match ty {
        FieldType::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        FieldType::F16 => f64::from(half::f16::from_bits(u16::from_le_bytes([b[0], b[1]])).to_f32()),
        FieldType::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        FieldType::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
        FieldType::U8 => f64::from(b[0]),
    }
}

/// Same value, NaN equal to NaN (NaN payloads are not promised through f32 <-> f64).
pub fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// Sample indices worth looking at: first, second, middle, last.
pub fn picks(n: usize) -> Vec<usize> {
    let mut v = vec![0, 1.min(n - 1), n / 2, n - 1];
    v.sort_unstable();
    v.dedup();
    v
}

/// Exercises every accessor of a file that `open` or `open_unchecked` accepted, within the
/// preconditions they document (indices below `len()`, components below the field's count,
/// pixels inside the image, fields of this file), and checks what a validated file promises.
/// The data CRCs are not assumed to hold (the file may come from `open_unchecked`).
pub fn exercise(file: &SampleFile) {
    let h = file.header();
    let n = file.len();
    assert_eq!(n as u64, h.sample_count, "len() is not the header's sample_count");
    assert!(!file.is_empty(), "a valid v1 file is never empty");
    assert_eq!(h.sample_count, u64::from(h.width) * u64::from(h.height) * u64::from(h.spp));
    assert!(h.chunk_samples >= 1);
    let rs = h.record_size as usize;
    assert!(rs >= 4 && rs.is_multiple_of(4), "record size {rs}");
    assert_eq!(file.data().len(), n * rs, "data() length");
    assert_eq!(file.data_offset() % 64, 0, "data offset {}", file.data_offset());
    assert_eq!(file.fields(), &h.fields[..]);
    assert!(!file.fields().is_empty() && file.fields().len() <= sampleio::MAX_FIELDS);

    let picks = picks(n);
    for f in file.fields() {
        assert_eq!(file.field(&f.name), Some(f), "field({:?})", f.name);
        assert!((1..=4).contains(&f.components));
        assert!(f.end() <= u64::from(h.record_size));
        let k = f.components as usize;
        let column = file.column(&f.name).expect("column() of a field the header lists");
        assert_eq!(column.len(), n * k, "column({:?}) length", f.name);
        for &i in &picks {
            let record = file.record(i);
            for c in 0..k {
                let v = file.value(i, f, c);
                assert_eq!(v.to_bits(), column[i * k + c].to_bits(), "value vs column, sample {i} `{}`", f.name);
                let at = f.offset as usize + c * f.ty.size();
                let want = decode(f.ty, &record[at..at + f.ty.size()]);
                assert!(
                    same(f64::from(v), want as f32 as f64),
                    "value({i}, `{}`, {c}) = {v}, bytes say {want}",
                    f.name
                );
                let v64 = file.value_f64(i, f, c);
                assert!(same(v64, want), "value_f64({i}, `{}`, {c}) = {v64}, bytes say {want}", f.name);
            }
        }
    }
    // `-` is no valid field name, so no file has it.
    match file.column("-") {
        Err(e @ SampleError::NoSuchField { .. }) => check_error(&e, file.path()),
        other => panic!("column(\"-\") gave {other:?}"),
    }
    assert!(file.field("-").is_none());

    for &i in &picks {
        let r = file.record(i);
        assert_eq!(r, &file.data()[i * rs..(i + 1) * rs], "record({i})");
    }
    let (w, hh, spp) = (h.width, h.height, h.spp as usize);
    for (x, y) in [(0, 0), (w - 1, hh - 1), (w / 2, hh / 2), (w - 1, 0)] {
        let r = file.pixel_samples(x, y);
        assert_eq!(r.len(), spp, "pixel_samples({x}, {y})");
        assert_eq!(r.start as u64, h.sample_index(x, y, 0));
        assert!(r.end <= n, "pixel_samples({x}, {y}) = {r:?} past len {n}");
    }
    assert_eq!(h.sample_index(w - 1, hh - 1, h.spp - 1), h.sample_count - 1);
}

/// How far apart (in ulps) a header `f64` may come back when not [`strict`]: serde_json's
/// default float parsing was measured off by at most 2 over 25 million random doubles.
pub const F64_ULPS: u64 = 4;

/// Units in the last place between two finite f64 of the same sign (or `u64::MAX`).
pub fn ulps(a: f64, b: f64) -> u64 {
    if a.to_bits() == b.to_bits() {
        return 0;
    }
    if a.is_nan() || b.is_nan() || (a.is_sign_negative() != b.is_sign_negative() && a != b) {
        return if a == b { 0 } else { u64::MAX };
    }
    if a == b {
        return 0; // +0 and -0
    }
    a.to_bits().abs_diff(b.to_bits())
}

fn close(a: f64, b: f64, what: &str) {
    let d = ulps(a, b);
    if strict() {
        assert_eq!(a.to_bits(), b.to_bits(), "{what}: wrote {a:e}, read {b:e}");
    } else {
        assert!(d <= F64_ULPS, "{what}: wrote {a:e}, read {b:e} ({d} ulps apart)");
    }
}

fn close_json(a: &serde_json::Value, b: &serde_json::Value, what: &str) {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) if x.is_f64() || y.is_f64() => {
            close(x.as_f64().unwrap(), y.as_f64().unwrap(), what)
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{what}");
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                close_json(p, q, &format!("{what}[{i}]"));
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            assert_eq!(x.keys().collect::<Vec<_>>(), y.keys().collect::<Vec<_>>(), "{what}");
            for (k, p) in x {
                close_json(p, &y[k], &format!("{what}.{k}"));
            }
        }
        _ => assert_eq!(a, b, "{what}"),
    }
}

/// Asserts that the header read back equals the one written: exactly, except that the `f64`
/// numbers of `camera`, `light` and `extra` may be [`F64_ULPS`] apart when not [`strict`].
pub fn assert_same_header(written: &Header, read: &Header) {
    let strip = |h: &Header| Header { camera: None, light: None, extra: None, ..h.clone() };
    assert_eq!(strip(written), strip(read), "header round trip");
    let (a, b) = (serde_json::to_value(written).unwrap(), serde_json::to_value(read).unwrap());
    for key in ["camera", "light", "extra"] {
        close_json(&a[key], &b[key], key);
    }
}

/// CRC-32 (ISO-HDLC), bit by bit: independent of the `crc32fast` the crate uses.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
        }
    }
    !crc
}

#[cfg(test)]
mod tests {
    #[test]
    fn crc_check_value() {
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
    }
}
