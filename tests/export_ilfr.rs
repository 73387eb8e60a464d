//! `lfr export --format ilfr-2.2`: the ILFR authors' sample buffer, read back as their README
//! describes it and checked field by field against our own sample file.

use crate::common;

use std::process::Command;

use common::project_root;
use glam::Vec3;
use sampleio::SampleFile;
use tracer::samples::secondary::decode_octahedral;

fn lfr(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lfr")).args(args).current_dir(project_root()).output().expect("lfr runs")
}

#[test]
fn ilfr_export_matches_the_samples_in_camera_space() {
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("s.lfrs");
    let out = dir.path().join("s.ilfr");
    let dump = lfr(&[
        "dump",
        "--kind",
        "indirect",
        "--spp",
        "4",
        "--width",
        "16",
        "--height",
        "12",
        "--out",
        samples.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(dump.status.success(), "{}", String::from_utf8_lossy(&dump.stderr));
    let export = lfr(&["export", "--format", "ilfr-2.2", samples.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(export.status.success(), "{}", String::from_utf8_lossy(&export.stderr));

    let header = std::fs::read_to_string(dir.path().join("s.ilfr.header")).unwrap();
    let lines: Vec<&str> = header.lines().collect();
    assert_eq!(&lines[..4], ["Version 2.2", "Width 16", "Height 12", "Samples per pixel 4"]);
    assert!(lines[4].starts_with("CoC coefficients (coc radius = C0/w+C1): "));
    let matrix: Vec<f64> =
        lines[5].strip_prefix("Pixel-to-camera matrix: ").unwrap().split(',').map(|v| v.parse().unwrap()).collect();
    assert_eq!(matrix.len(), 16);
    assert_eq!(lines[6], "Encoding = binary");
    assert!(lines[7].starts_with("x,y,w,u,v,t,r,g,b,pri_mv(3d),pri_normal(3d)"));

    let file = SampleFile::open(&samples).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(bytes.len(), file.len() * 39 * 4);
    let entries: Vec<[f32; 39]> = bytes
        .chunks_exact(39 * 4)
        .map(|e| std::array::from_fn(|k| f32::from_le_bytes(e[4 * k..4 * k + 4].try_into().unwrap())))
        .collect();
    let column = |n: &str| file.column(n).unwrap();
    let (x, radiance, direction, origin, hit) =
        (column("x"), column("radiance"), column("direction"), column("origin"), column("hit"));
    let camera = file.header().camera.as_ref().unwrap();
    let position = Vec3::new(camera.position[0] as f32, camera.position[1] as f32, camera.position[2] as f32);
    let v3 = |e: &[f32; 39], slot: usize| Vec3::new(e[9 + 3 * slot], e[10 + 3 * slot], e[11 + 3 * slot]);
    let mut checked = 0;
    for (i, e) in entries.iter().enumerate() {
        assert_eq!(e[0], x[i]);
        assert_eq!(&e[6..9], &radiance[3 * i..3 * i + 3]);
        assert_eq!(e[2], 0.0, "an all-diffuse scene has bandwidth 0");
        let pri_normal = v3(e, 1);
        if pri_normal == Vec3::ZERO {
            continue;
        }
        checked += 1;
        assert!((pri_normal.length() - 1.0).abs() < 1e-3);
        // The camera transform is rigid: distances and the ray direction's angles survive it.
        let (o, h) = (v3(e, 3), v3(e, 4));
        let world_o = Vec3::new(origin[3 * i], origin[3 * i + 1], origin[3 * i + 2]);
        let world_h = Vec3::new(hit[3 * i], hit[3 * i + 1], hit[3 * i + 2]);
        assert!(((o.length() - (world_o - position).length()).abs()) < 1e-2);
        if v3(e, 6) != Vec3::ZERO {
            assert!(((h - o).length() - (world_h - world_o).length()).abs() < 1e-2);
            // Their camera space looks down +z: every visible origin has positive z.
            assert!(o.z > 0.0);
            let world_direction = decode_octahedral([direction[2 * i], direction[2 * i + 1]]);
            let angle_to_normal_world = world_direction
                .dot(decode_octahedral([column("origin_normal")[2 * i], column("origin_normal")[2 * i + 1]]));
            let angle_to_normal_camera = (h - o).normalize().dot(pri_normal);
            assert!((angle_to_normal_world - angle_to_normal_camera).abs() < 2e-3);
        }
    }
    assert!(checked > 500);
}

#[test]
fn ilfr_export_refuses_other_kinds() {
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("ao.lfrs");
    let dump = lfr(&[
        "dump",
        "--kind",
        "ao",
        "--spp",
        "1",
        "--width",
        "4",
        "--height",
        "4",
        "--out",
        samples.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(dump.status.success());
    let out = dir.path().join("x.ilfr");
    let export = lfr(&["export", "--format", "ilfr-2.2", samples.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(!export.status.success());
    assert!(String::from_utf8_lossy(&export.stderr).contains("indirect"));
    assert!(!out.exists());
}
