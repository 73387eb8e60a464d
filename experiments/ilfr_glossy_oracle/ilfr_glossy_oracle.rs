//! Experiment (issue 23, the glossy bias floor): ILFR's glossy gather against the same rays
//! traced through the scene. Reads a glossy `indirect` file kept by `lfr compare --keep-samples`
//! (Figure 9 set-up, `--max-bounces 2`: the radiance along a reconstruction ray is the distant
//! light's direct light at its hit, which one traced ray with its shadow ray gives exactly),
//! runs the ILFR pipeline, and for every BSDF-sampled gather ray of every primary hit computes
//! - `nn`: RECONSTRUCT as the product does (glossy nearest neighbour, sky fallback, or none);
//! - `avg`: the same surface filtered by the g-weighted average of its members instead of the
//!   nearest neighbour (candidate b's oracle);
//! - `traced`: the exact radiance along the ray (Embree + the tracer's next-event estimate).
//!
//! Images (PSNR, relative MSE, mean display error on the heads = the brightest quarter of the
//! reference, and on the 10 % steepest-gradient pixels):
//! - `ilfr`: the product's estimator, Σ w·nn / N' over the supported rays;
//! - `a:unsupported=traced`: unsupported rays take their traced value, normalised by all N;
//! - `b:glossy=avg`: `avg` in place of `nn`;
//! - `c:no-shrink` (variant `noshrink`: the same pipeline without §2.3.1);
//! - `exact`: Σ w·traced / N, the same rays traced (the best any RECONSTRUCT can do here);
//! - `exact-on-supported`: Σ w·traced / N' over the rays ILFR supports.
//!
//! And on the heads, the mean of w·(nn − traced)/N per ray class (glossy NN, diffuse, sky,
//! unsupported), so that the darkening is split by where it comes from.
//!
//! Copy to examples/ of the root crate, then
//! cargo run --release --example ilfr_glossy_oracle -- SCENE GLOSSY_FILE REFERENCE_EXR RAYS MAX_BOUNCES [VARIANTS]
//! VARIANTS, comma-separated: noshrink, hitrays (shrink with hit rays only), disc (trim whole discs, the paper;
//! the default since session 27 trims wedges), norobust (robust=off), dump (raw f32 images to /tmp/glossy/)

use std::path::Path;

use glam::Vec3;
use rayon::prelude::*;
use recon::ilfr::bsdf_rays::bsdf_rays;
use recon::ilfr::bvh::DiscBvh;
use recon::ilfr::disc::{Disc, Ray};
use recon::ilfr::filter::{filter_radiance, glossy_weight, lobe, tent_weight, FilterMode, SplatShading};
use recon::ilfr::gather::rays_per_hit;
use recon::ilfr::method::{IlfrChoices, IlfrSettings};
use recon::ilfr::reconstruct::{nearest_sky, SkySample};
use recon::ilfr::robust::{robust_radiance, RobustMode, RobustParams};
use recon::ilfr::samples::{read_indirect, IndirectSamples, SampleClass};
use recon::ilfr::shrink::{input_rays, scene_diagonal, shrink_splats};
use recon::ilfr::splats::{size_splats, GatheredPoints};
use recon::ilfr::surfaces::{first_surface, prepare_candidates};
use recon::image::Image;
use recon::method::Effect;
use recon::metrics::{evaluate, ToneMap};
use sampleio::SampleFile;
use tracer::bsdf::sampling::hash_u32;
use tracer::integrator::{Integrator, PathStart, NoRecording};
use tracer::lights::LightSampler;
use tracer::sampler::Sampler;
use tracer::Accel;

struct Pipeline {
    bvh: DiscBvh,
    radiance: Vec<[f32; 3]>,
    direction: Vec<[f32; 3]>,
    kappa: Option<Vec<f32>>,
    offset: f32,
}

