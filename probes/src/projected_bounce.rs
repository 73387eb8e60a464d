//! The bounces in CPCA's projected space: our extension of Section 4.2's feedback loop.
//!
//! One bounce of `frame::indirect` maps the receivers' irradiance E to the next one through
//! sender radiance ρ/π ⊙ (D + E), the probes' SH λ (relight rays, Eq. 3, and the masked fit),
//! the cluster projection p = W λ (Eq. 11) and E' = U p. With the CPCA transport every E it
//! produces is U p for a projected vector p of R = Σ_c rank_c values (about 800 on Cornell
//! against 21k receivers and 29 × 64 probe coefficients), and every step is linear, so without
//! the clamp at zero
//!
//!   p_{k+1} = p_D + M p_k,   M = W · Fit · Project · diag(ρ/π) · U   (R × R, per channel),
//!
//! with p_D the projection of the direct light's radiance alone. [`ProjectedBounce::build`]
//! forms M once per (precompute, CPCA, albedo) — light-independent, so once per run — and a
//! frame then runs one full bounce (the direct light through the relight rays) and the rest as
//! R × R products, expanding to receivers and clamping negative irradiance (SH ringing) at
//! zero once at the end instead of after every bounce: that is the only difference from
//! `frame::indirect`, whose images it matches within float rounding when nothing clamps (test
//! `projected_bounces_equal_the_full_bounces`).
//!
//! Convergence: U's columns are orthonormal within each cluster, so ‖E_{k+1} − E_k‖₂ =
//! ‖p_{k+1} − p_k‖₂ and the loop stops when that, and the tail of bounces it predicts
//! (`frame::converged`), fall under `tolerance` × ‖p_{k+1}‖₂ (an L2 criterion;
//! `frame::indirect` uses the largest change over the largest irradiance).
//!
//! M's columns come from the relight table transposed (which probe rays read each sender), a
//! cluster at a time; each column is computed on its own in a fixed order, so any thread count
//! gives the same bits.

use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::cpca::Cpca;
use crate::frame::{converged, BounceTimes, Indirect};
use crate::near_field::NearField;
use crate::relight::RelightTable;
use crate::ProbesError;

/// M of the module's documentation, one R × R matrix per channel.
#[derive(Clone, Debug, PartialEq)]
pub struct ProjectedBounce {
    /// R: projected values in all clusters.
    pub size: usize,
    /// Each cluster's first projected value.
    offsets: Vec<usize>,
    /// Per channel, row-major R × R.
    m: [Vec<f32>; 3],
}

