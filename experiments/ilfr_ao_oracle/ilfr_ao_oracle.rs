//! Experiment (issue 23, item 4): ILFR's ambient occlusion against the same gather traced
//! through the real scene. Reads an `ao` sample file kept by `lfr compare --keep-samples`, runs
//! `ilfr` on it, traces the gather's very rays with Embree (visibility = no hit within the AO
//! radius), and also a long traced gather at the same primary hits; prints PSNR of each against
//! the comparison's reference and the error split by what the primary hit is.
//!
//! Copy to examples/ of the root crate, then
//! cargo run --release --example ilfr_ao_oracle -- SCENE AO_FILE REFERENCE_EXR RADIUS RAYS [LONG_RAYS [VARIANTS]]
//! with VARIANTS a comma-separated list of: nomerge (ILFR without the small-surface rule, now the
//! AO default), merge (with it), offplane (the off-plane conflict test), nocull (no near-field
//! back-face cull), old-convention (the traced gather counts directions below the geometric
//! surface as visible, the tracer's AO before issue 23), dump (raw f32 images to /tmp/ao/).

use std::path::Path;

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use recon::ilfr::gather::{rays_per_hit, reconstruction_rays};
use recon::ilfr::method::{reconstruct_samples, GatherTarget, IlfrSettings};
use recon::ilfr::samples::{read_indirect, SampleClass};
use recon::image::Image;
use recon::metrics::{evaluate, ToneMap};
use sampleio::SampleFile;
use tracer::Accel;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let scene = tracer::scene::Scene::load(Path::new(&args[1]))?;
    let accel = Accel::build(&scene)?;
    let file = SampleFile::open(Path::new(&args[2]))?;
    let samples = read_indirect(&file).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (w, h, ch) = tracer::output::read_exr(Path::new(&args[3]))?;
    let get = |suffix: &str| ch.iter().find(|(n, _)| n.ends_with(suffix)).map(|(_, v)| v.clone()).unwrap();
    eprintln!("reference channels: {:?}", ch.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>());
    let (r, g, b) = (get("R"), get("G"), get("B"));
    let reference = Image { width: w, height: h, pixels: (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect() };
    let radius: f32 = args[4].parse()?;
    let rays: u32 = args[5].parse()?;
    let long_rays: u32 = args.get(6).map_or(0, |s| s.parse().unwrap());
    let variant = args.get(7).cloned().unwrap_or_default();
    let tone = ToneMap::auto(&reference);

    let mut settings = IlfrSettings { recon_rays: rays, seed: 1, ..IlfrSettings::default() };
    if variant.contains("offplane") {
        settings.surfaces.conflict_test = recon::ilfr::surfaces::ConflictTest::EventLineOffPlane;
    } else {
        settings.surfaces.conflict_test = recon::ilfr::surfaces::ConflictTest::EventLine;
    }
    settings.surfaces.merge_small_surfaces = !variant.contains("nomerge");
    if variant.contains("nocull") {
        settings.surfaces.backface_near_field_cull = false;
    }
    let result = reconstruct_samples(&samples, GatherTarget::Visibility { ao_radius: radius }, &settings)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let spp = samples.spp.max(1) as usize;

    // The sample of each ray and its geometric normal (facing the camera).
    let hit_samples: Vec<usize> = (0..samples.len()).filter(|&i| samples.class[i] != SampleClass::CameraMiss).collect();
    let geo: Vec<Vec3> = hit_samples
        .par_iter()
        .map(|&i| {
            let f = samples.film[i];
            let (o, d) = scene.camera.generate_ray(Vec2::new(f[0], f[1]), Vec2::ZERO, samples.width, samples.height);
            accel.intersect(o, d, 0.0, f32::INFINITY, 0.0).map_or(Vec3::ZERO, |h| {
                let n = h.geometric_normal.normalize_or_zero();
                if n.dot(-d) >= 0.0 {
                    n
                } else {
                    -n
                }
            })
        })
        .collect();
    // Traced gather on the same rays.
    let traced_image = |gs: &recon::ilfr::gather::GatherSettings| -> Image {
        let rays = reconstruction_rays(&samples, gs);
        let vis: Vec<f32> = rays
            .par_iter()
            .enumerate()
            .map(|(k, r)| {
                let o = Vec3::from_array(r.origin);
                let d = Vec3::from_array(r.direction);
                let per_hit = rays_per_hit(gs.rays_per_pixel, samples.spp) as usize;
                if variant.contains("old-convention") && d.dot(geo[k / per_hit]) <= 0.0 {
                    return 1.0;
                }
                match accel.intersect(o, d, 0.0, f32::INFINITY, 0.0) {
                    Some(hit) if hit.distance < radius => 0.0,
                    _ => 1.0,
                }
            })
            .collect();
        let per_hit = rays_per_hit(gs.rays_per_pixel, samples.spp) as usize;
        let mut pixels = vec![[0.0f32; 3]; (samples.width * samples.height) as usize];
        let mut next = 0;
        for (p, pixel) in pixels.iter_mut().enumerate() {
            let mut sum = 0.0f64;
            for i in p * spp..(p + 1) * spp {
                if samples.class[i] == SampleClass::CameraMiss {
                    sum += 1.0;
                } else {
                    sum += vis[next..next + per_hit].iter().map(|&v| v as f64).sum::<f64>() / per_hit as f64;
                    next += per_hit;
                }
            }
            *pixel = [(sum / spp as f64) as f32; 3];
        }
        assert_eq!(next, vis.len());
        Image { width: samples.width, height: samples.height, pixels }
    };
    let traced = traced_image(&result.gather_settings);
    let long = (long_rays > 0).then(|| {
        traced_image(&recon::ilfr::gather::GatherSettings {
            rays_per_pixel: long_rays,
            ..result.gather_settings.clone()
        })
    });

    // What each pixel's primary hits are: alpha-masked (foliage), other.
    let masked: Vec<f32> = (0..(samples.width * samples.height) as usize)
        .map(|p| {
            let mut n = 0;
            for i in p * spp..(p + 1) * spp {
                if samples.class[i] == SampleClass::CameraMiss {
                    continue;
                }
                let f = samples.film[i];
                let (o, d) =
                    scene.camera.generate_ray(Vec2::new(f[0], f[1]), Vec2::ZERO, samples.width, samples.height);
                if let Some(hit) = accel.intersect(o, d, 0.0, f32::INFINITY, 0.0) {
                    let m = scene.meshes[hit.mesh as usize].material;
                    if scene.materials[m as usize].alpha.is_some() {
                        n += 1;
                    }
                }
            }
            n as f32 / spp as f32
        })
        .collect();

    // Per ray: ILFR's visibility against the traced one, by category.
    {
        use recon::ilfr::bvh::DiscBvh;
        use recon::ilfr::disc::Disc;
        use recon::ilfr::filter::SplatShading;
        use recon::ilfr::reconstruct::{ReconstructStats, Reconstructor, Scratch};
        use recon::ilfr::shrink::{input_rays, shrink_splats};
        use recon::ilfr::splats::{size_splats, GatheredPoints};
        let storage = GatheredPoints::from_samples(&samples);
        let points = storage.points();
        let sized = size_splats(&points, &settings.splats).unwrap();
        let discs: Vec<Disc> = (0..points.position.len())
            .map(|k| Disc::new(points.position[k], points.normal[k], sized.radius[k]))
            .collect();
        let mut bvh = DiscBvh::build(&discs).unwrap();
        let inrays = input_rays(&samples, &storage.sample_index);
        shrink_splats(&mut bvh, &inrays, &settings.shrink).unwrap();
        let radiance = vec![[0.0f32; 3]; storage.sample_index.len()];
        let shading = SplatShading { radiance: &radiance, direction: &storage.direction, kappa: None };
        let reconstructor = Reconstructor { bvh: &bvh, shading, surfaces: settings.surfaces };
        let gs = &result.gather_settings;
        let rays = reconstruction_rays(&samples, gs);
        let per_hit = rays_per_hit(gs.rays_per_pixel, samples.spp) as usize;

        // category -> (rays, sum of ilfr - truth, sum of sq)
        let cats = [
            "below-geo",
            "occl:no-surf",
            "occl:surf-vis",
            "occl:surf-occ",
            "vis:no-surf",
            "vis:surf-vis",
            "vis:surf-occ",
        ];
        let per_ray: Vec<(usize, f64, bool, bool, f32, u8)> = rays
            .par_iter()
            .enumerate()
            .map_init(Scratch::default, |scratch, (k, r)| {
                let mut stats = ReconstructStats::default();
                let v = reconstructor.visibility(r, radius, scratch, &mut stats) as f64;
                let no_surface = stats.no_surface > 0;
                let o = Vec3::from_array(r.origin);
                let d = Vec3::from_array(r.direction);
                let hit = accel.intersect(o, d, 0.0, f32::INFINITY, 0.0);
                let dist = hit.as_ref().map_or(f32::INFINITY, |h| h.distance);
                let alpha_occluder = hit
                    .as_ref()
                    .is_some_and(|h| scene.materials[scene.meshes[h.mesh as usize].material as usize].alpha.is_some());
                let below = d.dot(geo[k / per_hit]) <= 0.0;
                // The tracer's convention (issue 23): a direction below the geometric surface is occluded.
                let truth = if below || dist < radius { 0.0 } else { 1.0 };
                let cat = if below {
                    0
                } else if truth == 0.0 {
                    if no_surface {
                        1
                    } else if v > 0.5 {
                        2
                    } else {
                        3
                    }
                } else if no_surface {
                    4
                } else if v > 0.5 {
                    5
                } else {
                    6
                };
                // Why an occluded ray read visible.
                let mut why = 0u8;
                if cat == 2 {
                    use recon::ilfr::surfaces::{first_surface, prepare_candidates};
                    let (mut stack, mut hits, mut cands) = (Vec::new(), Vec::new(), Vec::new());
                    bvh.collect_hits(r, 0.0, f32::INFINITY, &mut stack, &mut hits);
                    let near_hits = hits.iter().filter(|h| h.hit.t < radius).count();
                    let near_back = hits.iter().filter(|h| h.hit.t < radius && h.hit.back_facing).count();
                    let no_cull =
                        recon::ilfr::surfaces::SurfaceParams { backface_near_field_cull: false, ..settings.surfaces };
                    prepare_candidates(&bvh, &hits, 0.0, &settings.surfaces, &mut cands);
                    let near_cands = cands.iter().filter(|c| c.hit.depth < radius).count();
                    let surface = first_surface(r, &cands, &settings.surfaces);
                    let merged = surface.as_ref().map_or(0, |s| s.merged_surfaces);
                    why = if near_hits == 0 {
                        1 // no splat within R along the ray: a hole
                    } else if near_cands == 0 && near_back > 0 {
                        2 // only back-facing near-field splats, culled
                    } else if merged > 0 {
                        3 // near small surface merged into a far one
                    } else if near_cands > 0 {
                        4 // near splats in the surface, outvoted (depth > R)
                    } else {
                        5 // near hits by t but centres deeper than R
                    };
                    let _ = no_cull;
                }
                (cat, v - truth, alpha_occluder, no_surface, dist / radius, why)
            })
            .collect();
        let whys = [
            "",
            "hole (no splat hit within R)",
            "near splats back-facing, culled",
            "near small surface merged",
            "near splats outvoted",
            "hit t < R but centre depth > R",
        ];
        let n2: Vec<_> = per_ray.iter().filter(|p| p.0 == 2).collect();
        for (w, name) in whys.iter().enumerate().skip(1) {
            let sel: Vec<_> = n2.iter().filter(|p| p.5 == w as u8).collect();
            let mut bins = [0usize; 4];
            for p in &sel {
                bins[if p.4 < 0.1 {
                    0
                } else if p.4 < 0.5 {
                    1
                } else if p.4 < 0.9 {
                    2
                } else {
                    3
                }] += 1;
            }
            println!(
                "    occl:surf-vis because {name}: {:.2}% of rays, bias {:+.5}; by true d/R <0.1/<0.5/<0.9/<1: {:?}",
                100.0 * sel.len() as f64 / per_ray.len() as f64,
                sel.iter().map(|p| p.1).sum::<f64>() / per_ray.len() as f64,
                bins
            );
        }
        let n = per_ray.len() as f64;
        println!("per ray ({} rays): category, share of rays, mean (ilfr - truth) contribution, share with an alpha-masked occluder", per_ray.len());
        for (c, name) in cats.iter().enumerate() {
            let sel: Vec<_> = per_ray.iter().filter(|p| p.0 == c).collect();
            let sum: f64 = sel.iter().map(|p| p.1).sum();
            let alpha = sel.iter().filter(|p| p.2).count();
            println!(
                "  {name:>14}: {:6.2}% of rays, bias contribution {:+.5}, |err| contribution {:.5}, alpha occluder {:.1}%",
                100.0 * sel.len() as f64 / n,
                sum / n,
                sel.iter().map(|p| p.1.abs()).sum::<f64>() / n,
                100.0 * alpha as f64 / sel.len().max(1) as f64
            );
        }
        // Errors of occluded rays by distance (fraction of R).
        for (lo, hi) in [(0.0, 0.1), (0.1, 0.5), (0.5, 0.9), (0.9, 1.0), (1.0, 1.1), (1.1, 2.0), (2.0, f32::INFINITY)] {
            let sel: Vec<_> = per_ray.iter().filter(|p| p.0 != 0 && p.4 >= lo && p.4 < hi).collect();
            println!(
                "  true distance/R in [{lo}, {hi}): {:6.2}% of rays, bias {:+.5}, |err| {:.5}",
                100.0 * sel.len() as f64 / n,
                sel.iter().map(|p| p.1).sum::<f64>() / n,
                sel.iter().map(|p| p.1.abs()).sum::<f64>() / n
            );
        }
    }

    let report = |name: &str, image: &Image| {
        let m = evaluate(&reference, image, &tone).unwrap();
        // Squared display error split by region.
        let (mut fol, mut other, mut nfol) = (0.0f64, 0.0f64, 0usize);
        let mut signed_fol = 0.0f64;
        let mut signed_other = 0.0f64;
        for p in 0..image.pixels.len() {
            let e = tone.apply(image.pixels[p][0]) as f64 - tone.apply(reference.pixels[p][0]) as f64;
            if masked[p] > 0.0 {
                fol += e * e;
                signed_fol += e;
                nfol += 1;
            } else {
                other += e * e;
                signed_other += e;
            }
        }
        let n = image.pixels.len();
        println!(
            "{name:>14}: PSNR {:.2} dB, rel MSE {:.3e}; foliage pixels {} ({:.1}%): {:.1}% of sq error, mean err {:+.4}; other mean err {:+.4}",
            m.psnr_db,
            m.rel_mse,
            nfol,
            100.0 * nfol as f64 / n as f64,
            100.0 * fol / (fol + other),
            signed_fol / nfol.max(1) as f64,
            signed_other / (n - nfol).max(1) as f64
        );
    };
    println!("{} spp, {} rays per pixel, radius {radius}", samples.spp, rays);
    report("ilfr", &result.image);
    report("traced gather", &traced);
    if let Some(l) = &long {
        report(&format!("traced {long_rays}"), l);
    }
    if variant.contains("dump") {
        let out = format!("/tmp/ao/oracle-{}spp", samples.spp);
        std::fs::create_dir_all(&out)?;
        let write = |name: &str, im: &Image| {
            let v: Vec<u8> = im.pixels.iter().flat_map(|p| p[0].to_le_bytes()).collect();
            std::fs::write(format!("{out}/{name}.f32"), v).unwrap();
        };
        write("ilfr", &result.image);
        write("traced", &traced);
        write("reference", &reference);
        write("masked", &Image { width: w, height: h, pixels: masked.iter().map(|&m| [m; 3]).collect() });
        if let Some(l) = &long {
            write("long", l);
        }
    }
    Ok(())
}
