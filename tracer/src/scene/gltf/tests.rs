//! The unit tests of `gltf.rs`, in a file of their own beside it for their length.

use super::*;

const FRAC_1_SQRT_2: f32 = std::f32::consts::FRAC_1_SQRT_2;

fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut encoded = String::new();
    for chunk in bytes.chunks(3) {
        let padded = [chunk[0], chunk.get(1).copied().unwrap_or(0), chunk.get(2).copied().unwrap_or(0)];
        let bits = u32::from(padded[0]) << 16 | u32::from(padded[1]) << 8 | u32::from(padded[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                encoded.push(ALPHABET[(bits >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                encoded.push('=');
            }
        }
    }
    encoded
}

/// One triangle in the z = 0 plane: positions (0,0,0), (1,0,0), (0,1,0), normals +Z,
/// uvs matching x and y, u16 indices.
fn triangle_buffer(indices: [u16; 3]) -> Vec<u8> {
    let mut bytes = Vec::new();
    let floats: [&[f32]; 3] =
        [&[0., 0., 0., 1., 0., 0., 0., 1., 0.], &[0., 0., 1., 0., 0., 1., 0., 0., 1.], &[0., 0., 1., 0., 0., 1.]];
    for value in floats.into_iter().flatten() {
        bytes.extend_from_slice(&value.to_le_bytes());
    }
    for index in indices {
        bytes.extend_from_slice(&index.to_le_bytes());
    }
    assert_eq!(bytes.len(), 102);
    bytes
}

fn embedded_buffer(bytes: &[u8]) -> String {
    format!(r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#, bytes.len(), base64(bytes))
}

/// Buffers, views, accessors and one mesh `Tri{i}` per entry of `primitive_extras` (extra
/// JSON members of its single primitive, e.g. `"material": 0`).
fn geometry_json(buffer: &str, primitive_extras: &[&str]) -> String {
    let meshes: Vec<String> = primitive_extras
        .iter()
        .enumerate()
        .map(|(i, extra)| {
            let extra = if extra.is_empty() { String::new() } else { format!(", {extra}") };
            format!(
                r#"{{"name": "Tri{i}", "primitives": [{{"attributes": {{"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}}, "indices": 3{extra}}}]}}"#
            )
        })
        .collect();
    format!(
        r#""asset": {{"version": "2.0"}},
        "buffers": [{buffer}],
        "bufferViews": [
            {{"buffer": 0, "byteOffset": 0, "byteLength": 36}},
            {{"buffer": 0, "byteOffset": 36, "byteLength": 36}},
            {{"buffer": 0, "byteOffset": 72, "byteLength": 24}},
            {{"buffer": 0, "byteOffset": 96, "byteLength": 6}}
        ],
        "accessors": [
            {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}},
            {{"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"}},
            {{"bufferView": 2, "componentType": 5126, "count": 3, "type": "VEC2"}},
            {{"bufferView": 3, "componentType": 5123, "count": 3, "type": "SCALAR"}}
        ],
        "meshes": [{}]"#,
        meshes.join(", ")
    )
}

/// The document of test 1: a translated and scaled triangle with an emissive material, a
/// point light below it in the hierarchy, a camera, a sun and a spot light.
fn lit_scene_json(buffer: &str) -> String {
    format!(
        r#"{{
        {},
        "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{{"nodes": [0, 2, 3, 4]}}],
        "nodes": [
            {{"name": "Tri", "mesh": 0, "translation": [1, 2, 3], "scale": [2, 2, 2], "children": [1]}},
            {{"name": "Bulb", "translation": [0, 1, 0], "extensions": {{"KHR_lights_punctual": {{"light": 0}}}}}},
            {{"name": "Cam", "camera": 0, "translation": [0, 0, 10], "rotation": [0, {FRAC_1_SQRT_2}, 0, {FRAC_1_SQRT_2}]}},
            {{"name": "Sun", "rotation": [-{FRAC_1_SQRT_2}, 0, 0, {FRAC_1_SQRT_2}], "extensions": {{"KHR_lights_punctual": {{"light": 1}}}}}},
            {{"name": "Spot", "translation": [0, 4, 0], "rotation": [-{FRAC_1_SQRT_2}, 0, 0, {FRAC_1_SQRT_2}], "extensions": {{"KHR_lights_punctual": {{"light": 2}}}}}}
        ],
        "cameras": [{{"type": "perspective", "perspective": {{"yfov": 0.8, "aspectRatio": 1.5, "znear": 0.1}}}}],
        "materials": [{{
            "name": "Glow",
            "emissiveFactor": [1, 0.5, 0.25],
            "extensions": {{"KHR_materials_emissive_strength": {{"emissiveStrength": 4}}}},
            "pbrMetallicRoughness": {{"baseColorFactor": [0.2, 0.4, 0.6, 1], "metallicFactor": 0.1, "roughnessFactor": 0.7}},
            "doubleSided": true
        }}],
        "extensions": {{"KHR_lights_punctual": {{"lights": [
            {{"type": "point", "color": [1, 0.5, 0.5], "intensity": 10}},
            {{"type": "directional", "intensity": 3}},
            {{"type": "spot", "intensity": 2, "spot": {{"innerConeAngle": 0.2, "outerConeAngle": 0.4}}}}
        ]}}}}
    }}"#,
        geometry_json(buffer, &[r#""material": 0"#])
    )
}

fn write(dir: &Path, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, contents).unwrap();
    path
}

fn load_new(path: &Path) -> Result<(Scene, GltfImport), SceneError> {
    let mut scene = Scene::empty(path);
    let import = load(path, &mut scene)?;
    Ok((scene, import))
}

fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut json = json.as_bytes().to_vec();
    json.resize(json.len().next_multiple_of(4), b' ');
    let mut bin = bin.to_vec();
    bin.resize(bin.len().next_multiple_of(4), 0);
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut bytes = b"glTF".to_vec();
    for word in [2, total as u32, json.len() as u32] {
        bytes.extend_from_slice(&word.to_le_bytes());
    }
    bytes.extend_from_slice(b"JSON");
    bytes.extend_from_slice(&json);
    bytes.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    bytes.extend_from_slice(b"BIN\0");
    bytes.extend_from_slice(&bin);
    bytes
}