impl ProjectedBounce {
    /// Forms M for `cpca`, `table` (with its fit, if any) and the senders' `albedo`.
    pub fn build(cpca: &Cpca, table: &RelightTable, albedo: &[Vec3]) -> Result<ProjectedBounce, ProbesError> {
        if albedo.len() != cpca.receivers {
            return Err(ProbesError::parameter(
                "albedo",
                format!("{} values for {} receivers: one per surfel", albedo.len(), cpca.receivers),
            ));
        }
        if let Some(i) = albedo.iter().position(|v| !v.is_finite() || v.min_element() < 0.0) {
            return Err(ProbesError::parameter("albedo", format!("value {i} is negative or not finite")));
        }
        let nc = table.coefficients;
        if nc != cpca.coefficients {
            return Err(ProbesError::parameter(
                "coefficients",
                format!("relight table of {nc} SH coefficients, CPCA of {}", cpca.coefficients),
            ));
        }
        let probes = table.ranges.len();
        let mut offsets = Vec::with_capacity(cpca.clusters.len());
        let mut size = 0;
        for c in &cpca.clusters {
            offsets.push(size);
            size += c.rank;
        }
        // Which relight rays read each sender: (probe, ray, weight).
        let mut reads: Vec<Vec<(u32, u32, f32)>> = vec![Vec::new(); cpca.receivers];
        for (p, (ranges, senders)) in table.ranges.iter().zip(&table.senders).enumerate() {
            for (k, &(start, end)) in ranges.iter().enumerate() {
                for &(s, w) in &senders[start as usize..end as usize] {
                    reads[s as usize].push((p as u32, k as u32, w));
                }
            }
        }
        let inv_pi = 1.0 / std::f64::consts::PI;
        // Per cluster (its columns of M): rank × R values per channel, column-major.
        let columns: Vec<Vec<[f32; 3]>> = cpca
            .clusters
            .par_iter()
            .map(|c| {
                let r = c.rank;
                // Every (probe, ray, local receiver, weight) reading this cluster, grouped by ray.
                let mut touching: Vec<(u32, u32, u32, f32)> = Vec::new();
                for (local, &s) in c.receivers.iter().enumerate() {
                    touching.extend(reads[s as usize].iter().map(|&(p, k, w)| (p, k, local as u32, w)));
                }
                touching.sort_by_key(|a| (a.0, a.1, a.2));
                // λ of each basis vector: probe-major, nc RGB values per probe.
                let mut lambda = vec![DVec3::ZERO; r * probes * nc];
                let mut ray_radiance = vec![DVec3::ZERO; r];
                let mut i = 0;
                while i < touching.len() {
                    let (p, k) = (touching[i].0, touching[i].1);
                    ray_radiance.iter_mut().for_each(|v| *v = DVec3::ZERO);
                    while i < touching.len() && (touching[i].0, touching[i].1) == (p, k) {
                        let (_, _, local, w) = touching[i];
                        let s = c.receivers[local as usize] as usize;
                        let rho = albedo[s].as_dvec3() * inv_pi * w as f64;
                        for (b, v) in ray_radiance.iter_mut().enumerate() {
                            *v += rho * c.u.get(local as usize * r + b) as f64;
                        }
                        i += 1;
                    }
                    let sh = &table.sh[k as usize * nc..(k as usize + 1) * nc];
                    for (b, l) in ray_radiance.iter().enumerate() {
                        let out = &mut lambda[(b * probes + p as usize) * nc..(b * probes + p as usize + 1) * nc];
                        for (o, y) in out.iter_mut().zip(sh) {
                            *o += *l * *y as f64;
                        }
                    }
                }
                if let Some(fit) = &table.fit {
                    let mut fitted = vec![DVec3::ZERO; nc];
                    for b in 0..r {
                        for p in 0..probes {
                            let block = &mut lambda[(b * probes + p) * nc..(b * probes + p + 1) * nc];
                            if block.iter().all(|v| *v == DVec3::ZERO) {
                                continue;
                            }
                            let m = &fit[p * nc * nc..(p + 1) * nc * nc];
                            for (j, out) in fitted.iter_mut().enumerate() {
                                let row = &m[j * nc..(j + 1) * nc];
                                *out =
                                    row.iter().zip(block.iter()).fold(DVec3::ZERO, |acc, (&a, v)| acc + *v * a as f64);
                            }
                            block.copy_from_slice(&fitted);
                        }
                    }
                }
                // M's columns: every cluster's W times each λ.
                let mut out = vec![[0.0f32; 3]; r * size];
                for b in 0..r {
                    let l = &lambda[b * probes * nc..(b + 1) * probes * nc];
                    for (c2, &offset) in cpca.clusters.iter().zip(&offsets) {
                        let m = c2.probes.len() * nc;
                        for k in 0..c2.rank {
                            let mut sum = DVec3::ZERO;
                            for (slot, &p) in c2.probes.iter().enumerate() {
                                let lp = &l[p as usize * nc..(p as usize + 1) * nc];
                                let row = k * m + slot * nc;
                                for (j, v) in lp.iter().enumerate() {
                                    sum += *v * c2.w.get(row + j) as f64;
                                }
                            }
                            out[b * size + offset + k] = sum.as_vec3().to_array();
                        }
                    }
                }
                out
            })
            .collect();
        let mut m = [vec![0.0f32; size * size], vec![0.0f32; size * size], vec![0.0f32; size * size]];
        for (columns, &offset) in columns.iter().zip(&offsets) {
            for (b, column) in columns.chunks(size.max(1)).enumerate() {
                for (row, v) in column.iter().enumerate() {
                    for ch in 0..3 {
                        m[ch][row * size + offset + b] = v[ch];
                    }
                }
            }
        }
        Ok(ProjectedBounce { size, offsets, m })
    }

