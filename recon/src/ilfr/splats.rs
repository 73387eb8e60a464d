//! Splat sizing, paper Section 2.2 (design: docs/ilfr-design.md §2–3).
//!
//! Each secondary hit h_i becomes a disc on its tangent plane whose radius adapts to the local
//! sampling rate in space and angle: r_i is the Euclidean distance to the k-th nearest other
//! hit, nearest under the metric that counts offsets along the query's normal α times
//! (`neighbours::metric_distance_squared`), counting only samples j whose direction lies in the
//! query's von Mises-Fisher lobe, A_i(ω_j) = exp(κ_i(ω_i·ω_j − 1)) ≥ τ (Eq. 2).
//!
//! What the paper leaves open, as in the design note: k counts *other* samples; only the
//! M = `max_candidates` nearest others are examined; if fewer than k of them are in the lobe at
//! τ = 0.5, τ is lowered by ×0.75 down to 0.01 (the authors' code does the same after a work
//! budget); after that the radius is the farthest qualifying one found ([`SplatStatus::Partial`]),
//! else the k-th neighbour ignoring direction ([`SplatStatus::DirectionBlind`]), else — no other
//! hit farther than ε at all — the median radius of the others ([`SplatStatus::Isolated`]).
//! Hits within ε = 1e-6 × the bounding-box diagonal count as coincident and are never
//! neighbours, so no radius is zero.
//!
//! Each radius is a pure function of the input (the walk's order is (distance, index)), so the
//! result is bit-identical for any number of threads and equal to the brute-force definition.

use rayon::prelude::*;

use super::neighbours::{KdTree, MetricQuery, WalkScratch};
use crate::error::Error;
use crate::vector::sub;

/// The parameters of splat sizing; `Default` is the paper's (k = 12, α = 3, τ = 0.5) with the
/// authors' relaxation (×0.75 down to 0.01, after 1000 candidates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplatParams {
    /// The neighbour whose distance is the radius (other samples, the sample itself not counted).
    pub k: usize,
    /// How many times an offset along the query's normal counts (≥ 1).
    pub alpha: f32,
    /// The lobe threshold τ: a neighbour counts when A_i(ω_j) ≥ τ.
    pub lobe_threshold: f32,
    /// τ is multiplied by this while fewer than k neighbours qualify …
    pub relax_factor: f32,
    /// … as long as it stays at or above this.
    pub min_lobe_threshold: f32,
    /// How many nearest others are examined at most.
    pub max_candidates: usize,
}

impl Default for SplatParams {
    fn default() -> Self {
        SplatParams {
            k: 12,
            alpha: 3.0,
            lobe_threshold: 0.5,
            relax_factor: 0.75,
            min_lobe_threshold: 0.01,
            max_candidates: 1000,
        }
    }
}

impl SplatParams {
    fn validate(&self) -> Result<(), Error> {
        if self.k == 0 {
            return Err(Error::parameter("k", "splat sizing: k must be at least 1"));
        }
        if !(self.alpha.is_finite() && self.alpha >= 1.0) {
            return Err(Error::parameter(
                "alpha",
                format!("splat sizing: α must be finite and at least 1, got {}", self.alpha),
            ));
        }
        if !(self.lobe_threshold > 0.0 && self.lobe_threshold <= 1.0) {
            let message = format!("splat sizing: the lobe threshold must be in (0, 1], got {}", self.lobe_threshold);
            return Err(Error::parameter("lobe_threshold", message));
        }
        if !(self.relax_factor > 0.0 && self.relax_factor < 1.0) {
            let message = format!("splat sizing: the relaxation factor must be in (0, 1), got {}", self.relax_factor);
            return Err(Error::parameter("relax_factor", message));
        }
        if !(self.min_lobe_threshold > 0.0 && self.min_lobe_threshold <= self.lobe_threshold) {
            let message = format!(
                "splat sizing: the smallest lobe threshold must be in (0, {}], got {}",
                self.lobe_threshold, self.min_lobe_threshold
            );
            return Err(Error::parameter("min_lobe_threshold", message));
        }
        if self.max_candidates < self.k {
            let message = format!("splat sizing: max_candidates ({}) below k ({})", self.max_candidates, self.k);
            return Err(Error::parameter("max_candidates", message));
        }
        Ok(())
    }

