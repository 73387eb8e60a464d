//! Light sampling for next-event estimation.
//!
//! The emitters fall in two kinds. *Local* emitters (emissive triangles and tessellated sphere
//! lights) form one table, chosen within it in proportion to emitted power. *Distant and
//! punctual* emitters (point, spot and directional lights, the constant environment) each stand
//! alone. At every shading point one of these candidates (the local table or one light) is
//! chosen in proportion to an estimate of the irradiance it delivers there: I/d² for point and
//! spot lights, E for a directional light, πL for the environment, and for the local table its
//! emitters' summed peak intensity over the squared distance to their centre (at least their
//! spread), mixed with 5 % uniform choice so that no light is ever left out. None of these grows
//! with the scene's size (the power of the environment and the sun used to be weighted by the
//! scene's bounding radius², so that a large floor took samples from the real light).
//!
//! Emissive triangles are sampled uniformly by area and converted to solid angle; a sphere light
//! seen from outside is sampled uniformly in the cone of directions its inscribed sphere
//! subtends (every such direction hits the tessellation's near side), from inside by area; the
//! environment uniformly over the sphere. A rectangle light (a static quad of constant emission)
//! is sampled uniformly in the solid angle it subtends from nearby points (Ureña et al. 2013,
//! `RectangleEmitter`), by area from far away. `pdf_*` functions give the densities the
//! integrator needs for multiple importance sampling when a BSDF-sampled ray hits an emitter. Sampling
//! by power alone stays available as [`LightStrategy::Legacy`], the oracle of the tests.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::bsdf::luminance;
use crate::scene::{PunctualLight, Scene};

#[derive(Clone, Debug)]
enum Emitter {
    Triangle(EmissiveTriangle),
    Sphere(SphereEmitter),
    Rectangle(RectangleEmitter),
    Punctual(PunctualLight),
    Environment,
}

/// How emitters are chosen and sampled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LightStrategy {
    /// By the irradiance each candidate delivers at the shading point, sphere lights by solid
    /// angle (see the module documentation).
    #[default]
    ByContribution,
    /// Sampling by power alone: one table over every emitter by power, the environment's
    /// and directional lights' power taken over the scene's bounding sphere, sphere lights
    /// sampled over their whole surface. Same expected value; the tests' oracle, built only for
    /// tests (`cfg(test)`, or the `oracles` feature that the dev-only `testkit` turns on).
    #[cfg(any(test, feature = "oracles"))]
    Legacy,
}

impl LightStrategy {
    /// Whether this is the power-only oracle (`Legacy`); never in a product build.
    fn is_power_only(self) -> bool {
        #[cfg(any(test, feature = "oracles"))]
        return self == LightStrategy::Legacy;
        #[cfg(not(any(test, feature = "oracles")))]
        return false;
    }
}

/// Which table entries a mesh's emission lives in.
#[derive(Clone, Copy, Debug)]
enum MeshEntry {
    /// One entry per triangle, from this index.
    Triangles(u32),
    /// One sphere entry.
    Sphere(u32),
    /// One rectangle entry.
    Rectangle(u32),
}

/// Solid angles (sr) between which a rectangle light is sampled by solid angle: below, f32/f64
/// cancellation in Ω = Σγ − 2π makes the spherical rectangle inaccurate (the light is a speck
/// and area sampling is as good), above, the point nearly touches the rectangle and the
/// inversion loses precision (pbrt-v4 uses the same kind of bounds, 3·10⁻⁴ and 6.22).
const RECTANGLE_MIN_SOLID_ANGLE: f64 = 1e-4;
const RECTANGLE_MAX_SOLID_ANGLE: f64 = 6.0;

/// Farther from a rectangle light's centre than this many of its diagonals, it is sampled by
/// area: cos/r² then varies little over the rectangle, so solid-angle sampling gains almost
/// nothing there, and it costs (f64 angles, four `acos` per sample and again per MIS pdf) about
/// a quarter of a Cornell box render's time when used everywhere (docs/performance.md).
const RECTANGLE_SOLID_ANGLE_REACH: f32 = 2.0;

/// A static rectangle light with constant emission: a mesh of two triangles that share a
/// diagonal and whose four corners form a rectangle (a TOML polygon of four points, an OBJ or
/// glTF quad). Sampled uniformly in the solid angle it subtends (Ureña, Fajardo and King 2013,
/// "An area-preserving parametrization for spherical rectangles"), so that the sample density
/// follows the light's apparent size instead of its area: no 1/r² spikes near the light and
/// no samples wasted on its far, foreshortened part. Beyond [`RECTANGLE_SOLID_ANGLE_REACH`]
/// diagonals from its centre (where that gains little) and outside the solid angles
/// [`RECTANGLE_MIN_SOLID_ANGLE`]..[`RECTANGLE_MAX_SOLID_ANGLE`] it is sampled by area.
#[derive(Clone, Debug)]
struct RectangleEmitter {
    mesh: u32,
    /// One corner and the two orthogonal edges leaving it.
    corner: Vec3,
    edge_x: Vec3,
    edge_y: Vec3,
    /// Unit front normal (counter-clockwise winding of the triangles).
    normal: Vec3,
    area: f32,
    /// Centre, and the squared distance from it within which it is sampled by solid angle.
    center: Vec3,
    reach2: f32,
    emission: Vec3,
    two_sided: bool,
}

