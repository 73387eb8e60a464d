//! The visibility weight V_i(ω) of Eq. 2 by exact rays, and a survey of how many of a receiver's
//! hit points no covering probe sees (the directions Eq. 2 defines as zero radiance; the
//! research notes' §3.3 measured ~5 % of Sponza's). Decisions (design note, "Visibility"): the
//! probe must be on the side of the hit surface that faces the receiver, and the segment from
//! the hit point (pushed off that side) to the probe must be unblocked; alpha masks count as the
//! tracer's `Accel` counts them.

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use shading::{sample_cosine_hemisphere, Frame};
use tracer::sampler::Sampler;
use tracer::Accel;

use crate::surfels::Surfels;
use crate::voxel::VoxelGrid;

/// The push-off of a ray origin at `p` in a scene of largest extent `scale`: relative to the
/// position's magnitude and the scene's size (no absolute epsilon).
pub fn offset(p: Vec3, scale: f32) -> f32 {
    (p.abs().max_element() + 1e-3 * scale) * 4e-6
}

/// The visibility weight V_i for the point `y` on a surface whose side facing the receiver has unit normal
/// `side`: whether the probe at `probe` is in front of that side and sees `y`.
pub fn probe_sees(accel: &Accel, y: Vec3, side: Vec3, probe: Vec3, scale: f32) -> bool {
    if !((probe - y).dot(side) > 0.0) {
        return false;
    }
    let origin = y + side * offset(y, scale);
    let to = probe - origin;
    let distance = to.length();
    if !(distance > 0.0) {
        return true;
    }
    !accel.occluded(origin, to / distance, 0.0, distance, 0.0)
}

/// What the survey found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UnseenSurvey {
    /// Receivers surveyed and cosine directions per receiver.
    pub receivers: usize,
    pub directions: u32,
    /// Receivers with at least 30 % of their hits on back faces (the wrong side of closed
    /// geometry): counted, left out of the figures below.
    pub back_facing_receivers: usize,
    /// Receivers whose front voxel the flood fill never reached (hidden; only with a grid):
    /// counted, left out of the figures below.
    pub hidden_receivers: usize,
    /// Over the other receivers: directions that hit something, and of those, hits no covering
    /// probe sees.
    pub hits: u64,
    pub unseen: u64,
    /// Directions that escaped the scene.
    pub escaped: u64,
    /// Mean number of covering probes per hit, and of those that see it.
    pub covering_per_hit: f64,
    pub seeing_per_hit: f64,
    /// Receivers (not back-facing, with hits) that lose no direction, ≤ 5 %, and > 90 %.
    pub lose_none: usize,
    pub lose_at_most_5_percent: usize,
    pub lose_over_90_percent: usize,
    /// Receivers with hits that are not back-facing.
    pub counted_receivers: usize,
}

impl UnseenSurvey {
    /// The fraction of hit directions no covering probe sees.
    pub fn unseen_fraction(&self) -> f64 {
        self.unseen as f64 / self.hits.max(1) as f64
    }
}

/// Per receiver: (hits, back-face hits, unseen hits, escaped, covering sum, seeing sum).
type Tally = (u64, u64, u64, u64, u64, u64);