    /// ln τ for the thresholds tried, in order: τ, τ·f, τ·f², … while ≥ the smallest.
    fn log_thresholds(&self) -> Vec<f32> {
        let mut out = Vec::new();
        let mut tau = self.lobe_threshold as f64;
        while tau >= self.min_lobe_threshold as f64 && out.len() < 256 {
            out.push(tau.ln() as f32);
            tau *= self.relax_factor as f64;
        }
        out
    }
}

/// The input of splat sizing: one entry per secondary hit.
#[derive(Clone, Copy, Debug)]
pub struct SplatPoints<'a> {
    /// h_i, world space.
    pub position: &'a [[f32; 3]],
    /// Unit normal at h_i.
    pub normal: &'a [[f32; 3]],
    /// ω_i, unit: the direction of the secondary ray.
    pub direction: &'a [[f32; 3]],
    /// κ_i ≥ 0; `None` means 0 for all (a diffuse file).
    pub kappa: Option<&'a [f32]>,
}

impl<'a> SplatPoints<'a> {
    fn len(&self) -> usize {
        self.position.len()
    }

    fn kappa(&self, i: usize) -> f32 {
        self.kappa.map_or(0.0, |k| k[i])
    }

    /// Checks the fields have one entry per hit and every value is finite (what the kd-tree of
    /// the positions assumes).
    pub fn validate(&self) -> Result<(), Error> {
        let n = self.len();
        if self.normal.len() != n || self.direction.len() != n || self.kappa.is_some_and(|k| k.len() != n) {
            return Err(Error::size_mismatch(
                "splat points",
                "splat sizing: position, normal, direction and κ differ in length",
            ));
        }
        for i in 0..n {
            if !self.position[i].iter().all(|c| c.is_finite()) {
                let message = format!("splat sizing: the position of hit {i} is not finite: {:?}", self.position[i]);
                return Err(Error::parameter("points", message));
            }
            for (name, v) in [("normal", self.normal[i]), ("direction", self.direction[i])] {
                let length_squared = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
                if !(length_squared.is_finite() && (length_squared - 1.0).abs() <= 1e-3) {
                    let message = format!("splat sizing: the {name} of hit {i} is not a unit vector: {v:?}");
                    return Err(Error::parameter("points", message));
                }
            }
            let kappa = self.kappa(i);
            if !(kappa.is_finite() && kappa >= 0.0) {
                let message = format!("splat sizing: κ of hit {i} is {kappa}, not finite and ≥ 0");
                return Err(Error::parameter("points", message));
            }
        }
        Ok(())
    }
}

/// The secondary hits of a sample file, in owned copies: what [`GatheredPoints::points`] lends
/// to the sizing.
#[derive(Clone, Debug, Default)]
pub struct GatheredPoints {
    pub position: Vec<[f32; 3]>,
    pub normal: Vec<[f32; 3]>,
    pub direction: Vec<[f32; 3]>,
    pub kappa: Option<Vec<f32>>,
    /// The displacement of each hit over the shutter (moving `lens-time` input only).
    pub motion: Option<Vec<[f32; 3]>>,
    /// The sample index (in the file) of each hit.
    pub sample_index: Vec<u32>,
}

impl GatheredPoints {
    /// The secondary hits of `samples` (their indices are `samples.hits()`); moving hits where
    /// they are at time 0.5, so that the samples of one moving surface, taken at different
    /// times, are sized together.
    pub fn from_samples(samples: &super::samples::IndirectSamples) -> GatheredPoints {
        let hits = samples.hits();
        let pick = |v: &[[f32; 3]]| hits.iter().map(|&i| v[i as usize]).collect::<Vec<_>>();
        GatheredPoints {
            position: hits.iter().map(|&i| samples.secondary_hit_at_middle(i as usize)).collect(),
            normal: pick(&samples.secondary_normal),
            direction: pick(&samples.direction),
            kappa: samples.kappa.as_ref().map(|k| hits.iter().map(|&i| k[i as usize]).collect()),
            motion: samples.secondary_motion.as_deref().map(pick),
            sample_index: hits,
        }
    }

