//! The splat hierarchy (docs/ilfr-design.md §4) — our `DiscBvh` against
//! Embree 3's oriented-disc points (`RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT`, vertex buffer
//! (x, y, z, r), normal buffer) with an intersection filter that records every hit (primitive id,
//! t) and rejects it, so that traversal goes on and collects *every* disc along the ray, as
//! `DiscBvh::collect_hits` does.
//!
//! Both hold the same discs: those `ilfr` makes from a sample file (`GatheredPoints::from_samples`,
//! `size_splats`, `DiscBvh::build`, `shrink_splats`, as `ilfr::pipeline` does), after shrinking.
//! The rays are reconstruction rays as the gather makes them: from every primary hit lifted by
//! 1e-4 × the scene diagonal along its normal, cosine-distributed about it (a fixed seed), t in
//! (0, ∞). Before timing, the hit sets are compared ray by ray; disagreements are counted and
//! classified (rim, window end, grazing), and must stay below 0.1 % of the rays.
//!
//! Timed in the same run: building our BVH against filling and committing the Embree scene (on 1
//! and on all Embree threads), the refit after shrinking against Embree's `REFIT` recommit, and
//! collecting all hits of the ray set on 1 thread and on 2 (rayon), as rays per second and ratios.
//! FTZ/DAZ are on in every thread that traces (Embree's recommendation), for both.
//!
//! `cargo bench -p recon --bench ilfr_discs` uses a synthetic Cornell box (an analytic room with
//! two boxes, 128×96 at 4 spp, the same pipeline); `ILFR_DISCS_SAMPLES=FILE.lfrs` uses a real
//! `indirect` file, e.g. from `lfr dump --scene scenes/cornell.toml --width 256 --height 256
//! --kind indirect --spp 8 --out FILE.lfrs`. `ILFR_DISCS_RAYS` sets the number of rays (default
//! 100 000).

use std::sync::atomic::{AtomicIsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use embree3::{enable_ftz_and_daz, BuildQuality, Config, Device, IntersectContextExt};
use rayon::prelude::*;
use recon::ilfr::bvh::DiscBvh;
use recon::ilfr::disc::{Disc, Ray};
use recon::ilfr::samples::{read_indirect, IndirectSamples, SampleClass};
use recon::ilfr::shrink::{input_rays, scene_diagonal, shrink_splats, ShrinkParams};
use recon::ilfr::splats::{size_splats, GatheredPoints, SplatParams};
use recon::lcg::Lcg;
use sampleio::{SampleFile, SampleKind};

use testkit::embree_discs::{Collected, EmbreeDiscs};

/// An Embree device with `threads` build threads (0: all) and a counter of its live bytes.
fn embree_device(threads: u32) -> (Device, Arc<AtomicIsize>) {
    let device = Device::with_config(Config { threads, ..Config::default() }).expect("embree device");
    let bytes = Arc::new(AtomicIsize::new(0));
    let counter = bytes.clone();
    device.set_memory_monitor_function(move |delta, _post| {
        counter.fetch_add(delta, Ordering::Relaxed);
        true
    });
    (device, bytes)
}

// ---------------------------------------------------------------------------------------------
// Input: a sample file or a synthetic Cornell box, through the pipeline of `ilfr::pipeline`.

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / l, v[1] / l, v[2] / l]
}

/// A cosine-distributed unit vector about the unit `n`.
fn cosine_about(n: [f32; 3], rng: &mut Lcg) -> [f32; 3] {
    let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let t = normalize([
        helper[1] * n[2] - helper[2] * n[1],
        helper[2] * n[0] - helper[0] * n[2],
        helper[0] * n[1] - helper[1] * n[0],
    ]);
    let b = [n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0]];
    let (u, v) = (rng.uniform(), rng.uniform() * std::f32::consts::TAU);
    let (r, z) = (u.sqrt(), (1.0 - u).max(0.0).sqrt());
    let (x, y) = (r * v.cos(), r * v.sin());
    normalize([0, 1, 2].map(|a| x * t[a] + y * b[a] + z * n[a]))
}

