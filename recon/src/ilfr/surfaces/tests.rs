//! The unit tests of `surfaces.rs`, in a file of their own beside it for their length.

use super::*;
use crate::ilfr::disc::Disc;

/// The ray of every test: from the origin along +y (depth = y).
const RAY: Ray = Ray { time: 0.0, origin: [0.0; 3], direction: [0.0, 1.0, 0.0] };

fn unit(x: f32, y: f32, z: f32) -> [f32; 3] {
    normalize([x, y, z])
}

/// Candidates for hand-made discs (all of which the ray must hit), sorted as in reconstruction.
fn candidates(discs: &[Disc], params: &SurfaceParams) -> Vec<Candidate> {
    let bvh = DiscBvh::build(discs).unwrap();
    let (mut stack, mut hits, mut out) = (Vec::new(), Vec::new(), Vec::new());
    bvh.collect_hits(&RAY, 0.0, f32::INFINITY, &mut stack, &mut hits);
    assert_eq!(hits.len(), discs.len(), "every test disc is hit");
    prepare_candidates(&bvh, &hits, RAY.time, params, &mut out);
    out
}

fn every_test() -> [SurfaceParams; 3] {
    [ConflictTest::EventLineOffPlane, ConflictTest::FacingOrCoplanar, ConflictTest::EventLine]
        .map(|conflict_test| SurfaceParams { conflict_test, ..SurfaceParams::default() })
}

fn groups(discs: &[Disc], params: &SurfaceParams) -> Vec<Vec<u32>> {
    let c = candidates(discs, params);
    let mut out = Vec::new();
    let mut start = 0;
    while start < c.len() {
        let end = group_end(&RAY, &c, start, params.conflict_test);
        out.push(c[start..end].iter().map(|c| c.id).collect());
        start = end;
    }
    out
}

#[test]
fn candidates_sort_by_depth_then_index_at_any_length() {
    // The insertion sort of short lists and the general sort of long ones against a plain
    // sort by (depth, id), with ties in depth (equal depths decided by the index).
    let mut rng = crate::lcg::Lcg(5);
    for n in [0usize, 1, 2, 7, 24, 25, 200] {
        let list: Vec<Candidate> = (0..n)
            .map(|k| Candidate {
                id: (k as u32 * 7919) % 1009,
                centre: [0.0; 3],
                normal: [0.0, 0.0, 1.0],
                radius: 1.0,
                hit: DiscHit { t: 0.0, spatial: 0.0, depth: (rng.uniform() * 4.0).floor(), back_facing: false },
            })
            .collect();
        let mut expected = list.clone();
        expected.sort_by(|a, b| a.hit.depth.total_cmp(&b.hit.depth).then(a.id.cmp(&b.id)));
        let mut sorted = list;
        sort_by_depth(&mut sorted);
        assert_eq!(sorted, expected, "n = {n}");
    }
}

#[test]
fn coplanar_splats_are_one_surface() {
    // Three splats on the plane y = 2 facing the ray origin, with the plane tilted 30° about z:
    // their event lines lie in the plane, on both half-spaces' boundary.
    let n = unit(0.5, -(0.75f32).sqrt(), 0.0); // normal of the tilted plane, towards the origin
    let along = unit((0.75f32).sqrt(), 0.5, 0.0); // in the plane, ⟂ z
    let at = |s: f32, z: f32| [0.0 + s * along[0], 2.0 + s * along[1], z];
    let discs = [Disc::new(at(-0.3, 0.1), n, 0.8), Disc::new(at(0.2, -0.2), n, 0.8), Disc::new(at(0.5, 0.0), n, 0.8)];
    for params in every_test() {
        assert_eq!(groups(&discs, &params).len(), 1, "{params:?}");
    }
}

