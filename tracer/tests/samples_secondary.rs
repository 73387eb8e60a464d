//! `indirect` and `ao` sample dumps: the samples reproduce the rendered image (Eq. 1 of the
//! indirect light field paper with one secondary ray per primary hit), their geometry is
//! consistent, ambient-occlusion distances follow the cosine distribution in closed form, and
//! fields appear only when the scene needs them.

use crate::common;

use common::{exr_channel, project_root, render, scene_from_toml, shared_scenes, SceneToml};
use glam::Vec3;
use sampleio::SampleFile;
use tracer::samples::secondary::{decode_octahedral, dump, SecondaryKind};
use tracer::RenderSettings;
use tracer::{Accel, Scene};

fn dump_file(
    scene: &Scene,
    kind: SecondaryKind,
    size: (u32, u32),
    spp: u32,
    seed: u32,
) -> (tempfile::TempDir, SampleFile) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("samples.lfrs");
    let accel = Accel::build(scene).unwrap();
    let settings = RenderSettings {
        width: size.0,
        height: size.1,
        spp,
        seed,
        max_bounces: scene.max_bounces,
        threads: 0,
        progress: false,
    };
    dump(scene, &accel, &settings, kind, &tracer::samples::FieldSelection::All, &path).unwrap();
    let file = SampleFile::open(&path).unwrap();
    (dir, file)
}

fn names(file: &SampleFile) -> Vec<String> {
    file.fields().iter().map(|f| f.name.clone()).collect()
}

fn vec3(column: &[f32], i: usize) -> Vec3 {
    Vec3::new(column[3 * i], column[3 * i + 1], column[3 * i + 2])
}

fn octahedral(column: &[f32], i: usize) -> Vec3 {
    decode_octahedral([column[2 * i], column[2 * i + 1]])
}

/// For a Lambertian primary hit, BSDF sampling is cosine sampling and the path weight is the
/// albedo, so direct + albedo · L is the path-traced estimate of each sample: its mean must
/// match the stored 16,384-spp reference of the same scene.
#[test]
fn indirect_samples_reproduce_the_reference_image() {
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let (_dir, file) = dump_file(&scene, SecondaryKind::Indirect, (32, 32), 64, 77);
    assert_eq!(
        names(&file),
        [
            "x",
            "y",
            "direction",
            "radiance",
            "origin",
            "hit",
            "origin_normal",
            "hit_normal",
            "albedo",
            "direct",
            "secondary_albedo",
            "secondary_direct"
        ],
        "a static, diffuse pinhole scene needs no lens, time, motion or bandwidth fields"
    );
    assert!(file.header().record_size <= 120);
    let (radiance, albedo, direct) =
        (file.column("radiance").unwrap(), file.column("albedo").unwrap(), file.column("direct").unwrap());
    let n = file.len();
    let mut sum = [0.0f64; 3];
    let mut sum_sq = [0.0f64; 3];
    for i in 0..n {
        let estimate = vec3(&direct, i) + vec3(&albedo, i) * vec3(&radiance, i);
        assert!(estimate.is_finite());
        for c in 0..3 {
            sum[c] += estimate[c] as f64;
            sum_sq[c] += (estimate[c] as f64).powi(2);
        }
    }
    let reference = project_root().join("tracer/tests/data/cornell-32-reference.exr");
    for (c, channel) in ["R", "G", "B"].iter().enumerate() {
        let mean = sum[c] / n as f64;
        let standard_error = ((sum_sq[c] / n as f64 - mean * mean) / n as f64).sqrt();
        let values = exr_channel(&reference, channel);
        let reference_mean = values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64;
        let z = (mean - reference_mean) / standard_error;
        assert!(z.abs() < 4.0, "channel {channel}: samples {mean} vs reference {reference_mean} (z = {z})");
    }
}