/// Two boxes standing in the room [0, 1]³ (a short and a tall one).
const BOXES: [([f32; 3], [f32; 3]); 2] =
    [([0.13, 0.0, 0.40], [0.43, 0.30, 0.70]), ([0.55, 0.0, 0.12], [0.85, 0.60, 0.42])];

/// The nearest surface along o + t·d, t > 1e-6, for o inside the room: its walls seen from
/// inside (the face z = 1 is open) and the outsides of the boxes; (t, unit normal facing the ray).
fn trace(o: [f32; 3], d: [f32; 3]) -> Option<(f32, [f32; 3])> {
    let mut best = None;
    let (mut t_exit, mut exit_axis) = (f32::INFINITY, 0);
    for a in 0..3 {
        if d[a] != 0.0 {
            let t = (if d[a] > 0.0 { 1.0 } else { 0.0 } - o[a]) / d[a];
            if t < t_exit {
                (t_exit, exit_axis) = (t, a);
            }
        }
    }
    if !(exit_axis == 2 && d[2] > 0.0) && t_exit > 1e-6 {
        let mut n = [0.0; 3];
        n[exit_axis] = -d[exit_axis].signum();
        best = Some((t_exit, n));
    }
    for (lo, hi) in BOXES {
        let (mut near, mut far, mut near_axis) = (f32::NEG_INFINITY, f32::INFINITY, 0);
        for a in 0..3 {
            let (t0, t1) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
            if t0.min(t1) > near {
                (near, near_axis) = (t0.min(t1), a);
            }
            far = far.min(t0.max(t1));
        }
        if near <= far && near > 1e-6 && best.map_or(true, |(t, _)| near < t) {
            let mut n = [0.0; 3];
            n[near_axis] = -d[near_axis].signum();
            best = Some((near, n));
        }
    }
    best
}

/// An `indirect`-like sample set of the analytic Cornell box: a pinhole camera just inside the
/// open face, one cosine-distributed secondary ray per primary hit.
fn synthetic_cornell(width: u32, height: u32, spp: u32) -> IndirectSamples {
    let n = (width * height * spp) as usize;
    let mut rng = Lcg(7);
    let mut s = IndirectSamples::empty(
        format!("synthetic Cornell box {width}x{height} at {spp} spp"),
        SampleKind::Indirect,
        (width, height, spp),
        n,
    );
    let camera = [0.5, 0.5, 0.999];
    let tan_half = 0.75f32;
    for y in 0..height {
        for x in 0..width {
            for _ in 0..spp {
                let film = [x as f32 + rng.uniform(), y as f32 + rng.uniform()];
                let px = (2.0 * film[0] / width as f32 - 1.0) * tan_half * width as f32 / height as f32;
                let py = (1.0 - 2.0 * film[1] / height as f32) * tan_half;
                let (t, normal) = trace(camera, normalize([px, py, -1.0])).expect("the camera looks into the room");
                let d = normalize([px, py, -1.0]);
                let o = [0, 1, 2].map(|a| camera[a] + t * d[a]);
                let lifted = [0, 1, 2].map(|a| o[a] + 1e-4 * normal[a]);
                let direction = cosine_about(normal, &mut rng);
                s.film.push(film);
                s.primary_hit.push(o);
                s.primary_normal.push(normal);
                s.direction.push(direction);
                match trace(lifted, direction) {
                    Some((t, hit_normal)) => {
                        s.class.push(SampleClass::Hit);
                        s.secondary_hit.push([0, 1, 2].map(|a| lifted[a] + t * direction[a]));
                        s.secondary_normal.push(hit_normal);
                    }
                    None => {
                        s.class.push(SampleClass::Escaped);
                        s.secondary_hit.push(o);
                        s.secondary_normal.push([0.0; 3]);
                    }
                }
            }
        }
    }
    s
}

