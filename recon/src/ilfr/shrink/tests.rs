//! The unit tests of `shrink.rs`, in a file of their own beside it for their length.

use super::*;
use crate::ilfr::disc::{half_plane_wedge_radii, tangent_coordinates, WEDGES};
use crate::ilfr::disc::{intersect, Disc};
use crate::lcg::Lcg;

const UP: [f32; 3] = [0.0, 0.0, 1.0];

use crate::vector::normalize;

#[test]
fn a_blocking_splat_shrinks_until_the_ray_passes() {
    // A ray from the origin up to its own hit at z = 2 (splat 0). Splat 1 at z = 1 is 0.3 off
    // the ray with radius 1: it blocks and must end with radius 0.3 (the ray's distance from its
    // centre), which the ray then just misses. Splat 2 (5 units aside) and splat 3 (beyond the
    // hit) do not block; splat 4, centred on the ray 1e-3 before the hit, is met inside
    // ε = 1e-3 · 2 of the end, part of the surface around h: kept (outside the window the
    // ray through its centre would kill it, as `escaped_rays_…` checks).
    let discs = [
        Disc::new([0.0, 0.0, 2.0], [0.0, 0.0, -1.0], 0.5),
        Disc::new([0.3, 0.0, 1.0], UP, 1.0),
        Disc::new([5.0, 0.0, 1.0], UP, 1.0),
        Disc::new([0.0, 0.0, 3.0], UP, 1.0),
        Disc::new([0.0, 0.0, 2.0 - 1e-3], normalize([0.2, 0.0, -1.0]), 0.5),
    ];
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let ray = InputRay { time: 0.0, origin: [0.0; 3], direction: UP, length: 2.0, own_splat: Some(0) };
    let stats = shrink_splats(&mut bvh, &[ray], &ShrinkParams::default()).unwrap();
    let radii = bvh.radii();
    assert!((radii[1] - 0.3).abs() < 1e-6, "{radii:?}");
    assert_eq!([radii[0], radii[2], radii[3], radii[4]], [0.5, 1.0, 1.0, 0.5]);
    assert_eq!((stats.shrunk_splats, stats.crossings, stats.blocked_rays, stats.dead_splats), (1, 1, 1, 0));
    let geometric = Ray { time: 0.0, origin: [0.0; 3], direction: UP };
    assert!(intersect(&Disc { radius: radii[1], ..discs[1] }, &geometric, 0.0, 2.0).is_none());
    assert!(intersect(&discs[1], &geometric, 0.0, 2.0).is_some());
}

#[test]
fn escaped_rays_shrink_along_their_whole_length_and_own_splats_are_spared() {
    // An escaped ray along +x meets splats at x = 10 and x = 1000 (0.2 and 0.4 off the ray).
    let discs =
        [Disc::new([10.0, 0.2, 0.0], [1.0, 0.0, 0.0], 1.0), Disc::new([1000.0, 0.0, 0.4], [-1.0, 0.0, 0.0], 1.0)];
    let ray =
        InputRay { time: 0.0, origin: [0.0; 3], direction: [1.0, 0.0, 0.0], length: f32::INFINITY, own_splat: None };
    let mut bvh = DiscBvh::build(&discs).unwrap();
    shrink_splats(&mut bvh, &[ray], &ShrinkParams::default()).unwrap();
    let radii = bvh.radii();
    assert!((radii[0] - 0.2).abs() < 1e-6 && (radii[1] - 0.4).abs() < 1e-4, "{radii:?}");
    // The same ray naming splat 1 as its own leaves that one alone.
    let mut bvh = DiscBvh::build(&discs).unwrap();
    shrink_splats(&mut bvh, &[InputRay { own_splat: Some(1), ..ray }], &ShrinkParams::default()).unwrap();
    assert_eq!(bvh.radii()[1], 1.0);
    // A ray through a centre kills the splat; one of length 0 does nothing.
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let through = InputRay { time: 0.0, origin: [0.0, 0.2, 0.0], ..ray };
    let zero = InputRay { time: 0.0, origin: [10.0, 0.2, -1.0], direction: UP, length: 0.0, own_splat: None };
    let stats = shrink_splats(&mut bvh, &[through, zero], &ShrinkParams::default()).unwrap();
    assert_eq!(bvh.radii()[0], 0.0);
    assert_eq!((stats.dead_splats, stats.short_rays), (1, 1));
    // Bad rays are named.
    let bad = InputRay { direction: [0.0; 3], ..ray };
    assert!(shrink_splats(&mut bvh, &[ray, bad], &ShrinkParams::default())
        .unwrap_err()
        .to_string()
        .contains("input ray 1"));
    let bad = InputRay { own_splat: Some(2), ..ray };
    assert!(shrink_splats(&mut bvh, &[bad], &ShrinkParams::default()).is_err());
}

