//! Receivers and senders: world-space surface elements ("surfels"), the crate's stand-in for
//! the paper's light-map texels (Section 5: "any other set of receivers can be used just as
//! well"; lfr has no light-map UVs). Design: `docs/probes.md`, "Choices beyond the paper".
//!
//! Construction, deterministic for any thread count:
//! 1. the cell size `h = √(A₂ / budget)` from the two-sided surface area `A₂` and the receiver
//!    budget (every surface of lfr shades on both sides, so each side is a surface); with
//!    [`Sides::Valid`] (the precompute's default, [`Surfels::from_geometry_valid`]) the budget is
//!    spent on the valid sides only: a first build at that `h` measures the area `A_valid` of
//!    the surfels a side test does not hide, the cell size becomes `h = √(A_valid / budget)`
//!    (at most 4× finer), and the surfels of the second build that the test hides are dropped;
//! 2. stratified area sampling at `samples_per_cell` samples per `h²`: per triangle
//!    `x = area · density` samples, rounded when `x ≥ 1` (exact area), otherwise one sample with
//!    probability `x` and weight `area / x` (unbiased area on triangles far smaller than a cell);
//!    sample positions from the tracer's Owen-scrambled Sobol' points, seeded per triangle;
//! 3. the samples binned in a hash grid of cell size `h`; inside a cell, per side, greedy
//!    clusters by normal (within 35° of the cluster's first sample) and plane offset
//!    (`|n·Δp| < h/4`). One cluster is one surfel: its area, its area-weighted mean shading
//!    normal, and as position the member nearest its centroid (always on a surface).

use std::collections::HashMap;

use glam::{DVec3, Vec3};
use rayon::prelude::*;
use shading::sampling::{hash_combine, hash_u32, to_unit_float};
use tracer::sampler::Sampler;
use tracer::Scene;

use crate::geometry::{Geometry, Triangle};
use crate::ProbesError;

/// The largest receiver budget accepted (the precompute keeps ~1 kB per receiver).
pub const MAX_RECEIVERS: usize = 20_000_000;
/// The cosine of the largest angle between a cluster's normals (35°).
pub const CLUSTER_COS: f64 = 0.819_152_044_288_992;

/// The most the cell size shrinks when the budget goes to the valid sides only.
pub const MAX_VALID_REFINEMENT: f64 = 4.0;

/// Which surface sides get surfels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sides {
    /// Both sides of every surface, the budget spread over the two-sided area.
    All,
    /// Only the sides a side test does not hide (`transport::side_hidden`: facing the inside
    /// of closed geometry or mostly back faces), the budget spread over their area. Applied by
    /// the layout, which has the flood fill and the rays ([`Surfels::from_geometry_valid`]);
    /// [`Surfels::build`] and [`Surfels::from_geometry`] build every side.
    Valid,
    /// As [`Sides::Valid`], and the sides none of whose test rays hits anything are dropped too
    /// (they see only the sky: E = 0 whatever the lights).
    Seeing,
}

/// How surfels are built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfelSettings {
    /// The number of receivers aimed at (the count is close to it, not equal).
    pub budget: usize,
    /// Area samples per `h²` cell area (stratification of the clustering).
    pub samples_per_cell: f64,
    pub seed: u32,
    /// Which sides the layout keeps (and spends the budget on).
    pub sides: Sides,
}

impl Default for SurfelSettings {
    fn default() -> Self {
        SurfelSettings { budget: crate::defaults::RECEIVERS, samples_per_cell: 8.0, seed: 0, sides: Sides::Valid }
    }
}

impl SurfelSettings {
    pub fn validate(&self) -> Result<(), ProbesError> {
        if self.budget == 0 || self.budget > MAX_RECEIVERS {
            return Err(ProbesError::parameter(
                "receivers",
                format!("must be between 1 and {MAX_RECEIVERS}, got {}", self.budget),
            ));
        }
        if !(self.samples_per_cell >= 1.0 && self.samples_per_cell <= 256.0) {
            return Err(ProbesError::parameter(
                "samples_per_cell",
                format!("must be between 1 and 256, got {}", self.samples_per_cell),
            ));
        }
        Ok(())
    }
}