/// What sampling a rectangle by solid angle from one point needs (Ureña et al. 2013, §4), in
/// double precision: the local frame (x, y along the edges, z towards the rectangle's plane
/// from the point), the rectangle's extent in it and the spherical rectangle's angles.
struct SphericalRectangle {
    x_axis: glam::DVec3,
    y_axis: glam::DVec3,
    z_axis: glam::DVec3,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    z0: f64,
    /// z components of the normals of the planes through the point and the edges y = y0 and
    /// y = y1.
    b0: f64,
    b1: f64,
    /// The interior angles, and the solid angle Σγ − 2π.
    gamma: [f64; 4],
    solid_angle: f64,
}

impl RectangleEmitter {
    /// The rectangle emitter of mesh `mesh`, when it qualifies (see [`RectangleEmitter`]).
    fn new(scene: &Scene, mesh: u32) -> Option<RectangleEmitter> {
        let m = &scene.meshes[mesh as usize];
        let material = &scene.materials[m.material as usize];
        if m.indices.len() != 2 || m.is_moving() || (material.emission_texture.is_some() && m.uvs.is_some()) {
            return None;
        }
        let corners = |t: usize| m.indices[t].map(|i| m.positions[i as usize]);
        let (first, second) = (corners(0), corners(1));
        // The diagonal: the two corners both triangles have; the others are opposite corners.
        let shared: Vec<Vec3> = first.iter().copied().filter(|p| second.contains(p)).collect();
        if shared.len() != 2 {
            return None;
        }
        let own = first.iter().copied().find(|p| !shared.contains(p))?;
        let other = second.iter().copied().find(|p| !shared.contains(p))?;
        let (edge_x, edge_y) = (shared[0] - own, shared[1] - own);
        let (lx, ly) = (edge_x.length(), edge_y.length());
        let size = lx.max(ly);
        let rectangular = edge_x.dot(edge_y).abs() <= 1e-5 * lx * ly
            && (own + edge_x + edge_y - other).length() <= 1e-5 * size
            && lx > 0.0
            && ly > 0.0;
        let normal_of = |[a, b, c]: [Vec3; 3]| shading::triangle_normal_and_area(a, b, c).0;
        let normal = normal_of(first);
        if !rectangular || normal == Vec3::ZERO || normal.dot(normal_of(second)) < 0.999 {
            return None;
        }
        Some(RectangleEmitter {
            mesh,
            corner: own,
            edge_x,
            edge_y,
            normal,
            area: lx * ly,
            center: own + 0.5 * (edge_x + edge_y),
            reach2: RECTANGLE_SOLID_ANGLE_REACH * RECTANGLE_SOLID_ANGLE_REACH * (lx * lx + ly * ly),
            emission: material.emission,
            two_sided: material.two_sided_emission,
        })
    }

    /// Whether `point` sees the emitting side.
    fn lit_side(&self, point: Vec3) -> bool {
        let height = (point - self.corner).dot(self.normal);
        height > 0.0 || (self.two_sided && height < 0.0)
    }

    /// The spherical rectangle seen from `point`, when the point is within reach and the solid
    /// angle in the range sampled by solid angle.
    fn spherical(&self, point: Vec3) -> Option<SphericalRectangle> {
        use glam::DVec3;
        if !((point - self.center).length_squared() <= self.reach2) {
            return None;
        }
        let (lx, ly) = (self.edge_x.as_dvec3().length(), self.edge_y.as_dvec3().length());
        let x_axis = self.edge_x.as_dvec3() / lx;
        let y_axis = self.edge_y.as_dvec3() / ly;
        let mut z_axis = x_axis.cross(y_axis);
        let d = (self.corner - point).as_dvec3();
        let (x0, y0, mut z0) = (d.dot(x_axis), d.dot(y_axis), d.dot(z_axis));
        if z0 > 0.0 {
            z_axis = -z_axis;
            z0 = -z0;
        }
        if !(z0 < 0.0) {
            return None;
        }
        let (x1, y1) = (x0 + lx, y0 + ly);
        let v00 = DVec3::new(x0, y0, z0);
        let v01 = DVec3::new(x0, y1, z0);
        let v10 = DVec3::new(x1, y0, z0);
        let v11 = DVec3::new(x1, y1, z0);
        let n0 = v00.cross(v10).normalize();
        let n1 = v10.cross(v11).normalize();
        let n2 = v11.cross(v01).normalize();
        let n3 = v01.cross(v00).normalize();
        let angle = |a: DVec3, b: DVec3| (-a).dot(b).clamp(-1.0, 1.0).acos();
        let gamma = [angle(n0, n1), angle(n1, n2), angle(n2, n3), angle(n3, n0)];
        let solid_angle = gamma.iter().sum::<f64>() - 2.0 * std::f64::consts::PI;
        if !(RECTANGLE_MIN_SOLID_ANGLE..=RECTANGLE_MAX_SOLID_ANGLE).contains(&solid_angle) {
            return None;
        }
        Some(SphericalRectangle { x_axis, y_axis, z_axis, x0, x1, y0, y1, z0, b0: n0.z, b1: n2.z, gamma, solid_angle })
    }

