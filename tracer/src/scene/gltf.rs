//! glTF 2.0 loader (`.gltf` with external or embedded data, and binary `.glb`).
//!
//! The default scene (or, without one, the first scene) is walked from its root nodes and
//! flattened into world-space [`Mesh`]es: each node's transform is composed with its parents'
//! and with the caller's transform. Positions go through the full matrix, normals through its
//! inverse transpose (renormalised), and a mirroring transform (negative determinant) reverses
//! the triangle winding so that front faces stay front faces.
//!
//! Supported:
//! - every `TRIANGLES` primitive becomes one mesh with `POSITION`, optional `NORMAL` (without
//!   it the tracer uses geometric normals), optional `TEXCOORD_0` (float, or normalised
//!   unsigned byte/short) and optional indices (sequential when absent); sparse accessors are
//!   read through the `gltf` crate after their byte ranges have been checked;
//! - metallic-roughness materials: base colour factor and texture (sRGB), metallic and
//!   roughness factors and texture (linear; roughness in G, metallic in B), emissive factor
//!   times `KHR_materials_emissive_strength` and emissive texture (sRGB), `doubleSided` as
//!   two-sided emission, alpha modes `MASK` and `BLEND` (the latter treated as `MASK` with
//!   cutoff 0.5, with a warning) as an [`AlphaMask`] on the base colour alpha;
//! - `KHR_texture_transform` (offset, rotation, scale) on every texture reference;
//! - `KHR_lights_punctual` point, spot and directional lights. Photometric units are taken
//!   1:1 as radiometric ones: candela as W/sr for point and spot lights, lux as W/m² for
//!   directional lights. The `range` cut-off is ignored (lights fall off with 1/d²);
//! - the first perspective camera met in the node walk (its `aspectRatio` is reported in
//!   [`GltfImport::aspect_ratio`]).
//!
//! Not supported (skipped, mostly with a warning in [`Scene::warnings`]): primitive modes
//! other than triangles; texture coordinate sets other than 0 (such textures are dropped);
//! sampler filter modes (textures are filtered bilinearly; wrap modes are kept);
//! normal and occlusion textures; vertex colours; skins and morph targets (the base mesh is
//! placed by its node transform); animations; orthographic cameras; every extension other
//! than the three above (an error when listed in `extensionsRequired`, a warning otherwise).
//! Texels are stored as 8 bits per channel, so 16-bit images lose precision.
//!
//! Malformed input (bad JSON, truncated GLB, missing buffers or images, out-of-range
//! accessors or indices) gives a [`SceneError`] naming the file and the glTF field; the
//! loader checks what the `gltf` crate's readers assume, so that no input makes it panic.
//! Non-finite vertex positions are kept and rejected later by [`Scene::validate`].

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Quat, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::json::accessor::{ComponentType, IndexComponentType};
use gltf::json::validation::Checked;
use gltf::khr_lights_punctual::Kind as LightKind;
use gltf::material::AlphaMode;
use gltf::mesh::Mode;

use super::input::FileAccess;
use super::{AlphaMask, Material, Mesh, PunctualLight, Scene};
use crate::camera::{Camera, FovAxis};
use crate::error::SceneError;
use crate::texture::{Texture, TextureRef, Wrap};

/// Extensions this loader interprets; any other one in `extensionsRequired` is an error.
const SUPPORTED_EXTENSIONS: [&str; 3] =
    ["KHR_lights_punctual", "KHR_materials_emissive_strength", "KHR_texture_transform"];

/// Largest element count accepted for a sparse accessor without a buffer view: its size is
/// not bounded by any buffer, so a corrupt count could otherwise ask for any amount of memory.
const MAX_UNBACKED_ACCESSOR_COUNT: usize = 1 << 26;

/// What a glTF file contributes besides geometry.
#[derive(Debug, Default)]
pub struct GltfImport {
    /// The first camera in the default scene, if any.
    pub camera: Option<Camera>,
    /// Image size the camera's aspect ratio suggests, if it has one.
    pub aspect_ratio: Option<f32>,
    /// Every perspective camera met in the node walk, in that order (the first is `camera`).
    pub cameras: Vec<super::FileCamera>,
}

/// Loads a glTF file into `scene` (see the module documentation).
pub fn load(path: &Path, scene: &mut Scene) -> Result<GltfImport, SceneError> {
    load_with_transform(path, scene, Mat4::IDENTITY)
}

/// Loads a glTF file into `scene`, placing its root nodes with `transform`. Meshes,
/// materials, textures and lights are appended; `scene.materials[0]` serves primitives
/// without a material.
pub fn load_with_transform(path: &Path, scene: &mut Scene, transform: Mat4) -> Result<GltfImport, SceneError> {
    let bytes = super::input::read_input(path, crate::limits::MAX_MODEL_BYTES, path, "file")?;
    load_from_bytes(path, &bytes, scene, transform)
}

