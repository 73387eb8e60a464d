//! The in-memory scene: meshes, materials, textures, lights, camera and render settings.
//!
//! Every loader (TOML description, OBJ, glTF) produces these types; the accelerator
//! (`accel`), the light sampler (`lights`) and the integrator read them. All geometry is in
//! world space: node hierarchies and per-mesh transforms are flattened at load time (Debian's
//! Embree allows one instance level only, and a flat scene is the fastest to trace anyway).

pub mod description;
pub mod gltf;
pub mod input;
pub mod obj;
pub mod ply;
pub mod shapes;
pub mod tangents;

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3, Vec4};

use crate::camera::Camera;
use crate::error::SceneError;
use crate::texture::{Texture, TextureRef};

/// A triangle mesh in world space with one material.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Name for messages (file and object name).
    pub name: String,
    /// World-space vertex positions at shutter open.
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (world space, unit length), if the source had them.
    pub normals: Option<Vec<Vec3>>,
    /// Per-vertex texture coordinates.
    pub uvs: Option<Vec<Vec2>>,
    /// Per-vertex tangents for normal mapping (world space): `xyz` the unit direction of
    /// increasing u, `w` = ±1 the handedness, glTF's convention (bitangent = w · normal × xyz,
    /// pointing towards decreasing v, "up" in the normal map). From the file (glTF `TANGENT`)
    /// or generated with MikkTSpace by [`Scene::validate`] for meshes whose material has a
    /// normal map ([`tangents`]).
    pub tangents: Option<Vec<Vec4>>,
    /// Triangles as indices into the vertex arrays.
    pub indices: Vec<[u32; 3]>,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// World-space translation of the whole mesh from shutter open to shutter close
    /// (linear motion). Zero for static meshes.
    pub motion: Vec3,
    /// Set by [`shapes::sphere`]: the mesh is a closed, convex icosphere whose vertices lie on
    /// this sphere, which lets the light sampler sample it by solid angle. Cleared by a
    /// transform; ignored when the mesh no longer has the triangle count it was made with.
    pub sphere: Option<SphereShape>,
}

/// The sphere a tessellated sphere mesh is inscribed in (see [`Mesh::sphere`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SphereShape {
    pub center: Vec3,
    pub radius: f32,
    /// The mesh's triangle count when it was made (a removed triangle leaves a hole).
    pub triangles: usize,
}

impl Mesh {
    pub fn is_moving(&self) -> bool {
        self.motion != Vec3::ZERO
    }

    /// Area of triangle `i` at shutter open.
    pub fn triangle_area(&self, i: usize) -> f32 {
        let [a, b, c] = self.indices[i];
        let (a, b, c) = (self.positions[a as usize], self.positions[b as usize], self.positions[c as usize]);
        shading::triangle_normal_and_area(a, b, c).1
    }
}

/// Where a material's alpha (cut-out) comes from.
#[derive(Clone, Debug)]
pub struct AlphaMask {
    /// Texture holding the coverage.
    pub texture: TextureRef,
    /// Channel of the texture read as coverage (3 = alpha, 0 = red/grey).
    pub channel: usize,
    /// Multiplier applied to the texture value (glTF base colour factor alpha).
    pub factor: f32,
    /// A hit is kept where coverage >= cutoff.
    pub cutoff: f32,
}

/// A tangent-space normal map (glTF `normalTexture`, OBJ `map_Bump`/`bump`/`norm`): texels
/// (r, g, b) in [0, 1] encode the normal (2r − 1, 2g − 1, 2b − 1) in the frame (tangent,
/// bitangent, normal) of [`Mesh::tangents`], x and y multiplied by `scale`.
#[derive(Clone, Debug)]
pub struct NormalMap {
    /// Linear (not sRGB) texture.
    pub texture: TextureRef,
    pub scale: f32,
}