/// One receiver-and-sender surface element.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surfel {
    /// A point on the surface (the cluster's sample nearest its centroid).
    pub position: Vec3,
    /// Unit normal of the side this surfel is on.
    pub normal: Vec3,
    /// Area of the side it stands for.
    pub area: f32,
    /// The mesh and triangle of the position (for its material).
    pub mesh: u32,
    pub triangle: u32,
}

/// Counts and sizes of a surfel set.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SurfelStats {
    pub surfels: usize,
    /// Sum of the surfels' areas (two-sided surface area).
    pub area: f64,
    /// Cell size.
    pub h: f64,
    /// Area samples drawn (one per point, both sides share it).
    pub samples: usize,
    pub triangles: usize,
    /// Triangles of zero area, skipped.
    pub degenerate_triangles: usize,
    /// Surfels dropped as hidden sides ([`Sides::Valid`]; 0 with [`Sides::All`]).
    pub dropped: usize,
}

/// The surfels, sorted by grid cell, with the grid for lookups.
#[derive(Clone, Debug)]
pub struct Surfels {
    pub surfels: Vec<Surfel>,
    /// Grid origin (the scene's lower bound) and cell size, in f64.
    pub origin: DVec3,
    pub h: f64,
    /// Cell → range of `surfels`.
    pub(crate) cells: HashMap<[i64; 3], (u32, u32)>,
    pub stats: SurfelStats,
}

/// An area sample: position, winding normal, front shading normal, area weight, triangle.
#[derive(Clone, Copy, Debug)]
struct Sample {
    position: DVec3,
    geometric: DVec3,
    shading: DVec3,
    weight: f64,
    triangle: u32,
}

impl Surfels {
    /// Builds the surfels of `scene`.
    pub fn build(scene: &Scene, settings: &SurfelSettings) -> Result<Surfels, ProbesError> {
        settings.validate()?;
        let geometry = Geometry::from_scene(scene)?;
        Surfels::from_geometry(scene, &geometry, settings)
    }

    /// [`Surfels::build`] on already flattened geometry.
    pub fn from_geometry(
        scene: &Scene,
        geometry: &Geometry,
        settings: &SurfelSettings,
    ) -> Result<Surfels, ProbesError> {
        settings.validate()?;
        let one_sided: f64 = geometry.triangles.iter().map(Triangle::area).sum();
        if !(one_sided > 0.0) || !one_sided.is_finite() {
            return Err(ProbesError::EmptyScene);
        }
        let h = (2.0 * one_sided / settings.budget as f64).sqrt();
        Surfels::at_cell_size(scene, geometry, settings, h)
    }

    /// The surfels of the sides that `hidden(index, surfel)` does not hide, the budget spent on
    /// their area (module docs, step 1): a first build at `h = √(A₂ / budget)` gives
    /// `A_valid`, the sum of its valid surfels' areas; the second at
    /// `h = √(A_valid / budget)` (no finer than `h / MAX_VALID_REFINEMENT`) keeps its valid
    /// surfels. `hidden` must be a function of its arguments (the result is then the same for
    /// any thread count). When nothing is valid, or nothing hidden, the first build is kept.
    pub fn from_geometry_valid(
        scene: &Scene,
        geometry: &Geometry,
        settings: &SurfelSettings,
        hidden: &(dyn Fn(u32, &Surfel) -> bool + Sync),
    ) -> Result<Surfels, ProbesError> {
        let first = Surfels::from_geometry(scene, geometry, settings)?;
        let flags = first.hidden_flags(hidden);
        let valid_area: f64 = first.surfels.iter().zip(&flags).filter(|(_, &h)| !h).map(|(s, _)| s.area as f64).sum();
        if !(valid_area > 0.0) || !flags.contains(&true) {
            return Ok(first);
        }
        let h = (valid_area / settings.budget as f64).sqrt().max(first.h / MAX_VALID_REFINEMENT);
        let second = Surfels::at_cell_size(scene, geometry, settings, h)?;
        let flags = second.hidden_flags(hidden);
        Ok(second.retain_valid(&flags))
    }

    /// `hidden` of every surfel, in surfel order.
    fn hidden_flags(&self, hidden: &(dyn Fn(u32, &Surfel) -> bool + Sync)) -> Vec<bool> {
        self.surfels.par_iter().enumerate().map(|(i, s)| hidden(i as u32, s)).collect()
    }