/// [`load_with_transform`] of the `.gltf` or `.glb` bytes `bytes`, named `path` in messages;
/// buffers and images are taken from the GLB chunk and `data:` URIs in memory, other URIs
/// read relative to `path`'s folder (the fuzz targets use a folder that does not exist).
pub fn load_from_bytes(
    path: &Path,
    bytes: &[u8],
    scene: &mut Scene,
    transform: Mat4,
) -> Result<GltfImport, SceneError> {
    let gltf::Gltf { document, blob } = parse(path, bytes)?;
    check_extensions(path, &document, &mut scene.warnings)?;
    let document = validate(path, document)?;
    check_version(path, &document)?;
    let base_dir = path.parent().unwrap_or_else(|| Path::new("."));
    check_buffer_views(path, &document)?;
    let buffers = load_buffers(path, base_dir, &document, blob, scene.file_access)?;
    let mut importer = Importer {
        path,
        base_dir,
        document: &document,
        buffers,
        scene,
        materials: HashMap::new(),
        textures: HashMap::new(),
        invisible_texture: None,
        unsupported_maps: 0,
        import: GltfImport::default(),
    };
    importer.import_nodes(transform)?;
    let animations = document.animations().len();
    if animations > 0 {
        importer.warn(format!(
            "{animations} animation(s) ignored (not supported); nodes are placed as the file places them at rest"
        ));
    }
    if importer.unsupported_maps > 0 {
        let count = importer.unsupported_maps;
        importer.warn(format!("{count} normal/occlusion texture(s) ignored (not supported)"));
    }
    Ok(importer.import)
}

/// Splits a `.glb` or parses a `.gltf` without validating it yet.
fn parse(path: &Path, bytes: &[u8]) -> Result<gltf::Gltf, SceneError> {
    let is_glb = bytes.starts_with(b"glTF");
    if is_glb {
        // The gltf crate subtracts the header size from the declared length unchecked.
        let declared = match bytes.get(8..12) {
            Some(&[a, b, c, d]) => u32::from_le_bytes([a, b, c, d]) as usize,
            _ => return Err(SceneError::new(path, "glb", "truncated GLB header")),
        };
        if declared < 12 {
            return Err(SceneError::new(
                path,
                "glb",
                format!("GLB header declares an impossible length of {declared} bytes"),
            ));
        }
        if declared > bytes.len() {
            return Err(SceneError::new(
                path,
                "glb",
                format!("truncated GLB: the header declares {declared} bytes, the file has {}", bytes.len()),
            ));
        }
    }
    gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| {
        let field = if is_glb { "glb" } else { "json" };
        SceneError::new(path, field, format!("cannot parse glTF: {e}"))
    })
}

/// Rejects required extensions we cannot honour and warns about ignored optional ones.
fn check_extensions(path: &Path, document: &gltf::Document, warnings: &mut Vec<String>) -> Result<(), SceneError> {
    if let Some((i, name)) =
        document.extensions_required().enumerate().find(|(_, name)| !SUPPORTED_EXTENSIONS.contains(name))
    {
        return Err(SceneError::new(
            path,
            format!("extensionsRequired[{i}]"),
            format!("required extension {name} is not supported"),
        ));
    }
    for name in document.extensions_used().filter(|name| !SUPPORTED_EXTENSIONS.contains(name)) {
        warnings.push(format!("{}: extension {name} is not supported and is ignored", path.display()));
    }
    Ok(())
}

/// Runs the gltf crate's validation (index ranges, enums, required fields). Its mesh check
/// indexes `accessors` with the `POSITION` index unchecked, so attribute indices are checked
/// here first.
fn validate(path: &Path, document: gltf::Document) -> Result<gltf::Document, SceneError> {
    let json = document.as_json();
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            if let Some(index) = primitive.attributes.values().find(|i| i.value() >= json.accessors.len()) {
                return Err(SceneError::new(
                    path,
                    format!("meshes[{m}].primitives[{p}].attributes"),
                    format!("accessor index {} out of range ({} accessors)", index.value(), json.accessors.len()),
                ));
            }
        }
    }
    gltf::Document::from_json(document.into_json()).map_err(|e| match e {
        gltf::Error::Validation(errors) if !errors.is_empty() => {
            let (field, error) = &errors[0];
            let more = match errors.len() {
                1 => String::new(),
                n => format!(" (and {} more problem(s))", n - 1),
            };
            SceneError::new(path, field.to_string(), format!("invalid glTF: {error}{more}"))
        }
        other => SceneError::new(path, "json", format!("invalid glTF: {other}")),
    })
}