/// The metallic-roughness material model (glTF 2.0), used for every source format.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    /// Linear base colour factor.
    pub base_color: Vec3,
    /// Multiplied into `base_color`; sRGB-encoded texels are decoded to linear on lookup.
    pub base_color_texture: Option<TextureRef>,
    pub metallic: f32,
    /// Perceptual roughness in [0, 1]; the GGX alpha is its square.
    pub roughness: f32,
    /// glTF metallicRoughness texture: roughness in green, metallic in blue.
    pub metallic_roughness_texture: Option<TextureRef>,
    /// Dielectric specular weight: 1 for glTF and glossy OBJ materials, 0 for a pure Lambertian
    /// surface (OBJ without Ks, the Cornell box walls).
    pub specular: f32,
    /// Index of refraction of the dielectric coat: F0 = ((ior − 1)/(ior + 1))², 1.5 → 0.04.
    pub ior: f32,
    /// Emitted radiance (linear RGB), already multiplied by any emissive strength.
    pub emission: Vec3,
    pub emission_texture: Option<TextureRef>,
    /// Emit from both faces; otherwise only from the front face (counter-clockwise winding).
    pub two_sided_emission: bool,
    pub alpha: Option<AlphaMask>,
    /// Perturbs the shading normal where the mesh has texture coordinates.
    pub normal_map: Option<NormalMap>,
    /// Seen from both sides (the default). A single-sided material (glTF `doubleSided: false`)
    /// is invisible from behind: every ray (camera, bounce, shadow) passes through its back
    /// faces ([`crate::accel`]), as glTF's back-face culling says.
    pub double_sided: bool,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            name: "default".into(),
            base_color: Vec3::splat(0.8),
            base_color_texture: None,
            metallic: 0.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            specular: 1.0,
            ior: 1.5,
            emission: Vec3::ZERO,
            emission_texture: None,
            two_sided_emission: false,
            alpha: None,
            normal_map: None,
            double_sided: true,
        }
    }
}

impl Material {
    pub fn is_emissive(&self) -> bool {
        self.emission.max_element() > 0.0
    }
}

/// Lights that are not geometry.
#[derive(Clone, Debug, PartialEq)]
pub enum PunctualLight {
    /// Radiant intensity `intensity` (W/sr per RGB channel) in every direction.
    Point { position: Vec3, intensity: Vec3 },
    /// A point light restricted to a cone with a smooth falloff between the inner and outer
    /// cone angles (radians), as in `KHR_lights_punctual`.
    Spot { position: Vec3, direction: Vec3, intensity: Vec3, inner_cone: f32, outer_cone: f32 },
    /// Light from infinitely far away travelling along `direction`; `irradiance` is the
    /// irradiance on a surface facing the light.
    Directional { direction: Vec3, irradiance: Vec3 },
}

/// A camera that a scene file defines (glTF), with the aspect ratio it asks for.
#[derive(Clone, Debug, PartialEq)]
pub struct FileCamera {
    pub camera: Camera,
    pub aspect_ratio: Option<f32>,
}

/// The default lighting of a scene without any emitter (docs/scene-format.md, "Default
/// lighting"): a neutral constant environment of this radiance ...
pub const DEFAULT_ENVIRONMENT: f32 = 0.25;
/// ... and a sun of this irradiance (on a surface facing it) ...
pub const DEFAULT_SUN_IRRADIANCE: f32 = 2.5;

/// ... shining from above, behind the camera and to its left: the direction towards the sun is
/// camera up + 1/2 backwards + 1/2 left, so what the camera sees is lit from the front with
/// shadows falling to the right, away from the viewer, whatever the file's orientation.
pub fn default_sun_direction(camera: &Camera) -> Vec3 {
    (camera.up - 0.5 * camera.forward - 0.5 * camera.right).normalize()
}

/// Everything the tracer needs to render.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The file the scene came from (for messages), or `<builtin>`.
    pub source: PathBuf,
    pub meshes: Vec<Mesh>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub lights: Vec<PunctualLight>,
    pub camera: Camera,
    /// Radiance of rays that leave the scene.
    pub environment: Vec3,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel when the command line does not say.
    pub spp: u32,
    /// Maximum path length in bounces when the command line does not say.
    pub max_bounces: u32,
    /// Warnings collected while loading (unsupported features skipped, degenerate triangles).
    pub warnings: Vec<String>,
    /// Which files the loaders may read for references inside scene files.
    pub file_access: input::FileAccess,
    /// The cameras that the scene's glTF files define, in file order (`--camera N`).
    pub file_cameras: Vec<FileCamera>,
}

