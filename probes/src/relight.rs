//! Section 4.2, "Probe Transport": each probe gathers the current sender radiance along a fixed
//! set of relight rays into its SH coefficients λ_i (Eq. 3). The rays are R directions of a
//! spherical Fibonacci set shared by all probes; their hits are traced once, and each hit reads
//! the senders through the image lookup (`lookup`, at most [`MAX_SENDERS`] surfels, weights
//! renormalised). Per frame, λ_ij = (4π / R) Σ_k B(hit_k) Y_j(ω_k): the SH values with the
//! uniform PDF weight folded in are tabulated once (as the paper does).
//!
//! Decisions (design note, "Relight rays"): escaped relight rays read zero radiance (light from
//! the sky straight to a surface is lfr's `direct` layer, and senders lit by the sky carry it
//! already); a relight hit on a lookup hole reads zero, counted.

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use tracer::Accel;

use crate::lookup::{lookup, Found};
use crate::sh::{Basis, MAX_ORDER};
use crate::surfels::Surfels;
use crate::visibility::offset;
use crate::ProbesError;

/// The most surfels one relight hit reads.
pub const MAX_SENDERS: usize = 4;
/// The most relight rays per probe.
pub const MAX_RAYS: u32 = 1 << 20;

/// `count` directions of the spherical Fibonacci set: `z_k = 1 − (2k + 1)/count`, azimuth
/// advancing by the golden angle.
pub fn fibonacci_directions(count: u32) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..count)
        .map(|k| {
            let z = 1.0 - (2.0 * k as f64 + 1.0) / count as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * k as f64;
            DVec3::new(r * phi.cos(), r * phi.sin(), z).as_vec3()
        })
        .collect()
}

/// The share of back-face hits above which a probe is inside geometry (DDGI-style).
pub const INSIDE_BACK_FACES: f32 = 0.25;

/// Which probes are inside geometry: at least [`INSIDE_BACK_FACES`] of the hits of `rays`
/// Fibonacci rays land on back faces (a flood fill through a non-watertight mesh can leave
/// probes there). Returns one flag per probe, `true` = inside.
pub fn probes_inside(accel: &Accel, probes: &[DVec3], rays: u32, scale: f32) -> Vec<bool> {
    let directions = fibonacci_directions(rays.max(1));
    probes
        .par_iter()
        .map(|p| {
            let origin = p.as_vec3();
            let t_min = offset(origin, scale);
            let (mut hits, mut back) = (0u32, 0u32);
            for &d in &directions {
                if let Some(hit) = accel.intersect(origin, d, t_min, f32::INFINITY, 0.0) {
                    hits += 1;
                    back += u32::from(hit.geometric_normal.dot(d) > 0.0);
                }
            }
            hits > 0 && back as f32 >= INSIDE_BACK_FACES * hits as f32
        })
        .collect()
}

/// The precomputed relight rays of every probe.
#[derive(Clone, Debug)]
pub struct RelightTable {
    pub rays: u32,
    pub coefficients: usize,
    /// `sh[k * coefficients + j] = (4π / R) Y_j(ω_k)`.
    pub sh: Vec<f32>,
    /// Per probe and ray, the range of `senders` its hit reads (empty: escaped or a hole).
    pub ranges: Vec<Vec<(u32, u32)>>,
    pub senders: Vec<Vec<(u32, f32)>>,
    /// Relight rays that escaped, and that hit a lookup hole, over all probes.
    pub escaped: u64,
    pub holes: u64,
    /// Per probe: the fraction of its hits on back faces (a probe inside geometry sees mostly
    /// back faces).
    pub back_face_fraction: Vec<f32>,
}

