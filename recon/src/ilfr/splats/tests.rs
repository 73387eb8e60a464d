//! The unit tests of `splats.rs`, in a file of their own beside it for their length.

use super::*;
use crate::lcg::Lcg;

const UP: [f32; 3] = [0.0, 0.0, 1.0];

use crate::vector::normalize;

struct Cloud {
    position: Vec<[f32; 3]>,
    normal: Vec<[f32; 3]>,
    direction: Vec<[f32; 3]>,
    kappa: Option<Vec<f32>>,
}

impl Cloud {
    fn points(&self) -> SplatPoints<'_> {
        SplatPoints {
            position: &self.position,
            normal: &self.normal,
            direction: &self.direction,
            kappa: self.kappa.as_deref(),
        }
    }

    fn push(&mut self, position: [f32; 3], normal: [f32; 3], direction: [f32; 3]) {
        self.position.push(position);
        self.normal.push(normal);
        self.direction.push(direction);
    }
}

/// A (2m + 1)² square lattice of spacing `s` on z = 0, all rays arriving along one direction.
fn square_lattice(m: i32, s: f32) -> Cloud {
    let direction = normalize([0.3, 0.2, -0.9]);
    let mut cloud = Cloud { position: vec![], normal: vec![], direction: vec![], kappa: None };
    for y in -m..=m {
        for x in -m..=m {
            cloud.push([x as f32 * s, y as f32 * s, 0.0], UP, direction);
        }
    }
    cloud
}

fn lattice_index(m: i32, x: i32, y: i32) -> usize {
    ((y + m) * (2 * m + 1) + (x + m)) as usize
}

fn interior(m: i32, margin: i32) -> impl Iterator<Item = (i32, i32)> {
    (-m + margin..=m - margin).flat_map(move |y| (-m + margin..=m - margin).map(move |x| (x, y)))
}

#[test]
fn square_lattice_radius_is_twice_the_spacing() {
    // Around a lattice point: 4 neighbours at s, 4 at √2·s, 4 at 2s — the 12th is at 2s.
    let (m, s) = (12, 0.25);
    let cloud = square_lattice(m, s);
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    for (x, y) in interior(m, 3) {
        let i = lattice_index(m, x, y);
        assert_eq!(splats.radius[i], 2.0 * s, "({x}, {y})");
        assert_eq!(splats.status[i], SplatStatus::Lobe(0));
    }
    assert_eq!(splats.stats.lobe[0], cloud.position.len());
    // The authors' counting (the sample itself among its 12) is k = 11: the 11th other is at 2s too;
    // k = 8 stops at √2·s.
    let params = SplatParams { k: 8, ..SplatParams::default() };
    let splats = size_splats(&cloud.points(), &params).unwrap();
    assert!((splats.radius[lattice_index(m, 0, 0)] - 2f32.sqrt() * s).abs() < 1e-6);
}

#[test]
fn hexagonal_lattice_radius_is_root_three_spacing() {
    // 6 neighbours at s and 6 at √3·s.
    let (m, s) = (10, 0.5f32);
    let direction = normalize([0.0, 0.1, -1.0]);
    let mut cloud = Cloud { position: vec![], normal: vec![], direction: vec![], kappa: None };
    for j in -m..=m {
        for i in -m..=m {
            let (x, y) = ((i as f32 + 0.5 * j as f32) * s, j as f32 * s * 3f32.sqrt() / 2.0);
            cloud.push([x, y, 0.0], UP, direction);
        }
    }
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    let centre = lattice_index(m, 0, 0);
    assert!((splats.radius[centre] - 3f32.sqrt() * s).abs() < 1e-5, "{}", splats.radius[centre]);
}

#[test]
fn offsets_along_the_normal_count_alpha_times() {
    // Four extra hits 0.8 s above and below the centre: 0.8 s and 1.07 s away in space, but
    // 2.4 s and 2.5 s under α = 3 — beyond the lattice's 12th neighbour at 2 s.
    let (m, s) = (6, 1.0f32);
    let mut cloud = square_lattice(m, s);
    let direction = cloud.direction[0];
    for p in [[0.0, 0.0, 0.8], [0.0, 0.0, -0.8], [0.5, 0.5, 0.8], [0.5, 0.5, -0.8]] {
        cloud.push(p, UP, direction);
    }
    let centre = lattice_index(m, 0, 0);
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert_eq!(splats.radius[centre], 2.0);
    // With α = 1 (plain Euclidean) they come first: 0.8, 0.8, 1, 1, 1, 1, 1.07, 1.07, then √2 × 4.
    let splats = size_splats(&cloud.points(), &SplatParams { alpha: 1.0, ..SplatParams::default() }).unwrap();
    assert!((splats.radius[centre] - 2f32.sqrt()).abs() < 1e-6, "{}", splats.radius[centre]);
}

