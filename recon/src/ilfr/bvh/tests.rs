//! The unit tests of `bvh.rs`, in a file of their own beside it for their length.

use super::*;
use crate::lcg::Lcg;
use crate::vector::length;

/// Discs on a bumpy surface and on a few random planes, with some duplicates and zero radii.
fn random_discs(n: usize, seed: u64) -> Vec<Disc> {
    let mut rng = Lcg(seed);
    let mut discs = Vec::with_capacity(n);
    for i in 0..n {
        let disc = if i % 3 == 0 {
            Disc::new(
                [rng.uniform() * 4.0, rng.uniform() * 4.0, rng.uniform() * 4.0],
                rng.unit_vector(),
                rng.uniform() * 0.3,
            )
        } else {
            let (x, y) = (rng.uniform() * 4.0, rng.uniform() * 4.0);
            let z = 0.3 * (3.0 * x).sin() * (2.0 * y).cos();
            let normal = [-0.9 * (3.0 * x).cos() * (2.0 * y).cos(), 0.6 * (3.0 * x).sin() * (2.0 * y).sin(), 1.0];
            Disc::new([x, y, z], normal, 0.02 + rng.uniform() * 0.1)
        };
        discs.push(match i % 101 {
            7 => discs[i - 1],
            8 => Disc { radius: 0.0, ..disc },
            _ => disc,
        });
    }
    discs
}

fn random_rays(n: usize, seed: u64) -> Vec<(Ray, f32, f32)> {
    let mut rng = Lcg(seed);
    (0..n)
        .map(|i| {
            let origin = [rng.uniform() * 6.0 - 1.0, rng.uniform() * 6.0 - 1.0, rng.uniform() * 3.0 - 1.0];
            let mut direction = rng.unit_vector();
            if i % 17 == 0 {
                // Axis-aligned directions exercise the 1/d guard.
                direction = [0.0, 0.0, if i % 2 == 0 { 1.0 } else { -1.0 }];
            }
            let (t_min, t_max) = match i % 3 {
                0 => (0.0, f32::INFINITY),
                1 => (1e-3, 2.0),
                _ => (0.5, 1.0 + rng.uniform() * 4.0),
            };
            (Ray { time: 0.0, origin, direction }, t_min, t_max)
        })
        .collect()
}

fn sorted(hits: &[SplatHit]) -> Vec<(u32, u32, u32, u32, bool, u32)> {
    let mut v: Vec<_> = hits
        .iter()
        .map(|h| {
            let hit = &h.hit;
            (h.id, hit.t.to_bits(), hit.spatial.to_bits(), hit.depth.to_bits(), hit.back_facing, h.radius.to_bits())
        })
        .collect();
    v.sort();
    v
}

fn assert_walk_equals_scan(bvh: &DiscBvh, rays: &[(Ray, f32, f32)]) -> usize {
    let (mut stack, mut walked, mut scanned) = (Vec::new(), Vec::new(), Vec::new());
    let mut total = 0;
    for (k, (ray, t_min, t_max)) in rays.iter().enumerate() {
        bvh.collect_hits(ray, *t_min, *t_max, &mut stack, &mut walked);
        bvh.collect_hits_brute_force(ray, *t_min, *t_max, &mut scanned);
        assert_eq!(sorted(&walked), sorted(&scanned), "ray {k}: {ray:?}");
        total += walked.len();
    }
    total
}

#[test]
fn the_walk_finds_every_disc_a_scan_finds() {
    let discs = random_discs(5000, 1);
    let bvh = DiscBvh::build(&discs).unwrap();
    let total = assert_walk_equals_scan(&bvh, &random_rays(3000, 2));
    // Not a vacuous comparison: many rays hit several discs.
    assert!(total > 3000, "{total}");
    // Leaves hold at most MAX_LEAF discs and every disc appears once.
    let mut seen = vec![false; discs.len()];
    for (id, disc) in bvh.discs() {
        assert!(!seen[id as usize]);
        seen[id as usize] = true;
        assert_eq!(*disc, discs[id as usize]);
    }
    assert!(bvh.nodes.iter().all(|n| n.count as usize <= MAX_LEAF));
}