#[test]
fn input_rays_come_from_hit_and_escaped_samples() {
    // Four records, one per class: a camera miss, a failed BSDF sample, an escaped ray and a hit
    // at distance 5 (splat 0, the only one).
    use SampleClass::*;
    let class = vec![CameraMiss, NoSecondaryRay, Escaped, Hit];
    let samples = IndirectSamples {
        film: vec![[0.5; 2]; 4],
        primary_hit: vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]],
        primary_normal: vec![[0.0; 3], UP, UP, UP],
        direction: vec![[0.0; 3], [0.0; 3], UP, [0.0, 0.6, 0.8]],
        secondary_hit: vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 3.0, 4.0]],
        secondary_normal: vec![[0.0; 3], [0.0; 3], [0.0; 3], [0.0, 0.0, -1.0]],
        class,
        ..IndirectSamples::empty("test".into(), sampleio::SampleKind::Indirect, (4, 1, 1), 0)
    };
    let rays = input_rays(&samples, &samples.hits());
    assert_eq!(
        rays,
        [
            InputRay { time: 0.0, origin: [2.0, 0.0, 0.0], direction: UP, length: f32::INFINITY, own_splat: None },
            InputRay {
                time: 0.0,
                origin: [3.0, 0.0, 0.0],
                direction: [0.0, 0.6, 0.8],
                length: 5.0,
                own_splat: Some(0)
            },
        ]
    );
}

/// Two parallel planes: splats on z = 0 (facing up) and z = 1 (facing down) with a gap in the
/// upper plane (no samples for |x − 2| < 0.25) that its neighbours' splats overlap, a third
/// plane at z = 2 (facing down) and a plane far aside that no ray reaches. Rays go from the
/// lower plane to the upper plane's samples (consistent) and through the gap to z = 2.
fn two_planes() -> (Vec<Disc>, Vec<InputRay>, std::ops::Range<usize>) {
    let mut rng = Lcg(3);
    let mut discs = Vec::new();
    let mut rays = Vec::new();
    let radius = 0.3;
    for _ in 0..1500 {
        let (x, y) = (rng.uniform() * 4.0, rng.uniform() * 4.0);
        discs.push(Disc::new([x, y, 0.0], UP, radius));
    }
    let shoot = |discs: &mut Vec<Disc>, rays: &mut Vec<InputRay>, hit: [f32; 3], normal: [f32; 3]| {
        let origin = discs[rays.len() % 1500].centre;
        let offset = crate::vector::sub(hit, origin);
        let l = length(offset);
        discs.push(Disc::new(hit, normal, radius));
        rays.push(InputRay {
            time: 0.0,
            origin,
            direction: [offset[0] / l, offset[1] / l, offset[2] / l],
            length: l,
            own_splat: Some(discs.len() as u32 - 1),
        });
    };
    for _ in 0..1500 {
        let (x, y) = (rng.uniform() * 4.0, rng.uniform() * 4.0);
        if (x - 2.0).abs() >= 0.25 {
            shoot(&mut discs, &mut rays, [x, y, 1.0], [0.0, 0.0, -1.0]);
        } else {
            // Through the gap: aim at z = 2 so that the ray crosses z = 1 inside the gap.
            let at_gap = [x, y, 1.0];
            let origin = discs[rays.len() % 1500].centre;
            let beyond = [2.0 * at_gap[0] - origin[0], 2.0 * at_gap[1] - origin[1], 2.0];
            shoot(&mut discs, &mut rays, beyond, [0.0, 0.0, -1.0]);
        }
    }
    let aside = discs.len()..discs.len() + 200;
    for _ in 0..200 {
        discs.push(Disc::new([20.0 + rng.uniform(), rng.uniform(), 0.5], [1.0, 0.0, 0.0], radius));
    }
    (discs, rays, aside)
}

