//! The numpy reader in `docs/tools/read_samples.py` reads what the Rust writer writes, with the
//! same values. This test fails (it does not skip) when python3 or numpy is missing.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::write_small;
use sampleio::SampleFile;
use serde_json::Value;

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/tools/read_samples.py")
}

fn run_python(args: &[&Path]) -> Output {
    let mut cmd = Command::new("python3");
    cmd.arg(script()).args(args);
    match cmd.output() {
        Ok(out) => out,
        Err(e) => panic!(
            "cannot run python3 ({e}): this test needs Python 3.9+ with numpy on PATH \
             (install Python, then `pip install numpy`)"
        ),
    }
}

fn check_numpy() {
    let out = Command::new("python3").args(["-c", "import numpy"]).output().unwrap_or_else(|e| {
        panic!("cannot run python3 ({e}): this test needs Python 3.9+ with numpy (`pip install numpy`)")
    });
    assert!(
        out.status.success(),
        "python3 cannot import numpy, which docs/tools/read_samples.py needs: `pip install numpy`\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A number from the Python report: a JSON number or "nan" / "inf" / "-inf".
fn number(v: &Value) -> f64 {
    match v {
        Value::Number(n) => n.as_f64().unwrap(),
        Value::String(s) if s == "nan" => f64::NAN,
        Value::String(s) if s == "inf" => f64::INFINITY,
        Value::String(s) if s == "-inf" => f64::NEG_INFINITY,
        other => panic!("not a number: {other}"),
    }
}

#[test]
fn numpy_reader_agrees_with_the_rust_reader() {
    check_numpy();
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = write_small(dir.path(), "mixed.lfrs");
    let report_path = dir.path().join("report.json");
    let out = run_python(&[&path, Path::new("--json"), &report_path]);
    assert!(
        out.status.success(),
        "read_samples.py failed (if numpy is missing: `pip install numpy`):\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("kind lens-time") && stdout.contains("12 samples"), "{stdout}");

    let report: Value = serde_json::from_slice(&std::fs::read(&report_path).unwrap()).unwrap();
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(report["header"], serde_json::to_value(file.header()).unwrap());
    assert_eq!(report["sample_count"], 12);
    let fields = report["fields"].as_object().unwrap();
    assert_eq!(fields.len(), file.fields().len());
    for field in file.fields() {
        let r = &report["fields"][&field.name];
        let n = field.components as usize;
        assert_eq!(r["type"], field.ty.name());
        let first = r["first"].as_array().unwrap();
        assert_eq!(first.len(), 5);
        for (i, row) in first.iter().enumerate() {
            let row = row.as_array().unwrap();
            assert_eq!(row.len(), n);
            for (c, v) in row.iter().enumerate() {
                let (py, rs) = (number(v), file.value_f64(i, field, c));
                assert!((py.is_nan() && rs.is_nan()) || py == rs, "{}[{i}][{c}]: python {py}, rust {rs}", field.name);
            }
        }
        let means = r["mean"].as_array().unwrap();
        assert_eq!(means.len(), n);
        for (c, m) in means.iter().enumerate() {
            let values: Vec<f64> =
                (0..file.len()).map(|i| file.value_f64(i, field, c)).filter(|v| !v.is_nan()).collect();
            let mean = values.iter().sum::<f64>() / values.len() as f64;
            let py = number(m);
            assert!(
                (py - mean).abs() <= 1e-12 * mean.abs().max(1.0),
                "{} mean[{c}]: python {py}, rust {mean}",
                field.name
            );
        }
    }
    // The NaN in radiance (sample 3) is skipped by the mean, not propagated.
    assert!(number(&report["fields"]["radiance"]["mean"][2]).is_finite());

    // Damage is found by the Python reader too, and `--no-verify` skips only the data CRCs.
    let (data, _, _) = common::parts(&bytes);
    let mut damaged = bytes.clone();
    damaged[data + 3] ^= 0x40;
    let bad = dir.path().join("bad.lfrs");
    std::fs::write(&bad, &damaged).unwrap();
    let out = run_python(&[&bad]);
    assert_eq!(out.status.code(), Some(1), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("chunk 0"), "{}", String::from_utf8_lossy(&out.stderr));
    let out = run_python(&[&bad, Path::new("--no-verify")]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let truncated = dir.path().join("short.lfrs");
    std::fs::write(&truncated, &bytes[..bytes.len() - 1]).unwrap();
    let out = run_python(&[&truncated, Path::new("--no-verify")]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("truncated"));
}

/// A file assembled by hand in Python from the spec alone (numpy structured array, zlib CRCs)
/// opens in Rust with the same values: the spec, not just our writer, defines the format.
#[test]
fn rust_reads_a_file_built_from_the_spec_in_python() {
    check_numpy();
    const BUILD: &str = r#"
import json, struct, sys, zlib
import numpy as np
fields = [
    {"name": "x", "type": "f32", "components": 1, "offset": 0, "meaning": "", "unit": "px"},
    {"name": "rgb", "type": "f16", "components": 3, "offset": 4, "meaning": "", "unit": ""},
    {"name": "id", "type": "u8", "components": 1, "offset": 10, "meaning": "", "unit": ""},
    {"name": "n", "type": "u32", "components": 2, "offset": 12, "meaning": "", "unit": ""},
]
h = {"format": "lfr-samples", "version": 1, "kind": "indirect", "width": 2, "height": 2, "spp": 3,
     "sample_count": 12, "order": "pixel-major", "record_size": 20, "fields": fields, "chunk_samples": 5}
text = json.dumps(h).encode()
text += b" " * ((-(16 + len(text))) % 64)
dt = np.dtype({"names": ["x", "rgb", "id", "n"], "formats": ["<f4", ("<f2", (3,)), "u1", ("<u4", (2,))],
               "offsets": [0, 4, 10, 12], "itemsize": 20})
rec = np.zeros(12, dtype=dt)
rec["x"] = np.arange(12) + 0.5
rec["rgb"] = np.arange(36).reshape(12, 3) / 4
rec["id"] = np.arange(12) * 20
rec["n"] = np.array([[i, 4294967295 - i] for i in range(12)])
data = rec.tobytes()
table = b"".join(struct.pack("<I", zlib.crc32(data[i:i + 100])) for i in range(0, len(data), 100))
trailer = b"LFRTAIL\0" + struct.pack("<QIIQ", 12, zlib.crc32(text), zlib.crc32(table), len(table) // 4)
with open(sys.argv[1], "wb") as f:
    f.write(b"LFRSAMP\0" + struct.pack("<II", 1, len(text)) + text + data + table + trailer)
"#;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("from_python.lfrs");
    let out = Command::new("python3").arg("-c").arg(BUILD).arg(&path).output().expect("python3 runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(file.header().kind, sampleio::SampleKind::Indirect);
    assert_eq!(file.header().chunk_count(), 3);
    assert_eq!(file.column("x").unwrap(), (0..12).map(|i| i as f32 + 0.5).collect::<Vec<_>>());
    assert_eq!(file.column("rgb").unwrap(), (0..36).map(|i| i as f32 / 4.0).collect::<Vec<_>>());
    assert_eq!(file.column("id").unwrap(), (0..12).map(|i| (i * 20) as f32).collect::<Vec<_>>());
    let n = file.field("n").unwrap();
    for i in 0..12 {
        assert_eq!(file.value_f64(i, n, 0), i as f64);
        assert_eq!(file.value_f64(i, n, 1), (u32::MAX - i as u32) as f64);
    }
    assert_eq!(file.pixel_samples(1, 1), 9..12);
}