/// On glossy primary hits the BSDF sample's weight is not the albedo: `direct + weight ·
/// radiance` must still estimate the rendered image (monkeys: metal heads on a glossy floor).
#[test]
fn glossy_samples_carry_the_bsdf_weight_and_reproduce_the_image() {
    let _ = shared_scenes();
    let scene = Scene::load(&project_root().join("scenes/monkeys.toml")).unwrap();
    let (_dir, file) = dump_file(&scene, SecondaryKind::Indirect, (24, 16), 64, 3);
    let (radiance, albedo, weight, direct) = (
        file.column("radiance").unwrap(),
        file.column("albedo").unwrap(),
        file.column("weight").expect("glossy scenes store the BSDF weight"),
        file.column("direct").unwrap(),
    );
    let (mut sum, mut sum_sq, mut weight_differs) = ([0.0f64; 3], [0.0f64; 3], 0usize);
    let n = file.len();
    for i in 0..n {
        let estimate = vec3(&direct, i) + vec3(&weight, i) * vec3(&radiance, i);
        assert!(estimate.is_finite());
        weight_differs += ((vec3(&weight, i) - vec3(&albedo, i)).abs().max_element() > 0.05) as usize;
        for c in 0..3 {
            sum[c] += estimate[c] as f64;
            sum_sq[c] += (estimate[c] as f64).powi(2);
        }
    }
    assert!(weight_differs > n / 10, "glossy hits: the weight is not the albedo ({weight_differs} of {n})");
    assert_origin_bsdf_reproduces_the_weight(&scene, &file);
    let frame = render(&scene, 24, 16, 256, 77);
    let reference = common::mean(&frame.beauty);
    for c in 0..3 {
        let mean = sum[c] / n as f64;
        let standard_error = ((sum_sq[c] / n as f64 - mean * mean) / n as f64).sqrt();
        let variance_of_reference: f64 =
            frame.variance.iter().map(|v| v[c] as f64).sum::<f64>() / (frame.variance.len() as f64).powi(2);
        let z = (mean - reference[c] as f64) / (standard_error.powi(2) + variance_of_reference).sqrt();
        assert!(z.abs() < 4.0, "channel {c}: samples {mean} vs render {} (z = {z})", reference[c]);
    }
}

/// The BSDFs stored in the five fields `{prefix}_base_color`, … of every sample.
fn stored_bsdfs(file: &SampleFile, prefix: &str) -> Vec<tracer::bsdf::Bsdf> {
    let column =
        |name: &str| file.column(&format!("{prefix}_{name}")).unwrap_or_else(|e| panic!("{prefix}_{name}: {e}"));
    let (base, metallic, roughness, specular, f0) =
        (column("base_color"), column("metallic"), column("roughness"), column("specular"), column("f0"));
    (0..file.len())
        .map(|i| tracer::bsdf::Bsdf {
            base_color: vec3(&base, i),
            metallic: metallic[i],
            alpha: (roughness[i] * roughness[i]).max(tracer::bsdf::MIN_ALPHA),
            specular: specular[i],
            f0: f0[i],
        })
        .collect()
}

/// The stored BSDF of o (gap G1 of docs/ilfr-design.md) is the one that drew ω: evaluated
/// again from the file alone, f·cos/pdf of ω for ωo towards the (pinhole) camera gives the
/// stored `weight` up to the f16 rounding of the parameters, and every ω lies above the stored
/// geometric normal (G2), which lies on the shading normal's side.
fn assert_origin_bsdf_reproduces_the_weight(scene: &Scene, file: &SampleFile) {
    use tracer::bsdf::Frame;
    let column = |name: &str| file.column(name).unwrap_or_else(|e| panic!("{name}: {e}"));
    let origin_bsdfs = stored_bsdfs(file, "origin");
    let (geometric, shading, direction, origin, weight) = (
        column("origin_geometric_normal"),
        column("origin_normal"),
        column("direction"),
        column("origin"),
        column("weight"),
    );
    let mut checked = 0;
    for (i, bsdf) in origin_bsdfs.iter().enumerate() {
        let wi = octahedral(&direction, i);
        if wi == Vec3::ZERO {
            continue;
        }
        let (n_geometric, n_shading) = (octahedral(&geometric, i), octahedral(&shading, i));
        assert!(wi.dot(n_geometric) > 0.0, "sample {i}: ω below the geometric normal");
        assert!(n_geometric.dot(n_shading) > 0.0, "sample {i}: normals on opposite sides");
        let frame = Frame::new(n_shading);
        let wo = frame.to_local((scene.camera.position - vec3(&origin, i)).normalize());
        let wi = frame.to_local(wi);
        let expected = bsdf.eval(wo, wi) / bsdf.pdf(wo, wi);
        let stored = vec3(&weight, i);
        let error = (expected - stored).abs().max_element() / stored.max_element().max(0.05);
        assert!(error < 0.03, "sample {i}: weight {stored} stored, {expected} from the stored BSDF");
        checked += 1;
    }
    assert!(checked > file.len() / 2, "{checked} of {}", file.len());
    // h's BSDF (gap G3) is the one whose albedo the file stores as `secondary_albedo`.
    let (hit_bsdfs, hit_normal, secondary_albedo) =
        (stored_bsdfs(file, "hit"), column("hit_normal"), column("secondary_albedo"));
    let mut hits = 0;
    for (i, bsdf) in hit_bsdfs.iter().enumerate() {
        if octahedral(&hit_normal, i) == Vec3::ZERO {
            assert_eq!(bsdf.base_color, Vec3::ZERO, "sample {i}: no hit, no BSDF");
            continue;
        }
        let error = (bsdf.albedo() - vec3(&secondary_albedo, i)).abs().max_element();
        assert!(
            error < 5e-3,
            "sample {i}: albedo {} from h's BSDF, {} stored",
            bsdf.albedo(),
            vec3(&secondary_albedo, i)
        );
        hits += 1;
    }
    assert!(hits > file.len() / 20, "{hits} of {}", file.len()); // most rays escape to the black sky
}