    /// The points for the sizing, borrowed.
    pub fn points(&self) -> SplatPoints<'_> {
        SplatPoints {
            position: &self.position,
            normal: &self.normal,
            direction: &self.direction,
            kappa: self.kappa.as_deref(),
        }
    }
}

/// How a radius was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplatStatus {
    /// The k-th neighbour in the lobe at threshold τ·f^level.
    Lobe(u8),
    /// Fewer than k in the lobe even at the smallest τ: the farthest that was.
    Partial,
    /// None in the lobe: the k-th (or last found) neighbour ignoring direction.
    DirectionBlind,
    /// No other hit farther than ε: the median radius of the others.
    Isolated,
}

/// Counts for reports.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SplatStats {
    /// Radii found in the lobe, per relaxation level (index 0: τ = 0.5).
    pub lobe: Vec<usize>,
    pub partial: usize,
    pub direction_blind: usize,
    pub isolated: usize,
    /// Neighbours examined, over all hits.
    pub candidates: u64,
    /// The radius given to isolated hits.
    pub isolated_radius: f32,
    /// Hits closer than this are coincident.
    pub coincidence_epsilon: f32,
}

/// Radii and how each was found, one per hit.
#[derive(Clone, Debug)]
pub struct Splats {
    pub radius: Vec<f32>,
    pub status: Vec<SplatStatus>,
    pub stats: SplatStats,
}

/// Sizes every splat (paper Section 2.2) in parallel; see the module documentation.
pub fn size_splats(points: &SplatPoints, params: &SplatParams) -> Result<Splats, Error> {
    points.validate()?;
    size_splats_in(&KdTree::build(points.position), points, params)
}

/// [`size_splats`] with the kd-tree of `points.position` built by the caller (who also needs
/// it for the robust radiance, [`super::robust::robust_radiance_in`]); `tree` must hold
/// exactly those positions.
pub fn size_splats_in(tree: &KdTree, points: &SplatPoints, params: &SplatParams) -> Result<Splats, Error> {
    Ok(size_splats_with_juries(tree, points, params, None)?.0)
}

/// Who sits on each splat's jury (the robust radiance's, [`super::robust`]): its first `size`
/// neighbours in the walk's order (metric distance, index) whose direction lies in its lobe at
/// `lobe_threshold`, A_i(ω_j) ≥ τ, coincident hits included, among the first `max_candidates`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JuryRule {
    pub size: usize,
    pub lobe_threshold: f32,
    pub max_candidates: usize,
}

/// Each splat's jury ([`JuryRule`]), found by the sizing's own walk.
#[derive(Clone, Debug, PartialEq)]
pub struct Juries {
    /// The rule they were found by.
    pub rule: JuryRule,
    /// Members per splat at most (the rule's size).
    pub size: usize,
    /// Splat i's members are `members[i * size .. i * size + count[i]]`.
    pub members: Vec<u32>,
    pub count: Vec<u32>,
}

impl Juries {
    /// The members of splat `i`'s jury, nearest first.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.members[i * self.size..i * self.size + self.count[i] as usize]
    }
}

