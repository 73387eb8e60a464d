//! Unidirectional path tracing with next-event estimation and multiple importance sampling.
//!
//! At every vertex one emitter is chosen by power and a shadow ray traced (NEE), and one
//! direction is drawn from the BSDF; light reached by either strategy is weighted with the
//! power heuristic against the other strategy's density (delta lights take NEE alone). Paths
//! longer than three bounces continue with Russian roulette on the throughput. Radiance is
//! split into `direct` (emission seen by the camera plus light reaching the first surface
//! straight from an emitter) and `indirect` (everything else).

use std::sync::atomic::{AtomicU64, Ordering};

use glam::{Vec2, Vec3};

use crate::accel::{Accel, Hit};
use crate::bsdf::{Bsdf, Frame};
use crate::camera::{concentric_disk, CameraSample};
use crate::lights::{triangle_at, triangle_emission, LightSampler};
use crate::sampler::Sampler;
use crate::scene::Scene;
use crate::texture::TextureRef;

/// What one camera sample measured.
#[derive(Clone, Copy, Debug, Default)]
pub struct PathSample {
    pub direct: Vec3,
    pub indirect: Vec3,
    /// First-hit data (zero when the camera ray escapes).
    pub first_hit: Option<FirstHit>,
    /// Rays traced (closest-hit plus shadow).
    pub rays: u32,
    /// The part of `direct + indirect` that left `Integrator::split_emitter` and was reflected
    /// at least once (its emission seen by the camera itself is not in it); zero without one.
    pub split_emitter_light: Vec3,
}

impl From<TracedRay> for PathSample {
    /// A camera path's sample from what its camera ray gathered.
    fn from(traced: TracedRay) -> PathSample {
        PathSample {
            direct: traced.emitted + traced.direct,
            indirect: traced.beyond,
            first_hit: traced.first_hit,
            rays: traced.rays,
            split_emitter_light: traced.split_emitter_light,
        }
    }
}

impl PathSample {
    pub fn radiance(&self) -> Vec3 {
        self.direct + self.indirect
    }
}

#[derive(Clone, Copy, Debug)]
pub struct FirstHit {
    pub albedo: Vec3,
    /// Shading normal, facing the camera.
    pub normal: Vec3,
    /// Geometric normal, facing the camera.
    pub geometric_normal: Vec3,
    pub position: Vec3,
    /// Distance along the camera's forward axis.
    pub depth: f32,
    /// The mesh that was hit.
    pub mesh: u32,
    /// Shading parameters there.
    pub bsdf: Bsdf,
}

impl FirstHit {
    pub fn new(surface: &SurfacePoint, mesh: u32, depth: f32) -> FirstHit {
        FirstHit {
            albedo: surface.bsdf.albedo(),
            normal: surface.shading_normal,
            geometric_normal: surface.geometric_normal,
            position: surface.position,
            depth,
            mesh,
            bsdf: surface.bsdf,
        }
    }
}

/// Kind of a traced ray, for the benchmark's replay.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RayKind {
    Closest,
    Shadow,
}

/// A traced ray, recorded for replay against raw Embree.
#[derive(Clone, Copy, Debug)]
pub struct RecordedRay {
    pub origin: Vec3,
    pub direction: Vec3,
    pub t_max: f32,
    pub time: f32,
    pub kind: RayKind,
}

/// Receives every ray the integrator traces; the no-op recorder compiles away.
pub trait RayRecorder {
    fn record(&mut self, ray: RecordedRay);
}

pub struct NoRecording;

impl RayRecorder for NoRecording {
    #[inline(always)]
    fn record(&mut self, _ray: RecordedRay) {}
}

impl RayRecorder for Vec<RecordedRay> {
    fn record(&mut self, ray: RecordedRay) {
        self.push(ray);
    }
}

/// The linear share of a pixel's (or a lobe's) angle one path's cone takes: 1/8 (see
/// [`RayCone`]).
pub const BUNDLE_SHARE: f32 = 0.125;

/// A ray cone (Akenine-Möller et al. 2019, "Texture Level of Detail Strategies for Real-Time
/// Ray Tracing"): the width of the bundle of paths one sample stands for, growing linearly
/// along the ray. It picks texture mip levels (`SurfacePoint::new`).
///
/// A camera ray starts at width 0 with an eighth of a pixel's angle (the finest footprint
/// pbrt-v4's `Approximate_dp_dxy` uses, reached there at 64 spp). A bounce adds the angle one
/// path gets of the sampled lobe when 64 paths share it: solid angle 1/(64 pdf), width √ of
/// that, `BUNDLE_SHARE / √pdf` (0 for a mirror, about 0.2 rad for a Lambertian bounce).
/// The footprints do not depend on the sample count, so renders at any spp converge to the
/// same image and references stay comparable with sparse inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayCone {
    /// Width where the ray starts.
    pub width: f32,
    /// Width gained per unit of distance.
    pub spread: f32,
}

