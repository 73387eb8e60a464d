//! The writer: exact sample counts, value checks, no partial files, a header external parsers
//! read.

mod common;

use std::path::Path;

use common::{small_spec, small_values, write_small};
use sampleio::{encode_record, FieldSpec, FieldType, HeaderSpec, SampleError, SampleFile, SampleKind, SampleWriter};

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

#[test]
fn writes_through_a_temporary_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.lfrs");
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    w.push(&small_values(0)).unwrap();
    assert_eq!(files_in(dir.path()), [format!("s.lfrs.{}.tmp", std::process::id())]);
    for i in 1..12 {
        w.push(&small_values(i)).unwrap();
    }
    assert_eq!(w.pushed(), 12);
    assert_eq!(w.finish().unwrap(), path);
    assert_eq!(files_in(dir.path()), ["s.lfrs"]);
}

#[test]
fn too_few_samples_leave_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.lfrs");
    for pushed in [0, 1, 11] {
        let mut w = SampleWriter::create(&path, small_spec()).unwrap();
        for i in 0..pushed {
            w.push(&small_values(i)).unwrap();
        }
        let e = w.finish().unwrap_err();
        assert!(matches!(e, SampleError::TooFewSamples { expected: 12, pushed: p, .. } if p == pushed as u64), "{e}");
        assert!(e.to_string().contains("s.lfrs"), "{e}");
        assert!(files_in(dir.path()).is_empty(), "{:?}", files_in(dir.path()));
    }
}

#[test]
fn too_many_samples_leave_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.lfrs");
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    for i in 0..12 {
        w.push(&small_values(i)).unwrap();
    }
    let e = w.push(&small_values(12)).unwrap_err();
    assert!(matches!(e, SampleError::TooManySamples { expected: 12, .. }), "{e}");
    let e = w.finish().unwrap_err();
    assert!(matches!(e, SampleError::Aborted { .. }), "{e}");
    assert!(files_in(dir.path()).is_empty());

    // Raw records too.
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    let record = vec![0u8; w.header().record_size as usize];
    for _ in 0..12 {
        w.push_record(&record).unwrap();
    }
    assert!(matches!(w.push_record(&record), Err(SampleError::TooManySamples { .. })));
    assert!(w.finish().is_err());
    assert!(files_in(dir.path()).is_empty());
}

#[test]
fn dropping_an_unfinished_writer_removes_its_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.lfrs");
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    for i in 0..12 {
        w.push(&small_values(i)).unwrap();
    }
    drop(w);
    assert!(files_in(dir.path()).is_empty());
}

#[test]
fn a_finished_file_is_replaced_only_when_complete() {
    let dir = tempfile::tempdir().unwrap();
    let (path, before) = write_small(dir.path(), "s.lfrs");
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    w.push(&small_values(0)).unwrap();
    assert!(w.finish().is_err());
    assert_eq!(std::fs::read(&path).unwrap(), before);
}

#[test]
fn values_that_do_not_fit_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.lfrs");
    // (index in the value list, bad value, field name)
    let cases = [
        (1, 256.0, "id"),
        (1, -1.0, "id"),
        (1, f32::NAN, "id"),
        (5, 65536.0, "count"),
        (6, f32::INFINITY, "count"),
        (7, 4_294_967_296.0, "seed"),
        (7, f32::NAN, "seed"),
    ];
    for (k, bad, name) in cases {
        let mut w = SampleWriter::create(&path, small_spec()).unwrap();
        let mut values = small_values(0);
        values[k] = bad;
        let e = w.push(&values).unwrap_err();
        assert!(matches!(&e, SampleError::ValueOutOfRange { field, .. } if field == name), "{e}");
        assert!(matches!(w.push(&small_values(0)), Err(SampleError::Aborted { .. })));
        drop(w);
        assert!(files_in(dir.path()).is_empty());
    }
    // Floats take anything.
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    let mut values = small_values(0);
    values[0] = f32::NEG_INFINITY;
    values[2] = f32::NAN;
    values[3] = 1e9; // f16 overflow: infinity
    w.push(&values).unwrap();
    // Wrong lengths are errors.
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    let e = w.push(&[1.0; 7]).unwrap_err();
    assert!(matches!(e, SampleError::WrongLength { expected: 8, actual: 7, .. }), "{e}");
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    assert!(matches!(w.push_record(&[0; 3]), Err(SampleError::WrongLength { .. })));
}

