//! Normal maps and single-sided materials.
//!
//! Normal maps (glTF `normalTexture` with its scale and `TANGENT`s or MikkTSpace tangents, OBJ
//! `norm`/`map_Bump`) change the shading as the tilted normal says, analytically.
//!
//! The model is a 2 × 2 quad in the plane z = 0 facing +z, made here as a glTF (or OBJ) file
//! with a generated PNG normal map of one constant texel, white and purely Lambertian, under a
//! sun of irradiance E from direction s and nothing else (black environment), seen head-on.
//! Every pixel then shows L = ρ/π · E · max(0, n · s) exactly (direct light only: light leaving
//! the plane never comes back), where n is the normal the map encodes, decoded here from the
//! texel by the glTF rules (2·texel/255 − 1, x and y times the scale, in the frame tangent =
//! direction of increasing u, bitangent = image up = decreasing v, normal), so the expected
//! value comes from the file, not from the tracer's code. The same model without the map is
//! the reference it must differ from.

use crate::common;

use std::path::{Path, PathBuf};

use common::{mean, render};
use glam::Vec3;
use tracer::camera::{Camera, FovAxis};
use tracer::Scene;

const ALBEDO: f32 = 0.5;
const SUN_IRRADIANCE: f32 = 2.0;

fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(ALPHABET[((n >> (18 - 6 * i)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A 4 × 4 PNG of one RGB colour.
fn png(rgb: [u8; 3]) -> Vec<u8> {
    let image = image::RgbImage::from_pixel(4, 4, image::Rgb(rgb));
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write_to(&mut bytes, image::ImageFormat::Png).expect("PNG encodes");
    bytes.into_inner()
}

/// The texel that encodes the unit tangent-space normal `n`, rounded to 8 bits.
fn encode(n: Vec3) -> [u8; 3] {
    ((n + Vec3::ONE) * 0.5 * 255.0).round().to_array().map(|c| c as u8)
}

/// The tangent-space normal a texel encodes with `scale` (glTF 2.0, "normalTexture").
fn decode(texel: [u8; 3], scale: f32) -> Vec3 {
    let v = Vec3::from(texel.map(|c| c as f32 / 255.0)) * 2.0 - Vec3::ONE;
    (v * Vec3::new(scale, scale, 1.0)).normalize()
}

/// What the normal map of a test model is.
struct Map {
    texel: [u8; 3],
    scale: Option<f32>,
}

/// The quad as a glTF file in `dir`: corners (±1, ±1, 0), normals +z, glTF uvs u = (x + 1)/2,
/// v = (1 − y)/2, optional `TANGENT`s, optional normal map, node scale `node_scale`.
fn quad_gltf(dir: &Path, name: &str, map: Option<&Map>, tangent: Option<[f32; 4]>, node_scale: [f32; 3]) -> PathBuf {
    quad_gltf_sided(dir, name, map, tangent, node_scale, false)
}

/// [`quad_gltf`] with its material's `doubleSided`.
fn quad_gltf_sided(
    dir: &Path,
    name: &str,
    map: Option<&Map>,
    tangent: Option<[f32; 4]>,
    node_scale: [f32; 3],
    double_sided: bool,
) -> PathBuf {
    let positions: [[f32; 3]; 4] = [[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]];
    let mut buffer = Vec::new();
    for p in positions {
        buffer.extend(p.iter().flat_map(|c| c.to_le_bytes()));
    }
    for _ in positions {
        buffer.extend([0.0f32, 0.0, 1.0].iter().flat_map(|c| c.to_le_bytes()));
    }
    for p in positions {
        buffer.extend([(p[0] + 1.0) / 2.0, (1.0 - p[1]) / 2.0].iter().flat_map(|c| c.to_le_bytes()));
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        buffer.extend(i.to_le_bytes());
    }
    let tangent_offset = buffer.len();
    if let Some(t) = tangent {
        for _ in positions {
            buffer.extend(t.iter().flat_map(|c| c.to_le_bytes()));
        }
    }
    let (tangent_attribute, tangent_view, tangent_accessor) = match tangent {
        Some(_) => (
            r#", "TANGENT": 4"#.to_string(),
            format!(r#", {{"buffer": 0, "byteOffset": {tangent_offset}, "byteLength": 64}}"#),
            r#", {"bufferView": 4, "componentType": 5126, "count": 4, "type": "VEC4"}"#.to_string(),
        ),
        None => (String::new(), String::new(), String::new()),
    };
    let (normal_texture, images) = match map {
        Some(map) => {
            let scale = map.scale.map(|s| format!(r#", "scale": {s}"#)).unwrap_or_default();
            (
                format!(r#", "normalTexture": {{"index": 0{scale}}}"#),
                format!(
                    r#", "images": [{{"uri": "data:image/png;base64,{}"}}], "textures": [{{"source": 0}}]"#,
                    base64(&png(map.texel))
                ),
            )
        }
        None => (String::new(), String::new()),
    };
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0, "scenes": [{{"nodes": [0]}}],
  "nodes": [{{"mesh": 0, "scale": {node_scale:?}}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2{tangent_attribute}}},
      "indices": 3, "material": 0}}]}}],
  "materials": [{{"pbrMetallicRoughness": {{"baseColorFactor": [{ALBEDO}, {ALBEDO}, {ALBEDO}, 1], "metallicFactor": 0,
      "roughnessFactor": 1}}, "doubleSided": {double_sided}{normal_texture}}}],
  "buffers": [{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}],
  "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 48}}, {{"buffer": 0, "byteOffset": 48, "byteLength": 48}},
      {{"buffer": 0, "byteOffset": 96, "byteLength": 32}}, {{"buffer": 0, "byteOffset": 128, "byteLength": 12}}{tangent_view}],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"}},
    {{"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"}},
    {{"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}}{tangent_accessor}]{images}
}}"#,
        buffer.len(),
        base64(&buffer)
    );
    let path = dir.join(name);
    std::fs::write(&path, json).unwrap();
    path
}