/// Refuses a file whose `asset.version` (or `asset.minVersion`) is not 2.x: a later major
/// version may change what the fields mean (the `gltf` crate parses any version string).
fn check_version(path: &Path, document: &gltf::Document) -> Result<(), SceneError> {
    let asset = &document.as_json().asset;
    let is_2x = |version: &str| {
        version.split_once('.').is_some_and(|(major, minor)| {
            major == "2" && !minor.is_empty() && minor.bytes().all(|b| b.is_ascii_digit())
        })
    };
    if !is_2x(&asset.version) {
        return Err(SceneError::new(
            path,
            "asset.version",
            format!("glTF version {:?} is not supported (this loader reads glTF 2.x)", asset.version),
        ));
    }
    if let Some(min_version) = asset.min_version.as_deref().filter(|v| !is_2x(v)) {
        return Err(SceneError::new(
            path,
            "asset.minVersion",
            format!("glTF minVersion {min_version:?} is not supported (this loader reads glTF 2.x)"),
        ));
    }
    Ok(())
}

/// Refuses a buffer view that does not lie inside its buffer's `byteLength` (the loaded data
/// may be longer than `byteLength`; bytes beyond it are not the buffer's), before any buffer is
/// read.
fn check_buffer_views(path: &Path, document: &gltf::Document) -> Result<(), SceneError> {
    for view in document.views() {
        let buffer = view.buffer();
        let end = view.offset().checked_add(view.length());
        if !end.is_some_and(|end| end <= buffer.length()) {
            return Err(SceneError::new(
                path,
                format!("bufferViews[{}]", view.index()),
                format!(
                    "byteOffset {} + byteLength {} exceeds the byteLength {} of buffers[{}]",
                    view.offset(),
                    view.length(),
                    buffer.length(),
                    buffer.index()
                ),
            ));
        }
    }
    Ok(())
}

/// Loads every buffer: the GLB binary chunk, a base64 `data:` URI or an external file.
fn load_buffers(
    path: &Path,
    base_dir: &Path,
    document: &gltf::Document,
    mut blob: Option<Vec<u8>>,
    access: FileAccess,
) -> Result<Vec<Vec<u8>>, SceneError> {
    document
        .buffers()
        .map(|buffer| {
            let field = format!("buffers[{}]", buffer.index());
            let data = match buffer.source() {
                gltf::buffer::Source::Bin => blob
                    .take()
                    .ok_or_else(|| SceneError::new(path, &field, "refers to the GLB binary chunk, which is missing"))?,
                gltf::buffer::Source::Uri(uri) => read_uri(path, base_dir, uri, &field, access)?,
            };
            if data.len() < buffer.length() {
                return Err(SceneError::new(
                    path,
                    &field,
                    format!("byteLength is {} but only {} bytes are available", buffer.length(), data.len()),
                ));
            }
            Ok(data)
        })
        .collect()
}

/// Reads the bytes a URI names: a base64 `data:` URI, a `file:` URI or a (percent-encoded)
/// path relative to the glTF file's directory, confined as `access` says. Errors name the
/// glTF file `path` and `field` (`buffers[0]`, `images[0].uri`).
fn read_uri(path: &Path, base_dir: &Path, uri: &str, field: &str, access: FileAccess) -> Result<Vec<u8>, SceneError> {
    let error = |message: String| SceneError::new(path, field, message);
    if uri.starts_with("data:") {
        return gltf::buffer::Data::from_source(gltf::buffer::Source::Uri(uri), None)
            .map(|data| data.0)
            .map_err(|e| error(format!("cannot decode data URI: {e}")));
    }
    let file = if let Some(rest) = uri.strip_prefix("file://").or_else(|| uri.strip_prefix("file:")) {
        PathBuf::from(rest)
    } else if uri.contains(':') {
        return Err(error(format!("unsupported URI scheme in '{uri}'")));
    } else {
        let decoded =
            percent_decode(uri).ok_or_else(|| error(format!("URI '{uri}' is not valid percent-encoded UTF-8")))?;
        base_dir.join(decoded)
    };
    super::input::confine(&file, uri, path, field, access)?;
    super::input::read_input(&file, crate::limits::MAX_MODEL_BYTES, path, field)
}

/// Decodes `%XX` escapes (RFC 3986); malformed escapes are kept literally.
fn percent_decode(uri: &str) -> Option<String> {
    let bytes = uri.as_bytes();
    let mut decoded = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let escape = match bytes.get(i..i + 3) {
            Some(&[b'%', hi, lo]) if hi.is_ascii_hexdigit() && lo.is_ascii_hexdigit() => {
                std::str::from_utf8(&[hi, lo]).ok().and_then(|hex| u8::from_str_radix(hex, 16).ok())
            }
            _ => None,
        };
        match escape {
            Some(byte) => {
                decoded.push(byte);
                i += 3;
            }
            None => {
                decoded.push(bytes[i]);
                i += 1;
            }
        }
    }
    String::from_utf8(decoded).ok()
}

/// The `KHR_texture_transform` matrix `T · R · S` acting on (u, v, 1). The rotation turns
/// UVs counter-clockwise by `rotation` radians in the spec's sense: u' = cos·u + sin·v,
/// v' = -sin·u + cos·v (v points down the image, so this is a clockwise turn of the image).
pub fn uv_transform(offset: Vec2, rotation: f32, scale: Vec2) -> Mat3 {
    let (sin, cos) = rotation.sin_cos();
    let translation = Mat3::from_translation(offset);
    let rotation = Mat3::from_cols(Vec3::new(cos, -sin, 0.0), Vec3::new(sin, cos, 0.0), Vec3::Z);
    translation * rotation * Mat3::from_scale(scale)
}

