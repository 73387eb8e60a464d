//! Scale invariance: the same scene built at 1e-6 and at 1e9 times its size
//! renders the same image. Every length scales by s; a point light's intensity scales by s² (its
//! irradiance falls with the squared distance), radiance (emitters, sphere lights, the
//! environment) does not change. With the same seed the paths take the same random numbers, so
//! the images differ only where float rounding or an absolute epsilon changes a decision.

use crate::common;

use common::{mean, render, SceneToml};
use glam::Vec3;

/// A room (floor, ceiling, three walls; the fourth side open to the environment) holding a
/// sphere and a block, lit by a sphere light, a point light, an emissive quad on the ceiling
/// and the environment, seen from inside, all lengths times `s`.
fn room_at_scale(s: f64) -> SceneToml {
    let p = |v: [f64; 3]| v.map(|x| (x * s) as f32);
    let quad = |a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3]| [p(a), p(b), p(c), p(d)];
    let intensity = (2.0 * s * s) as f32;
    SceneToml::new(4, Some([0.3, 0.35, 0.4]))
        .camera(p([0.0, 1.0, 3.5]), p([0.0, 0.8, 0.0]), 60.0, "")
        .diffuse("white", [0.7; 3])
        .diffuse("red", [0.6, 0.1, 0.1])
        .emitter("lamp", [4.0, 3.5, 3.0], "")
        .polygon("white", &quad([-2.0, 0.0, -2.0], [-2.0, 0.0, 4.0], [2.0, 0.0, 4.0], [2.0, 0.0, -2.0]), "")
        .polygon("white", &quad([-2.0, 2.5, -2.0], [2.0, 2.5, -2.0], [2.0, 2.5, 4.0], [-2.0, 2.5, 4.0]), "")
        .polygon("white", &quad([-2.0, 0.0, -2.0], [2.0, 0.0, -2.0], [2.0, 2.5, -2.0], [-2.0, 2.5, -2.0]), "")
        .polygon("red", &quad([-2.0, 0.0, -2.0], [-2.0, 2.5, -2.0], [-2.0, 2.5, 4.0], [-2.0, 0.0, 4.0]), "")
        .polygon("white", &quad([2.0, 0.0, -2.0], [2.0, 0.0, 4.0], [2.0, 2.5, 4.0], [2.0, 2.5, -2.0]), "")
        .polygon("lamp", &quad([-0.4, 2.49, -0.4], [0.4, 2.49, -0.4], [0.4, 2.49, 0.4], [-0.4, 2.49, 0.4]), "")
        .sphere("white", p([0.6, 0.4, 0.2]), (0.4 * s) as f32, "")
        .raw(&format!(
            "[[mesh]]\nshape = \"box\"\nmaterial = \"red\"\nmin = {:?}\nmax = {:?}\n\
             [[light]]\ntype = \"sphere\"\ncenter = {:?}\nradius = {:?}\nradiance = [6, 6, 5]\n\
             [[light]]\ntype = \"point\"\nposition = {:?}\nintensity = [{intensity:?}, {intensity:?}, {intensity:?}]",
            p([-1.2, 0.0, -1.0]),
            p([-0.5, 1.1, -0.3]),
            p([1.2, 1.9, -1.2]),
            0.15 * s,
            p([-1.0, 2.0, 1.5]),
        ))
}

#[test]
fn the_same_room_from_1e_minus_6_to_1e9_renders_the_same_image() {
    let (width, height, spp) = (24, 18, 8);
    let reference = render(&room_at_scale(1.0).scene(), width, height, spp, 7);
    let reference_mean = mean(&reference.beauty);
    assert!(reference_mean.min_element() > 0.05, "the room is lit: {reference_mean}");
    let mut failures = Vec::new();
    for s in [1e-9, 1e-6, 1e-3, 1e3, 1e6, 1e9, 1e12] {
        let scene = room_at_scale(s).scene();
        assert!(scene.warnings.is_empty(), "scale {s:e}: {:?}", scene.warnings);
        let frame = render(&scene, width, height, spp, 7);
        assert_eq!(frame.invalid_samples, 0, "scale {s:e}");
        let m = mean(&frame.beauty);
        let relative = ((m - reference_mean) / reference_mean).abs().max_element();
        if relative >= 0.01 {
            failures.push(format!("scale {s:e}: mean {m} against {reference_mean} at scale 1"));
        }
        // Pixel by pixel: the same paths, so most pixels agree closely; a few may take another
        // branch where rounding flips a decision.
        let close = frame
            .beauty
            .iter()
            .zip(&reference.beauty)
            .filter(|(a, b)| ((**a - **b).abs() - 0.02 * b.abs() - Vec3::splat(1e-3)).max_element() <= 0.0)
            .count();
        let share = close as f32 / frame.beauty.len() as f32;
        if share <= 0.9 {
            failures.push(format!("scale {s:e}: only {:.1} % of pixels agree with scale 1", 100.0 * share));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// A valid triangle far from the origin or of enormous size is not "degenerate": the area test
/// must not overflow (a cross product of 1e19-long edges is 1e38, its squared length +inf).
#[test]
fn huge_valid_triangles_are_kept() {
    for size in [1e17f32, 1e19, 1e-19] {
        let scene = SceneToml::lit_by_environment([1.0; 3])
            .camera([0.0, 0.0, 3.0 * size], [0.0; 3], 60.0, "")
            .diffuse("white", [0.8; 3])
            .polygon("white", &[[-size, -size, 0.0], [size, -size, 0.0], [0.0, size, 0.0]], "")
            .scene();
        assert!(scene.warnings.iter().all(|w| !w.contains("degenerate")), "size {size:e}: {:?}", scene.warnings);
        assert_eq!(scene.meshes.len(), 1, "size {size:e}");
    }
}