/// Neighbouring splats of one noisy surface, side by side across the ray, must not
/// fragment it. A jittered lattice of splats on the plane y = 2 (spacing 0.1, radius 0.2, as
/// k-NN sizing makes them), each normal tilted by up to 10° at random (shading-normal noise),
/// seen by rays from the origin up to 60° off the plane's normal. Under the default test (and
/// the authors') every ray finds one surface of all the splats it hits, none merged. The
/// paper's plain event-line test
/// splits such surfaces (its crossing point runs off to infinity when a pair lies side by side
/// across the ray, so normal noise decides the sign): it must fragment a fair share of rays,
/// which is why it is not the default.
#[test]
fn side_by_side_coplanar_neighbours_with_noisy_normals_are_one_surface() {
    let mut state = 0x9e37_79b9_u32;
    let mut uniform = move || {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 8) as f32 / (1u32 << 24) as f32
    };
    let mut discs = Vec::new();
    for i in -40..=40 {
        for k in -40..=40 {
            let centre = [i as f32 * 0.1 + 0.03 * uniform(), 2.0, k as f32 * 0.1 + 0.03 * uniform()];
            let tilt = 10f32.to_radians() * uniform().sqrt();
            let phi = std::f32::consts::TAU * uniform();
            let normal = [tilt.sin() * phi.cos(), -tilt.cos(), tilt.sin() * phi.sin()];
            discs.push(Disc::new(centre, normal, 0.2));
        }
    }
    let bvh = DiscBvh::build(&discs).unwrap();
    let (mut stack, mut hits, mut candidates) = (Vec::new(), Vec::new(), Vec::new());
    let mut fragmented = [0usize; 3];
    let rays = 400;
    for r in 0..rays {
        let theta = 60f32.to_radians() * uniform().sqrt();
        let phi = std::f32::consts::TAU * uniform();
        let direction = [theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()];
        let ray = Ray { time: 0.0, origin: [0.0; 3], direction };
        bvh.collect_hits(&ray, 0.0, f32::INFINITY, &mut stack, &mut hits);
        let tests = [ConflictTest::EventLineOffPlane, ConflictTest::FacingOrCoplanar, ConflictTest::EventLine];
        for (slot, test) in tests.into_iter().enumerate() {
            let params = SurfaceParams { conflict_test: test, ..SurfaceParams::default() };
            prepare_candidates(&bvh, &hits, 0.0, &params, &mut candidates);
            assert!(candidates.len() >= 3, "ray {r} meets the lattice");
            let surface = first_surface(&ray, &candidates, &params).unwrap();
            let whole = surface.members == (0..candidates.len()) && surface.merged_surfaces == 0;
            fragmented[slot] += !whole as usize;
        }
    }
    assert_eq!(SurfaceParams::default().conflict_test, ConflictTest::EventLineOffPlane);
    assert_eq!(fragmented[0], 0, "the default test fragmented {} of {rays} rays", fragmented[0]);
    assert_eq!(fragmented[1], 0, "the authors' test fragmented {} of {rays} rays", fragmented[1]);
    assert!(fragmented[2] > rays / 20, "the event-line test fragmented only {} of {rays} rays", fragmented[2]);
}

#[test]
fn convex_and_concave_corners_are_one_surface() {
    // Figure 5 left. In the x–y plane (y = depth): a convex corner with its apex (0, 1)
    // towards the ray origin, faces towards (−1, 2) and (1, 2), outward normals (−1, −1)/√2 and
    // (1, −1)/√2; splats at (−0.5, 1.5) and (0.25, 1.25). Event line: e = (0.75, −0.25),
    // λ = −1.5 / −0.25 = 6, q = (4, 0); n_a·(q − h_a) = (−4.5 + 1.5)/√2 < 0: no conflict.
    let convex = [
        Disc::new([-0.5, 1.5, 0.0], unit(-1.0, -1.0, 0.0), 0.8),
        Disc::new([0.25, 1.25, 0.0], unit(1.0, -1.0, 0.0), 0.8),
    ];
    // A concave corner, apex (0, 2) away from the origin, faces towards (−1, 1) and (1, 1),
    // normals (1, −1)/√2 and (−1, −1)/√2, splats at (−0.5, 1.5) and (0.25, 1.75): e = (0.75,
    // 0.25), λ = −6, q = (−5, 0), n_a·(q − h_a) = (−4.5 + 1.5)/√2 < 0: no conflict.
    let concave = [
        Disc::new([-0.5, 1.5, 0.0], unit(1.0, -1.0, 0.0), 0.8),
        Disc::new([0.25, 1.75, 0.0], unit(-1.0, -1.0, 0.0), 0.8),
    ];
    for params in every_test() {
        assert_eq!(groups(&convex, &params).len(), 1, "convex, {params:?}");
        assert_eq!(groups(&concave, &params).len(), 1, "concave, {params:?}");
    }
}

