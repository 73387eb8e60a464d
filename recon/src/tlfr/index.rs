//! An interim spatial index for the reconstruction queries: a uniform grid over each sample's
//! conservative screen bounds across the whole lens × time domain. The paper's hierarchy
//! (Section 4, Appendix A: quadtree leaves of one surface each, a BVH bounded by planes linear
//! in (u, t) and (v, t)) is not built yet; this grid finds the same candidates (every sample
//! that can reproject within the query radius), only with looser bounds, so queries over large
//! defocus or motion visit more samples than the paper's would.
//!
//! Bounds: on its valid time span (depth ≥ the near limit, `valid_span`) a sample's lens-centre
//! position `(x̄z + (t − tᵢ)m) / z'(t)` is a ratio of linear functions with a denominator that
//! keeps its sign, hence monotone, and `C(z'(t))` is monotone in t too; so their extremes are at
//! the span's ends, and `x' = centre + û·C` lies within [min centre − max|C|, max centre + max|C|]
//! for every |û| ≤ 1 (the lens term only where the file has lens coordinates).

use super::lens::LensModel;
use super::reprojection::{depth_at, reproject, LensTime, LensTimeSample};

/// The times in [0, 1] at which the sample's depth stays at or above `z_near`; `None` if none.
pub fn valid_span(sample: &LensTimeSample, z_near: f32) -> Option<(f32, f32)> {
    if sample.z.is_infinite() || sample.motion[2] == 0.0 {
        return (sample.z >= z_near).then_some((0.0, 1.0));
    }
    // z + (t − tᵢ)·m_z ≥ z_near ⇔ t ≥ t* (m_z > 0) or t ≤ t* (m_z < 0).
    let crossing = sample.t + (z_near - sample.z) / sample.motion[2];
    let (lo, hi) = if sample.motion[2] > 0.0 { (crossing.max(0.0), 1.0) } else { (0.0, crossing.min(1.0)) };
    (lo <= hi).then_some((lo, hi))
}

/// A conservative screen box [x0, y0, x1, y1] of everywhere the sample reprojects to.
pub fn screen_bounds(sample: &LensTimeSample, lens: &LensModel, has_lens: bool, z_near: f32) -> Option<[f32; 4]> {
    let (t0, t1) = valid_span(sample, z_near)?;
    let lens_reach = |t: f32| if has_lens { lens.coc(depth_at(sample, t)).abs() } else { 0.0 };
    let reach = lens_reach(t0).max(lens_reach(t1));
    let centre = |t: f32| reproject(sample, lens, LensTime { u: 0.0, v: 0.0, t }, 0.0);
    let (a, b) = (centre(t0)?, centre(t1)?);
    let bounds = [a.x.min(b.x) - reach, a.y.min(b.y) - reach, a.x.max(b.x) + reach, a.y.max(b.y) + reach];
    bounds.iter().all(|v| v.is_finite()).then_some(bounds)
}

/// Samples bucketed by the grid cells their screen bounds overlap.
pub struct SampleGrid {
    origin: [f32; 2],
    cell: f32,
    columns: usize,
    rows: usize,
    /// `starts[c]..starts[c + 1]` index `entries` for cell c.
    starts: Vec<u32>,
    entries: Vec<u32>,
    /// Samples that can never be seen (no valid time) or whose bounds are not finite.
    pub unplaced: usize,
}

/// At most this many grid entries per sample on average; the cell grows until it fits.
const MAX_ENTRIES_PER_SAMPLE: f64 = 48.0;

