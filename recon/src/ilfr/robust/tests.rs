//! The unit tests of `robust.rs`, in a file of their own beside it for their length.

use super::*;

/// A square lattice on the plane z = 0 (normal +z, directions straight down), spacing 1,
/// (2m + 1)² points, radiance `value(x, y)`, every radius `r`.
struct Lattice {
    position: Vec<[f32; 3]>,
    normal: Vec<[f32; 3]>,
    direction: Vec<[f32; 3]>,
    radius: Vec<f32>,
    radiance: Vec<[f32; 3]>,
}

fn lattice(m: i32, r: f32, value: impl Fn(f32, f32) -> [f32; 3]) -> Lattice {
    let mut l = Lattice {
        position: Vec::new(),
        normal: Vec::new(),
        direction: Vec::new(),
        radius: Vec::new(),
        radiance: Vec::new(),
    };
    for i in -m..=m {
        for j in -m..=m {
            let (x, y) = (i as f32, j as f32);
            l.position.push([x, y, 0.0]);
            l.normal.push([0.0, 0.0, 1.0]);
            l.direction.push([0.0, 0.0, -1.0]);
            l.radius.push(r);
            l.radiance.push(value(x, y));
        }
    }
    l
}

impl Lattice {
    fn points(&self) -> SplatPoints<'_> {
        SplatPoints { position: &self.position, normal: &self.normal, direction: &self.direction, kappa: None }
    }

    fn index(&self, x: f32, y: f32) -> usize {
        self.position.iter().position(|p| p[0] == x && p[1] == y).unwrap()
    }

    fn run(&self, params: &RobustParams) -> (Vec<[f32; 3]>, RobustStats) {
        robust_radiance(&self.points(), &self.radius, &self.radiance, params).unwrap()
    }

    /// Σ_j L_j r_j² per channel, in f64.
    fn power(&self, radiance: &[[f32; 3]]) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for (l, r) in radiance.iter().zip(&self.radius) {
            for k in 0..3 {
                sum[k] += l[k] as f64 * (*r as f64) * (*r as f64);
            }
        }
        sum
    }
}

/// A smooth field: 1 + 0.02 x − 0.01 y, slightly coloured.
fn smooth(x: f32, y: f32) -> [f32; 3] {
    let v = 1.0 + 0.02 * x - 0.01 * y;
    [v, 0.9 * v, 0.8 * v]
}

#[test]
fn a_smooth_field_and_a_bright_half_plane_are_left_alone() {
    for mode in [RobustMode::Spread, RobustMode::Clamp] {
        let params = RobustParams { mode, ..RobustParams::default() };
        let l = lattice(10, 2.0, smooth);
        let (out, stats) = l.run(&params);
        assert_eq!(out, l.radiance, "{mode:?}: nothing in a smooth field is an outlier");
        assert_eq!(stats.outliers, 0);
        assert_eq!(stats.judged, l.radiance.len(), "every splat of the lattice has a full jury");
        // A shadow edge: 0.01 on one side, 100 (10⁴ times brighter) on the other.
        let edge = lattice(10, 2.0, |x, _| if x > 0.5 { [100.0; 3] } else { [0.01; 3] });
        let (out, stats) = edge.run(&params);
        assert_eq!(out, edge.radiance, "{mode:?}: a lit half-plane is not an outlier");
        assert_eq!(stats.outliers, 0);
    }
}

