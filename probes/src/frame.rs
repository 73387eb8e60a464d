//! Section 4.2, run time, with the dense transport (CPCA comes in phase 5): sender radiance from
//! direct and indirect irradiance, probe SH by the relight rays, receiver irradiance by Eq. 7,
//! and the paper's feedback ("the resulting diffuse component of the outgoing radiance is fed
//! back … as input for the next direct-to-indirect transport iteration"), iterated here a given
//! number of times or to convergence.
//!
//! Sender radiance is `B_s = ρ_s / π · (E_direct,s + E_indirect,s)`: emission is not sent
//! through the probes (lfr's `indirect` layer excludes emitter → first-hit light). Negative
//! reconstructed irradiance (SH ringing) is clamped at zero and counted.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use tracer::Scene;

use crate::relight::RelightTable;
use crate::surfels::Surfels;
use crate::transport::Transport;
use crate::ProbesError;

/// The indirect irradiance at every receiver after some bounces.
#[derive(Clone, Debug, PartialEq)]
pub struct Indirect {
    pub irradiance: Vec<Vec3>,
    pub iterations: usize,
    /// Receiver channels clamped at zero in the last iteration.
    pub clamped: u64,
    /// The largest relative change of the last iteration (∞ after one).
    pub change: f32,
}

/// The diffuse albedo of every surfel: its material's base colour times (1 − metallic), with
/// the base-colour and metallic-roughness textures read at the surfel's point through the
/// tracer's own surface model, mip-filtered over a footprint of the surfel's cell size h (the
/// area it stands for) — the albedo the path tracer sees there, averaged over the surfel.
pub fn surfel_albedo(scene: &Scene, surfels: &Surfels) -> Vec<Vec3> {
    let footprint = surfels.h as f32;
    surfels
        .surfels
        .par_iter()
        .map(|s| {
            let mesh = &scene.meshes[s.mesh as usize];
            let m = &scene.materials[mesh.material as usize];
            if m.base_color_texture.is_none() && m.metallic_roughness_texture.is_none() {
                return m.base_color * (1.0 - m.metallic.clamp(0.0, 1.0));
            }
            let [ia, ib, ic] = mesh.indices[s.triangle as usize];
            let [a, b, c] = [ia, ib, ic].map(|i| mesh.positions[i as usize].as_dvec3());
            let (e1, e2, p) = (b - a, c - a, s.position.as_dvec3() - a);
            let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
            let (p1, p2) = (p.dot(e1), p.dot(e2));
            let det = d11 * d22 - d12 * d12;
            let (mut u, mut v) =
                if det > 0.0 { ((d22 * p1 - d12 * p2) / det, (d11 * p2 - d12 * p1) / det) } else { (0.0, 0.0) };
            u = u.clamp(0.0, 1.0);
            v = v.clamp(0.0, 1.0 - u);
            let hit = tracer::accel::Hit {
                distance: 0.0,
                mesh: s.mesh,
                triangle: s.triangle,
                barycentric: glam::Vec2::new(u as f32, v as f32),
                geometric_normal: e1.cross(e2).as_vec3(),
            };
            let surface = tracer::integrator::SurfacePoint::new(scene, &hit, s.normal, 0.0, footprint);
            surface.bsdf.base_color * (1.0 - surface.bsdf.metallic)
        })
        .collect()
}

/// What maps probe coefficients λ to every receiver's irradiance: the dense transports of
/// Eq. 7 or their CPCA compression.
pub trait ReceiverTransport: Sync {
    /// The number of receivers (surfels).
    fn receiver_count(&self) -> usize;
    /// Every receiver's irradiance, unclamped, for `lambda` (probe-major RGB, `coefficients`
    /// per probe).
    fn gather(&self, lambda: &[Vec3], coefficients: usize) -> Vec<Vec3>;
    /// [`ReceiverTransport::gather`] with its seconds added to `times`: the cluster projection
    /// (CPCA's λ onto each cluster's basis; none for the dense transport) and the receiver
    /// irradiance. The same values as `gather`.
    fn gather_timed(&self, lambda: &[Vec3], coefficients: usize, times: &mut BounceTimes) -> Vec<Vec3> {
        let t = Instant::now();
        let e = self.gather(lambda, coefficients);
        times.receiver_irradiance_s += t.elapsed().as_secs_f64();
        e
    }
}

