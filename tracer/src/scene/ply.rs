//! PLY (Stanford polygon file) meshes through the `ply-rs-bw` crate: ASCII and binary (both
//! byte orders), vertex positions (`x y z`), normals (`nx ny nz`), texture coordinates
//! (`u v`, `s t` or `texture_u texture_v`) and faces (`vertex_indices` or `vertex_index`
//! lists, polygons split into fans). Vertex colours are reported and ignored: lfr's materials
//! have no per-vertex colour. Every PLY file becomes one mesh with one material.

use std::path::Path;

use glam::{Mat4, Vec2, Vec3};
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

use super::{Mesh, Scene};
use crate::error::SceneError;

/// How a PLY file is placed in the scene.
#[derive(Clone, Debug)]
pub struct PlyOptions {
    /// Object-to-world transform applied to positions and normals.
    pub transform: Mat4,
    /// The scene material of every face (PLY files have none of their own).
    pub material: u32,
    /// World-space linear motion over the shutter.
    pub motion: Vec3,
}

impl Default for PlyOptions {
    fn default() -> Self {
        PlyOptions { transform: Mat4::IDENTITY, material: 0, motion: Vec3::ZERO }
    }
}

/// A scalar property as a float; `None` for a list.
fn scalar(property: &Property) -> Option<f64> {
    Some(match *property {
        Property::Char(v) => v as f64,
        Property::UChar(v) => v as f64,
        Property::Short(v) => v as f64,
        Property::UShort(v) => v as f64,
        Property::Int(v) => v as f64,
        Property::UInt(v) => v as f64,
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        _ => return None,
    })
}

/// A list property as integers (vertex indices); `None` for a scalar or a list of floats.
fn index_list(property: &Property) -> Option<Vec<i64>> {
    Some(match property {
        Property::ListChar(v) => v.iter().map(|&i| i as i64).collect(),
        Property::ListUChar(v) => v.iter().map(|&i| i as i64).collect(),
        Property::ListShort(v) => v.iter().map(|&i| i as i64).collect(),
        Property::ListUShort(v) => v.iter().map(|&i| i as i64).collect(),
        Property::ListInt(v) => v.iter().map(|&i| i as i64).collect(),
        Property::ListUInt(v) => v.iter().map(|&i| i as i64).collect(),
        _ => return None,
    })
}

/// Reads the PLY file `path` into one mesh of `scene` (see the module documentation). Errors
/// name the file and the element or line at fault; a truncated file is an error.
pub fn load(path: &Path, scene: &mut Scene, options: &PlyOptions) -> Result<(), SceneError> {
    let bytes = super::input::read_input(path, crate::limits::MAX_MODEL_BYTES, path, "file")?;
    let mesh = parse(path, &bytes, options, &mut scene.warnings)?;
    if !mesh.indices.is_empty() {
        scene.meshes.push(mesh);
    }
    Ok(())
}