fn assert_close(actual: Vec3, expected: Vec3) {
    assert!((actual - expected).abs().max_element() < 1e-5, "{actual} != {expected}");
}

#[test]
fn flattens_hierarchy_materials_lights_and_camera() {
    let dir = tempfile::tempdir().unwrap();
    let json = lit_scene_json(&embedded_buffer(&triangle_buffer([0, 1, 2])));
    let path = write(dir.path(), "lit.gltf", json);
    let (scene, import) = load_new(&path).unwrap();
    assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);

    assert_eq!(scene.meshes.len(), 1);
    let mesh = &scene.meshes[0];
    // Scale by 2, then translate by (1, 2, 3).
    let expected = [Vec3::new(1.0, 2.0, 3.0), Vec3::new(3.0, 2.0, 3.0), Vec3::new(1.0, 4.0, 3.0)];
    for (&p, e) in mesh.positions.iter().zip(expected) {
        assert_close(p, e);
    }
    assert_eq!(mesh.indices, vec![[0, 1, 2]]);
    assert_eq!(mesh.normals.as_deref(), Some(&[Vec3::Z; 3][..]));
    assert_eq!(mesh.uvs.as_deref(), Some(&[Vec2::ZERO, Vec2::X, Vec2::Y][..]));
    assert!(mesh.name.contains("Tri0"), "{}", mesh.name);

    // Appended after the default material.
    assert_eq!(scene.materials.len(), 2);
    assert_eq!(mesh.material, 1);
    let material = &scene.materials[1];
    assert_eq!(material.name, "Glow");
    assert_close(material.emission, Vec3::new(4.0, 2.0, 1.0));
    assert_close(material.base_color, Vec3::new(0.2, 0.4, 0.6));
    assert!((material.metallic - 0.1).abs() < 1e-6 && (material.roughness - 0.7).abs() < 1e-6);
    assert!(material.two_sided_emission);
    assert!(material.alpha.is_none() && material.base_color_texture.is_none());

    assert_eq!(scene.lights.len(), 3);
    let PunctualLight::Point { position, intensity } = scene.lights[0] else {
        panic!("expected a point light first, got {:?}", scene.lights[0]);
    };
    // Child of the triangle's node: (0, 1, 0) scaled by 2 and moved by (1, 2, 3).
    assert_close(position, Vec3::new(1.0, 4.0, 3.0));
    assert_close(intensity, Vec3::new(10.0, 5.0, 5.0));
    let PunctualLight::Directional { direction, irradiance } = scene.lights[1] else {
        panic!("expected a directional light, got {:?}", scene.lights[1]);
    };
    // -90 degrees about X turns -Z into -Y.
    assert_close(direction, Vec3::NEG_Y);
    assert_close(irradiance, Vec3::splat(3.0));
    let PunctualLight::Spot { position, direction, intensity, inner_cone, outer_cone } = scene.lights[2] else {
        panic!("expected a spot light, got {:?}", scene.lights[2]);
    };
    assert_close(position, Vec3::new(0.0, 4.0, 0.0));
    assert_close(direction, Vec3::NEG_Y);
    assert_close(intensity, Vec3::splat(2.0));
    assert_eq!((inner_cone, outer_cone), (0.2, 0.4));

    let camera = import.camera.expect("camera");
    assert_close(camera.position, Vec3::new(0.0, 0.0, 10.0));
    // +90 degrees about Y turns -Z into -X.
    assert_close(camera.forward, Vec3::NEG_X);
    assert_close(camera.up, Vec3::Y);
    assert!((camera.fov_deg - 0.8f32.to_degrees()).abs() < 1e-4);
    assert_eq!(camera.fov_axis, FovAxis::Y);
    assert_eq!(import.aspect_ratio, Some(1.5));
}

