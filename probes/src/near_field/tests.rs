//! The unit tests of `near_field.rs`, in a file of their own beside it for their length.

use super::*;
use crate::cache::{decode, encode, CacheKey};
use crate::frame::{indirect, ReceiverTransport, WithNearField};
use crate::placement::PlacementSettings;
use crate::precompute::{Precompute, PrecomputeSettings};
use crate::relight::RelightTable;
use crate::surfels::SurfelSettings;
use crate::test_scenes::{room, scene_of};
use crate::transport::{Transport, TransportSettings};
use glam::DVec3;
use tracer::scene::shapes::sphere;
use tracer::{Accel, Scene};

/// A closed unit sphere with one probe at its centre (it sees every inner point), support
/// radius 2: a near share s takes the hits nearer than 2s (the sphere's diameter is 2).
struct Sphere {
    accel: Accel,
    surfels: Surfels,
    inward: Vec<bool>,
}

const PROBES: [DVec3; 1] = [DVec3::ZERO];
const RADIUS: f64 = 2.0;

fn sphere_scene() -> Sphere {
    let scene = scene_of(vec![sphere("s", Vec3::ZERO, 1.0, 4, 0)], Vec3::ZERO);
    let accel = Accel::build(&scene).unwrap();
    let surfels = Surfels::build(&scene, &SurfelSettings { budget: 1200, ..Default::default() }).unwrap();
    let inward = surfels.surfels.iter().map(|s| s.normal.dot(s.position) < 0.0).collect();
    Sphere { accel, surfels, inward }
}

fn context(s: &Sphere, near: Option<f64>) -> TransportContext<'_> {
    let settings = TransportSettings { order: 4, directions: 128, near, ..Default::default() };
    TransportContext::new(&s.accel, &PROBES, RADIUS, 2.0, settings).unwrap()
}

/// The list with its weights in f32 (the gather's exact sums; `build` rounds them to fp16,
/// bounded in `the_fp16_weights_move_the_near_light_by_at_most_their_rounding`).
fn near_of(s: &Sphere, ctx: &TransportContext) -> NearField {
    NearField::build_f32(ctx, &s.surfels, &vec![true; s.surfels.surfels.len()]).unwrap()
}

#[test]
fn the_fp16_weights_move_the_near_light_by_at_most_their_rounding() {
    // Each fp16 weight is within 2⁻¹¹ of the f32 one relatively (half an ulp of an 11-bit
    // significand), or 2⁻²⁵ absolutely below 2⁻¹⁴ (subnormal): with radiance B ≥ 0 a
    // receiver's near light L = Σ w B moves by at most 2⁻¹¹ L + 2⁻²⁵ Σ B (f32 sums aside,
    // 1e-6 L). Over the sphere and varied radiance, and at most 1e-3 of L wherever L is.
    let s = sphere_scene();
    let n = s.surfels.surfels.len();
    let radiance: Vec<Vec3> = s
        .surfels
        .surfels
        .iter()
        .map(|x| Vec3::new(1.0 + x.position.x, 0.02 + (3.0 * x.position.y).sin().abs(), 5.0 * x.position.z.max(0.0)))
        .collect();
    for share in [0.25, 0.6, 4.0] {
        let ctx = context(&s, Some(share));
        let exact = near_of(&s, &ctx);
        let stored = NearField::build(&ctx, &s.surfels, &vec![true; n]).unwrap();
        assert_eq!(stored.offsets, exact.offsets);
        assert!(!exact.entries.is_empty());
        let (mut a, mut b) = (vec![Vec3::ZERO; n], vec![Vec3::ZERO; n]);
        exact.add_into(&radiance, &mut a);
        stored.add_into(&radiance, &mut b);
        let step = 2f32.powi(-11);
        let mut worst = 0.0f32;
        for r in 0..n {
            let sum_b = exact.row(r).iter().fold(Vec3::ZERO, |acc, &(x, _)| acc + radiance[x as usize]);
            for (e, q) in exact.row(r).iter().zip(stored.row(r)) {
                assert_eq!(e.0, q.0);
                assert!((q.1 - e.1).abs() <= (step * e.1).max(2f32.powi(-25)), "{} against {}", q.1, e.1);
            }
            let bound = a[r] * (step + 1e-6) + sum_b * 2f32.powi(-25);
            assert!((b[r] - a[r]).abs().cmple(bound).all(), "share {share}, receiver {r}: {} against {}", b[r], a[r]);
            for c in 0..3 {
                if a[r][c] > 0.0 {
                    worst = worst.max((b[r][c] - a[r][c]).abs() / a[r][c]);
                }
            }
        }
        assert!(worst < 1e-3, "share {share}: {worst}");
    }
}

