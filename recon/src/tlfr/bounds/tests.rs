//! The unit tests of `bounds.rs`, in a file of their own beside it for their length.

use super::*;
use crate::tlfr::reprojection::reproject;
use crate::tlfr::test_scenes::Lcg;

/// A random lens with |C| up to about 300 px over the depths below, and a random sample; a
/// third of the samples move through the camera plane (Δz crossing zero) within the shutter.
fn random_case(rng: &mut Lcg) -> (LensModel, LensTimeSample) {
    let f = 100.0 + 400.0 * rng.uniform();
    let a = 0.4 * rng.uniform() * rng.uniform();
    let focus = 0.5 + 10.0 * rng.uniform();
    let lens = LensModel { c1: -f * a, c2: f * a / focus, fx: f, fy: f, cx: 160.0, cy: 90.0 };
    let (u, v) = rng.disk();
    let z = 0.3 + 12.0 * rng.uniform();
    let t = rng.uniform();
    let dz = match (rng.uniform() * 3.0) as u32 {
        0 => 0.0,
        1 => 2.0 * (rng.uniform() - 0.5),
        // Through the camera plane: depth z at tᵢ, zero somewhere in the shutter.
        _ => {
            let when = rng.uniform();
            -z / (when - t + if when == t { 1e-3 } else { 0.0 })
        }
    };
    let sample = LensTimeSample {
        x: -40.0 + 400.0 * rng.uniform(),
        y: -40.0 + 260.0 * rng.uniform(),
        u,
        v,
        t,
        z: if rng.uniform() < 0.03 { f32::INFINITY } else { z },
        motion: [2.0 * (rng.uniform() - 0.5), 2.0 * (rng.uniform() - 0.5), dz],
    };
    let sample = if sample.z.is_infinite() { LensTimeSample { motion: [0.0; 3], ..sample } } else { sample };
    (lens, sample)
}

const AREA: ScreenArea = ScreenArea { width: 320.0, height: 180.0, max_reach: 16.0 };

/// x' and y' of the sample at (u, v, t) lie within the bounds, up to 1e-3 px or relative
/// 1e-5 of the magnitudes involved.
fn assert_inside(bounds: &Bounds, sample: &LensTimeSample, lens: &LensModel, z_near: f32, at: LensTime) {
    let Some(p) = reproject(sample, lens, at, z_near) else {
        return;
    };
    let check = |value: f32, lo: f32, hi: f32| {
        let tolerance = 1e-3f32.max(1e-5 * value.abs().max(lo.abs()).max(hi.abs()));
        value >= lo - tolerance && value <= hi + tolerance
    };
    let (x0, x1) = (bounds.x_min.at(at.t, at.u), bounds.x_max.at(at.t, at.u));
    let (y0, y1) = (bounds.y_min.at(at.t, at.v), bounds.y_max.at(at.t, at.v));
    assert!(
        check(p.x, x0, x1) && check(p.y, y0, y1),
        "{sample:?} with {lens:?} at {at:?}: ({}, {}) outside x {x0}..{x1}, y {y0}..{y1}",
        p.x,
        p.y
    );
}

#[test]
fn sample_bounds_contain_the_reprojections_over_the_span() {
    let mut rng = Lcg(2024);
    let z_near = 1e-3;
    let (mut bounded, mut crossing) = (0, 0);
    for _ in 0..10_000 {
        let (lens, sample) = random_case(&mut rng);
        let Some(bounds) = sample_bounds(&sample, &lens, z_near, &AREA) else {
            continue;
        };
        bounded += 1;
        let [t0, t1] = bounds.span;
        assert!(t0 <= t1 && t0 >= 0.0 && t1 <= 1.0);
        crossing += (t1 - t0 < 1.0 && sample.motion[2] != 0.0) as usize;
        for i in 0..33 {
            for j in 0..33 {
                let t = t0 + (t1 - t0) * j as f32 / 32.0;
                let w = -1.0 + i as f32 / 16.0;
                assert_inside(&bounds, &sample, &lens, z_near, LensTime { u: w, v: -w, t });
            }
        }
    }
    assert!(bounded > 5000 && crossing > 1000, "{bounded} bounded, {crossing} with a cut span");
}

