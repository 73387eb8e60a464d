//! ILFR's lens mode (paper §3.4) on the tracer's own `lens-time` files: the camera-space input
//! rays that `recon::ilfr::lens` derives from (x, y, u, v, z) and the depth gradient must put
//! every hit on the surface the tracer hit, with that surface's normal — the check that the
//! two crates agree on the lens, the image axes and the gradient's meaning.

use crate::common;

use common::emissive_polygon;
use glam::Vec3;
use recon::ilfr::lens::read_primary_rays;
use recon::ilfr::samples::SampleClass;
use sampleio::SampleFile;
use tracer::samples::lens_time;
use tracer::Accel;
use tracer::RenderSettings;

/// z = 4 + 0.5 x + 0.3 y, seen through an open lens focused at 3, translating by `motion`
/// (world space) over the shutter when it is not zero.
fn tilted_plane(motion: [f32; 3]) -> tracer::Scene {
    emissive_polygon(0.3, 3.0, 1.0, &[[-5.0, -4.0, 0.3], [5.0, -4.0, 5.3], [5.0, 4.0, 7.7], [-5.0, 4.0, 2.7]], motion)
}

/// A 24 × 16, 4 spp `lens-time` dump of `scene`.
fn dump_24x16(scene: &tracer::Scene) -> (tempfile::TempDir, SampleFile) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lens.lfrs");
    let settings =
        RenderSettings { width: 24, height: 16, spp: 4, seed: 3, max_bounces: 0, threads: 0, progress: false };
    lens_time::dump(scene, &Accel::build(scene).unwrap(), &settings, &tracer::samples::FieldSelection::All, &path)
        .unwrap();
    (dir, SampleFile::open(&path).unwrap())
}

/// The camera's position and the map of a camera-space vector (X along right, Y along −up, Z
/// along forward) to world space, from the file's header.
fn camera_frame(camera: &sampleio::Camera) -> (Vec3, impl Fn([f32; 3]) -> Vec3) {
    let axis = |a: [f64; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
    let (right, up, forward) = (axis(camera.right), axis(camera.up), axis(camera.forward));
    (axis(camera.position), move |c: [f32; 3]| right * c[0] - up * c[1] + forward * c[2])
}

#[test]
fn hits_and_normals_from_the_depth_gradient_match_the_tilted_plane() {
    let scene = tilted_plane([0.0; 3]);
    let (_dir, file) = dump_24x16(&scene);
    let header_camera = file.header().camera.clone().unwrap();
    let (samples, _, stats) = read_primary_rays(&file).unwrap();
    assert_eq!(stats.normals_from_the_ray, 0);
    let (position, to_world) = camera_frame(&header_camera);
    let plane_normal = Vec3::new(0.5, 0.3, -1.0).normalize(); // facing the camera at the origin
    let mut hits = 0;
    for i in 0..samples.len() {
        assert_eq!(samples.class[i], SampleClass::Hit, "the plane fills the view");
        let p = position + to_world(samples.secondary_hit[i]);
        assert!((p.z - (4.0 + 0.5 * p.x + 0.3 * p.y)).abs() < 2e-3, "sample {i}: {p} is not on the plane");
        let n = to_world(samples.secondary_normal[i]);
        assert!((n - plane_normal).length() < 1e-2, "sample {i}: normal {n}, plane {plane_normal}");
        let lens = position + to_world(samples.primary_hit[i]);
        assert!(lens.z.abs() < 1e-6 && lens.length() <= 0.3 + 1e-5, "the ray starts on the lens: {lens}");
        hits += 1;
    }
    assert_eq!(hits, 24 * 16 * 4);
}

/// The same plane moving by (0.4, 0.2, 0.3) over the shutter: every hit, moved to the middle of
/// the shutter by its `motion` (the time splats are indexed at), lies on the plane as it is
/// then, z − 0.15 = 4 + 0.5 (x − 0.2) + 0.3 (y − 0.1), whatever the sample's own time.
#[test]
fn moving_hits_brought_to_mid_shutter_lie_on_the_moved_plane() {
    let motion = [0.4f32, 0.2, 0.3];
    let scene = tilted_plane(motion);
    let (_dir, file) = dump_24x16(&scene);
    let header_camera = file.header().camera.clone().unwrap();
    let (samples, _, _) = read_primary_rays(&file).unwrap();
    let times = samples.time.as_ref().expect("a moving scene has times");
    assert!(times.iter().any(|&t| t < 0.25) && times.iter().any(|&t| t > 0.75));
    let (position, to_world) = camera_frame(&header_camera);
    for (i, time) in times.iter().enumerate() {
        let p = position + to_world(samples.secondary_hit_at_middle(i));
        let on_plane = 0.15 + 4.0 + 0.5 * (p.x - 0.2) + 0.3 * (p.y - 0.1);
        assert!((p.z - on_plane).abs() < 2e-3, "sample {i} (t = {time}): {p} is off the plane at mid-shutter");
    }
}