/// The definition by brute force: every ray against every disc; each disc's wedge radii
/// (all equal when trimming whole discs).
fn shrunk_by_brute_force(discs: &[Disc], rays: &[InputRay], params: &ShrinkParams, floor: f32) -> Vec<[f32; WEDGES]> {
    let mut radii: Vec<[f32; WEDGES]> = discs.iter().map(|d| [d.radius; WEDGES]).collect();
    for ray in rays.iter().filter(|r| params.escaped_rays || r.length.is_finite()) {
        let Some((t0, t1)) = blocking_window(ray, floor, params) else { continue };
        let geometric = Ray { time: ray.time, origin: ray.origin, direction: ray.direction };
        for (i, disc) in discs.iter().enumerate() {
            if Some(i as u32) == ray.own_splat {
                continue;
            }
            if let Some(hit) = intersect(disc, &geometric, t0, t1) {
                let bound = match params.trim {
                    Trim::Disc => [hit.spatial; WEDGES],
                    Trim::Wedges => {
                        let (x, y) = tangent_coordinates(disc.centre_at(ray.time), disc.normal, &geometric, hit.t);
                        half_plane_wedge_radii(x, y, hit.spatial)
                    }
                };
                for (r, b) in radii[i].iter_mut().zip(bound) {
                    *r = r.min(b);
                }
            }
        }
    }
    radii
}

fn same_bits(a: &[[f32; WEDGES]], b: &[[f32; WEDGES]]) -> bool {
    a.len() == b.len() && a.iter().flatten().zip(b.iter().flatten()).all(|(x, y)| x.to_bits() == y.to_bits())
}

const BOTH_TRIMS: [Trim; 2] = [Trim::Disc, Trim::Wedges];

#[test]
fn a_blocking_ray_trims_the_wedges_towards_it_only() {
    // Splat 1 (radius 1, 0.3 off the ray) blocks the ray from the origin to its hit at z = 2.
    // Trimming wedges, the two wedges that meet at the ray's side fall to 0.3 (the ray just
    // misses), the two next to them to 0.3 / cos 45°, and the four facing away keep radius 1:
    // a ray 0.6 from the centre on the far side still meets the disc (it would miss the
    // whole-disc trim's radius 0.3); the box and `radii` keep the largest wedge, the area
    // their mean square.
    let discs = [Disc::new([0.0, 0.0, 2.0], [0.0, 0.0, -1.0], 0.5), Disc::new([0.3, 0.0, 1.0], UP, 1.0)];
    let ray = InputRay { time: 0.0, origin: [0.0; 3], direction: UP, length: 2.0, own_splat: Some(0) };
    let far_side = Ray { time: 0.0, origin: [0.9, 0.0, 0.0], direction: UP };
    let blocked = Ray { time: 0.0, origin: [0.0; 3], direction: UP };
    let met = |bvh: &DiscBvh, r: &Ray| {
        let mut hits = Vec::new();
        bvh.collect_hits(r, 0.0, 1.5, &mut Vec::new(), &mut hits);
        hits.iter().map(|h| (h.id, h.radius)).collect::<Vec<_>>()
    };
    let params = ShrinkParams { trim: Trim::Wedges, ..ShrinkParams::default() };
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let stats = shrink_splats(&mut bvh, &[ray], &params).unwrap();
    assert_eq!((stats.shrunk_splats, stats.crossings, stats.dead_splats), (1, 1, 0));
    let mut wedges = bvh.wedge_radii()[1];
    wedges.sort_by(f32::total_cmp);
    let expected = [0.3, 0.3, 0.3 * 2.0f32.sqrt(), 0.3 * 2.0f32.sqrt(), 1.0, 1.0, 1.0, 1.0];
    assert!(wedges.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-6), "{wedges:?}");
    assert_eq!(bvh.radii()[1], 1.0);
    assert!((bvh.area_radii()[1] - ((4.0 + 2.0 * 0.09 + 2.0 * 0.18) / 8.0f32).sqrt()).abs() < 1e-6);
    assert!(met(&bvh, &blocked).is_empty());
    assert_eq!(met(&bvh, &far_side), vec![(1, 1.0)]);
    // The paper's trim: the whole disc falls to 0.3, and the far-side ray misses too.
    let mut whole = DiscBvh::build(&discs).unwrap();
    shrink_splats(&mut whole, &[ray], &ShrinkParams::default()).unwrap();
    assert!(met(&whole, &blocked).is_empty() && met(&whole, &far_side).is_empty());
}

#[test]
fn after_shrinking_no_input_ray_is_blocked() {
    for trim in BOTH_TRIMS {
        no_input_ray_is_blocked_after_shrinking(ShrinkParams { trim, ..ShrinkParams::default() });
    }
}