#[test]
fn samples_outside_the_lobe_do_not_count() {
    // A checkerboard of two directions 90° apart, κ = 40 (a 10.7° lobe at τ = 0.5, and
    // A = e^-40 at 90°, below every relaxed threshold): only the own colour counts, whose
    // 12th neighbour is at √8·s (4 at √2 s, 4 at 2 s, 4 at √8 s).
    let (m, s) = (10, 1.0f32);
    let mut cloud = square_lattice(m, s);
    let (a, b) = (normalize([0.0, 0.0, -1.0]), normalize([1.0, 0.0, 0.0]));
    for y in -m..=m {
        for x in -m..=m {
            cloud.direction[lattice_index(m, x, y)] = if (x + y).rem_euclid(2) == 0 { a } else { b };
        }
    }
    cloud.kappa = Some(vec![40.0; cloud.position.len()]);
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    for (x, y) in interior(m, 4) {
        let i = lattice_index(m, x, y);
        assert!((splats.radius[i] - 8f32.sqrt()).abs() < 1e-6, "({x}, {y}): {}", splats.radius[i]);
        assert_eq!(splats.status[i], SplatStatus::Lobe(0));
    }
    // κ = 0: the lobe is the whole sphere, the lattice radius is back.
    cloud.kappa = Some(vec![0.0; cloud.position.len()]);
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert_eq!(splats.radius[lattice_index(m, 0, 0)], 2.0);
}

#[test]
fn the_threshold_relaxes_when_too_few_are_in_the_lobe() {
    // Every neighbour of the centre arrives 28.4° off its direction: with κ = 10,
    // A = exp(10 (cos 28.4° − 1)) ≈ 0.30, below τ = 0.5 and 0.375 but above 0.28125 (level 2).
    let (m, s) = (8, 1.0f32);
    let mut cloud = square_lattice(m, s);
    let centre = lattice_index(m, 0, 0);
    let cosine = 1.0 + 0.3f32.ln() / 10.0;
    let sine = (1.0 - cosine * cosine).sqrt();
    let others = [sine, 0.0, -cosine];
    for d in cloud.direction.iter_mut() {
        *d = others;
    }
    cloud.direction[centre] = [0.0, 0.0, -1.0];
    cloud.kappa = Some(vec![10.0; cloud.position.len()]);
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert_eq!(splats.status[centre], SplatStatus::Lobe(2));
    assert_eq!(splats.radius[centre], 2.0);
    // Its neighbours see each other in full agreement, and the centre not at all at level 0.
    assert_eq!(splats.status[lattice_index(m, 1, 0)], SplatStatus::Lobe(0));
    assert_eq!(splats.stats.lobe[2], 1);
}

/// A bumpy surface with random directions, κ from a small set and a few coincident hits.
fn random_cloud(n: usize, seed: u64) -> Cloud {
    let mut rng = Lcg(seed);
    let mut next = move || rng.uniform();
    let mut cloud = Cloud { position: vec![], normal: vec![], direction: vec![], kappa: Some(vec![]) };
    for i in 0..n {
        let (x, y) = (next() * 4.0, next() * 4.0);
        let z = 0.1 * (3.0 * x).sin() * (2.0 * y).cos();
        let normal =
            normalize([-0.3 * (3.0 * x).cos() * (2.0 * y).cos(), 0.2 * (3.0 * x).sin() * (2.0 * y).sin(), 1.0]);
        let (u, v) = (next() * 2.0 - 1.0, next() * std::f32::consts::TAU);
        let r = (1.0 - u * u).sqrt();
        let direction = normalize([r * v.cos(), r * v.sin(), u]);
        let position = if i % 97 == 5 { cloud.position[i - 1] } else { [x, y, z] };
        cloud.push(position, normal, direction);
        cloud.kappa.as_mut().unwrap().push([0.0, 4.0, 40.0, 65504.0][(next() * 4.0) as usize % 4]);
    }
    cloud
}