#[test]
fn every_direction_is_the_near_fields_or_the_probes_once_a_furnace_gives_pi_l() {
    // Constant sender radiance L in a closed sphere: the probe's SH is √(4π) L in its constant
    // coefficient and every inner receiver's irradiance is π L, whatever share of its
    // directions the near field takes (none of them, some, all of them).
    let s = sphere_scene();
    let l = 1.7f32;
    let pi_l = std::f32::consts::PI * l;
    let radiance = vec![Vec3::splat(l); s.surfels.surfels.len()];
    let plain = context(&s, None).all(&s.surfels);
    let mut near_hits = Vec::new();
    for share in [0.1, 0.3, 0.5, 1.0, 4.0] {
        let ctx = context(&s, Some(share));
        let transports = ctx.all(&s.surfels);
        let near = near_of(&s, &ctx);
        assert_eq!(near.holes, 0);
        let nc = ctx.coefficients();
        let mut lambda = vec![0.0f32; nc];
        lambda[0] = (4.0 * std::f32::consts::PI).sqrt() * l;
        let mut e: Vec<Vec3> = transports.iter().map(|t| Vec3::splat(t.irradiance(&lambda, nc))).collect();
        near.add_into(&radiance, &mut e);
        for ((e, t), &inward) in e.iter().zip(&transports).zip(&s.inward) {
            // Every hit once: seen far hits through the probe, near hits from their senders.
            let expected = pi_l * (t.hits - t.unseen) as f32 / 128.0;
            assert!((e.x - expected).abs() < 1e-4 * pi_l, "share {share}: E = {e}, expected {expected}");
            if inward {
                assert_eq!((t.unseen, t.hits), (0, 128));
                assert!((e.x / pi_l - 1.0).abs() < 1e-4, "share {share}: E = {e}, π L = {pi_l}");
            }
        }
        if share >= 1.0 {
            // Every hit is nearer than the diameter: α is exactly zero, the near field all.
            assert!(transports.iter().all(|t| t.alpha.iter().all(|&a| a == 0.0)));
        }
        // The near field's weights are π / M per near hit.
        let weights: f64 = near.entries.iter().map(|&(_, w)| w as f64).sum();
        let expected = near.hits as f64 * std::f64::consts::PI / 128.0;
        assert!((weights / expected - 1.0).abs() < 1e-5, "share {share}: {weights} against {expected}");
        // The counts of the transport stay: hits (near ones included), escaped, back faces.
        for (a, b) in transports.iter().zip(&plain) {
            assert_eq!((a.hits, a.escaped, a.back_faces), (b.hits, b.escaped, b.back_faces));
        }
        near_hits.push(near.hits);
    }
    assert!(near_hits[..4].windows(2).all(|w| w[0] < w[1]) && near_hits[3] == near_hits[4], "{near_hits:?}");
    let all_hits: u64 = plain.iter().map(|t| t.hits as u64).sum();
    assert!(near_hits[0] > 0 && near_hits[3] == all_hits, "{near_hits:?} of {all_hits}");
}

