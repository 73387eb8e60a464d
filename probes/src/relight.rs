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

/// The senders a hit at `y` on the side facing `side` reads, into `found`: the lookup's
/// surfels, the [`MAX_SENDERS`] heaviest (ties by index), their weights renormalised to sum 1.
/// `false` (and `found` empty) on a lookup hole.
pub fn read_senders(surfels: &Surfels, y: Vec3, side: Vec3, found: &mut Vec<(u32, f32)>) -> bool {
    if lookup(surfels, y, side, found) == Found::Hole {
        found.clear();
        return false;
    }
    found.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    found.truncate(MAX_SENDERS);
    let total: f32 = found.iter().map(|f| f.1).sum();
    found.iter_mut().for_each(|f| f.1 /= total);
    true
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
    /// The masked fit of [`RelightTable::fit`], when set: per probe an `nc × nc` row-major
    /// matrix applied to the projected coefficients (derived from the rays, never cached).
    pub fit: Option<Vec<f32>>,
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
        shading::progress::begin("traced", probes.len() as u64, "probes");
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
                        if read_senders(surfels, y, side, &mut found) {
                            senders.extend_from_slice(&found);
                        } else {
                            holes += 1;
                        }
                    } else {
                        escaped += 1;
                    }
                    ranges.push((start, senders.len() as u32));
                }
                let back_fraction = if hits > 0 { back as f32 / hits as f32 } else { 0.0 };
                shading::progress::advance(1);
                (ranges, senders, escaped, holes, back_fraction)
            })
            .collect();
        shading::progress::end();
        let mut table = RelightTable {
            rays,
            coefficients: nc,
            sh,
            ranges: Vec::new(),
            senders: Vec::new(),
            escaped: 0,
            holes: 0,
            back_face_fraction: Vec::new(),
            fit: None,
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
            .collect::<Vec<Vec3>>()
            .chunks(nc)
            .zip(0..)
            .flat_map(|(b, p)| match &self.fit {
                None => b.to_vec(),
                Some(fit) => {
                    let m = &fit[p * nc * nc..(p + 1) * nc * nc];
                    (0..nc)
                        .map(|j| m[j * nc..(j + 1) * nc].iter().zip(b).fold(Vec3::ZERO, |acc, (&a, v)| acc + *v * a))
                        .collect()
                }
            })
            .collect()
    }

    /// Drops hidden senders (`valid[s]` false: no transport, as a hidden receiver) from every
    /// relight hit that also reads a valid one, the rest renormalised; a hit that reads only
    /// hidden senders keeps them. Returns the number of (ray, sender) entries dropped.
    ///
    /// Why (docs/probes.md, "Choices beyond the paper"): most hidden surfels lie inside or under
    /// geometry (70 % of Sponza's), where no light reaches them, yet within a lookup's reach of
    /// the visible surface a ray hits; read with their weight they darken every hit near them. On
    /// Sponza, one bounce of sun light gathered at the camera's hits through the senders was 0.62
    /// of the same gather with the direct light evaluated exactly at each hit, 0.87 with hidden
    /// senders dropped (`lfr probes relight --brute-force-rays`). The same rule as the image's
    /// for hidden receivers (`image::render_image`). Applied at run time, like [`Self::fit`]:
    /// the cached table is unchanged.
    pub fn drop_hidden_senders(&mut self, valid: &[bool]) -> Result<u64, ProbesError> {
        if let Some(&(s, _)) = self.senders.iter().flatten().find(|(s, _)| *s as usize >= valid.len()) {
            return Err(ProbesError::parameter(
                "valid",
                format!("{} flags for a table that reads sender {s}", valid.len()),
            ));
        }
        let mut dropped = 0u64;
        for (ranges, senders) in self.ranges.iter_mut().zip(self.senders.iter_mut()) {
            let mut kept: Vec<(u32, f32)> = Vec::with_capacity(senders.len());
            for range in ranges.iter_mut() {
                let read = &senders[range.0 as usize..range.1 as usize];
                let total: f32 = read.iter().filter(|(s, _)| valid[*s as usize]).map(|(_, w)| w).sum();
                let start = kept.len() as u32;
                if total > 0.0 && read.iter().any(|(s, _)| !valid[*s as usize]) {
                    kept.extend(read.iter().filter(|(s, _)| valid[*s as usize]).map(|&(s, w)| (s, w / total)));
                    dropped += (read.len() - (kept.len() - start as usize)) as u64;
                } else {
                    kept.extend_from_slice(read);
                }
                *range = (start, kept.len() as u32);
            }
            *senders = kept;
        }
        Ok(dropped)
    }

    /// Fits each probe's SH to the sender radiance along its rays that read senders, instead of
    /// projecting radiance that is zero along the rays that escape or hit a hole (the paper's
    /// projection, `miss_weight` = 1): λ_i minimises
    /// Σ_hit (L_k − Y(ω_k)·λ)² + μ Σ_miss (Y(ω_k)·λ)² with μ = `miss_weight` ∈ (0, 1], so
    /// λ_i = (G_hit + μ G_miss)⁻¹ b_i with b_i the projection of [`RelightTable::project`] and
    /// G the quadrature Gram matrices (4π/R) Σ Y Yᵀ over either set of rays.
    ///
    /// Why (docs/probes.md): a receiver reads probe i only in directions of surface points the
    /// probe sees, i.e. along its hit rays. A bandlimited projection of radiance that drops to
    /// zero where rays escape (Cornell's open side, Sponza's sky) spreads part of the hit
    /// region's energy into the escape region, where nobody reads it: the reconstruction comes
    /// out dark. In a closed scene G_miss = 0 and the fit is the inverse of the quadrature's
    /// Gram matrix, within 2e-3 of the identity.
    #[allow(clippy::needless_range_loop)]
    pub fn fit(&mut self, miss_weight: f64) -> Result<(), ProbesError> {
        if !(miss_weight > 0.0 && miss_weight <= 1.0) {
            return Err(ProbesError::parameter(
                "relight-miss-weight",
                format!("must be in (0, 1] (1: the paper's projection), got {miss_weight}"),
            ));
        }
        let nc = self.coefficients;
        let rays = self.rays as usize;
        // (4π/R) Y Yᵀ = sh shᵀ · R / 4π.
        let back = rays as f64 / (4.0 * std::f64::consts::PI);
        let gram_of = |rows: &mut dyn Iterator<Item = usize>| {
            let mut g = vec![0.0f64; nc * nc];
            for k in rows {
                let y = &self.sh[k * nc..(k + 1) * nc];
                for a in 0..nc {
                    let ya = y[a] as f64 * back;
                    for b in a..nc {
                        g[a * nc + b] += ya * y[b] as f64;
                    }
                }
            }
            for a in 0..nc {
                for b in 0..a {
                    g[a * nc + b] = g[b * nc + a];
                }
            }
            g
        };
        let full = gram_of(&mut (0..rays));
        let fits: Vec<Result<Vec<f32>, ProbesError>> = self
            .ranges
            .par_iter()
            .enumerate()
            .map(|(p, ranges)| {
                let miss = gram_of(&mut ranges.iter().enumerate().filter(|(_, r)| r.0 == r.1).map(|(k, _)| k));
                let g: Vec<f64> = full.iter().zip(&miss).map(|(f, m)| f - (1.0 - miss_weight) * m).collect();
                let inv = spd_inverse(&g, nc).ok_or_else(|| {
                    ProbesError::parameter("relight-miss-weight", format!("probe {p}: the fit's matrix is singular"))
                })?;
                Ok(inv.iter().map(|&v| v as f32).collect())
            })
            .collect();
        let mut fit = Vec::with_capacity(self.ranges.len() * nc * nc);
        for f in fits {
            fit.extend(f?);
        }
        self.fit = Some(fit);
        Ok(())
    }
}