fn build(samples: &IndirectSamples, settings: &IlfrSettings, shrink: bool) -> Pipeline {
    let storage = GatheredPoints::from_samples(samples);
    let points = storage.points();
    let sized = size_splats(&points, &settings.splats).unwrap();
    let discs: Vec<Disc> =
        (0..points.position.len()).map(|k| Disc::new(points.position[k], points.normal[k], sized.radius[k])).collect();
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let rays = input_rays(samples, &storage.sample_index);
    if shrink {
        let s = shrink_splats(&mut bvh, &rays, &settings.shrink).unwrap();
        eprintln!("shrunk {} of {} splats", s.shrunk_splats, bvh.len());
    }
    let diagonal = scene_diagonal(&bvh, &rays);
    let offset = settings.relative_offset * diagonal;
    let radii = bvh.radii();
    let per_sample = samples.radiance.as_ref().unwrap();
    let raw: Vec<[f32; 3]> = storage.sample_index.iter().map(|&i| per_sample[i as usize]).collect();
    let robust = RobustParams {
        alpha: settings.splats.alpha,
        lobe_threshold: settings.splats.lobe_threshold,
        ..settings.robust
    };
    let (radiance, _) = robust_radiance(&points, &radii, &raw, &robust).unwrap();
    Pipeline { bvh, radiance, direction: storage.direction.clone(), kappa: storage.kappa.clone(), offset }
}

/// Per-ray class of ILFR's answer.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Glossy,
    Diffuse,
    Sky,
    Unsupported,
    Below,
}

const KINDS: usize = 5;

fn sky_samples(samples: &IndirectSamples, x: u32, y: u32, radius: u32, out: &mut Vec<SkySample>) -> Option<f32> {
    out.clear();
    let radiance = samples.radiance.as_ref()?;
    let spp = samples.spp.max(1) as usize;
    let mut rays = 0usize;
    for py in y.saturating_sub(radius)..(y + radius + 1).min(samples.height) {
        for px in x.saturating_sub(radius)..(x + radius + 1).min(samples.width) {
            let first = (py as usize * samples.width as usize + px as usize) * spp;
            for i in first..first + spp {
                match samples.class[i] {
                    SampleClass::Hit => rays += 1,
                    SampleClass::Escaped => {
                        rays += 1;
                        out.push(SkySample { direction: samples.direction[i], radiance: radiance[i] });
                    }
                    _ => {}
                }
            }
        }
    }
    (rays > 0 && !out.is_empty()).then(|| (std::f32::consts::TAU / rays as f32).sqrt())
}

