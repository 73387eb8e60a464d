//! Eq. 11 and Section 4.1, "Compression": clustered PCA of the receivers' transport vectors,
//! and per frame the cluster projection (λ onto each cluster's basis once, then a short dot
//! product per receiver).
//!
//! A cluster's matrix T has one row per receiver and one column per (probe, SH coefficient) of
//! the union of its receivers' covering probes (a probe a receiver does not see is a zero).
//! T ≈ U W with U (receivers × r) orthonormal columns and W = Σ Vᵀ (r × columns), no mean
//! subtracted (Eq. 11 has none). The rank r is the smallest whose relative residual energy
//! ‖T − U W‖²_F / ‖T‖²_F is at most the tolerance τ (design decision 20); a cluster that needs
//! more than `max_coefficients` is split at the median of the longest axis of its receivers'
//! bounding box, as is every cluster of `cluster_limit` receivers or more (the paper's "under
//! 1024").
//!
//! The leading singular vectors come from a randomised range finder with two subspace
//! iterations (deterministic: the test matrix is a hash of the cluster's seed, row and
//! column), then an exact eigen-decomposition (cyclic Jacobi) of the small projected Gram
//! matrix. The residual of the basis found is computed exactly from it, so the threshold holds
//! whatever the range finder's quality; a poorer basis only costs coefficients. Hidden
//! receivers (no transport) belong to no cluster: E = 0. U and W are stored in f32 or fp16.

use glam::{DVec3, Vec3};
use half::f16;
use rayon::prelude::*;
use shading::sampling::{hash_combine, hash_u32, to_unit_float};

use crate::transport::Transport;
use crate::ProbesError;

/// How the transport is compressed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CpcaSettings {
    /// Clusters hold fewer receivers than this.
    pub cluster_limit: usize,
    /// τ: the largest relative residual energy per cluster.
    pub tolerance: f64,
    /// The most coefficients (basis vectors) per cluster.
    pub max_coefficients: usize,
    pub precision: Precision,
}

impl Default for CpcaSettings {
    fn default() -> Self {
        CpcaSettings { cluster_limit: 1024, tolerance: 0.005, max_coefficients: 32, precision: Precision::F32 }
    }
}

impl CpcaSettings {
    pub fn validate(&self) -> Result<(), ProbesError> {
        if !(2..=1 << 16).contains(&self.cluster_limit) {
            return Err(ProbesError::parameter(
                "cluster-limit",
                format!("must be between 2 and 65536, got {}", self.cluster_limit),
            ));
        }
        if !(self.tolerance >= 0.0 && self.tolerance < 1.0) {
            return Err(ProbesError::parameter("tolerance", format!("must be in [0, 1), got {}", self.tolerance)));
        }
        if !(1..=256).contains(&self.max_coefficients) {
            return Err(ProbesError::parameter(
                "coefficients",
                format!("must be between 1 and 256, got {}", self.max_coefficients),
            ));
        }
        Ok(())
    }
}

/// Storage precision of U and W.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    F32,
    F16,
}

/// A matrix's values at the chosen precision.
#[derive(Clone, Debug, PartialEq)]
pub enum Values {
    F32(Vec<f32>),
    F16(Vec<f16>),
}

impl Values {
    fn new(values: &[f64], precision: Precision) -> Values {
        match precision {
            Precision::F32 => Values::F32(values.iter().map(|&v| v as f32).collect()),
            Precision::F16 => Values::F16(values.iter().map(|&v| f16::from_f64(v)).collect()),
        }
    }

    #[inline]
    pub fn get(&self, i: usize) -> f32 {
        match self {
            Values::F32(v) => v[i],
            Values::F16(v) => v[i].to_f32(),
        }
    }

