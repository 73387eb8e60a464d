//! Statistical render regression, as Mitsuba 3 does it: a small render of the default scene is
//! compared per pixel with a stored high-sample reference by a z-test that uses both images'
//! variances, never by exact equality.
//!
//! The reference `tracer/tests/data/cornell-32-reference.exr` was made with
//! `lfr render --width 32 --height 32 --spp 16384 --seed 987654 --out tracer/tests/data/cornell-32-reference.exr`
//! (the embedded Cornell box). Regenerate it when the scene or the light transport changes on
//! purpose, and say why in the commit.

use crate::common;

use common::{exr_channel, project_root, render, scene_from_toml};

/// Per-pixel z-test pass fraction and the z-score of the image means, per channel.
fn z_statistics(scale: f32) -> (f64, [f64; 3]) {
    let reference = project_root().join("tracer/tests/data/cornell-32-reference.exr");
    let scene = scene_from_toml(include_str!("../../scenes/cornell.toml"));
    let frame = render(&scene, 32, 32, 1024, 4242);
    let channels = ["R", "G", "B"];
    let reference_values: Vec<Vec<f32>> = channels.iter().map(|c| exr_channel(&reference, c)).collect();
    let reference_variance: Vec<Vec<f32>> =
        channels.iter().map(|c| exr_channel(&reference, &format!("variance.{c}"))).collect();
    let mut failing_pixels = 0;
    let mut difference_sum = [0.0f64; 3];
    let mut variance_sum = [0.0f64; 3];
    for i in 0..frame.pixel_count() {
        let mut pixel_fails = false;
        for c in 0..3 {
            let ours = (scale * frame.beauty[i][c]) as f64;
            let ours_variance = (scale * scale * frame.variance[i][c]) as f64;
            let theirs = reference_values[c][i] as f64;
            let variance = ours_variance + reference_variance[c][i] as f64;
            let z = (ours - theirs) / (variance + 1e-12).sqrt();
            if z.abs() >= 3.5 {
                pixel_fails = true;
            }
            difference_sum[c] += ours - theirs;
            variance_sum[c] += variance;
        }
        failing_pixels += pixel_fails as usize;
    }
    let pass_fraction = 1.0 - failing_pixels as f64 / frame.pixel_count() as f64;
    let mean_z = [0, 1, 2].map(|c| difference_sum[c] / variance_sum[c].sqrt());
    (pass_fraction, mean_z)
}

#[test]
fn cornell_box_matches_the_stored_reference_in_a_per_pixel_z_test() {
    let (pass_fraction, mean_z) = z_statistics(1.0);
    // Unbiased renders fail a 3.5-sigma test on ~0.05% of channels; heavy tails of variance
    // estimates from 1024 samples push that up a little. A real bias fails many more.
    assert!(pass_fraction >= 0.97, "only {:.1}% of pixels pass", 100.0 * pass_fraction);
    // The image means agree within 4 standard errors.
    assert!(mean_z.iter().all(|z| z.abs() < 4.0), "image-mean z {mean_z:?}: biased against the reference");
}

#[test]
fn the_z_test_detects_a_two_percent_bias() {
    // The test above must be able to fail: a 2% brighter render is rejected.
    let (_, mean_z) = z_statistics(1.02);
    assert!(mean_z.iter().all(|&z| z > 4.0), "a 2% bias must be visible: image-mean z {mean_z:?}");
}
