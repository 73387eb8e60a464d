//! `light` samples (TLFR soft shadows): with plane Π placed at the blocker's depth, a light ray
//! is blocked exactly when it crosses Π inside the blocker, which pins (l_x, l_y), z and the
//! light frame together; the Cornell box dumps with its luminaire.

use crate::common;

use common::{project_root, scene_from_toml, SceneToml, FLOOR, LAMP};
use glam::{Vec2, Vec3};
use sampleio::SampleFile;
use tracer::samples::light::{dump, PlanarLight};
use tracer::RenderSettings;
use tracer::{Accel, Scene};

fn dump_light(scene: &Scene, size: (u32, u32), spp: u32) -> (tempfile::TempDir, SampleFile) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("light.lfrs");
    let accel = Accel::build(scene).unwrap();
    let settings =
        RenderSettings { width: size.0, height: size.1, spp, seed: 4, max_bounces: 4, threads: 0, progress: false };
    dump(scene, &accel, &settings, &tracer::samples::FieldSelection::All, &path).unwrap();
    (dir, SampleFile::open(&path).unwrap())
}

#[test]
fn a_ray_is_blocked_exactly_when_it_crosses_the_blocker() {
    // A 1 x 1 light at y = 2 facing down (so Π, at depth 1, is the plane y = 1), a 0.2 x 0.2
    // blocker at y = 1 and a receiving floor at y = 0.
    let scene = scene_from_toml(
        r#"
        [render]
        [camera]
        position = [0, 1.8, 0.01]
        look_at = [0, 0, 0]
        up = [0, 0, 1]
        fov = 60
        [[material]]
        name = "lamp"
        base_color = [0, 0, 0]
        specular = 0
        emission = [4, 4, 4]
        [[mesh]]
        shape = "polygon"
        material = "lamp"
        points = [[-0.5, 2, -0.5], [0.5, 2, -0.5], [0.5, 2, 0.5], [-0.5, 2, 0.5]]
        [[mesh]]
        shape = "polygon"
        points = [[-0.1, 1, -0.1], [0.1, 1, -0.1], [0.1, 1, 0.1], [-0.1, 1, 0.1]]
        [[mesh]]
        shape = "polygon"
        points = [[-5, 0, -5], [-5, 0, 5], [5, 0, 5], [5, 0, -5]]
        "#,
    );
    let light = PlanarLight::find(&scene).unwrap();
    assert!((light.normal - Vec3::NEG_Y).length() < 1e-6, "emits downwards");
    assert!((light.plane_distance - 1.0).abs() < 1e-6);
    let to_light_coordinates = |p: Vec3| {
        let rel = p - light.corner;
        Vec2::new(rel.dot(light.edge_u.normalize()), rel.dot(light.edge_v.normalize()))
    };
    let a = to_light_coordinates(Vec3::new(-0.1, 1.0, -0.1));
    let b = to_light_coordinates(Vec3::new(0.1, 1.0, 0.1));
    let (lo, hi) = (a.min(b), a.max(b));

    let (_dir, file) = dump_light(&scene, (24, 24), 16);
    let names: Vec<_> = file.fields().iter().map(|f| f.name.clone()).collect();
    assert_eq!(names, ["lu", "lv", "lx", "ly", "z", "radiance", "density"]);
    let header_light = file.header().light.as_ref().unwrap();
    assert_eq!(header_light.plane_distance, Some(1.0));
    let (lu, lv, lx, ly) = (
        file.column("lu").unwrap(),
        file.column("lv").unwrap(),
        file.column("lx").unwrap(),
        file.column("ly").unwrap(),
    );
    let (z, radiance, density) =
        (file.column("z").unwrap(), file.column("radiance").unwrap(), file.column("density").unwrap());
    let (mut blocked, mut lit) = (0, 0);
    for i in 0..file.len() {
        assert!((0.0..1.0).contains(&lu[i]) && (0.0..1.0).contains(&lv[i]));
        assert!(density[i] > 0.0 && density[i].is_finite(), "every camera ray sees the floor or the blocker");
        assert_eq!(&radiance[3 * i..3 * i + 3], &[4.0, 4.0, 4.0]);
        let crossing = Vec2::new(lx[i], ly[i]);
        let inside = crossing.cmpgt(lo + 1e-3).all() && crossing.cmplt(hi - 1e-3).all();
        let outside = crossing.cmplt(lo - 1e-3).any() || crossing.cmpgt(hi + 1e-3).any();
        if inside {
            assert!((z[i] - 1.0).abs() < 1e-3, "crosses the blocker at {crossing}, z = {}", z[i]);
            blocked += 1;
        } else if outside {
            assert!((z[i] - 2.0).abs() < 1e-3, "misses the blocker at {crossing}, z = {}", z[i]);
            lit += 1;
        }
    }
    assert!(blocked > 100 && lit > 1000, "blocked {blocked}, lit {lit}");
}

#[test]
fn cornell_box_light_samples_use_the_luminaire() {
    let scene = Scene::load(&project_root().join("scenes/cornell.toml")).unwrap();
    let light = PlanarLight::find(&scene).unwrap();
    assert!((light.edge_u.length() * light.edge_v.length() - 130.0 * 105.0).abs() < 1.0, "the 130 x 105 luminaire");
    let (_dir, file) = dump_light(&scene, (16, 16), 4);
    let z = file.column("z").unwrap();
    let density = file.column("density").unwrap();
    // Every visible point is below the luminaire (positive light-space depth), and blocked rays
    // end before it.
    for i in 0..file.len() {
        if density[i] > 0.0 {
            assert!(z[i] > 0.0 && z[i] < 560.0, "z = {}", z[i]);
        }
    }
}