/// The file extensions `Scene::load` reads (lower case), and how its errors list them.
const SCENE_EXTENSIONS: [&str; 5] = ["toml", "gltf", "glb", "obj", "ply"];
const SCENE_FORMATS: &str = ".toml, .gltf, .glb, .obj or .ply";

/// The names of the scene files directly inside `dir` (by extension), sorted, at most five.
fn scene_files_in(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Vec::new() };
    let mut names: Vec<String> = entries
        .filter_map(|entry| entry.ok())
        .map(|entry| entry.path())
        .filter(|p| {
            let ext = p.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
            p.is_file() && ext.is_some_and(|ext| SCENE_EXTENSIONS.contains(&ext.as_str()))
        })
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect();
    names.sort();
    names.truncate(5);
    names
}

impl Scene {
    /// An empty scene with a default camera.
    pub fn empty(source: impl Into<PathBuf>) -> Scene {
        Scene {
            source: source.into(),
            meshes: Vec::new(),
            materials: vec![Material::default()],
            textures: Vec::new(),
            lights: Vec::new(),
            camera: Camera::default(),
            environment: Vec3::ZERO,
            width: 256,
            height: 256,
            spp: 16,
            max_bounces: 64,
            warnings: Vec::new(),
            file_access: input::FileAccess::Confined,
            file_cameras: Vec::new(),
        }
    }

    /// Whether anything in the scene emits light: an emissive material on some mesh, a
    /// punctual light of non-zero colour, or a non-black environment.
    pub fn has_emitter(&self) -> bool {
        let emissive_mesh =
            self.meshes.iter().any(|m| self.materials.get(m.material as usize).is_some_and(Material::is_emissive));
        emissive_mesh || self.has_light_or_environment()
    }

    /// Adds a sun: directional light from `towards_sun` (the direction from the scene to the
    /// sun, any length) with `irradiance` on a surface facing it.
    pub fn add_sun(&mut self, towards_sun: Vec3, irradiance: Vec3) {
        self.lights.push(PunctualLight::Directional { direction: -towards_sun.normalize(), irradiance });
    }

    /// Whether the scene is a bare model file given directly (`.gltf`, `.glb`, `.obj`, `.ply`),
    /// not a TOML description (which is rendered exactly as authored) nor the embedded scene.
    pub fn is_bare_model(&self) -> bool {
        let ext = self.source.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        matches!(ext.as_str(), "gltf" | "glb" | "obj" | "ply")
    }

    /// Whether the scene lights itself: a punctual light of non-zero colour or a non-black
    /// environment (emissive surfaces not counted).
    pub fn has_light_or_environment(&self) -> bool {
        let light = self.lights.iter().any(|l| match l {
            PunctualLight::Point { intensity, .. } | PunctualLight::Spot { intensity, .. } => {
                intensity.max_element() > 0.0
            }
            PunctualLight::Directional { irradiance, .. } => irradiance.max_element() > 0.0,
        });
        light || self.environment.max_element() > 0.0
    }

    /// Whether [`Scene::apply_default_lighting`] lights this scene: a bare model file without
    /// a punctual light or an environment, even when it has emissive surfaces (glTF viewers
    /// light every model with an environment; a DamagedHelmet lit by its emissive panel alone
    /// renders at mean radiance 0.002), and any scene without an emitter at all. A TOML scene
    /// with an emitter stays as authored.
    pub fn needs_default_lighting(&self) -> bool {
        if self.is_bare_model() {
            !self.has_light_or_environment()
        } else {
            !self.has_emitter()
        }
    }

