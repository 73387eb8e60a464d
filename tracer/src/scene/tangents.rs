//! MikkTSpace tangents for meshes whose material has a normal map and whose file gives none.
//!
//! glTF 2.0 asks for tangents computed "using default MikkTSpace algorithms with the specified
//! vertex positions, normals, and texture coordinates" when a file has none, and normal maps
//! are baked against them by the tools that write these files (Blender, Substance, xNormal).
//! MikkTSpace's result depends on its exact vertex welding, triangle grouping and
//! degenerate-case rules, so an approximation would tilt the normals of baked maps; this
//! module therefore calls the `mikktspace` crate (the gltf-rs port of Mikkelsen's reference
//! implementation) instead of a re-implementation.
//!
//! Conventions. The scene's texture coordinates follow glTF (v grows downwards in the image,
//! OBJ's are flipped at load), while MikkTSpace's sign says whether the bitangent follows
//! increasing v. The normal map's green axis points up in the image, towards *decreasing* v,
//! so the sign is negated, as three.js does for glTF (`computeMikkTSpaceTangents`'s
//! `negateSign`); a tangent's `w` then satisfies glTF's bitangent = w · (normal × tangent).
//!
//! MikkTSpace computes one tangent per triangle corner; where the corners of one vertex
//! disagree (a uv seam, a mirrored half) the vertex is split, its position, normal and uv
//! copied.

use std::collections::HashMap;

use glam::{Vec2, Vec3, Vec4};

use super::Mesh;

struct Corners<'a> {
    mesh: &'a Mesh,
    normals: &'a [Vec3],
    uvs: &'a [Vec2],
    /// Tangent per triangle corner, glTF convention.
    tangents: Vec<Vec4>,
}

impl mikktspace::Geometry for Corners<'_> {
    fn num_faces(&self) -> usize {
        self.mesh.indices.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.mesh.positions[self.mesh.indices[face][vert] as usize].to_array()
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        self.normals[self.mesh.indices[face][vert] as usize].to_array()
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        self.uvs[self.mesh.indices[face][vert] as usize].to_array()
    }

    fn set_tangent_encoded(&mut self, tangent: [f32; 4], face: usize, vert: usize) {
        let [x, y, z, sign] = tangent;
        // Negated sign: see the module documentation.
        self.tangents[face * 3 + vert] = Vec4::new(x, y, z, if sign < 0.0 { 1.0 } else { -1.0 });
    }
}

/// Gives `mesh` (which has normals and uvs) MikkTSpace tangents, splitting vertices whose
/// corners get different ones. Returns false, leaving the mesh alone, when it lacks normals or
/// uvs or MikkTSpace gives up.
pub fn generate(mesh: &mut Mesh) -> bool {
    let (Some(normals), Some(uvs)) = (&mesh.normals, &mesh.uvs) else {
        return false;
    };
    let mut corners = Corners { mesh, normals, uvs, tangents: vec![Vec4::ZERO; mesh.indices.len() * 3] };
    if !mikktspace::generate_tangents(&mut corners) {
        return false;
    }
    let corner_tangents = corners.tangents;
    let (mut normals, mut uvs) = (normals.clone(), uvs.clone());
    let mut tangents: Vec<Option<Vec4>> = vec![None; mesh.positions.len()];
    // (original vertex, tangent bits) → vertex index, for the copies made at splits.
    let mut copies: HashMap<(u32, [u32; 4]), u32> = HashMap::new();
    for (f, triangle) in mesh.indices.iter_mut().enumerate() {
        for (k, vertex) in triangle.iter_mut().enumerate() {
            let tangent = corner_tangents[f * 3 + k];
            let v = *vertex as usize;
            match tangents[v] {
                None => tangents[v] = Some(tangent),
                Some(existing) if existing.to_array().map(f32::to_bits) == tangent.to_array().map(f32::to_bits) => {}
                Some(_) => {
                    let key = (*vertex, tangent.to_array().map(f32::to_bits));
                    *vertex = *copies.entry(key).or_insert_with(|| {
                        mesh.positions.push(mesh.positions[v]);
                        normals.push(normals[v]);
                        uvs.push(uvs[v]);
                        tangents.push(Some(tangent));
                        (mesh.positions.len() - 1) as u32
                    });
                }
            }
        }
    }
    mesh.normals = Some(normals);
    mesh.uvs = Some(uvs);
    mesh.tangents = Some(tangents.into_iter().map(|t| t.unwrap_or(Vec4::ZERO)).collect());
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit quad in the z = 0 plane facing +z with glTF uvs: u = x, v = 1 − y (v down).
    fn quad(uvs: [Vec2; 4]) -> Mesh {
        Mesh {
            name: "quad".into(),
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
            normals: Some(vec![Vec3::Z; 4]),
            uvs: Some(uvs.to_vec()),
            indices: vec![[0, 1, 2], [0, 2, 3]],
            ..Mesh::default()
        }
    }

    #[test]
    fn a_quad_gets_the_tangent_along_u_and_the_bitangent_towards_decreasing_v() {
        // u = x, v = 1 − y: the map's "up" (decreasing v) is +y = normal × tangent, so w = +1.
        let mut mesh = quad([Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 0.0)]);
        assert!(generate(&mut mesh));
        assert_eq!(mesh.positions.len(), 4, "no seam, no split");
        for t in mesh.tangents.as_ref().unwrap() {
            assert!((t.truncate() - Vec3::X).length() < 1e-5 && t.w == 1.0, "{t}");
        }
        // Mirrored in u (u = 1 − x): the tangent turns to −x and the handedness flips so that
        // the bitangent still points to decreasing v (+y): w · (z × −x) = w · (−y) → w = −1.
        let mut mirrored = quad([Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0), Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0)]);
        assert!(generate(&mut mirrored));
        for t in mirrored.tangents.as_ref().unwrap() {
            assert!((t.truncate() + Vec3::X).length() < 1e-5 && t.w == -1.0, "{t}");
        }
    }

    #[test]
    fn vertices_whose_corners_disagree_are_split() {
        // Two triangles sharing an edge, the second with its u mirrored: the shared vertices
        // need two tangents each, so they are copied; every corner keeps its position and uv.
        let mut mesh = quad([Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 0.0)]);
        mesh.positions.push(Vec3::new(-1.0, 1.0, 0.0));
        mesh.normals.as_mut().unwrap().push(Vec3::Z);
        mesh.uvs.as_mut().unwrap().push(Vec2::new(1.0, 0.0));
        mesh.indices.push([0, 3, 4]);
        let before: Vec<(Vec3, Vec2)> = mesh
            .indices
            .iter()
            .flatten()
            .map(|&v| (mesh.positions[v as usize], mesh.uvs.as_ref().unwrap()[v as usize]))
            .collect();
        assert!(generate(&mut mesh));
        assert!(mesh.positions.len() > 5, "split: {}", mesh.positions.len());
        let after: Vec<(Vec3, Vec2)> = mesh
            .indices
            .iter()
            .flatten()
            .map(|&v| (mesh.positions[v as usize], mesh.uvs.as_ref().unwrap()[v as usize]))
            .collect();
        assert_eq!(before, after);
        let tangents = mesh.tangents.as_ref().unwrap();
        assert_eq!(tangents.len(), mesh.positions.len());
        assert!((tangents[mesh.indices[2][1] as usize].truncate() + Vec3::X).length() < 1e-4);
        assert!((tangents[mesh.indices[0][0] as usize].truncate() - Vec3::X).length() < 1e-4);
    }
}