    /// Bytes held by M.
    pub fn bytes(&self) -> usize {
        3 * self.m[0].len() * 4
    }

    /// p_D + M p: per channel, rows of M against p in f32 (eight lanes, a fixed order: the
    /// same bits whatever the thread count).
    fn step(&self, p_direct: &[DVec3], p: &[DVec3]) -> Vec<DVec3> {
        let n = self.size;
        let channels: [Vec<f32>; 3] = [0, 1, 2].map(|ch| p.iter().map(|v| v[ch] as f32).collect());
        (0..n)
            .into_par_iter()
            .with_min_len(64)
            .map(|row| {
                let acc: [f64; 3] = [0, 1, 2].map(|ch| dot(&self.m[ch][row * n..(row + 1) * n], &channels[ch]) as f64);
                p_direct[row] + DVec3::from_array(acc)
            })
            .collect()
    }

    fn flatten(&self, per_cluster: &[Vec<DVec3>]) -> Vec<DVec3> {
        per_cluster.iter().flatten().copied().collect()
    }

    fn unflatten(&self, cpca: &Cpca, p: &[DVec3]) -> Vec<Vec<DVec3>> {
        cpca.clusters.iter().zip(&self.offsets).map(|(c, &o)| p[o..o + c.rank].to_vec()).collect()
    }

    /// `frame::indirect_timed` with the bounces after the first in projected space (see the
    /// module's documentation): at most `max_iterations` bounces from `start` (zero when
    /// `None`), stopping when the L2 change and its predicted tail fall under `tolerance` of
    /// the L2 norm.
    #[allow(clippy::too_many_arguments)]
    pub fn indirect(
        &self,
        cpca: &Cpca,
        table: &RelightTable,
        albedo: &[Vec3],
        direct: &[Vec3],
        start: Option<&[Vec3]>,
        max_iterations: usize,
        tolerance: f32,
    ) -> Result<(Indirect, BounceTimes), ProbesError> {
        self.indirect_with_near(cpca, None, table, albedo, direct, start, max_iterations, tolerance)
    }