/// Outside its span a sample is behind the camera, or more than the largest reach away from
/// the image at every lens position: trimming never removes a time a query could use.
#[test]
fn trimmed_times_are_far_from_the_image() {
    let mut rng = Lcg(77);
    let z_near = 1e-3;
    let mut trimmed = 0;
    for _ in 0..10_000 {
        let (lens, sample) = random_case(&mut rng);
        let span = sample_bounds(&sample, &lens, z_near, &AREA).map(|b| b.span);
        for j in 0..=64 {
            let t = j as f32 / 64.0;
            if span.is_some_and(|[t0, t1]| t >= t0 && t <= t1) {
                continue;
            }
            for i in 0..=8 {
                let w = -1.0 + i as f32 / 4.0;
                for at in [LensTime { u: w, v: 0.0, t }, LensTime { u: 0.0, v: w, t }] {
                    if let Some(p) = reproject(&sample, &lens, at, z_near) {
                        trimmed += 1;
                        let outside_x = (-p.x).max(p.x - AREA.width);
                        let outside_y = (-p.y).max(p.y - AREA.height);
                        assert!(
                            outside_x.max(outside_y) > AREA.max_reach * 0.999,
                            "{sample:?} at {at:?} is at ({}, {}), inside the reach, but outside {span:?}",
                            p.x,
                            p.y
                        );
                    }
                }
            }
        }
    }
    assert!(trimmed > 1000, "{trimmed}");
}

/// A sample's time segments: consecutive half-open times taking each query time at most
/// once; within its times and span a segment's bounds contain the reprojections; a time no
/// segment takes (or outside the taking segment's span) leaves the sample behind the camera
/// or beyond the largest reach from the image.
#[test]
fn time_segments_partition_the_shutter_and_bound_their_pieces() {
    let mut rng = Lcg(4242);
    let z_near = 1e-3;
    let (mut split, mut checked_far) = (0, 0);
    for _ in 0..6000 {
        let (lens, sample) = random_case(&mut rng);
        let segments = sample_segments(&sample, &lens, z_near, &AREA);
        let whole = sample_bounds(&sample, &lens, z_near, &AREA);
        assert_eq!(segments.is_empty(), whole.is_none(), "{sample:?}");
        assert!(segments.len() <= MAX_SEGMENTS);
        split += (segments.len() > 1) as usize;
        for (k, segment) in segments.iter().enumerate() {
            let [start, end] = segment.times;
            let [t0, t1] = segment.bounds.span;
            assert!(start < end && start <= t0 && t0 <= t1 && t1 <= end, "{segment:?}");
            if let Some(next) = segments.get(k + 1) {
                assert!(end <= next.times[0]);
            }
            let whole = whole.expect("placed");
            assert!(t0 >= whole.span[0] && t1 <= whole.span[1], "{segment:?} outside {whole:?}");
        }
        if segments.len() == 1 {
            assert_eq!(segments[0].times, [f32::NEG_INFINITY, f32::INFINITY]);
        }
        for j in 0..=96 {
            // Every segment's ends, and a grid.
            let times: Vec<f32> = segments
                .iter()
                .flat_map(|s| [s.times[0], s.bounds.span[0], s.bounds.span[1]])
                .filter(|t| (0.0..=1.0).contains(t))
                .chain([j as f32 / 96.0])
                .collect();
            let t = times[j % times.len()];
            let taking: Vec<&Segment> = segments.iter().filter(|s| s.times[0] <= t && t < s.times[1]).collect();
            assert!(taking.len() <= 1, "{t} taken by {taking:?}");
            for i in 0..=8 {
                let w = -1.0 + i as f32 / 4.0;
                let at = LensTime { u: w, v: -w, t };
                match taking.first() {
                    Some(segment) if t >= segment.bounds.span[0] && t <= segment.bounds.span[1] => {
                        assert_inside(&segment.bounds, &sample, &lens, z_near, at);
                    }
                    _ => {
                        if let Some(p) = reproject(&sample, &lens, at, z_near) {
                            checked_far += 1;
                            let outside = (-p.x).max(p.x - AREA.width).max((-p.y).max(p.y - AREA.height));
                            assert!(outside > AREA.max_reach * 0.999, "{sample:?} at {at:?}: ({}, {})", p.x, p.y);
                        }
                    }
                }
            }
        }
    }
    assert!(split > 500 && checked_far > 1000, "{split} split, {checked_far} far");
}