/// A node's local matrix. Quaternions are renormalised (exporters write them rounded).
fn local_matrix(node: &gltf::Node) -> Mat4 {
    match node.transform() {
        gltf::scene::Transform::Matrix { matrix } => Mat4::from_cols_array_2d(&matrix),
        gltf::scene::Transform::Decomposed { translation, rotation, scale } => Mat4::from_scale_rotation_translation(
            Vec3::from(scale),
            Quat::from_array(rotation).normalize(),
            Vec3::from(translation),
        ),
    }
}

/// How a node places its mesh in the world.
struct Placement {
    world: Mat4,
    /// Inverse transpose of the upper 3x3 (for normals).
    normal_matrix: Mat3,
    /// The transform mirrors (negative determinant): triangle winding must be reversed.
    mirrored: bool,
}

impl Placement {
    fn new(world: Mat4) -> Placement {
        let linear = Mat3::from_mat4(world);
        Placement { world, normal_matrix: linear.inverse().transpose(), mirrored: linear.determinant() < 0.0 }
    }
}

/// Vertex and index data of one primitive, already in world space.
struct Geometry {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    uvs: Option<Vec<Vec2>>,
    indices: Vec<[u32; 3]>,
}

/// State of one file's import.
struct Importer<'a> {
    path: &'a Path,
    base_dir: &'a Path,
    document: &'a gltf::Document,
    buffers: Vec<Vec<u8>>,
    scene: &'a mut Scene,
    /// glTF material index → index in `scene.materials`.
    materials: HashMap<usize, u32>,
    /// (glTF image index, sRGB) → index in `scene.textures`.
    textures: HashMap<(usize, bool), u32>,
    /// The 1x1 texture behind masks of materials that are invisible everywhere.
    invisible_texture: Option<u32>,
    /// Normal and occlusion textures met (ignored).
    unsupported_maps: usize,
    import: GltfImport,
}

impl<'a> Importer<'a> {
    fn warn(&mut self, message: String) {
        self.scene.warnings.push(format!("{}: {message}", self.path.display()));
    }

    fn error(&self, field: impl Into<String>, message: impl Into<String>) -> SceneError {
        SceneError::new(self.path, field, message)
    }

    /// Walks the scene's node trees depth-first (pre-order, children in order) with an
    /// explicit stack, so that deep hierarchies cannot overflow the call stack.
    fn import_nodes(&mut self, transform: Mat4) -> Result<(), SceneError> {
        let document = self.document;
        let roots: Vec<gltf::Node<'a>> = match document.default_scene().or_else(|| document.scenes().next()) {
            Some(scene) => scene.nodes().collect(),
            None => {
                let mut is_child = vec![false; document.nodes().len()];
                for child in document.nodes().flat_map(|node| node.children()) {
                    if let Some(flag) = is_child.get_mut(child.index()) {
                        *flag = true;
                    }
                }
                let roots: Vec<_> = document.nodes().filter(|node| !is_child[node.index()]).collect();
                if !roots.is_empty() {
                    self.warn("no scene defined; importing every root node".into());
                }
                roots
            }
        };
        let mut visited = vec![false; document.nodes().len()];
        let mut stack: Vec<(gltf::Node<'a>, Mat4)> = roots.into_iter().rev().map(|node| (node, transform)).collect();
        while let Some((node, parent)) = stack.pop() {
            match visited.get_mut(node.index()) {
                Some(seen) if !*seen => *seen = true,
                _ => {
                    self.warn(format!("node {} is reached twice (a cycle or a shared child); skipped", node.index()));
                    continue;
                }
            }
            let world = parent * local_matrix(&node);
            if let Some(mesh) = node.mesh() {
                if node.skin().is_some() {
                    self.warn(format!(
                        "node {}: skinning is not supported; the mesh is placed by the node transform",
                        node.index()
                    ));
                }
                self.import_mesh(&mesh, &Placement::new(world))?;
            }
            if let Some(light) = node.light() {
                self.import_light(&light, world);
            }
            if let Some(camera) = node.camera() {
                self.import_camera(&camera, world);
            }
            let children: Vec<_> = node.children().collect();
            stack.extend(children.into_iter().rev().map(|child| (child, world)));
        }
        Ok(())
    }