    /// Samples a point of the rectangle seen from `point` (selection probability `select`).
    fn sample(&self, point: Vec3, select: f32, u: [f32; 2]) -> Option<LightSample> {
        if !self.lit_side(point) {
            return None;
        }
        let Some(q) = self.spherical(point) else {
            // By area.
            let p = self.corner + self.edge_x * u[0] + self.edge_y * u[1];
            let to_light = p - point;
            let dist2 = to_light.length_squared();
            let distance = dist2.sqrt();
            let wi = to_light / distance;
            let cos_light = self.normal.dot(wi).abs();
            if !(dist2 > 0.0) || cos_light <= 1e-7 {
                return None;
            }
            let pdf = select * dist2 / (self.area * cos_light);
            return Some(LightSample {
                wi,
                distance,
                weighted_radiance: self.emission / pdf,
                pdf: Some(pdf),
                mesh: Some(self.mesh),
            });
        };
        let tau = 2.0 * std::f64::consts::PI;
        let [g0, g1, g2, g3] = q.gamma;
        let (u0, u1) = (u[0] as f64, u[1] as f64);
        // The azimuth of the sample's plane through the point (Ureña et al., Eq. 6–9) ...
        let au = u0 * (g0 + g1 - tau) + (u0 - 1.0) * (g2 + g3);
        let fu = (au.cos() * q.b0 - q.b1) / au.sin();
        let cu = (1.0 / (fu * fu + q.b0 * q.b0).sqrt()).copysign(fu).clamp(-1.0 + 1e-12, 1.0 - 1e-12);
        let xu = (-(cu * q.z0) / (1.0 - cu * cu).max(0.0).sqrt()).clamp(q.x0, q.x1);
        // ... and the height along it, uniform in the projected y (Eq. 10–11).
        let dd = (xu * xu + q.z0 * q.z0).sqrt();
        let h0 = q.y0 / (dd * dd + q.y0 * q.y0).sqrt();
        let h1 = q.y1 / (dd * dd + q.y1 * q.y1).sqrt();
        let hv = h0 + u1 * (h1 - h0);
        let hv2 = hv * hv;
        let yv = if hv2 < 1.0 - 1e-12 { (hv * dd / (1.0 - hv2).sqrt()).clamp(q.y0, q.y1) } else { q.y1 };
        let offset = q.x_axis * xu + q.y_axis * yv + q.z_axis * q.z0;
        let distance = offset.length();
        if !(distance > 0.0) || !xu.is_finite() || !yv.is_finite() {
            return None;
        }
        let wi = (offset / distance).as_vec3();
        let pdf = select / q.solid_angle as f32;
        Some(LightSample {
            wi,
            distance: distance as f32,
            weighted_radiance: self.emission / pdf,
            pdf: Some(pdf),
            mesh: Some(self.mesh),
        })
    }

    /// The density (without selection) of [`RectangleEmitter::sample`] choosing the point
    /// `hit` of the rectangle from `from`.
    fn pdf(&self, from: Vec3, hit: Vec3) -> f32 {
        if !self.lit_side(from) {
            return 0.0;
        }
        if let Some(q) = self.spherical(from) {
            return (1.0 / q.solid_angle) as f32;
        }
        let to_light = hit - from;
        let dist2 = to_light.length_squared();
        let cos_light = self.normal.dot(to_light / dist2.sqrt()).abs();
        if !(dist2 > 0.0) || cos_light <= 1e-7 {
            return 0.0;
        }
        dist2 / (self.area * cos_light)
    }
}

/// A tessellated sphere light (a closed, convex, static mesh with vertices on a sphere and
/// constant emission). From a point outside its circumscribed sphere it is sampled uniformly in
/// the cone of its inscribed sphere: every direction in that cone hits the mesh, and the
/// thin rim of directions between the two cones is left to BSDF sampling (pdf 0 here, so MIS
/// gives BSDF samples there full weight). From inside, by area over its triangles.
#[derive(Clone, Debug)]
struct SphereEmitter {
    mesh: u32,
    center: Vec3,
    /// Smallest distance from the centre to a triangle's plane.
    radius_in: f32,
    /// Largest distance from the centre to a vertex.
    radius_out: f32,
    emission: Vec3,
    triangles: Vec<EmissiveTriangle>,
    /// Cumulative area fractions of `triangles` (last = 1).
    cdf: Vec<f32>,
    area: f32,
}