/// The parallel build against the sequential one (its oracle): the same nodes in the same
/// places and the same disc order, on one thread and on four.
#[test]
fn the_parallel_build_lays_out_the_sequential_builds_nodes() {
    let discs = random_discs(40_000, 21);
    let refs = || -> Vec<BuildRef> {
        discs
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let (lo, hi) = d.bounds();
                BuildRef { centre: d.centre, lo, hi, id: i as u32 }
            })
            .collect()
    };
    let layout = |nodes: &[Node], refs: &[BuildRef]| -> (Vec<(u32, u32)>, Vec<u32>) {
        (nodes.iter().map(|n| (n.first, n.count)).collect(), refs.iter().map(|r| r.id).collect())
    };
    let mut sequential_refs = refs();
    let sequential = build_sequential(&mut sequential_refs, 0);
    let expected = layout(&sequential, &sequential_refs);
    assert!(sequential.len() > 4 * 40_000 / MAX_LEAF, "a deep tree: {}", sequential.len());
    for threads in [1, 4] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let mut parallel_refs = refs();
        let parallel = pool.install(|| build_subtree(&mut parallel_refs, 0));
        assert!(layout(&parallel, &parallel_refs) == expected, "{threads} threads");
    }
}

#[test]
fn the_wide_walk_returns_the_binary_walks_hits_bit_for_bit() {
    // Random clutter (bumpy surface, random planes, duplicates, zero radii), some discs
    // moving, rays at random times and windows: the wide walk, the binary walk (the walk of
    // before) and a scan agree hit for hit, every field to the bit, before and after a refit.
    let mut discs = random_discs(6000, 11);
    let mut rng = Lcg(12);
    for disc in discs.iter_mut().step_by(7) {
        *disc = disc.with_motion([rng.uniform() * 0.4 - 0.2, rng.uniform() * 0.4 - 0.2, rng.uniform() * 0.1]);
    }
    let mut rays = random_rays(3000, 13);
    for (k, (ray, _, _)) in rays.iter_mut().enumerate() {
        ray.time = (k % 5) as f32 * 0.25;
    }
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let compare = |bvh: &DiscBvh| {
        let (mut stack, mut wide, mut binary, mut total) = (Vec::new(), Vec::new(), Vec::new(), 0);
        let (mut wide_nodes, mut binary_nodes) = (0, 0);
        for (k, (ray, t_min, t_max)) in rays.iter().enumerate() {
            wide_nodes += bvh.collect_hits(ray, *t_min, *t_max, &mut stack, &mut wide).nodes;
            binary.clear();
            binary_nodes += bvh.for_each_hit_binary(ray, *t_min, *t_max, &mut stack, |h| binary.push(h)).nodes;
            assert_eq!(sorted(&wide), sorted(&binary), "ray {k}");
            total += wide.len();
        }
        assert_walk_equals_scan(bvh, &rays);
        (total, wide_nodes, binary_nodes)
    };
    let (before, wide_nodes, binary_nodes) = compare(&bvh);
    assert!(before > 3000, "{before}");
    // Four boxes per step: fewer steps than the binary walk.
    assert!(2 * wide_nodes < binary_nodes, "{wide_nodes} wide against {binary_nodes} binary steps");
    let radii: Vec<f32> = bvh.radii().iter().enumerate().map(|(i, &r)| if i % 3 == 0 { 0.5 * r } else { r }).collect();
    bvh.set_radii(&radii).unwrap();
    let (after, _, _) = compare(&bvh);
    assert!(after < before && after > 0, "{before} → {after}");
}

#[test]
fn the_wide_nodes_hold_every_leaf_once_with_its_binary_box() {
    for n in [1usize, 2, 3, 8, 9, 17, 500, 4000] {
        let bvh = DiscBvh::build(&random_discs(n, n as u64)).unwrap();
        let mut leaves: Vec<(u32, u32)> = Vec::new();
        let mut inner = vec![0usize; bvh.wide.len()];
        for node in &bvh.wide {
            let used = node.count.iter().filter(|&&c| c != EMPTY_LANE).count();
            assert!((1..=WIDTH).contains(&used));
            for lane in 0..WIDTH {
                match node.count[lane] {
                    EMPTY_LANE => {}
                    0 => inner[node.first[lane] as usize] += 1,
                    count => {
                        leaves.push((node.first[lane], count));
                        // The lane's box is that binary leaf's box.
                        let leaf = bvh.nodes.iter().find(|b| b.count == count && b.first == node.first[lane]).unwrap();
                        for axis in 0..3 {
                            assert_eq!(node.lo[axis][lane].to_bits(), leaf.lo[axis].to_bits());
                            assert_eq!(node.hi[axis][lane].to_bits(), leaf.hi[axis].to_bits());
                        }
                    }
                }
            }
        }
        // Every wide node but the root has exactly one parent; the leaves tile the discs.
        assert_eq!(inner[0], 0);
        assert!(inner[1..].iter().all(|&p| p == 1), "n = {n}");
        leaves.sort();
        let mut next = 0;
        for (first, count) in leaves {
            assert_eq!(first, next, "n = {n}");
            next += count;
        }
        assert_eq!(next as usize, n);
    }
}