#[test]
fn invalid_specs_are_refused_before_any_file_is_made() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.lfrs");
    let f = |name: &str| FieldSpec::new(name, FieldType::F32, 1);
    let cases: Vec<(HeaderSpec, &str)> = vec![
        (HeaderSpec::new(SampleKind::Ao, 0, 1, 1).field(f("a")), "width"),
        (HeaderSpec::new(SampleKind::Ao, 1, 70000, 1).field(f("a")), "height"),
        (HeaderSpec::new(SampleKind::Ao, 1, 1, 0).field(f("a")), "spp"),
        (HeaderSpec::new(SampleKind::Ao, 1, 1, 1), "fields"),
        (HeaderSpec::new(SampleKind::Ao, 1, 1, 1).field(f("a")).field(f("a")), "fields[1].name"),
        (HeaderSpec::new(SampleKind::Ao, 1, 1, 1).field(FieldSpec::new("a", FieldType::U8, 5)), "fields[0].components"),
        (HeaderSpec::new(SampleKind::Ao, 1, 1, 1).field(FieldSpec::new("a", FieldType::U8, 0)), "fields[0].components"),
        (HeaderSpec::new(SampleKind::Ao, 1, 1, 1).field(f("not ok")), "fields[0].name"),
        (HeaderSpec { chunk_samples: 0, ..HeaderSpec::new(SampleKind::Ao, 1, 1, 1).field(f("a")) }, "chunk_samples"),
    ];
    for (spec, key) in cases {
        let e = SampleWriter::create(&path, spec).unwrap_err();
        assert!(matches!(&e, SampleError::Invalid { field, .. } if field == key), "{key}: {e}");
        assert!(e.to_string().contains("s.lfrs"));
    }
    assert!(files_in(dir.path()).is_empty());
    // Missing folders are created (like every other output); a regular file among the
    // folders is refused, naming it, and nothing is made.
    std::fs::write(dir.path().join("plain"), b"x").unwrap();
    let e = SampleWriter::create(&dir.path().join("plain/sub/s.lfrs"), small_spec()).unwrap_err();
    assert!(matches!(e, SampleError::Io { .. }), "{e}");
    assert!(e.to_string().contains("plain"), "{e}");
    assert_eq!(files_in(dir.path()), vec!["plain".to_string()]);
    let deep = dir.path().join("no/such/dir/s.lfrs");
    let w = SampleWriter::create(&deep, small_spec()).unwrap();
    drop(w);
    assert!(dir.path().join("no/such/dir").is_dir());
}

#[test]
fn the_header_is_plain_json_and_the_data_is_aligned() {
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = write_small(dir.path(), "s.lfrs");
    assert_eq!(&bytes[..8], b"LFRSAMP\0");
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 1);
    let h = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    assert_eq!((16 + h) % 64, 0);
    let text = &bytes[16..16 + h];
    let v: serde_json::Value = serde_json::from_slice(text).unwrap();
    let end = text.iter().rposition(|&b| b != b' ').unwrap() + 1;
    assert_eq!(text[end - 1], b'}');
    let v2: serde_json::Value = serde_json::from_slice(&text[..end]).unwrap();
    assert_eq!(v, v2);
    assert_eq!(v["format"], "lfr-samples");
    assert_eq!(v["version"], 1);
    assert_eq!(v["kind"], "lens-time");
    assert_eq!(v["order"], "pixel-major");
    assert_eq!(v["sample_count"], 12);
    assert_eq!(v["record_size"], 20);
    assert_eq!(v["chunk_samples"], 5);
    assert_eq!(v["scene"], "test");
    assert_eq!(v["seed"], 7);
    let offsets: Vec<u64> = v["fields"].as_array().unwrap().iter().map(|f| f["offset"].as_u64().unwrap()).collect();
    assert_eq!(offsets, [0, 4, 6, 12, 16]);
    assert_eq!(v["fields"][2]["type"], "f16");
    assert_eq!(v["fields"][2]["components"], 3);
    assert_eq!(v["fields"][2]["unit"], "W/(m^2 sr)");
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(file.data_offset(), 16 + h);
    assert_eq!(file.data_offset() % 64, 0);
    // Trailer fields.
    let t = &bytes[bytes.len() - 32..];
    assert_eq!(&t[..8], b"LFRTAIL\0");
    assert_eq!(u64::from_le_bytes(t[8..16].try_into().unwrap()), 12);
    assert_eq!(u32::from_le_bytes(t[16..20].try_into().unwrap()), crc32fast::hash(text));
    let table = &bytes[16 + h + 12 * 20..bytes.len() - 32];
    assert_eq!(table.len(), 12);
    assert_eq!(u32::from_le_bytes(t[20..24].try_into().unwrap()), crc32fast::hash(table));
    assert_eq!(u64::from_le_bytes(t[24..32].try_into().unwrap()), 3);
    let data = &bytes[16 + h..16 + h + 12 * 20];
    assert_eq!(u32::from_le_bytes(table[..4].try_into().unwrap()), crc32fast::hash(&data[..100]));
    assert_eq!(u32::from_le_bytes(table[8..12].try_into().unwrap()), crc32fast::hash(&data[200..]));
}