#[test]
fn stacked_planes_are_two_surfaces() {
    // Figure 5 right: two planes y = 1 and y = 2 facing the origin (normal −y), splats offset
    // sideways. Event line through (0.3, 1) and (−0.2, 2): λ = −1/1, q = (0.8, 0) — at depth 0,
    // in front of both planes: n·(q − h) = 1 and 2 > 0: conflict. The nearer plane is the
    // first surface, its two splats together.
    let down = [0.0, -1.0, 0.0];
    let discs = [
        Disc::new([-0.2, 2.0, 0.1], down, 0.7),
        Disc::new([0.3, 1.0, 0.0], down, 0.7),
        Disc::new([-0.1, 1.0, 0.2], down, 0.7),
    ];
    for params in every_test() {
        assert_eq!(groups(&discs, &params), [vec![1, 2], vec![0]], "{params:?}");
        let c = candidates(&discs, &params);
        let surface = first_surface(&RAY, &c, &params).unwrap();
        assert_eq!(surface.members, 0..2);
        assert!(!surface.radiance_from_back_faces);
    }
    // The same two planes seen from behind (normals +y, both back-facing): still a conflict,
    // since n̂ is flipped to face the ray.
    let up = [0.0, 1.0, 0.0];
    let behind = [Disc::new([-0.2, 2.0, 0.1], up, 0.7), Disc::new([0.3, 1.0, 0.0], up, 0.7)];
    let params = SurfaceParams { backface_near_field_cull: false, ..SurfaceParams::default() };
    assert_eq!(groups(&behind, &params), [vec![1], vec![0]]);
}

#[test]
fn a_splat_behind_a_wall_conflicts_only_in_front_of_both() {
    // The crossing of the event line decides. Splat a on the plane y = 1 (normal −y, centre
    // (0, 1)), splat b centred at (1, 3) on planes of three slopes, all facing the ray and hit
    // by it. e = (1, 2), λ = −z_a/(d·e) = −1/2, q = h_a − e/2 = (−0.5, 0):
    // n_a·(q − h_a) = 1 > 0 always, n̂_b·(q − h_b) = (λ − 1) n̂_b·e = −1.5 n̂_b·e, positive
    // iff n̂_b·e < 0.
    let a = Disc::new([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], 2.0);
    let cases = [
        // n̂_b·e = −3/√2: conflict (b is a wall facing the origin behind a).
        (unit(-1.0, -1.0, 0.0), true),
        // n̂_b·e = −2.2/1: conflict.
        (unit(-0.6, -0.8, 0.0), true),
        // A steep plane, n̂_b·e = 0.5/|n| > 0: q lies behind b, no conflict (b could be the
        // continuation of a bending away).
        (unit(2.5, -1.0, 0.0), false),
    ];
    let params = SurfaceParams { backface_near_field_cull: false, ..SurfaceParams::default() };
    for (normal, expect) in cases {
        let b = Disc::new([1.0, 3.0, 0.0], normal, 3.0);
        let c = candidates(&[a, b], &params);
        assert_eq!((c[0].id, c[1].id), (0, 1));
        assert!(!c[1].hit.back_facing);
        assert_eq!(conflicts(&RAY, &c[0], &c[1], ConflictTest::EventLine), expect, "{normal:?}");
        assert_eq!(conflicts(&RAY, &c[1], &c[0], ConflictTest::EventLine), expect, "symmetric, {normal:?}");
    }
}