    /// The surfels whose flag is false, still sorted by cell, with the grid rebuilt.
    fn retain_valid(self, hidden: &[bool]) -> Surfels {
        let mut ranges: Vec<([i64; 3], (u32, u32))> = self.cells.into_iter().collect();
        ranges.sort_unstable_by_key(|r| r.1);
        let mut surfels = Vec::with_capacity(self.surfels.len());
        let mut cells = HashMap::new();
        for (c, (a, b)) in ranges {
            let first = surfels.len() as u32;
            surfels.extend((a..b).filter(|&i| !hidden[i as usize]).map(|i| self.surfels[i as usize]));
            if surfels.len() as u32 > first {
                cells.insert(c, (first, surfels.len() as u32));
            }
        }
        let stats = SurfelStats {
            surfels: surfels.len(),
            area: surfels.iter().map(|s| s.area as f64).sum(),
            dropped: self.surfels.len() - surfels.len(),
            ..self.stats
        };
        Surfels { surfels, origin: self.origin, h: self.h, cells, stats }
    }

    /// Every side's surfels at cell size `h`.
    fn at_cell_size(
        scene: &Scene,
        geometry: &Geometry,
        settings: &SurfelSettings,
        h: f64,
    ) -> Result<Surfels, ProbesError> {
        let one_sided: f64 = geometry.triangles.iter().map(Triangle::area).sum();
        let density = settings.samples_per_cell / (h * h);
        let expected_samples = one_sided * density;
        if expected_samples > 64.0 * MAX_RECEIVERS as f64 {
            return Err(ProbesError::TooLarge {
                what: "surfel samples",
                estimate: format!("{expected_samples:.3e}"),
                limit: format!("{:.3e}", 64.0 * MAX_RECEIVERS as f64),
            });
        }
        let seed = settings.seed;
        let per_triangle: Vec<Vec<Sample>> = geometry
            .triangles
            .par_iter()
            .enumerate()
            .map(|(g, t)| sample_triangle(scene, t, g as u32, density, seed))
            .collect();
        let degenerate_triangles = geometry.triangles.iter().filter(|t| t.normal().is_none()).count();
        let samples: Vec<Sample> = per_triangle.into_iter().flatten().collect();
        let origin = geometry.lo;
        let cell_of = |p: DVec3| -> [i64; 3] {
            let c = ((p - origin) / h).floor();
            [c.x as i64, c.y as i64, c.z as i64]
        };
        // Sort by cell, then by sample order: the clustering below sees a fixed order.
        let mut order: Vec<(u32, [i64; 3])> =
            samples.iter().enumerate().map(|(i, s)| (i as u32, cell_of(s.position))).collect();
        order.par_sort_unstable_by(|a, b| a.1.cmp(&b.1).then(a.0.cmp(&b.0)));
        let mut groups: Vec<(usize, usize)> = Vec::new();
        let mut start = 0;
        for i in 1..=order.len() {
            if i == order.len() || order[i].1 != order[start].1 {
                groups.push((start, i));
                start = i;
            }
        }
        let per_cell: Vec<Vec<Surfel>> = groups
            .par_iter()
            .map(|&(a, b)| {
                let members: Vec<&Sample> = order[a..b].iter().map(|&(i, _)| &samples[i as usize]).collect();
                let mut out = cluster_cell(&members, h, 1.0, geometry);
                out.extend(cluster_cell(&members, h, -1.0, geometry));
                out
            })
            .collect();
        let mut surfels = Vec::new();
        let mut cells = HashMap::new();
        for (&(a, _), cell) in groups.iter().zip(per_cell) {
            let first = surfels.len() as u32;
            surfels.extend(cell);
            cells.insert(order[a].1, (first, surfels.len() as u32));
        }
        let stats = SurfelStats {
            surfels: surfels.len(),
            area: surfels.iter().map(|s| s.area as f64).sum(),
            h,
            samples: samples.len(),
            triangles: geometry.triangles.len(),
            degenerate_triangles,
            dropped: 0,
        };
        Ok(Surfels { surfels, origin, h, cells, stats })
    }

    /// The grid cell of `p`.
    pub fn cell_of(&self, p: DVec3) -> [i64; 3] {
        let c = ((p - self.origin) / self.h).floor();
        [c.x as i64, c.y as i64, c.z as i64]
    }