    /// [`ProjectedBounce::indirect`] with the near field (`near_field`) beside CPCA's far
    /// transport: E_k = U p_k + q_k with q_k the near field's gather, exact every bounce
    /// (q_{k+1} = N ρ/π ⊙ (D + E_k)). The far field's next projection is
    /// p_{k+1} = p_D + M p_k + W·Fit·Project·ρ/π ⊙ q_k: the first bounce's near light q_1 goes
    /// through the relight rays once per frame (exact), the rest, q_k − q_1 (the near field of
    /// the indirect light), through M as its least-squares projection onto each cluster's U
    /// (Uᵀ (q_k − q_1), U's columns orthonormal), the one approximation. So the first two
    /// bounces equal the full loop's (but for the clamp), the later ones come close (test
    /// `the_projected_bounces_with_the_near_field_follow_the_full_ones`). `None`: exactly
    /// [`ProjectedBounce::indirect`].
    #[allow(clippy::too_many_arguments)]
    pub fn indirect_with_near(
        &self,
        cpca: &Cpca,
        near: Option<&NearField>,
        table: &RelightTable,
        albedo: &[Vec3],
        direct: &[Vec3],
        start: Option<&[Vec3]>,
        max_iterations: usize,
        tolerance: f32,
    ) -> Result<(Indirect, BounceTimes), ProbesError> {
        let n = cpca.receivers;
        if let Some(near) = near {
            if near.receivers() != n {
                return Err(ProbesError::parameter(
                    "near field",
                    format!("{} receivers' lists for {n} receivers", near.receivers()),
                ));
            }
        }
        if albedo.len() != n || direct.len() != n {
            return Err(ProbesError::parameter(
                "senders",
                format!(
                    "{n} receivers, {} albedos and {} direct values: one each per surfel",
                    albedo.len(),
                    direct.len()
                ),
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
        let mut times = BounceTimes::default();
        let mut out = Indirect { irradiance: vec![Vec3::ZERO; n], iterations: 0, clamped: 0, change: f32::INFINITY };
        if max_iterations == 0 {
            if let Some(start) = start {
                out.irradiance = start.to_vec();
            }
            return Ok((out, times));
        }
        let project = |sum: &dyn Fn(usize) -> Vec3, times: &mut BounceTimes| {
            let t = Instant::now();
            let radiance: Vec<Vec3> = (0..n).map(|i| albedo[i] * sum(i) / std::f32::consts::PI).collect();
            let lambda = table.project(&radiance);
            times.probe_relight_s += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let p = self.flatten(&cpca.project_clusters(&lambda));
            times.cluster_projection_s += t.elapsed().as_secs_f64();
            p
        };
        // The direct light's projection, and the first bounce (from `start` when given).
        let p_direct = project(&|i| direct[i], &mut times);
        let mut p = match start {
            None => p_direct.clone(),
            Some(start) => project(&|i| direct[i] + start[i], &mut times),
        };
        // The near field: its first bounce q_1, exact, and q_1 through the relight rays once.
        let gather_near = |near: &NearField, e: &dyn Fn(usize) -> Vec3, times: &mut BounceTimes| {
            let t = Instant::now();
            let radiance: Vec<Vec3> = (0..n).map(|i| albedo[i] * e(i) / std::f32::consts::PI).collect();
            let mut q = vec![Vec3::ZERO; n];
            near.add_into(&radiance, &mut q);
            times.near_field_s += t.elapsed().as_secs_f64();
            q
        };
        let (q_first, p_constant) = match near {
            None => (Vec::new(), p_direct),
            Some(near) => {
                let q = match start {
                    None => gather_near(near, &|i| direct[i], &mut times),
                    Some(start) => gather_near(near, &|i| direct[i] + start[i], &mut times),
                };
                let through = project(&|i| q[i], &mut times);
                (q, p_direct.iter().zip(&through).map(|(a, b)| *a + *b).collect())
            }
        };
        let mut q = q_first.clone();
        out.iterations = 1;
        let t = Instant::now();
        let norm = |v: &[DVec3]| v.iter().map(|x| x.length_squared()).sum::<f64>().sqrt();
        // The first bounce changed the irradiance by p itself when it started from zero.
        let mut history = if start.is_none() { vec![norm(&p)] } else { Vec::new() };
        while out.iterations < max_iterations {
            let next = match near {
                None => self.step(&p_constant, &p),
                Some(near) => {
                    // p + Uᵀ (q − q_1), then q's next bounce from this one's irradiance.
                    let rest: Vec<Vec3> = q.iter().zip(&q_first).map(|(a, b)| *a - *b).collect();
                    let shifted: Vec<DVec3> =
                        p.iter().zip(self.flatten(&transpose_expand(cpca, &rest))).map(|(a, b)| *a + b).collect();
                    let next = self.step(&p_constant, &shifted);
                    let far = cpca.expand(&self.unflatten(cpca, &p));
                    let e: Vec<Vec3> = far.iter().zip(&q).map(|(a, b)| *a + *b).collect();
                    q = gather_near(near, &|i| direct[i] + e[i], &mut times);
                    next
                }
            };
            let change = norm(&next.iter().zip(&p).map(|(a, b)| *a - *b).collect::<Vec<_>>());
            let size = norm(&next);
            out.change = if size > 0.0 { (change / size) as f32 } else { 0.0 };
            p = next;
            out.iterations += 1;
            history.push(change);
            if converged(out.change, &history, tolerance) {
                break;
            }
        }
        times.projected_bounces_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut e = cpca.expand(&self.unflatten(cpca, &p));
        if near.is_some() {
            e.iter_mut().zip(&q).for_each(|(a, b)| *a += *b);
        }
        out.clamped = e.iter().map(|v| v.to_array().iter().filter(|&&c| c < 0.0).count() as u64).sum();
        out.irradiance = e.into_iter().map(|v| v.max(Vec3::ZERO)).collect();
        times.receiver_irradiance_s += t.elapsed().as_secs_f64();
        Ok((out, times))
    }
}

/// Uᵀ x per cluster: each cluster's projection of the receivers' values `x` onto its U.
fn transpose_expand(cpca: &Cpca, x: &[Vec3]) -> Vec<Vec<DVec3>> {
    cpca.clusters
        .par_iter()
        .map(|c| {
            let mut s = vec![DVec3::ZERO; c.rank];
            for (r, &receiver) in c.receivers.iter().enumerate() {
                let v = x[receiver as usize].as_dvec3();
                for (k, s) in s.iter_mut().enumerate() {
                    *s += v * c.u.get(r * c.rank + k) as f64;
                }
            }
            s
        })
        .collect()
}

/// `a · b` in f32 over eight lanes (vectorised), then the lanes and the tail in order.
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for ((l, x), y) in lanes.iter_mut().zip(x).zip(y) {
            *l += x * y;
        }
    }
    let mut sum: f32 = lanes.iter().sum();
    for (x, y) in ra.iter().zip(rb) {
        sum += x * y;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpca::CpcaSettings;
    use crate::frame::indirect_timed;
    use crate::surfels::{SurfelSettings, Surfels};
    use crate::test_scenes::scene_of;
    use crate::transport::{Transport, TransportContext, TransportSettings};
    use glam::DVec3 as D;
    use tracer::scene::shapes::sphere;
    use tracer::Accel;

    struct Setup {
        transports: Vec<Transport>,
        table: RelightTable,
        surfels: Surfels,
    }

    /// A closed unit sphere with two probes inside (both see every inner point), its relight
    /// table fitted as `lfr compare` fits it (μ = 0.01).
    fn setup() -> Setup {
        let scene = scene_of(vec![sphere("s", Vec3::ZERO, 1.0, 4, 0)], Vec3::ZERO);
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 800, ..Default::default() }).unwrap();
        let probes = [D::ZERO, D::new(0.3, -0.2, 0.1)];
        let settings = TransportSettings { order: 3, directions: 96, ..Default::default() };
        let transports = TransportContext::new(&accel, &probes, 2.0, 2.0, settings).unwrap().all(&surfels);
        let mut table = RelightTable::build(&accel, &surfels, &probes, 2000, 3, 2.0).unwrap();
        table.fit(0.01).unwrap();
        Setup { transports, table, surfels }
    }