#[test]
fn an_event_line_parallel_to_the_st_plane_is_no_conflict() {
    // Two splats at the same depth on different, parallel planes (normals −y, but offset
    // sideways): the event line never meets the st plane.
    let a = Disc::new([0.2, 1.0, 0.0], [0.0, -1.0, 0.0], 0.5);
    let b = Disc::new([-0.2, 1.0, 0.0], unit(0.3, -1.0, 0.0), 0.5);
    let c = candidates(&[a, b], &SurfaceParams::default());
    assert!(!conflicts(&RAY, &c[0], &c[1], ConflictTest::EventLine));
    // Coincident centres: no conflict and nothing non-finite.
    let twin = candidates(&[a, a], &SurfaceParams::default());
    for test in [ConflictTest::EventLine, ConflictTest::FacingOrCoplanar, ConflictTest::EventLineOffPlane] {
        assert!(!conflicts(&RAY, &twin[0], &twin[1], test));
    }
    // Stiff cases of the off-plane test: splats a millionth apart, or 1e6 apart on stacked
    // planes, at scales 1e-6 and 1e9: the same decisions as at scale 1 (scale-free: the
    // coplanar limit is an angle), never from a NaN.
    for scale in [1e-6f32, 1.0, 1e9] {
        let at = |p: [f32; 3]| p.map(|c| c * scale);
        let near = candidates(
            &[
                Disc::new(at([0.0, 1.0, 0.0]), [0.0, -1.0, 0.0], 0.5 * scale),
                Disc::new(at([1e-6, 1.0, 1e-6]), [0.0, -1.0, 0.0], 0.5 * scale),
            ],
            &SurfaceParams::default(),
        );
        assert!(!conflicts(&RAY, &near[0], &near[1], ConflictTest::EventLineOffPlane), "scale {scale}");
        let stacked = candidates(
            &[
                Disc::new(at([0.1, 1.0, 0.0]), [0.0, -1.0, 0.0], 0.7 * scale),
                Disc::new(at([-0.1, 2.0, 0.0]), [0.0, -1.0, 0.0], 0.7 * scale),
            ],
            &SurfaceParams::default(),
        );
        assert!(conflicts(&RAY, &stacked[0], &stacked[1], ConflictTest::EventLineOffPlane), "scale {scale}");
    }
}

#[test]
fn back_facing_splats_give_radiance_only_when_alone() {
    // A surface at depth 2 of three coplanar splats, one of them facing away (a two-sided
    // wall sampled from both sides): only the front-facing ones give radiance.
    let down = [0.0, -1.0, 0.0];
    let up = [0.0, 1.0, 0.0];
    let params = SurfaceParams::default();
    let mixed = [
        Disc::new([0.1, 2.0, 0.0], down, 0.6),
        Disc::new([-0.2, 2.0, 0.0], up, 0.6),
        Disc::new([0.0, 2.0, 0.3], down, 0.6),
    ];
    let c = candidates(&mixed, &params);
    let surface = first_surface(&RAY, &c, &params).unwrap();
    assert_eq!(surface.members, 0..3);
    assert!(!surface.radiance_from_back_faces);
    let giving: Vec<u32> = c.iter().filter(|c| surface.gives_radiance(c)).map(|c| c.id).collect();
    assert_eq!(giving, [0, 2]);
    // All back-facing: they give radiance.
    let back = [Disc::new([0.1, 2.0, 0.0], up, 0.6), Disc::new([-0.2, 2.0, 0.0], up, 0.6)];
    let c = candidates(&back, &params);
    let surface = first_surface(&RAY, &c, &params).unwrap();
    assert!(surface.radiance_from_back_faces && c.iter().all(|c| surface.gives_radiance(c)));
}