    pub fn len(&self) -> usize {
        match self {
            Values::F32(v) => v.len(),
            Values::F16(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn bytes(&self) -> usize {
        match self {
            Values::F32(v) => v.len() * 4,
            Values::F16(v) => v.len() * 2,
        }
    }
}

/// One cluster: its receivers, the probes they see, and T ≈ U W.
#[derive(Clone, Debug, PartialEq)]
pub struct Cluster {
    /// Surfel indices, increasing.
    pub receivers: Vec<u32>,
    /// The union of their covering probes, increasing.
    pub probes: Vec<u32>,
    pub rank: usize,
    /// receivers × rank, row-major.
    pub u: Values,
    /// rank × (probes × coefficients), row-major.
    pub w: Values,
    /// The relative residual energy of the rank chosen (in f64, before storage rounding).
    pub error: f64,
}

/// The compressed transport of every receiver.
#[derive(Clone, Debug, PartialEq)]
pub struct Cpca {
    pub clusters: Vec<Cluster>,
    /// Receivers (surfels) in all, clustered or not.
    pub receivers: usize,
    pub coefficients: usize,
    pub settings: CpcaSettings,
}

impl Cpca {
    /// Compresses `transports` (one per surfel; `positions` are the surfels') of
    /// `coefficients` SH coefficients per probe.
    pub fn build(
        transports: &[Transport],
        positions: &[Vec3],
        coefficients: usize,
        settings: &CpcaSettings,
    ) -> Result<Cpca, ProbesError> {
        settings.validate()?;
        if positions.len() != transports.len() {
            return Err(ProbesError::parameter(
                "positions",
                format!("{} positions for {} transports", positions.len(), transports.len()),
            ));
        }
        if let Some(i) = transports.iter().position(|t| t.alpha.len() != t.probes.len() * coefficients) {
            return Err(ProbesError::parameter(
                "transport",
                format!("receiver {i} has {} values, not {coefficients} per probe", transports[i].alpha.len()),
            ));
        }
        let all: Vec<u32> =
            (0..transports.len() as u32).filter(|&i| !transports[i as usize].probes.is_empty()).collect();
        let clusters = compress(transports, positions, coefficients, settings, all, 1);
        Ok(Cpca { clusters, receivers: transports.len(), coefficients, settings: *settings })
    }

    /// The receivers' irradiance (unclamped) for probe coefficients `lambda` (probe-major, RGB):
    /// the cluster projection ([`Cpca::project_clusters`]) then every receiver's short dot
    /// product ([`Cpca::expand`]).
    pub fn irradiance(&self, lambda: &[Vec3]) -> Vec<Vec3> {
        self.expand(&self.project_clusters(lambda))
    }

    /// The cluster projection: per cluster, `W λ` over its probes (`rank` RGB values, summed
    /// in f64).
    pub fn project_clusters(&self, lambda: &[Vec3]) -> Vec<Vec<DVec3>> {
        let nc = self.coefficients;
        self.clusters
            .par_iter()
            .map(|c| {
                let m = c.probes.len() * nc;
                let mut projected = vec![DVec3::ZERO; c.rank];
                for (k, out) in projected.iter_mut().enumerate() {
                    let mut sum = DVec3::ZERO;
                    for (slot, &p) in c.probes.iter().enumerate() {
                        let l = &lambda[p as usize * nc..(p as usize + 1) * nc];
                        let row = k * m + slot * nc;
                        for (j, v) in l.iter().enumerate() {
                            sum += v.as_dvec3() * c.w.get(row + j) as f64;
                        }
                    }
                    *out = sum;
                }
                projected
            })
            .collect()
    }

    /// Every receiver's irradiance from the cluster projection `projected` (`U` times it); 0
    /// for receivers in no cluster (hidden).
    pub fn expand(&self, projected: &[Vec<DVec3>]) -> Vec<Vec3> {
        let per_cluster: Vec<Vec<Vec3>> = self
            .clusters
            .par_iter()
            .zip(projected)
            .map(|(c, projected)| {
                (0..c.receivers.len())
                    .map(|r| {
                        let mut e = DVec3::ZERO;
                        for (k, p) in projected.iter().enumerate() {
                            e += *p * c.u.get(r * c.rank + k) as f64;
                        }
                        e.as_vec3()
                    })
                    .collect()
            })
            .collect();
        let mut out = vec![Vec3::ZERO; self.receivers];
        for (c, values) in self.clusters.iter().zip(per_cluster) {
            for (&r, v) in c.receivers.iter().zip(values) {
                out[r as usize] = v;
            }
        }
        out
    }

    /// The decompressed transport row of cluster `c`'s receiver `r` over the cluster's probes.
    pub fn row(&self, c: &Cluster, r: usize) -> Vec<f64> {
        let m = c.probes.len() * self.coefficients;
        (0..m).map(|j| (0..c.rank).map(|k| c.u.get(r * c.rank + k) as f64 * c.w.get(k * m + j) as f64).sum()).collect()
    }

    /// Bytes held: U, W, receiver and probe indices.
    pub fn bytes(&self) -> usize {
        self.clusters.iter().map(|c| c.u.bytes() + c.w.bytes() + 4 * (c.receivers.len() + c.probes.len())).sum()
    }

    /// Receivers in some cluster (not hidden).
    pub fn clustered_receivers(&self) -> usize {
        self.clusters.iter().map(|c| c.receivers.len()).sum()
    }

    pub fn mean_rank(&self) -> f64 {
        let n = self.clustered_receivers().max(1) as f64;
        self.clusters.iter().map(|c| (c.rank * c.receivers.len()) as f64).sum::<f64>() / n
    }
}

/// The dense row of receiver `t` over the probes `probes` (increasing).
fn dense_row(t: &Transport, probes: &[u32], nc: usize, out: &mut [f64]) {
    out.iter_mut().for_each(|v| *v = 0.0);
    let mut slot = 0;
    for (k, &p) in t.probes.iter().enumerate() {
        while probes[slot] != p {
            slot += 1;
        }
        for j in 0..nc {
            out[slot * nc + j] = t.alpha[k * nc + j] as f64;
        }
    }
}

/// Clusters `members` recursively; `id` numbers the cluster (its range finder's seed).
fn compress(
    transports: &[Transport],
    positions: &[Vec3],
    nc: usize,
    settings: &CpcaSettings,
    members: Vec<u32>,
    id: u64,
) -> Vec<Cluster> {
    if members.is_empty() {
        return Vec::new();
    }
    let split = |mut members: Vec<u32>| -> Vec<Cluster> {
        let (lo, hi) = members.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &i| {
            (lo.min(positions[i as usize]), hi.max(positions[i as usize]))
        });
        let e = hi - lo;
        let axis = if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        };
        members.sort_by(|&a, &b| positions[a as usize][axis].total_cmp(&positions[b as usize][axis]).then(a.cmp(&b)));
        let right = members.split_off(members.len() / 2);
        let mut left = members;
        left.sort_unstable();
        let mut right = right;
        right.sort_unstable();
        let (a, b) = rayon::join(
            || compress(transports, positions, nc, settings, left, 2 * id),
            || compress(transports, positions, nc, settings, right, 2 * id + 1),
        );
        a.into_iter().chain(b).collect()
    };
    if members.len() >= settings.cluster_limit {
        return split(members);
    }
    let mut probes: Vec<u32> = members.iter().flat_map(|&i| transports[i as usize].probes.iter().copied()).collect();
    probes.sort_unstable();
    probes.dedup();
    let (n, m) = (members.len(), probes.len() * nc);
    let mut t = vec![0.0f64; n * m];
    for (r, &i) in members.iter().enumerate() {
        dense_row(&transports[i as usize], &probes, nc, &mut t[r * m..(r + 1) * m]);
    }
    let total: f64 = t.iter().map(|v| v * v).sum();
    let limit = settings.max_coefficients.min(n).min(m);
    let basis = leading_basis(&t, n, m, limit, id);
    // Smallest rank within the tolerance.
    let mut kept = 0.0;
    let mut rank = None;
    for r in 0..=basis.values.len() {
        if total - kept <= settings.tolerance * total {
            rank = Some(r);
            break;
        }
        if r < basis.values.len() {
            kept += basis.values[r];
        }
    }
    let rank = match rank {
        Some(r) => r,
        // Not within the tolerance at the coefficient limit: split while that can help.
        None if n > settings.max_coefficients => return split(members),
        // Full rank of a small cluster: exact but for rounding.
        None => basis.values.len(),
    };
    let kept: f64 = basis.values[..rank].iter().sum();
    let error = if total > 0.0 { ((total - kept) / total).max(0.0) } else { 0.0 };
    let u: Vec<f64> = (0..n).flat_map(|row| (0..rank).map(move |k| (row, k))).map(|(row, k)| basis.u[k][row]).collect();
    let w: Vec<f64> = basis.w[..rank].iter().flatten().copied().collect();
    vec![Cluster {
        receivers: members,
        probes,
        rank,
        u: Values::new(&u, settings.precision),
        w: Values::new(&w, settings.precision),
        error,
    }]
}

/// The leading left singular vectors `u` (columns, each of length n), the matching rows
/// `w = σ vᵀ` (length m) and the squared singular values, largest first, of the n × m matrix
/// `t` (row-major), at most `limit` of them.
struct Basis {
    u: Vec<Vec<f64>>,
    w: Vec<Vec<f64>>,
    values: Vec<f64>,
}

fn leading_basis(t: &[f64], n: usize, m: usize, limit: usize, seed: u64) -> Basis {
    if limit == 0 {
        return Basis { u: Vec::new(), w: Vec::new(), values: Vec::new() };
    }
    // The range finder's width: the limit plus oversampling, at most the smaller side.
    let l = (limit + 8).min(n).min(m);
    let seed32 = hash_u32((seed as u32) ^ hash_u32((seed >> 32) as u32 ^ 0x5bd1_e995));
    // Y = T Ω (n × l), Ω uniform in [−1, 1].
    let omega: Vec<f64> =
        (0..m * l).map(|k| 2.0 * to_unit_float(hash_combine(seed32, k as u32)) as f64 - 1.0).collect();
    let times = |a: &[f64], b: &[f64], cols: usize| -> Vec<Vec<f64>> {
        // T (n × m) times B (m × cols, row-major) → columns of length n.
        let mut out = vec![vec![0.0; n]; cols];
        for r in 0..n {
            let row = &a[r * m..(r + 1) * m];
            for (j, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    let b_row = &b[j * cols..(j + 1) * cols];
                    for (c, bv) in b_row.iter().enumerate() {
                        out[c][r] += v * bv;
                    }
                }
            }
        }
        out
    };
    let transpose_times = |q: &[Vec<f64>]| -> Vec<f64> {
        // Tᵀ Q (m × cols, row-major).
        let cols = q.len();
        let mut out = vec![0.0; m * cols];
        for r in 0..n {
            let row = &t[r * m..(r + 1) * m];
            for (j, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    for c in 0..cols {
                        out[j * cols + c] += v * q[c][r];
                    }
                }
            }
        }
        out
    };
    let mut q = times(t, &omega, l);
    orthonormalise(&mut q);
    for _ in 0..2 {
        let z = transpose_times(&q);
        // Orthonormalise the columns of Z (m × l) too, for stability.
        let mut zc: Vec<Vec<f64>> = (0..l).map(|c| (0..m).map(|j| z[j * l + c]).collect()).collect();
        orthonormalise(&mut zc);
        let zr: Vec<f64> = (0..m).flat_map(|j| zc.iter().map(move |col| col[j])).collect();
        q = times(t, &zr, l);
        orthonormalise(&mut q);
    }
    // B = Qᵀ T (l × m), its Gram matrix B Bᵀ (l × l) = U_b Λ U_bᵀ.
    let bt = transpose_times(&q); // m × l: Bᵀ
    let mut gram = vec![0.0; l * l];
    for j in 0..m {
        let row = &bt[j * l..(j + 1) * l];
        for a in 0..l {
            for b in a..l {
                gram[a * l + b] += row[a] * row[b];
            }
        }
    }
    for a in 0..l {
        for b in 0..a {
            gram[a * l + b] = gram[b * l + a];
        }
    }
    let (values, vectors) = symmetric_eigen(&gram, l);
    let count = limit.min(l);
    let mut u = Vec::with_capacity(count);
    let mut w = Vec::with_capacity(count);
    for k in 0..count {
        let ub: Vec<f64> = (0..l).map(|a| vectors[a * l + k]).collect();
        u.push((0..n).map(|r| (0..l).map(|a| q[a][r] * ub[a]).sum()).collect());
        w.push((0..m).map(|j| (0..l).map(|a| bt[j * l + a] * ub[a]).sum()).collect());
    }
    Basis { u, w, values: values[..count].iter().map(|&v| v.max(0.0)).collect() }
}

