//! Robust splat radiance, so that fireflies do not pass through: a splat whose radiance is far
//! above that of its neighbours in the reconstruction keeps only a bounded part of it, and the
//! rest is shared with those neighbours, so that a lone bright sample becomes a wide, faint
//! patch instead of a bright disc (diffuse tent) or a bright blob (glossy nearest neighbour).
//!
//! The paper pays "no special attention" to noise in the samples' radiance (§3.1) and leaves it
//! to recursive filtering (§4). Why that fails as the input grows: a sample of luminance Y_f
//! that occurs with probability p per sample becomes a splat whose footprint shrinks as 1/spp
//! while the fireflies grow in number as spp, so the reconstructed field's squared contrast
//! over directions (∫ L̃² dω, what the final gather's fixed number of rays samples) stays
//! constant in spp, and grows while rare paths first appear: the image's error stops falling,
//! or rises, with more input (docs/history/ilfr.md, "the error that grew with the input": Cornell's relative MSE rose from 4 to
//! 16 spp).
//!
//! The rule, per splat i, from the input alone and the same for any thread count:
//! - its *neighbours* are the nearest other hits under the sizing metric (offsets along i's
//!   normal count α = 3 times, [`super::neighbours`]) whose direction lies in i's lobe
//!   (A_i(ω_j) ≥ τ, Eq. 2): the samples of the same local light field that set its radius
//!   (§2.2); the first [`RobustParams::neighbours`] of them are its *jury*;
//! - its reference level is the [`RobustParams::rank`]-th largest luminance in the jury (the
//!   second largest by default, so that one other outlier among the jury does not vouch for it,
//!   while a real bright feature — a lit half-plane, a highlight — has many bright members);
//! - it is an outlier when its luminance Y_i exceeds T_i = c · that level
//!   ([`RobustParams::factor`]); its radiance is then scaled to luminance T_i (its colour kept);
//! - [`RobustMode::Spread`] (the default): the excess L_i (1 − T_i / Y_i) is added to i and its
//!   first [`RobustParams::spread`] neighbours in proportion to their disc areas r_j², so that
//!   Σ_j L_j r_j² — the splats' radiant power up to a constant, what the reconstruction
//!   integrates — is unchanged: no energy is lost, the excess is only blurred over a
//!   neighbourhood whose size shrinks with the sampling rate (consistent as spp → ∞);
//!   [`RobustMode::Clamp`] drops the excess (biased, measured in docs/history/ilfr.md).
//!
//! A splat with fewer than `neighbours` neighbours in its lobe among the `max_candidates`
//! nearest is not judged (a mirror lobe, an isolated hit). Radiances that are not finite and
//! non-negative are left alone (the reader refuses them anyway). Thresholds come from the input
//! radiances (not from radiances already changed), and the excess is distributed in the order of
//! the splats, so the result is a pure function of the input.

use rayon::prelude::*;

use super::neighbours::{KdTree, MetricQuery, WalkScratch};
use super::splats::{Juries, JuryRule, SplatPoints};
use crate::error::Error;

/// What is done with an outlier's excess.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RobustMode {
    /// Nothing is judged: the paper's reconstruction.
    Off,
    /// The excess is dropped (energy lost).
    Clamp,
    /// The excess is shared with the neighbours by disc area (energy kept).
    Spread,
}

impl RobustMode {
    pub fn name(self) -> &'static str {
        match self {
            RobustMode::Off => "off",
            RobustMode::Clamp => "clamp",
            RobustMode::Spread => "spread",
        }
    }
}

/// The parameters of [`robust_radiance`]; see the module documentation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobustParams {
    pub mode: RobustMode,
    /// c: an outlier exceeds c × its jury's reference level.
    pub factor: f32,
    /// Which largest luminance of the jury is the reference level (1 = the brightest).
    pub rank: usize,
    /// The jury: this many nearest neighbours in the lobe.
    pub neighbours: usize,
    /// The excess goes to the splat and this many nearest neighbours in its lobe (`Spread`).
    pub spread: usize,
    /// The sizing metric's α and lobe threshold τ (§2.2).
    pub alpha: f32,
    pub lobe_threshold: f32,
    /// How many nearest others are examined at most.
    pub max_candidates: usize,
}

impl Default for RobustParams {
    fn default() -> Self {
        RobustParams {
            mode: RobustMode::Spread,
            factor: 4.0,
            rank: 2,
            neighbours: 12,
            spread: 48,
            alpha: 3.0,
            lobe_threshold: 0.5,
            max_candidates: 1000,
        }
    }
}

impl RobustParams {
    /// The jury these parameters ask for, for the sizing's walk to find
    /// ([`super::splats::size_splats_with_juries`]).
    pub fn jury_rule(&self) -> JuryRule {
        JuryRule { size: self.neighbours, lobe_threshold: self.lobe_threshold, max_candidates: self.max_candidates }
    }