#[test]
fn a_scene_without_a_planar_light_is_a_clear_error() {
    let scene = scene_from_toml(
        r#"
        [render]
        environment = [1, 1, 1]
        [[light]]
        type = "sphere"
        center = [0, 2, 0]
        radius = 0.5
        radiance = [1, 1, 1]
        "#,
    );
    let message = PlanarLight::find(&scene).unwrap_err().to_string();
    assert!(message.contains("not planar"), "{message}");
    let empty = SceneToml::lit_by_environment([1.0, 1.0, 1.0]).scene();
    assert!(PlanarLight::find(&empty).unwrap_err().to_string().contains("emissive mesh"));
}

/// A 1 × 1 lamp (radiance 4) at y = 2 facing down, optionally a point light, over a grey floor,
/// seen from straight above; direct light only.
fn lamp_over_floor(point_light: bool) -> Scene {
    let point = if point_light {
        "[[light]]\ntype = \"point\"\nposition = [0.7, 1.5, 0.3]\nintensity = [3, 3, 3]\n"
    } else {
        ""
    };
    SceneToml::new(1, None)
        .camera([0.0, 1.5, 0.01], [0.0; 3], 50.0, "up = [0, 0, 1]\n")
        .emitter("lamp", [4.0; 3], "")
        .diffuse("floor", [0.5; 3])
        .polygon("lamp", &LAMP, "")
        .polygon("floor", &FLOOR, "")
        .raw(point)
        .scene()
}

fn dump_soft_shadow_lens_time(scene: &Scene, size: (u32, u32), spp: u32) -> (tempfile::TempDir, SampleFile) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lens-time.lfrs");
    let accel = Accel::build(scene).unwrap();
    let settings =
        RenderSettings { width: size.0, height: size.1, spp, seed: 9, max_bounces: 1, threads: 0, progress: false };
    tracer::samples::lens_time::dump_for_soft_shadows(
        scene,
        &accel,
        &settings,
        &tracer::samples::FieldSelection::All,
        &path,
    )
    .unwrap();
    (dir, SampleFile::open(&path).unwrap())
}

#[test]
fn soft_shadow_lens_time_samples_split_off_exactly_the_planar_light() {
    // Only the lamp: without it nothing reaches the floor, so `radiance_without_light` is exactly
    // zero, while `radiance` equals a plain lens-time dump of the same seed bit for bit.
    let scene = lamp_over_floor(false);
    let (_dir, file) = dump_soft_shadow_lens_time(&scene, (16, 16), 4);
    let names: Vec<_> = file.fields().iter().map(|f| f.name.clone()).collect();
    assert_eq!(names, ["x", "y", "z", "radiance", "depth_gradient", "albedo", "normal", "radiance_without_light"]);
    let radiance = file.column("radiance").unwrap();
    let without = file.column("radiance_without_light").unwrap();
    let albedo = file.column("albedo").unwrap();
    assert!(radiance.iter().sum::<f32>() > 0.0);
    assert!(without.iter().all(|&v| v == 0.0), "the lamp is the only light");
    assert!(albedo.iter().all(|&a| (a - 0.5).abs() < 1e-3), "every camera ray sees the grey floor");
    let normal = tracer::samples::secondary::decode_octahedral(
        file.column("normal").unwrap()[..2].try_into().expect("two components"),
    );
    assert!((normal - Vec3::Y).length() < 1e-3, "floor normal {normal}");
    let plain = {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plain.lfrs");
        let settings =
            RenderSettings { width: 16, height: 16, spp: 4, seed: 9, max_bounces: 1, threads: 0, progress: false };
        tracer::samples::lens_time::dump(
            &scene,
            &Accel::build(&scene).unwrap(),
            &settings,
            &tracer::samples::FieldSelection::All,
            &path,
        )
        .unwrap();
        SampleFile::open(&path).unwrap().column("radiance").unwrap()
    };
    assert_eq!(radiance, plain, "splitting does not change the paths");

    // With a point light too, what remains is the point light's light alone: its mean over the
    // samples equals the analytic (albedo/π)·I·cosθ/d² at each sample's floor point.
    let scene = lamp_over_floor(true);
    let (_dir, file) = dump_soft_shadow_lens_time(&scene, (24, 24), 16);
    let (x, y) = (file.column("x").unwrap(), file.column("y").unwrap());
    let without = file.column("radiance_without_light").unwrap();
    let light_position = Vec3::new(0.7, 1.5, 0.3);
    let (mut measured, mut expected) = (0.0f64, 0.0f64);
    for i in 0..file.len() {
        let (origin, direction) = scene.camera.generate_ray(Vec2::new(x[i], y[i]), Vec2::ZERO, 24, 24);
        let floor_point = origin + direction * (-origin.y / direction.y);
        let to_light = light_position - floor_point;
        let cos_theta = to_light.normalize().y;
        expected += (0.5 / std::f64::consts::PI) * 3.0 * cos_theta as f64 / to_light.length_squared() as f64;
        measured += without[3 * i] as f64;
    }
    let relative = (measured / expected - 1.0).abs();
    assert!(relative < 0.05, "point light alone: measured {measured}, expected {expected} ({relative})");
}
