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

use super::neighbours::{sub, KdTree, MetricQuery, WalkScratch};
use crate::error::Error;

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
mod tests {
    use super::*;
    use crate::lcg::Lcg;

    const UP: [f32; 3] = [0.0, 0.0, 1.0];

    fn normalize(v: [f32; 3]) -> [f32; 3] {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / l, v[1] / l, v[2] / l]
    }

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
        for params in
            [SplatParams::default(), SplatParams { k: 5, alpha: 1.5, max_candidates: 40, ..Default::default() }]
        {
            let tree = size_splats(&cloud.points(), &params).unwrap();
            let brute = size_splats_brute_force(&cloud.points(), &params).unwrap();
            assert_eq!(tree.status, brute.status);
            assert!(tree.radius.iter().zip(&brute.radius).all(|(a, b)| a.to_bits() == b.to_bits()));
            assert_eq!(tree.stats, brute.stats);
            assert!(tree.radius.iter().all(|r| r.is_finite() && *r > 0.0));
            assert!(
                tree.stats.lobe.iter().skip(1).sum::<usize>() + tree.stats.partial + tree.stats.direction_blind > 0
            );
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
        assert!(size_splats(&cloud.points(), &SplatParams::default())
            .unwrap_err()
            .to_string()
            .contains("normal of hit 1"));
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
                (
                    splats.stats.lobe.iter().take(3).collect::<Vec<_>>(),
                    splats.stats.partial,
                    splats.stats.direction_blind
                )
            );
        }
    }
}