impl SphereEmitter {
    /// The sphere emitter of mesh `mesh`, when it qualifies (see [`SphereEmitter`]).
    fn new(scene: &Scene, mesh: u32) -> Option<SphereEmitter> {
        let m = &scene.meshes[mesh as usize];
        let shape = m.sphere?;
        let material = &scene.materials[m.material as usize];
        if m.indices.len() != shape.triangles || m.is_moving() || material.emission_texture.is_some() {
            return None;
        }
        let center = shape.center;
        let triangles: Vec<EmissiveTriangle> =
            (0..m.indices.len() as u32).map(|t| EmissiveTriangle::new(scene, mesh, t)).collect();
        let mut radius_in = f32::INFINITY;
        for t in &triangles {
            // Outward-facing, at a positive distance from the centre: else not what we assume.
            let distance = t.normal.dot(t.corner - center);
            if !(t.area > 0.0) || !(distance > 0.0) {
                return None;
            }
            radius_in = radius_in.min(distance);
        }
        let radius_out = m.positions.iter().map(|p| (*p - center).length()).fold(0.0f32, f32::max);
        if !(radius_in > 0.0 && radius_out.is_finite()) {
            return None;
        }
        let area: f64 = triangles.iter().map(|t| t.area as f64).sum();
        let mut running = 0.0f64;
        let mut cdf: Vec<f32> = triangles
            .iter()
            .map(|t| {
                running += t.area as f64;
                (running / area) as f32
            })
            .collect();
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        Some(SphereEmitter {
            mesh,
            center,
            radius_in,
            radius_out,
            emission: material.emission,
            triangles,
            cdf,
            area: area as f32,
        })
    }

    /// Whether `point` is far enough outside for cone sampling, and if so the cone's
    /// 1 − cos θmax and the unit direction and distance to the centre.
    fn cone(&self, point: Vec3) -> Option<(f32, Vec3, f32)> {
        let to_center = self.center - point;
        let d2 = to_center.length_squared();
        let outside = self.radius_out * (1.0 + 1e-3);
        if !(d2 > outside * outside) {
            return None;
        }
        let sin2 = (self.radius_in * self.radius_in / d2).min(1.0);
        let cos_max = (1.0 - sin2).max(0.0).sqrt();
        let one_minus_cos = sin2 / (1.0 + cos_max);
        let d = d2.sqrt();
        (one_minus_cos > 0.0).then_some((one_minus_cos, to_center / d, d))
    }

    /// Samples a direction towards the sphere from `point` (selection probability `select`);
    /// `u_pick` chooses a triangle when the point is inside.
    fn sample(&self, scene: &Scene, point: Vec3, select: f32, u_pick: f32, u: [f32; 2]) -> Option<LightSample> {
        let Some((one_minus_cos, axis, d)) = self.cone(point) else {
            let index = self.cdf.partition_point(|&c| c <= u_pick).min(self.triangles.len() - 1);
            let (sample, (dist2, cos_light)) = sample_triangle(scene, &self.triangles[index], point, 0.0, u)?;
            // The triangle's share of the area times its own area pdf: the sphere's area pdf.
            let pdf = select * dist2 / (self.area * cos_light);
            return Some(LightSample { pdf: Some(pdf), weighted_radiance: sample.weighted_radiance / pdf, ..sample });
        };
        let one_minus_cos_theta = u[0] * one_minus_cos;
        let cos_theta = 1.0 - one_minus_cos_theta;
        let sin_theta = (one_minus_cos_theta * (2.0 - one_minus_cos_theta)).max(0.0).sqrt();
        let phi = 2.0 * PI * u[1];
        let (tangent, bitangent) = axis.any_orthonormal_pair();
        let wi =
            (tangent * (sin_theta * phi.cos()) + bitangent * (sin_theta * phi.sin()) + axis * cos_theta).normalize();
        // The near intersection with the circumscribed sphere, which lies before the mesh: the
        // shadow ray stops there.
        let b = d * cos_theta;
        let disc = (self.radius_out * self.radius_out - d * d * sin_theta * sin_theta).max(0.0);
        let distance = b - disc.sqrt();
        if !(distance > 0.0) {
            return None;
        }
        let pdf = select / (2.0 * PI * one_minus_cos);
        Some(LightSample {
            wi,
            distance,
            weighted_radiance: self.emission / pdf,
            pdf: Some(pdf),
            mesh: Some(self.mesh),
        })
    }

    /// The density (without selection) of [`SphereEmitter::sample`] choosing the point `hit`
    /// of triangle `triangle` from `from`.
    fn pdf(&self, triangle: u32, from: Vec3, hit: Vec3) -> f32 {
        match self.cone(from) {
            Some((one_minus_cos, axis, _)) => {
                let direction = (hit - from).normalize_or_zero();
                let cos_max = 1.0 - one_minus_cos;
                if direction.dot(axis) >= cos_max {
                    1.0 / (2.0 * PI * one_minus_cos)
                } else {
                    0.0
                }
            }
            None => {
                let Some(t) = self.triangles.get(triangle as usize) else { return 0.0 };
                let to_light = hit - from;
                let dist2 = to_light.length_squared();
                let cos_light = t.normal.dot(to_light / dist2.sqrt()).abs();
                if !(dist2 > 0.0) || cos_light <= 1e-7 {
                    return 0.0;
                }
                dist2 / (self.area * cos_light)
            }
        }
    }
}

