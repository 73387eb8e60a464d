//! PLY meshes: ASCII and binary files of the same geometry load the same,
//! a truncated file is an error naming it, PLY works as a `[[mesh]] file` in a description,
//! and the shared Stanford bunny's PLY equals its verbatim OBJ conversion.

use crate::common;

use std::path::{Path, PathBuf};

use glam::Vec3;
use tracer::Scene;

/// A tetrahedron with a quad face split in the file as one polygon: 5 vertices (a square base
/// and an apex) with normals, faces as 4 triangles and 1 quad.
fn pyramid() -> (Vec<[f32; 6]>, Vec<Vec<u32>>) {
    let vertices = vec![
        [-1.0, 0.0, -1.0, 0.0, -1.0, 0.0],
        [1.0, 0.0, -1.0, 0.0, -1.0, 0.0],
        [1.0, 0.0, 1.0, 0.0, -1.0, 0.0],
        [-1.0, 0.0, 1.0, 0.0, -1.0, 0.0],
        [0.0, 1.5, 0.0, 0.0, 1.0, 0.0],
    ];
    let faces = vec![vec![0, 1, 2, 3], vec![0, 4, 1], vec![1, 4, 2], vec![2, 4, 3], vec![3, 4, 0]];
    (vertices, faces)
}

const PROPERTIES: &str = "property float x\nproperty float y\nproperty float z\nproperty float nx\n\
                          property float ny\nproperty float nz\n";

fn header(format: &str, vertices: usize, faces: usize) -> String {
    format!(
        "ply\nformat {format} 1.0\nelement vertex {vertices}\n{PROPERTIES}element face {faces}\n\
         property list uchar int vertex_indices\nend_header\n"
    )
}

fn ascii_ply() -> Vec<u8> {
    let (vertices, faces) = pyramid();
    let mut text = header("ascii", vertices.len(), faces.len());
    for v in &vertices {
        text += &v.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(" ");
        text += "\n";
    }
    for f in &faces {
        text += &format!("{} {}\n", f.len(), f.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(" "));
    }
    text.into_bytes()
}

fn binary_ply(big_endian: bool) -> Vec<u8> {
    let (vertices, faces) = pyramid();
    let format = if big_endian { "binary_big_endian" } else { "binary_little_endian" };
    let mut bytes = header(format, vertices.len(), faces.len()).into_bytes();
    let f32_bytes = |x: f32| if big_endian { x.to_be_bytes() } else { x.to_le_bytes() };
    let i32_bytes = |x: i32| if big_endian { x.to_be_bytes() } else { x.to_le_bytes() };
    for v in &vertices {
        for &c in v {
            bytes.extend_from_slice(&f32_bytes(c));
        }
    }
    for f in &faces {
        bytes.push(f.len() as u8);
        for &i in f {
            bytes.extend_from_slice(&i32_bytes(i as i32));
        }
    }
    bytes
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

#[test]
fn ascii_and_binary_files_of_one_geometry_load_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let (vertices, faces) = pyramid();
    let ascii = Scene::load(&write(dir.path(), "a.ply", &ascii_ply())).unwrap();
    for big_endian in [false, true] {
        let binary = Scene::load(&write(dir.path(), "b.ply", &binary_ply(big_endian))).unwrap();
        assert_eq!(binary.meshes.len(), 1);
        let (a, b) = (&ascii.meshes[0], &binary.meshes[0]);
        assert_eq!((&a.positions, &a.normals, &a.indices), (&b.positions, &b.normals, &b.indices));
    }
    // The geometry is the file's: positions and normals as written, the quad as two triangles
    // of the same corners, 6 triangles in all.
    let mesh = &ascii.meshes[0];
    let expected: Vec<Vec3> = vertices.iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect();
    assert_eq!(mesh.positions, expected);
    assert_eq!(mesh.normals.as_ref().unwrap()[4], Vec3::Y);
    let triangles: usize = faces.iter().map(|f| f.len() - 2).sum();
    assert_eq!(mesh.indices.len(), triangles);
    let area: f32 = (0..mesh.indices.len()).map(|t| mesh.triangle_area(t)).sum();
    let slant = (1.5f32 * 1.5 + 1.0).sqrt();
    assert!((area - (4.0 + 4.0 * slant)).abs() < 1e-5, "surface area {area}");
    // A bare PLY gets the framing camera: it sees the model.
    assert!(ascii.camera.forward.dot(Vec3::ZERO - ascii.camera.position) > 0.0);
}

#[test]
fn a_truncated_or_malformed_file_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in [
        ("cut-binary.ply", binary_ply(false)[..binary_ply(false).len() - 7].to_vec()),
        ("cut-ascii.ply", ascii_ply()[..ascii_ply().len() - 10].to_vec()),
        ("cut-header.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n".to_vec()),
        ("text.ply", b"this is not a ply file\n".to_vec()),
    ] {
        let path = write(dir.path(), name, &bytes);
        let err = Scene::load(&path).unwrap_err();
        assert_eq!(err.file, path, "{err}");
        assert!(err.message.contains("not a valid PLY file"), "{name}: {err}");
    }
}

#[test]
fn a_ply_mesh_takes_a_description_material_and_transform() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "pyramid.ply", &binary_ply(false));
    let toml = "[[material]]\nname = \"red\"\nbase_color = [0.8, 0.1, 0.1]\n[[mesh]]\nfile = \"pyramid.ply\"\n\
                material = \"red\"\ntransform = { translate = [0, 2, 0], scale = 2 }\n";
    let path = write(dir.path(), "scene.toml", toml.as_bytes());
    let scene = Scene::load(&path).unwrap();
    let mesh = &scene.meshes[0];
    assert_eq!(scene.materials[mesh.material as usize].name, "red");
    assert_eq!(mesh.positions[4], Vec3::new(0.0, 5.0, 0.0), "apex (0, 1.5, 0) scaled by 2 and raised by 2");
}

#[test]
fn the_shared_bunny_ply_equals_its_obj_conversion() {
    let shared = common::shared_scenes().join("stanford-bunny");
    let ply = Scene::load(&shared.join("bunny.ply")).unwrap();
    let obj = Scene::load(&shared.join("bunny.obj")).unwrap();
    let (p, o) = (&ply.meshes[0], &obj.meshes[0]);
    assert_eq!(p.indices.len(), o.indices.len());
    // The OBJ is a verbatim conversion: the same vertices (to the OBJ's printed precision) in
    // the same triangles. Compare each triangle's corners, not the index numbers.
    let mut worst = 0.0f32;
    for (tp, to) in p.indices.iter().zip(&o.indices) {
        for k in 0..3 {
            worst = worst.max((p.positions[tp[k] as usize] - o.positions[to[k] as usize]).abs().max_element());
        }
    }
    assert!(worst < 1e-5, "largest corner difference {worst}");
}