#[test]
fn a_near_field_that_takes_no_hit_leaves_the_transport_bit_for_bit() {
    let s = sphere_scene();
    let plain = context(&s, None).all(&s.surfels);
    let ctx = context(&s, Some(1e-7));
    let near = near_of(&s, &ctx);
    assert_eq!((near.hits, near.entries.len()), (0, 0));
    assert_eq!(ctx.all(&s.surfels), plain);
    // Off, the list is empty whatever is asked.
    let off = near_of(&s, &context(&s, None));
    assert!(off.entries.is_empty() && off.receivers() == s.surfels.surfels.len());
}

#[test]
fn the_bounces_with_the_near_field_follow_the_geometric_series() {
    let s = sphere_scene();
    let n = s.surfels.surfels.len();
    let table = RelightTable::build(&s.accel, &s.surfels, &PROBES, 4000, 4, 2.0).unwrap();
    let e0 = Vec3::new(1.0, 2.0, 0.5);
    for share in [0.25, 0.6] {
        let ctx = context(&s, Some(share));
        let far = ctx.all(&s.surfels);
        let near = near_of(&s, &ctx);
        assert!(near.hits > 0);
        let both = WithNearField { far: &far, near: &near };
        assert_eq!(both.receiver_count(), n);
        for rho in [0.5f32, 0.9] {
            let albedo = vec![Vec3::splat(rho); n];
            for k in [1usize, 3] {
                let out = indirect(&both, &table, &albedo, &vec![e0; n], k, 0.0).unwrap();
                let series: f32 = (1..=k).map(|i| rho.powi(i as i32)).sum();
                for (e, &inward) in out.irradiance.iter().zip(&s.inward) {
                    if inward {
                        let rel = ((*e - e0 * series) / (e0 * series)).abs().max_element();
                        assert!(rel < 2e-2, "share {share}, ρ = {rho}, {k} bounces: {e} against {}", e0 * series);
                    }
                }
            }
            let out = indirect(&both, &table, &albedo, &vec![e0; n], 500, 1e-4).unwrap();
            let limit = e0 * rho / (1.0 - rho);
            let worst = out
                .irradiance
                .iter()
                .zip(&s.inward)
                .filter(|(_, &i)| i)
                .map(|(e, _)| ((*e - limit) / limit).abs().max_element())
                .fold(0.0f32, f32::max);
            assert!(worst < 3e-2, "share {share}, ρ = {rho}: converged off by {worst}");
        }
    }
}

#[test]
fn a_sharp_patch_beside_a_receiver_reaches_it_through_the_near_field() {
    // Sender radiance that is 1 on one small cap of the sphere and 0 elsewhere: order-4 SH at
    // the centre cannot carry the cap, the near field gathers it exactly. The irradiance it
    // gives at the receivers nearest the cap matches a direct gather over the same directions
    // (the lookup's senders, no probes) to rounding; through the probes alone it does not.
    let s = sphere_scene();
    let cap = Vec3::new(0.0, 0.0, -1.0);
    let radiance: Vec<Vec3> =
        s.surfels.surfels.iter().map(|x| if x.position.distance(cap) < 0.3 { Vec3::ONE } else { Vec3::ZERO }).collect();
    let ctx = context(&s, Some(4.0));
    let near = near_of(&s, &ctx);
    let mut e = vec![Vec3::ZERO; s.surfels.surfels.len()];
    near.add_into(&radiance, &mut e);
    let mut checked = 0;
    for (i, x) in s.surfels.surfels.iter().enumerate() {
        if !s.inward[i] || x.position.distance(cap) > 0.6 {
            continue;
        }
        // The same directions and lookups, summed here one hit at a time.
        let frame = Frame::new(x.normal);
        let origin = ctx.origin(x.position, x.normal);
        let mut found = Vec::new();
        let mut sum = 0.0f64;
        for k in 0..128 {
            let dir = ctx.direction(i as u32, &frame, k);
            let hit = s.accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0).expect("closed sphere");
            let ng = hit.geometric_normal.normalize_or_zero();
            let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
            assert!(read_senders(&s.surfels, origin + dir * hit.distance, side, &mut found));
            sum += found.iter().map(|&(s, w)| (radiance[s as usize].x * w) as f64).sum::<f64>();
        }
        let truth = sum * std::f64::consts::PI / 128.0;
        assert!((e[i].x as f64 - truth).abs() < 1e-5 * truth.max(1.0), "receiver {i}: {} against {truth}", e[i].x);
        checked += 1;
    }
    assert!(checked > 5, "{checked}");
}

