//! Shapes authored in scene descriptions: polygons, boxes and tessellated spheres, plus the
//! normal computation shared with the OBJ loader.

use glam::{Vec2, Vec3};

use super::{Mesh, SphereShape};

/// A planar convex polygon, fan-triangulated; counter-clockwise vertices face the viewer.
pub fn polygon(name: &str, corners: &[Vec3], material: u32) -> Mesh {
    let indices = (1..corners.len().saturating_sub(1)).map(|i| [0, i as u32, i as u32 + 1]).collect();
    Mesh {
        name: name.to_string(),
        positions: corners.to_vec(),
        normals: None,
        uvs: None,
        indices,
        material,
        ..Mesh::default()
    }
}

/// An axis-aligned box with outward-facing triangles.
pub fn axis_aligned_box(name: &str, min: Vec3, max: Vec3, material: u32) -> Mesh {
    let corner = |i: u32| {
        Vec3::new(
            if i & 1 != 0 { max.x } else { min.x },
            if i & 2 != 0 { max.y } else { min.y },
            if i & 4 != 0 { max.z } else { min.z },
        )
    };
    // Faces as corner indices, counter-clockwise seen from outside.
    let faces: [[u32; 4]; 6] = [
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
    ];
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    for face in faces {
        let base = positions.len() as u32;
        positions.extend(face.iter().map(|&c| corner(c)));
        indices.push([base, base + 1, base + 2]);
        indices.push([base, base + 2, base + 3]);
    }
    Mesh { name: name.to_string(), positions, normals: None, uvs: None, indices, material, ..Mesh::default() }
}