#[test]
fn caller_transform_applies_on_top_of_node_transforms() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "lit.gltf", lit_scene_json(&embedded_buffer(&triangle_buffer([0, 1, 2]))));
    let mut scene = Scene::empty(&path);
    load_with_transform(&path, &mut scene, Mat4::from_translation(Vec3::new(0.0, 0.0, -3.0))).unwrap();
    assert_close(scene.meshes[0].positions[1], Vec3::new(3.0, 2.0, 0.0));
    assert!(matches!(scene.lights[0], PunctualLight::Point { position, .. } if position == Vec3::new(1.0, 4.0, 0.0)));
}

#[test]
fn mirroring_transforms_flip_winding_and_normals_use_the_inverse_transpose() {
    let dir = tempfile::tempdir().unwrap();
    let json = format!(
        r#"{{ {}, "scenes": [{{"nodes": [0, 1, 2]}}], "nodes": [
            {{"mesh": 0, "scale": [-1, 1, 1]}},
            {{"mesh": 0, "scale": [1, 1, -1]}},
            {{"mesh": 0, "matrix": [1, 0, 0, 0,  0, 1, 0, 0,  1, 0, 1, 0,  0, 0, 0, 1]}}
        ]}}"#,
        geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[""])
    );
    let path = write(dir.path(), "mirror.gltf", json);
    let (scene, _) = load_new(&path).unwrap();
    assert_eq!(scene.meshes.len(), 3);
    // Without a material, the scene's default material.
    assert!(scene.meshes.iter().all(|m| m.material == 0));
    let geometric_normal = |mesh: &Mesh| {
        let [a, b, c] = mesh.indices[0].map(|i| mesh.positions[i as usize]);
        (b - a).cross(c - a).normalize()
    };

    let mirrored_x = &scene.meshes[0];
    assert_eq!(mirrored_x.indices, vec![[0, 2, 1]]);
    assert_close(mirrored_x.positions[1], Vec3::new(-1.0, 0.0, 0.0));
    assert_close(mirrored_x.normals.as_ref().unwrap()[0], Vec3::Z);
    assert_close(geometric_normal(mirrored_x), Vec3::Z);

    let mirrored_z = &scene.meshes[1];
    assert_eq!(mirrored_z.indices, vec![[0, 2, 1]]);
    assert_close(mirrored_z.normals.as_ref().unwrap()[0], Vec3::NEG_Z);
    assert_close(geometric_normal(mirrored_z), Vec3::NEG_Z);

    // A shear x += z keeps the plane z = 0: the normal stays +Z (the forward matrix would
    // give (1, 0, 1) / sqrt 2) and the winding is kept.
    let sheared = &scene.meshes[2];
    assert_eq!(sheared.indices, vec![[0, 1, 2]]);
    assert_close(sheared.normals.as_ref().unwrap()[2], Vec3::Z);
    assert_close(geometric_normal(sheared), Vec3::Z);
}

#[test]
fn texture_transform_matches_the_spec_by_hand() {
    // offset (0.5, -1), rotation 90 degrees, scale (2, 3) applied to uv (0.25, 0.5):
    // scale -> (0.5, 1.5); rotate (u' = cos u + sin v, v' = -sin u + cos v) -> (1.5, -0.5);
    // translate -> (2.0, -1.5).
    let m = uv_transform(Vec2::new(0.5, -1.0), std::f32::consts::FRAC_PI_2, Vec2::new(2.0, 3.0));
    let texture = TextureRef::with_transform(0, Some(m));
    let uv = texture.apply(Vec2::new(0.25, 0.5));
    assert!((uv - Vec2::new(2.0, -1.5)).abs().max_element() < 1e-6, "{uv}");
    let identity = uv_transform(Vec2::ZERO, 0.0, Vec2::ONE);
    assert!(identity.abs_diff_eq(Mat3::IDENTITY, 1e-7));
}