/// Loads `path`, makes its materials purely Lambertian (glTF's dielectric specular layer has no
/// simple closed form), lights it by the sun from `towards_sun` and looks at it head-on.
fn lit(path: &Path, towards_sun: Vec3) -> Scene {
    let mut scene = Scene::load(path).expect("test model loads");
    for m in &mut scene.materials {
        m.specular = 0.0;
    }
    scene.add_sun(towards_sun, Vec3::splat(SUN_IRRADIANCE));
    scene.camera = Camera::look_at(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 30.0, FovAxis::Y);
    scene
}

/// Mean beauty and mean first-hit normal of an 8 × 8 render (every pixel sees the quad).
fn shade(scene: &Scene) -> (f32, Vec3) {
    let frame = render(scene, 8, 8, 4, 7);
    assert_eq!(frame.invalid_samples, 0);
    assert!(frame.depth.iter().all(|&d| d > 0.0), "every pixel sees the quad");
    (mean(&frame.beauty).x, mean(&frame.normal))
}

fn expected_radiance(normal: Vec3, towards_sun: Vec3) -> f32 {
    ALBEDO / std::f32::consts::PI * SUN_IRRADIANCE * normal.dot(towards_sun.normalize()).max(0.0)
}

fn assert_shading(scene: &Scene, normal: Vec3, towards_sun: Vec3, what: &str) -> f32 {
    let (radiance, shading_normal) = shade(scene);
    let expected = expected_radiance(normal, towards_sun);
    assert!((radiance - expected).abs() <= 2e-3 * expected, "{what}: radiance {radiance}, expected {expected}");
    assert!((shading_normal - normal).length() < 2e-3, "{what}: normal layer {shading_normal}, expected {normal}");
    radiance
}

/// 30° from +z towards +x: the sun the red-tilted map faces.
fn sun() -> Vec3 {
    Vec3::new(0.5, 0.0, 0.75f32.sqrt())
}