impl RelightTable {
    /// Traces `rays` relight rays from every probe and records the senders their hits read.
    pub fn build(
        accel: &Accel,
        surfels: &Surfels,
        probes: &[DVec3],
        rays: u32,
        order: usize,
        scale: f32,
    ) -> Result<RelightTable, ProbesError> {
        if order > MAX_ORDER {
            return Err(ProbesError::parameter("order", format!("must be at most {MAX_ORDER}, got {order}")));
        }
        let basis = Basis::new(order);
        let nc = basis.len();
        if rays < 4 * nc as u32 || rays > MAX_RAYS {
            return Err(ProbesError::parameter(
                "relight rays",
                format!("must be between 4 (order + 1)² = {} and {MAX_RAYS}, got {rays}", 4 * nc),
            ));
        }
        let directions = fibonacci_directions(rays);
        let weight = 4.0 * std::f32::consts::PI / rays as f32;
        let mut sh = vec![0.0f32; rays as usize * nc];
        for (k, d) in directions.iter().enumerate() {
            basis.eval_into(*d, &mut sh[k * nc..(k + 1) * nc]);
        }
        sh.iter_mut().for_each(|v| *v *= weight);
        type PerProbe = (Vec<(u32, u32)>, Vec<(u32, f32)>, u64, u64, f32);
        let per_probe: Vec<PerProbe> = probes
            .par_iter()
            .map(|p| {
                let origin = p.as_vec3();
                let mut ranges = Vec::with_capacity(rays as usize);
                let mut senders = Vec::new();
                let mut found = Vec::new();
                let (mut escaped, mut holes, mut hits, mut back) = (0u64, 0u64, 0u64, 0u64);
                for &d in &directions {
                    let start = senders.len() as u32;
                    let t_min = offset(origin, scale);
                    if let Some(hit) = accel.intersect(origin, d, t_min, f32::INFINITY, 0.0) {
                        hits += 1;
                        let ng = hit.geometric_normal.normalize_or_zero();
                        if ng.dot(d) > 0.0 {
                            back += 1;
                        }
                        let side = if ng.dot(d) > 0.0 { -ng } else { ng };
                        let y = origin + d * hit.distance;
                        if lookup(surfels, y, side, &mut found) == Found::Hole {
                            holes += 1;
                        } else {
                            found.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
                            found.truncate(MAX_SENDERS);
                            let total: f32 = found.iter().map(|f| f.1).sum();
                            senders.extend(found.iter().map(|&(s, w)| (s, w / total)));
                        }
                    } else {
                        escaped += 1;
                    }
                    ranges.push((start, senders.len() as u32));
                }
                let back_fraction = if hits > 0 { back as f32 / hits as f32 } else { 0.0 };
                (ranges, senders, escaped, holes, back_fraction)
            })
            .collect();
        let mut table = RelightTable {
            rays,
            coefficients: nc,
            sh,
            ranges: Vec::new(),
            senders: Vec::new(),
            escaped: 0,
            holes: 0,
            back_face_fraction: Vec::new(),
        };
        for (ranges, senders, escaped, holes, back) in per_probe {
            table.ranges.push(ranges);
            table.senders.push(senders);
            table.escaped += escaped;
            table.holes += holes;
            table.back_face_fraction.push(back);
        }
        Ok(table)
    }

    /// λ for sender radiance `radiance` (one RGB value per surfel): per probe, `coefficients`
    /// RGB values, probe-major.
    pub fn project(&self, radiance: &[Vec3]) -> Vec<Vec3> {
        let nc = self.coefficients;
        // Per ray its sender radiance, then λ += L_k · (4π/R) Y(ω_k), one channel at a time in
        // f32 over contiguous rows (vectorised; a fixed order, so any thread count gives the
        // same bits; 8000 terms in f32 stay within ~1e-5 relative).
        self.ranges
            .par_iter()
            .zip(&self.senders)
            .flat_map_iter(|(ranges, senders)| {
                let (mut r, mut g, mut b) = (vec![0.0f32; nc], vec![0.0f32; nc], vec![0.0f32; nc]);
                for (k, &(start, end)) in ranges.iter().enumerate() {
                    if start == end {
                        continue;
                    }
                    let mut l = Vec3::ZERO;
                    for &(s, w) in &senders[start as usize..end as usize] {
                        l += radiance[s as usize] * w;
                    }
                    let row = &self.sh[k * nc..(k + 1) * nc];
                    for (acc, c) in [(&mut r, l.x), (&mut g, l.y), (&mut b, l.z)] {
                        if c != 0.0 {
                            acc.iter_mut().zip(row).for_each(|(a, y)| *a += c * y);
                        }
                    }
                }
                (0..nc).map(move |j| Vec3::new(r[j], g[j], b[j]))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::index;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{room, scene_of};
    use tracer::scene::shapes::sphere;

    #[test]
    fn a_probe_forced_inside_a_closed_box_is_found_inside() {
        let boxed = tracer::scene::shapes::axis_aligned_box("box", Vec3::splat(0.2), Vec3::splat(0.5), 0);
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), boxed], Vec3::splat(0.8));
        let accel = Accel::build(&scene).unwrap();
        let probes = [DVec3::splat(0.35), DVec3::splat(0.8), DVec3::new(0.1, 0.9, 0.5)];
        assert_eq!(probes_inside(&accel, &probes, 256, 1.0), vec![true, false, false]);
    }

