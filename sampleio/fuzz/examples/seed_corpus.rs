//! Writes seed inputs for the fuzz targets: valid sample files for `open_file` (random bytes
//! rarely get past the magic, let alone the CRCs) and a few recipes for `roundtrip_mutate`.
//!
//! ```sh
//! cd sampleio/fuzz
//! CARGO_TARGET_DIR=/tmp/fuzz-target cargo run --example seed_corpus -- corpus
//! ```
//!
//! writes `corpus/open_file/*.lfrs` and `corpus/roundtrip_mutate/seed-*`.

use std::path::Path;

use sampleio::{
    Camera, Coc, FieldSpec, FieldType, FovAxis, HeaderSpec, LightGeometry, SampleFile, SampleKind, SampleWriter,
};

fn write(path: &Path, spec: HeaderSpec, value: impl Fn(usize, usize) -> f32) {
    let mut w = SampleWriter::create(path, spec).expect("create");
    let n = w.header().sample_count as usize;
    let k = w.header().values_per_sample();
    for i in 0..n {
        let values: Vec<f32> = (0..k).map(|c| value(i, c)).collect();
        w.push(&values).expect("push");
    }
    w.finish().expect("finish");
    SampleFile::open(path).expect("the seed file opens");
    println!("{} ({} bytes)", path.display(), std::fs::metadata(path).unwrap().len());
}

fn main() {
    let root = std::env::args().nth(1).unwrap_or_else(|| "corpus".into());
    let open = Path::new(&root).join("open_file");
    let recipes = Path::new(&root).join("roundtrip_mutate");
    std::fs::create_dir_all(&open).unwrap();
    std::fs::create_dir_all(&recipes).unwrap();

    // Every type, 3x2 pixels, 2 spp, chunks of 5 samples (5, 5, 2): the integration tests' file.
    let mut spec = HeaderSpec::new(SampleKind::LensTime, 3, 2, 2)
        .field(FieldSpec::new("x", FieldType::F32, 1).meaning("pixel x").unit("px"))
        .field(FieldSpec::new("id", FieldType::U8, 1).meaning("object id"))
        .field(FieldSpec::new("radiance", FieldType::F16, 3).meaning("RGB radiance").unit("W/(m^2 sr)"))
        .field(FieldSpec::new("count", FieldType::U16, 2))
        .field(FieldSpec::new("seed", FieldType::U32, 1));
    spec.chunk_samples = 5;
    spec.scene = Some("test".into());
    spec.seed = Some(7);
    write(&open.join("mixed.lfrs"), spec, |i, c| match c {
        0 => i as f32 + 0.5,
        1 => (i % 256) as f32,
        2..=4 if i == 3 => f32::NAN,
        2..=4 => 0.25 * (i + c) as f32,
        5 | 6 => (i * 3 + c) as f32,
        _ => 1e6 + i as f32,
    });

    // A lens-time file like `lfr dump` writes: camera, coordinates, extra; one chunk.
    let mut spec = HeaderSpec::new(SampleKind::LensTime, 2, 2, 2);
    for name in ["x", "y", "u", "v", "t", "z"] {
        spec = spec.field(FieldSpec::new(name, FieldType::F32, 1));
    }
    spec = spec.field(FieldSpec::new("radiance", FieldType::F32, 3)).field(FieldSpec::new(
        "depth_gradient",
        FieldType::F32,
        2,
    ));
    spec.camera = Some(Camera {
        position: [0.0, 1.0, 6.8],
        forward: [0.0, 0.0, -1.0],
        up: [0.0, 1.0, 0.0],
        right: [1.0, 0.0, 0.0],
        fov_deg: 39.3,
        fov_axis: FovAxis::Y,
        aperture_radius: 0.05,
        focus_distance: 6.0,
        coc: Coc { c1: -27.1, c2: 4.52 },
        shutter: [0.0, 1.0],
        pixel_to_camera: [
            [0.0018, 0.0, -0.576, 0.0],
            [0.0, -0.0018, 0.324, 0.0],
            [0.0, 0.0, -1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
        world_to_camera: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, -1.0], [0.0, 0.0, 1.0, -6.8], [0.0, 0.0, 0.0, 1.0]],
    });
    spec.coordinates = Some([("x".to_string(), "pixels, 0..width".to_string())].into());
    spec.extra = Some(serde_json::json!({"tracer": {"spp": 2, "note": "seed"}}));
    write(&open.join("lens_time_camera.lfrs"), spec, |i, c| {
        if c == 5 && i % 3 == 0 {
            f32::INFINITY
        } else {
            (i * 10 + c) as f32 * 0.1
        }
    });

    // A light file: light geometry, u8 and u16 fields, one sample per chunk.
    let mut spec = HeaderSpec::new(SampleKind::Light, 2, 1, 3)
        .field(FieldSpec::new("hit", FieldType::U8, 3))
        .field(FieldSpec::new("index", FieldType::U16, 1))
        .field(FieldSpec::new("w", FieldType::F16, 1));
    spec.chunk_samples = 1;
    spec.light = Some(LightGeometry {
        corner: Some([-0.5, 1.98, -0.5]),
        edge_u: Some([1.0, 0.0, 0.0]),
        edge_v: Some([0.0, 0.0, 1.0]),
        normal: Some([0.0, -1.0, 0.0]),
        plane_distance: Some(-1.98),
    });
    write(&open.join("light_chunks_of_1.lfrs"), spec, |i, c| (i * 7 + c) as f32);

    // One sample, one u8: the smallest file.
    write(
        &open.join("ao_smallest.lfrs"),
        HeaderSpec::new(SampleKind::Ao, 1, 1, 1).field(FieldSpec::new("a", FieldType::U8, 1)),
        |_, _| 1.0,
    );

    // Recipes for roundtrip_mutate: any bytes are a recipe; these are just starting points.
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    for (i, len) in [16usize, 64, 256, 1024].into_iter().enumerate() {
        let bytes: Vec<u8> = (0..len)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state as u8
            })
            .collect();
        std::fs::write(recipes.join(format!("seed-{i}")), bytes).unwrap();
    }
    std::fs::write(recipes.join("seed-zeros"), [0u8; 128]).unwrap();
    println!("recipes in {}", recipes.display());
}