#[test]
fn near_field_back_faces_are_dropped_when_asked() {
    // A back-facing splat at depth 0.3 with radius 0.5 (a concavity around the ray origin)
    // and a front-facing one at depth 2.
    let discs = [Disc::new([0.0, 0.3, 0.1], [0.0, 1.0, 0.0], 0.5), Disc::new([0.1, 2.0, 0.0], [0.0, -1.0, 0.0], 0.5)];
    let bvh = DiscBvh::build(&discs).unwrap();
    let (mut stack, mut hits, mut out) = (Vec::new(), Vec::new(), Vec::new());
    bvh.collect_hits(&RAY, 0.0, f32::INFINITY, &mut stack, &mut hits);
    assert_eq!(prepare_candidates(&bvh, &hits, 0.0, &SurfaceParams::default(), &mut out), 1);
    assert_eq!(out.iter().map(|c| c.id).collect::<Vec<_>>(), [1]);
    let keep = SurfaceParams { backface_near_field_cull: false, ..SurfaceParams::default() };
    assert_eq!(prepare_candidates(&bvh, &hits, 0.0, &keep, &mut out), 0);
    assert_eq!(out.iter().map(|c| c.id).collect::<Vec<_>>(), [0, 1]);
    // At depth 0.6 > radius it stays even with the rule on.
    let far = [Disc::new([0.0, 0.6, 0.1], [0.0, 1.0, 0.0], 0.5), discs[1]];
    assert_eq!(candidates(&far, &SurfaceParams::default()).len(), 2);
}

/// A wall of five coplanar splats at depth 3 (normal −y) that every test ray hits.
fn wall() -> Vec<Disc> {
    let down = [0.0, -1.0, 0.0];
    [[0.0, 0.0], [0.3, 0.0], [-0.3, 0.0], [0.0, 0.3], [0.0, -0.3]]
        .iter()
        .map(|&[x, z]| Disc::new([x, 3.0, z], down, 1.0))
        .collect()
}

#[test]
fn a_single_splat_surface_needs_the_ray_within_half_its_radius() {
    // One splat at depth 1 (radius 1, facing the origin) in front of the wall. The ray passes
    // at distance s from its centre (tangent plane = the plane y = 1): kept iff s < 0.5.
    let params = SurfaceParams::default();
    for (s, kept) in [(0.0, true), (0.45, true), (0.55, false), (0.9, false)] {
        let mut discs = vec![Disc::new([s, 1.0, 0.0], [0.0, -1.0, 0.0], 1.0)];
        discs.extend(wall());
        let c = candidates(&discs, &params);
        let surface = first_surface(&RAY, &c, &params).unwrap();
        if kept {
            assert_eq!((surface.members.clone(), surface.merged_surfaces), (0..1, 0), "s = {s}");
        } else {
            // Merged into the wall behind it: the surface is both.
            assert_eq!((surface.members.clone(), surface.merged_surfaces), (0..6, 1), "s = {s}");
        }
    }
    // The last surface is never tested: alone, the splat is the surface at any s < r.
    let lone = [Disc::new([0.9, 1.0, 0.0], [0.0, -1.0, 0.0], 1.0)];
    let c = candidates(&lone, &params);
    assert_eq!(first_surface(&RAY, &c, &params).unwrap().members, 0..1);
    assert_eq!(first_surface(&RAY, &[], &params), None);
}