/// [`size_splats_in`], and with a `jury` rule each splat's jury from the same walk of the tree
/// (continued past the sizing's last neighbour while the jury is short), so that the robust
/// radiance needs no walk of its own ([`super::robust::robust_radiance_in`] takes them).
pub fn size_splats_with_juries(
    tree: &KdTree,
    points: &SplatPoints,
    params: &SplatParams,
    jury: Option<JuryRule>,
) -> Result<(Splats, Option<Juries>), Error> {
    params.validate()?;
    points.validate()?;
    if tree.len() != points.position.len() {
        let message = format!("a kd-tree of {} points for {} splats", tree.len(), points.position.len());
        return Err(Error::size_mismatch("splat sizing", message));
    }
    let setup = Setup::new(points, params);
    let alpha_squared_minus_one = params.alpha * params.alpha - 1.0;
    let jury_size = jury.map_or(0, |rule| rule.size);
    let jury_log_threshold = jury.map_or(0.0, |rule| rule.lobe_threshold.ln());
    let jury_candidates = jury.map_or(0, |rule| rule.max_candidates);
    // Queried in the tree's leaf order (neighbouring queries walk the same nodes), each result
    // a pure function of its hit, put back in input order.
    let in_leaf_order: Vec<((f32, SplatStatus, u32), Vec<u32>)> = tree
        .leaf_order()
        .par_iter()
        .with_max_len(super::PARALLEL_ITEMS)
        .map_init(
            || (WalkScratch::default(), Vec::new()),
            |(scratch, list), &i| {
                let i = i as usize;
                let mut selector = setup.selector(points, i, list);
                let query = points.position[i];
                let (kappa, direction) = (points.kappa(i), points.direction[i]);
                let mut members = Vec::with_capacity(jury_size);
                let (mut sizing, mut visited) = (true, 0usize);
                // k in the lobe: k others, a few more where hits coincide; a narrow lobe
                // continues past them.
                let expected = params.k + 4;
                let metric =
                    MetricQuery { position: query, normal: points.normal[i], alpha_squared_minus_one, skip: i as u32 };
                tree.walk(&metric, expected, scratch, |j, _| {
                    let j = j as usize;
                    visited += 1;
                    if members.len() < jury_size && visited <= jury_candidates {
                        let w = points.direction[j];
                        let cosine = direction[0] * w[0] + direction[1] * w[1] + direction[2] * w[2];
                        if kappa * (cosine - 1.0) >= jury_log_threshold {
                            members.push(j as u32);
                        }
                    }
                    if sizing {
                        sizing = selector.offer(distance(points.position[j], query), points.direction[j]);
                    }
                    sizing || (members.len() < jury_size && visited < jury_candidates)
                });
                (selector.finish(), members)
            },
        )
        .collect();
    let n = points.len();
    let mut per_hit = vec![(0.0, SplatStatus::Isolated, 0); n];
    let mut juries =
        jury.map(|rule| Juries { rule, size: jury_size, members: vec![u32::MAX; n * jury_size], count: vec![0; n] });
    for (&i, (result, members)) in tree.leaf_order().iter().zip(in_leaf_order) {
        let i = i as usize;
        per_hit[i] = result;
        if let Some(juries) = &mut juries {
            juries.members[i * jury_size..i * jury_size + members.len()].copy_from_slice(&members);
            juries.count[i] = members.len() as u32;
        }
    }
    Ok((setup.assemble(per_hit), juries))
}

/// The same definition by sorting all others for every hit: O(n² log n), for tests.
pub fn size_splats_brute_force(points: &SplatPoints, params: &SplatParams) -> Result<Splats, Error> {
    params.validate()?;
    points.validate()?;
    let setup = Setup::new(points, params);
    let alpha_squared_minus_one = params.alpha * params.alpha - 1.0;
    let mut list = Vec::new();
    let per_hit = (0..points.len())
        .map(|i| {
            let query = points.position[i];
            let mut order: Vec<(f32, usize)> = (0..points.len())
                .filter(|&j| j != i)
                .map(|j| {
                    let d = sub(points.position[j], query);
                    (super::neighbours::metric_distance_squared(d, points.normal[i], alpha_squared_minus_one), j)
                })
                .collect();
            order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let mut selector = setup.selector(points, i, &mut list);
            for &(_, j) in &order {
                if !selector.offer(distance(points.position[j], query), points.direction[j]) {
                    break;
                }
            }
            selector.finish()
        })
        .collect();
    Ok(setup.assemble(per_hit))
}

fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = sub(a, b);
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// What every hit's selection shares.
struct Setup {
    params: SplatParams,
    log_thresholds: Vec<f32>,
    epsilon: f32,
    /// For the isolated fallback when nothing else has a radius.
    scale: f32,
}

impl Setup {
    fn new(points: &SplatPoints, params: &SplatParams) -> Setup {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        let mut largest = 0.0f32;
        for p in points.position {
            for axis in 0..3 {
                lo[axis] = lo[axis].min(p[axis]);
                hi[axis] = hi[axis].max(p[axis]);
                largest = largest.max(p[axis].abs());
            }
        }
        let diagonal = if points.len() > 0 { distance(hi, lo) } else { 0.0 };
        Setup {
            params: *params,
            log_thresholds: params.log_thresholds(),
            epsilon: 1e-6 * diagonal,
            scale: if diagonal > 0.0 { diagonal } else { largest.max(1.0) },
        }
    }