#[test]
fn a_spike_is_cut_to_its_neighbours_level_and_its_power_is_kept_by_spreading() {
    // One 1e4 spike among the smooth samples.
    let mut l = lattice(10, 2.0, smooth);
    let spike = l.index(0.0, 0.0);
    l.radiance[spike] = [1e4, 1e4, 1e4];
    let params = RobustParams::default();
    let (out, stats) = l.run(&params);
    assert_eq!(stats.outliers, 1);
    // Its jury: the 12 nearest others (distances 1, √2, 2); the second largest luminance
    // among them is at (1, −1), and c = 4 times that is what the spike keeps of its own.
    let threshold = 4.0 * luminance(smooth(1.0, -1.0));
    let excess = luminance([1e4; 3]) - threshold;
    let changed: Vec<usize> = (0..l.radiance.len()).filter(|&j| out[j] != l.radiance[j]).collect();
    // The excess went to the spike and its 48 nearest (all within distance 4), equal radii:
    // equal shares of excess / 49.
    assert_eq!(changed.len(), 49, "changed: {changed:?}");
    let kept = luminance(out[spike]);
    assert!((kept - (threshold + excess / 49.0)).abs() < 1e-3 * kept, "kept {kept}");
    for &j in &changed {
        let p = l.position[j];
        assert!(p[0].hypot(p[1]) <= 4.0 + 1e-6, "{p:?} is not among the 48 nearest");
        if j != spike {
            let added = luminance(out[j]) - luminance(l.radiance[j]);
            assert!((added - excess / 49.0).abs() < 1e-3 * added, "{p:?}: added {added}");
        }
    }
    // Power kept per channel, to f32 rounding.
    let (a, b) = (l.power(&l.radiance), l.power(&out));
    for k in 0..3 {
        assert!((a[k] - b[k]).abs() <= 1e-6 * a[k], "channel {k}: {} → {}", a[k], b[k]);
    }
    // Clamp: the same cut, the excess gone; nothing else changes.
    let (clamped, stats) = l.run(&RobustParams { mode: RobustMode::Clamp, ..params });
    assert_eq!(stats.outliers, 1);
    for (j, (got, input)) in clamped.iter().zip(&l.radiance).enumerate() {
        if j == spike {
            let y = luminance(*got);
            assert!((y - threshold).abs() < 1e-5 * threshold, "clamped to 4 × its jury's 2nd largest: {y}");
            // The colour is kept.
            assert!((got[0] - got[2]).abs() < 1e-6 * y.max(1.0));
        } else {
            assert_eq!(got, input);
        }
    }
    assert!(stats.excess_fraction > 0.9, "the spike was almost all of the power: {}", stats.excess_fraction);
    // Off: the input.
    let (off, _) = l.run(&RobustParams { mode: RobustMode::Off, ..params });
    assert_eq!(off, l.radiance);
}

#[test]
fn one_other_outlier_in_the_jury_does_not_vouch_for_a_spike() {
    // Two adjacent spikes: with the second largest as the level each is still an outlier;
    // with the largest (rank 1) they vouch for each other.
    let mut l = lattice(6, 2.0, smooth);
    let (a, b) = (l.index(0.0, 0.0), l.index(1.0, 0.0));
    l.radiance[a] = [500.0; 3];
    l.radiance[b] = [800.0; 3];
    let (_, stats) = l.run(&RobustParams { mode: RobustMode::Clamp, ..RobustParams::default() });
    assert_eq!(stats.outliers, 2);
    let (_, stats) = l.run(&RobustParams { mode: RobustMode::Clamp, rank: 1, ..RobustParams::default() });
    assert_eq!(stats.outliers, 0);
}

#[test]
fn a_dark_field_spreads_a_lone_bright_sample_whole_and_dead_splats_receive_nothing() {
    // Everything 0 but one sample: the level is 0, so all of it is excess, shared by area.
    let mut l = lattice(8, 1.5, |_, _| [0.0; 3]);
    let lone = l.index(0.0, 0.0);
    l.radiance[lone] = [3.0, 2.0, 1.0];
    let dead = l.index(1.0, 0.0);
    l.radius[dead] = 0.0;
    let bigger = l.index(0.0, 1.0);
    l.radius[bigger] = 3.0;
    let (out, stats) = l.run(&RobustParams::default());
    assert_eq!(stats.outliers, 1);
    assert_eq!(out[dead], [0.0; 3], "a dead splat cannot show light");
    // Equal radiance added to every live sharer, so the bigger disc holds 4× the power.
    assert_eq!(out[bigger], out[lone]);
    let (a, b) = (l.power(&l.radiance), l.power(&out));
    for k in 0..3 {
        assert!((a[k] - b[k]).abs() <= 1e-6 * a[k], "channel {k}: {} → {}", a[k], b[k]);
    }
}