    fn import_mesh(&mut self, mesh: &gltf::Mesh, placement: &Placement) -> Result<(), SceneError> {
        let file_name = self.path.file_name().map(|n| n.to_string_lossy()).unwrap_or_default();
        let mesh_label = match mesh.name() {
            Some(name) => name.to_string(),
            None => format!("meshes[{}]", mesh.index()),
        };
        for primitive in mesh.primitives() {
            let name = format!("{file_name}:{mesh_label}#{}", primitive.index());
            let field = format!("meshes[{}].primitives[{}]", mesh.index(), primitive.index());
            if primitive.mode() != Mode::Triangles {
                self.warn(format!(
                    "mesh '{mesh_label}' primitive {}: mode {:?} is not supported (triangles only); skipped",
                    primitive.index(),
                    primitive.mode()
                ));
                continue;
            }
            if primitive.morph_targets().len() > 0 {
                self.warn(format!("mesh '{mesh_label}': morph targets are not supported; the base shape is used"));
            }
            let geometry = self.read_geometry(&primitive, &field, placement)?;
            let material = self.material_index(&primitive.material())?;
            self.scene.meshes.push(Mesh {
                name,
                positions: geometry.positions,
                normals: geometry.normals,
                uvs: geometry.uvs,
                indices: geometry.indices,
                material,
                ..Mesh::default()
            });
        }
        Ok(())
    }

    fn read_geometry(
        &mut self,
        primitive: &gltf::Primitive,
        field: &str,
        placement: &Placement,
    ) -> Result<Geometry, SceneError> {
        use gltf::Semantic;
        let buffers = &self.buffers;
        let reader = primitive.reader(|buffer| buffers.get(buffer.index()).map(Vec::as_slice));
        let attribute = |semantic: Semantic, name: &str, allowed: &[(DataType, Dimensions)]| {
            let field = format!("{field}.attributes.{name}");
            match primitive.get(&semantic) {
                Some(accessor) => check_accessor(&accessor, allowed, self.document, buffers)
                    .map(|()| Some(accessor.count()))
                    .map_err(|message| SceneError::new(self.path, &field, message)),
                None => Ok(None),
            }
        };
        let unreadable =
            |name: &str| self.error(format!("{field}.attributes.{name}"), "accessor data lies outside its buffer");

        let vertex_count = attribute(Semantic::Positions, "POSITION", &[(DataType::F32, Dimensions::Vec3)])?
            .ok_or_else(|| self.error(format!("{field}.attributes"), "POSITION is missing"))?;
        let positions: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| unreadable("POSITION"))?
            .map(|p| placement.world.transform_point3(Vec3::from(p)))
            .collect();

        let same_count = |name: &str, count: usize| {
            if count == vertex_count {
                Ok(())
            } else {
                Err(self.error(
                    format!("{field}.attributes.{name}"),
                    format!("{count} values for {vertex_count} positions"),
                ))
            }
        };
        let normals = match attribute(Semantic::Normals, "NORMAL", &[(DataType::F32, Dimensions::Vec3)])? {
            Some(count) => {
                same_count("NORMAL", count)?;
                let normals = reader.read_normals().ok_or_else(|| unreadable("NORMAL"))?;
                Some(normals.map(|n| (placement.normal_matrix * Vec3::from(n)).normalize_or_zero()).collect())
            }
            None => None,
        };
        let uv_types =
            [(DataType::F32, Dimensions::Vec2), (DataType::U8, Dimensions::Vec2), (DataType::U16, Dimensions::Vec2)];
        let uvs = match attribute(Semantic::TexCoords(0), "TEXCOORD_0", &uv_types)? {
            Some(count) => {
                same_count("TEXCOORD_0", count)?;
                let uvs = reader.read_tex_coords(0).ok_or_else(|| unreadable("TEXCOORD_0"))?;
                Some(uvs.into_f32().map(Vec2::from).collect())
            }
            None => None,
        };