/// An emissive triangle with what sampling it needs, computed once when the table is built
/// instead of at every shading point: its corner `a` and edges at shutter open, its unit
/// normal (counter-clockwise winding) and area, and its emission when no texture modulates it.
/// Motion is a translation, so only the corner moves with time.
#[derive(Clone, Debug)]
struct EmissiveTriangle {
    mesh: u32,
    triangle: u32,
    corner: Vec3,
    edge_b: Vec3,
    edge_c: Vec3,
    motion: Vec3,
    normal: Vec3,
    area: f32,
    /// Emission towards either side (`two_sided`) or the front side; `None` when a texture
    /// modulates it and `triangle_emission` must look it up.
    constant_emission: Option<Vec3>,
    two_sided: bool,
}

impl EmissiveTriangle {
    fn new(scene: &Scene, mesh: u32, triangle: u32) -> EmissiveTriangle {
        let [a, b, c] = triangle_at(scene, mesh, triangle, 0.0);
        let m = &scene.meshes[mesh as usize];
        let material = &scene.materials[m.material as usize];
        let (normal, area) = shading::triangle_normal_and_area(a, b, c);
        let textured = material.emission_texture.is_some() && m.uvs.is_some();
        EmissiveTriangle {
            mesh,
            triangle,
            corner: a,
            edge_b: b - a,
            edge_c: c - a,
            motion: m.motion,
            normal,
            area,
            constant_emission: (!textured).then_some(material.emission),
            two_sided: material.two_sided_emission,
        }
    }
}

/// Light arriving at a point from one sampled emitter.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point towards the light.
    pub wi: Vec3,
    /// Distance to the light sample (infinite for directional and environment light).
    pub distance: f32,
    /// Incident radiance (or irradiance-like quantity for delta lights) divided by the
    /// solid-angle pdf including the selection probability.
    pub weighted_radiance: Vec3,
    /// Solid-angle pdf including selection; `None` for delta lights (no MIS).
    pub pdf: Option<f32>,
    /// The emissive mesh the point lies on (`None` for punctual and environment light).
    pub mesh: Option<u32>,
}

/// The emitter table and how to choose from it (see the module documentation).
pub struct LightSampler {
    strategy: LightStrategy,
    /// The table's entries first (`..table_len`), then the separately chosen lights.
    emitters: Vec<Emitter>,
    table_len: usize,
    /// Cumulative selection probabilities within the table (last = 1).
    cdf: Vec<f32>,
    /// Selection probability of each table entry within the table.
    probability: Vec<f32>,
    /// The table's summed peak intensity (luminance × projected area), its intensity-weighted
    /// centre and the squared spread around it, for the irradiance estimate.
    table_intensity: f32,
    table_center: Vec3,
    table_spread2: f32,
    /// For each mesh, where its emission lives in the table.
    mesh_entry: Vec<Option<MeshEntry>>,
    environment_index: Option<u32>,
    environment_luminance: f32,
}

/// Share of the choice among candidates made uniformly, so that none is ever left out.
const UNIFORM_SHARE: f32 = 0.05;

/// The triangle sampled uniformly by area from `point` at time `time`: the sample with its
/// emitted radiance as `weighted_radiance` and no pdf, and (dist², cos at the light), whose
/// ratio is the solid-angle density times the triangle's area; `None` when nothing arrives.
fn sample_triangle(
    scene: &Scene,
    emitter: &EmissiveTriangle,
    point: Vec3,
    time: f32,
    u: [f32; 2],
) -> Option<(LightSample, (f32, f32))> {
    if !(emitter.area > 0.0) {
        return None;
    }
    // Uniform point on the triangle; (b1, b2) are Embree's (u, v) barycentrics.
    let su = u[0].sqrt();
    let b1 = u[1] * su;
    let b2 = su - b1;
    let p = emitter.corner + emitter.motion * time + emitter.edge_b * b1 + emitter.edge_c * b2;
    let to_light = p - point;
    let dist2 = to_light.length_squared();
    if !(dist2 > 0.0) {
        return None;
    }
    let distance = dist2.sqrt();
    let wi = to_light / distance;
    let cos_signed = emitter.normal.dot(-wi);
    let cos_light = cos_signed.abs();
    if cos_light <= 1e-7 {
        return None;
    }
    let le = match emitter.constant_emission {
        Some(emission) if emitter.two_sided || cos_signed > 0.0 => emission,
        Some(_) => return None,
        None => triangle_emission(scene, emitter.mesh, emitter.triangle, Vec2::new(b1, b2), emitter.normal, -wi),
    };
    if le == Vec3::ZERO {
        return None;
    }
    let sample = LightSample { wi, distance, weighted_radiance: le, pdf: None, mesh: Some(emitter.mesh) };
    Some((sample, (dist2, cos_light)))
}