#[test]
fn secondary_geometry_is_consistent() {
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let (_dir, file) = dump_file(&scene, SecondaryKind::Indirect, (16, 16), 8, 5);
    let (direction, origin, hit) =
        (file.column("direction").unwrap(), file.column("origin").unwrap(), file.column("hit").unwrap());
    let (origin_normal, hit_normal, secondary_direct, radiance) = (
        file.column("origin_normal").unwrap(),
        file.column("hit_normal").unwrap(),
        file.column("secondary_direct").unwrap(),
        file.column("radiance").unwrap(),
    );
    let mut hits = 0;
    for i in 0..file.len() {
        let (o, h, w) = (vec3(&origin, i), vec3(&hit, i), octahedral(&direction, i));
        let (n_o, n_h) = (octahedral(&origin_normal, i), octahedral(&hit_normal, i));
        if n_o == Vec3::ZERO {
            continue; // the outermost columns look past the box's front edge
        }
        assert!((n_o.length() - 1.0).abs() < 1e-4);
        assert!(w.dot(n_o) > -1e-3, "the secondary ray leaves above the surface");
        if n_h == Vec3::ZERO {
            continue; // escaped through the open front
        }
        hits += 1;
        // h lies on the ray up to the origin offset (about 1e-3 mm here) and direction quantisation.
        let distance = (h - o).length();
        let off_ray = ((h - o) - w * distance).length();
        assert!(off_ray < 1e-2 + 1e-3 * distance, "h is {off_ray} mm off the ray at distance {distance}");
        assert!(n_h.dot(-w) > -1e-3, "the hit normal faces the ray's origin");
        // The part of L reflected straight from the light cannot exceed L.
        let (l, sd) = (vec3(&radiance, i), vec3(&secondary_direct, i));
        // secondary_direct is stored as f16 (relative rounding 2^-11).
        assert!(sd.cmple(l * (1.0 + 1e-3) + Vec3::splat(1e-4)).all(), "secondary direct {sd} > radiance {l}");
    }
    assert!(hits > file.len() / 2);
}