    /// Gives a scene that [`Scene::needs_default_lighting`] the default lighting
    /// ([`DEFAULT_ENVIRONMENT`], [`DEFAULT_SUN_IRRADIANCE`], [`default_sun_direction`] of the
    /// current camera); returns whether it did.
    pub fn apply_default_lighting(&mut self) -> bool {
        if !self.needs_default_lighting() {
            return false;
        }
        self.environment = Vec3::splat(DEFAULT_ENVIRONMENT);
        self.add_sun(default_sun_direction(&self.camera), Vec3::splat(DEFAULT_SUN_IRRADIANCE));
        true
    }

    /// Makes the file's camera `index` (0-based, in [`Scene::file_cameras`]) the scene's camera;
    /// for a glTF scene its aspect ratio sets the width, as for the first camera at loading.
    pub fn select_file_camera(&mut self, index: usize) -> Result<(), String> {
        let Some(chosen) = self.file_cameras.get(index).cloned() else {
            return Err(match self.file_cameras.len() {
                0 => format!("the scene defines no cameras, so there is no camera {index}"),
                n => format!(
                    "the scene defines {n} camera{} (0 to {}), not {index}",
                    if n == 1 { "" } else { "s" },
                    n - 1
                ),
            });
        };
        self.camera = chosen.camera;
        let ext = self.source.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        if matches!(ext.as_str(), "gltf" | "glb") {
            if let Some(aspect) = chosen.aspect_ratio.filter(|a| a.is_finite() && *a > 0.0) {
                self.width = ((self.height as f32 * aspect).round() as u32).max(1);
            }
        }
        Ok(())
    }

