//! RECONSTRUCT(p, ω): the incident radiance (or ambient visibility) along one reconstruction
//! ray, paper Section 2 overview, Sections 2.3.2, 2.4 and 3.3 (design: docs/ilfr-design.md §2,
//! §3 #13).
//!
//! Paper → code:
//! - "we find all input rays whose spatial radius overlaps the ray": the hierarchy's all-hits
//!   walk ([`super::bvh::DiscBvh::collect_hits`], t in (0, ∞) from the ray's origin, which the
//!   caller has lifted off its surface);
//! - "and group them into apparent surfaces using a visibility heuristic": sort and group
//!   ([`super::surfaces::prepare_candidates`], [`super::surfaces::first_surface`]);
//! - "We then reconstruct radiance from the remaining samples": [`super::filter`] on the nearest
//!   surface — [`Reconstructor::radiance`]; for ambient occlusion the distance threshold —
//!   [`Reconstructor::visibility`].
//!
//! A ray that meets no splat has no support. For radiance the result is `None` and the caller
//! decides: the gather ([`super::gather`]) first asks the *sky samples* (input rays that escaped
//! the scene, with the environment radiance they carried) for the one nearest in direction
//! ([`nearest_sky`], design §3 #13), and otherwise leaves the ray out of its average, as the
//! authors do. For visibility, no splat means nothing occludes: 1. Nothing here produces NaN:
//! filter weights are finite in [0, 1] and sums guard against zero.

use super::bvh::{DiscBvh, Kept, SplatHit};
use super::disc::Ray;
use super::filter::{filter_radiance, filter_visibility, FilterMode, Filtered, SplatShading};
use super::surfaces::{first_surface, prepare_candidates, Candidate, Surface, SurfaceParams};
use crate::vector::dot;

/// Per-thread scratch of one reconstruction, reused between rays.
#[derive(Debug, Default)]
pub struct Scratch {
    stack: Vec<u32>,
    ordered_stack: Vec<(u32, f32)>,
    hits: Vec<SplatHit>,
    candidates: Vec<Candidate>,
}

/// Counts over reconstruction rays, for reports.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReconstructStats {
    pub rays: u64,
    /// Rays that met an apparent surface.
    pub surfaces: u64,
    /// Rays that met no splat (or, for radiance, whose surface gave none).
    pub no_surface: u64,
    /// Rays whose surface was filtered by the glossy nearest neighbour.
    pub glossy: u64,
    /// Rays whose chosen surface absorbed small surfaces in front of it (§2.5).
    pub merged_small_surfaces: u64,
    /// Splats collected over all rays.
    pub collected: u64,
    /// Splats in the chosen surfaces over all rays.
    pub surface_members: u64,
    /// Back-facing near-field splats dropped (§2.5, the authors' rule).
    pub near_field_back_faces: u64,
    /// Hierarchy nodes visited and discs tested.
    pub nodes: u64,
    pub discs_tested: u64,
}

impl ReconstructStats {
    pub fn add(&mut self, other: &ReconstructStats) {
        self.rays += other.rays;
        self.surfaces += other.surfaces;
        self.no_surface += other.no_surface;
        self.glossy += other.glossy;
        self.merged_small_surfaces += other.merged_small_surfaces;
        self.collected += other.collected;
        self.surface_members += other.surface_members;
        self.near_field_back_faces += other.near_field_back_faces;
        self.nodes += other.nodes;
        self.discs_tested += other.discs_tested;
    }
}

/// The splats after sizing and shrinking, ready for reconstruction rays.
#[derive(Clone, Copy, Debug)]
pub struct Reconstructor<'a> {
    pub bvh: &'a DiscBvh,
    pub shading: SplatShading<'a>,
    pub surfaces: SurfaceParams,
    pub model: RayModel<'a>,
}

/// What a reconstruction ray reads from the splats.
#[derive(Clone, Copy, Debug)]
pub enum RayModel<'a> {
    /// The paper's: every splat along the ray, grouped into apparent surfaces, the nearest
    /// surface filtered (§2.3.2, §2.4, §3.3).
    ApparentSurfaces,
    /// Beyond the paper: the nearest splat the ray meets ([`NearestSplat`]).
    NearestSplat(NearestSplat<'a>),
}