#[test]
fn camera_light_and_extra_round_trip() {
    use sampleio::{Camera, Coc, FovAxis, LightGeometry};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cam.lfrs");
    let id = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
    let mut spec = small_spec();
    spec.camera = Some(Camera {
        position: [0.0, 1.0, 5.0],
        forward: [0.0, 0.0, -1.0],
        up: [0.0, 1.0, 0.0],
        right: [1.0, 0.0, 0.0],
        fov_deg: 39.3,
        fov_axis: FovAxis::Smaller,
        aperture_radius: 0.05,
        focus_distance: 4.5,
        coc: Coc { c1: -12.5, c2: 2.75 },
        shutter: [0.0, 0.5],
        pixel_to_camera: id,
        world_to_camera: id,
    });
    spec.light = Some(LightGeometry {
        corner: Some([-0.5, 2.0, -0.5]),
        edge_u: Some([1.0, 0.0, 0.0]),
        edge_v: Some([0.0, 0.0, 1.0]),
        normal: Some([0.0, -1.0, 0.0]),
        plane_distance: Some(-2.0),
    });
    spec.coordinates = Some([("x".to_string(), "pixels, centers at +0.5".to_string())].into());
    spec.extra = Some(serde_json::json!({"tracer": {"version": "0.1.0"}, "notes": [1, 2.5, null]}));
    let mut w = SampleWriter::create(&path, spec.clone()).unwrap();
    for i in 0..12 {
        w.push(&small_values(i)).unwrap();
    }
    w.finish().unwrap();
    let file = SampleFile::open(&path).unwrap();
    let h = file.header();
    assert_eq!(h.camera, spec.camera);
    assert_eq!(h.light, spec.light);
    assert_eq!(h.coordinates, spec.coordinates);
    assert_eq!(h.extra, spec.extra);
    assert_eq!(h.camera.as_ref().unwrap().coc.at(2.0), -12.5 / 2.0 + 2.75);
}

/// Records encoded apart (`encode_record`) and pushed in runs of any length, across chunk
/// boundaries, give the very file `push` gives sample by sample.
#[test]
fn records_pushed_in_runs_give_the_same_file_as_samples_pushed_one_by_one() {
    let dir = tempfile::tempdir().unwrap();
    let (_, expected) = write_small(dir.path(), "one-by-one.lfrs");
    for runs in [vec![12], vec![1; 12], vec![5, 5, 2], vec![4, 7, 1], vec![0, 3, 9]] {
        let path = dir.path().join("runs.lfrs");
        let mut w = SampleWriter::create(&path, small_spec()).unwrap();
        let size = w.header().record_size as usize;
        let mut next = 0;
        for run in runs.iter().copied() {
            let mut records = vec![0u8; run * size];
            for (i, record) in records.chunks_exact_mut(size).enumerate() {
                encode_record(w.header(), &small_values(next + i), record).unwrap();
            }
            w.push_records(&records).unwrap();
            next += run;
        }
        w.finish().unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), expected, "runs {runs:?}");
        SampleFile::open(&path).unwrap();
    }
    // A partial record, or more records than the header declares, abort the writer.
    let path = dir.path().join("bad.lfrs");
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    let size = w.header().record_size as usize;
    assert!(matches!(w.push_records(&vec![0; size + 1]), Err(SampleError::WrongLength { .. })));
    assert!(matches!(w.push_records(&vec![0; size]), Err(SampleError::Aborted { .. })));
    let mut w = SampleWriter::create(&path, small_spec()).unwrap();
    assert!(matches!(w.push_records(&vec![0; 13 * size]), Err(SampleError::TooManySamples { expected: 12, .. })));
    drop(w);
    assert!(files_in(dir.path()).iter().all(|name| name != "bad.lfrs"));
    // A value a field cannot hold names the field and component.
    let header = SampleWriter::create(&path, small_spec()).unwrap().header().clone();
    let mut values = small_values(0);
    values[6] = -1.0;
    let mut record = vec![0; size];
    let bad = encode_record(&header, &values, &mut record).unwrap_err();
    assert_eq!((bad.field.as_str(), bad.component, bad.ty), ("count", 1, FieldType::U16));
    assert!(bad.at(&path, 9).to_string().contains("bad.lfrs"));
}