/// An icosphere: an icosahedron subdivided `subdivisions` times, with smooth normals and
/// outward-facing triangles.
pub fn sphere(name: &str, center: Vec3, radius: f32, subdivisions: u32, material: u32) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut unit: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|&p| Vec3::from(p).normalize())
    .collect();
    let mut faces: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions.min(8) {
        let mut midpoint = std::collections::HashMap::new();
        let mut split = |a: u32, b: u32, unit: &mut Vec<Vec3>| -> u32 {
            *midpoint.entry((a.min(b), a.max(b))).or_insert_with(|| {
                unit.push((unit[a as usize] + unit[b as usize]).normalize());
                unit.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = split(a, b, &mut unit);
            let bc = split(b, c, &mut unit);
            let ca = split(c, a, &mut unit);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    // The face list above winds counter-clockwise seen from outside.
    let indices = faces;
    let sphere = Some(SphereShape { center, radius, triangles: indices.len() });
    Mesh {
        name: name.to_string(),
        positions: unit.iter().map(|&n| center + n * radius).collect(),
        normals: Some(unit),
        uvs: None,
        tangents: None,
        indices,
        material,
        motion: Vec3::ZERO,
        sphere,
    }
}

/// Gives a mesh without normals per-corner normals: the area-weighted average of the normals
/// of the faces around each vertex whose normal is within `crease_degrees` of the corner's
/// own face. Hard edges (box corners) stay hard, curved scans (the bunny) become smooth.
/// Vertices are split per corner, so uvs are duplicated alongside.
///
/// The cost is linear in the corners for ordinary meshes and O(k log k) at a vertex shared by
/// k faces (not O(k²)): a vertex of more than [`TREE_MIN_FACES`] faces sums them through a
/// [`NormalTree`].
pub fn compute_normals(mesh: &mut Mesh, crease_degrees: f32) {
    compute_normals_counting(mesh, crease_degrees);
}

/// A vertex shared by more faces than this sums them through a [`NormalTree`]; below it, the
/// plain loop over its faces (whose sums keep the bits of the definition).
pub const TREE_MIN_FACES: usize = 64;

/// [`compute_normals`], returning the number of face tests and tree nodes it visited while
/// summing (the work that was quadratic in a vertex's valence).
pub fn compute_normals_counting(mesh: &mut Mesh, crease_degrees: f32) -> u64 {
    if mesh.normals.is_some() {
        return 0;
    }
    let cos_crease = crease_degrees.to_radians().cos();
    let corners = |&[a, b, c]: &[u32; 3]| [a, b, c].map(|i| mesh.positions[i as usize]);
    // One power-of-two scale for the whole mesh keeps the area weights and keeps the crosses
    // finite at any scene scale (shading::scaled_cross).
    let longest_edge = mesh.indices.iter().fold(0.0f32, |m, t| {
        let [a, b, c] = corners(t);
        m.max((b - a).abs().max_element()).max((c - a).abs().max_element())
    });
    let face_normals: Vec<Vec3> = mesh
        .indices
        .iter()
        .map(|t| {
            let [a, b, c] = corners(t);
            shading::scaled_cross(a, b, c, longest_edge) // length ∝ area: area weighting for free
        })
        .collect();
    let mut faces_of_vertex: Vec<Vec<u32>> = vec![Vec::new(); mesh.positions.len()];
    for (f, tri) in mesh.indices.iter().enumerate() {
        for &v in tri {
            faces_of_vertex[v as usize].push(f as u32);
        }
    }
    let unit_normals: Vec<Vec3> = face_normals.iter().map(|n| n.normalize_or_zero()).collect();
    // The sum at a corner depends only on its vertex and its own face's unit normal, so corners
    // that share both (every corner of a triangulated planar polygon's fan vertex) share one
    // sum: computed once, in face order as for each corner alone, so the bits are the same.
    let mut sums: std::collections::HashMap<(u32, [u32; 3]), Vec3> = std::collections::HashMap::new();
    // The trees of the vertices of many faces, built on their first corner.
    let mut trees: std::collections::HashMap<u32, NormalTree> = std::collections::HashMap::new();
    let mut work = 0u64;
    let mut positions = Vec::with_capacity(mesh.indices.len() * 3);
    let mut normals = Vec::with_capacity(mesh.indices.len() * 3);
    let mut uvs: Option<Vec<Vec2>> = mesh.uvs.as_ref().map(|_| Vec::with_capacity(mesh.indices.len() * 3));
    let mut indices = Vec::with_capacity(mesh.indices.len());
    for (f, tri) in mesh.indices.iter().enumerate() {
        let own = unit_normals[f];
        let base = positions.len() as u32;
        for &v in tri {
            let key = (v, own.to_array().map(f32::to_bits));
            let faces = &faces_of_vertex[v as usize];
            let sum = *sums.entry(key).or_insert_with(|| {
                if faces.len() > TREE_MIN_FACES {
                    let tree = trees.entry(v).or_insert_with(|| NormalTree::new(faces, &unit_normals, &face_normals));
                    return tree.sum_within(own, cos_crease, &unit_normals, &face_normals, &mut work);
                }
                let mut sum = Vec3::ZERO;
                for &g in faces {
                    if unit_normals[g as usize].dot(own) >= cos_crease {
                        sum += face_normals[g as usize];
                    }
                }
                work += faces.len() as u64;
                sum
            });
            let n = sum.normalize_or_zero();
            normals.push(if n == Vec3::ZERO { own } else { n });
            positions.push(mesh.positions[v as usize]);
            if let (Some(out), Some(src)) = (&mut uvs, &mesh.uvs) {
                out.push(src[v as usize]);
            }
        }
        indices.push([base, base + 1, base + 2]);
    }
    mesh.positions = positions;
    mesh.normals = Some(normals);
    mesh.uvs = uvs;
    mesh.indices = indices;
    work
}

/// The faces around one vertex as a k-d tree over their unit normals, each node with the box of
/// its normals and the (area-weighted) sum of its faces' normals. The sum over the faces whose
/// unit normal `u` has `u · own >= cos_crease` (the crease rule) then takes whole nodes whose
/// box lies clearly inside or outside that cap and tests single faces only in the nodes the
/// cap's boundary crosses: O(log k + boundary) per corner instead of O(k).
///
/// A node is taken or skipped whole only when every point of its box is at least
/// [`NormalTree::MARGIN`] inside or outside the cap, far beyond the f32 rounding of a single
/// test (< 1e-6 for unit vectors), so the faces summed are exactly those the plain loop sums;
/// only the order of the additions differs (in f64 here).
struct NormalTree {
    nodes: Vec<NormalNode>,
    /// The faces, ordered so that every node holds a contiguous range.
    faces: Vec<u32>,
}

struct NormalNode {
    lo: Vec3,
    hi: Vec3,
    sum: [f64; 3],
    range: std::ops::Range<usize>,
    /// The two children, or none for a leaf.
    children: Option<(usize, usize)>,
}

impl NormalTree {
    /// Most faces of a leaf.
    const LEAF: usize = 8;
    /// How far inside or outside the cap (in cosine) a box must lie to be taken or skipped whole.
    const MARGIN: f64 = 1e-5;

    fn new(faces: &[u32], unit_normals: &[Vec3], face_normals: &[Vec3]) -> NormalTree {
        let mut tree = NormalTree { nodes: Vec::new(), faces: faces.to_vec() };
        tree.build(0..faces.len(), unit_normals, face_normals);
        tree
    }

    /// Builds the node of `range` (and its subtree); returns its index.
    fn build(&mut self, range: std::ops::Range<usize>, unit_normals: &[Vec3], face_normals: &[Vec3]) -> usize {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut sum = [0.0f64; 3];
        for &g in &self.faces[range.clone()] {
            let u = unit_normals[g as usize];
            (lo, hi) = (lo.min(u), hi.max(u));
            let n = face_normals[g as usize];
            for c in 0..3 {
                sum[c] += n[c] as f64;
            }
        }
        let index = self.nodes.len();
        self.nodes.push(NormalNode { lo, hi, sum, range: range.clone(), children: None });
        if range.len() > Self::LEAF {
            let extent = hi - lo;
            let axis = if extent.x >= extent.y && extent.x >= extent.z {
                0
            } else if extent.y >= extent.z {
                1
            } else {
                2
            };
            let middle = range.len() / 2;
            self.faces[range.clone()].select_nth_unstable_by(middle, |&a, &b| {
                unit_normals[a as usize][axis].total_cmp(&unit_normals[b as usize][axis])
            });
            let split = range.start + middle;
            let left = self.build(range.start..split, unit_normals, face_normals);
            let right = self.build(split..range.end, unit_normals, face_normals);
            self.nodes[index].children = Some((left, right));
        }
        index
    }

    /// The sum of the normals of the faces within the crease of `own` (see the type's doc);
    /// adds the nodes and faces visited to `work`.
    fn sum_within(
        &self,
        own: Vec3,
        cos_crease: f32,
        unit_normals: &[Vec3],
        face_normals: &[Vec3],
        work: &mut u64,
    ) -> Vec3 {
        let mut sum = [0.0f64; 3];
        let mut add = |n: [f64; 3]| (0..3).for_each(|c| sum[c] += n[c]);
        let cos = cos_crease as f64;
        let mut stack = vec![0usize];
        while let Some(index) = stack.pop() {
            *work += 1;
            let node = &self.nodes[index];
            // The least and greatest of own · u over the node's box.
            let (mut least, mut greatest) = (0.0f64, 0.0f64);
            for c in 0..3 {
                let (a, b) = (own[c] as f64 * node.lo[c] as f64, own[c] as f64 * node.hi[c] as f64);
                least += a.min(b);
                greatest += a.max(b);
            }
            if least >= cos + Self::MARGIN {
                add(node.sum);
            } else if greatest < cos - Self::MARGIN {
                continue;
            } else if let Some((left, right)) = node.children {
                stack.extend([left, right]);
            } else {
                for &g in &self.faces[node.range.clone()] {
                    *work += 1;
                    if unit_normals[g as usize].dot(own) >= cos_crease {
                        add(face_normals[g as usize].to_array().map(f64::from));
                    }
                }
            }
        }
        Vec3::new(sum[0] as f32, sum[1] as f32, sum[2] as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn total_area(mesh: &Mesh) -> f32 {
        (0..mesh.indices.len()).map(|i| mesh.triangle_area(i)).sum()
    }

    fn winding_normal(mesh: &Mesh, i: usize) -> Vec3 {
        let [a, b, c] = mesh.indices[i];
        let (a, b, c) = (mesh.positions[a as usize], mesh.positions[b as usize], mesh.positions[c as usize]);
        (b - a).cross(c - a)
    }

    #[test]
    fn box_has_the_right_area_and_faces_outwards() {
        let min = Vec3::new(-1.0, 0.0, 2.0);
        let max = Vec3::new(1.0, 3.0, 5.0);
        let b = axis_aligned_box("b", min, max, 0);
        assert!((total_area(&b) - 2.0 * (2.0 * 3.0 + 2.0 * 3.0 + 3.0 * 3.0)).abs() < 1e-4);
        let centre = 0.5 * (min + max);
        for i in 0..b.indices.len() {
            let p = b.positions[b.indices[i][0] as usize];
            assert!(winding_normal(&b, i).dot(p - centre) > 0.0, "face {i} points inwards");
        }
    }

    #[test]
    fn icosphere_converges_to_the_sphere_area_and_faces_outwards() {
        let s = sphere("s", Vec3::new(1.0, 2.0, 3.0), 2.0, 4, 0);
        let exact = 4.0 * std::f32::consts::PI * 4.0;
        let area = total_area(&s);
        assert!(area < exact && area > 0.99 * exact, "{area} vs {exact}");
        for i in 0..s.indices.len() {
            let p = s.positions[s.indices[i][0] as usize];
            assert!(winding_normal(&s, i).dot(p - Vec3::new(1.0, 2.0, 3.0)) > 0.0);
        }
    }

    #[test]
    fn computed_normals_keep_box_edges_hard_and_smooth_a_sphere() {
        let mut b = axis_aligned_box("b", Vec3::ZERO, Vec3::ONE, 0);
        compute_normals(&mut b, 60.0);
        let normals = b.normals.as_ref().unwrap();
        for (i, tri) in b.indices.iter().enumerate() {
            let face = winding_normal(&b, i).normalize();
            for &v in tri {
                assert!((normals[v as usize] - face).length() < 1e-5);
            }
        }
        let mut s = sphere("s", Vec3::ZERO, 1.0, 3, 0);
        s.normals = None;
        compute_normals(&mut s, 60.0);
        let normals = s.normals.as_ref().unwrap();
        for (p, n) in s.positions.iter().zip(normals) {
            assert!(n.dot(p.normalize()) > 0.999);
        }
    }

    #[test]
    fn polygon_fan_covers_a_square() {
        let q = polygon("q", &[Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y], 0);
        assert_eq!(q.indices.len(), 2);
        assert!((total_area(&q) - 1.0).abs() < 1e-6);
        assert!(winding_normal(&q, 0).z > 0.0);
    }

    /// The normal of face `f`'s corner at vertex `v` as `compute_normals` was written before
    /// corners shared their sums: the corner sums every face at its vertex. The oracle of the
    /// fast version.
    fn corner_normal_by_definition(mesh: &Mesh, f: usize, v: u32, cos_crease: f32) -> Vec3 {
        let own = winding_normal(mesh, f).normalize_or_zero();
        let mut sum = Vec3::ZERO;
        for (g, other) in mesh.indices.iter().enumerate() {
            let n = winding_normal(mesh, g);
            if other.contains(&v) && n.normalize_or_zero().dot(own) >= cos_crease {
                sum += n;
            }
        }
        let n = sum.normalize_or_zero();
        if n == Vec3::ZERO {
            own
        } else {
            n
        }
    }

    fn compute_normals_by_definition(mesh: &Mesh, crease_degrees: f32) -> Vec<Vec3> {
        let cos_crease = crease_degrees.to_radians().cos();
        let corners = mesh.indices.iter().enumerate().flat_map(|(f, tri)| tri.iter().map(move |&v| (f, v)));
        corners.map(|(f, v)| corner_normal_by_definition(mesh, f, v, cos_crease)).collect()
    }

    #[test]
    fn shared_corner_sums_give_the_bits_of_the_definition() {
        let mut lcg = 0x1234_5678u32;
        let mut next = move || {
            lcg = lcg.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (lcg >> 8) as f32 / (1u32 << 24) as f32
        };
        let mut meshes = vec![
            axis_aligned_box("b", Vec3::ZERO, Vec3::ONE, 0),
            sphere("s", Vec3::ZERO, 1.0, 2, 0),
            polygon(
                "fan",
                &(0..40)
                    .map(|i| Vec3::new((i as f32 * 0.157).cos(), (i as f32 * 0.157).sin(), 0.0))
                    .collect::<Vec<_>>(),
                0,
            ),
        ];
        // A bumpy grid: many vertices whose faces are neither coplanar nor all within the crease.
        let n = 12u32;
        let positions: Vec<Vec3> =
            (0..n * n).map(|i| Vec3::new((i % n) as f32, (i / n) as f32, 2.0 * next() - 1.0)).collect();
        let mut indices = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let i = y * n + x;
                indices.extend([[i, i + 1, i + n + 1], [i, i + n + 1, i + n]]);
            }
        }
        meshes.push(Mesh {
            name: "grid".into(),
            positions,
            normals: None,
            uvs: None,
            indices,
            material: 0,
            ..Mesh::default()
        });
        for mut mesh in meshes {
            mesh.normals = None;
            for crease in [0.0, 30.0, 60.0, 180.0] {
                let expected = compute_normals_by_definition(&mesh, crease);
                let mut fast = mesh.clone();
                compute_normals(&mut fast, crease);
                let got = fast.normals.unwrap();
                let bits = |v: &[Vec3]| v.iter().map(|n| n.to_array().map(f32::to_bits)).collect::<Vec<_>>();
                assert_eq!(bits(&got), bits(&expected), "{} at {crease} degrees", mesh.name);
            }
        }
    }

    /// A fan of `k` triangles around one hub vertex (index 0) whose rim waves up and down
    /// (`waves` times around, or at random heights with `random`): every face's normal differs,
    /// so no two corners at the hub share a sum.
    fn wavy_fan(k: u32, waves: f32, random: bool) -> Mesh {
        let mut lcg = 0x9e37_79b9u32;
        let mut next = move || {
            lcg = lcg.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (lcg >> 8) as f32 / (1u32 << 24) as f32
        };
        let mut positions = vec![Vec3::ZERO];
        for i in 0..k {
            let a = i as f32 * std::f32::consts::TAU / k as f32;
            let z = if random { next() - 0.5 } else { 0.3 * (waves * a).sin() };
            positions.push(Vec3::new(a.cos(), a.sin(), z));
        }
        let indices = (0..k).map(|i| [0, 1 + i, 1 + (i + 1) % k]).collect();
        Mesh { name: "fan".into(), positions, indices, ..Mesh::default() }
    }

    #[test]
    fn a_vertex_of_many_faces_gets_the_normals_of_the_definition() {
        for (k, waves, random) in [(300, 7.0, false), (1000, 3.0, false), (500, 0.0, true)] {
            let mesh = wavy_fan(k, waves, random);
            for crease in [0.0, 30.0, 60.0, 120.0, 180.0] {
                let expected = compute_normals_by_definition(&mesh, crease);
                let mut fast = mesh.clone();
                compute_normals(&mut fast, crease);
                let got = fast.normals.unwrap();
                let mut hub_corners = 0;
                for (corner, (g, e)) in got.iter().zip(&expected).enumerate() {
                    if mesh.indices[corner / 3][corner % 3] == 0 {
                        // Summed through the tree: the same faces, added in another order.
                        hub_corners += 1;
                        assert!((*g - *e).length() < 1e-5, "k {k} crease {crease}: {g} against {e}");
                    } else {
                        // The rim's vertices have two faces each: the plain loop, bit for bit.
                        assert_eq!(g.to_array().map(f32::to_bits), e.to_array().map(f32::to_bits));
                    }
                }
                assert_eq!(hub_corners, k);
            }
        }
    }

    #[test]
    fn the_work_at_a_shared_vertex_grows_close_to_linearly_with_its_faces() {
        // The plain loop tests every face at every corner of the hub: k² tests. The tree's
        // work for 16 times the faces grows by far less than 16² (about 16 log 16).
        for (waves, random) in [(7.0, false), (0.0, true)] {
            let work = |k: u32| {
                let mut mesh = wavy_fan(k, waves, random);
                compute_normals_counting(&mut mesh, 60.0)
            };
            let (small, large) = (work(1_000), work(16_000));
            let ratio = large as f64 / small as f64;
            assert!(ratio < 40.0, "work {small} at 1000 faces, {large} at 16000: ×{ratio:.1} (quadratic: ×256)");
            assert!(large < 16_000 * 16_000 / 20, "{large} steps for 16000 faces");
        }
    }

    #[test]
    fn a_polygon_of_a_hundred_thousand_vertices_gets_its_normals() {
        // Its fan vertex is shared by every triangle: summed once, not once per corner (the
        // quadratic version needed about 1e10 steps here).
        let ring: Vec<Vec3> = (0..100_000)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 100_000.0;
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let mut mesh = polygon("big", &ring, 0);
        let original = mesh.clone();
        compute_normals(&mut mesh, 60.0);
        let normals = mesh.normals.as_ref().unwrap();
        // Every 997th corner against the definition (all of them would take the quadratic time).
        let cos_crease = 60.0f32.to_radians().cos();
        for corner in (0..normals.len()).step_by(997) {
            let (f, v) = (corner / 3, original.indices[corner / 3][corner % 3]);
            let expected = corner_normal_by_definition(&original, f, v, cos_crease);
            assert_eq!(normals[corner].to_array().map(f32::to_bits), expected.to_array().map(f32::to_bits));
        }
    }
}