/// The discs of `ilfr` for `samples` by input index: sized, shrunk; the radii before shrinking;
/// the scene diagonal; and the splats shrunk.
fn splat_discs(samples: &IndirectSamples) -> (Vec<Disc>, Vec<f32>, f32, usize) {
    let storage = GatheredPoints::from_samples(samples);
    let points = storage.points();
    let sized = size_splats(&points, &SplatParams::default()).expect("splat sizing");
    let discs: Vec<Disc> =
        (0..points.position.len()).map(|k| Disc::new(points.position[k], points.normal[k], sized.radius[k])).collect();
    let mut bvh = DiscBvh::build(&discs).expect("hierarchy");
    let rays = input_rays(samples, &storage.sample_index);
    let stats = shrink_splats(&mut bvh, &rays, &ShrinkParams::default()).expect("shrinking");
    let diagonal = scene_diagonal(&bvh, &rays);
    let shrunk = discs.iter().zip(bvh.radii()).map(|(d, radius)| Disc { radius, ..*d }).collect();
    (shrunk, sized.radius, diagonal, stats.shrunk_splats)
}

/// `count` reconstruction rays spread evenly over the primary hits.
fn reconstruction_rays(samples: &IndirectSamples, offset: f32, count: usize) -> Vec<Ray> {
    let hits: Vec<usize> = (0..samples.len()).filter(|&i| samples.class[i] != SampleClass::CameraMiss).collect();
    let mut rng = Lcg(12345);
    (0..count)
        .map(|k| {
            let i = hits[k * hits.len() / count];
            let n = samples.primary_normal[i];
            let origin = [0, 1, 2].map(|a| samples.primary_hit[i][a] + offset * n[a]);
            Ray { time: 0.0, origin, direction: cosine_about(n, &mut rng) }
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Agreement.

/// How close the disc test of `disc` is to flipping for `ray` (in f64): the smallest of the
/// relative distance of the plane point from the rim, |s − r| / r; the relative distance of t from
/// either end of the window; and |n·d| (grazing).
fn edge_margin(disc: &Disc, ray: &Ray, t_min: f32, t_max: f32) -> (f64, Edge) {
    let f = |v: [f32; 3]| v.map(|x| x as f64);
    let (c, n, o, d) = (f(disc.centre), f(disc.normal), f(ray.origin), f(ray.direction));
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let to_centre = [c[0] - o[0], c[1] - o[1], c[2] - o[2]];
    let cosine = dot(n, d);
    let t = dot(n, to_centre) / cosine;
    let p = [t * d[0] - to_centre[0], t * d[1] - to_centre[1], t * d[2] - to_centre[2]];
    let s = dot(p, p).sqrt();
    let r = disc.radius as f64;
    let rim = (s - r).abs() / r.max(1e-30);
    let window = ((t - t_min as f64).abs().min((t - t_max as f64).abs())) / t.abs().max(1e-30);
    let grazing = cosine.abs();
    if rim <= window && rim <= grazing {
        (rim, Edge::Rim)
    } else if window <= grazing {
        (window, Edge::WindowEnd)
    } else {
        (grazing, Edge::Grazing)
    }
}

/// Which test of a disc a ray is closest to flipping.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Edge {
    Rim,
    WindowEnd,
    Grazing,
}

#[derive(Debug, Default)]
struct Agreement {
    rays: usize,
    hits_ours: usize,
    hits_embree: usize,
    /// Rays whose id sets differ.
    disagreeing_rays: usize,
    only_ours: usize,
    only_embree: usize,
    /// Discs Embree reported more than once for one ray.
    duplicates: usize,
    /// The largest edge margin among the differing (ray, disc) pairs.
    worst_margin: f64,
    /// Differing (ray, disc) pairs by the test they are closest to flipping: rim, window end, grazing.
    edges: [usize; 3],
    /// Largest |t_embree − t_ours| / t_ours over the common hits.
    worst_t: f64,
}

fn compare(bvh: &DiscBvh, embree: &EmbreeDiscs, discs: &[Disc], rays: &[Ray], t_min: f32, t_max: f32) -> Agreement {
    let mut a = Agreement { rays: rays.len(), ..Agreement::default() };
    let (mut stack, mut ours) = (Vec::new(), Vec::new());
    let mut context = IntersectContextExt::incoherent(Collected::new());
    for ray in rays {
        bvh.collect_hits(ray, t_min, t_max, &mut stack, &mut ours);
        embree.collect(ray, t_min, t_max, &mut context);
        let mut mine: Vec<(u32, f32)> = ours.iter().map(|h| (h.id, h.hit.t)).collect();
        mine.sort_by_key(|h| h.0);
        let mut theirs = context.ext.clone();
        theirs.sort_by_key(|h| h.0);
        let before = theirs.len();
        theirs.dedup_by_key(|h| h.0);
        a.duplicates += before - theirs.len();
        a.hits_ours += mine.len();
        a.hits_embree += theirs.len();
        let (mut i, mut j, mut differs) = (0, 0, false);
        while i < mine.len() || j < theirs.len() {
            let next_mine = mine.get(i).map_or(u32::MAX, |h| h.0);
            let next_theirs = theirs.get(j).map_or(u32::MAX, |h| h.0);
            if next_mine == next_theirs {
                let (t0, t1) = (mine[i].1 as f64, theirs[j].1 as f64);
                a.worst_t = a.worst_t.max((t1 - t0).abs() / t0.abs().max(1e-30));
                (i, j) = (i + 1, j + 1);
                continue;
            }
            differs = true;
            let id = if next_mine < next_theirs {
                i += 1;
                a.only_ours += 1;
                next_mine
            } else {
                j += 1;
                a.only_embree += 1;
                next_theirs
            };
            let (margin, edge) = edge_margin(&discs[id as usize], ray, t_min, t_max);
            a.worst_margin = a.worst_margin.max(margin);
            a.edges[edge as usize] += 1;
        }
        a.disagreeing_rays += differs as usize;
    }
    a
}

// ---------------------------------------------------------------------------------------------
// Timing.

fn ours_hits(bvh: &DiscBvh, rays: &[Ray]) -> usize {
    let (mut stack, mut out) = (Vec::new(), Vec::new());
    rays.iter()
        .map(|ray| {
            bvh.collect_hits(ray, 0.0, f32::INFINITY, &mut stack, &mut out);
            out.len()
        })
        .sum()
}

fn embree_hits(embree: &EmbreeDiscs, rays: &[Ray]) -> usize {
    let mut context = IntersectContextExt::incoherent(Collected::new());
    rays.iter()
        .map(|ray| {
            embree.collect(ray, 0.0, f32::INFINITY, &mut context);
            context.ext.len()
        })
        .sum()
}

fn ours_hits_parallel(bvh: &DiscBvh, rays: &[Ray]) -> usize {
    rays.par_chunks(1024)
        .map_init(
            || (Vec::new(), Vec::new()),
            |(stack, out), chunk| {
                chunk
                    .iter()
                    .map(|ray| {
                        bvh.collect_hits(ray, 0.0, f32::INFINITY, stack, out);
                        out.len()
                    })
                    .sum::<usize>()
            },
        )
        .sum()
}

fn embree_hits_parallel(embree: &EmbreeDiscs, rays: &[Ray]) -> usize {
    rays.par_chunks(1024)
        .map_init(
            || IntersectContextExt::incoherent(Collected::new()),
            |context, chunk| {
                chunk
                    .iter()
                    .map(|ray| {
                        embree.collect(ray, 0.0, f32::INFINITY, context);
                        context.ext.len()
                    })
                    .sum::<usize>()
            },
        )
        .sum()
}

/// The shortest of `runs` timings of `f`, in seconds (dropping its result is not timed).
fn best_of<R>(runs: usize, mut f: impl FnMut() -> R) -> f64 {
    (0..runs)
        .map(|_| {
            let start = Instant::now();
            let result = std::hint::black_box(f());
            let seconds = start.elapsed().as_secs_f64();
            drop(result);
            seconds
        })
        .fold(f64::INFINITY, f64::min)
}

fn bench(c: &mut Criterion) {
    enable_ftz_and_daz();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).start_handler(|_| enable_ftz_and_daz()).build().unwrap();
    let start = Instant::now();
    let (samples, label) = match std::env::var_os("ILFR_DISCS_SAMPLES") {
        Some(path) => {
            let file = SampleFile::open(&path).expect("ILFR_DISCS_SAMPLES: a sample file");
            let stem = std::path::Path::new(&path).file_stem().map(|s| s.to_string_lossy().into_owned());
            (read_indirect(&file).expect("an indirect sample file"), stem.unwrap_or_default())
        }
        None => (synthetic_cornell(128, 96, 4), "synthetic".to_string()),
    };
    let ray_count = std::env::var("ILFR_DISCS_RAYS").ok().and_then(|s| s.parse().ok()).unwrap_or(100_000usize);
    let (discs, unshrunk_radii, diagonal, shrunk) = pool.install(|| splat_discs(&samples));
    let rays = reconstruction_rays(&samples, 1e-4 * diagonal, ray_count);
    println!(
        "{}: {} samples, {} discs ({shrunk} shrunk), {} rays; input {:.1} s",
        samples.path,
        samples.len(),
        discs.len(),
        rays.len(),
        start.elapsed().as_secs_f64()
    );
    drop(samples);

    // The structures, with their memory.
    let bvh = DiscBvh::build(&discs).unwrap();
    let ours_bytes = bvh.memory_bytes();
    let (device_1, bytes_1) = embree_device(1);
    let (device_all, _) = embree_device(0);
    let embree = EmbreeDiscs::build(&device_1, &discs, BuildQuality::MEDIUM);
    let embree_bytes = bytes_1.load(Ordering::Relaxed);

    // Agreement, before any timing: the reconstruction window (0, ∞) and a finite one.
    for (t_min, t_max) in [(0.0, f32::INFINITY), (1e-3 * diagonal, 0.3 * diagonal)] {
        let a = compare(&bvh, &embree, &discs, &rays, t_min, t_max);
        println!(
            "agreement, t in ({t_min:.3e}, {t_max:.3e}): {} of {} rays differ ({:.4} %), {} discs only ours, {} only \
             Embree's, {} Embree duplicates; {:.2} / {:.2} hits per ray; differences at the rim / window end / grazing \
             {:?}, largest edge margin {:.1e}; largest relative t difference of a common hit {:.1e}",
            a.disagreeing_rays,
            a.rays,
            100.0 * a.disagreeing_rays as f64 / a.rays as f64,
            a.only_ours,
            a.only_embree,
            a.duplicates,
            a.hits_ours as f64 / a.rays as f64,
            a.hits_embree as f64 / a.rays as f64,
            a.edges,
            a.worst_margin,
            a.worst_t
        );
        assert!(a.disagreeing_rays * 1000 <= a.rays, "more than 0.1 % of the rays disagree: {a:?}");
        assert!(a.hits_ours > a.rays, "a vacuous comparison: {a:?}");
    }

    // Build and refit, timed by hand for the summary (best of 5).
    let build_ours = best_of(5, || DiscBvh::build(&discs).unwrap());
    let build_embree_1 = best_of(5, || EmbreeDiscs::build(&device_1, &discs, BuildQuality::MEDIUM));
    let build_embree_all = best_of(5, || EmbreeDiscs::build(&device_all, &discs, BuildQuality::MEDIUM));
    let shrunk_radii: Vec<f32> = discs.iter().map(|d| d.radius).collect();
    let mut refitted = DiscBvh::build(
        &discs.iter().zip(&unshrunk_radii).map(|(d, &radius)| Disc { radius, ..*d }).collect::<Vec<_>>(),
    )
    .unwrap();
    let refit_ours = best_of(5, || refitted.set_radii(&shrunk_radii).unwrap());
    let unshrunk: Vec<Disc> = discs.iter().zip(&unshrunk_radii).map(|(d, &radius)| Disc { radius, ..*d }).collect();
    let mut embree_refit = EmbreeDiscs::build(&device_1, &unshrunk, BuildQuality::REFIT);
    let refit_embree = best_of(5, || embree_refit.set_radii(&shrunk_radii));
    let a = compare(&bvh, &embree_refit, &discs, &rays, 0.0, f32::INFINITY);
    println!(
        "after Embree's REFIT recommit: {} of {} rays differ, {:.2} hits per ray",
        a.disagreeing_rays,
        a.rays,
        a.hits_embree as f64 / a.rays as f64
    );
    assert!(a.disagreeing_rays * 1000 <= a.rays, "{a:?}");

    // Queries, by hand (best of 3).
    let n = rays.len() as f64;
    let ours_1 = n / best_of(3, || ours_hits(&bvh, &rays));
    let embree_1 = n / best_of(3, || embree_hits(&embree, &rays));
    let ours_2 = n / best_of(3, || pool.install(|| ours_hits_parallel(&bvh, &rays)));
    let embree_2 = n / best_of(3, || pool.install(|| embree_hits_parallel(&embree, &rays)));
    let embree_refit_1 = n / best_of(3, || embree_hits(&embree_refit, &rays));
    println!(
        "build: ours {:.1} ms, Embree commit {:.1} ms on 1 thread ({:.2}×), {:.1} ms on all; refit after shrinking: ours \
         {:.2} ms, Embree REFIT recommit {:.2} ms\n\
         memory: ours {:.2} MB ({} nodes), Embree {:.2} MB (buffers and BVH, from its memory monitor)\n\
         all hits, rays/s: 1 thread ours {ours_1:.0}, Embree {embree_1:.0} (ours/Embree {:.2}); 2 threads ours \
         {ours_2:.0}, Embree {embree_2:.0} (ours/Embree {:.2}); Embree REFIT scene, 1 thread {embree_refit_1:.0}",
        build_ours * 1e3,
        build_embree_1 * 1e3,
        build_embree_1 / build_ours,
        build_embree_all * 1e3,
        refit_ours * 1e3,
        refit_embree * 1e3,
        ours_bytes as f64 / 1e6,
        bvh.node_count(),
        embree_bytes as f64 / 1e6,
        ours_1 / embree_1,
        ours_2 / embree_2,
    );

    let mut group = c.benchmark_group(format!("ilfr_discs {label}"));
    group.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    group.throughput(Throughput::Elements(discs.len() as u64));
    group.bench_function("build ours", |b| b.iter_with_large_drop(|| DiscBvh::build(&discs).unwrap()));
    group.bench_function("build embree 1 thread", |b| {
        b.iter_with_large_drop(|| EmbreeDiscs::build(&device_1, &discs, BuildQuality::MEDIUM))
    });
    group.throughput(Throughput::Elements(rays.len() as u64));
    group.bench_function("all hits ours 1 thread", |b| b.iter(|| ours_hits(&bvh, &rays)));
    group.bench_function("all hits embree 1 thread", |b| b.iter(|| embree_hits(&embree, &rays)));
    group.bench_function("all hits ours 2 threads", |b| b.iter(|| pool.install(|| ours_hits_parallel(&bvh, &rays))));
    group.bench_function("all hits embree 2 threads", |b| {
        b.iter(|| pool.install(|| embree_hits_parallel(&embree, &rays)))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