/// Seconds spent in each stage of the bounces, summed over the iterations: the paper's Table 2
/// columns after "scene relight".
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BounceTimes {
    /// Sender radiance and the probes' SH from the relight rays (with the masked fit).
    pub probe_relight_s: f64,
    /// CPCA: λ projected onto each cluster's basis (0 for the dense transport).
    pub cluster_projection_s: f64,
    /// Every receiver's irradiance (CPCA: U times the projection; dense: Eq. 7), the clamp
    /// at zero and the convergence test.
    pub receiver_irradiance_s: f64,
    /// The bounces run in CPCA's projected space (`projected_bounce`), all three stages at
    /// once; 0 for the loop here.
    pub projected_bounces_s: f64,
}

impl BounceTimes {
    pub fn total_s(&self) -> f64 {
        self.probe_relight_s + self.cluster_projection_s + self.receiver_irradiance_s + self.projected_bounces_s
    }
}

impl ReceiverTransport for [Transport] {
    fn receiver_count(&self) -> usize {
        self.len()
    }
    fn gather(&self, lambda: &[Vec3], coefficients: usize) -> Vec<Vec3> {
        self.par_iter().map(|t| t.irradiance_rgb(lambda, coefficients)).collect()
    }
}

impl ReceiverTransport for Vec<Transport> {
    fn receiver_count(&self) -> usize {
        self.len()
    }
    fn gather(&self, lambda: &[Vec3], coefficients: usize) -> Vec<Vec3> {
        self.as_slice().gather(lambda, coefficients)
    }
}

impl ReceiverTransport for crate::cpca::Cpca {
    fn receiver_count(&self) -> usize {
        self.receivers
    }
    fn gather(&self, lambda: &[Vec3], _coefficients: usize) -> Vec<Vec3> {
        self.irradiance(lambda)
    }
    fn gather_timed(&self, lambda: &[Vec3], _coefficients: usize, times: &mut BounceTimes) -> Vec<Vec3> {
        let t = Instant::now();
        let projected = self.project_clusters(lambda);
        times.cluster_projection_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let e = self.expand(&projected);
        times.receiver_irradiance_s += t.elapsed().as_secs_f64();
        e
    }
}

/// Whether the bounces may stop: the last bounce's relative `change` is under `tolerance`, and
/// so is the light the remaining bounces would still add, estimated as a geometric tail
/// change · r / (1 − r), r the contraction per bounce ([`contraction`] of `history`, a summed
/// absolute change per bounce so far; no estimate after the first bounce).
///
/// The change alone is not enough where bounces keep most of the light: the tail after a
/// change c is about c / (1 − ρ), so at albedo 0.99 a tolerance of 1e-3 stopped 10 % short of
/// the converged irradiance (test `projected_bounces_follow_the_full_loop_at_albedo_0_99`).
/// Where r ≤ 1/2 the tail is at most the change and the test is the change's alone.
pub fn converged(change: f32, history: &[f64], tolerance: f32) -> bool {
    if !(change < tolerance) {
        return false;
    }
    match contraction(history) {
        None => true,
        Some(r) => r < 1.0 && (change as f64) * r / (1.0 - r) < tolerance as f64,
    }
}

/// The contraction per bounce from the summed changes of the bounces so far: the geometric
/// mean ratio over the last (up to) 8 bounces, which f32 rounding in the changes does not
/// make noisy as a ratio of two bounces does (the full loop's changes late in a slow series
/// are a few dozen f32 steps). `None` before two bounces; 0 when the last change is 0.
pub fn contraction(history: &[f64]) -> Option<f64> {
    let n = history.len();
    if n < 2 {
        return None;
    }
    let m = (n - 1).min(8);
    let (last, first) = (history[n - 1], history[n - 1 - m]);
    if last == 0.0 {
        return Some(0.0);
    }
    if !(first > 0.0) {
        return Some(f64::INFINITY);
    }
    Some((last / first).powf(1.0 / m as f64))
}