#[test]
fn hits_are_those_of_the_disc_test_with_input_ids() {
    // A hand-made stack of three discs on z = 1, 2, 3 under a vertical ray: all three, in
    // any order, with their ids; a window (1.5, 2.5) keeps only the middle one.
    let discs = [
        Disc::new([0.0, 0.0, 3.0], [0.0, 0.0, 1.0], 1.0),
        Disc::new([0.2, 0.0, 1.0], [0.0, 0.0, -1.0], 0.5),
        Disc::new([5.0, 5.0, 2.0], [0.0, 0.0, 1.0], 0.1),
        Disc::new([0.0, 0.3, 2.0], [0.0, 0.6, 0.8], 0.5),
    ];
    let bvh = DiscBvh::build(&discs).unwrap();
    let ray = Ray { time: 0.0, origin: [0.0, 0.0, 0.0], direction: [0.0, 0.0, 1.0] };
    let (mut stack, mut out) = (Vec::new(), Vec::new());
    bvh.collect_hits(&ray, 0.0, f32::INFINITY, &mut stack, &mut out);
    let mut ids: Vec<u32> = out.iter().map(|h| h.id).collect();
    ids.sort();
    assert_eq!(ids, [0, 1, 3]);
    for h in &out {
        assert_eq!(Some(h.hit), intersect(&discs[h.id as usize], &ray, 0.0, f32::INFINITY));
        assert_eq!(bvh.disc_at(h.slot).1, h.id);
    }
    bvh.collect_hits(&ray, 1.5, 2.5, &mut stack, &mut out);
    assert_eq!(out.iter().map(|h| h.id).collect::<Vec<_>>(), [3]);
}

/// The nearest hit of the ordered walk against its oracle, the least (t, slot) of every hit
/// the all-hits walk returns that the filter keeps (else of those it keeps as a fallback):
/// the same hit bit for bit, for whole and trimmed discs (coincident and dead ones among
/// them), windows closed and open, filters that keep only the inner 0.7 of each radius, only
/// front faces, or the rest of the disc as a fallback, at 1e-6, 1 and 1e9 scale; with
/// `first`, some kept hit exactly when the oracle has one.
#[test]
fn the_nearest_hit_is_the_least_of_the_kept_hits() {
    let discs = random_discs(3000, 21);
    let rays = random_rays(1500, 22);
    let whole = DiscBvh::build(&discs).unwrap();
    let mut rng = Lcg(5);
    let wedges: Vec<[f32; WEDGES]> = whole
        .radii()
        .iter()
        .map(|&r| std::array::from_fn(|_| [0.0, r, r * rng.uniform()][(rng.uniform() * 3.0) as usize % 3]))
        .collect();
    let mut trimmed = whole.clone();
    trimmed.set_wedge_radii(&wedges).unwrap();
    let kept = |yes: bool| if yes { Kept::Yes } else { Kept::No };
    let everything = |_: &SplatHit| Kept::Yes;
    let inner = |h: &SplatHit| kept(h.hit.spatial < 0.7 * h.radius);
    let front = |h: &SplatHit| kept(!h.hit.back_facing);
    let inner_else_any = |h: &SplatHit| if h.hit.spatial < 0.7 * h.radius { Kept::Yes } else { Kept::Fallback };
    let inner_else_front = |h: &SplatHit| match (h.hit.spatial < 0.7 * h.radius, h.hit.back_facing) {
        (true, _) => Kept::Yes,
        (false, false) => Kept::Fallback,
        (false, true) => Kept::No,
    };
    let filters: [&dyn Fn(&SplatHit) -> Kept; 5] = [&everything, &inner, &front, &inner_else_any, &inner_else_front];
    let (mut stack, mut ordered, mut all) = (Vec::new(), Vec::new(), Vec::new());
    let mut found = 0;
    for scale in [1.0f32, 1e-6, 1e9] {
        let scaled = |bvh: &DiscBvh| {
            let discs: Vec<Disc> = bvh
                .discs()
                .map(|(_, d)| Disc { centre: d.centre.map(|c| c * scale), radius: d.radius * scale, ..*d })
                .collect();
            let mut ids = vec![0; discs.len()];
            for (slot, (id, _)) in bvh.discs().enumerate() {
                ids[id as usize] = slot;
            }
            let by_id: Vec<Disc> = ids.iter().map(|&slot| discs[slot]).collect();
            let mut out = DiscBvh::build(&by_id).unwrap();
            if bvh.wedges.is_empty() {
                return out;
            }
            let w: Vec<[f32; WEDGES]> = bvh.wedge_radii().iter().map(|w| w.map(|r| r * scale)).collect();
            out.set_wedge_radii(&w).unwrap();
            out
        };
        for bvh in [scaled(&whole), scaled(&trimmed)] {
            for (ray, t_min, t_max) in &rays {
                let ray = Ray { origin: ray.origin.map(|c| c * scale), ..*ray };
                let window = (t_min * scale, t_max * scale);
                bvh.collect_hits(&ray, window.0, window.1, &mut stack, &mut all);
                for filter in filters {
                    let least = |kind: Kept| {
                        all.iter()
                            .filter(|h| filter(h) == kind)
                            .min_by(|a, b| a.hit.t.total_cmp(&b.hit.t).then(a.slot.cmp(&b.slot)))
                            .copied()
                    };
                    let oracle = least(Kept::Yes).or(least(Kept::Fallback));
                    let (nearest, _) = bvh.nearest_hit(&ray, window, false, &mut ordered, filter);
                    assert_eq!(nearest, oracle);
                    let (any, _) = bvh.nearest_hit(&ray, window, true, &mut ordered, filter);
                    assert_eq!(any.is_some(), oracle.is_some());
                    if let Some(h) = any {
                        assert!(filter(&h) != Kept::No && all.contains(&h));
                    }
                    found += oracle.is_some() as usize;
                }
            }
        }
    }
    assert!(found > 1000, "{found} rays met a kept disc");
}