    fn validate(&self) -> Result<(), Error> {
        if !(self.factor.is_finite() && self.factor >= 1.0) {
            return Err(Error::parameter("factor", format!("robust radiance: c must be ≥ 1, got {}", self.factor)));
        }
        if self.rank == 0 || self.rank > self.neighbours {
            let message = format!("robust radiance: rank {} not in 1..={}", self.rank, self.neighbours);
            return Err(Error::parameter("rank", message));
        }
        if !(self.alpha.is_finite() && self.alpha >= 1.0) {
            return Err(Error::parameter("alpha", format!("robust radiance: α must be ≥ 1, got {}", self.alpha)));
        }
        if !(self.lobe_threshold > 0.0 && self.lobe_threshold <= 1.0) {
            let message = format!("robust radiance: τ must be in (0, 1], got {}", self.lobe_threshold);
            return Err(Error::parameter("lobe_threshold", message));
        }
        if self.max_candidates < self.neighbours.max(self.spread) {
            let message = format!(
                "robust radiance: max_candidates ({}) below the jury ({}) or the spread ({})",
                self.max_candidates, self.neighbours, self.spread
            );
            return Err(Error::parameter("max_candidates", message));
        }
        Ok(())
    }
}

/// Counts for reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RobustStats {
    /// Splats with a full jury.
    pub judged: usize,
    /// Splats found to be outliers.
    pub outliers: usize,
    /// The outliers' excess over all splats' radiant power, Σ ΔY_i r_i² / Σ Y_j r_j² (moved by
    /// `Spread`, lost by `Clamp`).
    pub excess_fraction: f64,
}

/// Rec. 709 luminance.
#[inline]
pub fn luminance(l: [f32; 3]) -> f32 {
    0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2]
}

/// One splat's verdict: its excess radiance and who shares it.
struct Verdict {
    judged: bool,
    excess: Option<([f64; 3], Vec<u32>)>,
}

/// The robust radiance of every splat (see the module documentation): `radiance[i]` and
/// `radius[i]` belong to `points` entry i (`radius` the discs' radii after shrinking: a dead
/// splat, radius 0, receives nothing).
pub fn robust_radiance(
    points: &SplatPoints,
    radius: &[f32],
    radiance: &[[f32; 3]],
    params: &RobustParams,
) -> Result<(Vec<[f32; 3]>, RobustStats), Error> {
    if params.mode == RobustMode::Off {
        params.validate()?;
        check_lengths(points, radius, radiance)?;
        return Ok((radiance.to_vec(), RobustStats::default()));
    }
    robust_radiance_in(&KdTree::build(points.position), points, radius, radiance, params)
}

fn check_lengths(points: &SplatPoints, radius: &[f32], radiance: &[[f32; 3]]) -> Result<(), Error> {
    let n = points.position.len();
    if radius.len() != n || radiance.len() != n || points.normal.len() != n || points.direction.len() != n {
        return Err(Error::size_mismatch("robust radiance", "positions, radii and radiances differ in length"));
    }
    Ok(())
}

/// [`robust_radiance`] with the kd-tree of `points.position` built by the caller (shared with
/// the sizing, [`super::splats::size_splats_in`]); `tree` must hold exactly those positions.
pub fn robust_radiance_in(
    tree: &KdTree,
    points: &SplatPoints,
    radius: &[f32],
    radiance: &[[f32; 3]],
    params: &RobustParams,
) -> Result<(Vec<[f32; 3]>, RobustStats), Error> {
    robust_radiance_with_juries(tree, points, (radius, radiance), params, None)
}