        let vertex_limit = u32::try_from(vertex_count)
            .map_err(|_| self.error(format!("{field}.attributes.POSITION"), "too many vertices"))?;
        let flat_indices: Vec<u32> = match primitive.indices() {
            Some(accessor) => {
                let index_types = [
                    (DataType::U8, Dimensions::Scalar),
                    (DataType::U16, Dimensions::Scalar),
                    (DataType::U32, Dimensions::Scalar),
                ];
                check_accessor(&accessor, &index_types, self.document, buffers)
                    .map_err(|message| self.error(format!("{field}.indices"), message))?;
                let indices: Vec<u32> = reader
                    .read_indices()
                    .ok_or_else(|| self.error(format!("{field}.indices"), "accessor data lies outside its buffer"))?
                    .into_u32()
                    .collect();
                if let Some((i, &index)) = indices.iter().enumerate().find(|(_, &index)| index >= vertex_limit) {
                    return Err(self.error(
                        format!("{field}.indices"),
                        format!("index {i} is {index}, out of range for {vertex_count} vertices"),
                    ));
                }
                indices
            }
            None => (0..vertex_limit).collect(),
        };
        let triangles = flat_indices.chunks_exact(3);
        let leftover = triangles.remainder().len();
        let indices =
            triangles.map(|t| if placement.mirrored { [t[0], t[2], t[1]] } else { [t[0], t[1], t[2]] }).collect();
        if leftover > 0 {
            self.warn(format!("{field}: {leftover} trailing index/indices do not form a triangle; ignored"));
        }
        Ok(Geometry { positions, normals, uvs, indices })
    }

    /// Index in `scene.materials` of a primitive's material, converting it on first use.
    fn material_index(&mut self, material: &gltf::Material) -> Result<u32, SceneError> {
        let Some(gltf_index) = material.index() else {
            return Ok(0);
        };
        if let Some(&index) = self.materials.get(&gltf_index) {
            return Ok(index);
        }
        let converted = self.convert_material(material, gltf_index)?;
        let index =
            u32::try_from(self.scene.materials.len()).map_err(|_| self.error("materials", "too many materials"))?;
        self.scene.materials.push(converted);
        self.materials.insert(gltf_index, index);
        Ok(index)
    }

    fn convert_material(&mut self, material: &gltf::Material, gltf_index: usize) -> Result<Material, SceneError> {
        let label = match material.name() {
            Some(name) => name.to_string(),
            None => format!("materials[{gltf_index}]"),
        };
        let field = format!("materials[{gltf_index}]");
        let pbr = material.pbr_metallic_roughness();
        let [r, g, b, alpha_factor] = pbr.base_color_factor();
        let base_color_texture = match pbr.base_color_texture() {
            Some(info) => self.texture_ref(&info, true, &format!("{field}.pbrMetallicRoughness.baseColorTexture"))?,
            None => None,
        };
        let metallic_roughness_texture = match pbr.metallic_roughness_texture() {
            Some(info) => {
                self.texture_ref(&info, false, &format!("{field}.pbrMetallicRoughness.metallicRoughnessTexture"))?
            }
            None => None,
        };
        let emission_texture = match material.emissive_texture() {
            Some(info) => self.texture_ref(&info, true, &format!("{field}.emissiveTexture"))?,
            None => None,
        };
        self.unsupported_maps +=
            usize::from(material.normal_texture().is_some()) + usize::from(material.occlusion_texture().is_some());

        let cutoff = match material.alpha_mode() {
            AlphaMode::Opaque => None,
            AlphaMode::Mask => Some(material.alpha_cutoff().unwrap_or(0.5)),
            AlphaMode::Blend => {
                self.warn(format!(
                    "material '{label}': alphaMode BLEND is not supported; treated as MASK with cutoff 0.5"
                ));
                Some(0.5)
            }
        };
        let alpha = match (cutoff, &base_color_texture) {
            (None, _) => None,
            (Some(cutoff), Some(texture)) => {
                Some(AlphaMask { texture: texture.clone(), channel: 3, factor: alpha_factor, cutoff })
            }
            (Some(cutoff), None) if alpha_factor < cutoff => {
                Some(AlphaMask { texture: self.invisible_texture(), channel: 3, factor: alpha_factor, cutoff })
            }
            // Constant coverage at or above the cutoff: opaque everywhere.
            (Some(_), None) => None,
        };

        Ok(Material {
            name: label,
            base_color: Vec3::new(r, g, b),
            base_color_texture,
            metallic: pbr.metallic_factor(),
            roughness: pbr.roughness_factor(),
            metallic_roughness_texture,
            // glTF dielectrics always have the Fresnel-weighted specular layer.
            specular: 1.0,
            ior: 1.5,
            emission: Vec3::from(material.emissive_factor()) * material.emissive_strength().unwrap_or(1.0),
            emission_texture,
            two_sided_emission: material.double_sided(),
            alpha,
        })
    }

    /// A constant white texture; with a factor below the cutoff its mask hides everything.
    fn invisible_texture(&mut self) -> TextureRef {
        let index = *self.invisible_texture.get_or_insert_with(|| {
            self.scene.textures.push(Texture::constant([255; 4], false));
            (self.scene.textures.len() - 1) as u32
        });
        TextureRef::new(index)
    }

    /// Turns a texture reference into a [`TextureRef`], loading the image on first use.
    /// The sampler's wrap modes are kept (`Wrap`); its filter modes are ignored (bilinear with
    /// mipmaps always).
    fn texture_ref(
        &mut self,
        info: &gltf::texture::Info,
        srgb: bool,
        field: &str,
    ) -> Result<Option<TextureRef>, SceneError> {
        let transform = info.texture_transform();
        let set = transform.as_ref().and_then(|t| t.tex_coord()).unwrap_or_else(|| info.tex_coord());
        if set != 0 {
            self.warn(format!("{field}: texture coordinate set {set} is not supported (only 0); texture ignored"));
            return Ok(None);
        }
        let index = self.texture_index(info.texture().source().index(), srgb)?;
        let transform = transform.map(|t| uv_transform(Vec2::from(t.offset()), t.rotation(), Vec2::from(t.scale())));
        let sampler = info.texture().sampler();
        let wrap = |mode: gltf::texture::WrappingMode| match mode {
            gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
            gltf::texture::WrappingMode::ClampToEdge => Wrap::ClampToEdge,
            gltf::texture::WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
        };
        let wrap = [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())];
        Ok(Some(TextureRef::with_transform(index, transform).with_wrap(wrap)))
    }

    /// Index in `scene.textures` of an image decoded as sRGB or linear. Each (image, encoding)
    /// pair is loaded once; an image used both ways becomes two textures.
    fn texture_index(&mut self, image: usize, srgb: bool) -> Result<u32, SceneError> {
        if let Some(&index) = self.textures.get(&(image, srgb)) {
            return Ok(index);
        }
        let texture = match self.textures.get(&(image, !srgb)) {
            Some(&other) => self.scene.textures[other as usize].with_encoding(srgb),
            None => self.decode_image(image, srgb)?,
        };
        let index =
            u32::try_from(self.scene.textures.len()).map_err(|_| self.error("textures", "too many textures"))?;
        self.scene.textures.push(texture);
        self.textures.insert((image, srgb), index);
        Ok(index)
    }

    /// Decodes a PNG or JPEG image from its URI or buffer view (the format is recognised from
    /// the data; `mimeType` is not needed).
    fn decode_image(&self, image: usize, srgb: bool) -> Result<Texture, SceneError> {
        // Read the JSON directly: `gltf::Image::source` unwraps fields that validation does not
        // require (mimeType next to bufferView, uri without bufferView).
        let json = self
            .document
            .as_json()
            .images
            .get(image)
            .ok_or_else(|| self.error(format!("images[{image}]"), "image index out of range"))?;
        let (bytes, field, description): (Cow<[u8]>, String, String) = if let Some(view_index) = json.buffer_view {
            let field = format!("images[{image}].bufferView");
            let view = self
                .document
                .views()
                .nth(view_index.value())
                .ok_or_else(|| self.error(&field, "buffer view index out of range"))?;
            let bytes = view
                .offset()
                .checked_add(view.length())
                .and_then(|end| self.buffers.get(view.buffer().index())?.get(view.offset()..end))
                .ok_or_else(|| self.error(&field, "buffer view lies outside its buffer"))?;
            (Cow::Borrowed(bytes), field, format!("buffer view {}", view_index.value()))
        } else if let Some(uri) = &json.uri {
            let field = format!("images[{image}].uri");
            let bytes = read_uri(self.path, self.base_dir, uri, &field, self.scene.file_access)?;
            let description = if uri.starts_with("data:") { "data URI".to_string() } else { uri.clone() };
            (Cow::Owned(bytes), field, description)
        } else {
            return Err(self.error(format!("images[{image}]"), "has neither uri nor bufferView"));
        };
        let decoded = image::load_from_memory(&bytes)
            .map_err(|e| self.error(&field, format!("cannot decode image ({description}): {e}")))?
            .to_rgba8();
        let name = format!("{}:images[{image}] ({description})", self.path.display());
        Ok(Texture::from_rgba8(name, decoded.width(), decoded.height(), srgb, decoded.into_raw()))
    }

    fn import_light(&mut self, light: &gltf::khr_lights_punctual::Light, world: Mat4) {
        let power = Vec3::from(light.color()) * light.intensity();
        let position = world.transform_point3(Vec3::ZERO);
        // Lights shine along their node's local -Z axis.
        let direction = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
        let light = match light.kind() {
            LightKind::Point => PunctualLight::Point { position, intensity: power },
            LightKind::Spot { inner_cone_angle, outer_cone_angle } => PunctualLight::Spot {
                position,
                direction,
                intensity: power,
                inner_cone: inner_cone_angle,
                outer_cone: outer_cone_angle,
            },
            LightKind::Directional => PunctualLight::Directional { direction, irradiance: power },
        };
        self.scene.lights.push(light);
    }

    /// Keeps every perspective camera (the first is the default); it looks down its node's -Z
    /// with +Y up.
    fn import_camera(&mut self, camera: &gltf::Camera, world: Mat4) {
        use gltf::json::camera::Type;
        // Read the JSON directly: `gltf::Camera::projection` unwraps the projection object
        // matching `type`, which validation does not require.
        let Some(json) = self.document.as_json().cameras.get(camera.index()) else {
            return;
        };
        match (&json.type_, &json.perspective) {
            (Checked::Valid(Type::Perspective), Some(perspective)) => {
                let position = world.transform_point3(Vec3::ZERO);
                let forward = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
                let up = world.transform_vector3(Vec3::Y).normalize_or_zero();
                let camera =
                    Camera::look_at(position, position + forward, up, perspective.yfov.to_degrees(), FovAxis::Y);
                self.import
                    .cameras
                    .push(super::FileCamera { camera: camera.clone(), aspect_ratio: perspective.aspect_ratio });
                if self.import.camera.is_none() {
                    self.import.camera = Some(camera);
                    self.import.aspect_ratio = perspective.aspect_ratio;
                }
            }
            (Checked::Valid(Type::Orthographic), _) => {
                self.warn(format!("camera {}: orthographic cameras are not supported; ignored", camera.index()));
            }
            _ => self.warn(format!("camera {}: no projection matching its type; ignored", camera.index())),
        }
    }
}