#[test]
fn trimmed_wedges_keep_the_walk_exact() {
    let discs = random_discs(4000, 15);
    let rays = random_rays(2000, 16);
    let whole = DiscBvh::build(&discs).unwrap();
    // Every wedge at the same fraction of the radius is the disc shrunk whole: the same hits.
    let mut rng = Lcg(3);
    let fraction: Vec<f32> = (0..discs.len()).map(|_| rng.uniform()).collect();
    let radii: Vec<f32> = whole.radii().iter().zip(&fraction).map(|(r, f)| r * f).collect();
    let mut shrunk = whole.clone();
    shrunk.set_radii(&radii).unwrap();
    let mut uniform = whole.clone();
    uniform.set_wedge_radii(&radii.iter().map(|&r| [r; WEDGES]).collect::<Vec<_>>()).unwrap();
    let (mut stack, mut a, mut b) = (Vec::new(), Vec::new(), Vec::new());
    for (ray, t_min, t_max) in &rays {
        shrunk.collect_hits(ray, *t_min, *t_max, &mut stack, &mut a);
        uniform.collect_hits(ray, *t_min, *t_max, &mut stack, &mut b);
        assert_eq!(sorted(&a), sorted(&b));
    }
    // Wedges of their own radii (some dead, some whole): the wide walk, the binary walk and
    // the scan agree, every hit is one of the whole disc's within the wedge radius it reports,
    // inside the smallest wedge always kept and beyond the largest never.
    let wedges: Vec<[f32; WEDGES]> = whole
        .radii()
        .iter()
        .map(|&r| std::array::from_fn(|_| [0.0, r, r * rng.uniform()][(rng.uniform() * 3.0) as usize % 3]))
        .collect();
    let mut trimmed = whole.clone();
    trimmed.set_wedge_radii(&wedges).unwrap();
    assert_eq!(trimmed.wedge_radii(), wedges);
    let total = assert_walk_equals_scan(&trimmed, &rays);
    let mut kept_inside_smallest = 0;
    let mut c = Vec::new();
    for (ray, t_min, t_max) in &rays {
        b.clear();
        trimmed.for_each_hit_binary(ray, *t_min, *t_max, &mut stack, |h| b.push(h));
        trimmed.collect_hits(ray, *t_min, *t_max, &mut stack, &mut c);
        assert_eq!(sorted(&b), sorted(&c));
        let walked = sorted(&c);
        whole.collect_hits(ray, *t_min, *t_max, &mut stack, &mut a);
        for h in &a {
            let w = &wedges[h.id as usize];
            let smallest = w.iter().copied().fold(f32::INFINITY, f32::min);
            let largest = w.iter().copied().fold(0.0, f32::max);
            let found = walked.iter().find(|x| x.0 == h.id);
            if h.hit.spatial < smallest {
                assert!(found.is_some());
                kept_inside_smallest += 1;
            }
            if h.hit.spatial >= largest {
                assert!(found.is_none());
            }
            if let Some(x) = found {
                let radius = f32::from_bits(x.5);
                assert!(w.contains(&radius) && h.hit.spatial < radius);
                assert_eq!((x.1, x.2), (h.hit.t.to_bits(), h.hit.spatial.to_bits()));
            }
        }
    }
    assert!(total > 100 && kept_inside_smallest >= 5, "{total} {kept_inside_smallest}");
    assert!(trimmed.set_wedge_radii(&wedges[1..]).is_err());
    assert!(trimmed.set_wedge_radii(&vec![[f32::NAN; WEDGES]; wedges.len()]).is_err());
}

