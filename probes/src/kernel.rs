//! The spatial weight of Eq. 10: `w(t) = 2t³ − 3t² + 1` for `0 ≤ t ≤ 1`, 0 beyond, evaluated
//! at `t = ‖x − p_i‖ / r` (a cubic smoothstep from 1 at the probe to 0 at the support radius,
//! C¹ at both ends). The probe placement uses the same kernel for its density estimate.

/// Eq. 10, `w(t)`; 0 for `t > 1` and for NaN, 1 for `t ≤ 0`.
pub fn w(t: f64) -> f64 {
    if !(t < 1.0) {
        return 0.0;
    }
    let t = t.max(0.0);
    (2.0 * t - 3.0) * t * t + 1.0
}

/// The weight of a point at `distance` from a probe with support `radius` (> 0).
pub fn weight(distance: f64, radius: f64) -> f64 {
    w(distance / radius)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn end_conditions() {
        assert_eq!(w(0.0), 1.0);
        assert_eq!(w(1.0), 0.0);
        assert_eq!(w(1.5), 0.0);
        assert_eq!(w(f64::NAN), 0.0);
        assert_eq!(weight(3.0, 3.0), 0.0);
        assert_eq!(weight(0.0, 1e-9), 1.0);
        // Zero slope at both ends (C¹ with the constant 1 inside and 0 outside): central
        // differences shrink like h, not like a constant.
        for h in [1e-3, 1e-5] {
            let d0 = (w(h) - w(0.0)) / h;
            let d1 = (w(1.0) - w(1.0 - h)) / h;
            assert!(d0.abs() < 4.0 * h && d1.abs() < 4.0 * h, "slopes {d0} {d1} at h = {h}");
        }
    }

    #[test]
    fn monotone_and_point_symmetric() {
        let mut previous = w(0.0);
        for i in 1..=1000 {
            let t = i as f64 / 1000.0;
            let v = w(t);
            assert!(v <= previous, "w rises at {t}");
            // The smoothstep is point-symmetric about (½, ½): w(t) + w(1 − t) = 1.
            assert!((v + w(1.0 - t) - 1.0).abs() < 1e-12);
            previous = v;
        }
        assert!((w(0.5) - 0.5).abs() < 1e-15);
    }
}