/// [`robust_radiance_in`] with each splat's jury already found by the sizing's walk
/// ([`super::splats::size_splats_with_juries`] under [`RobustParams::jury_rule`]): only the
/// outliers walk the tree again, for their sharers. The same result bit for bit.
pub fn robust_radiance_with_juries(
    tree: &KdTree,
    points: &SplatPoints,
    (radius, radiance): (&[f32], &[[f32; 3]]),
    params: &RobustParams,
    juries: Option<&Juries>,
) -> Result<(Vec<[f32; 3]>, RobustStats), Error> {
    params.validate()?;
    if let Some(juries) = juries {
        let rule = params.jury_rule();
        let fits = juries.rule.size >= rule.size
            && juries.rule.lobe_threshold == rule.lobe_threshold
            && juries.rule.max_candidates == rule.max_candidates
            && juries.count.len() == points.position.len();
        if !fits {
            let message = format!("juries found by {:?} for the rule {rule:?} of {} splats", juries.rule, radius.len());
            return Err(Error::parameter("juries", message));
        }
    }
    check_lengths(points, radius, radiance)?;
    let n = points.position.len();
    if tree.len() != n {
        let message = format!("a kd-tree of {} points for {n} splats", tree.len());
        return Err(Error::size_mismatch("robust radiance", message));
    }
    if params.mode == RobustMode::Off || n == 0 {
        return Ok((radiance.to_vec(), RobustStats::default()));
    }
    let alpha_squared_minus_one = params.alpha * params.alpha - 1.0;
    let log_threshold = params.lobe_threshold.ln();
    // The first `wanted` neighbours in the lobe, in the walk's order (the jury is their first
    // `neighbours`; the sharers of `Spread` all of them).
    let in_lobe = |i: usize, wanted: usize, scratch: &mut WalkScratch, found: &mut Vec<u32>| {
        found.clear();
        let kappa = points.kappa.map_or(0.0, |k| k[i]);
        let direction = points.direction[i];
        let mut visited = 0usize;
        let expected = wanted + 4;
        let query = MetricQuery {
            position: points.position[i],
            normal: points.normal[i],
            alpha_squared_minus_one,
            skip: i as u32,
        };
        tree.walk(&query, expected, scratch, |j, _| {
            visited += 1;
            let w = points.direction[j as usize];
            let cosine = direction[0] * w[0] + direction[1] * w[1] + direction[2] * w[2];
            if kappa * (cosine - 1.0) >= log_threshold {
                found.push(j);
            }
            found.len() < wanted && visited < params.max_candidates
        });
    };
    // Judged in the tree's leaf order (neighbouring splats walk the same nodes), each verdict a
    // pure function of its splat, put back in input order.
    let in_leaf_order: Vec<Verdict> = tree
        .leaf_order()
        .par_iter()
        .with_max_len(super::PARALLEL_ITEMS)
        .map_init(
            || (WalkScratch::default(), Vec::<u32>::new()),
            |(scratch, found), &i| {
                let i = i as usize;
                let own = radiance[i];
                let y = luminance(own);
                if !(y.is_finite() && y > 0.0 && own.iter().all(|c| c.is_finite() && *c >= 0.0)) {
                    return Verdict { judged: false, excess: None };
                }
                match juries {
                    Some(juries) => {
                        found.clear();
                        found.extend_from_slice(juries.of(i));
                    }
                    None => in_lobe(i, params.neighbours, scratch, found),
                }
                if found.len() < params.neighbours {
                    return Verdict { judged: false, excess: None };
                }
                let mut jury: Vec<f32> =
                    found[..params.neighbours].iter().map(|&j| luminance(radiance[j as usize]).max(0.0)).collect();
                jury.sort_by(|a, b| b.total_cmp(a));
                let level = jury[params.rank - 1];
                let threshold = params.factor * level;
                if !threshold.is_finite() || y <= threshold {
                    return Verdict { judged: true, excess: None };
                }
                let keep = threshold as f64 / y as f64;
                let excess = own.map(|c| c as f64 * (1.0 - keep));
                // Only an outlier needs its sharers: the same walk, on to `spread` of them.
                let sharers = if params.mode == RobustMode::Spread {
                    in_lobe(i, params.neighbours.max(params.spread), scratch, found);
                    found.clone()
                } else {
                    Vec::new()
                };
                Verdict { judged: true, excess: Some((excess, sharers)) }
            },
        )
        .collect();
    let mut verdicts: Vec<Verdict> = (0..n).map(|_| Verdict { judged: false, excess: None }).collect();
    for (&i, verdict) in tree.leaf_order().iter().zip(in_leaf_order) {
        verdicts[i as usize] = verdict;
    }

    let mut stats = RobustStats::default();
    let mut out: Vec<[f64; 3]> = radiance.iter().map(|l| l.map(|c| c as f64)).collect();
    let area = |j: usize| (radius[j] as f64) * (radius[j] as f64);
    let (mut moved, mut total) = (0.0f64, 0.0f64);
    for (j, l) in radiance.iter().enumerate() {
        let y = luminance(*l) as f64;
        if y.is_finite() && y > 0.0 {
            total += y * area(j);
        }
    }
    for (i, verdict) in verdicts.iter().enumerate() {
        stats.judged += verdict.judged as usize;
        let Some((excess, sharers)) = &verdict.excess else { continue };
        stats.outliers += 1;
        moved += (0.2126 * excess[0] + 0.7152 * excess[1] + 0.0722 * excess[2]) * area(i);
        for k in 0..3 {
            out[i][k] -= excess[k];
        }
        if params.mode != RobustMode::Spread {
            continue;
        }
        let weight: f64 = area(i) + sharers.iter().map(|&j| area(j as usize)).sum::<f64>();
        if weight <= 0.0 {
            // Every sharer is dead: nothing can show the excess; keep it where it was.
            for k in 0..3 {
                out[i][k] += excess[k];
            }
            continue;
        }
        // The excess in power units, Δ = ΔL r_i², shared as Δ r_j² / Σ r², in radiance units
        // Δ / Σ r² to every sharer (so that Σ_j ΔL_j r_j² = Δ).
        let scale = area(i) / weight;
        for j in std::iter::once(i).chain(sharers.iter().map(|&j| j as usize)) {
            if area(j) > 0.0 {
                for k in 0..3 {
                    out[j][k] += excess[k] * scale;
                }
            }
        }
    }
    stats.excess_fraction = if total > 0.0 { moved / total } else { 0.0 };
    let out = out.iter().map(|l| l.map(|c| c.max(0.0) as f32)).collect();
    Ok((out, stats))
}

#[cfg(test)]
mod tests;
