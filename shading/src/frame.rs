//! An orthonormal shading frame about a unit normal.

use glam::Vec3;

/// An orthonormal frame around a unit normal (Duff et al. 2017).
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub tangent: Vec3,
    pub bitangent: Vec3,
    pub normal: Vec3,
}

impl Frame {
    pub fn new(normal: Vec3) -> Frame {
        let sign = 1.0f32.copysign(normal.z);
        let a = -1.0 / (sign + normal.z);
        let b = normal.x * normal.y * a;
        let tangent = Vec3::new(1.0 + sign * normal.x * normal.x * a, sign * b, -sign * normal.x);
        let bitangent = Vec3::new(b, sign + normal.y * normal.y * a, -normal.y);
        Frame { tangent, bitangent, normal }
    }

    #[inline]
    pub fn to_local(&self, w: Vec3) -> Vec3 {
        Vec3::new(w.dot(self.tangent), w.dot(self.bitangent), w.dot(self.normal))
    }

    #[inline]
    pub fn to_world(&self, w: Vec3) -> Vec3 {
        self.tangent * w.x + self.bitangent * w.y + self.normal * w.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_for_all_normals() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.3, -0.4, 0.866).normalize(),
            Vec3::new(0.0, 0.0, -0.99999).normalize(),
        ] {
            let f = Frame::new(n);
            assert!((f.tangent.length() - 1.0).abs() < 1e-5);
            assert!((f.bitangent.length() - 1.0).abs() < 1e-5);
            assert!(f.tangent.dot(f.normal).abs() < 1e-5 && f.bitangent.dot(f.normal).abs() < 1e-5);
            let w = Vec3::new(0.1, 0.7, -0.2).normalize();
            assert!((f.to_world(f.to_local(w)) - w).length() < 1e-5);
        }
    }
}