    /// Loads a scene from a TOML description, a glTF, OBJ or PLY file (by extension); its
    /// file references are confined ([`input::FileAccess::Confined`]).
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Scene::load_with_access(path, input::FileAccess::Confined)
    }

    /// [`Scene::load`] with file references allowed as `access` says.
    pub fn load_with_access(path: &Path, access: input::FileAccess) -> Result<Scene, SceneError> {
        let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).unwrap_or_default();
        let mut scene = match ext.as_str() {
            "toml" => description::load_with_access(path, access)?,
            "gltf" | "glb" => {
                let mut scene = Scene::empty(path);
                scene.file_access = access;
                let imported = gltf::load(path, &mut scene)?;
                if let Some(aspect) = imported.aspect_ratio.filter(|a| a.is_finite() && *a > 0.0) {
                    scene.width = ((scene.height as f32 * aspect).round() as u32).max(1);
                }
                scene.camera = match imported.camera {
                    Some(camera) => camera,
                    None => Camera::framing(&scene.bounds(), scene.aspect()),
                };
                scene.file_cameras = imported.cameras;
                scene
            }
            "obj" => {
                let mut scene = Scene::empty(path);
                scene.file_access = access;
                obj::load(path, &mut scene, &obj::ObjOptions::default())?;
                scene.camera = Camera::framing(&scene.bounds(), scene.aspect());
                scene
            }
            "ply" => {
                let mut scene = Scene::empty(path);
                scene.file_access = access;
                ply::load(path, &mut scene, &ply::PlyOptions::default())?;
                scene.camera = Camera::framing(&scene.bounds(), scene.aspect());
                scene
            }
            _ if path.is_dir() => {
                let found = scene_files_in(path);
                let hint = if found.is_empty() {
                    "none is directly inside it".to_string()
                } else {
                    format!("inside it: {}", found.join(", "))
                };
                return Err(SceneError::new(
                    path,
                    "path",
                    format!("a directory: name a scene file ({SCENE_FORMATS}); {hint}"),
                ));
            }
            _ => {
                return Err(SceneError::new(
                    path,
                    "extension",
                    format!("unknown scene format (expected {SCENE_FORMATS})"),
                ))
            }
        };
        scene.validate()?;
        Ok(scene)
    }

    pub fn aspect(&self) -> f32 {
        self.width as f32 / self.height.max(1) as f32
    }

    /// World-space bounds of all geometry over the whole shutter (min, max).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for mesh in &self.meshes {
            for &p in &mesh.positions {
                lo = lo.min(p).min(p + mesh.motion);
                hi = hi.max(p).max(p + mesh.motion);
            }
        }
        if lo.x > hi.x {
            (Vec3::ZERO, Vec3::ZERO)
        } else {
            (lo, hi)
        }
    }

    /// Whether any mesh moves during the shutter.
    pub fn has_motion(&self) -> bool {
        self.meshes.iter().any(Mesh::is_moving)
    }

    /// Checks the invariants the tracer relies on; removes degenerate triangles with a
    /// warning, rejects non-finite data with an error naming the field.
    pub fn validate(&mut self) -> Result<(), SceneError> {
        let source = self.source.clone();
        if self.width == 0 || self.height == 0 {
            return Err(SceneError::new(&source, "resolution", "width and height must be at least 1"));
        }
        if self.width > crate::limits::MAX_IMAGE_SIDE || self.height > crate::limits::MAX_IMAGE_SIDE {
            return Err(SceneError::new(&source, "resolution", "width and height must be at most 32768"));
        }
        if !self.environment.is_finite() || self.environment.min_element() < 0.0 {
            return Err(SceneError::new(&source, "environment", "must be finite and non-negative"));
        }
        for (i, m) in self.materials.iter().enumerate() {
            let field = |f: &str| format!("material[{i}] '{}'.{f}", m.name);
            if !m.base_color.is_finite() || m.base_color.min_element() < 0.0 {
                return Err(SceneError::new(&source, field("base_color"), "must be finite and non-negative"));
            }
            if !(0.0..=1.0).contains(&m.metallic) {
                return Err(SceneError::new(&source, field("metallic"), "must be in [0, 1]"));
            }
            if !(0.0..=1.0).contains(&m.roughness) {
                return Err(SceneError::new(&source, field("roughness"), "must be in [0, 1]"));
            }
            if !(0.0..=1.0).contains(&m.specular) {
                return Err(SceneError::new(&source, field("specular"), "must be in [0, 1]"));
            }
            if !(m.ior >= 1.0 && m.ior.is_finite()) {
                return Err(SceneError::new(&source, field("ior"), "must be finite and >= 1"));
            }
            if !m.emission.is_finite() || m.emission.min_element() < 0.0 {
                return Err(SceneError::new(&source, field("emission"), "must be finite and non-negative"));
            }
            if let Some(map) = &m.normal_map {
                if !map.scale.is_finite() {
                    return Err(SceneError::new(&source, field("normalTexture.scale"), "must be finite"));
                }
            }
            for t in [&m.base_color_texture, &m.metallic_roughness_texture, &m.emission_texture]
                .into_iter()
                .flatten()
                .chain(m.alpha.as_ref().map(|a| &a.texture))
                .chain(m.normal_map.as_ref().map(|n| &n.texture))
            {
                if t.index as usize >= self.textures.len() {
                    return Err(SceneError::new(&source, field("texture"), "texture index out of range"));
                }
            }
            // The factor times the texture's brightest texel, per channel: above 1 the surface
            // reflects more light than it receives (allowed, but rarely meant).
            let texture_peak =
                m.base_color_texture.as_ref().map_or(Vec3::ONE, |t| self.textures[t.index as usize].max_rgb());
            let peak = m.base_color * texture_peak;
            if peak.max_element() > 1.0 {
                let texture = if m.base_color_texture.is_some() { " times its texture" } else { "" };
                self.warnings.push(format!(
                    "{}: {}: the base colour{texture} reaches {:?} (above 1: the material reflects more light than \
                     it receives and adds energy to the image)",
                    source.display(),
                    field("base_color"),
                    peak.to_array()
                ));
            }
        }
        for (i, light) in self.lights.iter().enumerate() {
            let ok = match light {
                PunctualLight::Point { position, intensity } => {
                    position.is_finite() && intensity.is_finite() && intensity.min_element() >= 0.0
                }
                PunctualLight::Spot { position, direction, intensity, inner_cone, outer_cone } => {
                    position.is_finite()
                        && direction.is_finite()
                        && direction.length_squared() > 0.0
                        && intensity.is_finite()
                        && intensity.min_element() >= 0.0
                        && inner_cone.is_finite()
                        && outer_cone.is_finite()
                        && *inner_cone >= 0.0
                        && inner_cone <= outer_cone
                }
                PunctualLight::Directional { direction, irradiance } => {
                    direction.is_finite()
                        && direction.length_squared() > 0.0
                        && irradiance.is_finite()
                        && irradiance.min_element() >= 0.0
                }
            };
            if !ok {
                return Err(SceneError::new(
                    &source,
                    format!("light[{i}]"),
                    "non-finite, negative or degenerate light parameters",
                ));
            }
        }
        let mut degenerate = 0usize;
        for mesh in &mut self.meshes {
            if mesh.material as usize >= self.materials.len() {
                return Err(SceneError::new(
                    &source,
                    format!("mesh '{}'.material", mesh.name),
                    "material index out of range",
                ));
            }
            if let Some(i) = mesh.positions.iter().position(|p| !p.is_finite()) {
                return Err(SceneError::new(
                    &source,
                    format!("mesh '{}'.positions[{i}]", mesh.name),
                    "vertex position is NaN or infinite",
                ));
            }
            if !mesh.motion.is_finite() {
                return Err(SceneError::new(&source, format!("mesh '{}'.motion", mesh.name), "must be finite"));
            }
            let n = mesh.positions.len() as u32;
            if let Some(t) = mesh.indices.iter().position(|t| t.iter().any(|&v| v >= n)) {
                return Err(SceneError::new(
                    &source,
                    format!("mesh '{}'.indices[{t}]", mesh.name),
                    "vertex index out of range",
                ));
            }
            if let Some(normals) = &mut mesh.normals {
                if normals.len() != mesh.positions.len() {
                    return Err(SceneError::new(
                        &source,
                        format!("mesh '{}'.normals", mesh.name),
                        "count differs from positions",
                    ));
                }
                // Non-finite or zero normals fall back to the geometric normal at shading time.
                for nrm in normals.iter_mut() {
                    let len = nrm.length();
                    *nrm = if len.is_finite() && len > 0.0 { *nrm / len } else { Vec3::ZERO };
                }
            }
            if let Some(uvs) = &mut mesh.uvs {
                if uvs.len() != mesh.positions.len() {
                    return Err(SceneError::new(
                        &source,
                        format!("mesh '{}'.uvs", mesh.name),
                        "count differs from positions",
                    ));
                }
                for uv in uvs.iter_mut() {
                    if !uv.is_finite() {
                        *uv = Vec2::ZERO;
                    }
                }
            }
            if let Some(tangents) = &mut mesh.tangents {
                if tangents.len() != mesh.positions.len() {
                    return Err(SceneError::new(
                        &source,
                        format!("mesh '{}'.tangents", mesh.name),
                        "count differs from positions",
                    ));
                }
                // Unusable tangents are zero: the shading point then keeps its unmapped normal.
                for t in tangents.iter_mut() {
                    let len = t.truncate().length();
                    *t = if len.is_finite() && len > 0.0 && t.w.is_finite() {
                        (t.truncate() / len).extend(if t.w < 0.0 { -1.0 } else { 1.0 })
                    } else {
                        Vec4::ZERO
                    };
                }
            }
            let before = mesh.indices.len();
            let positions = &mesh.positions;
            mesh.indices.retain(|&[a, b, c]| {
                let (a, b, c) = (positions[a as usize], positions[b as usize], positions[c as usize]);
                shading::triangle_normal_and_area(a, b, c).1 > 0.0
            });
            degenerate += before - mesh.indices.len();
        }
        self.meshes.retain(|m| !m.indices.is_empty());
        self.prepare_normal_maps();
        // After the meshes: a camera framed around NaN geometry is a symptom, not the cause.
        self.camera.validate(&source)?;
        if degenerate > 0 {
            self.warnings.push(format!("removed {degenerate} degenerate (zero-area) triangles"));
        }
        Ok(())
    }
}