#[test]
fn a_hidden_sender_is_dropped_beside_a_valid_one_only() {
    let valid = [true, false, true];
    let mut found = vec![(0, 0.5), (1, 0.25), (2, 0.25)];
    drop_hidden(&mut found, &valid);
    assert_eq!(found, vec![(0, 2.0 / 3.0), (2, 1.0 / 3.0)]);
    let mut only_hidden = vec![(1, 1.0)];
    drop_hidden(&mut only_hidden, &valid);
    assert_eq!(only_hidden, vec![(1, 1.0)]);
    let mut all_valid = vec![(0, 0.25), (2, 0.75)];
    drop_hidden(&mut all_valid, &valid);
    assert_eq!(all_valid, vec![(0, 0.25), (2, 0.75)]);
}

fn small(near: Option<f64>) -> (Scene, PrecomputeSettings) {
    let block = tracer::scene::shapes::axis_aligned_box("block", Vec3::splat(0.3), Vec3::splat(0.6), 0);
    let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), block], Vec3::splat(0.15));
    let settings = PrecomputeSettings {
        surfels: SurfelSettings { budget: 400, ..Default::default() },
        placement: PlacementSettings { probes: 4, overlap: 3.0, ..Default::default() },
        transport: TransportSettings { order: 2, directions: 32, near, ..Default::default() },
        relight_rays: 200,
    };
    (scene, settings)
}

#[test]
fn the_precompute_keeps_the_near_field_in_its_cache_for_any_thread_count() {
    let (scene, settings) = small(Some(0.5));
    let build = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| Precompute::build(&scene, &settings, &mut |_| {}).unwrap())
    };
    let pre = build(1);
    let near = pre.near.as_ref().expect("on");
    assert!(near.hits > 0 && !near.entries.is_empty());
    assert_eq!(pre.near, build(2).near);
    // Hidden receivers (inside the block) get no list.
    for (r, t) in pre.transports.iter().enumerate() {
        if *t == Transport::empty() {
            assert!(near.row(r).is_empty());
        }
    }
    let key = CacheKey::of(&scene, &settings);
    let bytes = encode(&key, &pre);
    let back = decode(std::path::Path::new("c"), &bytes, &key, &settings).unwrap();
    assert_eq!(back.near, pre.near);
    assert_eq!(encode(&key, &back), bytes);
    // Off: no list, another key, fewer bytes; the radius is in the key.
    let (_, off) = small(None);
    let plain = Precompute::build(&scene, &off, &mut |_| {}).unwrap();
    assert!(plain.near.is_none() && plain.near_field_bytes() == 0);
    assert_ne!(CacheKey::of(&scene, &off), key);
    assert_ne!(CacheKey::of(&scene, &small(Some(0.25)).1), key);
    assert!(encode(&CacheKey::of(&scene, &off), &plain).len() < bytes.len());
    // A damaged list is refused by name.
    let mut bad = pre.clone();
    bad.near.as_mut().unwrap().entries[0].0 = u32::MAX;
    let err = decode(std::path::Path::new("c"), &encode(&key, &bad), &key, &settings).err().unwrap();
    assert!(err.to_string().contains("near-field"), "{err}");
}

