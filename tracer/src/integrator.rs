//! Unidirectional path tracing with next-event estimation and multiple importance sampling.
//!
//! At every vertex one emitter is chosen by power and a shadow ray traced (NEE), and one
//! direction is drawn from the BSDF; light reached by either strategy is weighted with the
//! power heuristic against the other strategy's density (delta lights take NEE alone). Paths
//! longer than three bounces continue with Russian roulette on the throughput. Radiance is
//! split into `direct` (emission seen by the camera plus light reaching the first surface
//! straight from an emitter) and `indirect` (everything else).

use glam::{Vec2, Vec3};

use crate::accel::{Accel, Hit};
use crate::bsdf::{Bsdf, Frame};
use crate::camera::concentric_disk;
use crate::lights::{triangle_at, triangle_emission, LightSampler};
use crate::sampler::Sampler;
use crate::scene::Scene;

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

/// The camera coordinates of one sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CameraSample {
    /// Film position in pixels (origin top-left).
    pub film: Vec2,
    /// Position on the unit lens disk (zero for a pinhole).
    pub lens: Vec2,
    /// Time in [0, 1] over the shutter (zero without motion).
    pub time: f32,
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
    pub fn new(scene: &Scene, hit: &Hit, wo: Vec3, time: f32) -> SurfacePoint {
        let mesh = &scene.meshes[hit.mesh as usize];
        let [a, b, c] = triangle_at(scene, hit.mesh, hit.triangle, time);
        let (u, v) = (hit.barycentric.x, hit.barycentric.y);
        let w = 1.0 - u - v;
        let position = a * w + b * u + c * v;
        let winding_normal = (b - a).cross(c - a).normalize_or_zero();
        let front_face = winding_normal.dot(wo) >= 0.0;
        let geometric_normal = if front_face { winding_normal } else { -winding_normal };
        let [ia, ib, ic] = mesh.indices[hit.triangle as usize];
        let mut shading_normal = match &mesh.normals {
            Some(n) => {
                let interpolated = n[ia as usize] * w + n[ib as usize] * u + n[ic as usize] * v;
                let interpolated = interpolated.normalize_or_zero();
                if interpolated == Vec3::ZERO {
                    geometric_normal
                } else if interpolated.dot(geometric_normal) < 0.0 {
                    -interpolated
                } else {
                    interpolated
                }
            }
            None => geometric_normal,
        };
        // A shading normal that hides wo would make the surface black; fall back.
        if shading_normal.dot(wo) <= 1e-4 {
            shading_normal = geometric_normal;
        }
        let uv = match &mesh.uvs {
            Some(uvs) => uvs[ia as usize] * w + uvs[ib as usize] * u + uvs[ic as usize] * v,
            None => Vec2::ZERO,
        };
        let material = &scene.materials[mesh.material as usize];
        let mut base_color = material.base_color;
        if let Some(t) = &material.base_color_texture {
            base_color *= scene.textures[t.index as usize].sample(t.apply(uv)).truncate();
        }
        let (mut metallic, mut roughness) = (material.metallic, material.roughness);
        if let Some(t) = &material.metallic_roughness_texture {
            let texel = scene.textures[t.index as usize].sample(t.apply(uv));
            roughness *= texel.y;
            metallic *= texel.z;
        }
        let scale = position.abs().max_element().max(a.abs().max_element());
        SurfacePoint {
            position,
            geometric_normal,
            shading_normal,
            front_face,
            uv,
            bsdf: Bsdf::with_ior(base_color, metallic, roughness, material.specular, material.ior),
            epsilon: (scale + 1e-3) * 4e-6,
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
}

impl TracedRay {
    /// Adds a contribution emitted towards vertex `level` (0 = emission of the first hit),
    /// dropping non-finite values.
    #[inline]
    fn add(&mut self, level: u32, value: Vec3) {
        if !value.is_finite() {
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
        if !value.is_finite() {
            return;
        }
        self.add(level, value);
        if from_split_emitter && level > 0 {
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
        Integrator {
            scene,
            accel,
            lights,
            max_bounces,
            split_emitter: None,
            width,
            height,
            film_tan: scene.camera.tan_half_fov(width, height),
            has_lens: scene.camera.has_lens(),
            has_motion: scene.has_motion(),
        }
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

    /// Traces the path of a given camera sample; `sampler` supplies the path's dimensions.
    pub fn trace_camera_sample<R: RayRecorder>(
        &self,
        camera_sample: &CameraSample,
        sampler: &mut Sampler,
        recorder: &mut R,
    ) -> PathSample {
        let (origin, direction) = self.scene.camera.generate_ray_with_tan(
            self.film_tan,
            camera_sample.film,
            camera_sample.lens,
            self.width,
            self.height,
        );
        let ray = PathStart { origin, direction, time: camera_sample.time, bounce: 0, previous: None };
        let traced = self.trace_ray(&ray, sampler, recorder);
        PathSample {
            direct: traced.emitted + traced.direct,
            indirect: traced.beyond,
            first_hit: traced.first_hit,
            rays: traced.rays,
            split_emitter_light: traced.split_emitter_light,
        }
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
        self.next_event_from(surface, wo, time, u, rays, recorder).0
    }

    /// `next_event` and the emissive mesh the light came from (`None` for punctual and
    /// environment light, or when nothing arrives).
    fn next_event_from<R: RayRecorder>(
        &self,
        surface: &SurfacePoint,
        wo: Vec3,
        time: f32,
        u: [f32; 3],
        rays: &mut u32,
        recorder: &mut R,
    ) -> (Vec3, Option<u32>) {
        let frame = Frame::new(surface.shading_normal);
        let wo_local = frame.to_local(wo);
        let (u_select, u_light) = (u[0], [u[1], u[2]]);
        let Some(light) = self.lights.sample(self.scene, surface.position, time, u_select, u_light) else {
            return (Vec3::ZERO, None);
        };
        // Reject light from below the geometric surface (light leaking through).
        if light.wi.dot(surface.geometric_normal) <= 0.0 {
            return (Vec3::ZERO, None);
        }
        let wi_local = frame.to_local(light.wi);
        let f = surface.bsdf.eval(wo_local, wi_local);
        if f == Vec3::ZERO {
            return (Vec3::ZERO, None);
        }
        let shadow_origin = surface.spawn_origin(light.wi);
        // Stop short of the light's own surface by a relative margin.
        let t_max = if light.distance.is_finite() {
            let light_point = surface.position + light.wi * light.distance;
            (light_point - shadow_origin).length() * (1.0 - 2e-4)
        } else {
            f32::INFINITY
        };
        *rays += 1;
        recorder.record(RecordedRay { origin: shadow_origin, direction: light.wi, t_max, time, kind: RayKind::Shadow });
        if !(t_max > 0.0) || self.accel.occluded(shadow_origin, light.wi, 0.0, t_max, time) {
            return (Vec3::ZERO, None);
        }
        let weight = match light.pdf {
            Some(light_pdf) => power_heuristic(light_pdf, surface.bsdf.pdf(wo_local, wi_local)),
            None => 1.0,
        };
        let value = f * light.weighted_radiance * weight;
        if value.is_finite() {
            (value, light.mesh)
        } else {
            (Vec3::ZERO, None)
        }
    }

    /// Radiance arriving at `start.origin` along `start.direction`, split by where it was
    /// emitted relative to the first surface the ray hits (see `TracedRay`).
    pub fn trace_ray<R: RayRecorder>(&self, start: &PathStart, sampler: &mut Sampler, recorder: &mut R) -> TracedRay {
        let scene = self.scene;
        let camera = &scene.camera;
        let time = start.time;
        let mut origin = start.origin;
        let mut direction = start.direction;
        let mut traced = TracedRay::default();
        let mut throughput = Vec3::ONE;
        let (mut previous_bsdf_pdf, mut previous_position) = match start.previous {
            Some((pdf, position)) => (Some(pdf), position),
            None => (None, origin),
        };

        for bounce in start.bounce..=self.max_bounces {
            // Vertex level relative to the first hit: 0 = the first hit itself.
            let level = bounce - start.bounce;
            traced.rays += 1;
            recorder.record(RecordedRay { origin, direction, t_max: f32::INFINITY, time, kind: RayKind::Closest });
            let Some(hit) = self.accel.intersect(origin, direction, 0.0, f32::INFINITY, time) else {
                if scene.environment.max_element() > 0.0 {
                    let weight = match previous_bsdf_pdf {
                        None => 1.0,
                        Some(pdf) => power_heuristic(pdf, self.lights.pdf_environment()),
                    };
                    traced.add(level, throughput * scene.environment * weight);
                }
                break;
            };
            let wo = -direction;
            let surface = SurfacePoint::new(scene, &hit, wo, time);

            if level == 0 {
                traced.first_hit = Some(FirstHit::new(&surface, hit.mesh, camera.depth(surface.position)));
            }

            let emitted = surface.emission(scene, &hit, wo);
            if emitted != Vec3::ZERO {
                let weight = match previous_bsdf_pdf {
                    None => 1.0,
                    Some(pdf) => {
                        let light_pdf =
                            self.lights.pdf_triangle(hit.mesh, hit.triangle, previous_position, surface.position);
                        power_heuristic(pdf, light_pdf)
                    }
                };
                let from_split_emitter = self.split_emitter == Some(hit.mesh);
                traced.add_from(level, throughput * emitted * weight, from_split_emitter);
            }
            if bounce == self.max_bounces {
                break;
            }

            let frame = Frame::new(surface.shading_normal);
            let wo_local = frame.to_local(wo);
            let [u_light_select, u_lobe] = sampler.next_2d();
            let u_light = sampler.next_2d();
            let u_bsdf = sampler.next_2d();
            let [u_roulette, _] = sampler.next_2d();

            let (direct, emitter) = self.next_event_from(
                &surface,
                wo,
                time,
                [u_light_select, u_light[0], u_light[1]],
                &mut traced.rays,
                recorder,
            );
            // Light reflected at this vertex straight from an emitter is one level deeper.
            let from_split_emitter = emitter.is_some() && emitter == self.split_emitter;
            traced.add_from(level + 1, throughput * direct, from_split_emitter);

            // Continue the path by BSDF sampling.
            let Some(bsdf_sample) = surface.bsdf.sample(wo_local, u_lobe, u_bsdf) else {
                break;
            };
            let wi = frame.to_world(bsdf_sample.wi);
            if wi.dot(surface.geometric_normal) <= 0.0 {
                break;
            }
            throughput *= bsdf_sample.weight;
            previous_bsdf_pdf = Some(bsdf_sample.pdf);
            previous_position = surface.position;
            origin = surface.spawn_origin(wi);
            direction = wi;

            if bounce >= 3 {
                let survive = throughput.max_element().min(0.95);
                if !(survive > 0.0) || u_roulette >= survive {
                    break;
                }
                throughput /= survive;
            }
        }
        traced
    }
}
