//! The unit tests of `hierarchy.rs`, in a file of their own beside it for their length.

use super::*;
use crate::tlfr::bounds::sample_bounds;
use crate::tlfr::query::{reconstruct, QueryStats, Scene, Scratch};
use crate::tlfr::reprojection::near_limit;
use crate::tlfr::same_surface::same_surface;
use crate::tlfr::test_scenes::{layered_scene, sample_scene, Lcg, MovingRect, ThinLens};

/// A scene of random moving rectangles over a `width` × `height` image with defocus; one of
/// them moves through the camera plane.
fn random_scene(seed: u64, width: u32, height: u32) -> (ThinLens, Vec<MovingRect>) {
    let mut rng = Lcg(seed);
    let lens =
        ThinLens { f: width as f32, a: 0.02 + 0.1 * rng.uniform(), focus: 1.5 + 4.0 * rng.uniform(), width, height };
    let mut rects = Vec::new();
    for k in 0..6 {
        let z = 1.0 + 8.0 * rng.uniform();
        let (x, y) = (z * (rng.uniform() - 0.6), z * (rng.uniform() - 0.6));
        let size = z * (0.1 + 0.5 * rng.uniform());
        let motion = if k == 0 {
            // Through the camera plane within the shutter.
            [0.2 * (rng.uniform() - 0.5), 0.2 * (rng.uniform() - 0.5), -z / (0.3 + 0.6 * rng.uniform())]
        } else {
            [0.3 * (rng.uniform() - 0.5), 0.3 * (rng.uniform() - 0.5), 2.0 * (rng.uniform() - 0.5)]
        };
        rects.push(MovingRect {
            x: [x, x + size],
            y: [y, y + size * (0.5 + rng.uniform())],
            z,
            motion,
            colour: [rng.uniform(), rng.uniform(), rng.uniform()],
        });
    }
    (lens, rects)
}

fn build(
    lens: &ThinLens,
    rects: &[MovingRect],
    spp: u32,
    seed: u64,
    max_reach: f32,
) -> (Vec<LensTimeSample>, Hierarchy, Vec<u32>, f32) {
    let (samples, _) = sample_scene(lens, rects, spp, [0.0; 3], seed);
    let z_near = near_limit(samples.iter().map(|s| s.z));
    let area = ScreenArea { width: lens.width as f32, height: lens.height as f32, max_reach };
    let (hierarchy, order) = Hierarchy::build(&samples, &lens.model(), z_near, &area);
    (samples, hierarchy, order, z_near)
}

/// The samples within `reach` of `location` at `at` (indices into `samples`, sorted):
/// through `hierarchy`'s leaves (each entry that takes t̂; asserting no sample comes twice)
/// and by scanning every sample; and the entries the tree found.
fn tree_and_scan(
    samples: &[LensTimeSample],
    hierarchy: &Hierarchy,
    order: &[u32],
    model: &LensModel,
    z_near: f32,
    (location, at, reach): ([f32; 2], LensTime, f32),
    leaves: &mut Vec<u32>,
) -> (Vec<u32>, Vec<u32>, Vec<usize>) {
    let within = |s: &LensTimeSample| {
        reproject(s, model, at, z_near).is_some_and(|p| {
            let (dx, dy) = (p.x - location[0], p.y - location[1]);
            dx * dx + dy * dy <= reach * reach
        })
    };
    let scanned: Vec<u32> = (0..samples.len() as u32).filter(|&i| within(&samples[i as usize])).collect();
    hierarchy.leaves_near(location, at, reach, leaves);
    let entries: Vec<usize> = leaves
        .iter()
        .flat_map(|&leaf| hierarchy.node(leaf).samples())
        .filter(|&k| hierarchy.entry_takes(k, at.t) && within(&samples[order[k] as usize]))
        .collect();
    let mut through_tree: Vec<u32> = entries.iter().map(|&k| order[k]).collect();
    through_tree.sort_unstable();
    let mut distinct = through_tree.clone();
    distinct.dedup();
    assert_eq!(distinct, through_tree, "a sample found twice at {location:?} {at:?}");
    (through_tree, scanned, entries)
}