fn no_input_ray_is_blocked_after_shrinking(params: ShrinkParams) {
    let (discs, rays, aside) = two_planes();
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let stats = shrink_splats(&mut bvh, &rays, &params).unwrap();
    // Equal to the brute-force definition, bit for bit.
    let expected = shrunk_by_brute_force(&discs, &rays, &params, stats.epsilon_floor);
    assert!(same_bits(&bvh.wedge_radii(), &expected), "{params:?}");
    let radii: Vec<f32> = bvh.wedge_radii().iter().map(|w| w.iter().copied().fold(f32::INFINITY, f32::min)).collect();
    // Something happened, and only to upper-plane splats bordering the gap.
    assert!(stats.shrunk_splats > 10 && stats.blocked_rays > 10, "{stats:?}");
    for (i, (r, d)) in radii.iter().zip(&discs).enumerate() {
        if *r < d.radius {
            assert!(d.centre[2] == 1.0 && (d.centre[0] - 2.0).abs() < 0.25 + d.radius, "splat {i}: {d:?}");
        }
    }
    assert!(aside.clone().all(|i| radii[i] == discs[i].radius));
    // The lower plane (origins) and the far plane at z = 2 (hits) are untouched.
    assert!(radii[..1500].iter().all(|&r| r == 0.3));
    let far_hits = discs.iter().zip(&radii).filter(|(d, _)| d.centre[2] == 2.0);
    assert!(far_hits.clone().count() > 50 && far_hits.clone().all(|(_, &r)| r == 0.3));
    // Retrace: no input ray is blocked any more, and shrinking again changes nothing.
    let mut stack = Vec::new();
    for ray in &rays {
        if let Some(window) = blocking_window(ray, stats.epsilon_floor, &params) {
            for_each_blocker(&bvh, ray, window, &mut stack, |hit| panic!("{ray:?} still blocked by {hit:?}"));
        }
    }
    let again = shrink_splats(&mut bvh, &rays, &params).unwrap();
    assert_eq!((again.shrunk_splats, again.crossings), (0, 0));
}

#[test]
fn wedges_at_1e_minus_6_and_1e9_scale_trim_the_same_splats_and_block_no_ray() {
    // The two-plane scene scaled: the same splats are trimmed (a few may differ by rounding
    // at the window's ends), every wedge radius stays finite and within the disc, and no
    // input ray is blocked afterwards.
    let (discs, rays, _) = two_planes();
    let params = ShrinkParams { trim: Trim::Wedges, ..ShrinkParams::default() };
    let shrunk = |scale: f32| {
        let discs: Vec<Disc> =
            discs.iter().map(|d| Disc::new(d.centre.map(|c| c * scale), d.normal, d.radius * scale)).collect();
        let rays: Vec<InputRay> = rays
            .iter()
            .map(|r| InputRay { origin: r.origin.map(|c| c * scale), length: r.length * scale, ..*r })
            .collect();
        let mut bvh = DiscBvh::build(&discs).unwrap();
        let stats = shrink_splats(&mut bvh, &rays, &params).unwrap();
        let mut stack = Vec::new();
        for ray in &rays {
            if let Some(window) = blocking_window(ray, stats.epsilon_floor, &params) {
                for_each_blocker(&bvh, ray, window, &mut stack, |hit| {
                    panic!("scale {scale}: {ray:?} blocked by {hit:?}")
                });
            }
        }
        let wedges = bvh.wedge_radii();
        assert!(wedges.iter().zip(&discs).all(|(w, d)| w.iter().all(|&r| r.is_finite() && r <= d.radius)));
        stats.shrunk_splats
    };
    let unit = shrunk(1.0);
    assert!(unit > 10);
    for scale in [1e-6f32, 1e9] {
        let scaled = shrunk(scale);
        assert!(scaled.abs_diff(unit) <= unit / 50, "scale {scale}: {scaled} shrunk, {unit} at unit scale");
    }
}