impl SampleGrid {
    /// The grid over `width` × `height` pixels (plus a margin of `margin` pixels, where samples
    /// reprojecting off the image still matter), with cells of about `cell` pixels.
    pub fn build(
        samples: &[LensTimeSample],
        lens: &LensModel,
        has_lens: bool,
        z_near: f32,
        (width, height): (u32, u32),
        margin: f32,
        cell: f32,
    ) -> SampleGrid {
        let bounds: Vec<Option<[f32; 4]>> = samples.iter().map(|s| screen_bounds(s, lens, has_lens, z_near)).collect();
        let origin = [-margin, -margin];
        let extent = [width as f32 + 2.0 * margin, height as f32 + 2.0 * margin];
        let mut cell = cell.max(0.25);
        loop {
            let columns = (extent[0] / cell).ceil().max(1.0) as usize;
            let rows = (extent[1] / cell).ceil().max(1.0) as usize;
            let range = |b: &[f32; 4]| {
                let clamp = |v: f32, n: usize| (v.floor().max(0.0) as usize).min(n - 1);
                let c0 = clamp((b[0] - origin[0]) / cell, columns);
                let c1 = clamp((b[2] - origin[0]) / cell, columns);
                let r0 = clamp((b[1] - origin[1]) / cell, rows);
                let r1 = clamp((b[3] - origin[1]) / cell, rows);
                let off = b[2] < origin[0]
                    || b[3] < origin[1]
                    || b[0] > origin[0] + extent[0]
                    || b[1] > origin[1] + extent[1];
                (!off).then_some((c0, c1, r0, r1))
            };
            let total: f64 = bounds
                .iter()
                .flatten()
                .filter_map(range)
                .map(|(c0, c1, r0, r1)| ((c1 - c0 + 1) * (r1 - r0 + 1)) as f64)
                .sum();
            if total > MAX_ENTRIES_PER_SAMPLE * samples.len().max(1) as f64 && cell < extent[0].max(extent[1]) {
                cell *= 2.0;
                continue;
            }
            let mut starts = vec![0u32; columns * rows + 1];
            let ranges: Vec<Option<(usize, usize, usize, usize)>> =
                bounds.iter().map(|b| b.as_ref().and_then(range)).collect();
            for (c0, c1, r0, r1) in ranges.iter().flatten() {
                for r in *r0..=*r1 {
                    for c in *c0..=*c1 {
                        starts[r * columns + c + 1] += 1;
                    }
                }
            }
            for c in 0..columns * rows {
                starts[c + 1] += starts[c];
            }
            let mut fill = starts.clone();
            let mut entries = vec![0u32; starts[columns * rows] as usize];
            for (i, r) in ranges.iter().enumerate() {
                if let Some((c0, c1, r0, r1)) = r {
                    for row in *r0..=*r1 {
                        for column in *c0..=*c1 {
                            let c = row * columns + column;
                            entries[fill[c] as usize] = i as u32;
                            fill[c] += 1;
                        }
                    }
                }
            }
            let unplaced = bounds.iter().filter(|b| b.is_none()).count();
            return SampleGrid { origin, cell, columns, rows, starts, entries, unplaced };
        }
    }

    /// Indices of every sample whose bounds overlap the square of half-width `radius` around
    /// `point`, sorted and without repeats, appended to `out` (cleared first).
    pub fn candidates(&self, point: [f32; 2], radius: f32, out: &mut Vec<u32>) {
        out.clear();
        let clamp = |v: f32, n: usize| (v.floor().max(0.0) as usize).min(n - 1);
        let c0 = clamp((point[0] - radius - self.origin[0]) / self.cell, self.columns);
        let c1 = clamp((point[0] + radius - self.origin[0]) / self.cell, self.columns);
        let r0 = clamp((point[1] - radius - self.origin[1]) / self.cell, self.rows);
        let r1 = clamp((point[1] + radius - self.origin[1]) / self.cell, self.rows);
        for r in r0..=r1 {
            for c in c0..=c1 {
                let cell = r * self.columns + c;
                out.extend_from_slice(&self.entries[self.starts[cell] as usize..self.starts[cell + 1] as usize]);
            }
        }
        out.sort_unstable();
        out.dedup();
    }