/// A point flying into the camera plane (depth 1 → 0 over t ∈ [0, 0.5]) near the optical
/// axis: one plane pair over its whole span is thousands of pixels thick; cut into
/// `MAX_SEGMENTS` segments, all but the last (nearest the camera, a few hundredths of the
/// shutter) are under 100 px thick, the longest under 1% of the whole's thickness, and the
/// work a query sees (duration × area at one lens position) drops by more than half. (The
/// lens term û·C(t) is bilinear: a plane in (t, u) cannot bound it closer than |ΔC| over a
/// segment, which keeps even the first segment, z' from 1 to 0.5, about 10 px thick.)
#[test]
fn segments_are_thin_where_a_sample_flies_into_the_camera() {
    let lens = LensModel { c1: -9.6, c2: 3.2, fx: 160.0, fy: 160.0, cx: 80.0, cy: 45.0 };
    let area = ScreenArea { width: 160.0, height: 90.0, max_reach: 11.5 };
    let sample = LensTimeSample { x: 78.0, y: 44.0, u: 0.3, v: -0.2, t: 0.1, z: 0.8, motion: [0.05, 0.0, -2.0] };
    let whole = sample_bounds(&sample, &lens, 1e-3, &area).unwrap();
    let segments = sample_segments(&sample, &lens, 1e-3, &area);
    assert_eq!(segments.len(), MAX_SEGMENTS);
    let thickest = |b: &Bounds| b.thickness()[0].max(b.thickness()[1]);
    assert!(thickest(&whole) > 10_000.0, "{:?}", whole.thickness());
    let (last, rest) = segments.split_last().unwrap();
    assert!(last.bounds.span[1] - last.bounds.span[0] < 0.05, "{last:?}");
    assert!(rest.iter().all(|s| thickest(&s.bounds) < 100.0), "{segments:?}");
    let duration = |b: &Bounds| b.span[1] - b.span[0];
    let longest = segments.iter().max_by(|a, b| duration(&a.bounds).total_cmp(&duration(&b.bounds))).unwrap();
    assert!(thickest(&longest.bounds) < 0.01 * thickest(&whole), "{longest:?}");
    let split_work: f64 = segments.iter().map(|s| segment_work(&s.bounds, &area)).sum();
    assert!(2.0 * split_work < segment_work(&whole, &area), "{split_work}");
}

#[test]
fn the_valid_span_is_exactly_where_reprojection_succeeds() {
    let s = LensTimeSample { z: 1.0, t: 0.0, motion: [0.0, 0.0, -2.0], ..LensTimeSample::default() };
    let (lo, hi) = valid_span(&s, 1e-3).unwrap();
    assert_eq!(lo, 0.0);
    assert!((hi - 0.4995).abs() < 1e-6);
    assert!(depth_at(&s, hi) >= 1e-3 && depth_at(&s, step_up(hi)) < 1e-3);
    let towards = LensTimeSample { z: 1.0, t: 1.0, motion: [0.0, 0.0, 2.0], ..s };
    let (lo, hi) = valid_span(&towards, 1e-3).unwrap();
    assert!((lo - 0.5005).abs() < 1e-6 && hi == 1.0);
    assert!(depth_at(&towards, lo) >= 1e-3 && depth_at(&towards, step_down(lo)) < 1e-3);
    let still = LensTimeSample { z: 2.0, motion: [0.0; 3], ..s };
    assert_eq!(valid_span(&still, 1e-3), Some((0.0, 1.0)));
    // Nearer than the near limit for the whole shutter.
    assert_eq!(valid_span(&LensTimeSample { z: 1e-4, motion: [0.0; 3], ..s }, 1e-3), None);
    assert_eq!(valid_span(&LensTimeSample { z: 1e-4, motion: [0.0, 0.0, -1.0], ..s }, 1e-3), None);
    // Random samples: Some exactly on the span.
    let mut rng = Lcg(5);
    let lens = LensModel { c1: -8.0, c2: 2.0, fx: 80.0, fy: 80.0, cx: 32.0, cy: 24.0 };
    for _ in 0..2000 {
        let (_, sample) = random_case(&mut rng);
        let span = valid_span(&sample, 1e-3);
        for j in 0..=100 {
            let t = j as f32 / 100.0;
            let inside = span.is_some_and(|(a, b)| t >= a && t <= b);
            let at = LensTime { u: 0.0, v: 0.0, t };
            assert_eq!(reproject(&sample, &lens, at, 1e-3).is_some(), inside, "{sample:?} at {t}");
        }
    }
}