/// Stiff case "samples on tile borders": the bins (tiles) of this input are exactly 1 px
/// (4761 samples over 32 × 32 px at `SAMPLES_PER_BIN` = 8 give 32 bins a side), and half of the samples
/// lie on their borders: a lattice of spacing 0.5 px from x, y = 0 to 32 inclusive, so also
/// on the image's own border (clamped into the border bins), plus a ring just outside the
/// image. Two planes, the near one ending exactly on the bin line x = 16, seen through a
/// lens (C = ±1.2 px). Queries exactly on bin corners, on the image border and at its
/// corners find exactly what a scan finds; a constant scene reconstructs exactly there.
#[test]
fn samples_on_tile_borders_are_found_as_a_scan_finds_them() {
    let model = LensModel { c1: -4.8, c2: 1.6, fx: 32.0, fy: 32.0, cx: 16.0, cy: 16.0 };
    let mut rng = Lcg(9);
    let mut samples = Vec::new();
    for j in -2..=66 {
        for i in -2..=66 {
            let (x, y) = (0.5 * i as f32, 0.5 * j as f32);
            let (u, v) = rng.disk();
            let z = if x < 16.0 { 2.0 } else { 6.0 };
            samples.push(LensTimeSample { x, y, u, v, t: 0.5, z, motion: [0.0; 3] });
        }
    }
    let z_near = near_limit(samples.iter().map(|s| s.z));
    let radius = 0.5;
    let area = ScreenArea { width: 32.0, height: 32.0, max_reach: 16.0 * radius };
    let (hierarchy, order) = Hierarchy::build(&samples, &model, z_near, &area);
    assert_eq!(hierarchy.unplaced, 0);
    let mut leaves = Vec::new();
    let mut found = 0;
    for (k, (qx, qy)) in
        [(0, 0), (16, 16), (32, 32), (0, 32), (32, 0), (16, 0), (7, 31), (31, 8), (16, 5)].into_iter().enumerate()
    {
        for reach in [0.5f32, 1.0, 2.0, 8.0] {
            for (u, v) in [(0.0, 0.0), (1.0, 0.0), (-0.6, 0.8), (0.0, -1.0)] {
                let at = LensTime { u, v, t: 0.5 };
                let location = [qx as f32, qy as f32];
                let (through_tree, scanned, _) =
                    tree_and_scan(&samples, &hierarchy, &order, &model, z_near, (location, at, reach), &mut leaves);
                assert_eq!(through_tree, scanned, "query {k} at {location:?} {at:?} reach {reach}");
                found += scanned.len();
            }
        }
    }
    assert!(found > 5000, "{found}");
    // A constant scene comes back exactly at every one of those locations.
    let colours = vec![[0.25, 0.5, 1.0]; samples.len()];
    let (ordered, ordered_colours) = (reorder(&samples, &order), reorder(&colours, &order));
    let scene = Scene {
        samples: &ordered,
        radiance: &ordered_colours,
        lens: &model,
        hierarchy: &hierarchy,
        radius,
        z_near,
        delta: 0.125,
        view_bandwidth: None,
    };
    let (mut scratch, mut stats) = (Scratch::default(), QueryStats::default());
    for (qx, qy) in [(0.0, 0.0), (16.0, 16.0), (32.0, 32.0), (0.0, 32.0), (16.0, 0.0), (31.5, 7.0)] {
        for (u, v) in [(0.0, 0.0), (1.0, 0.0), (-0.6, 0.8)] {
            let value = reconstruct(&scene, [qx, qy], LensTime { u, v, t: 0.5 }, &mut scratch, &mut stats);
            assert_eq!(value, Some([0.25, 0.5, 1.0]), "at ({qx}, {qy}), lens ({u}, {v})");
        }
    }
}