    #[test]
    fn fibonacci_quadrature_is_nearly_orthonormal() {
        let basis = Basis::new(MAX_ORDER);
        let n = basis.len();
        let dirs = fibonacci_directions(8000);
        let mut gram = vec![0.0f64; n * n];
        for d in &dirs {
            let y = basis.eval(*d);
            for a in 0..n {
                for b in 0..n {
                    gram[a * n + b] += y[a] as f64 * y[b] as f64 * 4.0 * std::f64::consts::PI / 8000.0;
                }
            }
        }
        let worst = (0..n * n).map(|i| (gram[i] - if i / n == i % n { 1.0 } else { 0.0 }).abs()).fold(0.0f64, f64::max);
        assert!(worst < 2e-3, "|G − I| = {worst}");
        assert!(dirs.iter().all(|d| (d.length() - 1.0).abs() < 1e-6));
    }

    #[test]
    fn constant_senders_in_a_closed_room_give_the_constant_coefficient() {
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE)], Vec3::splat(0.5));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 3000, ..Default::default() }).unwrap();
        let probes = [DVec3::new(0.3, 0.4, 0.5), DVec3::new(0.7, 0.6, 0.2)];
        let table = RelightTable::build(&accel, &surfels, &probes, 8000, MAX_ORDER, 1.0).unwrap();
        assert_eq!(table.escaped, 0);
        assert_eq!(table.holes, 0);
        assert!(table.back_face_fraction.iter().all(|&f| f == 0.0));
        let l = Vec3::new(1.0, 0.5, 0.25);
        let lambda = table.project(&vec![l; surfels.surfels.len()]);
        let nc = table.coefficients;
        let c0 = (4.0 * std::f32::consts::PI).sqrt();
        for p in 0..probes.len() {
            assert!((lambda[p * nc] - l * c0).length() < 1e-3, "λ_00 = {}", lambda[p * nc]);
            for j in 1..nc {
                assert!(lambda[p * nc + j].length() < 3e-3, "λ_{j} = {}", lambda[p * nc + j]);
            }
        }
        // Linear in the radiance; zero radiance gives exactly zero.
        let doubled = table.project(&vec![l * 2.0; surfels.surfels.len()]);
        assert!(lambda.iter().zip(&doubled).all(|(a, b)| (*a * 2.0 - *b).length() < 1e-5));
        assert!(table.project(&vec![Vec3::ZERO; surfels.surfels.len()]).iter().all(|v| *v == Vec3::ZERO));
        // Too few rays for the order are refused.
        let err = RelightTable::build(&accel, &surfels, &probes, 255, MAX_ORDER, 1.0).unwrap_err();
        assert!(err.to_string().starts_with("relight rays:"), "{err}");
    }

    #[test]
    fn a_probe_at_a_sphere_centre_recovers_sh_shaped_sender_radiance() {
        let centre = Vec3::new(0.2, 0.1, -0.3);
        let scene = scene_of(vec![sphere("s", centre, 1.0, 5, 0)], centre);
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 20000, ..Default::default() }).unwrap();
        let table = RelightTable::build(&accel, &surfels, &[centre.as_dvec3()], 8000, 3, 2.0).unwrap();
        // Inside, every probe ray hits a back face of the outward sphere.
        assert_eq!(table.back_face_fraction, vec![1.0]);
        let basis = Basis::new(3);
        for (l, m) in [(1usize, 0isize), (2, 2), (3, -1)] {
            let radiance: Vec<Vec3> = surfels
                .surfels
                .iter()
                .map(|s| Vec3::splat(basis.eval((s.position - centre).normalize())[index(l, m)]))
                .collect();
            let lambda = table.project(&radiance);
            for (j, v) in lambda.iter().enumerate() {
                let expected = if j == index(l, m) { 1.0 } else { 0.0 };
                assert!((v.x - expected).abs() < 2e-2, "Y_{l},{m}: λ_{j} = {} (expected {expected})", v.x);
            }
        }
    }
}