/// Per pixel: images [ilfr, a, b, exact, exact_on_supported] and per-kind signed error sums.
struct PixelOut {
    images: [[f64; 3]; 10],
    kind_error: [[f64; 3]; KINDS],
    kind_count: [u64; KINDS],
    glossy_wrong: [u64; 4],
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let scene = tracer::scene::Scene::load(Path::new(&args[1]))?;
    let accel = Accel::build(&scene)?;
    let lights = LightSampler::new(&scene);
    let file = SampleFile::open(Path::new(&args[2]))?;
    let samples = read_indirect(&file).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (w, h, ch) = tracer::output::read_exr(Path::new(&args[3]))?;
    let get = |suffix: &str| ch.iter().find(|(n, _)| n.ends_with(suffix)).map(|(_, v)| v.clone()).unwrap();
    let (r, g, b) = (get("R"), get("G"), get("B"));
    let reference = Image { width: w, height: h, pixels: (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect() };
    let rays: u32 = args[4].parse()?;
    let max_bounces: u32 = args[5].parse()?;
    let variant = args.get(6).cloned().unwrap_or_default();
    let tone = ToneMap::auto(&reference);
    let integrator = Integrator::new(&scene, &accel, &lights, max_bounces, samples.width, samples.height);

    let mut choices = IlfrChoices::default();
    if variant.contains("norobust") {
        choices.robust = RobustMode::Off;
    }
    if variant.contains("hitrays") {
        choices.shrink_with_escaped_rays = false;
    }
    if variant.contains("disc") {
        choices.trim = Some(recon::ilfr::shrink::Trim::Disc);
    }
    let settings = choices.apply(IlfrSettings { recon_rays: rays, seed: 1, ..IlfrSettings::default() }, Effect::Glossy);
    let shrink = !variant.contains("noshrink");
    let p = build(&samples, &settings, shrink);
    let shading = SplatShading { radiance: &p.radiance, direction: &p.direction, kappa: p.kappa.as_deref() };
    let spp = samples.spp.max(1);
    let per_hit = rays_per_hit(rays, spp);
    let shading_of = samples.primary_shading.as_ref().expect("a glossy file");
    let (width, height) = (samples.width, samples.height);

    let pixels: Vec<PixelOut> = (0..width * height)
        .into_par_iter()
        .map(|pixel| {
            let (x, y) = (pixel % width, pixel / width);
            let mut sky = Vec::new();
            let spacing = sky_samples(&samples, x, y, 2, &mut sky);
            let min_cosine = spacing.map(|s| (2.0 * s).min(std::f32::consts::PI).cos());
            let (mut stack, mut hits, mut cands) = (Vec::new(), Vec::new(), Vec::new());
            let mut out = PixelOut { images: [[0.0; 3]; 10], kind_error: [[0.0; 3]; KINDS], kind_count: [0; KINDS], glossy_wrong: [0; 4] };
            for i in (pixel * spp) as usize..((pixel + 1) * spp) as usize {
                if samples.class[i] == SampleClass::CameraMiss {
                    continue;
                }
                let scramble = hash_u32(settings.seed ^ hash_u32(i as u32 ^ 0x6a09_e667));
                let (o, n) = (samples.primary_hit[i], samples.primary_normal[i]);
                // sums: [ilfr supported, a (all N), b supported, exact (all N), exact on supported]
                let mut sums = [[0.0f64; 3]; 10];
                let (mut supported, mut supported_b) = (0u32, 0u32);
                let mut per_ray: Vec<(Kind, [f32; 3], [f32; 3])> = Vec::new();
                for wr in bsdf_rays(&shading_of[i], o, n, (0, per_hit), scramble, p.offset) {
                    let Some(ray) = wr.ray else {
                        supported += 1;
                        supported_b += 1;
                        per_ray.push((Kind::Below, [0.0; 3], [0.0; 3]));
                        continue;
                    };
                    // Traced truth.
                    let start = PathStart {
                        origin: Vec3::from(ray.origin),
                        direction: Vec3::from(ray.direction),
                        time: 0.0,
                        bounce: 1,
                        previous: Some((1.0, Vec3::from(o))),
                    };
                    let mut sampler = Sampler::new(7, x, y, i as u32);
                    let traced = integrator.trace_ray(&start, &mut sampler, &mut NoRecording).reflected().to_array();
                    // ILFR.
                    let (kind, nn, avg, surface_t) = reconstruct(&p, &shading, &ray, &settings, &mut stack, &mut hits, &mut cands)
                        .map(|(k, nn, avg, t)| (k, Some(nn), Some(avg), t))
                        .unwrap_or_else(|| match min_cosine.and_then(|c| nearest_sky(&sky, ray.direction, c)) {
                            Some(l) => (Kind::Sky, Some(l), Some(l), 0.0),
                            None => (Kind::Unsupported, None, None, 0.0),
                        });
                    let traced_t = accel
                        .intersect(Vec3::from(ray.origin), Vec3::from(ray.direction), 0.0, f32::INFINITY, 0.0)
                        .map(|h| h.distance);
                    let wrong_surface = kind == Kind::Glossy
                        && traced_t.is_none_or(|t| (surface_t - t).abs() > 0.05 * t + 0.02);
                    // 0 right depth, 1 the traced ray escapes, 2 ILFR's surface nearer, 3 farther.
                    let category = match (wrong_surface, traced_t) {
                        (false, _) => 0,
                        (true, None) => 1,
                        (true, Some(t)) if surface_t < t => 2,
                        (true, Some(_)) => 3,
                    };
                    if kind == Kind::Glossy {
                        out.glossy_wrong[category] += 1;
                    }
                    for c in 0..3 {
                        let wt = wr.weight[c] as f64;
                        sums[3][c] += wt * traced[c] as f64;
                        match nn {
                            Some(l) => {
                                let glossy_traced = if kind == Kind::Glossy { traced[c] } else { l[c] };
                                let sky_traced = if kind == Kind::Glossy && wrong_surface { traced[c] } else { l[c] };
                                sums[5][c] += wt * glossy_traced as f64;
                                let in_front = kind == Kind::Glossy && (category == 1 || category == 2);
                                let behind = kind == Kind::Glossy && category == 3;
                                sums[7][c] += wt * if in_front { traced[c] } else { l[c] } as f64;
                                sums[8][c] += wt * if behind { traced[c] } else { l[c] } as f64;
                                sums[9][c] += wt * if kind == Kind::Sky { traced[c] } else { l[c] } as f64;
                                sums[6][c] += wt * sky_traced as f64;
                                sums[0][c] += wt * l[c] as f64;
                                sums[1][c] += wt * l[c] as f64;
                                sums[4][c] += wt * traced[c] as f64;
                            }
                            None => sums[1][c] += wt * traced[c] as f64,
                        }
                        if let Some(l) = avg {
                            sums[2][c] += wt * l[c] as f64;
                        }
                    }
                    if nn.is_some() {
                        supported += 1;
                        supported_b += 1;
                    }
                    let weighted = |l: [f32; 3]| [0, 1, 2].map(|c| wr.weight[c] * l[c]);
                    per_ray.push((kind, weighted(nn.unwrap_or(traced)), weighted(traced)));
                }
                let own = || {
                    let wgt = samples.weight.as_ref().unwrap()[i];
                    let l = samples.radiance.as_ref().unwrap()[i];
                    [0, 1, 2].map(|c| (wgt[c] * l[c]) as f64)
                };
                let n_all = per_hit as f64;
                let value = |s: [f64; 3], count: u32| if count > 0 { s.map(|v| v / count as f64) } else { own() };
                let hit_values = [
                    value(sums[0], supported),
                    sums[1].map(|v| v / n_all),
                    value(sums[2], supported_b),
                    sums[3].map(|v| v / n_all),
                    value(sums[4], supported),
                    value(sums[5], supported),
                    value(sums[6], supported),
                    value(sums[7], supported),
                    value(sums[8], supported),
                    value(sums[9], supported),
                ];
                for (img, v) in out.images.iter_mut().zip(hit_values) {
                    for c in 0..3 {
                        img[c] += v[c] / spp as f64;
                    }
                }
                // Error of the product's estimate, split by ray kind. The product's value is
                // Σ_sup w nn / N'; write it as Σ_sup w (nn − t)/N' + Σ_sup w t/N', and the last
                // minus the exact Σ_all w t / N is the unsupported rays' share.
                if supported > 0 {
                    for (kind, wl, wt) in &per_ray {
                        let k = *kind as usize;
                        out.kind_count[k] += 1;
                        for c in 0..3 {
                            let e = if *kind == Kind::Unsupported {
                                0.0
                            } else {
                                (wl[c] - wt[c]) as f64 / supported as f64
                            };
                            out.kind_error[k][c] += e / spp as f64;
                        }
                    }
                    // Unsupported share: exact-on-supported minus exact.
                    let k = Kind::Unsupported as usize;
                    for c in 0..3 {
                        out.kind_error[k][c] += (hit_values[4][c] - hit_values[3][c]) / spp as f64;
                    }
                }
            }
            out
        })
        .collect();

    let image = |k: usize| Image {
        width,
        height,
        pixels: pixels.iter().map(|p| p.images[k].map(|v| v as f32)).collect(),
    };
    // Masks: the brightest quarter of the reference (display), the 10 % steepest gradient.
    let disp = |rgb: [f32; 3]| (tone.apply(rgb[0]) + tone.apply(rgb[1]) + tone.apply(rgb[2])) / 3.0;
    let ref_disp: Vec<f32> = reference.pixels.iter().map(|&p| disp(p)).collect();
    let mut sorted = ref_disp.clone();
    sorted.sort_by(f32::total_cmp);
    let q3 = sorted[sorted.len() * 3 / 4];
    let heads: Vec<bool> = ref_disp.iter().map(|&v| v >= q3).collect();
    let grad: Vec<f32> = (0..ref_disp.len())
        .map(|k| {
            let (x, y) = (k as u32 % width, k as u32 / width);
            let at = |x: u32, y: u32| ref_disp[(y * width + x) as usize];
            let gx = at((x + 1).min(width - 1), y) - at(x.saturating_sub(1), y);
            let gy = at(x, (y + 1).min(height - 1)) - at(x, y.saturating_sub(1));
            (gx * gx + gy * gy).sqrt()
        })
        .collect();
    let mut gs = grad.clone();
    gs.sort_by(f32::total_cmp);
    let g90 = gs[gs.len() * 9 / 10];
    let edges: Vec<bool> = grad.iter().map(|&v| v >= g90).collect();
    let names = [
        "ilfr",
        "a:unsupported=traced",
        "b:glossy=avg",
        "exact",
        "exact-on-supported",
        "glossy-rays=traced",
        "glossy-wrong-surface=traced",
        "surface-in-front=traced",
        "surface-behind=traced",
        "sky-rays=traced",
    ];
    let extra: Vec<(String, Image)> = std::env::var("EXTRA_EXR")
        .unwrap_or_default()
        .split(',')
        .filter(|s| !s.is_empty())
        .map(|path| {
            let (w, h, ch) = tracer::output::read_exr(Path::new(path)).unwrap();
            let get = |suffix: &str| ch.iter().find(|(n, _)| n.ends_with(suffix)).map(|(_, v)| v.clone()).unwrap();
            let (r, g, b) = (get("R"), get("G"), get("B"));
            (path.to_string(), Image { width: w, height: h, pixels: (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect() })
        })
        .collect();
    let all_images: Vec<(String, Image)> =
        names.iter().enumerate().map(|(k, n)| (n.to_string(), image(k))).chain(extra).collect();
    for (k, (name, img)) in all_images.into_iter().enumerate() {
        let m = evaluate(&reference, &img, &tone).unwrap();
        let mut stats = [(0.0f64, 0.0f64, 0usize); 2];
        let mut total_sq = 0.0f64;
        for (j, px) in img.pixels.iter().enumerate() {
            let e = (disp(*px) - ref_disp[j]) as f64;
            total_sq += e * e;
            for (s, mask) in stats.iter_mut().zip([&heads, &edges]) {
                if mask[j] {
                    s.0 += e;
                    s.1 += e * e;
                    s.2 += 1;
                }
            }
        }
        println!(
            "{variant:>10} {name:>26}: PSNR {:.2} dB, rel MSE {:.3e}; heads mean err {:+.4} ({:.0}% of sq err), edges mean err {:+.4} ({:.0}%)",
            m.psnr_db,
            m.rel_mse,
            stats[0].0 / stats[0].2 as f64,
            100.0 * stats[0].1 / total_sq,
            stats[1].0 / stats[1].2 as f64,
            100.0 * stats[1].1 / total_sq,
        );
        if variant.contains("dump") {
            std::fs::create_dir_all("/tmp/glossy")?;
            let bytes: Vec<u8> = img.pixels.iter().flat_map(|p| p.iter().flat_map(|v| v.to_le_bytes())).collect();
            std::fs::write(format!("/tmp/glossy/{variant}-{k}.f32"), bytes)?;
        }
    }
    // Linear mean error on the heads per ray kind (as a fraction of the reference's mean there).
    let ref_heads: f64 = reference
        .pixels
        .iter()
        .zip(&heads)
        .filter(|(_, &m)| m)
        .map(|(p, _)| (p[0] + p[1] + p[2]) as f64 / 3.0)
        .sum();
    let kind_names = ["glossy-nn", "diffuse", "sky", "unsupported", "below"];
    let mut line = String::new();
    let mut counts = [0u64; KINDS];
    for p in &pixels {
        for k in 0..KINDS {
            counts[k] += p.kind_count[k];
        }
    }
    let all: u64 = counts.iter().sum();
    for (k, kn) in kind_names.iter().enumerate() {
        let err: f64 = pixels
            .iter()
            .zip(&heads)
            .filter(|(_, &m)| m)
            .map(|(p, _)| (p.kind_error[k][0] + p.kind_error[k][1] + p.kind_error[k][2]) / 3.0)
            .sum();
        line += &format!(" {kn}: {:+.2}% ({:.1}% of rays);", 100.0 * err / ref_heads, 100.0 * counts[k] as f64 / all as f64);
    }
    let gw = pixels.iter().fold([0u64; 4], |a, p| [0, 1, 2, 3].map(|k| a[k] + p.glossy_wrong[k]));
    println!(
        "glossy rays: {} at the right depth, {} where the traced ray escapes, {} on a surface nearer, {} farther",
        gw[0], gw[1], gw[2], gw[3]
    );
    println!("{variant:>10} heads' linear error by ray kind, of the reference's mean there:{line}");
    Ok(())
}

#[allow(clippy::type_complexity)]
fn reconstruct(
    p: &Pipeline,
    shading: &SplatShading,
    ray: &Ray,
    settings: &IlfrSettings,
    stack: &mut Vec<u32>,
    hits: &mut Vec<recon::ilfr::bvh::SplatHit>,
    cands: &mut Vec<recon::ilfr::surfaces::Candidate>,
) -> Option<(Kind, [f32; 3], [f32; 3], f32)> {
    p.bvh.collect_hits(ray, 0.0, f32::INFINITY, stack, hits);
    prepare_candidates(&p.bvh, hits, ray.time, &settings.surfaces, cands);
    let surface = first_surface(ray, cands, &settings.surfaces)?;
    let f = filter_radiance(ray.direction, cands, &surface, shading)?;
    if f.mode == FilterMode::Diffuse {
        return Some((Kind::Diffuse, f.radiance, f.radiance, 0.0));
    }
    // An alternative glossy filter (env FILTER): `avg` (g-weighted average, the default),
    // `pow:P` (g^P-weighted), `nn-tent` (nearest neighbour by lobe × tent, no near-field
    // relaxation), `lobe-tent` (lobe × tent-weighted average), `top:K` (g-weighted mean of the K
    // largest g).
    let filter = std::env::var("FILTER").unwrap_or_else(|_| "avg".into());
    let mut scored: Vec<(f64, f64, [f32; 3])> = Vec::new();
    for c in cands[surface.members.clone()].iter().filter(|c| surface.gives_radiance(c)) {
        let kappa = shading.kappa_of(c.id);
        let direction = shading.direction[c.id as usize];
        let g = glossy_weight(c, direction, kappa, ray.direction) as f64;
        let lt = (lobe(kappa, direction, ray.direction) * tent_weight(c.hit.spatial, c.radius)) as f64;
        scored.push((g, lt, shading.radiance[c.id as usize]));
    }
    let mean = |items: &[(f64, [f32; 3])]| -> Option<[f32; 3]> {
        let total: f64 = items.iter().map(|x| x.0).sum();
        (total > 0.0).then(|| {
            [0, 1, 2].map(|k| (items.iter().map(|x| x.0 * x.1[k] as f64).sum::<f64>() / total) as f32)
        })
    };
    let avg = if let Some(p) = filter.strip_prefix("pow:") {
        let p: f64 = p.parse().unwrap();
        mean(&scored.iter().map(|x| (x.0.powf(p), x.2)).collect::<Vec<_>>())
    } else if filter == "nn-tent" {
        scored.iter().max_by(|a, b| a.1.total_cmp(&b.1)).filter(|x| x.1 > 0.0).map(|x| x.2)
    } else if filter == "lobe-tent" {
        mean(&scored.iter().map(|x| (x.1, x.2)).collect::<Vec<_>>())
    } else if let Some(k) = filter.strip_prefix("top:") {
        let k: usize = k.parse().unwrap();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        mean(&scored.iter().take(k).map(|x| (x.0, x.2)).collect::<Vec<_>>())
    } else {
        mean(&scored.iter().map(|x| (x.0, x.2)).collect::<Vec<_>>())
    }
    .unwrap_or(f.radiance);
    let members: Vec<_> = cands[surface.members.clone()].iter().filter(|c| surface.gives_radiance(c)).collect();
    let depth = members.iter().map(|c| c.hit.t).sum::<f32>() / members.len().max(1) as f32;
    Some((Kind::Glossy, f.radiance, avg, depth))
}
