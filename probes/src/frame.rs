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

use crate::near_field::NearField;
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
    /// The near field added to every bounce's gather (`near_field`), if any: the transport
    /// then carries the far hits only.
    fn near_field(&self) -> Option<&NearField> {
        None
    }
}

/// A transport of the far hits (`far`, dense or CPCA) with the near field gathered from the
/// senders beside it: each bounce E = far's gather + Σ_near w · B(sender).
pub struct WithNearField<'a> {
    pub far: &'a dyn ReceiverTransport,
    pub near: &'a NearField,
}

impl ReceiverTransport for WithNearField<'_> {
    fn receiver_count(&self) -> usize {
        self.far.receiver_count()
    }
    fn gather(&self, lambda: &[Vec3], coefficients: usize) -> Vec<Vec3> {
        self.far.gather(lambda, coefficients)
    }
    fn gather_timed(&self, lambda: &[Vec3], coefficients: usize, times: &mut BounceTimes) -> Vec<Vec3> {
        self.far.gather_timed(lambda, coefficients, times)
    }
    fn near_field(&self) -> Option<&NearField> {
        Some(self.near)
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
    /// The near field's gather from the senders (`near_field`), summed over the bounces.
    pub near_field_s: f64,
}

impl BounceTimes {
    pub fn total_s(&self) -> f64 {
        self.probe_relight_s
            + self.cluster_projection_s
            + self.receiver_irradiance_s
            + self.projected_bounces_s
            + self.near_field_s
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
        let mut gathered = transports.gather_timed(&lambda, nc, &mut times);
        if let Some(near) = transports.near_field() {
            if near.receivers() != n {
                return Err(ProbesError::parameter(
                    "near field",
                    format!("{} receivers' lists for {n} receivers", near.receivers()),
                ));
            }
            let t = Instant::now();
            near.add_into(&radiance, &mut gathered);
            times.near_field_s += t.elapsed().as_secs_f64();
        }
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
mod tests;