    fn selector<'s>(&'s self, points: &SplatPoints, i: usize, list: &'s mut Vec<(f32, f32)>) -> Selector<'s> {
        list.clear();
        Selector {
            setup: self,
            kappa: points.kappa(i),
            direction: points.direction[i],
            visited: 0,
            qualifying: 0,
            list,
            found: None,
        }
    }

    fn assemble(&self, per_hit: Vec<(f32, SplatStatus, u32)>) -> Splats {
        let mut stats = SplatStats {
            lobe: vec![0; self.log_thresholds.len()],
            coincidence_epsilon: self.epsilon,
            ..SplatStats::default()
        };
        let mut known: Vec<f32> = Vec::with_capacity(per_hit.len());
        for &(radius, status, visited) in &per_hit {
            stats.candidates += visited as u64;
            match status {
                SplatStatus::Lobe(level) => stats.lobe[level as usize] += 1,
                SplatStatus::Partial => stats.partial += 1,
                SplatStatus::DirectionBlind => stats.direction_blind += 1,
                SplatStatus::Isolated => stats.isolated += 1,
            }
            if status != SplatStatus::Isolated {
                known.push(radius);
            }
        }
        stats.isolated_radius = if known.is_empty() {
            1e-3 * self.scale
        } else {
            known.sort_by(|a, b| a.total_cmp(b));
            known[(known.len() - 1) / 2]
        };
        let radius = per_hit
            .iter()
            .map(|&(r, status, _)| if status == SplatStatus::Isolated { stats.isolated_radius } else { r })
            .collect();
        Splats { radius, status: per_hit.iter().map(|p| p.1).collect(), stats }
    }
}

/// The selection of one hit's radius from its neighbours, offered nearest first.
struct Selector<'s> {
    setup: &'s Setup,
    kappa: f32,
    direction: [f32; 3],
    visited: u32,
    /// In the lobe at the first threshold.
    qualifying: usize,
    /// (Euclidean distance, κ_i(ω_i·ω_j − 1) = ln A_i(ω_j)) of the non-coincident neighbours seen.
    list: &'s mut Vec<(f32, f32)>,
    found: Option<f32>,
}

impl Selector<'_> {
    /// Takes the next neighbour; false when no more are wanted.
    fn offer(&mut self, euclidean: f32, direction: [f32; 3]) -> bool {
        self.visited += 1;
        if euclidean > self.setup.epsilon {
            let cosine =
                self.direction[0] * direction[0] + self.direction[1] * direction[1] + self.direction[2] * direction[2];
            let log_lobe = self.kappa * (cosine - 1.0);
            self.list.push((euclidean, log_lobe));
            if log_lobe >= self.setup.log_thresholds[0] {
                self.qualifying += 1;
                if self.qualifying == self.setup.params.k {
                    self.found = Some(euclidean);
                    return false;
                }
            }
        }
        (self.visited as usize) < self.setup.params.max_candidates
    }

    fn finish(self) -> (f32, SplatStatus, u32) {
        let visited = self.visited;
        if let Some(radius) = self.found {
            return (radius, SplatStatus::Lobe(0), visited);
        }
        let k = self.setup.params.k;
        let levels = &self.setup.log_thresholds;
        for (level, &log_threshold) in levels.iter().enumerate().skip(1) {
            if let Some(&(radius, _)) = self.list.iter().filter(|e| e.1 >= log_threshold).nth(k - 1) {
                return (radius, SplatStatus::Lobe(level as u8), visited);
            }
        }
        let last = *levels.last().expect("at least one threshold");
        if let Some(&(radius, _)) = self.list.iter().rev().find(|e| e.1 >= last) {
            return (radius, SplatStatus::Partial, visited);
        }
        match self.list.get(k.min(self.list.len()).wrapping_sub(1)) {
            Some(&(radius, _)) => (radius, SplatStatus::DirectionBlind, visited),
            None => (f32::NAN, SplatStatus::Isolated, visited),
        }
    }
}

#[cfg(test)]
mod tests;