/// The nearest splat along the ray that it passes within `visibility_scale` of its radius, or
/// where it passes none that closely the nearest it meets at all (a back-facing splat whose
/// centre lies nearer than its radius never counts, as §2.5's near field), read as its
/// `radiance` (by splat id: each splat's radiance filtered over its neighbours,
/// [`super::prefilter`]); for ambient occlusion, occluded iff any splat it meets lies within the
/// radius. The scale plays the part of §2.5's small-surface rule: a ray that clips the rim of a
/// splat in front and meets another surface squarely behind takes that one.
#[derive(Clone, Copy, Debug)]
pub struct NearestSplat<'a> {
    pub radiance: &'a [[f32; 3]],
    pub visibility_scale: f32,
}

impl NearestSplat<'_> {
    /// What the walk makes of `hit` ([`Kept`]).
    #[inline]
    fn keeps(&self, hit: &SplatHit, cull_near_back_faces: bool) -> Kept {
        if cull_near_back_faces && hit.hit.back_facing && hit.hit.depth < hit.radius {
            Kept::No
        } else if hit.hit.spatial < self.visibility_scale * hit.radius {
            Kept::Yes
        } else {
            Kept::Fallback
        }
    }
}

impl Reconstructor<'_> {
    /// The nearest splat [`NearestSplat`] keeps along `ray` within (0, `t_max`) (with `first`,
    /// any one it keeps), counted.
    fn nearest_splat(
        &self,
        model: &NearestSplat,
        ray: &Ray,
        (t_max, first): (f32, bool),
        scratch: &mut Scratch,
        stats: &mut ReconstructStats,
    ) -> Option<SplatHit> {
        stats.rays += 1;
        let cull = self.surfaces.backface_near_field_cull;
        let (hit, walk) =
            self.bvh.nearest_hit(ray, (0.0, t_max), first, &mut scratch.ordered_stack, |h| model.keeps(h, cull));
        stats.nodes += walk.nodes;
        stats.discs_tested += walk.discs_tested;
        match hit {
            Some(_) => {
                stats.surfaces += 1;
                stats.collected += 1;
                stats.surface_members += 1;
            }
            None => stats.no_surface += 1,
        }
        hit
    }

    /// Collects, sorts and groups the splats along `ray`; the nearest surface or `None`.
    fn nearest_surface(&self, ray: &Ray, scratch: &mut Scratch, stats: &mut ReconstructStats) -> Option<Surface> {
        stats.rays += 1;
        let walk = self.bvh.collect_hits(ray, 0.0, f32::INFINITY, &mut scratch.stack, &mut scratch.hits);
        stats.nodes += walk.nodes;
        stats.discs_tested += walk.discs_tested;
        stats.collected += scratch.hits.len() as u64;
        stats.near_field_back_faces +=
            prepare_candidates(self.bvh, &scratch.hits, ray.time, &self.surfaces, &mut scratch.candidates) as u64;
        let surface = first_surface(ray, &scratch.candidates, &self.surfaces);
        match &surface {
            Some(s) => {
                stats.surfaces += 1;
                stats.surface_members += s.members.len() as u64;
                stats.merged_small_surfaces += (s.merged_surfaces > 0) as u64;
            }
            None => stats.no_surface += 1,
        }
        surface
    }

    /// The radiance arriving at `ray.origin` from `ray.direction` (unit), or `None` when the ray
    /// meets no splat.
    pub fn radiance(&self, ray: &Ray, scratch: &mut Scratch, stats: &mut ReconstructStats) -> Option<Filtered> {
        if let RayModel::NearestSplat(model) = &self.model {
            let hit = self.nearest_splat(model, ray, (f32::INFINITY, false), scratch, stats)?;
            let radiance = model.radiance[hit.id as usize];
            return Some(Filtered { radiance, mode: FilterMode::Diffuse, contributors: 1, distance: hit.hit.t });
        }
        let surface = self.nearest_surface(ray, scratch, stats)?;
        let filtered = filter_radiance(ray.direction, &scratch.candidates, &surface, &self.shading);
        match &filtered {
            Some(f) if f.mode == FilterMode::Glossy => stats.glossy += 1,
            Some(_) => {}
            None => stats.no_surface += 1,
        }
        filtered
    }

    /// [`Self::radiance`], or where no splat supports the ray the nearest sky sample within
    /// `min_cosine` of it ([`nearest_sky`]; no fallback without a `min_cosine`); `None` when
    /// neither. `fallbacks` counts the rays that took a sky sample and those left without support.
    pub fn radiance_or_sky(
        &self,
        ray: &Ray,
        (sky, min_cosine): (&[SkySample], Option<f32>),
        scratch: &mut Scratch,
        stats: &mut ReconstructStats,
        fallbacks: &mut SkyFallbacks,
    ) -> Option<[f32; 3]> {
        let found = self.radiance(ray, scratch, stats).map(|f| f.radiance);
        or_sky(found, ray.direction, (sky, min_cosine), fallbacks)
    }

    /// Ambient visibility along `ray` within `ao_radius`: 1 when the nearest apparent surface
    /// lies beyond the radius or there is none, 0 when within it, in between where its splats
    /// disagree (tent-weighted).
    pub fn visibility(&self, ray: &Ray, ao_radius: f32, scratch: &mut Scratch, stats: &mut ReconstructStats) -> f32 {
        if let RayModel::NearestSplat(model) = &self.model {
            let occluded = self.nearest_splat(model, ray, (ao_radius, true), scratch, stats).is_some();
            return if occluded { 0.0 } else { 1.0 };
        }
        match self.nearest_surface(ray, scratch, stats) {
            Some(surface) => filter_visibility(&scratch.candidates, &surface, ao_radius),
            None => 1.0,
        }
    }
}

