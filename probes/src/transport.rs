//! The local transport of one receiver: Eq. 2 (visibility-aware reconstruction), Eq. 4 (the
//! kernel K_ij), Eq. 5–7 (its measurement by the clamped cosine, the irradiance transport
//! vector α_x), and as the ablation baseline the spatial-only interpolation of Eq. 1.
//!
//! α_ij = ∫ K_ij(x, ω) cos θ dω is estimated with M cosine-distributed directions (density
//! cos θ / π) from the tracer's Owen-scrambled Sobol' sampler seeded by the receiver index:
//! α_ij ≈ (π / M) Σ_k K_ij(x, ω_k). Escaped directions contribute nothing (light from the sky
//! straight to the receiver is lfr's `direct` layer); directions whose hit no covering probe
//! sees are *unseen* and contribute nothing (the paper's definition), both counted. Sums run in
//! f64 in a fixed order: the result is the same for any thread count.

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use shading::{sample_cosine_hemisphere, Frame};
use tracer::sampler::Sampler;
use tracer::Accel;

use crate::kernel;
use crate::sh::{Basis, MAX_ORDER};
use crate::surfels::Surfels;
use crate::visibility::{offset, probe_sees};
use crate::voxel::VoxelGrid;
use crate::ProbesError;

/// The most directions per receiver.
pub const MAX_DIRECTIONS: u32 = 1 << 20;
/// The share of back-face hits at which a receiver is hidden ([`TransportContext::hidden`]).
pub const HIDDEN_BACK_FACES: f64 = 0.3;
/// Directions of [`side_hidden`], the test that decides which surface sides get surfels.
pub const SIDE_TEST_RAYS: u32 = 64;

/// Whether `back_faces` of a side's `hits` hide it: at least [`HIDDEN_BACK_FACES`] of them
/// (no hit hides nothing). The rule of [`TransportContext::hidden`] and [`side_hidden`].
pub fn mostly_back_faces(hits: u32, back_faces: u32) -> bool {
    hits > 0 && back_faces as f64 >= HIDDEN_BACK_FACES * hits as f64
}

/// Whether the surface side at `x` with unit normal `n` is hidden by the rule of
/// [`TransportContext::hidden`], its back-face share measured over `rays` cosine-distributed
/// directions of their own Sobol' stream (seeded by `seed` and `index`) instead of the
/// transport's: its front voxel is empty and never reached by the flood fill, or at least
/// [`HIDDEN_BACK_FACES`] of its hits are on back faces. What decides, before the transport,
/// which sides get surfels (`surfels::Sides::Valid`).
#[allow(clippy::too_many_arguments)]
pub fn side_hidden(
    accel: &Accel,
    grid: &VoxelGrid,
    x: Vec3,
    n: Vec3,
    index: u32,
    seed: u32,
    rays: u32,
    scale: f32,
) -> bool {
    side_hits(accel, grid, x, n, index, seed, rays, scale).map_or(true, |(hits, back)| mostly_back_faces(hits, back))
}

/// The hits and back-face hits of [`side_hidden`]'s rays, `None` when the side's front voxel is
/// empty and never reached (no ray traced).
#[allow(clippy::too_many_arguments)]
pub fn side_hits(
    accel: &Accel,
    grid: &VoxelGrid,
    x: Vec3,
    n: Vec3,
    index: u32,
    seed: u32,
    rays: u32,
    scale: f32,
) -> Option<(u32, u32)> {
    if grid.front_enclosed(x.as_dvec3(), n.as_dvec3()) {
        return None;
    }
    let frame = Frame::new(n);
    let origin = x + n * offset(x, scale);
    let (mut hits, mut back_faces) = (0u32, 0u32);
    for k in 0..rays {
        let u = Sampler::new(seed, index, 0x4fff_ffff, k).next_2d();
        let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
        if let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) {
            hits += 1;
            if hit.geometric_normal.normalize_or_zero().dot(dir) > 0.0 {
                back_faces += 1;
            }
        }
    }
    Some((hits, back_faces))
}