    /// The surfels in cell `c`.
    pub fn in_cell(&self, c: [i64; 3]) -> &[Surfel] {
        match self.cells.get(&c) {
            Some(&(a, b)) => &self.surfels[a as usize..b as usize],
            None => &[],
        }
    }

    /// The index of the first surfel of cell `c` (with [`Surfels::in_cell`]).
    pub(crate) fn cell_start(&self, c: [i64; 3]) -> u32 {
        self.cells.get(&c).map_or(0, |r| r.0)
    }

    pub fn positions(&self) -> Vec<DVec3> {
        self.surfels.iter().map(|s| s.position.as_dvec3()).collect()
    }
}

/// Stratified samples on one triangle (none on a degenerate one).
fn sample_triangle(scene: &Scene, t: &Triangle, g: u32, density: f64, seed: u32) -> Vec<Sample> {
    let Some(geometric) = t.normal() else {
        return Vec::new();
    };
    let area = t.area();
    let x = area * density;
    let (count, weight) = if x >= 1.0 {
        let n = x.round().max(1.0);
        (n as u32, area / n)
    } else {
        let u = to_unit_float(hash_combine(hash_u32(seed ^ 0x5eed_5afe), g)) as f64;
        (u32::from(u < x), area / x)
    };
    let mesh = &scene.meshes[t.mesh as usize];
    let normals = mesh.normals.as_ref().map(|n| mesh.indices[t.index as usize].map(|i| n[i as usize].as_dvec3()));
    let [a, b, c] = t.vertices;
    (0..count)
        .map(|k| {
            let [u, v] = Sampler::new(seed, g, 0x7fff_ffff, k).next_2d();
            let su = (u as f64).sqrt();
            let (b1, b2) = (1.0 - su, v as f64 * su);
            let b0 = 1.0 - b1 - b2;
            let position = a * b0 + b * b1 + c * b2;
            let shading = normals
                .map(|[na, nb, nc]| (na * b0 + nb * b1 + nc * b2).normalize_or_zero())
                .filter(|n| n.dot(geometric) > 0.0)
                .unwrap_or(geometric);
            Sample { position, geometric, shading, weight, triangle: g }
        })
        .collect()
}

