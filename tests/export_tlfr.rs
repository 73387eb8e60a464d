//! `lfr export --format tlfr-1.3`: the authors' sample-buffer format, read back here the way
//! their `UVTSampleBuffer` reads it (text header, 16 float32 per sample), and reprojected with
//! their conventions (lens centre at xy − C(w)·uv, homogeneous motion per Eq. 3).

use crate::common;

use std::process::Command;

use common::{emissive_polygon_toml, project_root, SQUARE_AT_DEPTH_4};

fn lfr(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lfr")).args(args).current_dir(project_root()).output().expect("lfr runs")
}

#[test]
fn tlfr_export_reads_back_and_reprojects_onto_the_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let scene_path = dir.path().join("square.toml");
    std::fs::write(&scene_path, emissive_polygon_toml(0.2, 2.0, 2.0, &SQUARE_AT_DEPTH_4, [0.4, 0.1, 1.0])).unwrap();
    let samples = dir.path().join("s.lfrs");
    let out = dir.path().join("s.tlfr");
    let (width, height, spp) = (24usize, 20usize, 8usize);
    let dump = lfr(&[
        "dump",
        "--scene",
        scene_path.to_str().unwrap(),
        "--kind",
        "lens-time",
        "--spp",
        "8",
        "--width",
        "24",
        "--height",
        "20",
        "--out",
        samples.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(dump.status.success(), "{}", String::from_utf8_lossy(&dump.stderr));
    let export = lfr(&["export", "--format", "tlfr-1.3", samples.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(export.status.success(), "{}", String::from_utf8_lossy(&export.stderr));

    // The header, line by line as their reader scans it.
    let header = std::fs::read_to_string(dir.path().join("s.tlfr.header")).unwrap();
    let lines: Vec<&str> = header.lines().collect();
    assert_eq!(lines[0], "Version 1.3");
    assert_eq!(lines[1], "Width 24");
    assert_eq!(lines[2], "Height 20");
    assert_eq!(lines[3], "Samples per pixel 8");
    assert_eq!(lines[4], "Motion model: affine");
    let coc = lines[5].strip_prefix("CoC coefficients (coc radius = C0/w+C1): ").unwrap();
    let (c0, c1) = coc.split_once(',').unwrap();
    let (c0, c1): (f64, f64) = (c0.parse().unwrap(), c1.parse().unwrap());
    assert_eq!(lines[6], "Encoding = binary");
    assert_eq!(lines[7], "x,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy");

    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(bytes.len(), width * height * spp * 16 * 4);
    let entries: Vec<[f32; 16]> = bytes
        .chunks_exact(64)
        .map(|e| std::array::from_fn(|k| f32::from_le_bytes(e[4 * k..4 * k + 4].try_into().unwrap())))
        .collect();

    // The square's image at shutter open through the lens centre, from the pinhole camera model.
    let scene = tracer::Scene::load(&scene_path).unwrap();
    let a = scene.camera.project(glam::Vec3::new(0.25, 0.25, 4.0), glam::Vec2::ZERO, 24, 20).unwrap();
    let b = scene.camera.project(glam::Vec3::new(-0.25, -0.25, 4.0), glam::Vec2::ZERO, 24, 20).unwrap();
    let (lo, hi) = (a.min(b), a.max(b));
    let mut hits = 0;
    for (i, e) in entries.iter().enumerate() {
        let [x, y, _zw, w, u, v, t, r, _g, _b, alpha, mvx, mvy, mvw, _, _] = e.map(|v| v as f64);
        let pixel = i / spp;
        assert!(x >= (pixel % width) as f64 && x < (pixel % width + 1) as f64, "(y, x, sample) order");
        assert!(y >= (pixel / width) as f64 && y < (pixel / width + 1) as f64);
        assert!((-1.0..=1.0).contains(&u) && (-1.0..=1.0).contains(&v) && (0.0..=1.0).contains(&t));
        assert_eq!(alpha, 1.0);
        if w >= 1e29 {
            assert_eq!(r, 0.0);
            continue;
        }
        hits += 1;
        // Lens centre, then back along the homogeneous motion to t = 0 (Eq. 2-3).
        let coc = c0 / w + c1;
        let (xc, yc) = (x - coc * u, y - coc * v);
        let w0 = w - t * mvw;
        let (x0, y0) = ((xc * w - t * mvx) / w0, (yc * w - t * mvy) / w0);
        assert!((w0 - 4.0).abs() < 1e-3, "w at t = 0: {w0}");
        assert!(
            x0 > lo.x as f64 - 0.02 && x0 < hi.x as f64 + 0.02 && y0 > lo.y as f64 - 0.02 && y0 < hi.y as f64 + 0.02,
            "sample {i} lands at ({x0}, {y0}) outside {lo}..{hi}"
        );
    }
    assert!(hits > 50);
}

#[test]
fn export_of_a_missing_or_damaged_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.tlfr");
    let missing = lfr(&["export", "--format", "tlfr-1.3", "nothere.lfrs", out.to_str().unwrap()]);
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("nothere.lfrs"));
    let junk = dir.path().join("junk.lfrs");
    std::fs::write(&junk, b"LFRSAMP\0 definitely not a sample file").unwrap();
    let damaged = lfr(&["export", "--format", "tlfr-1.3", junk.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(!damaged.status.success());
    assert!(String::from_utf8_lossy(&damaged.stderr).contains("junk.lfrs"));
    assert!(!String::from_utf8_lossy(&damaged.stderr).contains("panicked"));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "no output written");

    // A file of another kind: named by the format's word for it, not a Rust variant name.
    let indirect = dir.path().join("indirect.lfrs");
    let dump = lfr(&["dump", "--kind", "indirect", "--spp", "1", "--width", "4", "--height", "4", "--quiet", "--out"]
        .iter()
        .copied()
        .chain([indirect.to_str().unwrap()])
        .collect::<Vec<_>>());
    assert!(dump.status.success(), "{}", String::from_utf8_lossy(&dump.stderr));
    let wrong = lfr(&["export", "--format", "tlfr-1.3", indirect.to_str().unwrap(), out.to_str().unwrap()]);
    let message = String::from_utf8_lossy(&wrong.stderr);
    assert!(!wrong.status.success() && message.contains("this file holds indirect samples"), "{message}");
    assert!(!message.contains("Indirect") && !out.exists(), "{message}");
}
