//! The Embree 3 accelerator over a flattened scene.
//!
//! One Embree triangle geometry per mesh, attached in mesh order so that Embree's geometry id
//! is the mesh index. Moving meshes get two time steps (shutter open and close) and Embree
//! interpolates linearly at the ray's time. Materials with an alpha mask get intersection and
//! occlusion filter callbacks that reject hits where the mask's coverage is below the cutoff;
//! single-sided materials (glTF `doubleSided: false`) get callbacks that reject hits on back
//! faces, for every kind of ray: such a surface is not there seen from behind.
//! All `unsafe` lives inside the `embree3` crate; this module uses its safe API only.

use std::sync::Arc;

use embree3::{
    BufferUsage, BuildQuality, Device, Format, Geometry, GeometryKind, IntersectContext, Ray, RayHit, SoAHit, SoARay,
    INVALID_ID,
};
use glam::{Vec2, Vec3};

use crate::error::RenderError;
use crate::scene::{AlphaMask, Scene};
use crate::texture::Texture;

/// A ray-surface intersection as Embree reports it.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub distance: f32,
    pub mesh: u32,
    pub triangle: u32,
    /// Embree barycentrics: p = (1 − u − v) a + u b + v c.
    pub barycentric: Vec2,
    /// Unnormalised geometric normal from the triangle's winding.
    pub geometric_normal: Vec3,
}

/// Everything an alpha-mask filter callback needs, shared with Embree's threads.
struct AlphaTester {
    indices: Vec<[u32; 3]>,
    uvs: Vec<Vec2>,
    texture: Texture,
    mask: AlphaMask,
}

impl AlphaTester {
    fn keeps(&self, triangle: u32, u: f32, v: f32) -> bool {
        let Some(&[a, b, c]) = self.indices.get(triangle as usize) else {
            return true;
        };
        let uv = self.uvs[a as usize] * (1.0 - u - v) + self.uvs[b as usize] * u + self.uvs[c as usize] * v;
        let coverage = self.texture.sample(self.mask.texture.apply(uv))[self.mask.channel.min(3)] * self.mask.factor;
        coverage >= self.mask.cutoff
    }
}

/// The filter callbacks of one mesh: its alpha mask, and whether back faces are culled (a
/// single-sided material, glTF `doubleSided: false`).
struct HitFilter {
    alpha: Option<AlphaTester>,
    cull_back_faces: bool,
}

impl HitFilter {
    /// Whether a hit of a ray along `direction` on `triangle` at (u, v), whose Embree geometric
    /// normal is `ng`, counts. Embree's `Ng` points to the counter-clockwise front side (as
    /// (v1 − v0) × (v2 − v0); `tracer/tests/surfaces.rs` checks the convention), so a ray meets a
    /// back face when it travels along `Ng`.
    fn keeps(&self, direction: [f32; 3], ng: [f32; 3], triangle: u32, u: f32, v: f32) -> bool {
        if self.cull_back_faces && Vec3::from(direction).dot(Vec3::from(ng)) > 0.0 {
            return false;
        }
        self.alpha.as_ref().map_or(true, |alpha| alpha.keeps(triangle, u, v))
    }
}

pub struct Accel {
    // Field order matters for drop order: the scene before its geometries and device.
    scene: embree3::Scene<'static>,
    _geometries: Vec<Geometry<'static>>,
    _device: Device,
    /// Number of triangles attached (for statistics).
    pub triangle_count: usize,
}

fn embree_error(what: &str, e: impl std::fmt::Debug) -> RenderError {
    RenderError::Embree(format!("{what}: {e:?}"))
}