/// Modified Gram–Schmidt, twice; a column that vanishes (rank deficiency) becomes zero.
fn orthonormalise(cols: &mut [Vec<f64>]) {
    for c in 0..cols.len() {
        let original: f64 = cols[c].iter().map(|v| v * v).sum::<f64>().sqrt();
        for _ in 0..2 {
            for p in 0..c {
                let (done, rest) = cols.split_at_mut(c);
                let dot: f64 = done[p].iter().zip(&rest[0]).map(|(a, b)| a * b).sum();
                rest[0].iter_mut().zip(&done[p]).for_each(|(v, q)| *v -= dot * q);
            }
        }
        let norm: f64 = cols[c].iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 1e-10 * original && norm > 0.0 {
            cols[c].iter_mut().for_each(|v| *v /= norm);
        } else {
            cols[c].iter_mut().for_each(|v| *v = 0.0);
        }
    }
}

/// Eigenvalues (descending) and eigenvectors (columns of the row-major l × l result) of the
/// symmetric `a`, by cyclic Jacobi rotations.
fn symmetric_eigen(a: &[f64], l: usize) -> (Vec<f64>, Vec<f64>) {
    let mut a = a.to_vec();
    let mut v = vec![0.0; l * l];
    (0..l).for_each(|i| v[i * l + i] = 1.0);
    let norm: f64 = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    for _ in 0..100 {
        let off: f64 = (0..l)
            .flat_map(|p| (0..l).filter(move |&q| q != p).map(move |q| (p, q)))
            .map(|(p, q)| a[p * l + q].powi(2))
            .sum();
        if off.sqrt() <= 1e-15 * norm || norm == 0.0 {
            break;
        }
        for p in 0..l {
            for q in p + 1..l {
                let apq = a[p * l + q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q * l + q] - a[p * l + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..l {
                    let (akp, akq) = (a[k * l + p], a[k * l + q]);
                    a[k * l + p] = c * akp - s * akq;
                    a[k * l + q] = s * akp + c * akq;
                }
                for k in 0..l {
                    let (apk, aqk) = (a[p * l + k], a[q * l + k]);
                    a[p * l + k] = c * apk - s * aqk;
                    a[q * l + k] = s * apk + c * aqk;
                }
                for k in 0..l {
                    let (vkp, vkq) = (v[k * l + p], v[k * l + q]);
                    v[k * l + p] = c * vkp - s * vkq;
                    v[k * l + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..l).collect();
    order.sort_by(|&x, &y| a[y * l + y].total_cmp(&a[x * l + x]).then(x.cmp(&y)));
    let values = order.iter().map(|&k| a[k * l + k]).collect();
    let mut vectors = vec![0.0; l * l];
    for (new, &old) in order.iter().enumerate() {
        for r in 0..l {
            vectors[r * l + new] = v[r * l + old];
        }
    }
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::ReceiverTransport;
    use crate::placement::PlacementSettings;
    use crate::precompute::{Precompute, PrecomputeSettings};
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{room, scene_of};
    use crate::transport::TransportSettings;

    fn precompute(budget: usize, order: usize) -> Precompute {
        let block = tracer::scene::shapes::axis_aligned_box("block", Vec3::splat(0.3), Vec3::splat(0.6), 0);
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), block], Vec3::splat(0.15));
        let settings = PrecomputeSettings {
            surfels: SurfelSettings { budget, ..Default::default() },
            placement: PlacementSettings { probes: 8, overlap: 4.0, ..Default::default() },
            transport: TransportSettings { order, directions: 48, ..Default::default() },
            relight_rays: 400,
        };
        Precompute::build(&scene, &settings, &mut |_| {}).unwrap()
    }

    fn positions(pre: &Precompute) -> Vec<Vec3> {
        pre.surfels.surfels.iter().map(|s| s.position).collect()
    }

    /// λ with a fixed pseudo-random value per probe coefficient and channel.
    fn some_lambda(probes: usize, nc: usize) -> Vec<Vec3> {
        (0..(probes * nc) as u32)
            .map(|k| {
                let f = |c: u32| 2.0 * to_unit_float(hash_combine(k, c)) - 1.0;
                Vec3::new(f(1), f(2), f(3))
            })
            .collect()
    }

    /// Relative residual energy of each cluster against the dense transports, the slot of each
    /// probe found by search (independent of `dense_row`).
    fn measured_errors(cpca: &Cpca, transports: &[Transport]) -> Vec<f64> {
        let nc = cpca.coefficients;
        cpca.clusters
            .iter()
            .map(|c| {
                let (mut diff, mut total) = (0.0f64, 0.0f64);
                for (r, &i) in c.receivers.iter().enumerate() {
                    let t = &transports[i as usize];
                    let row = cpca.row(c, r);
                    for (slot, p) in c.probes.iter().enumerate() {
                        let own = t.probes.iter().position(|q| q == p);
                        for j in 0..nc {
                            let truth = own.map_or(0.0, |k| t.alpha[k * nc + j] as f64);
                            diff += (row[slot * nc + j] - truth).powi(2);
                            total += truth * truth;
                        }
                    }
                }
                if total > 0.0 {
                    diff / total
                } else {
                    diff
                }
            })
            .collect()
    }

    #[test]
    fn cpca_at_full_rank_equals_the_dense_operator() {
        let pre = precompute(500, 2);
        let nc = pre.coefficients();
        let settings = CpcaSettings { cluster_limit: 24, tolerance: 0.0, max_coefficients: 64, ..Default::default() };
        let cpca = Cpca::build(&pre.transports, &positions(&pre), nc, &settings).unwrap();
        assert!(cpca.clusters.len() > 10);
        assert!(cpca.clusters.iter().all(|c| c.receivers.len() < 24));
        assert!(measured_errors(&cpca, &pre.transports).iter().all(|&e| e < 1e-10), "full rank is not exact");
        let lambda = some_lambda(pre.probes.len(), nc);
        let dense = pre.transports.gather(&lambda, nc);
        let compressed = cpca.irradiance(&lambda);
        let largest = dense.iter().map(|e| e.abs().max_element()).fold(0.0f32, f32::max);
        assert!(largest > 0.0);
        for (d, c) in dense.iter().zip(&compressed) {
            assert!((*d - *c).abs().max_element() <= 1e-5 * largest, "{d} against {c}");
        }
        // Hidden receivers are in no cluster and get zero.
        let hidden: Vec<usize> = (0..pre.transports.len()).filter(|&i| pre.transports[i].probes.is_empty()).collect();
        assert_eq!(cpca.clustered_receivers() + hidden.len(), pre.transports.len());
        assert!(hidden.iter().all(|&i| compressed[i] == Vec3::ZERO));
    }

    #[test]
    fn the_reconstruction_error_stays_under_the_threshold_in_every_cluster() {
        let pre = precompute(1500, 2);
        let nc = pre.coefficients();
        let tau = 0.005;
        for (precision, slack) in [(Precision::F32, 1e-6), (Precision::F16, 1e-4)] {
            let settings = CpcaSettings { cluster_limit: 256, tolerance: tau, max_coefficients: 8, precision };
            let cpca = Cpca::build(&pre.transports, &positions(&pre), nc, &settings).unwrap();
            let errors = measured_errors(&cpca, &pre.transports);
            for (c, e) in cpca.clusters.iter().zip(&errors) {
                assert!(c.receivers.len() < 256 && c.rank <= 8);
                assert!(c.error <= tau, "claimed {}", c.error);
                assert!(
                    *e <= tau + slack,
                    "{precision:?}: cluster of {} at rank {}: error {e}",
                    c.receivers.len(),
                    c.rank
                );
            }
            // Every visible receiver in exactly one cluster.
            let mut seen = vec![0u8; pre.transports.len()];
            cpca.clusters.iter().flat_map(|c| &c.receivers).for_each(|&r| seen[r as usize] += 1);
            for (i, t) in pre.transports.iter().enumerate() {
                assert_eq!(seen[i], u8::from(!t.probes.is_empty()), "receiver {i}");
            }
            // Compression: fewer coefficients than the dense operator.
            assert!(cpca.mean_rank() <= 8.0);
        }
    }

    #[test]
    fn a_rank_three_operator_is_found_to_be_rank_three() {
        // Synthetic transports: every receiver sees probes 0..4 (order 1), its row a mix of three
        // fixed rows with weights from its position.
        let nc = 4;
        let basis: Vec<Vec<f32>> =
            (0..3).map(|k| (0..16).map(|j| (((k * 16 + j) * 7919) % 23) as f32 / 23.0 - 0.4).collect()).collect();
        let positions: Vec<Vec3> = (0..300).map(|i| Vec3::new(i as f32 * 0.01, (i % 7) as f32, 0.0)).collect();
        let transports: Vec<Transport> = positions
            .iter()
            .map(|p| {
                let a = [1.0 + p.x, p.y - 3.0, 0.5 * p.x * p.x];
                let alpha = (0..16).map(|j| (0..3).map(|k| a[k] * basis[k][j]).sum()).collect();
                Transport { probes: vec![0, 1, 2, 3], alpha, hits: 1, unseen: 0, escaped: 0, back_faces: 0 }
            })
            .collect();
        let settings = CpcaSettings { cluster_limit: 128, tolerance: 1e-9, ..Default::default() };
        let cpca = Cpca::build(&transports, &positions, nc, &settings).unwrap();
        assert!(cpca.clusters.len() >= 3);
        assert!(
            cpca.clusters.iter().all(|c| c.rank == 3),
            "{:?}",
            cpca.clusters.iter().map(|c| c.rank).collect::<Vec<_>>()
        );
        assert!(measured_errors(&cpca, &transports).iter().all(|&e| e < 1e-9));
        // The same clusters and values for any thread count.
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| Cpca::build(&transports, &positions, nc, &settings).unwrap());
        assert_eq!(one, cpca);
    }

    #[test]
    fn bad_settings_and_inputs_are_refused_by_name() {
        let t = vec![Transport::empty()];
        let p = vec![Vec3::ZERO];
        for (settings, field) in [
            (CpcaSettings { cluster_limit: 1, ..Default::default() }, "cluster-limit:"),
            (CpcaSettings { tolerance: f64::NAN, ..Default::default() }, "tolerance:"),
            (CpcaSettings { tolerance: 1.0, ..Default::default() }, "tolerance:"),
            (CpcaSettings { max_coefficients: 0, ..Default::default() }, "coefficients:"),
        ] {
            let err = Cpca::build(&t, &p, 4, &settings).unwrap_err();
            assert!(err.to_string().starts_with(field), "{err}");
        }
        assert!(Cpca::build(&t, &[], 4, &CpcaSettings::default()).unwrap_err().to_string().starts_with("positions:"));
        let bad = vec![Transport { probes: vec![0], alpha: vec![1.0; 3], ..Transport::empty() }];
        assert!(Cpca::build(&bad, &p, 4, &CpcaSettings::default()).unwrap_err().to_string().starts_with("transport:"));
        // No visible receiver: no cluster, zero irradiance.
        let cpca = Cpca::build(&t, &p, 4, &CpcaSettings::default()).unwrap();
        assert!(cpca.clusters.is_empty());
        assert_eq!(cpca.irradiance(&[Vec3::ONE; 4]), vec![Vec3::ZERO]);
    }
}
