//! Section 4.1, "To avoid placing probes inside scene geometry, we first voxelize the scene and
//! flood-fill the empty interior space": conservative voxelisation and a 6-connected flood fill.
//!
//! All tests run in voxel units (`q = (p − origin) / s`), so they are the same for a scene at
//! any scale. The grid is padded by `PAD` empty voxels and shifted by half a voxel, so the
//! faces of the scene's bounding box lie on voxel centres (one solid voxel thick), not on voxel
//! boundaries (where a wall would mark the voxels on both sides). A voxel is solid when a
//! triangle overlaps it (separating-axis test, the box grown by `GROW` voxels against rounding);
//! per solid voxel a 6-bit mask records which of its 6 neighbours some triangle in it faces:
//! the offset from the triangle's closest point to the neighbour's centre is at least a quarter
//! voxel along the triangle's normal and within 25° of it (so a voxel beside a wall's edge, in
//! front of its plane but not of the wall, is not faced).
//! The flood fill starts from the grid's boundary and from the seed points (camera, point and
//! spot lights) that lie in empty voxels.

use std::collections::VecDeque;

use glam::DVec3;
use rayon::prelude::*;

use crate::geometry::Geometry;
use crate::ProbesError;

/// Empty voxels around the scene's bounds.
pub const PAD: usize = 2;
/// The most voxels a grid may have.
pub const MAX_VOXELS: usize = 1 << 26;
/// Growth of each voxel box in the overlap test, in voxels.
const GROW: f64 = 1e-4;
/// How far in front of a triangle's plane a neighbour's centre must be to be faced, in voxels.
const FACING_MARGIN: f64 = 0.25;
/// The cosine of the largest angle between a triangle's normal and the offset to a faced centre.
const FACING_COS: f64 = 0.9;

/// The six neighbour offsets: −x, +x, −y, +y, −z, +z (bit d of a facing mask).
pub const NEIGHBOURS: [[i64; 3]; 6] = [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]];

/// A voxelised scene with its flood fill.
#[derive(Clone, Debug)]
pub struct VoxelGrid {
    /// World position of voxel (0, 0, 0)'s lower corner.
    pub origin: DVec3,
    /// Voxel edge length.
    pub size: f64,
    pub dims: [usize; 3],
    pub solid: Vec<bool>,
    /// Per voxel: bit d set when a triangle in it faces the neighbour `NEIGHBOURS[d]`.
    pub facing: Vec<u8>,
    /// Reached by the flood fill (empty voxels only).
    pub reached: Vec<bool>,
    /// Seed points that landed in an empty voxel.
    pub seeds_used: usize,
}

impl VoxelGrid {
    /// Voxelises `geometry` at voxel size `size` and flood-fills from the boundary and `seeds`.
    pub fn build(geometry: &Geometry, size: f64, seeds: &[DVec3]) -> Result<VoxelGrid, ProbesError> {
        if !(size > 0.0) || !size.is_finite() {
            return Err(ProbesError::parameter("voxel size", format!("must be positive and finite, got {size}")));
        }
        let extent = geometry.hi - geometry.lo;
        let origin = geometry.lo - DVec3::splat((PAD as f64 + 0.5) * size);
        let cells = |e: f64| (e / size).floor() + (2 * PAD + 2) as f64;
        let dims_f = [cells(extent.x), cells(extent.y), cells(extent.z)];
        let total = dims_f[0] * dims_f[1] * dims_f[2];
        if !(total <= MAX_VOXELS as f64) {
            return Err(ProbesError::TooLarge {
                what: "voxel grid (fewer probes give coarser voxels)",
                estimate: format!("{total:.3e} voxels"),
                limit: format!("{MAX_VOXELS} voxels"),
            });
        }
        let dims = dims_f.map(|d| d as usize);
        let count = dims[0] * dims[1] * dims[2];
        let to_grid = |p: DVec3| (p - origin) / size;

        // (voxel, facing mask) pairs per triangle, in triangle order.
        let marks: Vec<Vec<(usize, u8)>> = geometry
            .triangles
            .par_iter()
            .map(|t| {
                let v = t.vertices.map(to_grid);
                let normal = t.normal();
                let lo = v[0].min(v[1]).min(v[2]) - DVec3::splat(GROW);
                let hi = v[0].max(v[1]).max(v[2]) + DVec3::splat(GROW);
                let range = |a: f64, b: f64, d: usize| {
                    let first = (a.floor().max(0.0) as usize).min(d - 1);
                    let last = (b.floor().max(0.0) as usize).min(d - 1);
                    first..=last
                };
                let mut out = Vec::new();
                for z in range(lo.z, hi.z, dims[2]) {
                    for y in range(lo.y, hi.y, dims[1]) {
                        for x in range(lo.x, hi.x, dims[0]) {
                            let centre = DVec3::new(x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5);
                            if !triangle_overlaps_box(&v, centre, 0.5 + GROW) {
                                continue;
                            }
                            let mut mask = 0u8;
                            if let Some(n) = normal {
                                for (d, o) in NEIGHBOURS.iter().enumerate() {
                                    let c = centre + DVec3::new(o[0] as f64, o[1] as f64, o[2] as f64);
                                    let offset = c - closest_point_on_triangle(&v, c);
                                    let along = offset.dot(n);
                                    if along > FACING_MARGIN && along >= FACING_COS * offset.length() {
                                        mask |= 1 << d;
                                    }
                                }
                            }
                            out.push((x + dims[0] * (y + dims[1] * z), mask));
                        }
                    }
                }
                out
            })
            .collect();
        let mut solid = vec![false; count];
        let mut facing = vec![0u8; count];
        for (index, mask) in marks.into_iter().flatten() {
            solid[index] = true;
            facing[index] |= mask;
        }

        let mut grid = VoxelGrid { origin, size, dims, solid, facing, reached: vec![false; count], seeds_used: 0 };
        grid.flood_fill(seeds);
        Ok(grid)
    }