/// How the incident radiance is reconstructed from the probes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reconstruction {
    /// Eq. 2: each direction read at the surface point it hits, from the probes that see that
    /// point, each in its own direction.
    VisibilityAware,
    /// Eq. 1: the probes' radiance in the receiver's direction, blended by the spatial weights
    /// only (the paper's baseline; it leaks).
    SpatialOnly,
}

/// How the transport is precomputed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransportSettings {
    /// SH order of the probes (0..=7).
    pub order: usize,
    /// Directions per receiver, M.
    pub directions: u32,
    pub seed: u32,
    pub reconstruction: Reconstruction,
    /// The near field's radius as a share of the probes' support radius, when on: hits nearer
    /// than it are left out of α and gathered from their senders directly (`near_field`). `None`
    /// (the default here, and the paper's transport): every hit goes through the probes.
    pub near: Option<f64>,
}

impl Default for TransportSettings {
    fn default() -> Self {
        TransportSettings {
            order: crate::defaults::ORDER,
            directions: crate::defaults::DIRECTIONS,
            seed: 0,
            reconstruction: Reconstruction::VisibilityAware,
            near: None,
        }
    }
}

impl TransportSettings {
    pub fn validate(&self) -> Result<(), ProbesError> {
        if self.order > MAX_ORDER {
            return Err(ProbesError::parameter("order", format!("must be at most {MAX_ORDER}, got {}", self.order)));
        }
        if self.directions == 0 || self.directions > MAX_DIRECTIONS {
            return Err(ProbesError::parameter(
                "directions",
                format!("must be between 1 and {MAX_DIRECTIONS}, got {}", self.directions),
            ));
        }
        if let Some(near) = self.near {
            if !(near > 0.0 && near <= MAX_NEAR) {
                return Err(ProbesError::parameter(
                    "near-radius",
                    format!("must be in (0, {MAX_NEAR}] (a share of the support radius), got {near}"),
                ));
            }
            if self.reconstruction == Reconstruction::SpatialOnly {
                return Err(ProbesError::parameter(
                    "near-field",
                    "needs the visibility-aware reconstruction (the spatial-only one traces no hits)",
                ));
            }
        }
        Ok(())
    }
}

/// The largest near-field radius, in support radii.
pub const MAX_NEAR: f64 = 4.0;

/// α_x of one receiver over its covering probes.
#[derive(Clone, Debug, PartialEq)]
pub struct Transport {
    /// Indices of the probes with w_i(x) > 0, increasing.
    pub probes: Vec<u32>,
    /// α, probe-major: `alpha[k * coefficients + j]` for `probes[k]` and SH coefficient j.
    pub alpha: Vec<f32>,
    /// Directions that hit a surface, that hit one no covering probe sees, that escaped, and
    /// that hit a back face (the wrong side of closed geometry).
    pub hits: u32,
    pub unseen: u32,
    pub escaped: u32,
    pub back_faces: u32,
}

impl Transport {
    /// No probes, no directions: the transport of a hidden receiver.
    pub fn empty() -> Transport {
        Transport { probes: Vec::new(), alpha: Vec::new(), hits: 0, unseen: 0, escaped: 0, back_faces: 0 }
    }

    /// Eq. 7: I(x) = Σ_ij λ_ij α_ij for probe coefficients `lambda` (all probes, probe-major,
    /// `coefficients` per probe, one colour channel).
    pub fn irradiance(&self, lambda: &[f32], coefficients: usize) -> f32 {
        let mut sum = 0.0f64;
        for (k, &p) in self.probes.iter().enumerate() {
            let a = &self.alpha[k * coefficients..(k + 1) * coefficients];
            let l = &lambda[p as usize * coefficients..(p as usize + 1) * coefficients];
            sum += a.iter().zip(l).map(|(&a, &l)| a as f64 * l as f64).sum::<f64>();
        }
        sum as f32
    }

