//! Octahedral decoding of the `u16 × 2` unit vectors of the sample files
//! (docs/sample-format.md): values 1..=65535 map to [−1, 1]; (0, 0) means "no vector".

/// The unit vector of an octahedral pair, or `None` for (0, 0).
pub fn decode(q: [f32; 2]) -> Option<[f32; 3]> {
    if q[0] == 0.0 && q[1] == 0.0 {
        return None;
    }
    let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
    let px = (q[0] - 1.0) / 65534.0 * 2.0 - 1.0;
    let py = (q[1] - 1.0) / 65534.0 * 2.0 - 1.0;
    let z = 1.0 - px.abs() - py.abs();
    let (x, y) = if z < 0.0 { ((1.0 - py.abs()) * sign(px), (1.0 - px.abs()) * sign(py)) } else { (px, py) };
    let length = (x * x + y * y + z * z).sqrt();
    Some([x / length, y / length, z / length])
}