    fn inputs(s: &Setup) -> (Vec<Vec3>, Vec<Vec3>) {
        let albedo = s
            .surfels
            .surfels
            .iter()
            .map(|x| Vec3::new(0.5 + 0.3 * x.position.x, 0.6, 0.4 + 0.2 * x.position.z))
            .collect();
        let direct =
            s.surfels.surfels.iter().map(|x| Vec3::new(1.0 + x.position.y, 2.0, 0.5 + x.position.x.abs())).collect();
        (albedo, direct)
    }

    fn worst(a: &[Vec3], b: &[Vec3]) -> f32 {
        let largest = b.iter().map(|v| v.max_element()).fold(0.0f32, f32::max);
        a.iter().zip(b).map(|(x, y)| (*x - *y).abs().max_element()).fold(0.0f32, f32::max) / largest
    }

    #[test]
    fn projected_bounces_equal_the_full_bounces() {
        let s = setup();
        let (albedo, direct) = inputs(&s);
        let positions: Vec<Vec3> = s.surfels.surfels.iter().map(|x| x.position).collect();
        // Full rank in one cluster, and a lossy compression in many small clusters: the same
        // CPCA either way, so the two loops agree whatever its error.
        for settings in [
            CpcaSettings { tolerance: 0.0, ..Default::default() },
            CpcaSettings { cluster_limit: 64, tolerance: 0.02, max_coefficients: 6, ..Default::default() },
        ] {
            let cpca = Cpca::build(&s.transports, &positions, s.table.coefficients, &settings).unwrap();
            let op = ProjectedBounce::build(&cpca, &s.table, &albedo).unwrap();
            assert_eq!(op.size, cpca.clusters.iter().map(|c| c.rank).sum::<usize>());
            for k in [1usize, 2, 5, 12] {
                let (full, _) = indirect_timed(&cpca, &s.table, &albedo, &direct, None, k, 0.0).unwrap();
                let (fast, times) = op.indirect(&cpca, &s.table, &albedo, &direct, None, k, 0.0).unwrap();
                assert_eq!((full.clamped, fast.clamped), (0, 0), "the comparison needs nothing clamped");
                assert_eq!(fast.iterations, k);
                let err = worst(&fast.irradiance, &full.irradiance);
                assert!(err < 1e-4, "{k} bounces, {} clusters: {err}", cpca.clusters.len());
                assert!(times.projected_bounces_s >= 0.0 && times.total_s() > 0.0);
                // From a start (the animation's feedback): the same as the full loop from it.
                let (full2, _) =
                    indirect_timed(&cpca, &s.table, &albedo, &direct, Some(&full.irradiance), 3, 0.0).unwrap();
                let (fast2, _) =
                    op.indirect(&cpca, &s.table, &albedo, &direct, Some(&full.irradiance), 3, 0.0).unwrap();
                let err2 = worst(&fast2.irradiance, &full2.irradiance);
                assert!(err2 < 1e-4, "from a start, {k}: {err2}, clamped {} {}", full2.clamped, fast2.clamped);
            }
            // Converged: the L2 test stops it, and near where the full loop converges.
            let (full, _) = indirect_timed(&cpca, &s.table, &albedo, &direct, None, 400, 1e-6).unwrap();
            let (fast, _) = op.indirect(&cpca, &s.table, &albedo, &direct, None, 400, 1e-6).unwrap();
            assert!(fast.iterations < 400 && fast.change < 1e-6, "{} {}", fast.iterations, fast.change);
            assert!(worst(&fast.irradiance, &full.irradiance) < 1e-4);
        }
    }

