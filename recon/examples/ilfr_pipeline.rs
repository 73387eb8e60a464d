//! ILFR alone and ILFR then OIDN on a kept sample file, against a reference EXR (measurement
//! tool for docs/ilfr.md; `lfr compare` runs the same methods with tracing and timing of its own).
//!
//! ```sh
//! cargo run --release -p recon --example ilfr_pipeline -- SAMPLES.lfrs REFERENCE.exr EFFECT SPEC[,SPEC…] RAYS[,RAYS…] [REPEATS]
//! ```
//!
//! For every method spec (`ilfr`, `ilfr:variant=paper`, …) and ray count: PSNR (the comparison's
//! tone map: the reference's 99th-percentile luminance → 1), relative MSE, the method's time
//! split (median of REPEATS runs, in this one process, specs interleaved), then the same image
//! through OIDN with the albedo and normal of the file's primary hits (pixel means), and OIDN's
//! own time (the warm execute call, as the `oidn` method reports it).

use std::path::PathBuf;

use exr::prelude::*;
use recon::baselines::oidn::Oidn;
use recon::ilfr::samples::{read_indirect, SampleClass};
use recon::method::{Effect, ImageInput, InputData, Inputs, Method};
use recon::metrics::{psnr_db, relative_mse, ToneMap};
use recon::Image;

fn read_reference(path: &str) -> Image {
    let image = read_all_flat_layers_from_file(path).expect("reference EXR");
    let layer = &image.layer_data[0];
    let (w, h) = (layer.size.0 as u32, layer.size.1 as u32);
    let channel = |suffix: &str| -> Vec<f32> {
        let c = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string().ends_with(suffix))
            .unwrap_or_else(|| panic!("no channel {suffix}"));
        c.sample_data.values_as_f32().collect()
    };
    let (r, g, b) = (channel("R"), channel("G"), channel("B"));
    Image::from_pixels(w, h, (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 6 {
        eprintln!("usage: ilfr_pipeline SAMPLES REFERENCE EFFECT SPECS RAYS [REPEATS]");
        std::process::exit(2);
    }
    let samples_path = PathBuf::from(&args[1]);
    let reference = read_reference(&args[2]);
    let effect = Effect::from_name(&args[3]).expect("effect");
    let specs: Vec<&str> = args[4].split(',').collect();
    let rays: Vec<u32> = args[5].split(',').map(|r| r.parse().expect("rays")).collect();
    let repeats: usize = args.get(6).map_or(1, |r| r.parse().expect("repeats"));
    let ao_radius: f32 = std::env::var("AO_RADIUS").ok().map_or(1.0, |r| r.parse().expect("AO_RADIUS"));
    let tone = ToneMap::auto(&reference);

    let file = sampleio::SampleFile::open(&samples_path).expect("samples");
    let samples = read_indirect(&file).expect("read");
    drop(file);
    let (width, height, spp) = (samples.width, samples.height, samples.spp.max(1));
    // OIDN's guides: the pixel means of the primary hits' albedo and normal.
    let mut albedo = Image::new(width, height);
    let mut normal = Image::new(width, height);
    for p in 0..(width * height) as usize {
        let (mut a, mut n) = ([0.0f32; 3], [0.0f32; 3]);
        for i in p * spp as usize..(p + 1) * spp as usize {
            if samples.class[i] == SampleClass::CameraMiss {
                continue;
            }
            let ai = samples.albedo.as_ref().map_or([1.0; 3], |al| al[i]);
            for c in 0..3 {
                a[c] += ai[c] / spp as f32;
                n[c] += samples.primary_normal[i][c] / spp as f32;
            }
        }
        albedo.pixels[p] = a;
        normal.pixels[p] = n;
    }
    let methods: Vec<_> = specs
        .iter()
        .map(|s| recon::registry::find(s).expect("spec").unwrap_or_else(|| panic!("no method {s}")))
        .collect();
    let inputs = Inputs {
        effect,
        width,
        height,
        spp,
        data: InputData::Samples { samples: &samples_path, light_samples: None },
        ao_radius,
        seed: 1,
        threads: 0,
    };
    println!("spec\trays\tpsnr\trelmse\toidn_psnr\toidn_relmse\tpre_s\trecon_s\toidn_s\tstats");
    for &r in &rays {
        let mut times: Vec<Vec<(f64, f64)>> = vec![Vec::new(); methods.len()];
        let mut outputs = vec![None; methods.len()];
        for _ in 0..repeats {
            for (m, method) in methods.iter().enumerate() {
                let out = method.run(&inputs, r).expect("run");
                times[m].push((out.preprocess_s, out.recon_s));
                outputs[m] = Some(out);
            }
        }
        for (m, spec) in specs.iter().enumerate() {
            let out = outputs[m].take().unwrap();
            let psnr = psnr_db(&reference, &out.image, &tone).unwrap();
            let rel = relative_mse(&reference, &out.image).unwrap();
            let frame = ImageInput { color: out.image.clone(), albedo: albedo.clone(), normal: normal.clone() };
            let oidn_inputs = Inputs { data: InputData::Image(&frame), ..inputs.clone() };
            let denoised = Oidn::default().run(&oidn_inputs, 0).expect("oidn");
            let opsnr = psnr_db(&reference, &denoised.image, &tone).unwrap();
            let orel = relative_mse(&reference, &denoised.image).unwrap();
            let pre = median(times[m].iter().map(|t| t.0).collect());
            let rec = median(times[m].iter().map(|t| t.1).collect());
            let pick = |k: &str| out.stats.get(k).copied().unwrap_or(f64::NAN);
            println!(
                "{spec}\t{r}\t{psnr:.2}\t{rel:.3e}\t{opsnr:.2}\t{orel:.3e}\t{pre:.3}\t{rec:.3}\t{:.3}\tsizing {:.3} bvh {:.3} shrink {:.3} robust {:.3} gather {:.3} nodes {:.1} discs {:.1} records {} uncovered {:.3}",
                denoised.recon_s,
                pick("sizing_s"),
                pick("hierarchy_s"),
                pick("shrinking_s"),
                pick("robust_s"),
                pick("gather_s"),
                pick("nodes_per_ray"),
                pick("discs_tested_per_ray"),
                pick("cache_records"),
                pick("cache_uncovered_fraction"),
            );
        }
    }
}