    /// Grid entries per sample (memory: 4 bytes each).
    pub fn entries_per_sample(&self, samples: usize) -> f64 {
        self.entries.len() as f64 / samples.max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens() -> LensModel {
        LensModel { c1: -8.0, c2: 2.0, fx: 80.0, fy: 80.0, cx: 32.0, cy: 24.0 }
    }

    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f32 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    fn random_sample(rng: &mut Lcg) -> LensTimeSample {
        LensTimeSample {
            x: 64.0 * rng.next(),
            y: 48.0 * rng.next(),
            u: 2.0 * rng.next() - 1.0,
            v: 2.0 * rng.next() - 1.0,
            t: rng.next(),
            z: 0.3 + 6.0 * rng.next(),
            // Some move through the camera plane within the shutter.
            motion: [rng.next() - 0.5, rng.next() - 0.5, 3.0 * (rng.next() - 0.6)],
        }
    }

    #[test]
    fn bounds_contain_every_reprojection() {
        let mut rng = Lcg(21);
        let z_near = 1e-3;
        for _ in 0..2000 {
            let sample = random_sample(&mut rng);
            let Some(b) = screen_bounds(&sample, &lens(), true, z_near) else {
                assert!(valid_span(&sample, z_near).is_none());
                continue;
            };
            for i in 0..=16 {
                for j in 0..=16 {
                    let at = LensTime { u: -1.0 + i as f32 / 8.0, v: 1.0 - j as f32 / 8.0, t: j as f32 / 16.0 };
                    if let Some(p) = reproject(&sample, &lens(), at, z_near) {
                        let slack = 1e-3 * (1.0 + p.x.abs().max(p.y.abs()));
                        assert!(
                            p.x >= b[0] - slack && p.x <= b[2] + slack && p.y >= b[1] - slack && p.y <= b[3] + slack,
                            "{sample:?} at {at:?}: {p:?} outside {b:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn spans_exclude_times_behind_the_camera() {
        let s = LensTimeSample { z: 1.0, t: 0.0, motion: [0.0, 0.0, -2.0], ..LensTimeSample::default() };
        let (lo, hi) = valid_span(&s, 1e-3).unwrap();
        assert_eq!(lo, 0.0);
        assert!((hi - 0.4995).abs() < 1e-6);
        let towards = LensTimeSample { z: 1.0, t: 1.0, motion: [0.0, 0.0, 2.0], ..s };
        let (lo, hi) = valid_span(&towards, 1e-3).unwrap();
        assert!((lo - 0.5005).abs() < 1e-6 && hi == 1.0);
        let still = LensTimeSample { z: 2.0, motion: [0.0; 3], ..s };
        assert_eq!(valid_span(&still, 1e-3), Some((0.0, 1.0)));
    }

    #[test]
    fn the_grid_returns_every_sample_that_can_land_near_a_point() {
        let mut rng = Lcg(5);
        let samples: Vec<LensTimeSample> = (0..3000).map(|_| random_sample(&mut rng)).collect();
        let grid = SampleGrid::build(&samples, &lens(), true, 1e-3, (64, 48), 16.0, 2.0);
        let mut found = Vec::new();
        for _ in 0..200 {
            let point = [64.0 * rng.next(), 48.0 * rng.next()];
            let at = LensTime { u: 2.0 * rng.next() - 1.0, v: 2.0 * rng.next() - 1.0, t: rng.next() };
            let radius = 1.5;
            grid.candidates(point, radius, &mut found);
            for (i, sample) in samples.iter().enumerate() {
                if let Some(p) = reproject(sample, &lens(), at, 1e-3) {
                    if (p.x - point[0]).abs() <= radius && (p.y - point[1]).abs() <= radius {
                        assert!(found.binary_search(&(i as u32)).is_ok(), "sample {i} missing");
                    }
                }
            }
        }
        assert!(grid.entries_per_sample(samples.len()) <= MAX_ENTRIES_PER_SAMPLE);
    }
}
