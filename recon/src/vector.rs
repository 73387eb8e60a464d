//! Vector maths on the `[f32; 3]` records the sample format gives and the reconstructions keep,
//! defined once, through glam's `Vec3`. Each is the same IEEE operations in the same order as
//! the component-wise form (x·x' + y·y' + z·z' added left to right; no fused multiply-add), so
//! results are bit for bit those of the hand-written forms they replaced (tested).

use glam::Vec3;

/// a · b.
#[inline]
pub fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    Vec3::from(a).dot(Vec3::from(b))
}

/// a − b.
#[inline]
pub fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    (Vec3::from(a) - Vec3::from(b)).to_array()
}

/// a + s·b.
#[inline]
pub fn add_scaled(a: [f32; 3], b: [f32; 3], s: f32) -> [f32; 3] {
    (Vec3::from(a) + Vec3::from(b) * s).to_array()
}

/// |a|.
#[inline]
pub fn length(a: [f32; 3]) -> f32 {
    Vec3::from(a).length()
}

/// a × b.
#[inline]
pub fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    Vec3::from(a).cross(Vec3::from(b)).to_array()
}

/// a / |a|, each component divided (glam's `normalize` multiplies by the reciprocal, which
/// rounds differently); the zero vector stays zero.
#[inline]
pub fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = length(a);
    if l > 0.0 {
        (Vec3::from(a) / l).to_array()
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;

    /// Each against its component-wise form, bit for bit, on random vectors over many scales.
    #[test]
    fn each_is_its_component_wise_form_bit_for_bit() {
        let mut rng = Lcg(7);
        let vector = |rng: &mut Lcg| {
            let scale = 10f32.powi((rng.uniform() * 24.0) as i32 - 12);
            [0, 1, 2].map(|_| (rng.uniform() - 0.5) * scale)
        };
        let bits = |v: [f32; 3]| v.map(f32::to_bits);
        for _ in 0..10_000 {
            let (a, b, s) = (vector(&mut rng), vector(&mut rng), rng.uniform() * 3.0 - 1.5);
            let dot_by_hand = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            assert_eq!(dot(a, b).to_bits(), dot_by_hand.to_bits());
            assert_eq!(bits(sub(a, b)), bits([a[0] - b[0], a[1] - b[1], a[2] - b[2]]));
            assert_eq!(bits(add_scaled(a, b, s)), bits([a[0] + b[0] * s, a[1] + b[1] * s, a[2] + b[2] * s]));
            let length_by_hand = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            assert_eq!(length(a).to_bits(), length_by_hand.to_bits());
            let cross_by_hand = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
            assert_eq!(bits(cross(a, b)), bits(cross_by_hand));
            let l = length_by_hand;
            assert_eq!(bits(normalize(a)), bits([a[0] / l, a[1] / l, a[2] / l]));
        }
        assert_eq!(normalize([0.0; 3]), [0.0; 3]);
        assert_eq!(normalize([0.0, 3.0, 4.0]), [0.0, 0.6, 0.8]);
    }
}