impl Accel {
    pub fn build(scene: &Scene) -> Result<Accel, RenderError> {
        let device = Device::new().map_err(|e| embree_error("creating the device", e))?;
        let mut embree_scene = device.create_scene().map_err(|e| embree_error("creating the scene", e))?;
        embree_scene.set_build_quality(BuildQuality::HIGH);
        let mut geometries = Vec::with_capacity(scene.meshes.len());
        let mut triangle_count = 0;
        for (index, mesh) in scene.meshes.iter().enumerate() {
            let mut geometry = device
                .create_geometry(GeometryKind::TRIANGLE)
                .map_err(|e| embree_error("creating a triangle geometry", e))?;
            let steps: u32 = if mesh.is_moving() { 2 } else { 1 };
            if steps == 2 {
                geometry.set_time_step_count(2);
            }
            for step in 0..steps {
                let shift = if step == 0 { Vec3::ZERO } else { mesh.motion };
                let mut vertices = geometry
                    .set_new_buffer::<[f32; 3]>(BufferUsage::VERTEX, step, Format::FLOAT3, 12, mesh.positions.len())
                    .map_err(|e| embree_error(&format!("vertex buffer of mesh '{}'", mesh.name), e))?;
                for (dst, p) in vertices.iter_mut().zip(&mesh.positions) {
                    *dst = (*p + shift).to_array();
                }
            }
            geometry
                .set_new_buffer::<[u32; 3]>(BufferUsage::INDEX, 0, Format::UINT3, 12, mesh.indices.len())
                .map_err(|e| embree_error(&format!("index buffer of mesh '{}'", mesh.name), e))?
                .copy_from_slice(&mesh.indices);
            let material = &scene.materials[mesh.material as usize];
            let alpha = match (&material.alpha, &mesh.uvs) {
                (Some(mask), Some(uvs)) => Some(AlphaTester {
                    indices: mesh.indices.clone(),
                    uvs: uvs.clone(),
                    texture: scene.textures[mask.texture.index as usize].clone(),
                    mask: mask.clone(),
                }),
                _ => None,
            };
            if alpha.is_some() || !material.double_sided {
                let filter = Arc::new(HitFilter { alpha, cull_back_faces: !material.double_sided });
                let for_occlusion = filter.clone();
                geometry.set_intersect_filter_function::<_, ()>(move |rays, hits, mut valid, _ctx, _| {
                    for i in 0..hits.len() {
                        if valid[i] != 0
                            && !filter.keeps(rays.dir(i), hits.normal(i), hits.prim_id(i), hits.u(i), hits.v(i))
                        {
                            valid[i] = 0;
                        }
                    }
                });
                geometry.set_occluded_filter_function::<_, ()>(move |rays, hits, mut valid, _ctx, _| {
                    for i in 0..hits.len() {
                        if valid[i] != 0
                            && !for_occlusion.keeps(rays.dir(i), hits.normal(i), hits.prim_id(i), hits.u(i), hits.v(i))
                        {
                            valid[i] = 0;
                        }
                    }
                });
            }
            let geometry = geometry.commit();
            let id = embree_scene.attach_geometry(&geometry);
            if id != index as u32 {
                return Err(RenderError::Embree(format!("geometry id {id} differs from mesh index {index}")));
            }
            triangle_count += mesh.indices.len();
            geometries.push(geometry);
        }
        embree_scene.commit();
        Ok(Accel { scene: embree_scene, _geometries: geometries, _device: device, triangle_count })
    }

    /// Closest hit along `origin + t·direction` for t in (t_min, t_max) at ray time `time`.
    #[inline]
    pub fn intersect(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32, time: f32) -> Option<Hit> {
        let mut ray = Ray::segment(origin.to_array(), direction.to_array(), t_min, t_max);
        ray.time = time;
        let mut ray_hit = RayHit::from(ray);
        let mut context = IntersectContext::incoherent();
        self.scene.intersect(&mut context, &mut ray_hit);
        let hit = ray_hit.hit;
        if hit.geomID == INVALID_ID {
            return None;
        }
        Some(Hit {
            distance: ray_hit.ray.tfar,
            mesh: hit.geomID,
            triangle: hit.primID,
            barycentric: Vec2::new(hit.u, hit.v),
            geometric_normal: Vec3::new(hit.Ng_x, hit.Ng_y, hit.Ng_z),
        })
    }

    /// Whether anything blocks the segment (t_min, t_max).
    #[inline]
    pub fn occluded(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32, time: f32) -> bool {
        let mut ray = Ray::segment(origin.to_array(), direction.to_array(), t_min, t_max);
        ray.time = time;
        let mut context = IntersectContext::incoherent();
        self.scene.occluded(&mut context, &mut ray)
    }

    /// Traces a batch of rays with no shading (for the raw-Embree baseline of the benchmark).
    /// Returns the number of hits.
    pub fn intersect_batch(&self, rays: &[Ray]) -> usize {
        let mut hits = 0;
        let mut context = IntersectContext::incoherent();
        for ray in rays {
            let mut ray_hit = RayHit::from(*ray);
            self.scene.intersect(&mut context, &mut ray_hit);
            hits += (ray_hit.hit.geomID != INVALID_ID) as usize;
        }
        hits
    }

    /// Occlusion tests for a batch of rays; returns how many are blocked.
    pub fn occluded_batch(&self, rays: &[Ray]) -> usize {
        let mut context = IntersectContext::incoherent();
        rays.iter()
            .filter(|ray| {
                let mut ray = **ray;
                self.scene.occluded(&mut context, &mut ray)
            })
            .count()
    }
}
