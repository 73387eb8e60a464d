use rayon::prelude::*;
use std::time::Instant;
use tracer::integrator::NoRecording;
use tracer::render::{thread_pool, RenderSettings};
use tracer::sampler::Sampler;
use tracer::samples::FieldSelection;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scene = tracer::Scene::load(std::path::Path::new(&args[1])).unwrap();
    let size: u32 = args[2].parse().unwrap();
    let spp: u32 = args[3].parse().unwrap();
    let repeats: usize = args[4].parse().unwrap();
    let accel = tracer::Accel::build(&scene).unwrap();
    let mut settings = RenderSettings::from_scene(&scene);
    settings.width = size;
    settings.height = size;
    settings.spp = spp;
    settings.threads = 2;
    settings.progress = false;
    settings.seed = 1;
    let fields = FieldSelection::parse_strict("x,y,radiance").unwrap();
    let lights = tracer::lights::LightSampler::new(&scene);
    let integrator = tracer::samples::integrator(&scene, &accel, &lights, &settings);
    let pool = thread_pool(2).unwrap();
    let path = std::path::PathBuf::from(std::env::var("DVR_PATH").unwrap_or("/tmp/dvr.lfrs".into()));
    let only = args.get(5).cloned();
    let names = [
        "open",
        "average",
        "render",
        "dump",
        "rows-trace-only",
        "tiles-trace-only",
        "dump-1thread",
        "render-1thread",
        "rows-values",
        "dump-own-closure",
        "dump-replace",
    ];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let trace_pixel = |x: u32, y: u32, sink: &mut f32| {
        for index in 0..spp {
            let mut sampler = Sampler::new(settings.seed, x, y, index);
            let cs = integrator.camera_sample(x, y, &mut sampler);
            let p = integrator.trace_camera_sample(&cs, &mut sampler, &mut NoRecording);
            *sink += p.radiance().x;
        }
    };
    tracer::samples::lens_time::dump(&scene, &accel, &settings, &fields, tracer::samples::DumpTarget::scratch(&path))
        .unwrap();
    // The values of a full lens-time record of a scene with lens, motion and glossy materials
    // (x, y, u, v, t, z, motion, radiance, depth_gradient, bandwidth), as the dump computes them.
    let lens_time_values = |x: u32, y: u32, samples: std::ops::Range<u32>, values: &mut Vec<f32>| {
        for index in samples {
            let mut sampler = Sampler::new(settings.seed, x, y, index);
            let cs = integrator.camera_sample(x, y, &mut sampler);
            let p = integrator.trace_camera_sample(&cs, &mut sampler, &mut NoRecording);
            values.extend_from_slice(&[cs.film.x, cs.film.y, cs.lens.x, -cs.lens.y, cs.time]);
            match p.first_hit {
                Some(hit) => {
                    values.push(hit.depth);
                    let motion = scene.meshes[hit.mesh as usize].motion;
                    values.extend_from_slice(&scene.camera.vector_to_camera_space(motion).to_array());
                    values.extend_from_slice(&p.radiance().to_array());
                    values.extend_from_slice(&[0.0, 0.0]);
                    values.push(tracer::samples::secondary::bandwidth(&hit.bsdf));
                }
                None => {
                    values.push(f32::INFINITY);
                    values.extend_from_slice(&[0.0; 3]);
                    values.extend_from_slice(&p.radiance().to_array());
                    values.extend_from_slice(&[0.0; 3]);
                }
            }
        }
    };
    for _ in 0..repeats {
        for (k, name) in names.iter().enumerate() {
            if only.as_deref().is_some_and(|o| o != *name) {
                continue;
            }
            let start = Instant::now();
            match *name {
                "open" => {
                    std::hint::black_box(sampleio::SampleFile::open(&path).unwrap());
                }
                "average" => {
                    let file = sampleio::SampleFile::open(&path).unwrap();
                    let t = Instant::now();
                    pool.install(|| {
                        std::hint::black_box(
                            recon::baselines::box_filter::average(&file, recon::method::Effect::Dof, 1.0).unwrap(),
                        )
                    });
                    times[k].push(t.elapsed().as_secs_f64());
                    continue;
                }
                "render" => {
                    tracer::render(&scene, &accel, &settings).unwrap();
                }
                "render-1thread" => {
                    tracer::render(&scene, &accel, &RenderSettings { threads: 1, ..settings.clone() }).unwrap();
                }
                "dump" | "dump-replace" => {
                    // `dump` starts from no file; `dump-replace` renames over the previous one.
                    if *name == "dump" {
                        let _ = std::fs::remove_file(&path);
                    }
                    let target = tracer::samples::DumpTarget::scratch(&path);
                    let report = tracer::samples::lens_time::dump(&scene, &accel, &settings, &fields, target).unwrap();
                    eprintln!(
                        "{name}: {:.4} s, of which the parallel pass {:.4} s",
                        report.seconds, report.trace_seconds
                    );
                }
                "dump-1thread" => {
                    tracer::samples::lens_time::dump(
                        &scene,
                        &accel,
                        &RenderSettings { threads: 1, ..settings.clone() },
                        &fields,
                        tracer::samples::DumpTarget::scratch(&path),
                    )
                    .unwrap();
                }
                "rows-trace-only" => {
                    let rows: Vec<u32> = (0..size).collect();
                    let s: f32 = pool.install(|| {
                        rows.par_chunks(2)
                            .map(|r| {
                                let mut s = 0.0;
                                for &y in r {
                                    for x in 0..size {
                                        trace_pixel(x, y, &mut s);
                                    }
                                }
                                s
                            })
                            .sum()
                    });
                    std::hint::black_box(s);
                }
                "rows-values" => {
                    let rows: Vec<u32> = (0..size).collect();
                    let s: f32 = pool.install(|| {
                        rows.par_chunks(2)
                            .map(|r| {
                                let mut values: Vec<f32> = Vec::with_capacity(2 * size as usize * spp as usize * 15);
                                for &y in r {
                                    for x in 0..size {
                                        lens_time_values(x, y, 0..spp, &mut values);
                                    }
                                }
                                values.iter().sum::<f32>()
                            })
                            .sum()
                    });
                    std::hint::black_box(s);
                }
                "dump-own-closure" => {
                    let layout = tracer::samples::lens_time::LensTimeLayout::for_scene(&scene);
                    let spec = layout.header(&scene, &settings);
                    let target = tracer::samples::DumpTarget::scratch(&path);
                    tracer::samples::write_samples(
                        target,
                        spec,
                        &fields,
                        &settings,
                        layout.values_per_sample(),
                        |x, y, samples, values| lens_time_values(x, y, samples, values),
                    )
                    .unwrap();
                }
                "tiles-trace-only" => {
                    let tiles: Vec<(u32, u32)> =
                        (0..size).step_by(16).flat_map(|y| (0..size).step_by(16).map(move |x| (x, y))).collect();
                    let s: f32 = pool.install(|| {
                        tiles
                            .par_iter()
                            .map(|&(x0, y0)| {
                                let mut s = 0.0;
                                for y in y0..(y0 + 16).min(size) {
                                    for x in x0..(x0 + 16).min(size) {
                                        trace_pixel(x, y, &mut s);
                                    }
                                }
                                s
                            })
                            .sum()
                    });
                    std::hint::black_box(s);
                }
                _ => unreachable!(),
            }
            times[k].push(start.elapsed().as_secs_f64());
        }
    }
    if let Some(only) = &only {
        let k = names.iter().position(|n| n == only).expect("a mode");
        println!("{only}: median {:.4} s of {}", median(times[k].clone()), times[k].len());
        return;
    }
    let base = median(times[2].clone());
    for (k, name) in names.iter().enumerate() {
        let m = median(times[k].clone());
        println!(
            "{name:>18}: median {:.4} s  ({:.3}x render)  min {:.4}",
            m,
            m / base,
            times[k].iter().cloned().fold(f64::MAX, f64::min)
        );
    }
}