/// Barycentric interpolation helper: the triangle's vertices at ray time `time`.
pub fn triangle_at(scene: &Scene, mesh: u32, triangle: u32, time: f32) -> [Vec3; 3] {
    let m = &scene.meshes[mesh as usize];
    let [a, b, c] = m.indices[triangle as usize];
    let shift = m.motion * time;
    [m.positions[a as usize] + shift, m.positions[b as usize] + shift, m.positions[c as usize] + shift]
}

/// Emitted radiance of a mesh triangle at barycentrics (u, v) towards `wo` (unit, pointing away
/// from the surface); `geometric_normal` follows the triangle's winding.
pub fn triangle_emission(
    scene: &Scene,
    mesh: u32,
    triangle: u32,
    bary: Vec2,
    geometric_normal: Vec3,
    wo: Vec3,
) -> Vec3 {
    let m = &scene.meshes[mesh as usize];
    let material = &scene.materials[m.material as usize];
    if !material.is_emissive() {
        return Vec3::ZERO;
    }
    if !material.two_sided_emission && geometric_normal.dot(wo) <= 0.0 {
        return Vec3::ZERO;
    }
    let mut emission = material.emission;
    if let (Some(tex), Some(uvs)) = (&material.emission_texture, &m.uvs) {
        let [a, b, c] = m.indices[triangle as usize];
        let uv = uvs[a as usize] * (1.0 - bary.x - bary.y) + uvs[b as usize] * bary.x + uvs[c as usize] * bary.y;
        let texel = scene.textures[tex.index as usize].sample(tex.apply(uv));
        emission *= texel.truncate();
    }
    emission
}

impl LightSampler {
    pub fn new(scene: &Scene) -> LightSampler {
        LightSampler::with_strategy(scene, LightStrategy::default())
    }

