//! Write-then-read round trips over random field lists, sizes, chunk sizes and values.

use proptest::prelude::*;
use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleFile, SampleKind, SampleWriter};

fn field_type() -> impl Strategy<Value = FieldType> {
    prop::sample::select(FieldType::ALL.to_vec())
}

/// A value the writer must store: anything (NaN and infinities included) for floats, exact
/// integers in range for integer types (u32 only up to 2^24, where f32 is exact).
fn value(ty: FieldType) -> BoxedStrategy<f32> {
    match ty {
        FieldType::F32 | FieldType::F16 => prop_oneof![
            4 => prop::num::f32::ANY,
            1 => Just(f32::NAN),
            1 => Just(f32::INFINITY),
            1 => Just(f32::NEG_INFINITY),
            1 => -70000.0f32..70000.0,
        ]
        .boxed(),
        FieldType::U8 => (0u32..=255).prop_map(|v| v as f32).boxed(),
        FieldType::U16 => (0u32..=65535).prop_map(|v| v as f32).boxed(),
        FieldType::U32 => prop_oneof![(0u32..=1 << 24).prop_map(|v| v as f32), Just(4_294_967_040.0f32)].boxed(),
    }
}

/// What reading back `v` stored as `ty` must give.
fn stored(ty: FieldType, v: f32) -> f32 {
    match ty {
        FieldType::F16 => half::f16::from_f32(v).to_f32(),
        _ => v,
    }
}

fn same(a: f32, b: f32) -> bool {
    (a.is_nan() && b.is_nan()) || a.to_bits() == b.to_bits()
}

#[derive(Debug, Clone)]
struct Case {
    fields: Vec<(FieldType, u32)>,
    width: u32,
    height: u32,
    spp: u32,
    chunk_samples: u32,
    values: Vec<Vec<f32>>,
}

fn case() -> impl Strategy<Value = Case> {
    (prop::collection::vec((field_type(), 1u32..=4), 1..=6), 1u32..=4, 1u32..=3, 1u32..=3, 1u32..=10).prop_flat_map(
        |(fields, width, height, spp, chunk_samples)| {
            let per_sample: Vec<BoxedStrategy<f32>> =
                fields.iter().flat_map(|&(ty, n)| (0..n).map(move |_| value(ty))).collect();
            let n = (width * height * spp) as usize;
            prop::collection::vec(per_sample, n).prop_map(move |values| Case {
                fields: fields.clone(),
                width,
                height,
                spp,
                chunk_samples,
                values,
            })
        },
    )
}

fn spec(case: &Case) -> HeaderSpec {
    let mut spec = HeaderSpec::new(SampleKind::Indirect, case.width, case.height, case.spp);
    for (i, &(ty, n)) in case.fields.iter().enumerate() {
        spec = spec.field(FieldSpec::new(format!("f{i}"), ty, n).meaning(format!("field {i}")).unit("u"));
    }
    spec.chunk_samples = case.chunk_samples;
    spec
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    #[test]
    fn values_round_trip(case in case()) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.lfrs");
        let mut w = SampleWriter::create(&path, spec(&case)).unwrap();
        let written_header = w.header().clone();
        for v in &case.values {
            w.push(v).unwrap();
        }
        prop_assert_eq!(w.finish().unwrap(), path.clone());

        let file = SampleFile::open(&path).unwrap();
        prop_assert_eq!(file.header(), &written_header);
        prop_assert_eq!(file.len(), case.values.len());
        prop_assert_eq!(file.data_offset() % 64, 0);
        let chunks = (case.values.len() as u64).div_ceil(u64::from(case.chunk_samples));
        let expected_size = file.data_offset() as u64
            + case.values.len() as u64 * u64::from(file.header().record_size)
            + 4 * chunks
            + 32;
        prop_assert_eq!(std::fs::metadata(&path).unwrap().len(), expected_size);

        for (i, values) in case.values.iter().enumerate() {
            let mut k = 0;
            for field in file.fields() {
                for c in 0..field.components as usize {
                    let want = stored(field.ty, values[k]);
                    let got = file.value(i, field, c);
                    prop_assert!(same(got, want), "sample {} field {} comp {}: {} != {}", i, field.name, c, got, want);
                    prop_assert!(same(file.value_f64(i, field, c) as f32, want));
                    k += 1;
                }
            }
        }
        for field in file.fields() {
            let column = file.column(&field.name).unwrap();
            let n = field.components as usize;
            prop_assert_eq!(column.len(), file.len() * n);
            for (j, &got) in column.iter().enumerate() {
                prop_assert!(same(got, file.value(j / n, field, j % n)));
            }
        }
        let h = file.header();
        for y in 0..h.height {
            for x in 0..h.width {
                let r = file.pixel_samples(x, y);
                prop_assert_eq!(r.start, ((y * h.width + x) * h.spp) as usize);
                prop_assert_eq!(r.len(), h.spp as usize);
                // The pixel's records, decoded per record, give `value`'s values.
                let records = file.pixel_records(x, y);
                prop_assert_eq!(records.len(), r.len() * h.record_size as usize);
                for (sample, record) in r.zip(records.chunks_exact(h.record_size as usize)) {
                    prop_assert_eq!(record, file.record(sample));
                    for field in file.fields() {
                        for c in 0..field.components as usize {
                            prop_assert!(same(field.decode_from(record, c), file.value(sample, field, c)));
                        }
                    }
                }
            }
        }
    }

    /// Raw records come back byte for byte, and `value_f64` decodes every type exactly (u32
    /// over its whole range included).
    #[test]
    fn raw_records_round_trip(
        fields in prop::collection::vec((field_type(), 1u32..=4), 1..=5),
        n in 1u32..=20,
        chunk_samples in 1u32..=8,
        seed in any::<u64>(),
    ) {
        let mut spec = HeaderSpec::new(SampleKind::Ao, n, 1, 1);
        for (i, &(ty, c)) in fields.iter().enumerate() {
            spec = spec.field(FieldSpec::new(format!("f{i}"), ty, c));
        }
        spec.chunk_samples = chunk_samples;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("raw.lfrs");
        let mut w = SampleWriter::create(&path, spec).unwrap();
        let rs = w.header().record_size as usize;
        let mut state = seed;
        let records: Vec<Vec<u8>> = (0..n)
            .map(|_| {
                (0..rs)
                    .map(|_| {
                        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        (state >> 56) as u8
                    })
                    .collect()
            })
            .collect();
        for r in &records {
            w.push_record(r).unwrap();
        }
        w.finish().unwrap();
        let file = SampleFile::open(&path).unwrap();
        for (i, r) in records.iter().enumerate() {
            prop_assert_eq!(file.record(i), &r[..]);
            for f in file.fields() {
                for c in 0..f.components as usize {
                    let at = f.offset as usize + c * f.ty.size();
                    let b = &r[at..at + f.ty.size()];
                    let want = match f.ty {
                        FieldType::F32 => f64::from(f32::from_le_bytes(b.try_into().unwrap())),
                        FieldType::F16 => f64::from(half::f16::from_le_bytes(b.try_into().unwrap())),
                        FieldType::U32 => f64::from(u32::from_le_bytes(b.try_into().unwrap())),
                        FieldType::U16 => f64::from(u16::from_le_bytes(b.try_into().unwrap())),
                        FieldType::U8 => f64::from(b[0]),
                    };
                    let got = file.value_f64(i, f, c);
                    prop_assert!((got.is_nan() && want.is_nan()) || got == want);
                }
            }
        }
    }
}

