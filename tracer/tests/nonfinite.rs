//! Contributions that overflow f32 are dropped, and counted: a point light
//! of intensity 3e38 half a unit above a plane gives I/d² above f32's range (+inf) wherever
//! d < 0.94, which covers the whole narrow view, so every shadow ray that reaches it carries an
//! infinite value. The frame and the sample dumps report
//! how many were dropped (the commands warn with the count) instead of a silently black image.

use crate::common;

use common::{mean, render, SceneToml};
use tracer::{Accel, RenderSettings};

/// A grey plane filling the view of a camera 5 units above it (10° field of view: 0.44 units
/// either side of the centre), lit by a point light of `intensity` half a unit above its centre.
fn plane_under_point_light(intensity: f32) -> tracer::Scene {
    SceneToml::new(4, None)
        .camera([0.0, 5.0, 0.0], [0.0; 3], 10.0, "up = [0, 0, 1]\n")
        .diffuse("grey", [0.5; 3])
        .polygon("grey", &[[-10.0, 0.0, -10.0], [-10.0, 0.0, 10.0], [10.0, 0.0, 10.0], [10.0, 0.0, -10.0]], "")
        .raw(&format!("[[light]]\ntype = \"point\"\nposition = [0, 0.5, 0]\nintensity = [{intensity:e}, {intensity:e}, {intensity:e}]"))
        .scene()
}

#[test]
fn overflowing_point_light_contributions_are_counted() {
    let (width, height, spp) = (8, 8, 4);
    let bright = render(&plane_under_point_light(3e38), width, height, spp, 1);
    // Every camera sample hits the plane, and its light sample reaches the light unblocked.
    let samples = u64::from(width * height * spp);
    assert!(bright.dropped_contributions >= samples, "{} < {samples}", bright.dropped_contributions);
    assert_eq!(mean(&bright.beauty).max_element(), 0.0, "nothing else lights the plane");
    assert!(bright
        .warnings()
        .iter()
        .any(|w| w.contains(&format!("{} path contributions", bright.dropped_contributions))));

    // The same scene with a finite light: nothing dropped, no warning, a lit plane.
    let dim = render(&plane_under_point_light(1.0), width, height, spp, 1);
    assert_eq!(dim.dropped_contributions, 0);
    assert!(dim.warnings().is_empty(), "{:?}", dim.warnings());
    assert!(mean(&dim.beauty).min_element() > 0.0);
}

#[test]
fn sample_dumps_count_dropped_contributions() {
    let dir = tempfile::tempdir().unwrap();
    for (intensity, dropped) in [(3e38, true), (1.0, false)] {
        let scene = plane_under_point_light(intensity);
        let accel = Accel::build(&scene).unwrap();
        let settings =
            RenderSettings { width: 4, height: 4, spp: 2, seed: 1, max_bounces: 4, threads: 1, progress: false };
        let path = dir.path().join("lens.lfrs");
        let report =
            tracer::samples::lens_time::dump(&scene, &accel, &settings, &tracer::samples::FieldSelection::All, &path)
                .unwrap();
        assert_eq!(report.dropped_contributions >= 32, dropped, "lens-time {intensity}: {report:?}");
        assert_eq!(report.dropped_contributions > 0, dropped, "lens-time {intensity}: {report:?}");
        let path = dir.path().join("indirect.lfrs");
        let kind = tracer::samples::secondary::SecondaryKind::Indirect;
        let report = tracer::samples::secondary::dump(
            &scene,
            &accel,
            &settings,
            kind,
            &tracer::samples::FieldSelection::All,
            &path,
        )
        .unwrap();
        assert_eq!(report.dropped_contributions > 0, dropped, "indirect {intensity}: {report:?}");
    }
}