    pub fn index(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    pub fn coords(&self, index: usize) -> [usize; 3] {
        [index % self.dims[0], (index / self.dims[0]) % self.dims[1], index / (self.dims[0] * self.dims[1])]
    }

    /// The voxel containing `p`, if inside the grid.
    pub fn voxel_of(&self, p: DVec3) -> Option<[usize; 3]> {
        let q = ((p - self.origin) / self.size).floor();
        let inside = |v: f64, d: usize| v >= 0.0 && v < d as f64;
        (inside(q.x, self.dims[0]) && inside(q.y, self.dims[1]) && inside(q.z, self.dims[2])).then_some([
            q.x as usize,
            q.y as usize,
            q.z as usize,
        ])
    }

    /// The world-space centre of voxel `c`.
    pub fn centre(&self, c: [usize; 3]) -> DVec3 {
        self.origin + (DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) + DVec3::splat(0.5)) * self.size
    }

    /// The neighbour of `c` in direction `d`, if inside the grid.
    pub fn neighbour(&self, c: [usize; 3], d: usize) -> Option<[usize; 3]> {
        let o = NEIGHBOURS[d];
        let mut n = [0usize; 3];
        for a in 0..3 {
            let v = c[a] as i64 + o[a];
            if v < 0 || v >= self.dims[a] as i64 {
                return None;
            }
            n[a] = v as usize;
        }
        Some(n)
    }

    /// 6-connected breadth-first fill of the empty voxels from the grid's boundary and `seeds`.
    fn flood_fill(&mut self, seeds: &[DVec3]) {
        let mut queue = VecDeque::new();
        let [nx, ny, nz] = self.dims;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let boundary = x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1;
                    let i = self.index([x, y, z]);
                    if boundary && !self.solid[i] && !self.reached[i] {
                        self.reached[i] = true;
                        queue.push_back([x, y, z]);
                    }
                }
            }
        }
        for &p in seeds {
            if let Some(c) = self.voxel_of(p) {
                let i = self.index(c);
                if !self.solid[i] {
                    self.seeds_used += 1;
                    if !self.reached[i] {
                        self.reached[i] = true;
                        queue.push_back(c);
                    }
                }
            }
        }
        while let Some(c) = queue.pop_front() {
            for d in 0..6 {
                if let Some(n) = self.neighbour(c, d) {
                    let i = self.index(n);
                    if !self.solid[i] && !self.reached[i] {
                        self.reached[i] = true;
                        queue.push_back(n);
                    }
                }
            }
        }
    }

    /// Whether the point one voxel in front of a surface point `p` with unit normal `n` lies in
    /// a voxel the flood fill reached: a receiver whose front is never reached faces the inside
    /// of closed geometry or a gap narrower than a voxel (hidden). Points outside the grid count
    /// as reached (open space).
    pub fn front_reached(&self, p: DVec3, n: DVec3) -> bool {
        match self.voxel_of(p + n * self.size) {
            Some(c) => self.reached[self.index(c)],
            None => true,
        }
    }

    /// Whether the voxel one voxel in front of `p` (unit normal `n`) is empty space the flood
    /// fill never reached: the receiver faces the inside of closed geometry. A solid front voxel
    /// (another surface within a voxel: a concave edge, a narrow gap) decides nothing; the
    /// transport's own rays do (`TransportContext::hidden`).
    pub fn front_enclosed(&self, p: DVec3, n: DVec3) -> bool {
        match self.voxel_of(p + n * self.size) {
            Some(c) => {
                let i = self.index(c);
                !self.solid[i] && !self.reached[i]
            }
            None => false,
        }
    }

    pub fn solid_count(&self) -> usize {
        self.solid.iter().filter(|&&s| s).count()
    }

    pub fn reached_count(&self) -> usize {
        self.reached.iter().filter(|&&r| r).count()
    }
}