/// The samples within `reach` of `location` at `at` (by index into the original samples),
/// through the tree (each entry that takes t̂) and by scanning every sample: the same, and
/// no sample twice. Scenes with a surface flying through the camera plane, whose samples
/// are split into time segments; a third of the query times are the segments' own
/// boundaries, where one segment ends and the next begins.
#[test]
fn the_tree_finds_exactly_the_samples_a_scan_finds() {
    let radius = 0.6;
    let max_reach = 16.0 * radius;
    for seed in 0..4u64 {
        let (lens, rects) = if seed == 0 { layered_scene(64, 40, true) } else { random_scene(seed, 64, 40) };
        let (samples, hierarchy, order, z_near) = build(&lens, &rects, 6, seed, max_reach);
        let model = lens.model();
        assert!(hierarchy.leaf_count() > samples.len() / MAX_LEAF_SAMPLES);
        let boundaries: Vec<f32> =
            hierarchy.segment_times.iter().map(|times| times[0]).filter(|t| t.is_finite()).collect();
        assert!(boundaries.len() > 100, "scene {seed}: {} segment boundaries", boundaries.len());
        let mut rng = Lcg(seed + 100);
        let (mut leaves, mut found_total, mut found_in_segments) = (Vec::new(), 0, 0);
        for query in 0..450 {
            let location = [64.0 * rng.uniform(), 40.0 * rng.uniform()];
            let (u, v) = rng.disk();
            let t = if query % 3 == 2 {
                boundaries[(rng.uniform() * boundaries.len() as f32) as usize % boundaries.len()]
            } else {
                rng.uniform()
            };
            let at = LensTime { u, v, t };
            let reach = radius * [2.0f32, 4.0, 8.0, 16.0][query % 4];
            let (through_tree, scanned, entries) =
                tree_and_scan(&samples, &hierarchy, &order, &model, z_near, (location, at, reach), &mut leaves);
            assert_eq!(through_tree, scanned, "scene {seed}, {location:?} {at:?} reach {reach}");
            found_total += scanned.len();
            found_in_segments += entries.iter().filter(|&&k| k >= hierarchy.whole_entries).count();
            // The pruning works: far fewer leaves than all.
            assert!(leaves.len() < hierarchy.leaf_count(), "{} of {}", leaves.len(), hierarchy.leaf_count());
        }
        assert!(found_total > 1000 && found_in_segments > 10, "scene {seed}: {found_total}, {found_in_segments}");
    }
}

#[test]
fn every_leaf_holds_one_surface_of_at_most_32_samples() {
    for seed in 0..4u64 {
        let (lens, rects) = if seed == 0 { layered_scene(48, 32, true) } else { random_scene(seed + 10, 48, 32) };
        let (samples, hierarchy, order, z_near) = build(&lens, &rects, 8, seed, 8.0);
        let model = lens.model();
        let area = ScreenArea { width: 48.0, height: 32.0, max_reach: 8.0 };
        // Every placed sample is in one leaf per time segment; the unplaced are never near the
        // image.
        let segments: Vec<_> = samples.iter().map(|s| sample_segments(s, &model, z_near, &area)).collect();
        // The time span of entry k's bounds.
        let span = |k: usize| {
            let own = &segments[order[k] as usize];
            if k < hierarchy.whole_entries {
                assert_eq!(own.len(), 1, "a whole entry of a sample with several segments");
                own[0].bounds.span
            } else {
                let times = hierarchy.segment_times[k - hierarchy.whole_entries];
                own.iter().find(|s| s.times == times).expect("the entry's segment").bounds.span
            }
        };
        let mut seen = vec![0u32; samples.len()];
        let (mut pairs, mut split_leaves) = (0, 0);
        for node in hierarchy.nodes().iter().filter(|n| n.is_leaf()) {
            let range = node.samples();
            assert!((1..=MAX_LEAF_SAMPLES).contains(&range.len()));
            // A leaf holds whole samples or time segments.
            assert!(range.end <= hierarchy.whole_entries || range.start >= hierarchy.whole_entries);
            for k in range.clone() {
                seen[order[k] as usize] += 1;
            }
            for a in range.clone() {
                for b in range.start..a {
                    let (sa, sb) = (&samples[order[a] as usize], &samples[order[b] as usize]);
                    let (ta, tb) = (span(a), span(b));
                    let same = if ta == [0.0, 1.0] && tb == [0.0, 1.0] {
                        // The whole domain: δ = 1 around the cube's centre.
                        let centre = LensTime { u: 0.0, v: 0.0, t: 0.5 };
                        same_surface(sa, sb, &model, centre, 1.0, BUILD_CROSSING_TOLERANCE_PX, z_near)
                    } else {
                        let (t0, t1) = (ta[0].max(tb[0]), ta[1].min(tb[1]));
                        let corner = |w: f32, t: f32| LensTime { u: w, v: w, t };
                        let corners = [corner(-1.0, t0), corner(-1.0, t1), corner(1.0, t0), corner(1.0, t1)];
                        t0 <= t1 && same_surface_at(sa, sb, &model, corners, BUILD_CROSSING_TOLERANCE_PX, z_near)
                    };
                    assert!(same, "scene {seed}: {sa:?} and {sb:?} share a leaf");
                    pairs += 1;
                }
            }
            split_leaves += (range.len() < MAX_LEAF_SAMPLES) as usize;
        }
        for (i, count) in seen.iter().enumerate() {
            assert_eq!(*count as usize, segments[i].len(), "sample {i}");
            assert_eq!(segments[i].is_empty(), sample_bounds(&samples[i], &model, z_near, &area).is_none());
        }
        assert_eq!(hierarchy.unplaced, seen.iter().filter(|&&c| c == 0).count());
        assert!(pairs > 10_000 && split_leaves > 0, "{pairs} pairs");
    }
}