/// An input ray that escaped the scene: its direction and the environment radiance it carried.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkySample {
    pub direction: [f32; 3],
    pub radiance: [f32; 3],
}

/// Rays without a supporting splat: those a sky sample stood in for, and those left out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SkyFallbacks {
    pub sky_rays: u64,
    pub unsupported_rays: u64,
}

impl SkyFallbacks {
    pub fn add(&mut self, other: &SkyFallbacks) {
        self.sky_rays += other.sky_rays;
        self.unsupported_rays += other.unsupported_rays;
    }
}

/// `found` (the radiance a reconstruction ray met), or where it met nothing the nearest sky
/// sample's within the cosine `min_cosine` of `direction`, counted in `fallbacks`.
pub fn or_sky(
    found: Option<[f32; 3]>,
    direction: [f32; 3],
    (sky, min_cosine): (&[SkySample], Option<f32>),
    fallbacks: &mut SkyFallbacks,
) -> Option<[f32; 3]> {
    if found.is_some() {
        return found;
    }
    let from_sky = min_cosine.and_then(|c| nearest_sky(sky, direction, c));
    if from_sky.is_some() {
        fallbacks.sky_rays += 1;
    } else {
        fallbacks.unsupported_rays += 1;
    }
    from_sky
}

/// The radiance of the sky sample whose direction is nearest to `query` (unit), if its cosine
/// to `query` is at least `min_cosine`; ties by the lower position in `sky`.
pub fn nearest_sky(sky: &[SkySample], query: [f32; 3], min_cosine: f32) -> Option<[f32; 3]> {
    let mut best: Option<(f32, [f32; 3])> = None;
    for s in sky {
        let cosine = dot(s.direction, query);
        let nearer = match best {
            None => true,
            Some((b, _)) => cosine > b,
        };
        if cosine >= min_cosine && nearer {
            best = Some((cosine, s.radiance));
        }
    }
    best.map(|(_, radiance)| radiance)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ilfr::disc::Disc;

    /// Discs of a square lattice on the plane z = `height` (normal +z), spacing 1, radius
    /// `radius`, over [−m, m]²; `value(x, y)` gives each splat's radiance.
    fn lattice(
        height: f32,
        m: i32,
        radius: f32,
        value: impl Fn(f32, f32) -> [f32; 3],
        keep: impl Fn(f32, f32) -> bool,
    ) -> (Vec<Disc>, Vec<[f32; 3]>) {
        let (mut discs, mut radiance) = (Vec::new(), Vec::new());
        for i in -m..=m {
            for j in -m..=m {
                let (x, y) = (i as f32, j as f32);
                if keep(x, y) {
                    discs.push(Disc::new([x, y, height], [0.0, 0.0, 1.0], radius));
                    radiance.push(value(x, y));
                }
            }
        }
        (discs, radiance)
    }

    fn reconstruct(discs: &[Disc], radiance: &[[f32; 3]], ray: &Ray) -> Option<[f32; 3]> {
        let bvh = DiscBvh::build(discs).unwrap();
        let direction = vec![[0.0, 0.0, -1.0]; discs.len()];
        let shading = SplatShading { radiance, direction: &direction, kappa: None };
        let reconstructor =
            Reconstructor { bvh: &bvh, shading, surfaces: SurfaceParams::default(), model: RayModel::ApparentSurfaces };
        let (mut scratch, mut stats) = (Scratch::default(), ReconstructStats::default());
        reconstructor.radiance(ray, &mut scratch, &mut stats).map(|f| f.radiance)
    }

    fn unit(v: [f32; 3]) -> [f32; 3] {
        let l = dot(v, v).sqrt();
        v.map(|c| c / l)
    }

    /// A ray from `from` through the point `(x, y, z)`.
    fn ray_through(from: [f32; 3], target: [f32; 3]) -> Ray {
        Ray {
            time: 0.0,
            origin: from,
            direction: unit([target[0] - from[0], target[1] - from[1], target[2] - from[2]]),
        }
    }

    #[test]
    fn a_plane_of_constant_radiance_comes_back_exactly() {
        let value = [0.3, 7.0, 1e6];
        let (discs, radiance) = lattice(0.0, 8, 2.2, |_, _| value, |_, _| true);
        for (from, target) in [
            ([0.0, 0.0, 5.0], [0.0, 0.0, 0.0]),
            ([3.0, -1.0, 2.0], [0.37, 0.81, 0.0]),
            ([-4.0, 2.5, 0.5], [-1.3, 0.2, 0.0]),
        ] {
            let got = reconstruct(&discs, &radiance, &ray_through(from, target)).unwrap();
            assert_eq!(got, value, "from {from:?} to {target:?}");
        }
    }

    #[test]
    fn a_linear_ramp_comes_back_as_its_tent_average() {
        // L = a + b·x + c·y at the centres. At a symmetry point of the lattice (a lattice point,
        // a cell centre) the tent weights are symmetric, so the average of a linear function is
        // its value there; elsewhere it is Σ w L / Σ w with w = 1 − s/r, summed here by brute
        // force in f64 over every disc (own plane intersection).
        let (a, b, c) = (2.0f64, 0.5f64, -0.25f64);
        let ramp = |x: f32, y: f32| [(a + b * x as f64 + c * y as f64) as f32; 3];
        let radius = 2.2f32;
        let (discs, radiance) = lattice(0.0, 8, radius, ramp, |_, _| true);
        for (target, from) in
            [([0.0f32, 0.0], [1.0f32, 2.0, 4.0]), ([0.5, 0.5], [-2.0, 1.0, 3.0]), ([1.0, -2.0], [0.0, 0.0, 6.0])]
        {
            let got = reconstruct(&discs, &radiance, &ray_through(from, [target[0], target[1], 0.0])).unwrap();
            let expected = a + b * target[0] as f64 + c * target[1] as f64;
            assert!((got[0] as f64 - expected).abs() < 1e-5, "{target:?}: {got:?} vs {expected}");
        }
        for (target, from) in [([0.3f64, 0.1f64], [1.0f64, 2.0, 4.0]), ([-0.77, 1.41], [2.0, -3.0, 1.5])] {
            let ray = ray_through(from.map(|v| v as f32), [target[0] as f32, target[1] as f32, 0.0]);
            let got = reconstruct(&discs, &radiance, &ray).unwrap();
            // The ray meets z = 0 at `target`; every disc lies on that plane.
            let (mut sum, mut weight) = (0.0f64, 0.0f64);
            for i in -8..=8 {
                for j in -8..=8 {
                    let s = ((target[0] - i as f64).powi(2) + (target[1] - j as f64).powi(2)).sqrt();
                    if s < radius as f64 {
                        let w = 1.0 - s / radius as f64;
                        sum += w * (a + b * i as f64 + c * j as f64);
                        weight += w;
                    }
                }
            }
            let expected = sum / weight;
            let plain = a + b * target[0] + c * target[1];
            assert!((got[0] as f64 - expected).abs() < 1e-5, "{target:?}: {got:?} vs {expected}");
            assert!((expected - plain).abs() < 0.05, "the tent average stays near the ramp: {expected} vs {plain}");
        }
    }

    #[test]
    fn a_surface_behind_a_front_one_does_not_leak() {
        // Front plane z = 1 (radiance 1) with a hole of radius 3 around (4, 4); back plane z = 0
        // (radiance 100) everywhere; rays from above.
        let hole = |x: f32, y: f32| ((x - 4.0).powi(2) + (y - 4.0).powi(2)).sqrt() < 3.0;
        let (mut discs, mut radiance) = lattice(1.0, 8, 1.6, |_, _| [1.0; 3], |x, y| !hole(x, y));
        let (back, back_radiance) = lattice(0.0, 8, 1.6, |_, _| [100.0; 3], |_, _| true);
        discs.extend(back);
        radiance.extend(back_radiance);
        for target in [[0.0, 0.0], [-3.3, 2.7], [1.5, -5.1]] {
            let ray = ray_through([0.5, 0.2, 4.0], [target[0], target[1], 1.0]);
            assert_eq!(reconstruct(&discs, &radiance, &ray), Some([1.0; 3]), "{target:?}");
        }
        // Through the hole: the back plane.
        let ray = ray_through([4.0, 4.0, 4.0], [4.2, 3.9, 0.0]);
        assert_eq!(reconstruct(&discs, &radiance, &ray), Some([100.0; 3]));
    }

    #[test]
    fn nothing_hit_gives_no_radiance_full_visibility_and_the_sky_fallback() {
        let (discs, radiance) = lattice(0.0, 3, 1.6, |_, _| [5.0; 3], |_, _| true);
        let bvh = DiscBvh::build(&discs).unwrap();
        let direction = vec![[0.0, 0.0, -1.0]; discs.len()];
        let shading = SplatShading { radiance: &radiance, direction: &direction, kappa: None };
        let reconstructor =
            Reconstructor { bvh: &bvh, shading, surfaces: SurfaceParams::default(), model: RayModel::ApparentSurfaces };
        let (mut scratch, mut stats) = (Scratch::default(), ReconstructStats::default());
        // Upwards from above the plane, and downwards beside it.
        for ray in [
            Ray { time: 0.0, origin: [0.0, 0.0, 1.0], direction: [0.0, 0.0, 1.0] },
            ray_through([10.0, 10.0, 1.0], [10.0, 10.5, 0.0]),
        ] {
            assert_eq!(reconstructor.radiance(&ray, &mut scratch, &mut stats), None);
            assert_eq!(reconstructor.visibility(&ray, 100.0, &mut scratch, &mut stats), 1.0);
        }
        assert_eq!((stats.rays, stats.no_surface), (4, 4));
        // Visibility of the plane itself: within the radius → 0, beyond → 1.
        let down = Ray { time: 0.0, origin: [0.0, 0.0, 1.0], direction: [0.0, 0.0, -1.0] };
        assert_eq!(reconstructor.visibility(&down, 2.0, &mut scratch, &mut stats), 0.0);
        assert_eq!(reconstructor.visibility(&down, 0.5, &mut scratch, &mut stats), 1.0);

        let sky = [
            SkySample { direction: [0.0, 0.0, 1.0], radiance: [1.0; 3] },
            SkySample { direction: unit([1.0, 0.0, 1.0]), radiance: [2.0; 3] },
        ];
        let near_second = unit([0.9, 0.1, 1.0]);
        assert_eq!(nearest_sky(&sky, near_second, 0.5), Some([2.0; 3]));
        assert_eq!(nearest_sky(&sky, [0.0, 0.0, 1.0], 0.5), Some([1.0; 3]));
        assert_eq!(nearest_sky(&sky, [0.0, 1.0, 0.0], 0.5), None, "nothing within the angle");
        assert_eq!(nearest_sky(&[], [0.0, 1.0, 0.0], -1.0), None);
    }
}
