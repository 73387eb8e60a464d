//! Benchmark: the ambient-occlusion image (`ambient_occlusion_frame`, path tracing's rung in
//! `lfr compare --effect ao`) against the `ao` dump of the same samples (`box`'s input), on the
//! Cornell box at 256², 1 and 4 spp, all cores and one thread; prints each median of five and
//! their ratio. The two trace the same rays, so the ratio should be near 1 (the dump also
//! encodes and writes its records). Run from the repository root:
//! `cargo run --release -p tracer --example ao_image_vs_dump`.

use std::time::Instant;

use tracer::samples::secondary::{ambient_occlusion_frame, dump, SecondaryKind};
use tracer::samples::FieldSelection;
use tracer::{Accel, RenderSettings, Scene};

fn median(mut times: Vec<f64>) -> f64 {
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

fn main() {
    let scene = Scene::load(std::path::Path::new("scenes/cornell.toml")).expect("run from the repository root");
    let accel = Accel::build(&scene).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let fields = FieldSelection::named(["x", "y", "distance", "origin_normal"]);
    for threads in [0usize, 1] {
        for spp in [1u32, 4] {
            let settings =
                RenderSettings { width: 256, height: 256, spp, seed: 1, max_bounces: 4, threads, progress: false };
            let (mut image, mut dumped) = (Vec::new(), Vec::new());
            for _ in 0..5 {
                let start = Instant::now();
                ambient_occlusion_frame(&scene, &accel, &settings, 1.0).unwrap();
                image.push(start.elapsed().as_secs_f64());
                let start = Instant::now();
                dump(&scene, &accel, &settings, SecondaryKind::AmbientOcclusion, &fields, &dir.path().join("ao.lfrs"))
                    .unwrap();
                dumped.push(start.elapsed().as_secs_f64());
            }
            let (image, dumped) = (median(image), median(dumped));
            println!(
                "threads {threads}, {spp} spp: image {image:.4} s, dump {dumped:.4} s, image / dump {:.2}",
                image / dumped
            );
        }
    }
}