/// Surveys `count` receivers (one drawn from each of `count` equal runs of surfels) with
/// `directions` cosine-distributed Owen-scrambled Sobol' rays each against `probes` of support
/// radius `radius`; with `grid`, receivers whose front voxel the flood fill never reached are
/// counted as hidden and not surveyed (the notes' §3.3 protocol).
#[allow(clippy::too_many_arguments)]
pub fn survey_unseen(
    accel: &Accel,
    surfels: &Surfels,
    grid: Option<&VoxelGrid>,
    probes: &[DVec3],
    radius: f64,
    count: usize,
    directions: u32,
    seed: u32,
) -> UnseenSurvey {
    let n = surfels.surfels.len();
    let count = count.min(n);
    if count == 0 || directions == 0 {
        return UnseenSurvey::default();
    }
    let stride = n / count;
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for s in &surfels.surfels {
        lo = lo.min(s.position.as_dvec3());
        hi = hi.max(s.position.as_dvec3());
    }
    let scale = (hi - lo).max_element() as f32;
    let probes_f: Vec<Vec3> = probes.iter().map(|p| p.as_vec3()).collect();
    let tallies: Vec<Option<Tally>> = (0..count)
        .into_par_iter()
        .map(|k| {
            let index = k * stride + (shading::sampling::hash_u32(seed ^ k as u32) as usize % stride);
            let s = &surfels.surfels[index];
            let x = s.position;
            let covering: Vec<Vec3> = probes
                .iter()
                .zip(&probes_f)
                .filter(|(p, _)| p.distance(x.as_dvec3()) < radius)
                .map(|(_, &q)| q)
                .collect();
            let frame = Frame::new(s.normal);
            let origin = x + s.normal * offset(x, scale);
            let mut t: Tally = (0, 0, 0, 0, 0, 0);
            if grid.is_some_and(|g| !g.front_reached(x.as_dvec3(), s.normal.as_dvec3())) {
                return None;
            }
            for d in 0..directions {
                let u = Sampler::new(seed, index as u32, 0x3fff_ffff, d).next_2d();
                let dir = frame.to_world(sample_cosine_hemisphere(u)).normalize();
                let Some(hit) = accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else {
                    t.3 += 1;
                    continue;
                };
                t.0 += 1;
                let ng = hit.geometric_normal.normalize_or_zero();
                if ng.dot(dir) > 0.0 {
                    t.1 += 1;
                }
                let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                let y = origin + dir * hit.distance;
                let seeing = covering.iter().filter(|&&p| probe_sees(accel, y, side, p, scale)).count() as u64;
                t.4 += covering.len() as u64;
                t.5 += seeing;
                if seeing == 0 {
                    t.2 += 1;
                }
            }
            Some(t)
        })
        .collect();
    let mut survey = UnseenSurvey { receivers: count, directions, ..Default::default() };
    let (mut covering, mut seeing) = (0u64, 0u64);
    for tally in &tallies {
        let Some((hits, back, unseen, escaped, cov, see)) = *tally else {
            survey.hidden_receivers += 1;
            continue;
        };
        if hits > 0 && back as f64 >= 0.3 * hits as f64 {
            survey.back_facing_receivers += 1;
            continue;
        }
        survey.escaped += escaped;
        if hits == 0 {
            continue;
        }
        survey.counted_receivers += 1;
        survey.hits += hits;
        survey.unseen += unseen;
        covering += cov;
        seeing += see;
        let lost = unseen as f64 / hits as f64;
        survey.lose_none += usize::from(unseen == 0);
        survey.lose_at_most_5_percent += usize::from(lost <= 0.05);
        survey.lose_over_90_percent += usize::from(lost > 0.9);
    }
    survey.covering_per_hit = covering as f64 / survey.hits.max(1) as f64;
    survey.seeing_per_hit = seeing as f64 / survey.hits.max(1) as f64;
    survey
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surfels::SurfelSettings;
    use crate::test_scenes::{room, scene_of};
    use tracer::scene::shapes::polygon;

    #[test]
    fn a_wall_hides_the_probe_behind_it_and_a_convex_room_hides_nothing() {
        // The unit room split by a zero-thickness wall at x = 0.5.
        let wall = polygon(
            "wall",
            &[Vec3::new(0.5, 0.0, 0.0), Vec3::new(0.5, 0.0, 1.0), Vec3::new(0.5, 1.0, 1.0), Vec3::new(0.5, 1.0, 0.0)],
            0,
        );
        let scene = scene_of(vec![room(Vec3::ZERO, Vec3::ONE), wall], Vec3::splat(0.25));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 3000, ..Default::default() }).unwrap();
        // Keep the receivers inside the left half, facing into it.
        let mut left = surfels.clone();
        left.surfels.retain(|s| {
            let p = s.position + s.normal * 0.01;
            p.x > 0.0 && p.x < 0.5 && p.y > 0.0 && p.y < 1.0 && p.z > 0.0 && p.z < 1.0
        });
        assert!(left.surfels.len() > 200);
        let radius = 10.0;
        let beyond = survey_unseen(&accel, &left, None, &[DVec3::new(0.75, 0.5, 0.5)], radius, 200, 32, 0);
        assert_eq!(beyond.back_facing_receivers, 0);
        assert!(beyond.hits > 0);
        assert_eq!(beyond.unseen, beyond.hits, "a probe behind the wall sees a hit point");
        assert_eq!(beyond.lose_over_90_percent, beyond.counted_receivers);
        let here = survey_unseen(&accel, &left, None, &[DVec3::new(0.25, 0.5, 0.5)], radius, 200, 32, 0);
        assert_eq!(here.unseen, 0, "the convex half hides a point from its centre");
        assert_eq!(here.seeing_per_hit, 1.0);
        assert_eq!(here.escaped, 0);
        // Out of range: not covering, so unseen.
        let far = survey_unseen(&accel, &left, None, &[DVec3::new(0.25, 0.5, 0.5)], 1e-3, 200, 32, 0);
        assert_eq!(far.unseen, far.hits);
    }

    #[test]
    fn the_back_of_a_closed_box_is_counted_not_surveyed() {
        // Receivers on the outside of an inward-facing room look at nothing; inside the box
        // made of outward faces they see back faces only.
        let boxed = tracer::scene::shapes::axis_aligned_box("box", Vec3::ZERO, Vec3::ONE, 0);
        let scene = scene_of(vec![boxed], Vec3::splat(3.0));
        let accel = Accel::build(&scene).unwrap();
        let surfels = Surfels::build(&scene, &SurfelSettings { budget: 2000, ..Default::default() }).unwrap();
        let survey = survey_unseen(&accel, &surfels, None, &[DVec3::splat(2.0)], 10.0, 400, 16, 1);
        // Half the surfels face inwards (hits on back faces), half outwards (escape).
        let inward = survey.back_facing_receivers as f64 / survey.receivers as f64;
        assert!((inward - 0.5).abs() < 0.1, "{inward}");
        assert_eq!(survey.hits, 0);
        assert_eq!(survey.escaped, (survey.receivers - survey.back_facing_receivers) as u64 * 16);
        // With the flood fill (from outside), the inward sides are hidden instead.
        let geometry = crate::geometry::Geometry::from_scene(&scene).unwrap();
        let grid = VoxelGrid::build(&geometry, 0.1, &[]).unwrap();
        let with_grid = survey_unseen(&accel, &surfels, Some(&grid), &[DVec3::splat(2.0)], 10.0, 400, 16, 1);
        assert_eq!(with_grid.hidden_receivers, survey.back_facing_receivers);
        assert_eq!(with_grid.back_facing_receivers, 0);
        assert_eq!(with_grid.escaped, survey.escaped);
    }
}