/// The mesh of the PLY bytes `bytes`, named `path` in messages.
pub fn parse(path: &Path, bytes: &[u8], options: &PlyOptions, warnings: &mut Vec<String>) -> Result<Mesh, SceneError> {
    let error = |field: &str, message: String| SceneError::new(path, field, message);
    let ply = Parser::<DefaultElement>::new().read_ply(&mut &bytes[..]).map_err(|e| {
        let field = e.line().map_or_else(|| "data".to_string(), |line| format!("line {line}"));
        // The crate's text starts with its own "Line N: " and spans several lines.
        let text = e.to_string();
        let text = e.line().and_then(|line| text.strip_prefix(&format!("Line {line}: "))).unwrap_or(&text);
        let text = text.split('\n').map(str::trim).filter(|l| !l.is_empty()).collect::<Vec<_>>().join("; ");
        let message = match e.kind() {
            std::io::ErrorKind::UnexpectedEof => {
                format!("not a valid PLY file: the file ends before the data its header declares ({text})")
            }
            _ => format!("not a valid PLY file: {text}"),
        };
        SceneError::new(path, field, message)
    })?;
    let header_has = |element: &str, property: &str| {
        ply.header.elements.get(element).is_some_and(|e| e.properties.contains_key(property))
    };
    let Some(vertices) = ply.payload.get("vertex") else {
        return Err(error("vertex", "no `vertex` element".into()));
    };
    let read = |name: &str, i: usize, v: &DefaultElement| -> Result<f32, SceneError> {
        let p = v.get(name).ok_or_else(|| error(&format!("vertex[{i}].{name}"), "missing".into()))?;
        scalar(p)
            .map(|x| x as f32)
            .ok_or_else(|| error(&format!("vertex.{name}"), "must be a number, not a list".into()))
    };
    let triple = |names: [&str; 3]| names.iter().all(|n| header_has("vertex", n));
    if !triple(["x", "y", "z"]) {
        return Err(error("vertex", "needs the properties `x`, `y` and `z`".into()));
    }
    let mut positions = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        positions.push(Vec3::new(read("x", i, v)?, read("y", i, v)?, read("z", i, v)?));
    }
    let normals = if triple(["nx", "ny", "nz"]) {
        let mut normals = Vec::with_capacity(vertices.len());
        for (i, v) in vertices.iter().enumerate() {
            normals.push(Vec3::new(read("nx", i, v)?, read("ny", i, v)?, read("nz", i, v)?));
        }
        Some(normals)
    } else {
        None
    };
    let uv_names = [["u", "v"], ["s", "t"], ["texture_u", "texture_v"]]
        .into_iter()
        .find(|[u, v]| header_has("vertex", u) && header_has("vertex", v));
    let uvs = match uv_names {
        Some([u, v]) => {
            let mut uvs = Vec::with_capacity(vertices.len());
            for (i, vertex) in vertices.iter().enumerate() {
                // PLY's v runs up the image, as OBJ's: flipped to lfr's top-down rows.
                uvs.push(Vec2::new(read(u, i, vertex)?, 1.0 - read(v, i, vertex)?));
            }
            Some(uvs)
        }
        None => None,
    };
    if ["red", "green", "blue", "diffuse_red"].iter().any(|c| header_has("vertex", c)) {
        warnings.push(format!(
            "{}: vertex colours ignored (lfr materials have no per-vertex colour; the mesh uses one material)",
            path.display()
        ));
    }

    let faces = ply.payload.get("face").map(Vec::as_slice).unwrap_or(&[]);
    let list_name = ["vertex_indices", "vertex_index"].into_iter().find(|n| header_has("face", n));
    if !faces.is_empty() && list_name.is_none() {
        return Err(error("face", "needs a `vertex_indices` (or `vertex_index`) list".into()));
    }
    let mut indices = Vec::with_capacity(faces.len());
    for (f, face) in faces.iter().enumerate() {
        let name = list_name.unwrap_or("vertex_indices");
        let field = format!("face[{f}].{name}");
        let list = face
            .get(name)
            .and_then(index_list)
            .ok_or_else(|| error(&field, "must be a list of integer vertex indices".into()))?;
        if let Some(&bad) = list.iter().find(|&&i| i < 0 || i as usize >= positions.len()) {
            return Err(error(
                &field,
                format!("vertex index {bad} out of range (the file has {} vertices)", positions.len()),
            ));
        }
        for k in 2..list.len() {
            indices.push([list[0] as u32, list[k - 1] as u32, list[k] as u32]);
        }
    }
    if faces.is_empty() {
        warnings.push(format!("{}: no faces (a point cloud?); nothing to render", path.display()));
    }

    let transform = options.transform;
    let normal_matrix = transform.inverse().transpose();
    for p in &mut positions {
        *p = transform.transform_point3(*p);
    }
    let normals =
        normals.map(|ns| ns.into_iter().map(|n| normal_matrix.transform_vector3(n).normalize_or_zero()).collect());
    if transform.determinant() < 0.0 {
        for t in &mut indices {
            t.swap(1, 2);
        }
    }
    Ok(Mesh {
        name: path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned()),
        positions,
        normals,
        uvs,
        tangents: None,
        indices,
        material: options.material,
        motion: options.motion,
        sphere: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square (two triangles as one quad face) with normals and uvs, as ASCII text.
    const ASCII: &str = "ply\nformat ascii 1.0\ncomment a square\nelement vertex 4\nproperty float x\n\
        property float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
        property float u\nproperty float v\nelement face 1\nproperty list uchar int vertex_indices\n\
        end_header\n0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1 0\n1 1 0 0 0 1 1 1\n0 1 0 0 0 1 0 1\n4 0 1 2 3\n";

    #[test]
    fn a_quad_is_split_into_a_fan_with_normals_and_flipped_uvs() {
        let mut warnings = Vec::new();
        let mesh = parse(Path::new("square.ply"), ASCII.as_bytes(), &PlyOptions::default(), &mut warnings).unwrap();
        assert_eq!(mesh.indices, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(mesh.positions[2], Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(mesh.normals.as_ref().unwrap()[3], Vec3::Z);
        assert_eq!(mesh.uvs.as_ref().unwrap()[1], Vec2::new(1.0, 1.0));
        assert!(warnings.is_empty(), "{warnings:?}");
    }

    #[test]
    fn bad_indices_and_missing_coordinates_name_the_file_and_field() {
        let mut warnings = Vec::new();
        let bad_index = ASCII.replace("4 0 1 2 3", "3 0 1 7");
        let err = parse(Path::new("sq.ply"), bad_index.as_bytes(), &PlyOptions::default(), &mut warnings).unwrap_err();
        assert_eq!(
            err.to_string(),
            "sq.ply: face[0].vertex_indices: vertex index 7 out of range (the file has 4 vertices)"
        );
        let no_z = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n";
        let err = parse(Path::new("sq.ply"), no_z.as_bytes(), &PlyOptions::default(), &mut warnings).unwrap_err();
        assert_eq!(err.to_string(), "sq.ply: vertex: needs the properties `x`, `y` and `z`");
        let err = parse(Path::new("sq.ply"), b"OFF\n3 1 0\n", &PlyOptions::default(), &mut warnings).unwrap_err();
        assert!(err.to_string().starts_with("sq.ply: ") && err.message.contains("not a valid PLY file"), "{err}");
    }
}