#[test]
fn refit_after_shrinking_keeps_the_walk_exact() {
    let discs = random_discs(4000, 5);
    let mut bvh = DiscBvh::build(&discs).unwrap();
    let rays = random_rays(2000, 6);
    let before = assert_walk_equals_scan(&bvh, &rays);
    // Shrink every other disc to a pseudo-random fraction, some to zero.
    let mut rng = Lcg(9);
    let radii: Vec<f32> = bvh
        .radii()
        .iter()
        .enumerate()
        .map(|(i, &r)| match i % 4 {
            0 => r * rng.uniform(),
            1 => 0.0,
            _ => r,
        })
        .collect();
    bvh.set_radii(&radii).unwrap();
    assert_eq!(bvh.radii(), radii);
    let after = assert_walk_equals_scan(&bvh, &rays);
    assert!(after < before && after > 0, "{before} → {after}");
    // Refit boxes are tight: the root box equals that of a tree built on the shrunk discs.
    let fresh =
        DiscBvh::build(&discs.iter().zip(&radii).map(|(d, &r)| Disc { radius: r, ..*d }).collect::<Vec<_>>()).unwrap();
    let (fresh_root, refit_root) = (&fresh.nodes[0], &bvh.nodes[0]);
    assert_eq!((fresh_root.lo, fresh_root.hi), (refit_root.lo, refit_root.hi));
    assert!(bvh.set_radii(&radii[1..]).is_err());
    assert!(bvh.set_radii(&vec![f32::NAN; radii.len()]).is_err());
}

#[test]
fn the_tree_does_not_depend_on_the_thread_count() {
    // The build is sequential; built inside pools of 1 and 3 threads it is the same tree.
    let discs = random_discs(3000, 3);
    let build = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| DiscBvh::build(&discs).unwrap())
    };
    let (a, b) = (build(1), build(3));
    assert_eq!(a.ids, b.ids);
    assert_eq!(a.nodes.len(), b.nodes.len());
    for (x, y) in a.nodes.iter().zip(&b.nodes) {
        assert_eq!((x.first, x.count), (y.first, y.count));
        assert!(x.lo.iter().chain(&x.hi).zip(y.lo.iter().chain(&y.hi)).all(|(p, q)| p.to_bits() == q.to_bits()));
    }
}

#[test]
fn degenerate_sets_build_and_query() {
    // Empty, one disc, and 100 coincident discs (no centroid spread: split by order).
    let empty = DiscBvh::build(&[]).unwrap();
    let (mut stack, mut out) = (Vec::new(), Vec::new());
    let ray = Ray { time: 0.0, origin: [0.0, 0.0, 5.0], direction: [0.0, 0.0, -1.0] };
    empty.collect_hits(&ray, 0.0, f32::INFINITY, &mut stack, &mut out);
    assert!(out.is_empty());
    // 100 coincident discs, and 5000 (past PARALLEL_BUILD_MIN: the parallel build's split
    // by order, joined as the sequential one would lay it out).
    for n in [100, 5000] {
        let same = vec![Disc::new([0.0; 3], [0.0, 0.0, 1.0], 1.0); n];
        let bvh = DiscBvh::build(&same).unwrap();
        bvh.collect_hits(&ray, 0.0, f32::INFINITY, &mut stack, &mut out);
        assert_eq!(out.len(), n);
        assert!(bvh.nodes.iter().all(|node| node.count as usize <= MAX_LEAF));
    }
    // Bad input names the disc.
    let mut bad = random_discs(10, 1);
    bad[4].centre[2] = f32::NAN;
    assert!(DiscBvh::build(&bad).unwrap_err().to_string().contains("disc 4"));
    bad = random_discs(10, 1);
    bad[2].radius = -1.0;
    assert!(DiscBvh::build(&bad).unwrap_err().to_string().contains("disc 2"));
    assert!(length(bad[0].normal) > 0.99);
}