/// The header a writer of `spec` lays out (the writer is dropped, leaving no file).
fn header_of(dir: &Path, spec: HeaderSpec) -> sampleio::Header {
    SampleWriter::create(&dir.join("layout.lfrs"), spec).unwrap().header().clone()
}

/// The oracle of the encoders: each value on its own through `FieldType::encode`, at its
/// field's offset plus its component times the type's size; the first value no field can hold
/// as (sample, field, component).
fn encode_value_by_value(
    header: &sampleio::Header,
    values: &[f32],
    records: &mut [u8],
) -> Result<(), (usize, String, u32)> {
    let per_sample = header.values_per_sample();
    let size = header.record_size as usize;
    for (sample, (values, record)) in values.chunks_exact(per_sample).zip(records.chunks_exact_mut(size)).enumerate() {
        let mut values = values.iter();
        for field in &header.fields {
            for component in 0..field.components {
                let start = field.offset as usize + component as usize * field.ty.size();
                let value = *values.next().unwrap();
                if !field.ty.encode(value, &mut record[start..start + field.ty.size()]) {
                    return Err((sample, field.name.clone(), component));
                }
            }
        }
    }
    Ok(())
}

proptest::proptest! {
    /// `encode_records` (one pass over a packed all-`f32` record, else record by record) and
    /// `encode_record` on each sample in turn give the bytes of encoding value by value, and on
    /// a value no field can hold, the first such sample's index, field and component.
    #[test]
    fn encoding_many_records_matches_encoding_them_one_by_one(
        fields in proptest::collection::vec((0usize..5, 1u32..4), 1..5),
        samples in 0usize..6,
        seed in 0u64..1 << 32,
        all_f32 in proptest::bool::ANY,
    ) {
        let dir = tempfile::tempdir().unwrap();
        let types = [FieldType::F32, FieldType::F16, FieldType::U8, FieldType::U16, FieldType::U32];
        let mut spec = HeaderSpec::new(SampleKind::LensTime, 1, 1, 1);
        for (i, (ty, components)) in fields.iter().enumerate() {
            let ty = if all_f32 { FieldType::F32 } else { types[*ty] };
            spec = spec.field(FieldSpec::new(format!("f{i}"), ty, *components));
        }
        let header = header_of(dir.path(), spec);
        let per_sample = header.values_per_sample();
        let size = header.record_size as usize;
        // Mostly small non-negative values; now and then one an integer field cannot hold.
        let mut state = seed;
        let values: Vec<f32> = (0..samples * per_sample)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                match state >> 58 {
                    0 => -3.0,
                    1 => f32::NAN,
                    2 => f32::INFINITY,
                    r => (r as f32) * 1.37,
                }
            })
            .collect();
        let mut expected = vec![0u8; samples * size];
        let expected_error = encode_value_by_value(&header, &values, &mut expected).err();
        let mut one_by_one = vec![0u8; samples * size];
        let mut one_by_one_error = None;
        for (at, (v, record)) in values.chunks_exact(per_sample).zip(one_by_one.chunks_exact_mut(size)).enumerate() {
            if let Err(bad) = encode_record(&header, v, record) {
                one_by_one_error = Some((at, bad.field, bad.component));
                break;
            }
        }
        proptest::prop_assert_eq!(&one_by_one_error, &expected_error);
        if expected_error.is_none() {
            proptest::prop_assert_eq!(&one_by_one, &expected);
        }
        let mut records = vec![0u8; samples * size];
        match (sampleio::encode_records(&header, &values, &mut records), expected_error) {
            (Ok(()), None) => proptest::prop_assert_eq!(records, expected),
            (Err((at, bad)), Some((expected_at, field, component))) => {
                proptest::prop_assert_eq!((at, bad.field, bad.component), (expected_at, field, component));
            }
            (got, wanted) => proptest::prop_assert!(false, "got {got:?}, expected {wanted:?}"),
        }
    }
}