#[test]
fn a_gltf_normal_map_tilts_the_shading_normal_along_u_and_image_up() {
    let dir = tempfile::tempdir().unwrap();
    let tilt = 30f32.to_radians();
    // Unmapped: n = +z, cos 30°.
    let plain = quad_gltf(dir.path(), "plain.gltf", None, None, [1.0; 3]);
    let unmapped = assert_shading(&lit(&plain, sun()), Vec3::Z, sun(), "no map");

    // Red tilt: towards the tangent, +u = +x (MikkTSpace tangents, the file has none): facing
    // the sun, so brighter by 1/cos 30° (up to 8-bit rounding of the texel).
    let texel = encode(Vec3::new(tilt.sin(), 0.0, tilt.cos()));
    let red = quad_gltf(dir.path(), "red.gltf", Some(&Map { texel, scale: None }), None, [1.0; 3]);
    let n = decode(texel, 1.0);
    let mapped = assert_shading(&lit(&red, sun()), n, sun(), "red tilt");
    assert!(mapped > 1.1 * unmapped, "the map shows: {mapped} against {unmapped} without it");

    // Green tilt: towards image up (decreasing v = +y here), away from the sun's plane.
    let texel = encode(Vec3::new(0.0, tilt.sin(), tilt.cos()));
    let green = quad_gltf(dir.path(), "green.gltf", Some(&Map { texel, scale: None }), None, [1.0; 3]);
    let n = decode(texel, 1.0);
    assert!(n.y > 0.45, "{n}");
    let dimmer = assert_shading(&lit(&green, sun()), n, sun(), "green tilt");
    assert!(dimmer < 0.9 * unmapped, "{dimmer} against {unmapped}");

    // The scale multiplies x and y: half the tilt's tangent.
    let texel = encode(Vec3::new(tilt.sin(), 0.0, tilt.cos()));
    let half = quad_gltf(dir.path(), "half.gltf", Some(&Map { texel, scale: Some(0.5) }), None, [1.0; 3]);
    assert_shading(&lit(&half, sun()), decode(texel, 0.5), sun(), "scale 0.5");

    // A sun on the other side (−x) at 70° from +z: the red tilt turns the quad away from it.
    let low_sun = Vec3::new(-(70f32.to_radians().sin()), 0.0, 70f32.to_radians().cos());
    assert_shading(&lit(&red, low_sun), decode(encode(Vec3::new(tilt.sin(), 0.0, tilt.cos())), 1.0), low_sun, "away");
}

/// The sample outputs build their surfaces the same way: the guide buffers of the filtered path
/// tracer (and every `lfr dump` kind, through `SurfacePoint::new`) hold the mapped normal.
#[test]
fn the_guide_buffers_hold_the_mapped_normal() {
    let dir = tempfile::tempdir().unwrap();
    let tilt = 30f32.to_radians();
    let texel = encode(Vec3::new(tilt.sin(), 0.0, tilt.cos()));
    let red = quad_gltf(dir.path(), "red.gltf", Some(&Map { texel, scale: None }), None, [1.0; 3]);
    let scene = lit(&red, sun());
    let accel = tracer::Accel::build(&scene).unwrap();
    let mut settings = tracer::RenderSettings::from_scene(&scene);
    (settings.width, settings.height, settings.spp) = (4, 4, 2);
    let buffers = tracer::samples::guide::guide_buffers(&scene, &accel, &settings).unwrap();
    let expected = decode(texel, 1.0);
    for n in &buffers.normal {
        assert!((*n - expected).length() < 1e-3, "{n} against {expected}");
    }
}

/// A malformed normal texture is an error naming the file and the field, not a panic.
#[test]
fn bad_normal_texture_fields_are_errors_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let map = Map { texel: [128, 128, 255], scale: None };
    let path = quad_gltf(dir.path(), "bad.gltf", Some(&map), None, [1.0; 3]);
    let json = std::fs::read_to_string(&path).unwrap();
    let bad = json.replace(
        r#""normalTexture": {"index": 0"#,
        r#""normalTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"offset": [1]}}"#,
    );
    assert_ne!(bad, json);
    std::fs::write(&path, bad).unwrap();
    let error = Scene::load(&path).unwrap_err().to_string();
    assert!(
        error.contains("bad.gltf")
            && error.contains("materials[0].normalTexture.extensions.KHR_texture_transform.offset"),
        "{error}"
    );
    // A tangent accessor of the wrong type names the attribute.
    let path = quad_gltf(dir.path(), "tangent.gltf", Some(&map), Some([1.0, 0.0, 0.0, 1.0]), [1.0; 3]);
    let json = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, json.replace(r#""count": 4, "type": "VEC4""#, r#""count": 4, "type": "VEC3""#)).unwrap();
    let error = Scene::load(&path).unwrap_err().to_string();
    assert!(error.contains("attributes.TANGENT"), "{error}");
}