/// Between two parallel planes H apart, a cosine-weighted ray from the floor always hits the
/// ceiling, at distance H / cos θ, and P(distance < r) = P(cos θ > H / r) = 1 − (H / r)².
#[test]
fn ambient_occlusion_distances_follow_the_cosine_distribution() {
    let scene = scene_from_toml(
        r#"
        [render]
        [camera]
        position = [0, 0.5, 0]
        look_at = [0, 0, 0]
        up = [0, 0, 1]
        fov = 30
        [[mesh]]
        shape = "polygon"
        points = [[-200, 0, -200], [-200, 0, 200], [200, 0, 200], [200, 0, -200]]
        [[mesh]]
        shape = "polygon"
        points = [[-200, 1, -200], [200, 1, -200], [200, 1, 200], [-200, 1, 200]]
        "#,
    );
    let (_dir, file) = dump_file(&scene, SecondaryKind::AmbientOcclusion, (16, 16), 64, 9);
    assert_eq!(names(&file), ["x", "y", "direction", "distance", "origin", "hit", "origin_normal", "hit_normal"]);
    let (distance, direction) = (file.column("distance").unwrap(), file.column("direction").unwrap());
    let mut within_two = 0usize;
    for (i, &d) in distance.iter().enumerate() {
        let cos_theta = octahedral(&direction, i).y;
        // Planes 200 wide: rays flatter than cos = 1/200 may escape past the edge.
        if !d.is_finite() {
            assert!(cos_theta < 0.01);
            continue;
        }
        assert!((d * cos_theta - 1.0).abs() < 2e-3, "distance {d} at cos {cos_theta}");
        within_two += (d < 2.0) as usize;
    }
    let fraction = within_two as f64 / file.len() as f64;
    // 1 - (1/2)^2 = 0.75; 16384 stratified samples.
    assert!((fraction - 0.75).abs() < 0.01, "{fraction}");
}

/// A floor whose shading normal is tilted θ = 60° from its geometric normal (vertex normals, no
/// occluder): cosine directions about the shading normal fall below the geometric surface with
/// probability (1 − cos θ) / 2 = 1/4 (Malley: the directions project uniformly onto the unit
/// disc, and those below are the part of the disc outside the ellipse x²/cos²θ + y² < 1 on one
/// side). They enter the surface, so they are occluded (distance 0, no direction), and the AO
/// image reads 3/4; every other ray escapes. Before, they counted as escapes (AO 1), which no
/// reconstruction from the file (it knows only the shading normal) could reproduce.
#[test]
fn ambient_occlusion_directions_below_the_geometric_surface_are_occluded() {
    let mut scene = scene_from_toml(
        r#"
        [render]
        [camera]
        position = [0, 1, 0]
        look_at = [0, 0, 0]
        up = [0, 0, 1]
        fov = 20
        [[mesh]]
        shape = "polygon"
        points = [[-5, 0, -5], [-5, 0, 5], [5, 0, 5], [5, 0, -5]]
        "#,
    );
    let theta = 60f32.to_radians();
    let tilted = Vec3::new(theta.sin(), theta.cos(), 0.0);
    let vertices = scene.meshes[0].positions.len();
    scene.meshes[0].normals = Some(vec![tilted; vertices]);
    let (_dir, file) = dump_file(&scene, SecondaryKind::AmbientOcclusion, (16, 16), 64, 5);
    let (distance, direction) = (file.column("distance").unwrap(), file.column("direction").unwrap());
    let mut below = 0usize;
    for (i, &d) in distance.iter().enumerate() {
        let omega = octahedral(&direction, i);
        if d == 0.0 {
            assert_eq!(omega, Vec3::ZERO, "sample {i}: an occluded-below sample carries no direction");
            below += 1;
        } else {
            assert_eq!(d, f32::INFINITY, "sample {i}: nothing else to hit");
            assert!(omega.y > 0.0 && (omega.dot(tilted) > 0.0), "sample {i}: {omega}");
        }
    }
    let fraction = below as f64 / file.len() as f64;
    let expected = (1.0 - theta.cos() as f64) / 2.0;
    // 16384 samples: standard error 0.0034.
    assert!((fraction - expected).abs() < 0.015, "{fraction} below, expected {expected}");

    let accel = Accel::build(&scene).unwrap();
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp: 64,
        seed: 5,
        max_bounces: scene.max_bounces,
        threads: 0,
        progress: false,
    };
    let frame = tracer::samples::secondary::ambient_occlusion_frame(&scene, &accel, &settings, 1.0).unwrap();
    let mean = frame.visibility.iter().map(|&v| v as f64).sum::<f64>() / frame.visibility.len() as f64;
    assert!(
        (mean - (1.0 - fraction)).abs() < 1e-6,
        "the AO image is the dump's samples: {mean} against {}",
        1.0 - fraction
    );
    // A list of pixels (scattered, repeated, 1 and 2 threads) reads the same visibility as the
    // whole image, bit for bit; a pixel outside it is refused.
    let pixels: Vec<(u32, u32)> =
        (0..40u32).map(|i| ((i * 5) % 16, (i * 3 + i / 7) % 16)).chain([(15, 15), (0, 0)]).collect();
    for threads in [1, 2] {
        let settings = RenderSettings { threads, ..settings.clone() };
        let visibility =
            tracer::samples::secondary::ambient_occlusion_pixels(&scene, &accel, &settings, 1.0, &pixels).unwrap();
        for (&(x, y), v) in pixels.iter().zip(&visibility) {
            assert_eq!(v.to_bits(), frame.visibility[(y * 16 + x) as usize].to_bits(), "({x}, {y}), {threads} threads");
        }
    }
    let outside = tracer::samples::secondary::ambient_occlusion_pixels(&scene, &accel, &settings, 1.0, &[(0, 16)]);
    assert!(outside.unwrap_err().to_string().contains("(0, 16) is outside the 16x16 image"));
}