impl RayCone {
    /// Width at distance `t` along the ray.
    #[inline]
    pub fn width_at(&self, t: f32) -> f32 {
        self.width + self.spread * t
    }

    /// The cone leaving a surface `t` along this one, in a direction drawn with density `pdf`.
    #[inline]
    pub fn after_bounce(&self, t: f32, pdf: f32) -> RayCone {
        let added = BUNDLE_SHARE / pdf.sqrt();
        let added = if added.is_nan() { 0.0 } else { added.clamp(0.0, 2.0) };
        RayCone { width: self.width_at(t), spread: self.spread + added }
    }
}

/// Level of detail, before a texture's own resolution and uv transform are added, of a lookup
/// with a footprint `width` wide on a triangle with doubled world area `world_cross` and
/// doubled uv area `uv_cross`, seen at cosine `cos_view`: log2 of the footprint's width in uv
/// units (the ray-cone formula). −∞ (the finest level) for a zero width or degenerate uvs.
#[inline]
pub fn uv_level_of_detail(width: f32, world_cross: f32, uv_cross: f32, cos_view: f32) -> f32 {
    let lod = (width / cos_view.abs().max(1e-3) * (uv_cross / world_cross).sqrt()).log2();
    if lod.is_nan() {
        f32::NEG_INFINITY
    } else {
        lod
    }
}

/// Local geometry and material at a hit, oriented towards the outgoing direction.
pub struct SurfacePoint {
    pub position: Vec3,
    /// Unit geometric normal on the side of `wo`.
    pub geometric_normal: Vec3,
    /// Unit shading normal on the side of `wo`.
    pub shading_normal: Vec3,
    /// Whether `wo` leaves through the triangle's front face (counter-clockwise winding).
    pub front_face: bool,
    pub uv: Vec2,
    pub bsdf: Bsdf,
    /// Offset applied to ray origins leaving this point.
    pub epsilon: f32,
}

impl SurfacePoint {
    /// The surface at `hit`, its textures filtered over a footprint `footprint_width` wide
    /// (a ray cone's width there; 0 for the finest level).
    pub fn new(scene: &Scene, hit: &Hit, wo: Vec3, time: f32, footprint_width: f32) -> SurfacePoint {
        let mesh = &scene.meshes[hit.mesh as usize];
        let [a, b, c] = triangle_at(scene, hit.mesh, hit.triangle, time);
        let (u, v) = (hit.barycentric.x, hit.barycentric.y);
        let w = 1.0 - u - v;
        let position = a * w + b * u + c * v;
        let (winding_normal, area) = shading::triangle_normal_and_area(a, b, c);
        let front_face = winding_normal.dot(wo) >= 0.0;
        let geometric_normal = if front_face { winding_normal } else { -winding_normal };
        let [ia, ib, ic] = mesh.indices[hit.triangle as usize];
        // The interpolated vertex normal as the mesh gives it, and the sign that turns it to
        // the side of wo (that of the geometric normal).
        let (vertex_normal, side) = match &mesh.normals {
            Some(n) => {
                let interpolated = (n[ia as usize] * w + n[ib as usize] * u + n[ic as usize] * v).normalize_or_zero();
                if interpolated == Vec3::ZERO {
                    (geometric_normal, 1.0)
                } else if interpolated.dot(geometric_normal) < 0.0 {
                    (interpolated, -1.0)
                } else {
                    (interpolated, 1.0)
                }
            }
            None => (geometric_normal, 1.0),
        };
        let mut shading_normal = vertex_normal * side;
        // A shading normal that hides wo would make the surface black; fall back.
        if shading_normal.dot(wo) <= 1e-4 {
            shading_normal = geometric_normal;
        }
        let material = &scene.materials[mesh.material as usize];
        let textured = material.base_color_texture.is_some()
            || material.metallic_roughness_texture.is_some()
            || material.normal_map.is_some();
        let (uv, uv_lod) = match &mesh.uvs {
            Some(uvs) => {
                let [uv_a, uv_b, uv_c] = [uvs[ia as usize], uvs[ib as usize], uvs[ic as usize]];
                let uv = uv_a * w + uv_b * u + uv_c * v;
                let uv_lod = if textured && footprint_width > 0.0 {
                    let uv_cross = (uv_b - uv_a).perp_dot(uv_c - uv_a).abs();
                    uv_level_of_detail(footprint_width, 2.0 * area, uv_cross, winding_normal.dot(wo))
                } else {
                    f32::NEG_INFINITY
                };
                (uv, uv_lod)
            }
            None => (Vec2::ZERO, f32::NEG_INFINITY),
        };
        let lookup = |t: &TextureRef| {
            let texture = &scene.textures[t.index as usize];
            texture.sample_filtered(t.apply(uv), uv_lod + t.half_log2_scale() + texture.half_log2_texels())
        };
        if let (Some(map), Some(tangents), Some(_)) = (&material.normal_map, &mesh.tangents, &mesh.uvs) {
            let tangent = tangents[ia as usize] * w + tangents[ib as usize] * u + tangents[ic as usize] * v;
            let texel = lookup(&map.texture);
            let mapped = normal_mapped(vertex_normal, tangent, texel.truncate(), map.scale) * side;
            // A mapped normal that hides wo falls back to the unmapped one (as above).
            if mapped.dot(wo) > 1e-4 {
                shading_normal = mapped;
            }
        }
        let mut base_color = material.base_color;
        if let Some(t) = &material.base_color_texture {
            base_color *= lookup(t).truncate();
        }
        let (mut metallic, mut roughness) = (material.metallic, material.roughness);
        if let Some(t) = &material.metallic_roughness_texture {
            let texel = lookup(t);
            roughness *= texel.y;
            metallic *= texel.z;
        }
        // Scale-free: the largest coordinate magnitude involved in the hit (Embree's error and
        // the interpolated position's rounding grow with it), never an absolute floor (one of
        // 1e-3 pushed a room 1e-6 across 0.4 % of its size off each surface).
        let scale = position.abs().max(a.abs()).max(b.abs()).max(c.abs()).max_element();
        SurfacePoint {
            position,
            geometric_normal,
            shading_normal,
            front_face,
            uv,
            bsdf: Bsdf::with_ior(base_color, metallic, roughness, material.specular, material.ior),
            epsilon: (scale * 4e-6).max(f32::MIN_POSITIVE),
        }
    }