/// The point of triangle `v` closest to `p` (by the triangle's Voronoi regions: vertices, edges,
/// face).
pub fn closest_point_on_triangle(v: &[DVec3; 3], p: DVec3) -> DVec3 {
    let [a, b, c] = *v;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Separating-axis test of a triangle against the cube at `centre` with half-size `half`
/// (Akenine-Möller's 13 axes: the box's 3, the triangle's normal, the 9 edge cross products).
pub fn triangle_overlaps_box(v: &[DVec3; 3], centre: DVec3, half: f64) -> bool {
    let p = [v[0] - centre, v[1] - centre, v[2] - centre];
    let separated = |axis: DVec3| {
        if !(axis.length_squared() > 1e-24) {
            return false;
        }
        let d = [p[0].dot(axis), p[1].dot(axis), p[2].dot(axis)];
        let lo = d[0].min(d[1]).min(d[2]);
        let hi = d[0].max(d[1]).max(d[2]);
        let r = half * (axis.x.abs() + axis.y.abs() + axis.z.abs());
        lo > r || hi < -r
    };
    let edges = [p[1] - p[0], p[2] - p[1], p[0] - p[2]];
    let axes = [DVec3::X, DVec3::Y, DVec3::Z];
    if axes.iter().any(|&a| separated(a)) {
        return false;
    }
    if separated(edges[0].cross(edges[1])) {
        return false;
    }
    for e in edges {
        for a in axes {
            if separated(a.cross(e)) {
                return false;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_matches_a_dense_search() {
        let mut state = 99u32;
        let mut rand = || {
            state = shading::sampling::hash_u32(state);
            shading::sampling::to_unit_float(state) as f64 * 4.0 - 2.0
        };
        for _ in 0..200 {
            let v = [
                DVec3::new(rand(), rand(), rand()),
                DVec3::new(rand(), rand(), rand()),
                DVec3::new(rand(), rand(), rand()),
            ];
            let p = DVec3::new(rand(), rand(), rand()) * 2.0;
            let q = closest_point_on_triangle(&v, p);
            let n = 300;
            let mut best = f64::INFINITY;
            for i in 0..=n {
                for j in 0..=(n - i) {
                    let (a, b) = (i as f64 / n as f64, j as f64 / n as f64);
                    best = best.min((v[0] * (1.0 - a - b) + v[1] * a + v[2] * b).distance(p));
                }
            }
            // The analytic point is never farther than the best lattice point, and the lattice
            // comes within its spacing of it.
            assert!(q.distance(p) <= best + 1e-9, "{} > {best}", q.distance(p));
            assert!(q.distance(p) > best - 0.05, "{} < {best}", q.distance(p));
        }
    }

    #[test]
    fn overlap_test_agrees_with_point_sampling() {
        // A brute-force second implementation: a triangle overlaps the box if a dense set of
        // its points lies inside the (slightly shrunk) box, and never if none lies in the grown
        // box. Random triangles around a unit box.
        let mut state = 12345u32;
        let mut rand = || {
            state = shading::sampling::hash_u32(state);
            shading::sampling::to_unit_float(state) as f64 * 4.0 - 2.0
        };
        let inside = |q: DVec3, h: f64| q.x.abs() <= h && q.y.abs() <= h && q.z.abs() <= h;
        let mut agree = 0;
        for _ in 0..400 {
            let v = [
                DVec3::new(rand(), rand(), rand()),
                DVec3::new(rand(), rand(), rand()),
                DVec3::new(rand(), rand(), rand()),
            ];
            let sat = triangle_overlaps_box(&v, DVec3::ZERO, 0.5);
            let n = 200;
            let mut hit_shrunk = false;
            let mut hit_grown = false;
            for i in 0..=n {
                for j in 0..=(n - i) {
                    let (a, b) = (i as f64 / n as f64, j as f64 / n as f64);
                    let q = v[0] * (1.0 - a - b) + v[1] * a + v[2] * b;
                    hit_shrunk |= inside(q, 0.49);
                    hit_grown |= inside(q, 0.55);
                }
            }
            if hit_shrunk {
                assert!(sat, "SAT misses a triangle that has points inside: {v:?}");
            }
            if !hit_grown {
                // Every point of the triangle is within 7/200 < 0.05 of a sample: none can be
                // inside the box when no sample is inside the box grown by 0.05.
                assert!(!sat, "SAT reports a triangle that stays outside: {v:?}");
            }
            agree += usize::from(sat == hit_shrunk);
        }
        assert!(agree > 350, "SAT and point sampling agree on {agree} of 400");
    }
}