    #[test]
    fn any_thread_count_builds_the_same_operator_and_bad_input_is_refused_by_name() {
        let s = setup();
        let (albedo, direct) = inputs(&s);
        let positions: Vec<Vec3> = s.surfels.surfels.iter().map(|x| x.position).collect();
        let settings = CpcaSettings { cluster_limit: 64, tolerance: 0.01, ..Default::default() };
        let cpca = Cpca::build(&s.transports, &positions, s.table.coefficients, &settings).unwrap();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let op = ProjectedBounce::build(&cpca, &s.table, &albedo).unwrap();
                let (out, _) = op.indirect(&cpca, &s.table, &albedo, &direct, None, 6, 0.0).unwrap();
                (op, out.irradiance)
            })
        };
        let (a, ea) = run(1);
        let (b, eb) = run(3);
        assert_eq!(a, b);
        assert_eq!(ea, eb);
        assert!(a.bytes() == 12 * a.size * a.size);
        let err = ProjectedBounce::build(&cpca, &s.table, &albedo[1..]).unwrap_err();
        assert!(err.to_string().starts_with("albedo:"), "{err}");
        let err = a.indirect(&cpca, &s.table, &albedo, &direct[1..], None, 2, 0.0).unwrap_err();
        assert!(err.to_string().starts_with("senders:"), "{err}");
        let err = a.indirect(&cpca, &s.table, &albedo, &direct, Some(&direct[1..]), 2, 0.0).unwrap_err();
        assert!(err.to_string().starts_with("start:"), "{err}");
        // Zero direct light: zero indirect light.
        let zero = vec![Vec3::ZERO; direct.len()];
        let (out, _) = a.indirect(&cpca, &s.table, &albedo, &zero, None, 5, 0.0).unwrap();
        assert!(out.irradiance.iter().all(|v| *v == Vec3::ZERO));
    }
}