#[test]
fn file_tangents_are_used_and_mirroring_keeps_the_map_on_the_surface() {
    let dir = tempfile::tempdir().unwrap();
    let tilt = 30f32.to_radians();
    let texel = encode(Vec3::new(tilt.sin(), 0.0, tilt.cos()));
    let local = decode(texel, 1.0);
    let map = Map { texel, scale: None };
    // The file's tangents point along +y (w = 1, so the bitangent is z × y = −x): the red tilt
    // follows them, not the uvs. (The decoded texels keep their 8-bit rounding: 128 is +0.004.)
    let towards_y = Vec3::new(0.0, 0.5, 0.75f32.sqrt());
    let along_y = quad_gltf(dir.path(), "tangents.gltf", Some(&map), Some([0.0, 1.0, 0.0, 1.0]), [1.0; 3]);
    assert_shading(&lit(&along_y, towards_y), Vec3::new(-local.y, local.x, local.z), towards_y, "file tangents");
    // w = −1 flips only the bitangent: the green tilt goes to +x.
    let texel_g = encode(Vec3::new(0.0, tilt.sin(), tilt.cos()));
    let local_g = decode(texel_g, 1.0);
    let green = Map { texel: texel_g, scale: None };
    let flipped = quad_gltf(dir.path(), "flipped.gltf", Some(&green), Some([0.0, 1.0, 0.0, -1.0]), [1.0; 3]);
    assert_shading(&lit(&flipped, sun()), Vec3::new(local_g.y, local_g.x, local_g.z), sun(), "w = -1");

    // Mirrored by the node (x → −x): u now grows towards −x, so the red tilt leans to −x,
    // with generated tangents and with the file's (+x in the file, −x in the world, w flipped).
    let towards_minus_x = Vec3::new(-0.5, 0.0, 0.75f32.sqrt());
    let expected = Vec3::new(-local.x, local.y, local.z);
    let mirrored = quad_gltf(dir.path(), "mirrored.gltf", Some(&map), None, [-1.0, 1.0, 1.0]);
    assert_shading(&lit(&mirrored, towards_minus_x), expected, towards_minus_x, "mirrored, MikkTSpace");
    let mirrored = quad_gltf(dir.path(), "mirrored-t.gltf", Some(&map), Some([1.0, 0.0, 0.0, 1.0]), [-1.0, 1.0, 1.0]);
    assert_shading(&lit(&mirrored, towards_minus_x), expected, towards_minus_x, "mirrored, file tangents");
    // ... and the green tilt still leans to image up (+y) in the mirror.
    let mirrored = quad_gltf(dir.path(), "mirrored-g.gltf", Some(&green), None, [-1.0, 1.0, 1.0]);
    let towards_y = Vec3::new(0.0, 0.5, 0.75f32.sqrt());
    assert_shading(
        &lit(&mirrored, towards_y),
        Vec3::new(-local_g.x, local_g.y, local_g.z),
        towards_y,
        "mirrored, green",
    );
}