/// Checks what the gltf crate's accessor iterators assume without checking (they would
/// panic otherwise): the element type the reader expects, a non-zero count, a stride at least
/// the element size, and byte ranges inside their buffer views and buffers, computed without
/// overflow. Sparse substitutions are checked the same way.
fn check_accessor(
    accessor: &gltf::Accessor,
    allowed: &[(DataType, Dimensions)],
    document: &gltf::Document,
    buffers: &[Vec<u8>],
) -> Result<(), String> {
    let index = accessor.index();
    let kind = (accessor.data_type(), accessor.dimensions());
    if !allowed.contains(&kind) {
        return Err(format!("accessor {index} has type {:?} {:?}, expected one of {allowed:?}", kind.0, kind.1));
    }
    let count = accessor.count();
    if count == 0 {
        return Err(format!("accessor {index} has count 0"));
    }
    let element_size = accessor.size();
    let sparse = document.as_json().accessors.get(index).and_then(|json| json.sparse.as_ref());
    match (accessor.view(), sparse) {
        (Some(view), _) => check_view_range(&view, accessor.offset(), count, element_size, buffers)
            .map_err(|e| format!("accessor {index}: {e}"))?,
        (None, None) => return Err(format!("accessor {index} has neither bufferView nor sparse")),
        (None, Some(_)) if count > MAX_UNBACKED_ACCESSOR_COUNT => {
            return Err(format!("accessor {index}: count {count} is implausibly large"))
        }
        (None, Some(_)) => {}
    }
    if let (Some(json), Some(sparse)) = (sparse, accessor.sparse()) {
        let sparse_count = sparse.count();
        if sparse_count == 0 || sparse_count > count {
            return Err(format!("accessor {index}: sparse count {sparse_count} is not in 1..={count}"));
        }
        let index_size = match json.indices.component_type {
            Checked::Valid(IndexComponentType(ComponentType::U8)) => 1,
            Checked::Valid(IndexComponentType(ComponentType::U16)) => 2,
            Checked::Valid(IndexComponentType(ComponentType::U32)) => 4,
            _ => return Err(format!("accessor {index}: sparse indices must be unsigned integers")),
        };
        let indices = sparse.indices();
        check_view_range(&indices.view(), indices.offset(), sparse_count, index_size, buffers)
            .map_err(|e| format!("accessor {index} sparse indices: {e}"))?;
        // Every substituted element must exist (the ranges above make these reads in bounds).
        let view = indices.view();
        let data = &buffers[view.buffer().index()][view.offset()..view.offset() + view.length()];
        let stride = view.stride().unwrap_or(index_size);
        for k in 0..sparse_count {
            let at = indices.offset() + k * stride;
            let bytes = &data[at..at + index_size];
            let target = bytes.iter().rev().fold(0usize, |value, &byte| value << 8 | usize::from(byte));
            if target >= count {
                return Err(format!(
                    "accessor {index}: sparse index {k} is {target}, outside the accessor's {count} elements"
                ));
            }
        }
        let values = sparse.values();
        check_view_range(&values.view(), values.offset(), sparse_count, element_size, buffers)
            .map_err(|e| format!("accessor {index} sparse values: {e}"))?;
    }
    Ok(())
}