/// Iterates the feedback loop at most `max_iterations` times, stopping early when the largest
/// change of a receiver's irradiance, and the tail of bounces it predicts ([`converged`]), fall
/// below `tolerance` times the largest irradiance (0 to run every iteration). `albedo` and `direct` have one value per surfel (the receivers
/// and senders are the same surfels, in the same order as `transports`).
pub fn indirect<T: ReceiverTransport + ?Sized>(
    transports: &T,
    table: &RelightTable,
    albedo: &[Vec3],
    direct: &[Vec3],
    max_iterations: usize,
    tolerance: f32,
) -> Result<Indirect, ProbesError> {
    indirect_from(transports, table, albedo, direct, None, max_iterations, tolerance)
}

/// [`indirect`] starting from the indirect irradiance `start` (one value per receiver; zero
/// when `None`): the paper's per-frame feedback, one iteration a frame, starts from the last
/// frame's result.
pub fn indirect_from<T: ReceiverTransport + ?Sized>(
    transports: &T,
    table: &RelightTable,
    albedo: &[Vec3],
    direct: &[Vec3],
    start: Option<&[Vec3]>,
    max_iterations: usize,
    tolerance: f32,
) -> Result<Indirect, ProbesError> {
    indirect_timed(transports, table, albedo, direct, start, max_iterations, tolerance).map(|(out, _)| out)
}