/// `cargo test --release -p recon --lib ilfr::bvh -- --ignored --nocapture`
#[test]
#[ignore = "timing, run by hand"]
fn hierarchy_speed() {
    use rayon::prelude::*;
    let n = 200_000;
    // Splats on a bumpy 20 × 20 surface sized like slice 1's k = 12 radii (≈ 2 spacings).
    let mut rng = Lcg(1);
    let spacing = (400.0f32 / n as f32).sqrt();
    let discs: Vec<Disc> = (0..n)
        .map(|_| {
            let (x, y) = (rng.uniform() * 20.0, rng.uniform() * 20.0);
            let z = 0.5 * (x * 0.7).sin() * (y * 0.5).cos();
            let normal = [-0.35 * (x * 0.7).cos() * (y * 0.5).cos(), 0.25 * (x * 0.7).sin() * (y * 0.5).sin(), 1.0];
            Disc::new([x, y, z], normal, 2.0 * spacing)
        })
        .collect();
    let start = std::time::Instant::now();
    let bvh = DiscBvh::build(&discs).unwrap();
    let build = start.elapsed().as_secs_f64();
    let leaves = bvh.nodes.iter().filter(|n| n.count > 0).count();
    let m = 1_000_000;
    // Rays leaving the surface (upper hemisphere, mostly escaping: the gather's case on a
    // plane) and rays from 3 units above crossing it (the case of a ray meeting a surface).
    let leaving: Vec<Ray> = (0..m)
        .map(|_| {
            let (x, y) = (rng.uniform() * 20.0, rng.uniform() * 20.0);
            let z = 0.5 * (x * 0.7).sin() * (y * 0.5).cos() + 0.01;
            let mut d = rng.unit_vector();
            d[2] = d[2].abs();
            Ray { time: 0.0, origin: [x, y, z], direction: d }
        })
        .collect();
    let crossing: Vec<Ray> = (0..m)
        .map(|_| {
            let (x, y) = (2.0 + rng.uniform() * 16.0, 2.0 + rng.uniform() * 16.0);
            let mut d = rng.unit_vector();
            d[2] = -d[2].abs().max(0.5);
            let l = length(d);
            Ray { time: 0.0, origin: [x, y, 3.0], direction: [d[0] / l, d[1] / l, d[2] / l] }
        })
        .collect();
    println!(
        "{n} discs: build {build:.3} s ({} nodes, {leaves} leaves, {:.1} discs/leaf), on {} threads",
        bvh.nodes.len(),
        n as f64 / leaves as f64,
        rayon::current_num_threads()
    );
    for (name, rays) in [("leaving", &leaving), ("crossing", &crossing)] {
        let start = std::time::Instant::now();
        let (hits, nodes, tested) = rays
            .par_iter()
            .map_init(
                || (Vec::new(), Vec::new()),
                |(stack, out), ray| {
                    let c = bvh.collect_hits(ray, 1e-4, f32::INFINITY, stack, out);
                    (out.len() as u64, c.nodes, c.discs_tested)
                },
            )
            .reduce(|| (0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
        let seconds = start.elapsed().as_secs_f64();
        let m = m as f64;
        println!(
            "  {name}: {:.0} rays/s, {:.1} hits/ray, {:.1} nodes/ray, {:.1} discs tested/ray",
            m / seconds,
            hits as f64 / m,
            nodes as f64 / m,
            tested as f64 / m
        );
    }
    let start = std::time::Instant::now();
    let radii: Vec<f32> = bvh.radii().iter().map(|r| r * 0.9).collect();
    let mut refitted = bvh.clone();
    refitted.set_radii(&radii).unwrap();
    let refit = start.elapsed().as_secs_f64();
    println!("  refit {refit:.4} s");
}