impl Scene {
    /// Gives every mesh whose material has a normal map what the map needs: normals (from the
    /// faces, creased at 60°, where the file has none) and tangents (MikkTSpace where the file
    /// has none). A mesh without texture coordinates cannot use its map: a warning, and the
    /// tracer shades it with its unmapped normals.
    fn prepare_normal_maps(&mut self) {
        let source = self.source.display().to_string();
        for mesh in &mut self.meshes {
            let material = &self.materials[mesh.material as usize];
            if material.normal_map.is_none() {
                continue;
            }
            if mesh.uvs.is_none() {
                self.warnings.push(format!(
                    "{source}: mesh '{}': material '{}' has a normal map but the mesh has no texture coordinates; \
                     the map is not used there",
                    mesh.name, material.name
                ));
                continue;
            }
            if mesh.normals.is_none() {
                // Tangents given without normals belong to no frame; generated again below.
                mesh.tangents = None;
                shapes::compute_normals(mesh, 60.0);
            }
            if mesh.tangents.is_none() && !tangents::generate(mesh) {
                self.warnings.push(format!(
                    "{source}: mesh '{}': MikkTSpace could not generate tangents; its normal map is not used",
                    mesh.name
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A directory given as the scene is named as one, with the scene files inside it (not
    /// other files) as the hint; an empty one says so.
    #[test]
    fn a_directory_is_refused_naming_the_scene_files_inside() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["notes.txt", "bunny.OBJ", "a.toml", "textures"] {
            if name.contains('.') {
                std::fs::write(dir.path().join(name), b"").unwrap();
            } else {
                std::fs::create_dir(dir.path().join(name)).unwrap();
            }
        }
        let error = Scene::load(dir.path()).unwrap_err();
        assert_eq!(error.field, "path");
        assert!(error.message.contains("a directory") && error.message.contains("a.toml, bunny.OBJ"), "{error}");
        assert!(!error.message.contains("notes.txt") && !error.message.contains("textures"), "{error}");
        let empty = tempfile::tempdir().unwrap();
        let error = Scene::load(empty.path()).unwrap_err();
        assert!(error.message.contains("none is directly inside it"), "{error}");
    }

    /// The warnings about energy-gaining base colours of a scene with `materials`
    /// (factor, texture RGBA8 if any) after validation.
    fn energy_warnings(materials: &[(&str, Vec3, Option<[u8; 4]>)]) -> Vec<String> {
        let mut scene = Scene::empty("scene.toml");
        for (name, base_color, texel) in materials {
            let base_color_texture = texel.map(|texel| {
                scene.textures.push(Texture::constant(texel, true));
                TextureRef::new(scene.textures.len() as u32 - 1)
            });
            let material =
                Material { name: name.to_string(), base_color: *base_color, base_color_texture, ..Material::default() };
            scene.materials.push(material);
        }
        scene.validate().unwrap();
        scene.warnings.into_iter().filter(|w| w.contains("base colour")).collect()
    }

    #[test]
    fn energy_gaining_base_colours_are_named_in_a_warning() {
        // Factors at most 1, or a factor above 1 over a texture dark enough (sRGB 128 is 0.216).
        let quiet = [
            ("white", Vec3::ONE, None),
            ("grey", Vec3::splat(0.5), Some([255, 255, 255, 255])),
            ("boosted", Vec3::splat(4.0), Some([128, 128, 128, 255])),
        ];
        assert!(energy_warnings(&quiet).is_empty(), "{:?}", energy_warnings(&quiet));
        let loud = [("hot", Vec3::new(0.5, 1.5, 0.5), None), ("bright", Vec3::splat(1.2), Some([255, 10, 10, 255]))];
        let warnings = energy_warnings(&loud);
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(warnings[0].starts_with("scene.toml: material[1] 'hot'.base_color: "), "{}", warnings[0]);
        assert!(warnings[0].contains("[0.5, 1.5, 0.5]"), "{}", warnings[0]);
        assert!(warnings[1].contains("material[2] 'bright'.base_color") && warnings[1].contains("times its texture"));
        assert!(warnings[1].contains("[1.2,"), "only the red channel's texel is white: {}", warnings[1]);
    }
}