#[test]
fn without_the_small_surface_rule_a_single_splat_in_front_is_the_surface() {
    // The splat of the test above, passed at s = 0.9 (the rule merges it into the wall): with
    // the rule off it is the surface, so a visibility threshold between it (depth 1) and the
    // wall (depth 3) reads it as an occluder; with the rule on, the merged surface's tent vote
    // is the wall's: visible.
    use crate::ilfr::filter::filter_visibility;
    let mut discs = vec![Disc::new([0.9, 1.0, 0.0], [0.0, -1.0, 0.0], 1.0)];
    discs.extend(wall());
    for (merge, members, visibility) in [(true, 0..6, 1.0), (false, 0..1, 0.0)] {
        let params = SurfaceParams { merge_small_surfaces: merge, ..SurfaceParams::default() };
        let c = candidates(&discs, &params);
        let surface = first_surface(&RAY, &c, &params).unwrap();
        assert_eq!((surface.members.clone(), surface.merged_surfaces), (members, merge as u32), "merge {merge}");
        let v = filter_visibility(&c, &surface, 2.0);
        assert!((v - visibility).abs() < 0.05, "merge {merge}: visibility {v}");
    }
}

#[test]
fn a_two_splat_surface_keeps_rays_inside_the_hull_of_its_footprints() {
    // Two coplanar splats at depth 1, centres (±0.7, 1, 0), radius 1: footprints (scale 0.6)
    // are circles of radius 0.6 around (±0.7, 0) on the st plane, whose hull is a stadium. A ray
    // offset by z meets both discs (√(0.49 + z²) < 1) and lies inside the stadium iff |z| < 0.6,
    // though it is farther than 0.6 from either centre.
    let params = SurfaceParams::default();
    for (z, kept) in [(0.0, true), (0.55, true), (-0.55, true), (0.65, false), (-0.68, false)] {
        let down = [0.0, -1.0, 0.0];
        let mut discs = vec![Disc::new([0.7, 1.0, -z], down, 1.0), Disc::new([-0.7, 1.0, -z], down, 1.0)];
        discs.extend(wall());
        let c = candidates(&discs, &params);
        let surface = first_surface(&RAY, &c, &params).unwrap();
        let expected = if kept { (0..2, 0) } else { (0..7, 1) };
        assert_eq!((surface.members.clone(), surface.merged_surfaces), expected, "z = {z}");
    }
}