#[test]
fn the_same_input_gives_the_same_tree_for_any_thread_count() {
    let (lens, rects) = random_scene(5, 64, 40);
    let (samples, _) = sample_scene(&lens, &rects, 8, [0.0; 3], 5);
    let z_near = near_limit(samples.iter().map(|s| s.z));
    let area = ScreenArea { width: 64.0, height: 40.0, max_reach: 10.0 };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| Hierarchy::build(&samples, &lens.model(), z_near, &area))
    };
    let one = run(1);
    assert_eq!(one, run(2));
    assert_eq!(one, run(3));
    assert!(one.0.leaf_count() > 0);
}

#[test]
fn nodes_take_one_cache_line_and_the_layout_is_depth_first() {
    assert_eq!(std::mem::size_of::<Node>(), 64);
    let (lens, rects) = layered_scene(40, 30, false);
    let (samples, hierarchy, order, _) = build(&lens, &rects, 4, 1, 8.0);
    assert_eq!(order.len() + hierarchy.unplaced, samples.len());
    assert_eq!((hierarchy.whole_entries, hierarchy.entry_count()), (order.len(), order.len()));
    // Inner nodes are followed by their subtree; leaves cover the entries in order.
    let mut next_sample = 0;
    for (i, node) in hierarchy.nodes().iter().enumerate() {
        if node.is_leaf() {
            assert_eq!(node.samples().start, next_sample);
            next_sample = node.samples().end;
        } else {
            assert!(node.first_or_end as usize > i + 1 && node.first_or_end as usize <= hierarchy.nodes().len());
        }
    }
    assert_eq!(next_sample, order.len());
    assert_eq!(hierarchy.nodes().len(), 2 * hierarchy.leaf_count() - 1);
    assert!(hierarchy.node_bytes() as f64 / samples.len() as f64 <= 16.0);
    // With a card flying through the camera: the whole samples' leaves in order, then the
    // time segments' leaves in order.
    let (lens, rects) = layered_scene(40, 30, true);
    let (_, hierarchy, order, _) = build(&lens, &rects, 4, 1, 8.0);
    assert!(hierarchy.segment_entries() > 0 && hierarchy.entry_count() == order.len());
    let mut next = [0, hierarchy.whole_entries];
    for node in hierarchy.nodes().iter().filter(|n| n.is_leaf()) {
        let part = (node.samples().start >= hierarchy.whole_entries) as usize;
        assert_eq!(node.samples().start, next[part]);
        next[part] = node.samples().end;
    }
    assert_eq!(next, [hierarchy.whole_entries, order.len()]);
    // A binary tree: one fewer inner node than leaves.
    assert_eq!(hierarchy.nodes().len(), 2 * hierarchy.leaf_count() - 1);
}

#[test]
fn an_empty_or_unseen_input_has_no_leaves() {
    let lens = LensModel { c1: 0.0, c2: 0.0, fx: 10.0, fy: 10.0, cx: 5.0, cy: 5.0 };
    let area = ScreenArea { width: 10.0, height: 10.0, max_reach: 2.0 };
    let (h, order) = Hierarchy::build(&[], &lens, 1e-3, &area);
    assert!(h.nodes().is_empty() && order.is_empty());
    let far = LensTimeSample { x: 500.0, y: 5.0, t: 0.5, z: 1.0, ..LensTimeSample::default() };
    let (h, order) = Hierarchy::build(&[far], &lens, 1e-3, &area);
    assert!(h.nodes().is_empty() && order.is_empty() && h.unplaced == 1);
    let mut out = vec![7];
    h.leaves_near([5.0, 5.0], LensTime { u: 0.0, v: 0.0, t: 0.5 }, 2.0, &mut out);
    assert!(out.is_empty());
}