/// Greedy clusters of one cell's samples on one side (`side` = ±1 along the winding normal).
fn cluster_cell(members: &[&Sample], h: f64, side: f64, geometry: &Geometry) -> Vec<Surfel> {
    struct Cluster {
        seed_normal: DVec3,
        seed_position: DVec3,
        area: f64,
        weighted_position: DVec3,
        weighted_normal: DVec3,
        members: Vec<usize>,
    }
    let mut clusters: Vec<Cluster> = Vec::new();
    for (i, s) in members.iter().enumerate() {
        let n = s.geometric * side;
        let found = clusters.iter().position(|c| {
            c.seed_normal.dot(n) >= CLUSTER_COS && c.seed_normal.dot(s.position - c.seed_position).abs() < 0.25 * h
        });
        let k = found.unwrap_or_else(|| {
            clusters.push(Cluster {
                seed_normal: n,
                seed_position: s.position,
                area: 0.0,
                weighted_position: DVec3::ZERO,
                weighted_normal: DVec3::ZERO,
                members: Vec::new(),
            });
            clusters.len() - 1
        });
        let cluster = &mut clusters[k];
        cluster.area += s.weight;
        cluster.weighted_position += s.weight * s.position;
        cluster.weighted_normal += s.weight * s.shading * side;
        cluster.members.push(i);
    }
    clusters
        .into_iter()
        .map(|c| {
            let centroid = c.weighted_position / c.area;
            // The member nearest the centroid; near-ties (two equal-weight members are always
            // tied) go to the earlier member, so rounding cannot decide.
            let tie = 1e-6 * h * h;
            let mut nearest = c.members[0];
            let mut best = members[nearest].position.distance_squared(centroid);
            for &m in &c.members[1..] {
                let d = members[m].position.distance_squared(centroid);
                if d < best - tie {
                    nearest = m;
                    best = d;
                }
            }
            let s = members[nearest];
            let normal = c.weighted_normal.try_normalize().unwrap_or(c.seed_normal);
            let t = &geometry.triangles[s.triangle as usize];
            Surfel {
                position: s.position.as_vec3(),
                normal: normal.as_vec3(),
                area: c.area as f32,
                mesh: t.mesh,
                triangle: t.index,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_scenes::{cornell, scaled, scene_of, unit_quad};
    use tracer::scene::Mesh;

    fn build(scene: &Scene, budget: usize) -> Surfels {
        Surfels::build(scene, &SurfelSettings { budget, ..Default::default() }).expect("surfels build")
    }

    #[test]
    fn a_flat_quad_gets_surfels_on_both_sides_covering_its_area() {
        let scene = scene_of(vec![unit_quad()], Vec3::new(0.5, 0.5, 2.0));
        let s = build(&scene, 400);
        assert!((s.h - (2.0f64 / 400.0).sqrt()).abs() < 1e-12);
        for side in [1.0f32, -1.0] {
            let mine: Vec<&Surfel> = s.surfels.iter().filter(|x| x.normal.z * side > 0.0).collect();
            let area: f64 = mine.iter().map(|x| x.area as f64).sum();
            assert!((area - 1.0).abs() < 1e-5, "side {side}: area {area}");
            assert!(mine.len() >= 150 && mine.len() <= 300, "side {side}: {} surfels for a budget of 200", mine.len());
            for x in &mine {
                assert!((x.normal - Vec3::Z * side).length() < 1e-6);
                assert!(
                    x.position.z == 0.0 && (0.0..=1.0).contains(&x.position.x) && (0.0..=1.0).contains(&x.position.y)
                );
            }
            // No gap: every point of the quad has a surfel of this side within 1.5 cells.
            for i in 0..=20 {
                for j in 0..=20 {
                    let p = Vec3::new(i as f32 / 20.0, j as f32 / 20.0, 0.0);
                    let d = mine.iter().map(|x| x.position.distance(p)).fold(f32::INFINITY, f32::min);
                    assert!((d as f64) < 1.5 * s.h, "gap of {d} at {p}");
                }
            }
        }
        assert_eq!(s.surfels.len(), s.stats.surfels);
        assert!((s.stats.area - 2.0).abs() < 1e-5);
    }

    #[test]
    fn cornell_counts_scale_with_the_budget() {
        let scene = cornell();
        let one_sided: f64 =
            scene.meshes.iter().map(|m| (0..m.indices.len()).map(|i| m.triangle_area(i) as f64).sum::<f64>()).sum();
        let small = build(&scene, 2000);
        let large = build(&scene, 8000);
        let ratio = large.surfels.len() as f64 / small.surfels.len() as f64;
        assert!((3.4..4.6).contains(&ratio), "4× the budget gives {ratio}× the surfels");
        for s in [&small, &large] {
            assert!(
                (s.stats.area / (2.0 * one_sided) - 1.0).abs() < 1e-4,
                "area {} vs {}",
                s.stats.area,
                2.0 * one_sided
            );
            let budget = if std::ptr::eq(s, &small) { 2000.0 } else { 8000.0 };
            let n = s.surfels.len() as f64;
            assert!(n > 0.7 * budget && n < 1.6 * budget, "{n} surfels for a budget of {budget}");
            assert!(s.surfels.iter().all(|x| x.position.is_finite() && x.normal.is_normalized() && x.area > 0.0));
        }
    }

    #[test]
    fn degenerate_triangles_are_skipped_and_counted() {
        let mut bad = unit_quad();
        let base = bad.positions.len() as u32;
        bad.positions.extend([Vec3::new(2.0, 0.0, 0.0), Vec3::new(3.0, 0.0, 0.0), Vec3::new(4.0, 0.0, 0.0)]);
        bad.indices.push([base, base + 1, base + 2]); // collinear
        bad.indices.push([base, base, base + 1]); // repeated vertex
        let with = build(&scene_of(vec![bad], Vec3::Z), 400);
        let without = build(&scene_of(vec![unit_quad()], Vec3::Z), 400);
        assert_eq!(with.stats.degenerate_triangles, 2);
        // The bounds grew (origin unchanged), the quad's surfels are the same.
        assert_eq!(with.surfels.len(), without.surfels.len());
        assert!(with.surfels.iter().all(|s| s.position.is_finite() && s.normal.is_finite()));
    }

    #[test]
    fn surfels_are_relative_to_the_scene_size() {
        // Scaling rounds every f32 vertex, so a sample within ~1e-6 of a cell boundary may
        // change cells: the sets agree surfel for surfel up to such rare moves.
        let scene = cornell();
        let reference = build(&scene, 3000);
        for s in [1e-6f32, 1e9] {
            let other = build(&scaled(&scene, s), 3000);
            let (n, m) = (reference.surfels.len() as f64, other.surfels.len() as f64);
            assert!((m / n - 1.0).abs() < 0.01, "scale {s}: {m} surfels against {n}");
            assert!((other.h / reference.h / s as f64 - 1.0).abs() < 1e-5);
            assert!((other.stats.area / reference.stats.area / (s as f64 * s as f64) - 1.0).abs() < 1e-4);
            let tolerance = 1e-5 * 560.0;
            let matched = reference
                .surfels
                .iter()
                .filter(|a| {
                    other.surfels.iter().any(|b| {
                        (b.position / s - a.position).length() < tolerance
                            && (b.normal - a.normal).length() < 1e-5
                            && ((b.area as f64) / (s as f64 * s as f64) / a.area as f64 - 1.0).abs() < 1e-4
                    })
                })
                .count();
            assert!(matched as f64 > 0.98 * n, "scale {s}: {matched} of {n} surfels match");
            assert!(other.surfels.iter().all(|x| x.position.is_finite() && x.normal.is_normalized() && x.area > 0.0));
        }
    }

    /// The valid-side surfels of a floor quad under a sealed slab, with the slab's box, the
    /// sides' exact areas (two-sided, valid) and the all-sides build at the same budget.
    fn floor_and_sealed_slab(budget: usize, threads: usize) -> (Surfels, Surfels, f64, f64) {
        use crate::geometry::Geometry;
        use crate::transport::{side_hidden, SIDE_TEST_RAYS};
        use crate::voxel::VoxelGrid;
        let (lo, hi) = (Vec3::new(0.2, 0.2, 0.4), Vec3::new(0.8, 0.8, 0.6));
        let slab = tracer::scene::shapes::axis_aligned_box("slab", lo, hi, 0);
        let scene = scene_of(vec![unit_quad(), slab], Vec3::new(0.5, 0.5, 2.0));
        let geometry = Geometry::from_scene(&scene).unwrap();
        let accel = tracer::Accel::build(&scene).unwrap();
        let grid = VoxelGrid::build(&geometry, 0.05, &[DVec3::new(0.5, 0.5, 2.0)]).unwrap();
        let settings = SurfelSettings { budget, ..Default::default() };
        let hidden = |i: u32, s: &Surfel| side_hidden(&accel, &grid, s.position, s.normal, i, 0, SIDE_TEST_RAYS, 1.0);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let valid = pool.install(|| Surfels::from_geometry_valid(&scene, &geometry, &settings, &hidden)).unwrap();
        let all = Surfels::from_geometry(&scene, &geometry, &settings).unwrap();
        // The slab's six faces, the floor's one; the slab's inside is never reached.
        let slab_area = 2.0 * (0.6 * 0.6) + 4.0 * (0.6 * 0.2);
        let two_sided = 2.0 * (slab_area + 1.0);
        let valid_area = slab_area + 2.0;
        (valid, all, two_sided, valid_area)
    }

    #[test]
    fn the_budget_goes_to_the_valid_sides_only() {
        let budget = 3000;
        let (valid, all, two_sided, valid_area) = floor_and_sealed_slab(budget, 2);
        let inside = |p: Vec3| p.cmpgt(Vec3::new(0.2, 0.2, 0.4)).all() && p.cmplt(Vec3::new(0.8, 0.8, 0.6)).all();
        // Every side sampled at the old cell size; the slab's inner sides are among them.
        assert!((all.h / (two_sided / budget as f64).sqrt() - 1.0).abs() < 1e-6);
        assert!(all.surfels.iter().filter(|s| inside(s.position - s.normal * 0.01)).count() > 100);
        // No surfel faces the slab's inside; the area kept is the valid sides' exactly.
        for s in &valid.surfels {
            assert!(!inside(s.position + s.normal * 0.01), "a surfel at {} faces the sealed inside", s.position);
        }
        assert!((valid.stats.area / valid_area - 1.0).abs() < 1e-4, "area {} vs {valid_area}", valid.stats.area);
        // The budget lands on that area: h shrinks by √(A₂ / A_valid).
        let expected = (valid_area / budget as f64).sqrt();
        assert!((valid.h / expected - 1.0).abs() < 1e-4, "h {} vs {expected}", valid.h);
        assert!((all.h / valid.h / (two_sided / valid_area).sqrt() - 1.0).abs() < 1e-4);
        let n = valid.surfels.len() as f64;
        assert!(n > 0.7 * budget as f64 && n < 1.6 * budget as f64, "{n} surfels for a budget of {budget}");
        assert_eq!(valid.stats.surfels, valid.surfels.len());
        assert!(valid.stats.dropped > 100 && all.stats.dropped == 0);
        // The grid still finds every surfel in its cell.
        for (i, s) in valid.surfels.iter().enumerate() {
            let c = valid.cell_of(s.position.as_dvec3());
            let first = valid.cell_start(c) as usize;
            assert!((first..first + valid.in_cell(c).len()).contains(&i), "surfel {i} not in its cell");
        }
        // The same surfels for any thread count.
        let (one, ..) = floor_and_sealed_slab(budget, 1);
        assert_eq!(one.surfels, valid.surfels);
        assert_eq!(one.cells, valid.cells);
    }

    #[test]
    fn with_nothing_valid_every_side_is_kept_and_with_everything_valid_nothing_changes() {
        let scene = scene_of(vec![unit_quad()], Vec3::new(0.5, 0.5, 2.0));
        let geometry = Geometry::from_scene(&scene).unwrap();
        let settings = SurfelSettings { budget: 400, ..Default::default() };
        let all = Surfels::from_geometry(&scene, &geometry, &settings).unwrap();
        for verdict in [true, false] {
            let s = Surfels::from_geometry_valid(&scene, &geometry, &settings, &|_, _| verdict).unwrap();
            assert_eq!(s.surfels, all.surfels);
            assert_eq!(s.h, all.h);
            assert_eq!(s.stats.dropped, 0);
        }
        // One side hidden: half the area, h shrinks by √2, no surfel of that side.
        let s = Surfels::from_geometry_valid(&scene, &geometry, &settings, &|_, x| x.normal.z < 0.0).unwrap();
        assert!((all.h / s.h / 2f64.sqrt() - 1.0).abs() < 1e-6);
        assert!(s.surfels.iter().all(|x| x.normal.z > 0.0));
        assert!((s.stats.area - 1.0).abs() < 1e-5);
    }

    #[test]
    fn bad_input_is_a_clear_error() {
        let quad = scene_of(vec![unit_quad()], Vec3::Z);
        let err = Surfels::build(&quad, &SurfelSettings { budget: 0, ..Default::default() }).unwrap_err();
        assert!(err.to_string().starts_with("receivers:"), "{err}");
        let err = Surfels::build(&quad, &SurfelSettings { budget: usize::MAX, ..Default::default() }).unwrap_err();
        assert!(err.to_string().starts_with("receivers:"), "{err}");
        let err =
            Surfels::build(&quad, &SurfelSettings { samples_per_cell: f64::NAN, ..Default::default() }).unwrap_err();
        assert!(err.to_string().starts_with("samples_per_cell:"), "{err}");
        assert_eq!(
            Surfels::build(&scene_of(vec![], Vec3::Z), &SurfelSettings::default()).unwrap_err(),
            ProbesError::EmptyScene
        );
        let flat = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
            indices: vec![[0, 1, 2]],
            ..Default::default()
        };
        assert_eq!(
            Surfels::build(&scene_of(vec![flat], Vec3::Z), &SurfelSettings::default()).unwrap_err(),
            ProbesError::EmptyScene
        );
        let mut moving = unit_quad();
        moving.motion = Vec3::X;
        let err = Surfels::build(&scene_of(vec![moving], Vec3::Z), &SurfelSettings::default()).unwrap_err();
        assert_eq!(err, ProbesError::MovingGeometry { mesh: "quad".into() });
        let mut nan = unit_quad();
        nan.positions[2].y = f32::NAN;
        let err = Surfels::build(&scene_of(vec![nan], Vec3::Z), &SurfelSettings::default()).unwrap_err();
        assert_eq!(err, ProbesError::NonFinite { mesh: "quad".into(), vertex: 2 });
    }
}