    /// Fills the unseen directions with the mean of the seen ones (an ablation of the paper's
    /// zero, decision 14): α scaled by hits / (hits − unseen); unchanged when nothing is seen.
    pub fn renormalise_unseen(&mut self) {
        let seen = self.hits.saturating_sub(self.unseen);
        if seen > 0 && self.unseen > 0 {
            let f = self.hits as f64 / seen as f64;
            self.alpha.iter_mut().for_each(|a| *a = (*a as f64 * f) as f32);
        }
    }

    /// [`Transport::irradiance`] for RGB coefficients.
    pub fn irradiance_rgb(&self, lambda: &[Vec3], coefficients: usize) -> Vec3 {
        let mut sum = DVec3::ZERO;
        for (k, &p) in self.probes.iter().enumerate() {
            let a = &self.alpha[k * coefficients..(k + 1) * coefficients];
            let l = &lambda[p as usize * coefficients..(p as usize + 1) * coefficients];
            for (&a, l) in a.iter().zip(l) {
                sum += l.as_dvec3() * a as f64;
            }
        }
        sum.as_vec3()
    }
}

/// What every receiver's transport shares.
pub struct TransportContext<'a> {
    pub accel: &'a Accel,
    pub probes: &'a [DVec3],
    pub radius: f64,
    /// The scene's largest extent (ray offsets).
    pub scale: f32,
    pub settings: TransportSettings,
    basis: Basis,
}