#[test]
fn the_tree_equals_the_brute_force_definition() {
    let cloud = random_cloud(3000, 11);
    for params in [SplatParams::default(), SplatParams { k: 5, alpha: 1.5, max_candidates: 40, ..Default::default() }] {
        let tree = size_splats(&cloud.points(), &params).unwrap();
        let brute = size_splats_brute_force(&cloud.points(), &params).unwrap();
        assert_eq!(tree.status, brute.status);
        assert!(tree.radius.iter().zip(&brute.radius).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(tree.stats, brute.stats);
        assert!(tree.radius.iter().all(|r| r.is_finite() && *r > 0.0));
        assert!(tree.stats.lobe.iter().skip(1).sum::<usize>() + tree.stats.partial + tree.stats.direction_blind > 0);
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let cloud = random_cloud(4000, 3);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| size_splats(&cloud.points(), &SplatParams::default()).unwrap())
    };
    let one = run(1);
    for threads in [2, 4] {
        let other = run(threads);
        assert!(one.radius.iter().zip(&other.radius).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(one.status, other.status);
    }
}

/// The sizing with juries: the same radii, statuses and juries on 1 and 3 threads, the radii
/// those of the sizing alone; and an empty and a one-hit cloud.
#[test]
fn sizing_with_juries_does_not_depend_on_the_thread_count() {
    use crate::ilfr::neighbours::KdTree;
    let cloud = random_cloud(3000, 5);
    let points = cloud.points();
    let tree = KdTree::build(points.position);
    let rule = JuryRule { size: 12, lobe_threshold: 0.5, max_candidates: 64 };
    let run = |threads: usize, jury: Option<JuryRule>| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| size_splats_with_juries(&tree, &points, &SplatParams::default(), jury).unwrap())
    };
    let (one, one_juries) = run(1, Some(rule));
    let (three, three_juries) = run(3, Some(rule));
    let (one_juries, three_juries) = (one_juries.unwrap(), three_juries.unwrap());
    assert!(one.radius.iter().zip(&three.radius).all(|(a, b)| a.to_bits() == b.to_bits()));
    assert_eq!((one.status.clone(), one.stats.clone()), (three.status, three.stats));
    assert_eq!((&one_juries.members, &one_juries.count), (&three_juries.members, &three_juries.count));
    assert!(one_juries.count.contains(&12) && one_juries.count.iter().any(|&c| c < 12));
    let (plain, none) = run(3, None);
    assert!(none.is_none());
    assert!(one.radius.iter().zip(&plain.radius).all(|(a, b)| a.to_bits() == b.to_bits()));
    for n in [0, 1] {
        let small = random_cloud(n, 2);
        let points = small.points();
        let tree = KdTree::build(points.position);
        let (sized, juries) = size_splats_with_juries(&tree, &points, &SplatParams::default(), Some(rule)).unwrap();
        let juries = juries.unwrap();
        assert_eq!((sized.radius.len(), juries.count.len(), juries.members.len()), (n, n, 12 * n));
        assert!(juries.count.iter().all(|&c| c == 0));
        assert!(sized.radius.iter().all(|r| r.is_finite() && *r > 0.0));
        assert_eq!(sized.status, vec![SplatStatus::Isolated; n]);
    }
}

#[test]
fn mirror_lobes_fall_back_to_direction_blind_radii() {
    // κ at the f16 clamp and random directions: nothing is in a 0.26° lobe, so the radius is
    // the k-th neighbour ignoring direction — the diffuse radius.
    let mut cloud = random_cloud(2000, 5);
    cloud.kappa = Some(vec![0.0; 2000]);
    let diffuse = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    cloud.kappa = Some(vec![65504.0; 2000]);
    let mirror = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert!(mirror.radius.iter().all(|r| r.is_finite() && *r > 0.0));
    let mut blind = 0;
    for i in 0..2000 {
        match mirror.status[i] {
            SplatStatus::DirectionBlind => {
                assert_eq!(mirror.radius[i], diffuse.radius[i]);
                blind += 1;
            }
            SplatStatus::Partial | SplatStatus::Lobe(_) => {}
            SplatStatus::Isolated => panic!("hit {i} is not isolated"),
        }
    }
    assert!(blind > 1900, "{blind}");
    // Identical directions: a mirror lobe holds them all, the lattice radius is unchanged.
    let (m, s) = (6, 1.0);
    let mut lattice = square_lattice(m, s);
    lattice.kappa = Some(vec![65504.0; lattice.position.len()]);
    let splats = size_splats(&lattice.points(), &SplatParams::default()).unwrap();
    assert_eq!(splats.radius[lattice_index(m, 0, 0)], 2.0);
    assert_eq!(splats.status[lattice_index(m, 0, 0)], SplatStatus::Lobe(0));
}

#[test]
fn fewer_hits_than_k_use_the_farthest() {
    // Five hits on a line: each has only four others.
    let mut cloud = Cloud { position: vec![], normal: vec![], direction: vec![], kappa: None };
    for x in 0..5 {
        cloud.push([x as f32, 0.0, 0.0], UP, [0.0, 0.0, -1.0]);
    }
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert_eq!(splats.radius, [4.0, 3.0, 2.0, 3.0, 4.0]);
    assert!(splats.status.iter().all(|s| *s == SplatStatus::Partial));

    // One hit alone: isolated, with a finite positive radius from the scene's scale.
    let cloud = Cloud { position: vec![[3.0, 4.0, 0.0]], normal: vec![UP], direction: vec![UP], kappa: None };
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert_eq!(splats.status, [SplatStatus::Isolated]);
    assert!(splats.radius[0].is_finite() && splats.radius[0] > 0.0);

    // No hits at all.
    let empty = Cloud { position: vec![], normal: vec![], direction: vec![], kappa: None };
    assert!(size_splats(&empty.points(), &SplatParams::default()).unwrap().radius.is_empty());
}