    /// Radiance the surface emits towards `wo` (zero for non-emissive materials; one-sided
    /// emitters only from their front face).
    pub fn emission(&self, scene: &Scene, hit: &Hit, wo: Vec3) -> Vec3 {
        let material = &scene.materials[scene.meshes[hit.mesh as usize].material as usize];
        if !material.is_emissive() {
            return Vec3::ZERO;
        }
        let winding_normal = if self.front_face { self.geometric_normal } else { -self.geometric_normal };
        triangle_emission(scene, hit.mesh, hit.triangle, hit.barycentric, winding_normal, wo)
    }

    /// Origin for a ray leaving towards `direction`, pushed off the surface on that side.
    #[inline]
    pub fn spawn_origin(&self, direction: Vec3) -> Vec3 {
        let side = if direction.dot(self.geometric_normal) >= 0.0 { 1.0 } else { -1.0 };
        self.position + self.geometric_normal * (self.epsilon * side)
    }
}

/// The normal a tangent-space normal map's `texel` (r, g, b in [0, 1]) gives at a point whose
/// unit vertex normal is `normal` and whose interpolated tangent is `tangent` (glTF: `xyz`
/// along increasing u, bitangent = `w` · normal × tangent): (2·texel − 1) with x and y scaled
/// by `scale`, in the frame (tangent made orthogonal to the normal, bitangent, normal),
/// normalised. Returns `normal` where the frame or the result degenerates (a zero tangent, a
/// texel of zero length).
pub fn normal_mapped(normal: Vec3, tangent: glam::Vec4, texel: Vec3, scale: f32) -> Vec3 {
    let t = (tangent.truncate() - normal * normal.dot(tangent.truncate())).normalize_or_zero();
    if t == Vec3::ZERO {
        return normal;
    }
    let handedness = if tangent.w < 0.0 { -1.0 } else { 1.0 };
    let b = normal.cross(t) * handedness;
    let local = (texel * 2.0 - Vec3::ONE) * Vec3::new(scale, scale, 1.0);
    let mapped = (t * local.x + b * local.y + normal * local.z).normalize_or_zero();
    if mapped == Vec3::ZERO || !mapped.is_finite() {
        normal
    } else {
        mapped
    }
}

/// Reads the vertex data (corners, normals, uvs) that [`SurfacePoint::new`] will need for each
/// of `hits`, ahead of shading a batch of paths. The loads of different hits do not depend on
/// each other, so their cache misses overlap here, where shading one hit at a time waits for
/// each miss in turn (about −5 % of a Sponza render, `docs/performance.md`).
pub fn preload_vertices(scene: &Scene, hits: &[Option<Hit>]) {
    let mut loaded = 0.0f32;
    for hit in hits.iter().flatten() {
        let Some(mesh) = scene.meshes.get(hit.mesh as usize) else { continue };
        let Some(&corners) = mesh.indices.get(hit.triangle as usize) else { continue };
        for corner in corners.map(|i| i as usize) {
            loaded += mesh.positions.get(corner).map_or(0.0, |p| p.x);
            loaded += mesh.normals.as_ref().and_then(|n| n.get(corner)).map_or(0.0, |n| n.x);
            loaded += mesh.uvs.as_ref().and_then(|uv| uv.get(corner)).map_or(0.0, |uv| uv.x);
        }
    }
    // The sum is never used; observing it keeps the loads.
    std::hint::black_box(loaded);
}