#[test]
fn textures_are_shared_per_encoding_and_carry_transforms_and_masks() {
    let dir = tempfile::tempdir().unwrap();
    let texels: Vec<u8> = vec![10, 20, 30, 255, 40, 50, 60, 128, 70, 80, 90, 0, 100, 110, 120, 64];
    image::RgbaImage::from_raw(2, 2, texels.clone()).unwrap().save(dir.path().join("my tex.png")).unwrap();
    let transform = format!(
        r#""extensions": {{"KHR_texture_transform": {{"offset": [0.5, -1], "rotation": {}, "scale": [2, 3]}}}}"#,
        std::f32::consts::FRAC_PI_2
    );
    let json = format!(
        r#"{{ {}, "scenes": [{{"nodes": [0, 1, 2, 3]}}],
        "nodes": [{{"mesh": 0}}, {{"mesh": 1}}, {{"mesh": 2}}, {{"mesh": 3}}],
        "extensionsUsed": ["KHR_texture_transform", "KHR_materials_transmission"],
        "images": [{{"uri": "my%20tex.png"}}],
        "samplers": [{{"wrapS": 33071}}],
        "textures": [{{"source": 0}}, {{"source": 0, "sampler": 0}}],
        "materials": [
            {{"name": "Masked", "alphaMode": "MASK", "alphaCutoff": 0.3,
              "pbrMetallicRoughness": {{"baseColorFactor": [1, 1, 1, 0.8],
                "baseColorTexture": {{"index": 0, {transform}}},
                "metallicRoughnessTexture": {{"index": 0}}}},
              "emissiveTexture": {{"index": 1}}, "emissiveFactor": [1, 1, 1]}},
            {{"name": "Invisible", "alphaMode": "MASK", "pbrMetallicRoughness": {{"baseColorFactor": [1, 1, 1, 0.2]}}}},
            {{"name": "Blended", "alphaMode": "BLEND"}},
            {{"name": "SecondSet", "pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0, "texCoord": 1}}}}}}
        ]}}"#,
        geometry_json(
            &embedded_buffer(&triangle_buffer([0, 1, 2])),
            &[r#""material": 0"#, r#""material": 1"#, r#""material": 2"#, r#""material": 3"#]
        )
    );
    let path = write(dir.path(), "textured.gltf", json);
    let (scene, _) = load_new(&path).unwrap();
    assert_eq!(scene.materials.len(), 5);

    // Image 0 as sRGB (base colour and emission share it), as linear (metallic-roughness),
    // and the constant behind the invisible material's mask.
    assert_eq!(scene.textures.len(), 3);
    let masked = &scene.materials[1];
    let base = masked.base_color_texture.clone().expect("base colour texture");
    let emission = masked.emission_texture.clone().expect("emission texture");
    let metallic_roughness = masked.metallic_roughness_texture.clone().expect("metallic-roughness texture");
    assert_eq!(base.index, emission.index);
    assert_ne!(base.index, metallic_roughness.index);
    let srgb = &scene.textures[base.index as usize];
    let linear = &scene.textures[metallic_roughness.index as usize];
    assert!(srgb.srgb && !linear.srgb);
    for texture in [srgb, linear] {
        assert_eq!((texture.width, texture.height), (2, 2));
        assert_eq!(texture.texels.concat(), texels);
    }
    let uv = base.apply(Vec2::new(0.25, 0.5));
    assert!((uv - Vec2::new(2.0, -1.5)).abs().max_element() < 1e-5, "{uv}");
    // Texture 1's sampler clamps u (wrapS 33071) and repeats v (the default).
    assert_eq!(base.wrap(), [Wrap::Repeat; 2]);
    assert_eq!(emission.wrap(), [Wrap::ClampToEdge, Wrap::Repeat]);
    assert_eq!(emission.apply(Vec2::new(1.5, 1.5)), Vec2::new(1.0, 1.5));
    assert!(metallic_roughness.transform().is_none() && emission.transform().is_none());
    let mask = masked.alpha.as_ref().expect("alpha mask");
    assert_eq!((&mask.texture, mask.channel, mask.factor, mask.cutoff), (&base, 3, 0.8, 0.3));

    // MASK without a texture and alpha below the cutoff: hidden everywhere.
    let invisible = scene.materials[2].alpha.as_ref().expect("mask on the invisible material");
    let coverage = scene.textures[invisible.texture.index as usize].sample(Vec2::splat(0.5)).w * invisible.factor;
    assert!(coverage < invisible.cutoff);
    assert_eq!(invisible.cutoff, 0.5);

    // BLEND with opaque alpha: no mask, but a warning.
    assert!(scene.materials[3].alpha.is_none());
    let warnings = scene.warnings.join("\n");
    assert!(warnings.contains("Blended") && warnings.contains("BLEND"), "{warnings}");
    // A texture on TEXCOORD_1 is dropped with a warning.
    assert!(scene.materials[4].base_color_texture.is_none());
    assert!(warnings.contains("coordinate set 1"), "{warnings}");
    assert!(warnings.contains("KHR_materials_transmission"), "{warnings}");
}

#[test]
fn non_triangle_primitives_are_skipped_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let json = format!(
        r#"{{ {}, "scenes": [{{"nodes": [0, 1]}}], "nodes": [{{"mesh": 0}}, {{"mesh": 1}}] }}"#,
        geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[r#""mode": 1"#, r#""mode": 4"#])
    );
    let path = write(dir.path(), "lines.gltf", json);
    let (scene, _) = load_new(&path).unwrap();
    assert_eq!(scene.meshes.len(), 1);
    assert!(scene.meshes[0].name.contains("Tri1"));
    assert!(scene.warnings.iter().any(|w| w.contains("Tri0") && w.contains("Lines")), "{:?}", scene.warnings);
}

#[test]
fn ignored_animations_are_named_in_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let geometry = geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[""]);
    let animation = r#""animations": [{"channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
        "samplers": [{"input": 3, "output": 0}]}]"#;
    let still = format!(r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#);
    let moving = format!(r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}], {animation} }}"#);
    let (scene, _) = load_new(&write(dir.path(), "still.gltf", still)).unwrap();
    assert!(!scene.warnings.iter().any(|w| w.contains("animation")), "{:?}", scene.warnings);
    let (scene, _) = load_new(&write(dir.path(), "moving.gltf", moving)).unwrap();
    assert!(scene.warnings.iter().any(|w| w.contains("1 animation(s) ignored")), "{:?}", scene.warnings);
    assert_eq!(scene.meshes.len(), 1, "the mesh is still loaded");
}