#[test]
fn coincident_hits_are_not_neighbours() {
    // A duplicate of the centre does not shrink its radius to zero.
    let (m, s) = (6, 1.0);
    let mut cloud = square_lattice(m, s);
    let centre = lattice_index(m, 0, 0);
    let (p, n, d) = (cloud.position[centre], cloud.normal[centre], cloud.direction[centre]);
    cloud.push(p, n, d);
    cloud.push(p, n, d);
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert_eq!(splats.radius[centre], 2.0);
    assert_eq!(*splats.radius.last().unwrap(), 2.0);

    // Twenty hits at one point and nothing else: isolated, finite, positive.
    let cloud =
        Cloud { position: vec![[1.0, 1.0, 1.0]; 20], normal: vec![UP; 20], direction: vec![UP; 20], kappa: None };
    let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
    assert!(splats.status.iter().all(|s| *s == SplatStatus::Isolated));
    assert!(splats.radius.iter().all(|r| r.is_finite() && *r > 0.0));

    // Thirteen coincident hits far from a lattice, with only 12 candidates examined: each
    // sees only its twins, is isolated, and takes the median radius of the lattice's hits.
    let mut cloud = square_lattice(m, s);
    let lattice = cloud.position.len();
    for _ in 0..13 {
        cloud.push([1000.0, 0.0, 0.0], UP, UP);
    }
    let params = SplatParams { max_candidates: 12, ..SplatParams::default() };
    let splats = size_splats(&cloud.points(), &params).unwrap();
    let mut sized: Vec<f32> = splats.radius[..lattice].to_vec();
    sized.sort_by(|a, b| a.total_cmp(b));
    assert!(splats.status[lattice..].iter().all(|s| *s == SplatStatus::Isolated));
    assert!(splats.radius[lattice..].iter().all(|&r| r == sized[(lattice - 1) / 2]));
    assert_eq!(splats.stats.isolated, 13);
}

#[test]
fn bad_input_is_rejected_with_the_field() {
    let mut cloud = square_lattice(2, 1.0);
    cloud.position[3][1] = f32::NAN;
    let error = size_splats(&cloud.points(), &SplatParams::default()).unwrap_err().to_string();
    assert!(error.contains("position of hit 3"), "{error}");
    let mut cloud = square_lattice(2, 1.0);
    cloud.normal[1] = [0.0, 0.0, 0.0];
    assert!(size_splats(&cloud.points(), &SplatParams::default()).unwrap_err().to_string().contains("normal of hit 1"));
    let mut cloud = square_lattice(2, 1.0);
    cloud.kappa = Some(vec![1.0; cloud.position.len()]);
    cloud.kappa.as_mut().unwrap()[2] = f32::NAN;
    assert!(size_splats(&cloud.points(), &SplatParams::default()).unwrap_err().to_string().contains("κ of hit 2"));
    let cloud = square_lattice(2, 1.0);
    for params in [
        SplatParams { k: 0, ..Default::default() },
        SplatParams { alpha: 0.5, ..Default::default() },
        SplatParams { lobe_threshold: 0.0, ..Default::default() },
        SplatParams { relax_factor: 1.0, ..Default::default() },
        SplatParams { max_candidates: 3, ..Default::default() },
    ] {
        assert!(size_splats(&cloud.points(), &params).is_err(), "{params:?}");
    }
}

/// `cargo test -p recon --lib ilfr::splats -- --ignored --nocapture`
#[test]
#[ignore = "timing, run by hand"]
fn splat_sizing_speed() {
    for (n, kappa) in [(200_000usize, None), (200_000, Some(40.0f32))] {
        let mut cloud = random_cloud(n, 1);
        cloud.kappa = kappa.map(|k| vec![k; n]);
        // Coherent directions, as from a camera: all rays arrive from roughly above.
        for (i, d) in cloud.direction.iter_mut().enumerate() {
            let a = (i % 64) as f32 / 64.0 * 0.3;
            *d = normalize([a.sin(), 0.2 * a.cos(), -1.0]);
        }
        let start = std::time::Instant::now();
        let splats = size_splats(&cloud.points(), &SplatParams::default()).unwrap();
        let seconds = start.elapsed().as_secs_f64();
        println!(
            "n = {n}, κ = {kappa:?}: {seconds:.3} s, {:.0} samples/s on {} threads, {:.1} candidates/hit, {:?}",
            n as f64 / seconds,
            rayon::current_num_threads(),
            splats.stats.candidates as f64 / n as f64,
            (splats.stats.lobe.iter().take(3).collect::<Vec<_>>(), splats.stats.partial, splats.stats.direction_blind)
        );
    }
}