/// The method builds one kd-tree of the hits for the sizing and every robust pass: with it,
/// the radiance is that of the self-contained call bit for bit (spike included); a tree of
/// other points is refused, naming both counts.
#[test]
fn a_shared_kd_tree_gives_the_same_radiance_and_a_wrong_one_is_refused() {
    let mut l = lattice(6, 1.5, |x, y| [1.0 + 0.1 * x, 0.5, 0.2 * y]);
    let spike = l.index(1.0, 1.0);
    l.radiance[spike] = [1e4; 3];
    let params = RobustParams::default();
    let own = l.run(&params);
    let tree = KdTree::build(&l.position);
    let shared = robust_radiance_in(&tree, &l.points(), &l.radius, &l.radiance, &params).unwrap();
    assert_eq!(own.1.outliers, shared.1.outliers);
    let bits = |v: &[[f32; 3]]| v.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
    assert_eq!(bits(&own.0), bits(&shared.0));
    assert!(own.1.outliers >= 1, "not vacuous: the spike is judged");
    let other = KdTree::build(&l.position[1..]);
    let error = robust_radiance_in(&other, &l.points(), &l.radius, &l.radiance, &params).unwrap_err();
    let n = l.position.len();
    assert!(error.to_string().contains(&format!("a kd-tree of {} points for {n} splats", n - 1)), "{error}");
    let sizing = crate::ilfr::splats::size_splats_in(&other, &l.points(), &Default::default()).unwrap_err();
    assert!(sizing.to_string().contains("a kd-tree of"), "{sizing}");
}

/// The juries the sizing's walk finds give the robust radiance of the robust pass's own
/// walks bit for bit: a random cloud on two planes and a sphere (normals noisy, coincident
/// hits), heavy-tailed spikes, diffuse and glossy lobes (κ up to 300, so that juries run
/// short and walks go long), spread and clamp; the sizing's radii are those of the plain
/// sizing, and juries found by another rule are refused.
#[test]
fn juries_from_the_sizing_walk_give_the_same_radiance() {
    use crate::ilfr::splats::{size_splats_in, size_splats_with_juries, SplatParams};
    let mut rng = crate::lcg::Lcg(77);
    let (mut position, mut normal, mut direction, mut radiance, mut kappa) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for i in 0..3000 {
        let (p, n) = match i % 3 {
            0 => ([rng.uniform() * 4.0, rng.uniform() * 4.0, 0.0], [0.0, 0.0, 1.0]),
            1 => ([rng.uniform() * 4.0, 0.0, rng.uniform() * 2.0], [0.0, 1.0, 0.0]),
            _ => {
                let u = rng.unit_vector();
                ([2.0 + u[0], 2.0 + u[1], 1.0 + u[2]], u)
            }
        };
        let tilt = rng.unit_vector();
        let n = crate::vector::normalize([0, 1, 2].map(|a| n[a] + 0.1 * tilt[a]));
        let d = rng.unit_vector();
        let d = if crate::vector::dot(d, n) > 0.0 { d.map(|c| -c) } else { d };
        let (p, n, d) = if i % 41 == 40 { (position[i - 1], normal[i - 1], direction[i - 1]) } else { (p, n, d) };
        position.push(p);
        normal.push(n);
        direction.push(d);
        let y = if rng.uniform() < 0.03 { 1e3 / (1.0 - rng.uniform()).max(1e-3) } else { 0.5 + rng.uniform() };
        radiance.push([y, 0.7 * y, 0.3 * y]);
        kappa.push(match i % 4 {
            0 => 0.0,
            1 => 3.0,
            2 => 40.0,
            _ => 300.0,
        });
    }
    let radius: Vec<f32> = (0..position.len()).map(|_| 0.05 + 0.1 * rng.uniform()).collect();
    let tree = KdTree::build(&position);
    for glossy in [false, true] {
        let points = SplatPoints {
            position: &position,
            normal: &normal,
            direction: &direction,
            kappa: glossy.then_some(&kappa[..]),
        };
        for mode in [RobustMode::Spread, RobustMode::Clamp] {
            let params = RobustParams { mode, ..RobustParams::default() };
            let (sized, juries) =
                size_splats_with_juries(&tree, &points, &SplatParams::default(), Some(params.jury_rule())).unwrap();
            let plain = size_splats_in(&tree, &points, &SplatParams::default()).unwrap();
            assert_eq!(
                sized.radius.iter().map(|r| r.to_bits()).collect::<Vec<_>>(),
                plain.radius.iter().map(|r| r.to_bits()).collect::<Vec<_>>()
            );
            let juries = juries.unwrap();
            let walked = robust_radiance_in(&tree, &points, &radius, &radiance, &params).unwrap();
            let given =
                robust_radiance_with_juries(&tree, &points, (&radius, &radiance), &params, Some(&juries)).unwrap();
            let bits = |v: &[[f32; 3]]| v.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
            assert_eq!(bits(&walked.0), bits(&given.0), "glossy {glossy}, {mode:?}");
            assert_eq!(walked.1, given.1);
            assert!(walked.1.outliers > 20 && walked.1.judged > 1000, "{:?}", walked.1);
            if glossy {
                assert!((0..position.len()).any(|i| juries.of(i).len() < params.neighbours), "some juries run short");
            }
            let other = RobustParams { lobe_threshold: 0.4, ..params };
            assert!(robust_radiance_with_juries(&tree, &points, (&radius, &radiance), &other, Some(&juries)).is_err());
        }
    }
}