#[test]
fn merged_bounds_contain_both_children() {
    let mut rng = Lcg(99);
    let z_near = 1e-3;
    let mut merged_count = 0;
    for _ in 0..2000 {
        // One lens per group, as in a file.
        let (lens, _) = random_case(&mut rng);
        let mut members: Vec<(LensTimeSample, Bounds)> = Vec::new();
        while members.len() < 4 {
            let (_, sample) = random_case(&mut rng);
            if let Some(b) = sample_bounds(&sample, &lens, z_near, &AREA) {
                members.push((sample, b));
            }
        }
        let left = members[0].1.merge(&members[1].1);
        let right = members[2].1.merge(&members[3].1);
        let root = left.merge(&right);
        merged_count += 1;
        for (child, parent) in [(&members[0].1, &left), (&members[1].1, &left), (&left, &root), (&right, &root)] {
            assert!(parent.span[0] <= child.span[0] && parent.span[1] >= child.span[1]);
            for t in [child.span[0], child.span[1], 0.5 * (child.span[0] + child.span[1])] {
                for w in [-1.0f32, 0.0, 1.0] {
                    let ok = |p: &Plane, c: &Plane, upper: bool| {
                        let (pv, cv) = (p.at(t, w), c.at(t, w));
                        let tolerance = 1e-6 * pv.abs().max(cv.abs()).max(1.0);
                        if upper {
                            pv >= cv - tolerance
                        } else {
                            pv <= cv + tolerance
                        }
                    };
                    assert!(ok(&parent.x_min, &child.x_min, false) && ok(&parent.x_max, &child.x_max, true));
                    assert!(ok(&parent.y_min, &child.y_min, false) && ok(&parent.y_max, &child.y_max, true));
                }
            }
        }
        // And the samples themselves.
        for (sample, own) in &members {
            for j in 0..=16 {
                let t = own.span[0] + (own.span[1] - own.span[0]) * j as f32 / 16.0;
                for i in 0..=8 {
                    let w = -1.0 + i as f32 / 4.0;
                    assert_inside(&root, sample, &lens, z_near, LensTime { u: w, v: w, t });
                }
            }
        }
    }
    assert_eq!(merged_count, 2000);
}

#[test]
fn a_static_sample_has_exact_planes_and_the_node_test_uses_them() {
    let lens = LensModel { c1: -8.0, c2: 2.0, fx: 80.0, fy: 80.0, cx: 32.0, cy: 24.0 };
    // C(2) = −2: x' = 10 + 0.5·2 − 2û (x̄ = 11), y' = 20 + 2v̂·… (ȳ = 20).
    let sample = LensTimeSample { x: 10.0, y: 20.0, u: 0.5, v: 0.0, t: 0.3, z: 2.0, motion: [0.0; 3] };
    let b = sample_bounds(&sample, &lens, 1e-3, &ScreenArea { width: 64.0, height: 48.0, max_reach: 4.0 }).unwrap();
    assert_eq!(b.span, [0.0, 1.0]);
    for plane in [b.x_min, b.x_max] {
        assert_eq!((plane.time, plane.lens), (0.0, -2.0));
        assert!((plane.constant - 11.0).abs() < 1e-4);
    }
    let at = LensTime { u: 1.0, v: 0.0, t: 0.7 };
    assert!(b.near([9.0 + 0.9, 20.0], at, 1.0) && !b.near([9.0 + 1.1, 20.0], at, 0.05));
    assert!(!b.near([9.0, 21.5], at, 1.0) && b.near([9.0, 20.5], at, 1.0));
    let (w, h) = b.extent();
    assert!((w - 4.0).abs() < 1e-3 && (h - 4.0).abs() < 1e-3, "{w} {h}");
    // Far off the image (x = 500 on a 64-px image, reach 4): never near it.
    let far = LensTimeSample { x: 500.0, ..sample };
    assert!(sample_bounds(&far, &lens, 1e-3, &ScreenArea { width: 64.0, height: 48.0, max_reach: 4.0 }).is_none());
}