#[test]
fn obj_norm_and_coloured_map_bump_are_normal_maps_and_a_grey_bump_map_is_ignored_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let tilt = 30f32.to_radians();
    let red = encode(Vec3::new(tilt.sin(), 0.0, tilt.cos()));
    let green = encode(Vec3::new(0.0, tilt.sin(), tilt.cos()));
    std::fs::write(dir.path().join("red.png"), png(red)).unwrap();
    std::fs::write(dir.path().join("green.png"), png(green)).unwrap();
    std::fs::write(dir.path().join("height.png"), png([90, 90, 90])).unwrap();
    // OBJ uvs have v up: vt = ((x + 1)/2, (y + 1)/2), so image up is +y here too.
    let obj = |mtl_line: &str| {
        let name = format!("quad{}.obj", mtl_line.len());
        std::fs::write(
            dir.path().join(format!("{name}.mtl")),
            format!("newmtl white\nKd {ALBEDO} {ALBEDO} {ALBEDO}\n{mtl_line}\n"),
        )
        .unwrap();
        std::fs::write(
            dir.path().join(&name),
            format!(
                "mtllib {name}.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
                 vn 0 0 1\nusemtl white\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n"
            ),
        )
        .unwrap();
        dir.path().join(name)
    };
    let towards_y = Vec3::new(0.0, 0.5, 0.75f32.sqrt());
    let scene = lit(&obj("norm red.png"), sun());
    assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
    assert_shading(&scene, decode(red, 1.0), sun(), "OBJ norm");
    assert_shading(&lit(&obj("map_Bump -bm 0.5 green.png"), towards_y), decode(green, 0.5), towards_y, "map_Bump -bm");
    let scene = lit(&obj("bump height.png"), sun());
    assert!(
        scene.warnings.iter().any(|w| w.contains("bump") && w.contains("height") && w.contains("white")),
        "{:?}",
        scene.warnings
    );
    assert_shading(&scene, Vec3::Z, sun(), "grey bump map");
    // A bad option is an error naming the MTL file and the field.
    std::fs::write(dir.path().join("bad.obj"), "mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n")
        .unwrap();
    std::fs::write(dir.path().join("bad.mtl"), "newmtl m\nnorm -bm x red.png\n").unwrap();
    let error = Scene::load(&dir.path().join("bad.obj")).unwrap_err().to_string();
    assert!(error.contains("bad.mtl") && error.contains("'m'.norm") && error.contains("-bm"), "{error}");
}

/// glTF `doubleSided: false` (the default): the quad is there for rays that meet its front face
/// and absent for rays that meet its back, camera rays and shadow rays alike; `doubleSided:
/// true` is there from both sides. A mirroring node keeps the file's front face (the winding
/// is reversed with the geometry).
#[test]
fn single_sided_materials_are_invisible_from_behind_for_every_ray() {
    let dir = tempfile::tempdir().unwrap();
    let single = quad_gltf(dir.path(), "single.gltf", None, None, [1.0; 3]);
    let double = quad_gltf_sided(dir.path(), "double.gltf", None, None, [1.0; 3], true);
    let flipped = quad_gltf(dir.path(), "flipped.gltf", None, None, [1.0, 1.0, -1.0]);
    let mirrored = quad_gltf(dir.path(), "mirrored.gltf", None, None, [-1.0, 1.0, 1.0]);
    // (scene, visible from +z, visible from −z)
    for (path, from_front, from_behind) in
        [(&single, true, false), (&double, true, true), (&flipped, false, true), (&mirrored, true, false)]
    {
        let scene = Scene::load(path).unwrap();
        let accel = tracer::Accel::build(&scene).unwrap();
        for (z, expected) in [(3.0f32, from_front), (-3.0, from_behind)] {
            let origin = Vec3::new(0.25, -0.5, z);
            let direction = Vec3::new(0.0, 0.0, -z.signum());
            let what = format!("{} from z = {z}", path.display());
            assert_eq!(accel.intersect(origin, direction, 0.0, 10.0, 0.0).is_some(), expected, "{what}: intersect");
            assert_eq!(accel.occluded(origin, direction, 0.0, 10.0, 0.0), expected, "{what}: occluded");
        }
        // A camera behind the single-sided quad sees the (black) environment through it.
        let mut scene = scene;
        scene.environment = Vec3::splat(0.3);
        scene.camera = Camera::look_at(Vec3::new(0.0, 0.0, -3.0), Vec3::ZERO, Vec3::Y, 30.0, FovAxis::Y);
        let frame = render(&scene, 4, 4, 2, 1);
        let seen = frame.depth.iter().filter(|&&d| d > 0.0).count();
        assert_eq!(seen, if from_behind { 16 } else { 0 }, "{}: pixels that see the quad from behind", path.display());
        if !from_behind {
            assert!((mean(&frame.beauty) - Vec3::splat(0.3)).abs().max_element() < 1e-6);
        }
    }
}