#[inline]
fn power_heuristic(pdf_a: f32, pdf_b: f32) -> f32 {
    let a2 = pdf_a * pdf_a;
    let b2 = pdf_b * pdf_b;
    if a2.is_infinite() {
        return 1.0;
    }
    if a2 + b2 > 0.0 {
        a2 / (a2 + b2)
    } else {
        0.0
    }
}

/// Where a ray starts: a camera ray (bounce 0, no previous vertex) or a ray leaving a surface.
#[derive(Clone, Copy, Debug)]
pub struct PathStart {
    pub origin: Vec3,
    pub direction: Vec3,
    pub time: f32,
    /// Path vertex index of the surface this ray will hit (0 for camera rays); bounds the path
    /// length with the integrator's `max_bounces` and starts Russian roulette at 3.
    pub bounce: u32,
    /// BSDF density with which the direction was drawn and the vertex it was drawn at, for
    /// MIS against light sampling when the ray hits an emitter; `None` for camera rays.
    pub previous: Option<(f32, Vec3)>,
}

/// Radiance arriving along a ray, split by the vertex it was emitted towards.
#[derive(Clone, Copy, Debug, Default)]
pub struct TracedRay {
    /// Emission of the first surface hit (or the environment when the ray escapes).
    pub emitted: Vec3,
    /// Light reflected at the first hit straight from an emitter.
    pub direct: Vec3,
    /// Everything else: light that bounced at least twice.
    pub beyond: Vec3,
    pub first_hit: Option<FirstHit>,
    pub rays: u32,
    /// The part of `direct + beyond` emitted by `Integrator::split_emitter`.
    pub split_emitter_light: Vec3,
    /// Contributions dropped because they were NaN or infinite (an emitter so bright that a
    /// product overflows f32, a degenerate BSDF value); the commands warn with the total.
    pub dropped: u32,
}

impl TracedRay {
    /// Adds a contribution emitted towards vertex `level` (0 = emission of the first hit),
    /// dropping (and counting) non-finite values.
    #[inline]
    fn add(&mut self, level: u32, value: Vec3) {
        if !value.is_finite() {
            self.dropped += 1;
            return;
        }
        match level {
            0 => self.emitted += value,
            1 => self.direct += value,
            _ => self.beyond += value,
        }
    }

    /// `add`, also counting the value in `split_emitter_light` when it was reflected at least
    /// once and `from_split_emitter` says it left the split emitter.
    #[inline]
    fn add_from(&mut self, level: u32, value: Vec3, from_split_emitter: bool) {
        self.add(level, value);
        if from_split_emitter && level > 0 && value.is_finite() {
            self.split_emitter_light += value;
        }
    }

    /// Radiance along the ray excluding the first hit's own emission.
    pub fn reflected(&self) -> Vec3 {
        self.direct + self.beyond
    }
}

pub struct Integrator<'a> {
    pub scene: &'a Scene,
    pub accel: &'a Accel,
    pub lights: &'a LightSampler,
    pub max_bounces: u32,
    /// An emissive mesh whose reflected light is also tallied on its own
    /// (`PathSample::split_emitter_light`): the planar light of the soft-shadow samples.
    pub split_emitter: Option<u32>,
    width: u32,
    height: u32,
    /// Per-render constants, computed once instead of per camera ray: tan of half the field
    /// of view along x and y, whether the camera has a lens and whether anything moves.
    film_tan: Vec2,
    has_lens: bool,
    has_motion: bool,
    /// The ray cone's spread for camera rays (see `RayCone`).
    camera_spread: f32,
    /// Non-finite contributions dropped by the paths traced so far (`TracedRay::dropped`).
    dropped: AtomicU64,
}