/// Checks that `count` elements of `element_size` bytes starting at `offset` in `view` (with
/// its stride) lie inside the view, and the view inside its loaded buffer.
fn check_view_range(
    view: &gltf::buffer::View,
    offset: usize,
    count: usize,
    element_size: usize,
    buffers: &[Vec<u8>],
) -> Result<(), String> {
    let stride = view.stride().unwrap_or(element_size);
    if stride < element_size {
        return Err(format!("byteStride {stride} is smaller than the element size {element_size}"));
    }
    let end =
        stride.checked_mul(count - 1).and_then(|n| n.checked_add(element_size)).and_then(|n| n.checked_add(offset));
    if !end.is_some_and(|end| end <= view.length()) {
        return Err(format!("{count} elements at offset {offset} do not fit in buffer view {}", view.index()));
    }
    let buffer_len = buffers.get(view.buffer().index()).map_or(0, Vec::len);
    if !view.offset().checked_add(view.length()).is_some_and(|end| end <= buffer_len) {
        return Err(format!("buffer view {} lies outside buffer {}", view.index(), view.buffer().index()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
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
        assert!(
            matches!(scene.lights[0], PunctualLight::Point { position, .. } if position == Vec3::new(1.0, 4.0, 0.0))
        );
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
        let moving =
            format!(r#"{{ {geometry}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}], {animation} }}"#);
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
            format!(
                r#"{{ {}, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}] }}"#,
                geometry_json(&buffer, &[""])
            )
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
        for version in [r#"{"version": "2.0"}"#, r#"{"version": "2.1"}"#, r#"{"version": "2.0", "minVersion": "2.0"}"#]
        {
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
}