#[test]
fn the_linear_hull_test_decides_as_the_sorted_angles_do() {
    // Random groups of 2–5 splats (random tilts, radii, scales) around and beside the ray:
    // the one-pass half-plane test against the angles' sort (the first implementation),
    // wherever the decision is not within rounding of a gap of exactly π (checked by
    // moving the group a hair both ways, which must agree with each other), and the same
    // decisions with the group at 1e-6 and 1e9 scale.
    let mut rng = crate::lcg::Lcg(41);
    let (mut inside, mut outside, mut borderline) = (0, 0, 0);
    for trial in 0..20_000 {
        let count = 2 + trial % 4;
        let spread = if trial % 3 == 0 { 0.5 } else { 2.0 };
        let shift = [(rng.uniform() - 0.5) * spread, (rng.uniform() - 0.5) * spread];
        let group: Vec<Candidate> = (0..count)
            .map(|k| Candidate {
                id: k as u32,
                centre: [
                    shift[0] + (rng.uniform() - 0.5) * 2.0,
                    1.0 + rng.uniform() * 3.0,
                    shift[1] + (rng.uniform() - 0.5) * 2.0,
                ],
                normal: unit(rng.uniform() - 0.5, -0.2 - rng.uniform(), rng.uniform() - 0.5),
                radius: 0.05 + rng.uniform() * 0.5,
                // Outside every footprint, so that the vertices decide.
                hit: DiscHit { t: 2.0, spatial: f32::INFINITY, depth: 2.0, back_facing: false },
            })
            .collect();
        let scale = 0.4 + 0.4 * rng.uniform();
        let nudged = |dx: f32| {
            let moved: Vec<Candidate> = group
                .iter()
                .map(|c| Candidate { centre: [c.centre[0] + dx, c.centre[1], c.centre[2] + dx], ..*c })
                .collect();
            inside_footprint_hull_by_angles(&RAY, &moved, scale)
        };
        if nudged(1e-4) != nudged(-1e-4) {
            borderline += 1;
            continue;
        }
        let expected = inside_footprint_hull_by_angles(&RAY, &group, scale);
        assert_eq!(inside_footprint_hull(&RAY, &group, scale), expected, "trial {trial}");
        // The same group at 1e-6 and 1e9 scale (the ray's origin is the centre of scaling).
        for size in [1e-6f32, 1e9] {
            let scaled: Vec<Candidate> = group
                .iter()
                .map(|c| Candidate { centre: c.centre.map(|v| v * size), radius: c.radius * size, ..*c })
                .collect();
            assert_eq!(inside_footprint_hull(&RAY, &scaled, scale), expected, "trial {trial} at {size}");
        }
        if expected {
            inside += 1;
        } else {
            outside += 1;
        }
    }
    assert!(inside > 2000 && outside > 2000 && borderline < 200, "{inside} {outside} {borderline}");
    // Exact configurations: two points opposite (a gap of exactly π) are inside, as the angles
    // say; one direction repeated, or an arc under π, is outside; the arc closing on the
    // far side of the start is inside.
    assert!(!in_open_half_plane(&[(1.0, 0.0), (-1.0, 0.0)]));
    assert!(in_open_half_plane(&[(1.0, 0.0), (2.0, 0.0), (3.0, 0.0)]));
    assert!(in_open_half_plane(&[(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (1.0, -1.0)]));
    assert!(!in_open_half_plane(&[(1.0, 0.0), (0.0, 1.0), (-1.0, 0.1), (-1.0, -1.0)]));
    assert!(!in_open_half_plane(&[(1.0, 0.0), (-1.0, 1.0), (-1.0, -1.0)]));
}

#[test]
fn the_footprint_hull_of_tilted_splats_is_their_projection() {
    // A splat tilted 60° away from the ray (normal (0, −cos 60°, sin 60°)): its footprint is an
    // ellipse with semi-axes ρ along x and ρ·cos 60° = ρ/2 along z. Two such splats at x = ±1
    // (radius 1, scale 0.6 → ρ = 0.6): the hull holds rays with |z| < 0.3 and not 0.35 (on the
    // st plane; the tangent-plane offset differs, so this is the projection at work).
    let n = [0.0, -0.5, (0.75f32).sqrt()];
    let at = |x: f32, z: f32| Candidate {
        id: 0,
        centre: [x, 2.0, z],
        normal: n,
        radius: 1.0,
        hit: DiscHit { t: 2.0, spatial: 1.0, depth: 2.0, back_facing: false },
    };
    for (z, inside) in [(0.0, true), (0.28, true), (-0.28, true), (0.32, false), (0.5, false)] {
        // The ray offset by z ⇔ the splats offset by −z.
        let members = [at(1.0, -z), at(-1.0, -z)];
        assert_eq!(inside_footprint_hull(&RAY, &members, 0.6), inside, "z = {z}");
    }
    // Three splats around the ray (triangle) hold it; the same three all on one side do not.
    let around = [at(1.0, 0.0), at(-0.5, 1.0), at(-0.5, -1.0)];
    assert!(inside_footprint_hull(&RAY, &around, 0.1));
    let aside = [at(1.0, 0.0), at(2.0, 1.0), at(2.0, -1.0)];
    assert!(!inside_footprint_hull(&RAY, &aside, 0.1));
    // More than three splats (their vertices go to the heap): a square around the ray holds
    // it, the same square moved aside does not, and with a fifth splat on the far side again
    // does.
    let square = [at(1.0, 1.0), at(-1.0, 1.0), at(-1.0, -1.0), at(1.0, -1.0)];
    assert!(inside_footprint_hull(&RAY, &square, 0.1));
    let moved = square.map(|c| Candidate { centre: [c.centre[0] + 3.0, c.centre[1], c.centre[2]], ..c });
    assert!(!inside_footprint_hull(&RAY, &moved, 0.1));
    let mut closed = moved.to_vec();
    closed.push(at(-2.0, 0.0));
    assert!(inside_footprint_hull(&RAY, &closed, 0.1));
}
