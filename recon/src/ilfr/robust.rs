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
mod tests {
    use super::*;

    /// A square lattice on the plane z = 0 (normal +z, directions straight down), spacing 1,
    /// (2m + 1)² points, radiance `value(x, y)`, every radius `r`.
    struct Lattice {
        position: Vec<[f32; 3]>,
        normal: Vec<[f32; 3]>,
        direction: Vec<[f32; 3]>,
        radius: Vec<f32>,
        radiance: Vec<[f32; 3]>,
    }

    fn lattice(m: i32, r: f32, value: impl Fn(f32, f32) -> [f32; 3]) -> Lattice {
        let mut l = Lattice {
            position: Vec::new(),
            normal: Vec::new(),
            direction: Vec::new(),
            radius: Vec::new(),
            radiance: Vec::new(),
        };
        for i in -m..=m {
            for j in -m..=m {
                let (x, y) = (i as f32, j as f32);
                l.position.push([x, y, 0.0]);
                l.normal.push([0.0, 0.0, 1.0]);
                l.direction.push([0.0, 0.0, -1.0]);
                l.radius.push(r);
                l.radiance.push(value(x, y));
            }
        }
        l
    }

    impl Lattice {
        fn points(&self) -> SplatPoints<'_> {
            SplatPoints { position: &self.position, normal: &self.normal, direction: &self.direction, kappa: None }
        }

        fn index(&self, x: f32, y: f32) -> usize {
            self.position.iter().position(|p| p[0] == x && p[1] == y).unwrap()
        }

        fn run(&self, params: &RobustParams) -> (Vec<[f32; 3]>, RobustStats) {
            robust_radiance(&self.points(), &self.radius, &self.radiance, params).unwrap()
        }