#[test]
fn glossy_neighbours_outside_the_lobe_are_not_jurors() {
    // A sharp lobe (κ = 200): the half of the lattice whose input directions lie 30° away
    // is outside it (A = e^{−200·0.134} ≈ 0), so a splat bright only in its own direction is
    // judged by the samples of its direction alone.
    let mut l = lattice(8, 2.0, |_, _| [1.0; 3]);
    let tilted = [0.5f32, 0.0, -(0.75f32).sqrt()];
    for (k, p) in l.position.clone().iter().enumerate() {
        if (p[0] + p[1]) as i32 % 2 != 0 {
            l.direction[k] = tilted;
            l.radiance[k] = [50.0; 3]; // a highlight seen from that direction
        }
    }
    let kappa = vec![200.0f32; l.position.len()];
    let points = SplatPoints { position: &l.position, normal: &l.normal, direction: &l.direction, kappa: Some(&kappa) };
    let (out, stats) = robust_radiance(&points, &l.radius, &l.radiance, &RobustParams::default()).unwrap();
    assert_eq!(stats.outliers, 0, "the highlight's jurors are the other highlight samples");
    assert_eq!(out, l.radiance);
    // Whereas one 50 among 1s of one direction is an outlier.
    let mut single = lattice(8, 2.0, |_, _| [1.0; 3]);
    let centre = single.index(0.0, 0.0);
    single.radiance[centre] = [50.0; 3];
    let (_, stats) = single.run(&RobustParams::default());
    assert_eq!(stats.outliers, 1);
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    // A noisy field with heavy-tailed spikes (an LCG, so the test needs no crate).
    let mut state = 12345u64;
    let mut next = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((state >> 33) as f32) / (1u64 << 31) as f32
    };
    let mut l = lattice(15, 2.0, |_, _| [1.0; 3]);
    for v in l.radiance.iter_mut() {
        let u = next();
        let y = if u < 0.02 { 1.0 / (1.0 - next()).max(1e-4) * 100.0 } else { 0.5 + next() };
        *v = [y, 0.5 * y, 0.25 * y];
    }
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| l.run(&RobustParams::default()))
    };
    let (one, stats) = run(1);
    assert!(stats.outliers > 0);
    assert!(one.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
    let (three, _) = run(3);
    assert_eq!(one, three);
    let (a, b) = (l.power(&l.radiance), l.power(&one));
    for k in 0..3 {
        assert!((a[k] - b[k]).abs() <= 1e-5 * a[k], "channel {k}: {} → {}", a[k], b[k]);
    }
}