/// [`indirect_from`] with the seconds of each stage, summed over the iterations.
pub fn indirect_timed<T: ReceiverTransport + ?Sized>(
    transports: &T,
    table: &RelightTable,
    albedo: &[Vec3],
    direct: &[Vec3],
    start: Option<&[Vec3]>,
    max_iterations: usize,
    tolerance: f32,
) -> Result<(Indirect, BounceTimes), ProbesError> {
    let n = transports.receiver_count();
    if albedo.len() != n || direct.len() != n {
        return Err(ProbesError::parameter(
            "senders",
            format!("{n} receivers, {} albedos and {} direct values: one each per surfel", albedo.len(), direct.len()),
        ));
    }
    if let Some(i) = albedo.iter().chain(direct).position(|v| !v.is_finite() || v.min_element() < 0.0) {
        return Err(ProbesError::parameter("senders", format!("value {i} is negative or not finite")));
    }
    if let Some(start) = start {
        if start.len() != n {
            return Err(ProbesError::parameter(
                "start",
                format!("{} values for {n} receivers: one per surfel", start.len()),
            ));
        }
        if let Some(i) = start.iter().position(|v| !v.is_finite() || v.min_element() < 0.0) {
            return Err(ProbesError::parameter("start", format!("value {i} is negative or not finite")));
        }
    }
    let nc = table.coefficients;
    let mut e = start.map_or_else(|| vec![Vec3::ZERO; n], |s| s.to_vec());
    let mut out = Indirect { irradiance: Vec::new(), iterations: 0, clamped: 0, change: f32::INFINITY };
    let mut times = BounceTimes::default();
    let mut history: Vec<f64> = Vec::new();
    for _ in 0..max_iterations {
        let t = Instant::now();
        let radiance: Vec<Vec3> =
            albedo.iter().zip(direct).zip(&e).map(|((a, d), e)| *a * (*d + *e) / std::f32::consts::PI).collect();
        let lambda = table.project(&radiance);
        times.probe_relight_s += t.elapsed().as_secs_f64();
        let gathered = transports.gather_timed(&lambda, nc, &mut times);
        let t = Instant::now();
        let next: Vec<(Vec3, u64)> = gathered
            .into_iter()
            .map(|v| {
                let clamped = v.to_array().iter().filter(|&&c| c < 0.0).count() as u64;
                (v.max(Vec3::ZERO), clamped)
            })
            .collect();
        let largest = next.iter().map(|(v, _)| v.max_element()).fold(0.0f32, f32::max);
        let change = next.iter().zip(&e).map(|((v, _), old)| (*v - *old).abs().max_element()).fold(0.0f32, f32::max);
        out.change = if largest > 0.0 { change / largest } else { 0.0 };
        out.clamped = next.iter().map(|(_, c)| c).sum();
        let summed: f64 = next.iter().zip(&e).map(|((v, _), old)| (*v - *old).abs().element_sum() as f64).sum();
        e = next.into_iter().map(|(v, _)| v).collect();
        out.iterations += 1;
        times.receiver_irradiance_s += t.elapsed().as_secs_f64();
        history.push(summed);
        if converged(out.change, &history, tolerance) {
            break;
        }
    }
    out.irradiance = e;
    Ok((out, times))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surfels::{SurfelSettings, Surfels};
    use crate::test_scenes::scene_of;
    use crate::transport::{TransportContext, TransportSettings};
    use glam::DVec3;
    use tracer::scene::shapes::sphere;
    use tracer::Accel;

    struct Setup {
        transports: Vec<Transport>,
        table: RelightTable,
        inward: Vec<bool>,
        surfels: Surfels,
    }

    /// A closed unit sphere with one probe at its centre (it sees every inner point).
    fn sphere_setup() -> Setup {
        let centre = Vec3::ZERO;
        let scene = scene_of(vec![sphere("s", centre, 1.0, 4, 0)], centre);
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 1200, ..Default::default() }).unwrap();
        let probes = [DVec3::ZERO];
        let settings = TransportSettings { order: 4, directions: 128, ..Default::default() };
        let transports = TransportContext::new(&accel, &probes, 2.0, 2.0, settings).unwrap().all(&surfels);
        let table = RelightTable::build(&accel, &surfels, &probes, 4000, 4, 2.0).unwrap();
        let inward = surfels.surfels.iter().map(|s| s.normal.dot(s.position) < 0.0).collect();
        Setup { transports, table, inward, surfels }
    }

    #[test]
    fn multiple_bounces_follow_the_geometric_series() {
        let s = sphere_setup();
        let n = s.surfels.surfels.len();
        let e0 = Vec3::new(1.0, 2.0, 0.5);
        for rho in [0.5f32, 0.9] {
            let albedo = vec![Vec3::splat(rho); n];
            for k in [1usize, 3, 10] {
                let out = indirect(&s.transports, &s.table, &albedo, &vec![e0; n], k, 0.0).unwrap();
                assert_eq!(out.iterations, k);
                let series: f32 = (1..=k).map(|i| rho.powi(i as i32)).sum();
                for (e, &inside) in out.irradiance.iter().zip(&s.inward) {
                    if inside {
                        let rel = ((*e - e0 * series) / (e0 * series)).abs().max_element();
                        assert!(rel < 2e-2, "ρ = {rho}, {k} bounces: {e} against {}", e0 * series);
                    } else {
                        // The outer side sees only the sky: no indirect light.
                        assert_eq!(*e, Vec3::ZERO);
                    }
                }
            }
            // Converged: ρ / (1 − ρ).
            let out = indirect(&s.transports, &s.table, &albedo, &vec![e0; n], 500, 1e-4).unwrap();
            assert!(out.iterations < 500 && out.change < 1e-4);
            let limit = e0 * rho / (1.0 - rho);
            let worst = out
                .irradiance
                .iter()
                .zip(&s.inward)
                .filter(|(_, &i)| i)
                .map(|(e, _)| ((*e - limit) / limit).abs().max_element())
                .fold(0.0f32, f32::max);
            assert!(worst < 3e-2, "ρ = {rho}: converged off by {worst}");
        }
    }

    #[test]
    fn albedo_comes_from_the_surfels_material() {
        let s = sphere_setup();
        let mut scene = scene_of(vec![sphere("s", Vec3::ZERO, 1.0, 4, 1)], Vec3::ZERO);
        scene.materials.push(tracer::scene::Material {
            base_color: Vec3::new(0.8, 0.4, 0.2),
            metallic: 0.25,
            ..Default::default()
        });
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 200, ..Default::default() }).unwrap();
        let albedo = surfel_albedo(&scene, &surfels);
        assert!(albedo.iter().all(|a| (*a - Vec3::new(0.6, 0.3, 0.15)).abs().max_element() < 1e-6));
        assert_eq!(
            surfel_albedo(&scene_of(vec![sphere("s", Vec3::ZERO, 1.0, 4, 0)], Vec3::ZERO), &s.surfels).len(),
            s.surfels.surfels.len()
        );
    }

    #[test]
    fn albedo_reads_the_base_colour_texture_at_the_surfel() {
        // A unit quad with uv = xy and a 4 × 1 linear texture: red, red, blue, blue.
        let mut quad = crate::test_scenes::unit_quad();
        quad.uvs = Some(quad.positions.iter().map(|p| glam::Vec2::new(p.x, p.y)).collect());
        let mut scene = scene_of(vec![quad], Vec3::new(0.5, 0.5, 1.0));
        let texels = [[255u8, 0, 0, 255], [255, 0, 0, 255], [0, 0, 255, 255], [0, 0, 255, 255]].concat();
        scene.textures.push(tracer::texture::Texture::from_rgba8("t".into(), 4, 1, false, texels));
        scene.materials[0].base_color = Vec3::splat(0.5);
        scene.materials[0].metallic = 0.0;
        scene.materials[0].base_color_texture = Some(tracer::texture::TextureRef::new(0));
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 400, ..Default::default() }).unwrap();
        let albedo = surfel_albedo(&scene, &surfels);
        let (mut red, mut blue) = (0, 0);
        for (s, a) in surfels.surfels.iter().zip(&albedo) {
            if (0.15..0.35).contains(&s.position.x) {
                red += 1;
                assert!((*a - Vec3::new(0.5, 0.0, 0.0)).abs().max_element() < 0.05, "{} at {}", a, s.position);
            } else if (0.65..0.85).contains(&s.position.x) {
                blue += 1;
                assert!((*a - Vec3::new(0.0, 0.0, 0.5)).abs().max_element() < 0.05, "{} at {}", a, s.position);
            }
        }
        assert!(red > 10 && blue > 10, "{red} {blue}");
    }

    #[test]
    fn indirect_light_is_linear_in_the_direct_light() {
        let s = sphere_setup();
        let n = s.surfels.surfels.len();
        let albedo = vec![Vec3::new(0.7, 0.5, 0.3); n];
        let a: Vec<Vec3> = s.surfels.surfels.iter().map(|x| Vec3::splat(1.0 + x.position.z)).collect();
        let b: Vec<Vec3> = s.surfels.surfels.iter().map(|x| Vec3::new(2.0 - x.position.x, 0.5, 1.0)).collect();
        let sum: Vec<Vec3> = a.iter().zip(&b).map(|(a, b)| *a + *b).collect();
        let run = |d: &[Vec3]| indirect(&s.transports, &s.table, &albedo, d, 4, 0.0).unwrap();
        let (ea, eb, es) = (run(&a), run(&b), run(&sum));
        assert_eq!(es.clamped, 0);
        for ((x, y), z) in ea.irradiance.iter().zip(&eb.irradiance).zip(&es.irradiance) {
            assert!((*x + *y - *z).abs().max_element() <= 1e-5 * z.max_element().max(1.0), "{x} + {y} ≠ {z}");
        }
        let zero = run(&vec![Vec3::ZERO; n]);
        assert!(zero.irradiance.iter().all(|e| *e == Vec3::ZERO));
        // Mismatched or negative inputs are refused by name.
        let err = indirect(&s.transports, &s.table, &albedo[1..], &a, 1, 0.0).unwrap_err();
        assert!(err.to_string().starts_with("senders:"), "{err}");
        let mut bad = a.clone();
        bad[3] = Vec3::splat(f32::NAN);
        assert!(indirect(&s.transports, &s.table, &albedo, &bad, 1, 0.0).is_err());
    }

    #[test]
    fn one_bounce_per_frame_with_feedback_equals_the_bounces_at_once() {
        let s = sphere_setup();
        let n = s.surfels.surfels.len();
        let albedo = vec![Vec3::new(0.7, 0.5, 0.3); n];
        let direct: Vec<Vec3> = s.surfels.surfels.iter().map(|x| Vec3::splat(1.0 + x.position.z)).collect();
        let at_once = indirect(&s.transports, &s.table, &albedo, &direct, 4, 0.0).unwrap();
        let mut e: Option<Vec<Vec3>> = None;
        for _ in 0..4 {
            e = Some(
                indirect_from(&s.transports, &s.table, &albedo, &direct, e.as_deref(), 1, 0.0).unwrap().irradiance,
            );
        }
        assert_eq!(e.unwrap(), at_once.irradiance);
        let err = indirect_from(&s.transports, &s.table, &albedo, &direct, Some(&direct[1..]), 1, 0.0).unwrap_err();
        assert!(err.to_string().starts_with("start:"), "{err}");
    }

    /// Diagnostic (run by hand, `--ignored --nocapture`): on the Cornell box, the probes'
    /// one-bounce gather (Eq. 7 with λ from the relight rays) against a brute-force gather of
    /// the same sender radiance along 1024 cosine rays per receiver.
    #[test]
    #[ignore]
    fn cornell_probe_gather_against_a_brute_force_gather() {
        use crate::direct::direct_irradiance;
        use crate::lookup::lookup;
        use crate::precompute::{Precompute, PrecomputeSettings};
        use crate::visibility::offset;
        use shading::{sample_cosine_hemisphere, Frame};
        use tracer::sampler::Sampler;
        let scene = crate::test_scenes::cornell();
        let mut settings = PrecomputeSettings::default();
        settings.surfels.budget = 5000;
        settings.placement.probes = 27;
        settings.transport.directions = 256;
        let pre = Precompute::build(&scene, &settings, &mut |_| {}).unwrap();
        let accel = Accel::build(&scene).unwrap();
        let scale = pre.scale as f32;
        let albedo = surfel_albedo(&scene, &pre.surfels);
        let direct = direct_irradiance(&scene, &accel, &pre.surfels, 64, 0, scale).unwrap();
        let out = indirect(&pre.transports, &pre.table, &albedo, &direct, 30, 1e-4).unwrap();
        let radiance: Vec<Vec3> = albedo
            .iter()
            .zip(&direct)
            .zip(&out.irradiance)
            .map(|((a, d), e)| *a * (*d + *e) / std::f32::consts::PI)
            .collect();
        let lambda = pre.table.project(&radiance);
        let nc = pre.coefficients();
        let (mut sum_p, mut sum_b, mut sum_l) = (glam::DVec3::ZERO, glam::DVec3::ZERO, glam::DVec3::ZERO);
        let mut found = Vec::new();
        for (i, (s, t)) in pre.surfels.surfels.iter().zip(&pre.transports).enumerate().step_by(23) {
            if t.probes.is_empty() {
                continue;
            }
            sum_p += t.irradiance_rgb(&lambda, nc).as_dvec3();
            let frame = Frame::new(s.normal);
            let origin = s.position + s.normal * offset(s.position, scale);
            let (mut b, mut l) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
            for k in 0..1024 {
                let u = Sampler::new(3, i as u32, 7, k).next_2d();
                let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                let ng = hit.geometric_normal.normalize_or_zero();
                let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                let y = origin + dir * hit.distance;
                lookup(&pre.surfels, y, side, &mut found);
                for &(s, w) in &found {
                    b += (radiance[s as usize] * w).as_dvec3();
                }
                // The probe nearest the hit that sees it, read in its own direction.
                let mut best: Option<(f32, usize)> = None;
                for (pi, p) in pre.probes.iter().enumerate() {
                    let p = p.as_vec3();
                    let d = p.distance(y);
                    if crate::visibility::probe_sees(&accel, y, side, p, scale) && best.map_or(true, |(bd, _)| d < bd) {
                        best = Some((d, pi));
                    }
                }
                if let Some((_, pi)) = best {
                    let psi = (y - pre.probes[pi].as_vec3()).normalize();
                    let basis = crate::sh::Basis::new(settings.transport.order);
                    let mut yv = vec![0.0f32; nc];
                    basis.eval_into(psi, &mut yv);
                    let mut v = Vec3::ZERO;
                    for j in 0..nc {
                        v += lambda[pi * nc + j] * yv[j];
                    }
                    l += v.as_dvec3();
                }
            }
            sum_b += b * std::f64::consts::PI / 1024.0;
            sum_l += l * std::f64::consts::PI / 1024.0;
        }
        println!("probes / brute force: {}", sum_p / sum_b);
        println!("nearest seeing probe's SH / brute force: {}", sum_l / sum_b);
        println!(
            "relight escaped {} holes {} of {}",
            pre.table.escaped,
            pre.table.holes,
            pre.table.rays as usize * pre.probes.len()
        );
        // A brute-force surfel radiosity: 256 cosine rays per valid receiver, each hit read
        // through the lookup, iterated to convergence; both solutions rendered at 128².
        let rays = 256u32;
        let gathers: Vec<Vec<(u32, f32)>> = pre
            .surfels
            .surfels
            .par_iter()
            .zip(&pre.transports)
            .enumerate()
            .map(|(i, (s, t))| {
                let mut row: Vec<(u32, f32)> = Vec::new();
                if t.probes.is_empty() {
                    return row;
                }
                let frame = Frame::new(s.normal);
                let origin = s.position + s.normal * offset(s.position, scale);
                let mut found = Vec::new();
                for k in 0..rays {
                    let u = Sampler::new(5, i as u32, 9, k).next_2d();
                    let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                    let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                    let ng = hit.geometric_normal.normalize_or_zero();
                    let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                    lookup(&pre.surfels, origin + dir * hit.distance, side, &mut found);
                    row.extend(found.iter().map(|&(s, w)| (s, w * std::f32::consts::PI / rays as f32)));
                }
                row
            })
            .collect();
        let mut e = vec![Vec3::ZERO; radiance.len()];
        for _ in 0..60 {
            let b: Vec<Vec3> =
                albedo.iter().zip(&direct).zip(&e).map(|((a, d), e)| *a * (*d + *e) / std::f32::consts::PI).collect();
            e = gathers.iter().map(|row| row.iter().fold(Vec3::ZERO, |acc, &(s, w)| acc + b[s as usize] * w)).collect();
        }
        let image =
            crate::image::ImageSettings { width: 128, height: 128, light_samples: 16, pixel_samples: 1, seed: 0 };
        for (name, values) in [("probes", &out.irradiance), ("brute force", &e)] {
            let img = crate::image::render_image(&scene, &accel, &pre, values, &image).unwrap();
            let mean = img.indirect.iter().fold(Vec3::ZERO, |a, v| a + *v) / img.indirect.len() as f32;
            println!("{name}: mean indirect at 128x128 {mean}");
        }
        // One bounce: the gather of the senders' direct-only radiance through the lookup
        // against the same gather with the direct light evaluated exactly at each hit.
        let lights = tracer::lights::LightSampler::new(&scene);
        let direct_only: Vec<Vec3> = albedo.iter().zip(&direct).map(|(a, d)| *a * *d / std::f32::consts::PI).collect();
        let (mut via_lookup, mut exact) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
        for (i, (s, t)) in pre.surfels.surfels.iter().zip(&pre.transports).enumerate().step_by(23) {
            if t.probes.is_empty() {
                continue;
            }
            let frame = Frame::new(s.normal);
            let origin = s.position + s.normal * offset(s.position, scale);
            for k in 0..256 {
                let u = Sampler::new(11, i as u32, 13, k).next_2d();
                let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                let ng = hit.geometric_normal.normalize_or_zero();
                let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                let y = origin + dir * hit.distance;
                lookup(&pre.surfels, y, side, &mut found);
                for &(s, w) in &found {
                    via_lookup += (direct_only[s as usize] * w).as_dvec3();
                }
                let m = &scene.materials[scene.meshes[hit.mesh as usize].material as usize];
                let rho = m.base_color * (1.0 - m.metallic);
                let e = crate::direct::direct_at(&scene, &accel, &lights, y, side, k + 7919 * i as u32, 64, 0, scale);
                exact += (rho * e / std::f32::consts::PI).as_dvec3();
            }
        }
        println!("one bounce, senders through the lookup / direct light exact at each hit: {}", via_lookup / exact);
        let one = indirect(&pre.transports, &pre.table, &albedo, &direct, 1, 0.0).unwrap();
        let img = crate::image::render_image(&scene, &accel, &pre, &one.irradiance, &image).unwrap();
        let mean = img.indirect.iter().fold(Vec3::ZERO, |a, v| a + *v) / img.indirect.len() as f32;
        println!("probes, one bounce: mean indirect at 128x128 {mean}");
    }
}