#[test]
fn bad_near_settings_are_refused_by_name() {
    for near in [0.0, -1.0, 4.5, f64::NAN] {
        let settings = TransportSettings { near: Some(near), ..Default::default() };
        assert!(settings.validate().err().unwrap().to_string().starts_with("near-radius"), "{near}");
    }
    let spatial = TransportSettings {
        near: Some(0.5),
        reconstruction: crate::transport::Reconstruction::SpatialOnly,
        ..Default::default()
    };
    assert!(spatial.validate().err().unwrap().to_string().starts_with("near-field"));
    let s = sphere_scene();
    let ctx = context(&s, Some(0.5));
    assert!(NearField::build(&ctx, &s.surfels, &[true]).is_err());
    assert!(NearField::build_f32(&ctx, &s.surfels, &[true]).is_err());
}

#[test]
fn the_projected_bounces_with_the_near_field_follow_the_full_ones() {
    use crate::cpca::{Cpca, CpcaSettings};
    use crate::frame::indirect_timed;
    use crate::projected_bounce::ProjectedBounce;
    // Two probes in the closed sphere, a lossy CPCA in small clusters, albedo and direct light
    // that vary over the sphere: the first two bounces are the full loop's, the later ones
    // differ only by the near field of the indirect light taken through U.
    let s = sphere_scene();
    let probes = [DVec3::ZERO, DVec3::new(0.3, -0.2, 0.1)];
    let settings = TransportSettings { order: 3, directions: 96, near: Some(0.4), ..Default::default() };
    let ctx = TransportContext::new(&s.accel, &probes, RADIUS, 2.0, settings).unwrap();
    let far = ctx.all(&s.surfels);
    let near = near_of(&s, &ctx);
    assert!(near.hits > 0);
    let mut table = RelightTable::build(&s.accel, &s.surfels, &probes, 2000, 3, 2.0).unwrap();
    table.fit(0.01).unwrap();
    let albedo: Vec<Vec3> =
        s.surfels.surfels.iter().map(|x| Vec3::new(0.5 + 0.3 * x.position.x, 0.6, 0.4 + 0.2 * x.position.z)).collect();
    let direct: Vec<Vec3> =
        s.surfels.surfels.iter().map(|x| Vec3::new(1.0 + x.position.y, 2.0, 0.5 + x.position.x.abs())).collect();
    let positions: Vec<Vec3> = s.surfels.surfels.iter().map(|x| x.position).collect();
    let worst = |a: &[Vec3], b: &[Vec3]| {
        let largest = b.iter().map(|v| v.max_element()).fold(0.0f32, f32::max);
        a.iter().zip(b).map(|(x, y)| (*x - *y).abs().max_element()).fold(0.0f32, f32::max) / largest
    };
    let settings = CpcaSettings { cluster_limit: 64, tolerance: 0.02, max_coefficients: 6, ..Default::default() };
    let cpca = Cpca::build(&far, &positions, table.coefficients, &settings).unwrap();
    let op = ProjectedBounce::build(&cpca, &table, &albedo).unwrap();
    let both = WithNearField { far: &cpca, near: &near };
    for (k, bound) in [(1usize, 1e-4f32), (2, 1e-4), (5, 2e-2), (40, 2e-2)] {
        let (full, _) = indirect_timed(&both, &table, &albedo, &direct, None, k, 0.0).unwrap();
        let (fast, times) = op.indirect_with_near(&cpca, Some(&near), &table, &albedo, &direct, None, k, 0.0).unwrap();
        assert_eq!((full.clamped, fast.clamped), (0, 0), "the comparison needs nothing clamped");
        let err = worst(&fast.irradiance, &full.irradiance);
        assert!(err < bound, "{k} bounces: {err}");
        assert!(times.near_field_s > 0.0);
    }
    // Without the near field, exactly the projected loop.
    let (a, _) = op.indirect(&cpca, &table, &albedo, &direct, None, 5, 0.0).unwrap();
    let (b, _) = op.indirect_with_near(&cpca, None, &table, &albedo, &direct, None, 5, 0.0).unwrap();
    assert_eq!(a, b);
    let short = NearField { offsets: vec![0; 3], entries: Vec::new(), hits: 0, holes: 0 };
    assert!(op.indirect_with_near(&cpca, Some(&short), &table, &albedo, &direct, None, 2, 0.0).is_err());
}