    pub fn with_strategy(scene: &Scene, strategy: LightStrategy) -> LightSampler {
        let legacy = strategy.is_power_only();
        let (lo, hi) = scene.bounds();
        let radius = (0.5 * (hi - lo).length()).max(1e-3);
        let mut emitters = Vec::new();
        let mut power = Vec::new();
        // Peak intensity and centre of each table entry, for the table's irradiance estimate.
        let mut intensity = Vec::new();
        let mut mesh_entry = vec![None; scene.meshes.len()];
        for (mi, mesh) in scene.meshes.iter().enumerate() {
            let material = &scene.materials[mesh.material as usize];
            if !material.is_emissive() {
                continue;
            }
            let sides = if material.two_sided_emission { 2.0 } else { 1.0 };
            let lum = luminance(material.emission);
            if !legacy {
                if let Some(sphere) = SphereEmitter::new(scene, mi as u32) {
                    mesh_entry[mi] = Some(MeshEntry::Sphere(emitters.len() as u32));
                    power.push(lum * sphere.area * PI * sides);
                    let r = sphere.radius_out;
                    intensity.push((lum * PI * r * r, sphere.center, r * r));
                    emitters.push(Emitter::Sphere(sphere));
                    continue;
                }
                if let Some(rectangle) = RectangleEmitter::new(scene, mi as u32) {
                    mesh_entry[mi] = Some(MeshEntry::Rectangle(emitters.len() as u32));
                    power.push(lum * rectangle.area * PI * sides);
                    intensity.push((lum * rectangle.area, rectangle.center, rectangle.area / PI));
                    emitters.push(Emitter::Rectangle(rectangle));
                    continue;
                }
            }
            mesh_entry[mi] = Some(MeshEntry::Triangles(emitters.len() as u32));
            for t in 0..mesh.indices.len() {
                let emitter = EmissiveTriangle::new(scene, mi as u32, t as u32);
                power.push(lum * emitter.area * PI * sides);
                let center = emitter.corner + (emitter.edge_b + emitter.edge_c) / 3.0 + 0.5 * emitter.motion;
                intensity.push((lum * emitter.area, center, emitter.area / PI + emitter.motion.length_squared()));
                emitters.push(Emitter::Triangle(emitter));
            }
        }
        let local = emitters.len();
        for light in &scene.lights {
            emitters.push(Emitter::Punctual(light.clone()));
            if legacy {
                power.push(match light {
                    PunctualLight::Point { intensity, .. } => 4.0 * PI * luminance(*intensity),
                    PunctualLight::Spot { intensity, inner_cone, outer_cone, .. } => {
                        2.0 * PI * (1.0 - (0.5 * (inner_cone + outer_cone)).cos()) * luminance(*intensity)
                    }
                    PunctualLight::Directional { irradiance, .. } => PI * radius * radius * luminance(*irradiance),
                });
            }
        }
        let mut environment_index = None;
        if scene.environment.max_element() > 0.0 {
            environment_index = Some(emitters.len() as u32);
            emitters.push(Emitter::Environment);
            if legacy {
                power.push(PI * 4.0 * PI * radius * radius * luminance(scene.environment));
            }
        }
        let table_len = if legacy { emitters.len() } else { local };
        // Emitters with zero luminance but some colour still need a chance.
        for (p, e) in power.iter_mut().zip(&emitters) {
            if !(*p > 0.0) || !p.is_finite() {
                *p = match e {
                    Emitter::Triangle(_) => 1e-6,
                    _ => 1e-3,
                };
            }
        }
        let total: f64 = power.iter().map(|&p| p as f64).sum();
        let mut cdf = Vec::with_capacity(power.len());
        let mut probability = Vec::with_capacity(power.len());
        let mut running = 0.0f64;
        for &p in &power {
            running += p as f64;
            cdf.push((running / total) as f32);
            probability.push((p as f64 / total) as f32);
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        // The table's intensity-weighted centre and spread (its emitters' own size included).
        let (mut sum, mut center) = (0.0f64, glam::DVec3::ZERO);
        for &(j, c, _) in &intensity {
            let j = (j as f64).max(f64::MIN_POSITIVE);
            sum += j;
            center += c.as_dvec3() * j;
        }
        let table_center = if sum > 0.0 { (center / sum).as_vec3() } else { Vec3::ZERO };
        let mut spread = 0.0f64;
        for &(j, c, size2) in &intensity {
            spread += (j as f64).max(f64::MIN_POSITIVE) * ((c - table_center).length_squared() + size2) as f64;
        }
        let table_spread2 = if sum > 0.0 { ((spread / sum) as f32).max(f32::MIN_POSITIVE) } else { 1.0 };
        LightSampler {
            strategy,
            emitters,
            table_len,
            cdf,
            probability,
            table_intensity: (sum as f32).max(f32::MIN_POSITIVE),
            table_center,
            table_spread2,
            mesh_entry,
            environment_index,
            environment_luminance: luminance(scene.environment),
        }
    }

    pub fn strategy(&self) -> LightStrategy {
        self.strategy
    }

    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// The number of candidates chosen among at a point: the table (if it has entries) and
    /// each light outside it.
    fn candidate_count(&self) -> usize {
        usize::from(self.table_len > 0) + self.emitters.len() - self.table_len
    }

    /// The irradiance estimate that weights candidate `k` at `point` (0 = the table when it has
    /// entries, then the lights outside it in order).
    fn candidate_weight(&self, k: usize, point: Vec3) -> f32 {
        let k = if self.table_len > 0 {
            if k == 0 {
                let d2 = (point - self.table_center).length_squared().max(self.table_spread2);
                return self.table_intensity / d2;
            }
            self.table_len + k - 1
        } else {
            k
        };
        let w = match &self.emitters[k] {
            Emitter::Punctual(PunctualLight::Point { position, intensity })
            | Emitter::Punctual(PunctualLight::Spot { position, intensity, .. }) => {
                luminance(*intensity) / (*position - point).length_squared().max(f32::MIN_POSITIVE)
            }
            Emitter::Punctual(PunctualLight::Directional { irradiance, .. }) => luminance(*irradiance),
            Emitter::Environment => PI * self.environment_luminance,
            _ => 0.0,
        };
        if w > 0.0 && w.is_finite() {
            w
        } else {
            1e-6
        }
    }

    /// The probability of choosing candidate `k` at `point` (1 with the legacy strategy, whose
    /// only candidate is the whole table).
    fn candidate_probability(&self, k: usize, point: Vec3) -> f32 {
        let n = self.candidate_count();
        if n <= 1 {
            return 1.0;
        }
        let total: f32 = (0..n).map(|i| self.candidate_weight(i, point)).sum();
        (1.0 - UNIFORM_SHARE) * self.candidate_weight(k, point) / total + UNIFORM_SHARE / n as f32
    }

    /// Samples one emitter and a point on it as seen from `point` at ray time `time`.
    pub fn sample(&self, scene: &Scene, point: Vec3, time: f32, u_select: f32, u: [f32; 2]) -> Option<LightSample> {
        if self.emitters.is_empty() {
            return None;
        }
        // Choose a candidate, and reuse what is left of `u_select` inside its share.
        let n = self.candidate_count();
        let (mut k, mut start, mut share) = (n - 1, 0.0f32, 1.0f32);
        if n > 1 {
            let total: f32 = (0..n).map(|i| self.candidate_weight(i, point)).sum();
            let mut acc = 0.0f32;
            for i in 0..n {
                let p = (1.0 - UNIFORM_SHARE) * self.candidate_weight(i, point) / total + UNIFORM_SHARE / n as f32;
                if u_select < acc + p || i == n - 1 {
                    (k, start, share) = (i, acc, p);
                    break;
                }
                acc += p;
            }
        } else {
            k = 0;
        }
        let u_rest = ((u_select - start) / share).clamp(0.0, 1.0 - f32::EPSILON);
        let (index, select, u_pick) = if self.table_len > 0 && k == 0 {
            let index = self.cdf.partition_point(|&c| c <= u_rest).min(self.table_len - 1);
            let below = if index == 0 { 0.0 } else { self.cdf[index - 1] };
            let within = self.probability[index];
            let u_pick = if within > 0.0 { ((u_rest - below) / within).clamp(0.0, 1.0 - f32::EPSILON) } else { 0.0 };
            (index, share * within, u_pick)
        } else {
            let index = if self.table_len > 0 { self.table_len + k - 1 } else { k };
            (index, share, u_rest)
        };
        match &self.emitters[index] {
            Emitter::Triangle(emitter) => {
                let (sample, (dist2, cos_light)) = sample_triangle(scene, emitter, point, time, u)?;
                let pdf = select * dist2 / (emitter.area * cos_light);
                Some(LightSample { weighted_radiance: sample.weighted_radiance / pdf, pdf: Some(pdf), ..sample })
            }
            Emitter::Sphere(sphere) => sphere.sample(scene, point, select, u_pick, u),
            Emitter::Rectangle(rectangle) => rectangle.sample(point, select, u),
            Emitter::Punctual(light) => {
                let (wi, distance, radiance) = punctual_incident(light, point)?;
                Some(LightSample { wi, distance, weighted_radiance: radiance / select, pdf: None, mesh: None })
            }
            Emitter::Environment => {
                let z = 1.0 - 2.0 * u[0];
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * PI * u[1];
                let wi = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                let pdf = select / (4.0 * PI);
                Some(LightSample {
                    wi,
                    distance: f32::INFINITY,
                    weighted_radiance: scene.environment / pdf,
                    pdf: Some(pdf),
                    mesh: None,
                })
            }
        }
    }

    /// Solid-angle pdf with which `sample` would have chosen the point `hit` on a mesh
    /// triangle, seen from `from`.
    pub fn pdf_triangle(&self, mesh: u32, triangle: u32, from: Vec3, hit: Vec3) -> f32 {
        let Some(entry) = self.mesh_entry.get(mesh as usize).copied().flatten() else {
            return 0.0;
        };
        let table = self.candidate_probability(0, from);
        match entry {
            MeshEntry::Sphere(index) => {
                let Some(Emitter::Sphere(sphere)) = self.emitters.get(index as usize) else { return 0.0 };
                table * self.probability[index as usize] * sphere.pdf(triangle, from, hit)
            }
            MeshEntry::Rectangle(index) => {
                let Some(Emitter::Rectangle(rectangle)) = self.emitters.get(index as usize) else { return 0.0 };
                table * self.probability[index as usize] * rectangle.pdf(from, hit)
            }
            MeshEntry::Triangles(offset) => {
                let index = (offset + triangle) as usize;
                let Some(Emitter::Triangle(emitter)) = self.emitters.get(index) else {
                    return 0.0;
                };
                let to_light = hit - from;
                let dist2 = to_light.length_squared();
                if !(emitter.area > 0.0) || !(dist2 > 0.0) {
                    return 0.0;
                }
                let cos_light = emitter.normal.dot(to_light / dist2.sqrt()).abs();
                if cos_light <= 1e-7 {
                    return 0.0;
                }
                table * self.probability[index] * dist2 / (emitter.area * cos_light)
            }
        }
    }

    /// Solid-angle pdf of sampling the environment in any direction from `from`.
    pub fn pdf_environment(&self, from: Vec3) -> f32 {
        match self.environment_index {
            Some(i) if self.strategy.is_power_only() => self.probability[i as usize] / (4.0 * PI),
            Some(i) => {
                let k = i as usize - self.table_len + usize::from(self.table_len > 0);
                self.candidate_probability(k, from) / (4.0 * PI)
            }
            None => 0.0,
        }
    }
}

/// Direction, distance and incident radiance-times-solid-angle of a punctual light at `point`.
fn punctual_incident(light: &PunctualLight, point: Vec3) -> Option<(Vec3, f32, Vec3)> {
    match light {
        PunctualLight::Point { position, intensity } => {
            let d = *position - point;
            let dist2 = d.length_squared();
            if !(dist2 > 0.0) {
                return None;
            }
            let distance = dist2.sqrt();
            Some((d / distance, distance, *intensity / dist2))
        }
        PunctualLight::Spot { position, direction, intensity, inner_cone, outer_cone } => {
            let d = *position - point;
            let dist2 = d.length_squared();
            if !(dist2 > 0.0) {
                return None;
            }
            let distance = dist2.sqrt();
            let wi = d / distance;
            let cos_angle = (-wi).dot(direction.normalize());
            let (cos_inner, cos_outer) = (inner_cone.cos(), outer_cone.cos());
            let falloff = if cos_angle >= cos_inner {
                1.0
            } else if cos_angle <= cos_outer {
                0.0
            } else {
                let x = (cos_angle - cos_outer) / (cos_inner - cos_outer).max(1e-6);
                x * x
            };
            if falloff <= 0.0 {
                return None;
            }
            Some((wi, distance, *intensity * falloff / dist2))
        }
        PunctualLight::Directional { direction, irradiance } => {
            Some((-direction.normalize(), f32::INFINITY, *irradiance))
        }
    }
}

#[cfg(test)]
mod tests;