fn scenes_dir() -> PathBuf {
    let dir = std::env::var_os("LFR_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes"));
    assert!(dir.is_dir(), "test scenes not found at {} (set LFR_SCENES to the scenes directory)", dir.display());
    dir
}

#[test]
fn loads_the_roughness_scale_spheres() {
    let path = scenes_dir().join("roughness-scale/scene.gltf");
    let (mut scene, _) = load_new(&path).unwrap();
    assert_eq!(scene.meshes.len(), 10);
    let material = |mesh: &Mesh| &scene.materials[mesh.material as usize];
    for expected in [0.004, 0.25, 0.5, 0.75, 0.99] {
        assert!(
            scene.meshes.iter().any(|m| material(m).metallic_roughness_texture.is_none()
                && (material(m).roughness - expected).abs() < 0.005),
            "no sphere with roughness {expected}"
        );
    }
    let textured = scene.meshes.iter().filter(|m| material(m).metallic_roughness_texture.is_some()).count();
    assert_eq!(textured, 5);
    assert!(scene.textures.iter().all(|t| !t.srgb));
    // The spheres sit on x = 0 at y = +-3.
    for mesh in &scene.meshes {
        let centre = mesh.positions.iter().sum::<Vec3>() / mesh.positions.len() as f32;
        assert!(centre.x.abs() < 0.1 && (centre.y.abs() - 3.0).abs() < 0.1, "{centre}");
    }
    scene.validate().unwrap();
}

#[test]
fn loads_the_roughness_scale_floor_with_its_texture_transform() {
    let path = scenes_dir().join("roughness-scale/floor/scene.gltf");
    let (scene, _) = load_new(&path).unwrap();
    assert_eq!(scene.meshes.len(), 1);
    let material = &scene.materials[scene.meshes[0].material as usize];
    let texture = material.metallic_roughness_texture.as_ref().expect("roughness texture");
    assert!(texture.transform().is_some());
    // offset (0, -23), scale (24, 24).
    let uv = texture.apply(Vec2::new(0.5, 0.5));
    assert!((uv - Vec2::new(12.0, -11.0)).abs().max_element() < 1e-4, "{uv}");
}

#[test]
fn loads_suzanne_with_both_textures() {
    let path = scenes_dir().join("glossy-monkeys/Suzanne/glTF/Suzanne.gltf");
    let (mut scene, _) = load_new(&path).unwrap();
    assert_eq!(scene.meshes.len(), 1);
    assert_eq!(scene.meshes[0].indices.len(), 3936);
    assert!(scene.meshes[0].uvs.is_some() && scene.meshes[0].normals.is_some());
    let material = &scene.materials[scene.meshes[0].material as usize];
    let base = material.base_color_texture.as_ref().expect("base colour texture");
    let metallic_roughness = material.metallic_roughness_texture.as_ref().expect("metallic-roughness texture");
    assert!(scene.textures[base.index as usize].srgb);
    assert!(!scene.textures[metallic_roughness.index as usize].srgb);
    assert!(scene.textures.iter().all(|t| t.width > 1 && t.texels.len() == (t.width * t.height) as usize));
    scene.validate().unwrap();
}