#[test]
fn lens_motion_and_gloss_add_their_fields_within_120_bytes() {
    let _ = shared_scenes();
    let scene = Scene::load(&project_root().join("scenes/monkeys-defocus-motion.toml")).unwrap();
    let (_dir, file) = dump_file(&scene, SecondaryKind::Indirect, (24, 16), 2, 1);
    let fields = names(&file);
    for name in ["u", "v", "t", "origin_motion", "hit_motion", "bandwidth"] {
        assert!(fields.iter().any(|f| f == name), "missing {name} in {fields:?}");
    }
    // The paper's 30 floats (120 B) plus the BSDFs of o and h (32 B), which the paper's gather
    // and recursive step take from the scene.
    assert!(file.header().record_size <= 152, "ILFR target: {} bytes", file.header().record_size);
    let bandwidth = file.column("bandwidth").unwrap();
    assert!(bandwidth.iter().all(|k| k.is_finite() && *k >= 0.0));
    assert!(bandwidth.iter().any(|&k| k > 0.0), "the metal heads and floor are glossy");
    let (_dir, ao) = dump_file(&scene, SecondaryKind::AmbientOcclusion, (24, 16), 2, 1);
    assert!(!names(&ao).iter().any(|f| f == "bandwidth" || f == "radiance"));
}

/// In the furnace (white Lambertian sphere in a uniform environment E), the light leaving every
/// guide hit is E: direct (environment seen straight) plus indirect (via the sphere) add up to E.
#[test]
fn guide_buffers_in_the_furnace_add_up_to_the_environment() {
    let scene = SceneToml::new(1000, Some([0.5, 1.0, 2.0]))
        .camera([0.0, 0.0, 4.0], [0.0; 3], 20.0, "")
        .diffuse("white", [1.0; 3])
        .sphere("white", [0.0; 3], 1.0, "subdivisions = 5\n")
        .scene();
    let accel = Accel::build(&scene).unwrap();
    let settings =
        RenderSettings { width: 12, height: 12, spp: 256, seed: 2, max_bounces: 1000, threads: 0, progress: false };
    let guide = tracer::samples::guide::guide_buffers(&scene, &accel, &settings).unwrap();
    let environment = Vec3::new(0.5, 1.0, 2.0);
    let mut hits = 0;
    for i in 0..(12 * 12) {
        if guide.depth[i] == 0.0 {
            assert_eq!(guide.direct[i], environment, "a miss sees the environment");
            continue;
        }
        hits += 1;
        // The guide ray goes through the pixel centre: its hit is on the unit sphere.
        assert!((guide.position[i].length() - 1.0).abs() < 2e-3);
        assert!(guide.normal[i].dot(guide.position[i].normalize()) > 0.999);
        assert!((guide.depth[i] - (4.0 - guide.position[i].z)).abs() < 1e-3);
        let total = guide.direct[i] + guide.indirect[i];
        let sigma = guide.indirect_variance[i].max(Vec3::splat(1e-6)).powf(0.5);
        let error = (total - environment).abs();
        assert!(error.cmplt(5.0 * sigma + 0.02 * environment).all(), "pixel {i}: {total} vs {environment}");
    }
    assert!(hits > 40);
}