/// The inverse of a symmetric positive definite `n × n` matrix (row-major) by Cholesky; `None`
/// when it is not positive definite.
#[allow(clippy::needless_range_loop)]
fn spd_inverse(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0f64; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s = a[i * n + j] - (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum::<f64>();
            if i == j {
                if !(s > 0.0) {
                    return None;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    // Solve L Lᵀ X = I column by column.
    let mut inv = vec![0.0f64; n * n];
    let mut y = vec![0.0f64; n];
    for c in 0..n {
        for i in 0..n {
            let rhs = if i == c { 1.0 } else { 0.0 };
            y[i] = (rhs - (0..i).map(|k| l[i * n + k] * y[k]).sum::<f64>()) / l[i * n + i];
        }
        for i in (0..n).rev() {
            let x = (y[i] - (i + 1..n).map(|k| l[k * n + i] * inv[k * n + c]).sum::<f64>()) / l[i * n + i];
            inv[i * n + c] = x;
        }
    }
    Some(inv)
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
    fn hidden_senders_take_no_weight_beside_valid_ones() {
        // Every third surfel made hidden with zero radiance (as a surfel inside geometry reads
        // no light), the others a constant L: after dropping the hidden ones, every hit that
        // reads a valid sender reads exactly L, and λ_00 is L √(4π) as if none were hidden.
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE)], Vec3::splat(0.5));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 3000, ..Default::default() }).unwrap();
        let probes = [DVec3::new(0.3, 0.4, 0.5)];
        let mut table = RelightTable::build(&accel, &surfels, &probes, 4000, 2, 1.0).unwrap();
        let n = surfels.surfels.len();
        let valid: Vec<bool> = (0..n).map(|i| i % 3 != 0).collect();
        let l = Vec3::new(1.0, 0.5, 0.25);
        let radiance: Vec<Vec3> = valid.iter().map(|&v| if v { l } else { Vec3::ZERO }).collect();
        let c0 = (4.0 * std::f32::consts::PI).sqrt();
        let before = table.project(&radiance)[0];
        assert!(before.x < 0.95 * l.x * c0, "the hidden senders darken it: {before}");
        let entries = table.senders[0].len();
        let dropped = table.drop_hidden_senders(&valid).unwrap();
        assert!(dropped > 0 && table.senders[0].len() as u64 + dropped == entries as u64);
        let (mut only_hidden, mut rays) = (0, 0);
        for &(start, end) in &table.ranges[0] {
            let read = &table.senders[0][start as usize..end as usize];
            if read.is_empty() {
                continue;
            }
            rays += 1;
            if read.iter().all(|(s, _)| !valid[*s as usize]) {
                only_hidden += 1;
            } else {
                assert!(read.iter().all(|(s, _)| valid[*s as usize]));
                let sum: f32 = read.iter().map(|(_, w)| w).sum();
                assert!((sum - 1.0).abs() < 1e-5, "{sum}");
            }
        }
        assert!(only_hidden * 50 < rays, "{only_hidden} of {rays} rays read only hidden senders");
        let after = table.project(&radiance)[0];
        assert!(((after - l * c0) / (l * c0)).abs().max_element() < 0.02, "{after} against {}", l * c0);
        // Applied twice, nothing more to drop; a flag list too short is refused by name.
        assert_eq!(table.drop_hidden_senders(&valid).unwrap(), 0);
        let err = table.drop_hidden_senders(&valid[..10]).unwrap_err();
        assert!(err.to_string().starts_with("valid:"), "{err}");
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

    /// The mean over a probe's hit directions of its SH reconstruction of radiance L on a big
    /// floor below it (the sky above escapes).
    fn floor_mean(miss_weight: Option<f64>) -> (f64, f64) {
        let floor = tracer::scene::shapes::polygon(
            "floor",
            &[
                Vec3::new(-40.0, -40.0, 0.0),
                Vec3::new(40.0, -40.0, 0.0),
                Vec3::new(40.0, 40.0, 0.0),
                Vec3::new(-40.0, 40.0, 0.0),
            ],
            0,
        );
        let scene = crate::test_scenes::scene_of(vec![floor], Vec3::new(0.0, 0.0, 1.0));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 3000, ..Default::default() }).unwrap();
        let probe = DVec3::new(0.0, 0.0, 0.5);
        let mut table = RelightTable::build(&accel, &surfels, &[probe], 8000, MAX_ORDER, 80.0).unwrap();
        if let Some(w) = miss_weight {
            table.fit(w).unwrap();
        }
        let lambda = table.project(&vec![Vec3::ONE; surfels.surfels.len()]);
        let basis = Basis::new(MAX_ORDER);
        let (mut sum, mut worst, mut n) = (0.0f64, 0.0f64, 0usize);
        for (k, d) in fibonacci_directions(8000).iter().enumerate() {
            let (start, end) = table.ranges[0][k];
            if start == end {
                continue;
            }
            let y = basis.eval(*d);
            let v: f64 = y.iter().zip(&lambda).map(|(y, l)| *y as f64 * l.x as f64).sum();
            sum += v;
            n += 1;
            // Away from the horizon (more than 30° below it).
            if d.z < -0.5 {
                worst = worst.max((v - 1.0).abs());
            }
        }
        assert!(n > 3800 && n < 4000, "{n} hits");
        (sum / n as f64, worst)
    }

    #[test]
    fn the_masked_fit_keeps_the_radiance_the_projection_spreads_into_the_sky() {
        // Expectation: the order-7 projection of a hemisphere's indicator keeps
        // Σ_{l ≤ 7} c_l² / 2π of it over the hemisphere, c_l = 2π √((2l+1)/4π) ∫_{-1}^0 P_l,
        // by Legendre polynomials here (independent of the SH code).
        let mut kept = 0.0f64;
        for l in 0..=MAX_ORDER {
            // ∫_{-1}^0 P_l by Gauss–Legendre-free midpoint quadrature of the recurrence.
            let m = 20000;
            let mut integral = 0.0;
            for i in 0..m {
                let z = -1.0 + (i as f64 + 0.5) / m as f64;
                let (mut p0, mut p1) = (1.0f64, z);
                let p = if l == 0 {
                    1.0
                } else {
                    for k in 1..l {
                        let p2 = ((2 * k + 1) as f64 * z * p1 - k as f64 * p0) / (k + 1) as f64;
                        p0 = p1;
                        p1 = p2;
                    }
                    p1
                };
                integral += p / m as f64;
            }
            let c = 2.0 * std::f64::consts::PI * ((2 * l + 1) as f64 / (4.0 * std::f64::consts::PI)).sqrt() * integral;
            kept += c * c / (2.0 * std::f64::consts::PI);
        }
        assert!((kept - 0.9626).abs() < 1e-3, "{kept}");
        let (paper, _) = floor_mean(None);
        assert!((paper - kept).abs() < 0.015, "projection keeps {paper}, expected about {kept}");
        let (fitted, worst) = floor_mean(Some(0.01));
        assert!((fitted - 1.0).abs() < 0.01, "the fit keeps {fitted}");
        assert!(worst < 0.03, "the fit is off by {worst} more than 30° below the horizon");
        // A weight of 1 is the paper's projection, up to the quadrature's Gram matrix.
        let (one, _) = floor_mean(Some(1.0));
        assert!((one - paper).abs() < 3e-3, "{one} against {paper}");
        // Out of range.
        let mut table = RelightTable {
            rays: 0,
            coefficients: 1,
            sh: vec![],
            ranges: vec![],
            senders: vec![],
            escaped: 0,
            holes: 0,
            back_face_fraction: vec![],
            fit: None,
        };
        for bad in [0.0, -1.0, 1.5, f64::NAN] {
            let err = table.fit(bad).unwrap_err();
            assert!(err.to_string().starts_with("relight-miss-weight:"), "{err}");
        }
    }

    #[test]
    fn in_a_closed_room_the_fit_changes_nothing() {
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE)], Vec3::splat(0.5));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 3000, ..Default::default() }).unwrap();
        let probes = [DVec3::new(0.3, 0.4, 0.5)];
        let mut table = RelightTable::build(&accel, &surfels, &probes, 8000, MAX_ORDER, 1.0).unwrap();
        let radiance: Vec<Vec3> =
            surfels.surfels.iter().map(|s| Vec3::new(1.0 + s.position.x, 0.5, s.position.z)).collect();
        let plain = table.project(&radiance);
        table.fit(0.01).unwrap();
        let fitted = table.project(&radiance);
        let largest = plain.iter().map(|v| v.abs().max_element()).fold(0.0f32, f32::max);
        let worst = plain.iter().zip(&fitted).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0f32, f32::max);
        assert!(worst < 5e-3 * largest, "{worst} of {largest}");
    }
}