#[test]
fn glb_loads_and_truncations_give_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = glb(&lit_scene_json(r#"{"byteLength": 102}"#), &triangle_buffer([0, 1, 2]));
    let path = write(dir.path(), "lit.glb", &bytes);
    let (scene, import) = load_new(&path).unwrap();
    assert_close(scene.meshes[0].positions[2], Vec3::new(1.0, 4.0, 3.0));
    assert!(import.camera.is_some());

    for length in 0..bytes.len() {
        let path = write(dir.path(), "cut.glb", &bytes[..length]);
        // Cuts inside the BIN chunk padding may still load; nothing may panic.
        if let Err(e) = load_new(&path) {
            assert!(e.to_string().contains(&path.display().to_string()), "{e}");
        }
    }
    let path = write(dir.path(), "half.glb", &bytes[..bytes.len() / 2]);
    let error = load_new(&path).unwrap_err();
    assert!(error.to_string().contains("half.glb") && error.message.contains("truncated"), "{error}");
}

#[test]
fn malformed_json_and_missing_files_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "broken.gltf", r#"{"asset": {"version": "2.0"}, "nodes": [ "#);
    let error = load_new(&path).unwrap_err();
    assert!(error.to_string().contains(&path.display().to_string()), "{error}");

    let geometry = geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[r#""material": 0"#]);
    let json = format!(
        r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}],
        "images": [{{"uri": "textures/missing.png"}}], "textures": [{{"source": 0}}],
        "materials": [{{"pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}}}}}] }}"#
    );
    let error = load_new(&write(dir.path(), "no-image.gltf", json)).unwrap_err();
    assert_eq!(error.field, "images[0].uri");
    assert!(error.message.contains("missing.png"), "{error}");

    let json = format!(
        r#"{{ {}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#,
        geometry_json(r#"{"byteLength": 102, "uri": "geometry.bin"}"#, &[""])
    );
    let error = load_new(&write(dir.path(), "no-buffer.gltf", json)).unwrap_err();
    assert_eq!(error.field, "buffers[0]");
    assert!(error.message.contains("geometry.bin"), "{error}");

    let error = load_new(&dir.path().join("absent.gltf")).unwrap_err();
    assert!(error.to_string().contains("absent.gltf"));
}

#[test]
fn unsupported_required_extensions_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let json = format!(
        r#"{{ {}, "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"] }}"#,
        geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[""])
    );
    let error = load_new(&write(dir.path(), "draco.gltf", json)).unwrap_err();
    assert!(error.message.contains("KHR_draco_mesh_compression"), "{error}");
}

#[test]
fn corrupt_accessors_and_indices_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let good_buffer = embedded_buffer(&triangle_buffer([0, 1, 2]));
    let document = |buffer: &str| {
        format!(r#"{{ {}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#, geometry_json(buffer, &[""]))
    };
    let good = document(&good_buffer);
    let position_accessor = r#"{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3""#;
    let index_accessor = r#"{"bufferView": 3, "componentType": 5123, "count": 3"#;
    let cases = [
        ("vertex index", document(&embedded_buffer(&triangle_buffer([0, 1, 7]))), "indices"),
        ("POSITION index", good.replace(r#""POSITION": 0"#, r#""POSITION": 99"#), "attributes"),
        (
            "count 0",
            good.replace(position_accessor, &position_accessor.replace("\"count\": 3", "\"count\": 0")),
            "POSITION",
        ),
        (
            "huge count",
            good.replace(
                position_accessor,
                &position_accessor.replace("\"count\": 3", "\"count\": 4611686018427387904"),
            ),
            "POSITION",
        ),
        (
            "count past view",
            good.replace(index_accessor, &index_accessor.replace("\"count\": 3", "\"count\": 4")),
            "indices",
        ),
        ("float indices", good.replace(index_accessor, &index_accessor.replace("5123", "5126")), "indices"),
        ("VEC2 positions", good.replace(position_accessor, &position_accessor.replace("VEC3", "VEC2")), "POSITION"),
        (
            "short stride",
            good.replace(
                r#""byteOffset": 0, "byteLength": 36}"#,
                r#""byteOffset": 0, "byteLength": 36, "byteStride": 4}"#,
            ),
            "POSITION",
        ),
        (
            "view past buffer",
            good.replace(
                r#""byteOffset": 96, "byteLength": 6"#,
                r#""byteOffset": 18446744073709551610, "byteLength": 6"#,
            ),
            "bufferViews[3]",
        ),
        ("short buffer", good.replace(r#""byteLength": 102"#, r#""byteLength": 1000"#), "buffers[0]"),
        (
            "undecodable image",
            good.replace(
                r#""nodes": [{"mesh": 0}]"#,
                r#""nodes": [{"mesh": 0}], "images": [{"bufferView": 0}], "textures": [{"source": 0}],
                "materials": [{"emissiveTexture": {"index": 0}}]"#,
            )
            .replace(r#""indices": 3}"#, r#""indices": 3, "material": 0}"#),
            "images[0].bufferView",
        ),
    ];
    for (what, json, field) in cases {
        assert_ne!(json, good, "{what}: the corruption did not apply");
        let path = write(dir.path(), "corrupt.gltf", &json);
        match load_new(&path) {
            Ok(_) => panic!("{what}: loaded"),
            Err(e) => assert!(e.field.contains(field), "{what}: {e}"),
        }
    }
}

#[test]
fn odd_but_loadable_documents_do_not_panic() {
    let dir = tempfile::tempdir().unwrap();
    let geometry = geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[""]);
    // A node that is its own child, a camera whose type lacks its projection, an
    // orthographic camera, an image in a buffer view without a mime type (unused).
    let json = format!(
        r#"{{ {geometry}, "scenes": [{{"nodes": [0, 1, 2]}}],
        "nodes": [{{"mesh": 0, "children": [0]}}, {{"camera": 0}}, {{"camera": 1}}],
        "cameras": [{{"type": "perspective", "orthographic": {{"xmag": 1, "ymag": 1, "zfar": 10, "znear": 1}}}},
                    {{"type": "orthographic", "orthographic": {{"xmag": 1, "ymag": 1, "zfar": 10, "znear": 1}}}}],
        "images": [{{"bufferView": 0}}] }}"#
    );
    let (scene, import) = load_new(&write(dir.path(), "odd.gltf", json)).unwrap();
    assert_eq!(scene.meshes.len(), 1);
    assert!(import.camera.is_none());
    let warnings = scene.warnings.join("\n");
    assert!(warnings.contains("reached twice") && warnings.contains("orthographic"), "{warnings}");
}

#[test]
fn mutated_numbers_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "tri.bin", triangle_buffer([0, 1, 2]));
    let json = lit_scene_json(r#"{"byteLength": 102, "uri": "tri.bin"}"#);
    let path = dir.path().join("mutant.gltf");
    let digits = json.char_indices().filter(|(_, c)| c.is_ascii_digit()).map(|(i, _)| i);
    let mut loaded = 0;
    for i in digits {
        for replacement in ["9999999999", "0", "-1", "1e39"] {
            let mutant = format!("{}{replacement}{}", &json[..i], &json[i + 1..]);
            std::fs::write(&path, &mutant).unwrap();
            let mut scene = Scene::empty(&path);
            if load(&path, &mut scene).is_ok() {
                loaded += 1;
                // Whatever loaded must be consistent enough for validation to judge it.
                let _ = scene.validate();
            }
        }
    }
    assert!(loaded > 0);
}

#[test]
fn sparse_accessors_substitute_values() {
    let dir = tempfile::tempdir().unwrap();
    // Accessor 4: the positions with vertex 0 replaced by the first normal, (0, 0, 1),
    // indexed by the first u16 of the index view.
    let sparse = r#"{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1],
        "sparse": {"count": 1, "indices": {"bufferView": 3, "componentType": COMPONENT}, "values": {"bufferView": 1}}}"#;
    let geometry = geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[""])
        .replace(r#""POSITION": 0"#, r#""POSITION": 4"#);
    let document = |component: &str| {
        let accessor = sparse.replace("COMPONENT", component);
        let geometry = geometry.replace(r#""type": "SCALAR"}"#, &format!(r#""type": "SCALAR"}}, {accessor}"#));
        format!(r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#)
    };
    let (scene, _) = load_new(&write(dir.path(), "sparse.gltf", document("5123"))).unwrap();
    assert_eq!(scene.meshes[0].positions, vec![Vec3::Z, Vec3::X, Vec3::Y]);
    // Float sparse indices (the gltf crate would hit `unreachable!`).
    assert!(load_new(&write(dir.path(), "sparse.gltf", document("5126"))).is_err());
}

/// A one-triangle document over `tri.bin` (written beside it) whose buffer declares
/// `byte_length` bytes, with `asset` as its asset object.
fn triangle_over_bin(dir: &Path, asset: &str, byte_length: usize) -> PathBuf {
    write(dir, "tri.bin", triangle_buffer([0, 1, 2]));
    let geometry = geometry_json(&format!(r#"{{"byteLength": {byte_length}, "uri": "tri.bin"}}"#), &[""])
        .replace(r#""asset": {"version": "2.0"}"#, &format!(r#""asset": {asset}"#));
    write(dir, "tri.gltf", format!(r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#))
}

#[test]
fn an_energy_gaining_base_color_factor_is_named_in_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "tri.bin", triangle_buffer([0, 1, 2]));
    let json = lit_scene_json(r#"{"byteLength": 102, "uri": "tri.bin"}"#);
    let cool = Scene::load(&write(dir.path(), "cool.gltf", &json)).unwrap();
    assert!(!cool.warnings.iter().any(|w| w.contains("base colour")), "{:?}", cool.warnings);
    let hot = json.replace("[0.2, 0.4, 0.6, 1]", "[1.5, 0.4, 0.6, 1]");
    let hot = Scene::load(&write(dir.path(), "hot.gltf", hot)).unwrap();
    let warning = hot.warnings.iter().find(|w| w.contains("base colour")).expect("a warning");
    assert!(warning.contains("'Glow'.base_color") && warning.contains("[1.5, 0.4, 0.6]"), "{warning}");
}

#[test]
fn buffer_and_image_uris_stay_in_the_scene_folder() {
    let dir = tempfile::tempdir().unwrap();
    let (scene_dir, outside) = (dir.path().join("scene"), dir.path().join("outside"));
    std::fs::create_dir_all(&scene_dir).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    write(&outside, "tri.bin", triangle_buffer([0, 1, 2]));
    #[cfg(unix)]
    std::os::unix::fs::symlink(outside.join("tri.bin"), scene_dir.join("link.bin")).unwrap();
    let document = |uri: &str| {
        let buffer = format!(r#"{{"byteLength": 102, "uri": "{uri}"}}"#);
        format!(r#"{{ {}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#, geometry_json(&buffer, &[""]))
    };
    let load_as = |uri: &str, access: FileAccess| {
        let path = write(&scene_dir, "tri.gltf", document(uri));
        let mut scene = Scene::empty(&path);
        scene.file_access = access;
        load(&path, &mut scene).map(|_| scene)
    };
    let depth = dir.path().components().count();
    let passwd = format!("{}etc/passwd", "../".repeat(depth + 1));
    let file_uri = format!("file://{}", outside.join("tri.bin").display());
    for uri in [passwd.as_str(), "../outside/tri.bin", "link.bin", file_uri.as_str()] {
        if uri == "link.bin" && !cfg!(unix) {
            continue;
        }
        let error = load_as(uri, FileAccess::Confined).unwrap_err();
        assert_eq!(error.field, "buffers[0]", "{uri}");
        let message = error.to_string();
        assert!(message.contains(&format!("`{uri}` resolves to ")) && message.contains("outside"), "{message}");
        assert!(message.contains("--allow-outside-scene-dir"), "{message}");
        assert!(!message.contains("root:"), "no byte of the refused file: {message}");
    }
    // Allowed with the option (a file of this test, never /etc/passwd), and inside the folder.
    for uri in ["../outside/tri.bin", "link.bin", file_uri.as_str()] {
        if uri == "link.bin" && !cfg!(unix) {
            continue;
        }
        assert_eq!(load_as(uri, FileAccess::Anywhere).unwrap().meshes.len(), 1, "{uri}");
    }
    std::fs::copy(outside.join("tri.bin"), scene_dir.join("tri.bin")).unwrap();
    assert_eq!(load_as("tri.bin", FileAccess::Confined).unwrap().meshes.len(), 1);
    std::fs::create_dir(scene_dir.join("sub")).unwrap();
    assert_eq!(load_as("./sub/../tri.bin", FileAccess::Confined).unwrap().meshes.len(), 1);

    // Images too.
    let geometry = geometry_json(&embedded_buffer(&triangle_buffer([0, 1, 2])), &[r#""material": 0"#]);
    let json = format!(
        r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}],
        "images": [{{"uri": "../outside/tri.bin"}}], "textures": [{{"source": 0}}],
        "materials": [{{"pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}}}}}] }}"#
    );
    let error = load_new(&write(&scene_dir, "image.gltf", json)).unwrap_err();
    assert_eq!(error.field, "images[0].uri");
    assert!(error.message.contains("`../outside/tri.bin` resolves to"), "{error}");
}

#[test]
fn versions_other_than_2x_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for version in [r#"{"version": "2.0"}"#, r#"{"version": "2.1"}"#, r#"{"version": "2.0", "minVersion": "2.0"}"#] {
        let (scene, _) = load_new(&triangle_over_bin(dir.path(), version, 102)).unwrap();
        assert_eq!(scene.meshes.len(), 1, "{version}");
    }
    for (asset, field, shown) in [
        (r#"{"version": "3.0"}"#, "asset.version", "\"3.0\""),
        (r#"{"version": "1.0"}"#, "asset.version", "\"1.0\""),
        (r#"{"version": "2"}"#, "asset.version", "\"2\""),
        (r#"{"version": "20.0"}"#, "asset.version", "\"20.0\""),
        (r#"{"version": "2.0", "minVersion": "3.0"}"#, "asset.minVersion", "\"3.0\""),
    ] {
        let path = triangle_over_bin(dir.path(), asset, 102);
        let error = load_new(&path).unwrap_err();
        assert_eq!(error.field, field, "{asset}");
        let message = error.to_string();
        assert!(message.starts_with(&format!("{}: {field}: ", path.display())), "{message}");
        assert!(message.contains(shown) && message.contains("2.x"), "{message}");
    }
}

#[test]
fn a_buffer_shorter_than_its_views_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    // tri.bin has 102 bytes; the buffer claims 96, the index view lies at 96..102.
    let path = triangle_over_bin(dir.path(), r#"{"version": "2.0"}"#, 96);
    let error = load_new(&path).unwrap_err();
    assert_eq!(error.field, "bufferViews[3]");
    let message = error.to_string();
    assert!(message.contains("byteOffset 96 + byteLength 6 exceeds the byteLength 96 of buffers[0]"), "{message}");
    // A view ending exactly at the buffer's end is fine; a file shorter than the buffer is not.
    assert!(load_new(&triangle_over_bin(dir.path(), r#"{"version": "2.0"}"#, 102)).is_ok());
    let error = load_new(&triangle_over_bin(dir.path(), r#"{"version": "2.0"}"#, 104)).unwrap_err();
    assert_eq!(error.field, "buffers[0]", "{error}");
}

#[test]
fn out_of_range_sparse_indices_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Accessor 4: the 3 positions with one element replaced; its index is the u16 in buffer 1.
    let sparse = r#"{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1],
        "sparse": {"count": 1, "indices": {"bufferView": 4, "componentType": 5123}, "values": {"bufferView": 1}}}"#;
    let document = |index: u16| {
        let buffers =
            format!("{}, {}", embedded_buffer(&triangle_buffer([0, 1, 2])), embedded_buffer(&index.to_le_bytes()));
        let geometry = geometry_json(&buffers, &[""])
            .replace(r#""POSITION": 0"#, r#""POSITION": 4"#)
            .replace(r#""type": "SCALAR"}"#, &format!(r#""type": "SCALAR"}}, {sparse}"#))
            .replace(
                r#"{"buffer": 0, "byteOffset": 96, "byteLength": 6}"#,
                r#"{"buffer": 0, "byteOffset": 96, "byteLength": 6}, {"buffer": 1, "byteLength": 2}"#,
            );
        format!(r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#)
    };
    let (scene, _) = load_new(&write(dir.path(), "sparse.gltf", document(2))).unwrap();
    assert_eq!(scene.meshes[0].positions, vec![Vec3::ZERO, Vec3::X, Vec3::Z], "element 2 replaced");
    for index in [3, 65535] {
        let path = write(dir.path(), "sparse.gltf", document(index));
        let message = load_new(&path).unwrap_err().to_string();
        let expected = format!("sparse index 0 is {index}, outside the accessor's 3 elements");
        assert!(message.starts_with(&path.display().to_string()) && message.contains(&expected), "{message}");
    }
}