impl<'a> TransportContext<'a> {
    pub fn new(
        accel: &'a Accel,
        probes: &'a [DVec3],
        radius: f64,
        scale: f32,
        settings: TransportSettings,
    ) -> Result<TransportContext<'a>, ProbesError> {
        settings.validate()?;
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(ProbesError::parameter("radius", format!("must be positive and finite, got {radius}")));
        }
        Ok(TransportContext { accel, probes, radius, scale, settings, basis: Basis::new(settings.order) })
    }

    pub fn coefficients(&self) -> usize {
        self.basis.len()
    }

    /// The near field's radius in scene units (hits nearer than it are the near field's), or
    /// `None` when it is off.
    pub fn near_distance(&self) -> Option<f32> {
        self.settings.near.map(|f| (f * self.radius) as f32)
    }

    /// The ray origin of the receiver at `x` with unit normal `n`, offset along `n`.
    pub fn origin(&self, x: Vec3, n: Vec3) -> Vec3 {
        x + n * offset(x, self.scale)
    }

    /// Direction `k` of receiver `index` in its normal's `frame`: cosine-distributed,
    /// Owen-scrambled Sobol'.
    pub fn direction(&self, index: u32, frame: &Frame, k: u32) -> Vec3 {
        let u = Sampler::new(self.settings.seed, index, 0x1fff_ffff, k).next_2d();
        frame.to_world(sample_cosine_hemisphere(u)).normalize()
    }

    /// The transport of the receiver at `x` with unit normal `n`: Eq. 4's kernel K_ij measured by
    /// the clamped cosine (Eq. 5–6) into α_ij; `index` seeds its directions.
    pub fn receiver(&self, index: u32, x: Vec3, n: Vec3) -> Transport {
        let nc = self.basis.len();
        let xd = x.as_dvec3();
        let covering: Vec<(u32, f64, Vec3)> = self
            .probes
            .iter()
            .enumerate()
            .filter_map(|(i, p)| {
                let w = kernel::weight(p.distance(xd), self.radius);
                (w > 0.0).then(|| (i as u32, w, p.as_vec3()))
            })
            .collect();
        let mut acc = vec![0.0f64; covering.len() * nc];
        let mut y = vec![0.0f32; nc];
        let mut visible = vec![false; covering.len()];
        let frame = Frame::new(n);
        let origin = self.origin(x, n);
        let near = self.near_distance();
        let (mut hits, mut unseen, mut escaped, mut back_faces) = (0u32, 0u32, 0u32, 0u32);
        for k in 0..self.settings.directions {
            let dir = self.direction(index, &frame, k);
            match self.settings.reconstruction {
                Reconstruction::SpatialOnly => {
                    let total: f64 = covering.iter().map(|c| c.1).sum();
                    if !(total > 0.0) {
                        unseen += 1;
                        continue;
                    }
                    self.basis.eval_into(dir, &mut y);
                    for (c, (_, w, _)) in covering.iter().enumerate() {
                        let f = w / total;
                        for j in 0..nc {
                            acc[c * nc + j] += f * y[j] as f64;
                        }
                    }
                }
                Reconstruction::VisibilityAware => {
                    let Some(hit) = self.accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else {
                        escaped += 1;
                        continue;
                    };
                    hits += 1;
                    let ng = hit.geometric_normal.normalize_or_zero();
                    if ng.dot(dir) > 0.0 {
                        back_faces += 1;
                    }
                    if near.is_some_and(|r| hit.distance < r) {
                        // The near field's (`near_field`): gathered from its senders directly.
                        continue;
                    }
                    let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                    let point = origin + dir * hit.distance;
                    let mut total = 0.0f64;
                    for (c, &(_, w, p)) in covering.iter().enumerate() {
                        visible[c] = probe_sees(self.accel, point, side, p, self.scale);
                        if visible[c] {
                            total += w;
                        }
                    }
                    if !(total > 0.0) {
                        unseen += 1;
                        continue;
                    }
                    for (c, &(_, w, p)) in covering.iter().enumerate() {
                        if !visible[c] {
                            continue;
                        }
                        let psi = (point - p).normalize_or_zero();
                        self.basis.eval_into(psi, &mut y);
                        let f = w / total;
                        for j in 0..nc {
                            acc[c * nc + j] += f * y[j] as f64;
                        }
                    }
                }
            }
        }
        let scale = std::f64::consts::PI / self.settings.directions as f64;
        Transport {
            probes: covering.iter().map(|c| c.0).collect(),
            alpha: acc.iter().map(|&a| (a * scale) as f32).collect(),
            hits,
            unseen,
            escaped,
            back_faces,
        }
    }

    /// Whether a receiver is hidden: its front voxel is empty and never reached by the flood
    /// fill (inside closed geometry), or at least 30 % of its transport's hits are on back faces.
    /// A hidden receiver gets no transport (E = 0). (Until cache version 2 an unreached *solid*
    /// front voxel hid the receiver too, which hid bands along every concave edge, within a
    /// voxel of the adjacent wall: 10 % of Cornell's receivers.)
    pub fn hidden(grid: &VoxelGrid, x: Vec3, n: Vec3, transport: Option<&Transport>) -> bool {
        grid.front_enclosed(x.as_dvec3(), n.as_dvec3())
            || transport.is_some_and(|t| mostly_back_faces(t.hits, t.back_faces))
    }

    /// The transport of every surfel, hidden ones (see [`TransportContext::hidden`]) left empty
    /// (no probes, no directions traced past the voxel test); and how many were hidden.
    pub fn all_valid(&self, surfels: &Surfels, grid: &VoxelGrid) -> (Vec<Transport>, usize) {
        // The precompute's long step: receivers done, for the caller's progress bar.
        shading::progress::begin("traced", surfels.surfels.len() as u64, "receivers");
        let out: Vec<(Transport, bool)> = surfels
            .surfels
            .par_iter()
            .enumerate()
            .map(|(i, s)| {
                let result = if Self::hidden(grid, s.position, s.normal, None) {
                    (Transport::empty(), true)
                } else {
                    let t = self.receiver(i as u32, s.position, s.normal);
                    if Self::hidden(grid, s.position, s.normal, Some(&t)) {
                        (Transport::empty(), true)
                    } else {
                        (t, false)
                    }
                };
                shading::progress::advance(1);
                result
            })
            .collect();
        shading::progress::end();
        let hidden = out.iter().filter(|(_, h)| *h).count();
        (out.into_iter().map(|(t, _)| t).collect(), hidden)
    }

    /// The transport of every surfel, in surfel order.
    pub fn all(&self, surfels: &Surfels) -> Vec<Transport> {
        surfels.surfels.par_iter().enumerate().map(|(i, s)| self.receiver(i as u32, s.position, s.normal)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::index;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{room, scene_of};
    use tracer::scene::shapes::{polygon, sphere};

    fn inward_surfels(surfels: &Surfels, inside: impl Fn(Vec3) -> bool) -> Vec<(Vec3, Vec3)> {
        surfels
            .surfels
            .iter()
            .filter(|s| inside(s.position + s.normal * 0.01))
            .map(|s| (s.position, s.normal))
            .collect()
    }

    #[test]
    fn furnace_constant_probes_give_pi_l_wherever_every_hit_is_seen() {
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::new(1.0, 0.7, 0.8))], Vec3::splat(0.3));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 600, ..Default::default() }).unwrap();
        let receivers =
            inward_surfels(&surfels, |p| p.cmpgt(Vec3::ZERO).all() && p.cmplt(Vec3::new(1.0, 0.7, 0.8)).all());
        assert!(receivers.len() > 100);
        let probes = [DVec3::new(0.2, 0.3, 0.4), DVec3::new(0.7, 0.5, 0.2), DVec3::new(0.5, 0.2, 0.6)];
        let radius = 0.9;
        let radiance = 1.7f32;
        for order in [0, 2, 7] {
            let ctx = TransportContext::new(
                &accel,
                &probes,
                radius,
                1.0,
                TransportSettings { order, directions: 256, ..Default::default() },
            )
            .unwrap();
            let nc = ctx.coefficients();
            let mut lambda = vec![0.0f32; probes.len() * nc];
            for i in 0..probes.len() {
                lambda[i * nc] = (4.0 * std::f32::consts::PI).sqrt() * radiance;
            }
            let mut checked = 0;
            for (k, &(x, n)) in receivers.iter().enumerate() {
                let t = ctx.receiver(k as u32, x, n);
                assert_eq!(t.escaped, 0);
                assert_eq!(t.hits, 256);
                let e = t.irradiance(&lambda, nc) as f64;
                let expected = std::f64::consts::PI * radiance as f64 * (t.hits - t.unseen) as f64 / 256.0;
                assert!(
                    (e - expected).abs() < 1e-5 * expected.max(1.0),
                    "order {order}: E = {e}, π L seen = {expected}"
                );
                if t.unseen == 0 && !t.probes.is_empty() {
                    checked += 1;
                    assert!((e / (std::f64::consts::PI * radiance as f64) - 1.0).abs() < 1e-5);
                }
            }
            assert!(checked > receivers.len() / 2, "order {order}: only {checked} fully seen receivers");
        }
    }

    #[test]
    fn one_probe_at_a_sphere_centre_reproduces_sh_radiance_where_spatial_only_fails() {
        let centre = Vec3::new(0.1, -0.2, 0.3);
        let scene = scene_of(vec![sphere("s", centre, 1.0, 4, 0)], centre);
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 400, ..Default::default() }).unwrap();
        let receivers = inward_surfels(&surfels, |p| p.distance(centre) < 1.0);
        let probes = [centre.as_dvec3()];
        let settings = |reconstruction| TransportSettings { directions: 1024, reconstruction, ..Default::default() };
        let ours = TransportContext::new(&accel, &probes, 2.0, 2.0, settings(Reconstruction::VisibilityAware)).unwrap();
        let eq1 = TransportContext::new(&accel, &probes, 2.0, 2.0, settings(Reconstruction::SpatialOnly)).unwrap();
        let basis = Basis::new(MAX_ORDER);
        let mut worst_same = 0.0f64;
        let mut worst_ours = 0.0f64;
        let mut worst_eq1 = 0.0f64;
        for (l, m) in [(1usize, 1isize), (2, -1), (3, 2), (7, -5)] {
            // Sender radiance L(y) = Y_lm(direction from the centre to y): the probe's exact SH
            // is the unit vector e_lm.
            let mut lambda = vec![0.0f32; basis.len()];
            lambda[index(l, m)] = 1.0;
            for (k, &(x, n)) in receivers.iter().enumerate().step_by(7) {
                // The truth read at the hits directly: over the transport's own 1024 directions
                // (the reconstruction is exact, so only rounding may differ) and over 8192 other
                // directions (a quadrature of its own).
                let frame = Frame::new(n);
                let origin = x + n * offset(x, 2.0);
                let mut y = vec![0.0f32; basis.len()];
                let mut radiance_at = |seed: u32, dim: u32, count: u32| -> f64 {
                    let mut sum = 0.0f64;
                    for d in 0..count {
                        let u = Sampler::new(seed, k as u32, dim, d).next_2d();
                        let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                        let hit = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0).expect("closed sphere");
                        basis.eval_into((origin + dir * hit.distance - centre).normalize(), &mut y);
                        sum += y[index(l, m)] as f64;
                    }
                    sum * std::f64::consts::PI / count as f64
                };
                let same = radiance_at(0, 0x1fff_ffff, 1024);
                let truth = radiance_at(77, 5, 8192);
                let e = ours.receiver(k as u32, x, n).irradiance(&lambda, basis.len()) as f64;
                let e1 = eq1.receiver(k as u32, x, n).irradiance(&lambda, basis.len()) as f64;
                worst_same = worst_same.max((e - same).abs());
                worst_ours = worst_ours.max((e - truth).abs());
                worst_eq1 = worst_eq1.max((e1 - truth).abs());
            }
        }
        assert!(worst_same < 1e-5, "the reconstruction is not exact: off by {worst_same} on its own directions");
        assert!(worst_ours < 2e-2, "visibility-aware reconstruction off by {worst_ours} against 8192 directions");
        assert!(worst_eq1 > 0.3, "spatial-only interpolation should fail here, off by only {worst_eq1}");
    }

    #[test]
    fn a_wall_between_rooms_lets_no_light_through_where_eq1_leaks() {
        let wall = polygon(
            "wall",
            &[Vec3::new(0.5, 0.0, 0.0), Vec3::new(0.5, 0.0, 1.0), Vec3::new(0.5, 1.0, 1.0), Vec3::new(0.5, 1.0, 0.0)],
            0,
        );
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), wall], Vec3::new(0.75, 0.5, 0.5));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 1500, ..Default::default() }).unwrap();
        let room_b = inward_surfels(&surfels, |p| {
            p.x > 0.5 && p.x < 1.0 && p.cmpgt(Vec3::ZERO).all() && p.cmplt(Vec3::ONE).all()
        });
        assert!(room_b.len() > 100);
        // Probe 0 in room A, probe 1 in room B, both covering every receiver.
        let probes = [DVec3::new(0.25, 0.5, 0.5), DVec3::new(0.75, 0.5, 0.5)];
        let settings =
            |reconstruction| TransportSettings { order: 2, directions: 128, reconstruction, ..Default::default() };
        let ours = TransportContext::new(&accel, &probes, 3.0, 1.0, settings(Reconstruction::VisibilityAware)).unwrap();
        let eq1 = TransportContext::new(&accel, &probes, 3.0, 1.0, settings(Reconstruction::SpatialOnly)).unwrap();
        let nc = ours.coefficients();
        // Red light only in room A: probe 0 sees a constant red radiance, probe 1 none.
        let mut red = vec![0.0f32; 2 * nc];
        red[0] = 10.0;
        let mut leaked = 0.0f64;
        for (k, &(x, n)) in room_b.iter().enumerate() {
            let t = ours.receiver(k as u32, x, n);
            assert_eq!(t.probes, vec![0, 1]);
            assert_eq!(t.irradiance(&red, nc), 0.0, "light of room A reaches {x} in room B");
            assert!(t.alpha[..nc].iter().all(|&a| a == 0.0));
            leaked += eq1.receiver(k as u32, x, n).irradiance(&red, nc) as f64;
        }
        assert!(leaked / room_b.len() as f64 > 1.0, "Eq. 1 should leak through the wall: {leaked}");
    }

    #[test]
    fn hidden_receivers_get_no_transport() {
        // A closed block (outward faces) inside a room: its inner sides are hidden by the flood
        // fill, the room's outer sides see nothing, the rest is valid.
        let block = tracer::scene::shapes::axis_aligned_box("block", Vec3::splat(0.3), Vec3::splat(0.6), 0);
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), block], Vec3::splat(0.15));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 1500, ..Default::default() }).unwrap();
        let geometry = crate::geometry::Geometry::from_scene(&scene).unwrap();
        let grid = VoxelGrid::build(&geometry, 0.05, &[DVec3::splat(0.15)]).unwrap();
        let probes = [DVec3::splat(0.15), DVec3::splat(0.85)];
        let ctx = TransportContext::new(
            &accel,
            &probes,
            1.5,
            1.0,
            TransportSettings { directions: 64, ..Default::default() },
        )
        .unwrap();
        let (transports, hidden) = ctx.all_valid(&surfels, &grid);
        let inside_block = |p: Vec3| p.cmpgt(Vec3::splat(0.3)).all() && p.cmplt(Vec3::splat(0.6)).all();
        let mut block_inner = 0;
        for (s, t) in surfels.surfels.iter().zip(&transports) {
            if inside_block(s.position + s.normal * 0.01) {
                block_inner += 1;
                assert_eq!(*t, Transport::empty(), "a receiver inside the block has a transport");
            }
        }
        assert!(block_inner > 20 && hidden >= block_inner, "{block_inner} inner, {hidden} hidden");
        // Every valid receiver inside the room sees most of its hits.
        let valid: Vec<&Transport> = transports.iter().filter(|t| t.hits > 0).collect();
        let unseen: u32 = valid.iter().map(|t| t.unseen).sum();
        let hits: u32 = valid.iter().map(|t| t.hits).sum();
        assert!((unseen as f64) < 0.05 * hits as f64, "{unseen} of {hits} unseen");
    }

    #[test]
    fn the_side_test_hides_the_sealed_inside_and_counts_the_sides_that_see_nothing() {
        // A floor quad (facing +z) under a sealed slab, seen from above.
        let slab =
            tracer::scene::shapes::axis_aligned_box("slab", Vec3::new(0.2, 0.2, 0.4), Vec3::new(0.8, 0.8, 0.6), 0);
        let scene = scene_of(vec![crate::test_scenes::unit_quad(), slab], Vec3::new(0.5, 0.5, 2.0));
        let geometry = crate::geometry::Geometry::from_scene(&scene).unwrap();
        let accel = Accel::build(&scene).unwrap();
        let grid = VoxelGrid::build(&geometry, 0.05, &[DVec3::new(0.5, 0.5, 2.0)]).unwrap();
        let hits = |x: Vec3, n: Vec3| side_hits(&accel, &grid, x, n, 7, 0, SIDE_TEST_RAYS, 1.0);
        let hidden = |x: Vec3, n: Vec3| side_hidden(&accel, &grid, x, n, 7, 0, SIDE_TEST_RAYS, 1.0);
        // The floor's underside sees only the sky: valid, and none of its rays hits.
        assert_eq!(hits(Vec3::new(0.5, 0.5, 0.0), -Vec3::Z), Some((0, 0)));
        assert!(!hidden(Vec3::new(0.5, 0.5, 0.0), -Vec3::Z));
        // The floor's top under the slab sees the slab's outside, front faces only, in the
        // slab's cosine-weighted solid angle: between its inscribed disc's (sin² θ = 0.36) and
        // its circumscribed disc's (0.18 / 0.34 = 0.53), with Sobol' rays' slack.
        let (h, back) = hits(Vec3::new(0.5, 0.5, 0.0), Vec3::Z).unwrap();
        let share = h as f64 / SIDE_TEST_RAYS as f64;
        assert!((0.3..0.6).contains(&share) && back == 0, "{h} hits, {back} back faces");
        assert!(!hidden(Vec3::new(0.5, 0.5, 0.0), Vec3::Z));
        // The slab's inside: its front voxel is sealed, no ray is traced.
        assert_eq!(hits(Vec3::new(0.5, 0.5, 0.6), -Vec3::Z), None);
        assert!(hidden(Vec3::new(0.5, 0.5, 0.6), -Vec3::Z));
        // A side that faces a back face within a voxel (no enclosed front voxel) is hidden by
        // its rays: the inside of a slab thinner than a voxel.
        let thin =
            tracer::scene::shapes::axis_aligned_box("thin", Vec3::new(0.2, 0.2, 0.5), Vec3::new(0.8, 0.8, 0.51), 0);
        let scene = scene_of(vec![thin], Vec3::new(0.5, 0.5, 2.0));
        let geometry = crate::geometry::Geometry::from_scene(&scene).unwrap();
        let accel = Accel::build(&scene).unwrap();
        let grid = VoxelGrid::build(&geometry, 0.05, &[DVec3::new(0.5, 0.5, 2.0)]).unwrap();
        let (h, back) =
            side_hits(&accel, &grid, Vec3::new(0.5, 0.5, 0.51), -Vec3::Z, 3, 0, SIDE_TEST_RAYS, 1.0).unwrap();
        assert!(h > 0 && back == h, "{h} hits, {back} back faces");
        assert!(side_hidden(&accel, &grid, Vec3::new(0.5, 0.5, 0.51), -Vec3::Z, 3, 0, SIDE_TEST_RAYS, 1.0));
    }

    #[test]
    fn receivers_next_to_a_concave_edge_are_not_hidden() {
        // A closed room seen from inside: every inward receiver is valid, also those within a
        // voxel of the adjacent wall (their front voxel is solid, not enclosed).
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE)], Vec3::splat(0.5));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 2000, ..Default::default() }).unwrap();
        let geometry = crate::geometry::Geometry::from_scene(&scene).unwrap();
        let voxel = 0.08;
        let grid = VoxelGrid::build(&geometry, voxel, &[DVec3::splat(0.5)]).unwrap();
        let probes = [DVec3::splat(0.3), DVec3::splat(0.7)];
        let ctx = TransportContext::new(
            &accel,
            &probes,
            2.0,
            1.0,
            TransportSettings { order: 1, directions: 32, ..Default::default() },
        )
        .unwrap();
        let (transports, _) = ctx.all_valid(&surfels, &grid);
        let mut near_edge = 0;
        for (s, t) in surfels.surfels.iter().zip(&transports) {
            let p = s.position + s.normal * 1e-3;
            if !(p.cmpgt(Vec3::ZERO).all() && p.cmplt(Vec3::ONE).all()) {
                continue; // the room's outer side
            }
            // Distance to the nearest wall other than the receiver's own.
            let a = s.normal.abs();
            let own = if a.x >= a.y && a.x >= a.z {
                0
            } else if a.y >= a.z {
                1
            } else {
                2
            };
            let gap = (0..3)
                .filter(|&a| a != own)
                .map(|a| s.position[a].min(1.0 - s.position[a]))
                .fold(f32::INFINITY, f32::min);
            if gap < voxel as f32 {
                near_edge += 1;
                assert_eq!(t.probes, vec![0, 1], "receiver at {} ({gap} from a wall) is hidden", s.position);
            }
            assert!(!t.probes.is_empty(), "inward receiver at {} is hidden", s.position);
        }
        assert!(near_edge > 50, "{near_edge}");
    }

    #[test]
    fn transports_are_the_same_for_any_thread_count_and_bad_settings_are_refused() {
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE)], Vec3::splat(0.5));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 300, ..Default::default() }).unwrap();
        let probes = [DVec3::splat(0.3), DVec3::splat(0.6)];
        let ctx = TransportContext::new(
            &accel,
            &probes,
            0.8,
            1.0,
            TransportSettings { directions: 64, ..Default::default() },
        )
        .unwrap();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| ctx.all(&surfels))
        };
        assert_eq!(run(1), run(2));
        for (settings, field) in [
            (TransportSettings { order: 8, ..Default::default() }, "order:"),
            (TransportSettings { directions: 0, ..Default::default() }, "directions:"),
        ] {
            let err = TransportContext::new(&accel, &probes, 0.8, 1.0, settings).err().unwrap();
            assert!(err.to_string().starts_with(field), "{err}");
        }
        assert!(TransportContext::new(&accel, &probes, f64::NAN, 1.0, TransportSettings::default()).is_err());
    }
}