        /// Σ_j L_j r_j² per channel, in f64.
        fn power(&self, radiance: &[[f32; 3]]) -> [f64; 3] {
            let mut sum = [0.0f64; 3];
            for (l, r) in radiance.iter().zip(&self.radius) {
                for k in 0..3 {
                    sum[k] += l[k] as f64 * (*r as f64) * (*r as f64);
                }
            }
            sum
        }
    }

    /// A smooth field: 1 + 0.02 x − 0.01 y, slightly coloured.
    fn smooth(x: f32, y: f32) -> [f32; 3] {
        let v = 1.0 + 0.02 * x - 0.01 * y;
        [v, 0.9 * v, 0.8 * v]
    }

    #[test]
    fn a_smooth_field_and_a_bright_half_plane_are_left_alone() {
        for mode in [RobustMode::Spread, RobustMode::Clamp] {
            let params = RobustParams { mode, ..RobustParams::default() };
            let l = lattice(10, 2.0, smooth);
            let (out, stats) = l.run(&params);
            assert_eq!(out, l.radiance, "{mode:?}: nothing in a smooth field is an outlier");
            assert_eq!(stats.outliers, 0);
            assert_eq!(stats.judged, l.radiance.len(), "every splat of the lattice has a full jury");
            // A shadow edge: 0.01 on one side, 100 (10⁴ times brighter) on the other.
            let edge = lattice(10, 2.0, |x, _| if x > 0.5 { [100.0; 3] } else { [0.01; 3] });
            let (out, stats) = edge.run(&params);
            assert_eq!(out, edge.radiance, "{mode:?}: a lit half-plane is not an outlier");
            assert_eq!(stats.outliers, 0);
        }
    }

    #[test]
    fn a_spike_is_cut_to_its_neighbours_level_and_its_power_is_kept_by_spreading() {
        // One 1e4 spike among the smooth samples.
        let mut l = lattice(10, 2.0, smooth);
        let spike = l.index(0.0, 0.0);
        l.radiance[spike] = [1e4, 1e4, 1e4];
        let params = RobustParams::default();
        let (out, stats) = l.run(&params);
        assert_eq!(stats.outliers, 1);
        // Its jury: the 12 nearest others (distances 1, √2, 2); the second largest luminance
        // among them is at (1, −1), and c = 4 times that is what the spike keeps of its own.
        let threshold = 4.0 * luminance(smooth(1.0, -1.0));
        let excess = luminance([1e4; 3]) - threshold;
        let changed: Vec<usize> = (0..l.radiance.len()).filter(|&j| out[j] != l.radiance[j]).collect();
        // The excess went to the spike and its 48 nearest (all within distance 4), equal radii:
        // equal shares of excess / 49.
        assert_eq!(changed.len(), 49, "changed: {changed:?}");
        let kept = luminance(out[spike]);
        assert!((kept - (threshold + excess / 49.0)).abs() < 1e-3 * kept, "kept {kept}");
        for &j in &changed {
            let p = l.position[j];
            assert!(p[0].hypot(p[1]) <= 4.0 + 1e-6, "{p:?} is not among the 48 nearest");
            if j != spike {
                let added = luminance(out[j]) - luminance(l.radiance[j]);
                assert!((added - excess / 49.0).abs() < 1e-3 * added, "{p:?}: added {added}");
            }
        }
        // Power kept per channel, to f32 rounding.
        let (a, b) = (l.power(&l.radiance), l.power(&out));
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() <= 1e-6 * a[k], "channel {k}: {} → {}", a[k], b[k]);
        }
        // Clamp: the same cut, the excess gone; nothing else changes.
        let (clamped, stats) = l.run(&RobustParams { mode: RobustMode::Clamp, ..params });
        assert_eq!(stats.outliers, 1);
        for (j, (got, input)) in clamped.iter().zip(&l.radiance).enumerate() {
            if j == spike {
                let y = luminance(*got);
                assert!((y - threshold).abs() < 1e-5 * threshold, "clamped to 4 × its jury's 2nd largest: {y}");
                // The colour is kept.
                assert!((got[0] - got[2]).abs() < 1e-6 * y.max(1.0));
            } else {
                assert_eq!(got, input);
            }
        }
        assert!(stats.excess_fraction > 0.9, "the spike was almost all of the power: {}", stats.excess_fraction);
        // Off: the input.
        let (off, _) = l.run(&RobustParams { mode: RobustMode::Off, ..params });
        assert_eq!(off, l.radiance);
    }

    #[test]
    fn one_other_outlier_in_the_jury_does_not_vouch_for_a_spike() {
        // Two adjacent spikes: with the second largest as the level each is still an outlier;
        // with the largest (rank 1) they vouch for each other.
        let mut l = lattice(6, 2.0, smooth);
        let (a, b) = (l.index(0.0, 0.0), l.index(1.0, 0.0));
        l.radiance[a] = [500.0; 3];
        l.radiance[b] = [800.0; 3];
        let (_, stats) = l.run(&RobustParams { mode: RobustMode::Clamp, ..RobustParams::default() });
        assert_eq!(stats.outliers, 2);
        let (_, stats) = l.run(&RobustParams { mode: RobustMode::Clamp, rank: 1, ..RobustParams::default() });
        assert_eq!(stats.outliers, 0);
    }

    #[test]
    fn a_dark_field_spreads_a_lone_bright_sample_whole_and_dead_splats_receive_nothing() {
        // Everything 0 but one sample: the level is 0, so all of it is excess, shared by area.
        let mut l = lattice(8, 1.5, |_, _| [0.0; 3]);
        let lone = l.index(0.0, 0.0);
        l.radiance[lone] = [3.0, 2.0, 1.0];
        let dead = l.index(1.0, 0.0);
        l.radius[dead] = 0.0;
        let bigger = l.index(0.0, 1.0);
        l.radius[bigger] = 3.0;
        let (out, stats) = l.run(&RobustParams::default());
        assert_eq!(stats.outliers, 1);
        assert_eq!(out[dead], [0.0; 3], "a dead splat cannot show light");
        // Equal radiance added to every live sharer, so the bigger disc holds 4× the power.
        assert_eq!(out[bigger], out[lone]);
        let (a, b) = (l.power(&l.radiance), l.power(&out));
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() <= 1e-6 * a[k], "channel {k}: {} → {}", a[k], b[k]);
        }
    }

    /// The method builds one kd-tree of the hits for the sizing and every robust pass: with it,
    /// the radiance is that of the self-contained call bit for bit (spike included); a tree of
    /// other points is refused, naming both counts.
    #[test]
    fn a_shared_kd_tree_gives_the_same_radiance_and_a_wrong_one_is_refused() {
        let mut l = lattice(6, 1.5, |x, y| [1.0 + 0.1 * x, 0.5, 0.2 * y]);
        let spike = l.index(1.0, 1.0);
        l.radiance[spike] = [1e4; 3];
        let params = RobustParams::default();
        let own = l.run(&params);
        let tree = KdTree::build(&l.position);
        let shared = robust_radiance_in(&tree, &l.points(), &l.radius, &l.radiance, &params).unwrap();
        assert_eq!(own.1.outliers, shared.1.outliers);
        let bits = |v: &[[f32; 3]]| v.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(&own.0), bits(&shared.0));
        assert!(own.1.outliers >= 1, "not vacuous: the spike is judged");
        let other = KdTree::build(&l.position[1..]);
        let error = robust_radiance_in(&other, &l.points(), &l.radius, &l.radiance, &params).unwrap_err();
        let n = l.position.len();
        assert!(error.to_string().contains(&format!("a kd-tree of {} points for {n} splats", n - 1)), "{error}");
        let sizing = crate::ilfr::splats::size_splats_in(&other, &l.points(), &Default::default()).unwrap_err();
        assert!(sizing.to_string().contains("a kd-tree of"), "{sizing}");
    }

    /// The juries the sizing's walk finds give the robust radiance of the robust pass's own
    /// walks bit for bit: a random cloud on two planes and a sphere (normals noisy, coincident
    /// hits), heavy-tailed spikes, diffuse and glossy lobes (κ up to 300, so that juries run
    /// short and walks go long), spread and clamp; the sizing's radii are those of the plain
    /// sizing, and juries found by another rule are refused.
    #[test]
    fn juries_from_the_sizing_walk_give_the_same_radiance() {
        use crate::ilfr::splats::{size_splats_in, size_splats_with_juries, SplatParams};
        let mut rng = crate::lcg::Lcg(77);
        let (mut position, mut normal, mut direction, mut radiance, mut kappa) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for i in 0..3000 {
            let (p, n) = match i % 3 {
                0 => ([rng.uniform() * 4.0, rng.uniform() * 4.0, 0.0], [0.0, 0.0, 1.0]),
                1 => ([rng.uniform() * 4.0, 0.0, rng.uniform() * 2.0], [0.0, 1.0, 0.0]),
                _ => {
                    let u = rng.unit_vector();
                    ([2.0 + u[0], 2.0 + u[1], 1.0 + u[2]], u)
                }
            };
            let tilt = rng.unit_vector();
            let n = crate::ilfr::directions::normalize([0, 1, 2].map(|a| n[a] + 0.1 * tilt[a]));
            let d = rng.unit_vector();
            let d = if crate::ilfr::disc::dot(d, n) > 0.0 { d.map(|c| -c) } else { d };
            let (p, n, d) = if i % 41 == 40 { (position[i - 1], normal[i - 1], direction[i - 1]) } else { (p, n, d) };
            position.push(p);
            normal.push(n);
            direction.push(d);
            let y = if rng.uniform() < 0.03 { 1e3 / (1.0 - rng.uniform()).max(1e-3) } else { 0.5 + rng.uniform() };
            radiance.push([y, 0.7 * y, 0.3 * y]);
            kappa.push(match i % 4 {
                0 => 0.0,
                1 => 3.0,
                2 => 40.0,
                _ => 300.0,
            });
        }
        let radius: Vec<f32> = (0..position.len()).map(|_| 0.05 + 0.1 * rng.uniform()).collect();
        let tree = KdTree::build(&position);
        for glossy in [false, true] {
            let points = SplatPoints {
                position: &position,
                normal: &normal,
                direction: &direction,
                kappa: glossy.then_some(&kappa[..]),
            };
            for mode in [RobustMode::Spread, RobustMode::Clamp] {
                let params = RobustParams { mode, ..RobustParams::default() };
                let (sized, juries) =
                    size_splats_with_juries(&tree, &points, &SplatParams::default(), Some(params.jury_rule())).unwrap();
                let plain = size_splats_in(&tree, &points, &SplatParams::default()).unwrap();
                assert_eq!(
                    sized.radius.iter().map(|r| r.to_bits()).collect::<Vec<_>>(),
                    plain.radius.iter().map(|r| r.to_bits()).collect::<Vec<_>>()
                );
                let juries = juries.unwrap();
                let walked = robust_radiance_in(&tree, &points, &radius, &radiance, &params).unwrap();
                let given =
                    robust_radiance_with_juries(&tree, &points, (&radius, &radiance), &params, Some(&juries)).unwrap();
                let bits = |v: &[[f32; 3]]| v.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
                assert_eq!(bits(&walked.0), bits(&given.0), "glossy {glossy}, {mode:?}");
                assert_eq!(walked.1, given.1);
                assert!(walked.1.outliers > 20 && walked.1.judged > 1000, "{:?}", walked.1);
                if glossy {
                    assert!(
                        (0..position.len()).any(|i| juries.of(i).len() < params.neighbours),
                        "some juries run short"
                    );
                }
                let other = RobustParams { lobe_threshold: 0.4, ..params };
                assert!(
                    robust_radiance_with_juries(&tree, &points, (&radius, &radiance), &other, Some(&juries)).is_err()
                );
            }
        }
    }

    #[test]
    fn glossy_neighbours_outside_the_lobe_are_not_jurors() {
        // A sharp lobe (κ = 200): the half of the lattice whose input directions lie 30° away
        // is outside it (A = e^{−200·0.134} ≈ 0), so a splat bright only in its own direction is
        // judged by the samples of its direction alone.
        let mut l = lattice(8, 2.0, |_, _| [1.0; 3]);
        let tilted = [0.5f32, 0.0, -(0.75f32).sqrt()];
        for (k, p) in l.position.clone().iter().enumerate() {
            if (p[0] + p[1]) as i32 % 2 != 0 {
                l.direction[k] = tilted;
                l.radiance[k] = [50.0; 3]; // a highlight seen from that direction
            }
        }
        let kappa = vec![200.0f32; l.position.len()];
        let points =
            SplatPoints { position: &l.position, normal: &l.normal, direction: &l.direction, kappa: Some(&kappa) };
        let (out, stats) = robust_radiance(&points, &l.radius, &l.radiance, &RobustParams::default()).unwrap();
        assert_eq!(stats.outliers, 0, "the highlight's jurors are the other highlight samples");
        assert_eq!(out, l.radiance);
        // Whereas one 50 among 1s of one direction is an outlier.
        let mut single = lattice(8, 2.0, |_, _| [1.0; 3]);
        let centre = single.index(0.0, 0.0);
        single.radiance[centre] = [50.0; 3];
        let (_, stats) = single.run(&RobustParams::default());
        assert_eq!(stats.outliers, 1);
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        // A noisy field with heavy-tailed spikes (an LCG, so the test needs no crate).
        let mut state = 12345u64;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 33) as f32) / (1u64 << 31) as f32
        };
        let mut l = lattice(15, 2.0, |_, _| [1.0; 3]);
        for v in l.radiance.iter_mut() {
            let u = next();
            let y = if u < 0.02 { 1.0 / (1.0 - next()).max(1e-4) * 100.0 } else { 0.5 + next() };
            *v = [y, 0.5 * y, 0.25 * y];
        }
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| l.run(&RobustParams::default()))
        };
        let (one, stats) = run(1);
        assert!(stats.outliers > 0);
        assert!(one.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
        let (three, _) = run(3);
        assert_eq!(one, three);
        let (a, b) = (l.power(&l.radiance), l.power(&one));
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() <= 1e-5 * a[k], "channel {k}: {} → {}", a[k], b[k]);
        }
    }
}