#[test]
fn random_scenes_match_the_definition_for_any_thread_count() {
    // Random discs and random rays between random points, some escaping.
    let mut rng = Lcg(17);
    let discs: Vec<Disc> = (0..2000)
        .map(|_| {
            let n = normalize([rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5 + 1e-3]);
            Disc::new([rng.uniform() * 3.0, rng.uniform() * 3.0, rng.uniform() * 3.0], n, rng.uniform() * 0.3)
        })
        .collect();
    let rays: Vec<InputRay> = (0..3000)
        .map(|j| {
            let own = (j * 7 % discs.len()) as u32;
            let origin = [rng.uniform() * 3.0, rng.uniform() * 3.0, rng.uniform() * 3.0];
            let offset = crate::vector::sub(discs[own as usize].centre, origin);
            let l = length(offset);
            let direction = [offset[0] / l, offset[1] / l, offset[2] / l];
            if j % 5 == 0 {
                InputRay { time: 0.0, origin, direction, length: f32::INFINITY, own_splat: None }
            } else {
                InputRay { time: 0.0, origin, direction, length: l, own_splat: Some(own) }
            }
        })
        .collect();
    let mut kept = Vec::new();
    for trim in BOTH_TRIMS {
        let params = ShrinkParams { trim, ..ShrinkParams::default() };
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut bvh = DiscBvh::build(&discs).unwrap();
            let stats = pool.install(|| shrink_splats(&mut bvh, &rays, &params).unwrap());
            (bvh.wedge_radii(), stats)
        };
        let (one, stats) = run(1);
        let (two, stats_two) = run(2);
        assert!(same_bits(&one, &two), "{trim:?}");
        assert_eq!(stats, stats_two);
        let expected = shrunk_by_brute_force(&discs, &rays, &params, stats.epsilon_floor);
        assert!(same_bits(&one, &expected), "{trim:?}");
        assert!(stats.shrunk_splats > 100, "{stats:?}");
        kept.push(one);
    }
    // Wedges never keep less than the whole-disc rule (every wedge at least its radius) and,
    // here, keep more area.
    let (disc, wedges) = (&kept[0], &kept[1]);
    assert!(disc.iter().zip(wedges).all(|(d, w)| w.iter().all(|&r| r >= d[0])));
    let area = |radii: &[[f32; WEDGES]]| radii.iter().flatten().map(|r| (r * r) as f64).sum::<f64>();
    assert!(area(wedges) > 1.1 * area(disc), "{} {}", area(wedges), area(disc));
}

/// `cargo test --release -p recon --lib ilfr::shrink -- --ignored --nocapture`
#[test]
#[ignore = "timing, run by hand"]
fn shrinking_speed() {
    // 200k splats on a bumpy 20 × 20 surface (radius 2 spacings) and 200k rays to its samples
    // from 1 to 3 units up and up to 1 aside, a quarter escaping upwards. (Rays are not checked
    // against the true surface, so a few cross its hills: the counts are indicative only.)
    let n = 200_000;
    let mut rng = Lcg(1);
    let spacing = (400.0f32 / n as f32).sqrt();
    let height = |x: f32, y: f32| 0.5 * (x * 0.7).sin() * (y * 0.5).cos();
    let discs: Vec<Disc> = (0..n)
        .map(|_| {
            let (x, y) = (rng.uniform() * 20.0, rng.uniform() * 20.0);
            let normal = [-0.35 * (x * 0.7).cos() * (y * 0.5).cos(), 0.25 * (x * 0.7).sin() * (y * 0.5).sin(), 1.0];
            Disc::new([x, y, height(x, y)], normal, 2.0 * spacing)
        })
        .collect();
    let rays: Vec<InputRay> = (0..n)
        .map(|j| {
            let target = discs[j].centre;
            let origin = [
                target[0] + 2.0 * rng.uniform() - 1.0,
                target[1] + 2.0 * rng.uniform() - 1.0,
                1.0 + 2.0 * rng.uniform(),
            ];
            if j % 4 == 0 {
                return InputRay { time: 0.0, origin, direction: UP, length: f32::INFINITY, own_splat: None };
            }
            let offset = crate::vector::sub(discs[j].centre, origin);
            let l = length(offset);
            InputRay {
                time: 0.0,
                origin,
                direction: [offset[0] / l, offset[1] / l, offset[2] / l],
                length: l,
                own_splat: Some(j as u32),
            }
        })
        .collect();
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let start = std::time::Instant::now();
    let stats = shrink_splats(&mut bvh, &rays, &ShrinkParams::default()).unwrap();
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{n} splats, {} rays: {seconds:.3} s ({:.0} rays/s on {} threads, refit included); {stats:?}",
        rays.len(),
        rays.len() as f64 / seconds,
        rayon::current_num_threads()
    );
}
