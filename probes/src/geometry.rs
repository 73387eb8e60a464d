//! The scene's static triangles as the precompute sees them: checked once (static, finite,
//! not empty), flattened with a global triangle index, in f64 so that scenes from 1e-6 to 1e9
//! in size behave alike (every length the crate uses is relative to the scene's extent).

use glam::{DVec3, Vec3};
use tracer::Scene;

use crate::ProbesError;

/// One triangle with its origin in the scene.
#[derive(Clone, Copy, Debug)]
pub struct Triangle {
    pub mesh: u32,
    pub index: u32,
    pub vertices: [DVec3; 3],
}

impl Triangle {
    /// `(b − a) × (c − a)`: twice the area along the winding (front-face) normal.
    pub fn cross(&self) -> DVec3 {
        let [a, b, c] = self.vertices;
        (b - a).cross(c - a)
    }

    pub fn area(&self) -> f64 {
        0.5 * self.cross().length()
    }

    /// The unit winding normal, `None` for a degenerate triangle (zero or non-finite area).
    pub fn normal(&self) -> Option<DVec3> {
        let n = self.cross();
        let len = n.length();
        (len > 0.0 && len.is_finite()).then(|| n / len).filter(|n| n.is_finite())
    }
}

/// The scene's triangles, in mesh order, and their bounds.
#[derive(Clone, Debug)]
pub struct Geometry {
    pub triangles: Vec<Triangle>,
    pub lo: DVec3,
    pub hi: DVec3,
}

impl Geometry {
    /// Flattens `scene`, refusing moving meshes, non-finite vertices and a scene without any
    /// triangle of non-zero area.
    pub fn from_scene(scene: &Scene) -> Result<Geometry, ProbesError> {
        let mut triangles = Vec::new();
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for (m, mesh) in scene.meshes.iter().enumerate() {
            if mesh.is_moving() {
                return Err(ProbesError::MovingGeometry { mesh: mesh.name.clone() });
            }
            if let Some(vertex) = mesh.positions.iter().position(|p| !p.is_finite()) {
                return Err(ProbesError::NonFinite { mesh: mesh.name.clone(), vertex });
            }
            for (t, idx) in mesh.indices.iter().enumerate() {
                let v = idx.map(|i| mesh.positions[i as usize].as_dvec3());
                for p in v {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
                triangles.push(Triangle { mesh: m as u32, index: t as u32, vertices: v });
            }
        }
        if !triangles.iter().any(|t| t.area() > 0.0) {
            return Err(ProbesError::EmptyScene);
        }
        Ok(Geometry { triangles, lo, hi })
    }

    /// The largest extent of the bounds (> 0: some triangle has area).
    pub fn scale(&self) -> f64 {
        (self.hi - self.lo).max_element()
    }
}

/// The camera position and the positions of the scene's point and spot lights: the places the
/// flood fill must reach even inside a closed room.
pub fn seed_points(scene: &Scene) -> Vec<DVec3> {
    let mut seeds = vec![scene.camera.position.as_dvec3()];
    for light in &scene.lights {
        match light {
            tracer::scene::PunctualLight::Point { position, .. }
            | tracer::scene::PunctualLight::Spot { position, .. } => seeds.push(position.as_dvec3()),
            tracer::scene::PunctualLight::Directional { .. } => {}
        }
    }
    seeds.retain(|p| p.is_finite());
    seeds
}

/// `v` as f32 (positions handed back to the tracer).
pub fn to_f32(v: DVec3) -> Vec3 {
    v.as_vec3()
}