impl<'a> Integrator<'a> {
    /// An integrator for images of `width` × `height` pixels and paths of up to `max_bounces`
    /// bounces, without a split emitter.
    pub fn new(
        scene: &'a Scene,
        accel: &'a Accel,
        lights: &'a LightSampler,
        max_bounces: u32,
        width: u32,
        height: u32,
    ) -> Integrator<'a> {
        let film_tan = scene.camera.tan_half_fov(width, height);
        let pixel_angle = (2.0 * film_tan.x / width.max(1) as f32).min(2.0 * film_tan.y / height.max(1) as f32);
        Integrator {
            scene,
            accel,
            lights,
            max_bounces,
            split_emitter: None,
            width,
            height,
            film_tan,
            has_lens: scene.camera.has_lens(),
            has_motion: scene.has_motion(),
            camera_spread: pixel_angle * BUNDLE_SHARE,
            dropped: AtomicU64::new(0),
        }
    }

    /// Adds the non-finite contributions `traced` dropped to this integrator's total; every
    /// finished path goes through here (`trace_ray`, `render`'s tiles).
    #[inline]
    pub fn count_dropped(&self, traced: &TracedRay) {
        if traced.dropped > 0 {
            self.dropped.fetch_add(u64::from(traced.dropped), Ordering::Relaxed);
        }
    }

    /// Non-finite contributions the paths traced by this integrator dropped, in total.
    pub fn dropped_contributions(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// The ray cone of a camera ray.
    pub fn camera_cone(&self) -> RayCone {
        RayCone { width: 0.0, spread: self.camera_spread }
    }

    /// The ray cone leaving a surface at `position` in a direction drawn with density `pdf`,
    /// when the path before it is not known: the camera ray's cone at that distance, bent.
    pub fn cone_after_bounce_at(&self, position: Vec3, pdf: f32) -> RayCone {
        let distance = (position - self.scene.camera.position).length();
        self.camera_cone().after_bounce(distance, pdf)
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Draws the camera coordinates of one sample in pixel (px, py): film position (box
    /// filter), lens position (only with an aperture) and time (only with motion).
    pub fn camera_sample(&self, px: u32, py: u32, sampler: &mut Sampler) -> CameraSample {
        let film = sampler.next_2d();
        let film = Vec2::new(px as f32 + film[0], py as f32 + film[1]);
        let lens = if self.has_lens { concentric_disk(Vec2::from(sampler.next_2d())) } else { Vec2::ZERO };
        let time = if self.has_motion { sampler.next_1d() } else { 0.0 };
        CameraSample { film, lens, time }
    }

    /// Traces one camera path through pixel (px, py).
    pub fn trace<R: RayRecorder>(&self, px: u32, py: u32, sampler: &mut Sampler, recorder: &mut R) -> PathSample {
        let camera_sample = self.camera_sample(px, py, sampler);
        self.trace_camera_sample(&camera_sample, sampler, recorder)
    }

    /// The ray a camera sample starts its path with.
    pub fn camera_path_start(&self, camera_sample: &CameraSample) -> PathStart {
        let (origin, direction) = self.scene.camera.generate_ray_with_tan(
            self.film_tan,
            camera_sample.film,
            camera_sample.lens,
            self.width,
            self.height,
        );
        PathStart { origin, direction, time: camera_sample.time, bounce: 0, previous: None }
    }

    /// Traces the path of a given camera sample; `sampler` supplies the path's dimensions.
    pub fn trace_camera_sample<R: RayRecorder>(
        &self,
        camera_sample: &CameraSample,
        sampler: &mut Sampler,
        recorder: &mut R,
    ) -> PathSample {
        let start = self.camera_path_start(camera_sample);
        PathSample::from(self.trace_ray(&start, sampler, recorder))
    }

    /// Next-event estimation at `surface`: one emitter chosen by power, one shadow ray, the
    /// power-heuristic weight against BSDF sampling. Returns the reflected radiance towards
    /// `wo` (not multiplied by any path throughput).
    pub fn next_event<R: RayRecorder>(
        &self,
        surface: &SurfacePoint,
        wo: Vec3,
        time: f32,
        u: [f32; 3],
        rays: &mut u32,
        recorder: &mut R,
    ) -> Vec3 {
        let frame = Frame::new(surface.shading_normal);
        let Some(test) = self.light_sample_test(surface, &frame, wo, time, u, rays, recorder) else {
            return Vec3::ZERO;
        };
        if self.is_occluded(&test) {
            Vec3::ZERO
        } else if !test.value.is_finite() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            Vec3::ZERO
        } else {
            test.value
        }
    }

    /// Next-event estimation up to its shadow ray: one emitter chosen by power and the
    /// power-heuristic weight against BSDF sampling. Returns the shadow ray (counted in `rays`
    /// and recorded) with the reflected radiance towards `wo` it carries when unoccluded, or
    /// `None` when no light can arrive and no ray is needed.
    #[allow(clippy::too_many_arguments)]
    fn light_sample_test<R: RayRecorder>(
        &self,
        surface: &SurfacePoint,
        frame: &Frame,
        wo: Vec3,
        time: f32,
        u: [f32; 3],
        rays: &mut u32,
        recorder: &mut R,
    ) -> Option<ShadowTest> {
        let (u_select, u_light) = (u[0], [u[1], u[2]]);
        let light = self.lights.sample(self.scene, surface.position, time, u_select, u_light)?;
        // Reject light from below the geometric surface (light leaking through).
        if light.wi.dot(surface.geometric_normal) <= 0.0 {
            return None;
        }
        let wo_local = frame.to_local(wo);
        let wi_local = frame.to_local(light.wi);
        let f = surface.bsdf.eval(wo_local, wi_local);
        if f == Vec3::ZERO {
            return None;
        }
        let origin = surface.spawn_origin(light.wi);
        // Aim from the pushed-off origin at the light point itself and stop short of it by a
        // relative margin. (Along `light.wi` from the pushed-off origin, the segment ended
        // beside the light point, inside a convex emitter facing the surface whenever the push,
        // which grows with the surface's coordinates, exceeded the margin: a 1200-unit floor
        // lost a quarter of a sphere light's direct light.)
        let (direction, t_max) = if light.distance.is_finite() {
            let to_light = surface.position + light.wi * light.distance - origin;
            let length = to_light.length();
            (to_light / length, length * (1.0 - 2e-4))
        } else {
            (light.wi, f32::INFINITY)
        };
        *rays += 1;
        recorder.record(RecordedRay { origin, direction, t_max, time, kind: RayKind::Shadow });
        let weight = match light.pdf {
            Some(light_pdf) => power_heuristic(light_pdf, surface.bsdf.pdf(wo_local, wi_local)),
            None => 1.0,
        };
        // A non-finite value stays as it is: `TracedRay::add` drops and counts it if the shadow
        // ray is not blocked.
        let value = f * light.weighted_radiance * weight;
        let emitter = if value.is_finite() { light.mesh } else { None };
        Some(ShadowTest { origin, direction, t_max, time, value, emitter, level: 0 })
    }

    /// Whether a shadow ray is blocked (an empty segment counts as blocked).
    #[inline]
    pub fn is_occluded(&self, test: &ShadowTest) -> bool {
        !(test.t_max > 0.0) || self.accel.occluded(test.origin, test.direction, 0.0, test.t_max, test.time)
    }

    /// Radiance arriving at `start.origin` along `start.direction`, split by where it was
    /// emitted relative to the first surface the ray hits (see `TracedRay`).
    ///
    /// One path at a time: the vertex steps of [`PathState`] with each ray traced as soon as
    /// it is known. `render` runs the same steps over a batch of paths instead.
    pub fn trace_ray<R: RayRecorder>(&self, start: &PathStart, sampler: &mut Sampler, recorder: &mut R) -> TracedRay {
        let mut path = self.start_path(start, sampler.clone());
        while let Some(ray) = self.next_ray(&mut path, recorder) {
            let hit = self.accel.intersect(ray.origin, ray.direction, 0.0, ray.t_max, ray.time);
            if let Some(test) = self.shade(&mut path, hit.as_ref(), recorder) {
                let occluded = self.is_occluded(&test);
                self.resolve_shadow(&mut path, &test, occluded);
            }
        }
        *sampler = path.sampler;
        self.count_dropped(&path.traced);
        path.traced
    }

    /// Adds the radiance of a shadow ray `shade` returned for `path`, unless it is `occluded`.
    #[inline]
    pub fn resolve_shadow(&self, path: &mut PathState, test: &ShadowTest, occluded: bool) {
        if !occluded {
            let from_split_emitter = test.emitter.is_some() && test.emitter == self.split_emitter;
            path.traced.add_from(test.level, test.value, from_split_emitter);
        }
    }

    /// The state of a path about to trace the ray `start`, drawing its dimensions from `sampler`.
    pub fn start_path(&self, start: &PathStart, sampler: Sampler) -> PathState {
        let (previous_bsdf_pdf, previous_position) = match start.previous {
            Some((pdf, position)) => (Some(pdf), position),
            None => (None, start.origin),
        };
        let cone = match start.previous {
            Some((pdf, position)) => self.cone_after_bounce_at(position, pdf),
            None => self.camera_cone(),
        };
        PathState {
            sampler,
            origin: start.origin,
            direction: start.direction,
            time: start.time,
            throughput: Vec3::ONE,
            previous_bsdf_pdf,
            previous_position,
            cone,
            bounce: start.bounce,
            first_bounce: start.bounce,
            alive: start.bounce <= self.max_bounces,
            traced: TracedRay::default(),
        }
    }

    /// The closest-hit ray the path traces next (counted and recorded), or `None` when the
    /// path has ended.
    #[inline]
    pub fn next_ray<R: RayRecorder>(&self, path: &mut PathState, recorder: &mut R) -> Option<RecordedRay> {
        if !path.alive {
            return None;
        }
        path.traced.rays += 1;
        let ray = RecordedRay {
            origin: path.origin,
            direction: path.direction,
            t_max: f32::INFINITY,
            time: path.time,
            kind: RayKind::Closest,
        };
        recorder.record(ray);
        Some(ray)
    }

    /// One path vertex: what the path's last ray (from `next_ray`) found. Adds the emission
    /// there (or the environment's on a miss), draws the light sample and the BSDF direction
    /// that continues the path, and applies Russian roulette. Returns the light sample's
    /// shadow ray, whose radiance [`Integrator::resolve_shadow`] adds once its occlusion is
    /// known; it must be resolved before the path's next ray is traced.
    pub fn shade<R: RayRecorder>(
        &self,
        path: &mut PathState,
        hit: Option<&Hit>,
        recorder: &mut R,
    ) -> Option<ShadowTest> {
        let scene = self.scene;
        let bounce = path.bounce;
        // Vertex level relative to the first hit: 0 = the first hit itself.
        let level = bounce - path.first_bounce;
        path.alive = false;
        let Some(hit) = hit else {
            if scene.environment.max_element() > 0.0 {
                let weight = match path.previous_bsdf_pdf {
                    None => 1.0,
                    Some(pdf) => power_heuristic(pdf, self.lights.pdf_environment(path.previous_position)),
                };
                path.traced.add(level, path.throughput * scene.environment * weight);
            }
            return None;
        };
        let time = path.time;
        let wo = -path.direction;
        let footprint_width = path.cone.width_at(hit.distance);
        let surface = SurfacePoint::new(scene, hit, wo, time, footprint_width);

        if level == 0 {
            path.traced.first_hit = Some(FirstHit::new(&surface, hit.mesh, scene.camera.depth(surface.position)));
        }

        let emitted = surface.emission(scene, hit, wo);
        if emitted != Vec3::ZERO {
            let weight = match path.previous_bsdf_pdf {
                None => 1.0,
                Some(pdf) => {
                    let light_pdf =
                        self.lights.pdf_triangle(hit.mesh, hit.triangle, path.previous_position, surface.position);
                    power_heuristic(pdf, light_pdf)
                }
            };
            let from_split_emitter = self.split_emitter == Some(hit.mesh);
            path.traced.add_from(level, path.throughput * emitted * weight, from_split_emitter);
        }
        if bounce == self.max_bounces {
            return None;
        }

        let frame = Frame::new(surface.shading_normal);
        let wo_local = frame.to_local(wo);
        let [u_light_select, u_lobe] = path.sampler.next_2d();
        let u_light = path.sampler.next_2d();
        let u_bsdf = path.sampler.next_2d();
        let [u_roulette, _] = path.sampler.next_2d();

        let mut shadow = self.light_sample_test(
            &surface,
            &frame,
            wo,
            time,
            [u_light_select, u_light[0], u_light[1]],
            &mut path.traced.rays,
            recorder,
        );
        if let Some(test) = &mut shadow {
            test.value *= path.throughput;
            // Light reflected at this vertex straight from an emitter is one level deeper.
            test.level = level + 1;
        }

        // Continue the path by BSDF sampling.
        let Some(bsdf_sample) = surface.bsdf.sample(wo_local, u_lobe, u_bsdf) else {
            return shadow;
        };
        let wi = frame.to_world(bsdf_sample.wi);
        if wi.dot(surface.geometric_normal) <= 0.0 {
            return shadow;
        }
        path.throughput *= bsdf_sample.weight;
        path.cone = path.cone.after_bounce(hit.distance, bsdf_sample.pdf);
        path.previous_bsdf_pdf = Some(bsdf_sample.pdf);
        path.previous_position = surface.position;
        path.origin = surface.spawn_origin(wi);
        path.direction = wi;

        if bounce >= 3 {
            let survive = path.throughput.max_element().min(0.95);
            if !(survive > 0.0) || u_roulette >= survive {
                return shadow;
            }
            path.throughput /= survive;
        }
        path.bounce += 1;
        path.alive = true;
        shadow
    }
}

/// A light sample's shadow ray and the radiance it brings when nothing blocks it.
#[derive(Clone, Copy, Debug)]
pub struct ShadowTest {
    pub origin: Vec3,
    pub direction: Vec3,
    /// End of the segment tested (stops short of the light; infinite for distant light).
    pub t_max: f32,
    pub time: f32,
    /// Radiance reflected towards the vertex's outgoing direction if unoccluded (times the
    /// path throughput once [`Integrator::shade`] returns it).
    pub value: Vec3,
    /// The emissive mesh the light came from (`None` for punctual and environment light).
    pub emitter: Option<u32>,
    /// Level of the contribution in the path's `TracedRay` (set by `shade`).
    pub level: u32,
}

/// One path between two of its rays: everything [`Integrator::shade`] carries from a vertex to
/// the next, so paths can be advanced one at a time ([`Integrator::trace_ray`]) or a batch
/// at a time (`render`) with bit-identical results.
#[derive(Clone, Debug)]
pub struct PathState {
    /// The path's sample dimensions.
    pub sampler: Sampler,
    origin: Vec3,
    direction: Vec3,
    time: f32,
    throughput: Vec3,
    /// BSDF density of the last bounce and where it happened (MIS against light sampling).
    previous_bsdf_pdf: Option<f32>,
    previous_position: Vec3,
    cone: RayCone,
    /// Path vertex index of the surface the next ray will hit.
    bounce: u32,
    /// `bounce` of the path's first ray: contributions are levelled relative to it.
    first_bounce: u32,
    /// Whether the path traces another ray.
    alive: bool,
    /// What the path has gathered so far.
    pub traced: TracedRay,
}

#[cfg(test)]
mod tests {
    use std::f32::consts::{FRAC_1_PI, PI};

    use super::*;
    use crate::scene::shapes::polygon;
    use crate::scene::Material;
    use crate::texture::Texture;

    #[test]
    fn ray_cones_grow_linearly_and_bounces_add_the_lobe_share() {
        let cone = RayCone { width: 0.5, spread: 0.01 };
        assert_eq!(cone.width_at(10.0), 0.5 + 0.1);
        // A mirror (delta lobe, infinite density) keeps the spread; a Lambertian bounce in the
        // normal direction (pdf 1/π) adds BUNDLE_SHARE √π.
        assert_eq!(cone.after_bounce(10.0, f32::INFINITY), RayCone { width: 0.6, spread: 0.01 });
        let lambert = cone.after_bounce(10.0, FRAC_1_PI);
        assert!((lambert.spread - (0.01 + BUNDLE_SHARE * PI.sqrt())).abs() < 1e-6);
        // Vanishing or invalid densities add a bounded amount or nothing.
        assert_eq!(cone.after_bounce(0.0, 0.0).spread, 0.01 + 2.0);
        assert_eq!(cone.after_bounce(0.0, f32::NAN).spread, 0.01);
    }

    #[test]
    fn level_of_detail_is_log2_of_the_footprint_in_uv_units() {
        // A triangle of world area 4 mapped onto uv area 1: a footprint 2 wide covers 1 uv.
        assert!((uv_level_of_detail(2.0, 8.0, 2.0, 1.0) - 0.0).abs() < 1e-6);
        assert!((uv_level_of_detail(8.0, 8.0, 2.0, 1.0) - 2.0).abs() < 1e-6);
        // Seen at 60° the footprint stretches by 1/cos = 2: one level coarser.
        assert!((uv_level_of_detail(2.0, 8.0, 2.0, -0.5) - 1.0).abs() < 1e-6);
        // Grazing views stay finite; no footprint or degenerate uvs mean the finest level.
        assert!(uv_level_of_detail(2.0, 8.0, 2.0, 0.0).is_finite());
        assert_eq!(uv_level_of_detail(0.0, 8.0, 2.0, 1.0), f32::NEG_INFINITY);
        assert_eq!(uv_level_of_detail(2.0, 8.0, 0.0, 1.0), f32::NEG_INFINITY);
        assert_eq!(uv_level_of_detail(0.0, 0.0, 0.0, 1.0), f32::NEG_INFINITY);
    }

    /// A 2 × 2 m floor at y = 0 with a 256 × 256 black-and-white checkerboard of single texels.
    fn checkerboard_floor() -> Scene {
        let mut scene = Scene::empty("checkerboard");
        let raw: Vec<u8> = (0..256 * 256)
            .flat_map(|i| {
                let v = if (i % 256 + i / 256) % 2 == 0 { 255 } else { 0 };
                [v, v, v, 255]
            })
            .collect();
        scene.textures.push(Texture::from_rgba8("checker".into(), 256, 256, false, raw));
        scene.materials.push(Material {
            base_color: Vec3::ONE,
            base_color_texture: Some(TextureRef::new(0)),
            ..Material::default()
        });
        let corners = [
            Vec3::new(-1.0, 0.0, -1.0),
            Vec3::new(-1.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, -1.0),
        ];
        let mut floor = polygon("floor", &corners, 1);
        floor.uvs = Some(vec![Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)]);
        scene.meshes.push(floor);
        scene
    }

    #[test]
    fn wide_footprints_see_the_texture_mean_and_narrow_ones_single_texels() {
        let scene = checkerboard_floor();
        let hit = |u: f32, v: f32| Hit {
            distance: 1.0,
            mesh: 0,
            triangle: 0,
            barycentric: Vec2::new(u, v),
            geometric_normal: Vec3::Y,
        };
        let wo = Vec3::Y;
        // Barycentrics at texel centres: the finest level returns the texel itself.
        let (mut narrow, mut wide) = (Vec::new(), Vec::new());
        for i in 0..50 {
            let u = (i as f32 * 0.618_034).fract() * 0.45;
            let v = (i as f32 * 0.754_877_7).fract() * 0.45;
            narrow.push(SurfacePoint::new(&scene, &hit(u, v), wo, 0.0, 0.0).bsdf.base_color.x);
            // A footprint of 0.5 m is 64 texels: level 6, a 4 × 4 checkerboard of means 0.5.
            wide.push(SurfacePoint::new(&scene, &hit(u, v), wo, 0.0, 0.5).bsdf.base_color.x);
        }
        let spread = |values: &[f32]| values.iter().fold(0.0f32, |m, &x| m.max((x - 0.5).abs()));
        assert!(spread(&narrow) > 0.3, "single texels are far from the mean: {narrow:?}");
        assert!(spread(&wide) < 0.01, "wide footprints average the checkerboard: {wide:?}");
    }
}