#[test]
fn one_by_one_by_one() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("one.lfrs");
    let spec = HeaderSpec::new(SampleKind::Light, 1, 1, 1).field(FieldSpec::new("z", FieldType::F32, 1));
    let mut w = SampleWriter::create(&path, spec).unwrap();
    w.push(&[42.5]).unwrap();
    w.finish().unwrap();
    let file = SampleFile::open(&path).unwrap();
    assert_eq!(file.len(), 1);
    assert_eq!(file.header().record_size, 4);
    assert_eq!(file.header().chunk_count(), 1);
    assert_eq!(file.column("z").unwrap(), [42.5]);
    assert_eq!(file.pixel_samples(0, 0), 0..1);
    assert_eq!(std::fs::metadata(&path).unwrap().len(), file.data_offset() as u64 + 4 + 4 + 32);
}

/// Sample counts around multiples of a small chunk size: the last chunk is shorter, the table
/// has one CRC per chunk, and damage is reported in the right chunk.
#[test]
fn chunk_boundaries() {
    let dir = tempfile::tempdir().unwrap();
    for n in 1..=30u32 {
        let path = dir.path().join(format!("c{n}.lfrs"));
        let mut spec = HeaderSpec::new(SampleKind::LensTime, n, 1, 1)
            .field(FieldSpec::new("t", FieldType::F16, 1))
            .field(FieldSpec::new("k", FieldType::U8, 3));
        spec.chunk_samples = 7;
        let mut w = SampleWriter::create(&path, spec).unwrap();
        for i in 0..n {
            w.push(&[i as f32 / 32.0, 1.0, 2.0, (i % 200) as f32]).unwrap();
        }
        w.finish().unwrap();
        let file = SampleFile::open(&path).unwrap();
        let chunks = u64::from(n.div_ceil(7));
        assert_eq!(file.header().chunk_count(), chunks);
        assert_eq!(file.header().record_size, 8);
        let mut bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len() as u64, file.data_offset() as u64 + 8 * u64::from(n) + 4 * chunks + 32);
        let trailer = &bytes[bytes.len() - 32..];
        assert_eq!(u64::from_le_bytes(trailer[24..32].try_into().unwrap()), chunks);
        assert_eq!(u64::from_le_bytes(trailer[8..16].try_into().unwrap()), u64::from(n));
        for i in 0..n as usize {
            assert_eq!(file.value(i, file.field("t").unwrap(), 0), i as f32 / 32.0);
        }
        // Damage the last data byte: the last chunk is blamed.
        let last = file.data_offset() + 8 * n as usize - 1;
        drop(file);
        bytes[last] ^= 0x10;
        std::fs::write(&path, &bytes).unwrap();
        match SampleFile::open(&path) {
            Err(sampleio::SampleError::Corrupted { chunk, first_sample, .. }) => {
                assert_eq!(chunk, chunks - 1);
                assert_eq!(first_sample, (chunks - 1) * 7);
            }
            other => panic!("n = {n}: expected Corrupted, got {other:?}"),
        }
    }
}
