//! ILFR's preprocessing timed on a kept sample file: the stage times of `ilfr` (sizing,
//! hierarchy, shrinking, robust radiance), the median of REPEATS runs in one process, and a
//! hash of the image's bits, so that two builds can be compared for speed and for identical
//! output (measurement tool for docs/ilfr.md).
//!
//! ```sh
//! lfr dump --scene scenes/cornell.toml --kind indirect --width 128 --height 128 --spp 4 --seed 1 --out cornell.lfrs
//! cargo run --release -p recon --example ilfr_preprocess -- cornell.lfrs SPEC RAYS [REPEATS] [EFFECT]
//! ```
//!
//! SPEC is a method spec (`ilfr`, `ilfr:variant=paper`, …), RAYS the reconstruction rays per
//! pixel (1 makes the gather small beside the preprocessing), EFFECT `indirect` unless given.

use std::path::PathBuf;

use recon::method::{Effect, InputData, Inputs};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 4 {
        eprintln!("usage: ilfr_preprocess SAMPLES SPEC RAYS [REPEATS] [EFFECT]");
        std::process::exit(2);
    }
    let samples_path = PathBuf::from(&args[1]);
    let method = recon::registry::find(&args[2]).expect("spec").unwrap_or_else(|| panic!("no method {}", args[2]));
    let rays: u32 = args[3].parse().expect("rays");
    let repeats: usize = args.get(4).map_or(1, |r| r.parse().expect("repeats"));
    let effect = Effect::from_name(args.get(5).map_or("indirect", |e| e.as_str())).expect("effect");
    let file = sampleio::SampleFile::open(&samples_path).expect("samples");
    let header = recon::ilfr::samples::read_indirect(&file).expect("read");
    drop(file);
    let inputs = Inputs {
        effect,
        width: header.width,
        height: header.height,
        spp: header.spp.max(1),
        data: InputData::Samples { samples: &samples_path, light_samples: None },
        ao_radius: 1.0,
        seed: 1,
        threads: 0,
    };
    let stages = ["sizing_s", "hierarchy_s", "shrinking_s", "robust_s", "gather_s"];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); stages.len()];
    let mut hash = 0u64;
    for _ in 0..repeats.max(1) {
        let out = method.run(&inputs, rays).expect("run");
        for (t, stage) in times.iter_mut().zip(stages) {
            t.push(out.stats.get(stage).copied().unwrap_or(f64::NAN));
        }
        // FNV-1a over the image's bits: equal hashes, equal images.
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for c in out.image.pixels.iter().flatten() {
            for b in c.to_bits().to_le_bytes() {
                h = (h ^ b as u64).wrapping_mul(0x100_0000_01b3);
            }
        }
        hash = h;
    }
    let line: Vec<String> = stages.iter().zip(times).map(|(s, t)| format!("{s} {:.4}", median(t))).collect();
    println!("{} {} rays: {}; image {hash:016x}", args[2], rays, line.join(", "));
}
