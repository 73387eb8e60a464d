//! The TOML scene description: what OBJ and glTF lack (camera with lens and shutter, motion,
//! extra lights, environment, render settings, material overrides). The format is documented
//! with examples in `docs/scene-format.md`.
//!
//! File paths are relative to the description file. A path starting with `@shared/` is resolved
//! in the third-party scene folder: `$LFR_SCENES` when set, else `../shared/scenes` beside the
//! project (the description's folder `../../shared/scenes` for files in `scenes/`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec3};
use serde::Deserialize;

use super::input::{confine, FileAccess};
use super::obj::ObjOptions;
use super::shapes;
use super::{Material, PunctualLight, Scene};
use crate::camera::{Camera, FovAxis};
use crate::error::SceneError;
use crate::texture::TextureRef;

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct Description {
    #[serde(default)]
    render: RenderDesc,
    camera: Option<CameraDesc>,
    #[serde(default, rename = "material")]
    materials: Vec<MaterialDesc>,
    #[serde(default, rename = "mesh")]
    meshes: Vec<MeshDesc>,
    #[serde(default, rename = "light")]
    lights: Vec<LightDesc>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderDesc {
    #[serde(default = "default_width")]
    width: u32,
    #[serde(default = "default_height")]
    height: u32,
    #[serde(default = "default_spp")]
    spp: u32,
    #[serde(default = "default_bounces")]
    max_bounces: u32,
    #[serde(default)]
    environment: [f32; 3],
}

fn default_width() -> u32 {
    256
}
fn default_height() -> u32 {
    256
}
fn default_spp() -> u32 {
    16
}
fn default_bounces() -> u32 {
    64
}

impl Default for RenderDesc {
    fn default() -> Self {
        RenderDesc {
            width: default_width(),
            height: default_height(),
            spp: default_spp(),
            max_bounces: default_bounces(),
            environment: [0.0; 3],
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraDesc {
    position: [f32; 3],
    look_at: [f32; 3],
    #[serde(default = "default_up")]
    up: [f32; 3],
    /// Full field of view in degrees.
    fov: f32,
    #[serde(default)]
    fov_axis: FovAxis,
    #[serde(default)]
    aperture_radius: f32,
    /// Defaults to the distance to `look_at`.
    focus_distance: Option<f32>,
    #[serde(default = "default_shutter")]
    shutter: [f32; 2],
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}
fn default_shutter() -> [f32; 2] {
    [0.0, 1.0]
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialDesc {
    name: String,
    #[serde(default = "default_base")]
    base_color: [f32; 3],
    base_color_texture: Option<String>,
    #[serde(default)]
    metallic: f32,
    #[serde(default = "one")]
    roughness: f32,
    /// Dielectric specular weight; 0 = pure Lambertian.
    #[serde(default = "one")]
    specular: f32,
    /// Index of refraction of the dielectric coat (1.5 gives F0 = 0.04).
    #[serde(default = "default_ior")]
    ior: f32,
    #[serde(default)]
    emission: [f32; 3],
    #[serde(default)]
    two_sided_emission: bool,
}

fn default_base() -> [f32; 3] {
    [0.8, 0.8, 0.8]
}
fn default_ior() -> f32 {
    1.5
}
fn one() -> f32 {
    1.0
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct TransformDesc {
    #[serde(default)]
    translate: Option<[f32; 3]>,
    /// Uniform or per-axis scale.
    #[serde(default)]
    scale: Option<ScaleDesc>,
    /// Rotation about an axis: [x, y, z, degrees].
    #[serde(default)]
    rotate: Option<[f32; 4]>,
    /// A full 4x4 matrix, row-major; applied after scale, rotate and translate are ignored.
    #[serde(default)]
    matrix: Option<[[f32; 4]; 4]>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum ScaleDesc {
    Uniform(f32),
    Axes([f32; 3]),
}

impl TransformDesc {
    /// The transform, or the name of the key that makes it impossible (`Err((key, why))`): a
    /// rotation about a zero or non-finite axis, a matrix whose last row is not [0, 0, 0, 1]
    /// (projective transforms are not supported).
    fn matrix(&self) -> Result<Mat4, (&'static str, String)> {
        if let Some(m) = self.matrix {
            if m[3] != [0.0, 0.0, 0.0, 1.0] {
                return Err(("matrix", format!("the last row must be [0, 0, 0, 1], got {:?}", m[3])));
            }
            return Ok(Mat4::from_cols_array_2d(&m).transpose());
        }
        let scale = match self.scale {
            None => Vec3::ONE,
            Some(ScaleDesc::Uniform(s)) => Vec3::splat(s),
            Some(ScaleDesc::Axes(a)) => Vec3::from(a),
        };
        let rotation = match self.rotate {
            None => Quat::IDENTITY,
            Some([x, y, z, deg]) => {
                let axis = Vec3::new(x, y, z).normalize_or_zero();
                if axis == Vec3::ZERO || !deg.is_finite() {
                    return Err((
                        "rotate",
                        format!("needs a non-zero, finite axis and angle, got {:?}", [x, y, z, deg]),
                    ));
                }
                Quat::from_axis_angle(axis, deg.to_radians())
            }
        };
        Ok(Mat4::from_scale_rotation_translation(scale, rotation, Vec3::from(self.translate.unwrap_or([0.0; 3]))))
    }
}

fn default_subdivisions() -> u32 {
    4
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshDesc {
    /// An OBJ, glTF or GLB file.
    file: Option<String>,
    /// An inline shape when there is no file.
    shape: Option<String>,
    points: Option<Vec<[f32; 3]>>,
    min: Option<[f32; 3]>,
    max: Option<[f32; 3]>,
    center: Option<[f32; 3]>,
    radius: Option<f32>,
    subdivisions: Option<u32>,
    /// A scene material for every face (overrides the file's materials).
    material: Option<String>,
    /// Replace file materials by name with scene materials.
    #[serde(default)]
    material_map: HashMap<String, String>,
    #[serde(default)]
    transform: TransformDesc,
    /// World-space translation over the shutter interval.
    #[serde(default)]
    motion: [f32; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, tag = "type", rename_all = "lowercase")]
enum LightDesc {
    Point {
        position: [f32; 3],
        intensity: [f32; 3],
    },
    Spot {
        position: [f32; 3],
        direction: [f32; 3],
        intensity: [f32; 3],
        #[serde(default)]
        inner_cone_deg: f32,
        #[serde(default = "default_outer")]
        outer_cone_deg: f32,
    },
    Directional {
        direction: [f32; 3],
        irradiance: [f32; 3],
    },
    /// A tessellated emissive sphere.
    Sphere {
        center: [f32; 3],
        radius: f32,
        radiance: [f32; 3],
        #[serde(default = "default_subdivisions")]
        subdivisions: u32,
    },
}

fn default_outer() -> f32 {
    45.0
}

/// The folder that `@shared/` paths resolve to.
pub fn shared_scenes_dir(description_dir: &Path) -> PathBuf {
    match std::env::var_os("LFR_SCENES") {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => description_dir.join("../../shared/scenes"),
    }
}

fn resolve(path: &str, dir: &Path) -> PathBuf {
    match path.strip_prefix("@shared/") {
        Some(rest) => shared_scenes_dir(dir).join(rest),
        None => dir.join(path),
    }
}

/// Parses the description text; `path` is used for messages and relative paths. File
/// references are confined ([`FileAccess::Confined`]).
pub fn parse(text: &str, path: &Path) -> Result<Scene, SceneError> {
    parse_with_access(text, path, FileAccess::Confined)
}

/// [`parse`] with file references allowed as `access` says.
pub fn parse_with_access(text: &str, path: &Path, access: FileAccess) -> Result<Scene, SceneError> {
    let desc: Description = toml::from_str(text).map_err(|e| {
        let field = e.span().map(|s| locate(text, s.start)).unwrap_or_else(|| "toml".into());
        SceneError::new(path, field, e.message().to_string())
    })?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut scene = Scene::empty(path);
    scene.file_access = access;
    scene.width = desc.render.width;
    scene.height = desc.render.height;
    scene.spp = desc.render.spp;
    scene.max_bounces = desc.render.max_bounces;
    scene.environment = Vec3::from(desc.render.environment);

    let mut names: HashMap<String, u32> = HashMap::new();
    for (i, m) in desc.materials.iter().enumerate() {
        let mut material = Material {
            name: m.name.clone(),
            base_color: Vec3::from(m.base_color),
            metallic: m.metallic,
            roughness: m.roughness,
            specular: m.specular,
            ior: m.ior,
            emission: Vec3::from(m.emission),
            two_sided_emission: m.two_sided_emission,
            ..Material::default()
        };
        if let Some(t) = &m.base_color_texture {
            let (file, field) = (resolve(t, dir), format!("material[{i}].base_color_texture"));
            confine(&file, t, path, &field, access)?;
            let texture = crate::texture::Texture::load(&file, true, path, &field)?;
            scene.textures.push(texture);
            material.base_color_texture = Some(TextureRef::new(scene.textures.len() as u32 - 1));
        }
        if !(0.0..=1.0).contains(&m.specular) {
            return Err(SceneError::new(path, format!("material[{i}].specular"), "must be in [0, 1]"));
        }
        if names.insert(m.name.clone(), scene.materials.len() as u32).is_some() {
            return Err(SceneError::new(
                path,
                format!("material[{i}].name"),
                format!("duplicate material '{}'", m.name),
            ));
        }
        scene.materials.push(material);
    }
    let lookup = |name: &str, field: String| -> Result<u32, SceneError> {
        names.get(name).copied().ok_or_else(|| SceneError::new(path, field, format!("no material named '{name}'")))
    };

    for (i, m) in desc.meshes.iter().enumerate() {
        let transform = m
            .transform
            .matrix()
            .map_err(|(key, why)| SceneError::new(path, format!("mesh[{i}].transform.{key}"), why))?;
        if !transform.is_finite() || transform.determinant() == 0.0 {
            return Err(SceneError::new(path, format!("mesh[{i}].transform"), "must be finite and invertible"));
        }
        let material_override = match &m.material {
            Some(name) => Some(lookup(name, format!("mesh[{i}].material"))?),
            None => None,
        };
        let motion = Vec3::from(m.motion);
        let first_new_mesh = scene.meshes.len();
        match (&m.file, &m.shape) {
            (Some(file), None) => {
                let file_path = resolve(file, dir);
                let field = format!("mesh[{i}].file");
                confine(&file_path, file, path, &field, access)?;
                // Checked here too, so that a missing or special file is named with this field;
                // problems inside the file are the loader's, named with the file itself.
                super::input::check_input(&file_path, crate::limits::MAX_MODEL_BYTES, path, &field)?;
                let ext = file_path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
                match ext.as_str() {
                    "obj" => {
                        let mut material_map = HashMap::new();
                        for (from, to) in &m.material_map {
                            material_map.insert(from.clone(), lookup(to, format!("mesh[{i}].material_map.{from}"))?);
                        }
                        let options = ObjOptions { transform, material_override, material_map, motion };
                        super::obj::load(&file_path, &mut scene, &options)?;
                    }
                    "gltf" | "glb" => {
                        super::gltf::load_with_transform(&file_path, &mut scene, transform)?;
                        for mesh in &mut scene.meshes[first_new_mesh..] {
                            if let Some(mat) = material_override {
                                mesh.material = mat;
                            }
                            mesh.motion = motion;
                        }
                    }
                    _ => {
                        return Err(SceneError::new(
                            path,
                            format!("mesh[{i}].file"),
                            format!("unsupported mesh format '{file}'"),
                        ))
                    }
                }
                if scene.meshes.len() == first_new_mesh {
                    scene.warnings.push(format!("mesh[{i}] ({file}) contributed no triangles"));
                }
            }
            (None, Some(shape)) => {
                let material = material_override.unwrap_or(0);
                let name = format!("mesh[{i}]");
                let missing = |what: &str| {
                    SceneError::new(path, format!("mesh[{i}].{what}"), format!("shape '{shape}' needs `{what}`"))
                };
                let mut mesh = match shape.as_str() {
                    "polygon" => {
                        let points = m.points.as_ref().ok_or_else(|| missing("points"))?;
                        if points.len() < 3 {
                            return Err(SceneError::new(
                                path,
                                format!("mesh[{i}].points"),
                                "a polygon needs at least 3 points",
                            ));
                        }
                        let pts: Vec<Vec3> = points.iter().map(|&p| Vec3::from(p)).collect();
                        shapes::polygon(&name, &pts, material)
                    }
                    "box" => {
                        let (min, max) = (m.min.ok_or_else(|| missing("min"))?, m.max.ok_or_else(|| missing("max"))?);
                        shapes::axis_aligned_box(&name, Vec3::from(min), Vec3::from(max), material)
                    }
                    "sphere" => {
                        let center = m.center.ok_or_else(|| missing("center"))?;
                        let radius = m.radius.ok_or_else(|| missing("radius"))?;
                        if !(radius > 0.0) {
                            return Err(SceneError::new(path, format!("mesh[{i}].radius"), "must be > 0"));
                        }
                        let subdivisions = m.subdivisions.unwrap_or_else(default_subdivisions);
                        shapes::sphere(&name, Vec3::from(center), radius, subdivisions, material)
                    }
                    other => {
                        return Err(SceneError::new(
                            path,
                            format!("mesh[{i}].shape"),
                            format!("unknown shape '{other}' (expected polygon, box or sphere)"),
                        ))
                    }
                };
                let normal_matrix = transform.inverse().transpose();
                for p in &mut mesh.positions {
                    *p = transform.transform_point3(*p);
                }
                if let Some(normals) = &mut mesh.normals {
                    for n in normals.iter_mut() {
                        *n = normal_matrix.transform_vector3(*n).normalize_or_zero();
                    }
                }
                if transform.determinant() < 0.0 {
                    for t in &mut mesh.indices {
                        t.swap(1, 2);
                    }
                }
                mesh.motion = motion;
                scene.meshes.push(mesh);
            }
            (Some(_), Some(_)) => {
                return Err(SceneError::new(path, format!("mesh[{i}]"), "give either `file` or `shape`, not both"))
            }
            (None, None) => return Err(SceneError::new(path, format!("mesh[{i}]"), "needs a `file` or a `shape`")),
        }
    }

    for (i, light) in desc.lights.iter().enumerate() {
        match light {
            LightDesc::Point { position, intensity } => scene
                .lights
                .push(PunctualLight::Point { position: Vec3::from(*position), intensity: Vec3::from(*intensity) }),
            LightDesc::Spot { position, direction, intensity, inner_cone_deg, outer_cone_deg } => {
                scene.lights.push(PunctualLight::Spot {
                    position: Vec3::from(*position),
                    direction: Vec3::from(*direction).normalize_or_zero(),
                    intensity: Vec3::from(*intensity),
                    inner_cone: inner_cone_deg.to_radians(),
                    outer_cone: outer_cone_deg.to_radians(),
                })
            }
            LightDesc::Directional { direction, irradiance } => scene.lights.push(PunctualLight::Directional {
                direction: Vec3::from(*direction).normalize_or_zero(),
                irradiance: Vec3::from(*irradiance),
            }),
            LightDesc::Sphere { center, radius, radiance, subdivisions } => {
                if !(*radius > 0.0) {
                    return Err(SceneError::new(path, format!("light[{i}].radius"), "must be > 0"));
                }
                scene.materials.push(Material {
                    name: format!("light[{i}]"),
                    base_color: Vec3::ZERO,
                    specular: 0.0,
                    emission: Vec3::from(*radiance),
                    ..Material::default()
                });
                let material = scene.materials.len() as u32 - 1;
                scene.meshes.push(shapes::sphere(
                    &format!("light[{i}]"),
                    Vec3::from(*center),
                    *radius,
                    *subdivisions,
                    material,
                ));
            }
        }
    }

    scene.camera = match &desc.camera {
        Some(c) => {
            let position = Vec3::from(c.position);
            let target = Vec3::from(c.look_at);
            let mut camera = Camera::look_at(position, target, Vec3::from(c.up), c.fov, c.fov_axis);
            camera.aperture_radius = c.aperture_radius;
            camera.focus_distance = c.focus_distance.unwrap_or((target - position).length());
            camera.shutter = c.shutter;
            camera
        }
        None => Camera::framing(&scene.bounds(), scene.aspect()),
    };
    Ok(scene)
}

/// "line N" for a byte offset, for messages.
fn locate(text: &str, offset: usize) -> String {
    let line = text[..offset.min(text.len())].matches('\n').count() + 1;
    let key = text.lines().nth(line - 1).and_then(|l| l.split('=').next()).map(str::trim).unwrap_or("");
    if key.is_empty() {
        format!("line {line}")
    } else {
        format!("line {line} ({key})")
    }
}

pub fn load(path: &Path) -> Result<Scene, SceneError> {
    load_with_access(path, FileAccess::Confined)
}

/// [`load`] with file references allowed as `access` says.
pub fn load_with_access(path: &Path, access: FileAccess) -> Result<Scene, SceneError> {
    let bytes = super::input::read_input(path, crate::limits::MAX_SCENE_TEXT_BYTES, path, "file")?;
    let text = String::from_utf8(bytes).map_err(|e| SceneError::new(path, "file", format!("not UTF-8 text: {e}")))?;
    parse_with_access(&text, path, access)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_camera_materials_shapes_lights_and_motion() {
        let text = r#"
            [render]
            width = 64
            height = 32
            environment = [0.1, 0.2, 0.3]
            [camera]
            position = [0, 1, 5]
            look_at = [0, 1, 0]
            fov = 45
            fov_axis = "smaller"
            aperture_radius = 0.1
            shutter = [0, 0.5]
            [[material]]
            name = "red"
            base_color = [0.7, 0.1, 0.1]
            specular = 0
            [[mesh]]
            shape = "box"
            min = [-1, 0, -1]
            max = [1, 2, 1]
            material = "red"
            motion = [0, 0, 1]
            transform = { translate = [0, 1, 0] }
            [[light]]
            type = "sphere"
            center = [0, 5, 0]
            radius = 0.5
            radiance = [10, 10, 10]
            [[light]]
            type = "directional"
            direction = [0, -1, 0]
            irradiance = [3, 3, 3]
        "#;
        let mut scene = parse(text, Path::new("/tmp/test.toml")).unwrap();
        scene.validate().unwrap();
        assert_eq!((scene.width, scene.height), (64, 32));
        assert_eq!(scene.environment, Vec3::new(0.1, 0.2, 0.3));
        assert_eq!(scene.meshes.len(), 2);
        assert_eq!(scene.meshes[0].motion, Vec3::Z);
        assert!(scene.has_motion());
        let (lo, hi) = (
            scene.meshes[0].positions.iter().fold(Vec3::INFINITY, |a, &b| a.min(b)),
            scene.meshes[0].positions.iter().fold(Vec3::NEG_INFINITY, |a, &b| a.max(b)),
        );
        assert_eq!((lo.y, hi.y), (1.0, 3.0));
        assert!((scene.camera.focus_distance - 5.0).abs() < 1e-6);
        assert_eq!(scene.camera.aperture_radius, 0.1);
        assert_eq!(scene.camera.shutter, [0.0, 0.5]);
        assert!(scene.materials[scene.meshes[1].material as usize].is_emissive());
        assert_eq!(scene.lights.len(), 1);
    }

    #[test]
    fn errors_name_the_file_and_field() {
        let p = Path::new("/tmp/bad.toml");
        let err = parse("[render]\nwidth = \"wide\"\n", p).unwrap_err();
        assert!(err.to_string().contains("bad.toml") && err.field.contains("width"), "{err}");
        let err =
            parse("[[mesh]]\nshape = \"box\"\nmin = [0,0,0]\nmax = [1,1,1]\nmaterial = \"nope\"\n", p).unwrap_err();
        assert!(err.field.contains("mesh[0].material"), "{err}");
        // A missing mesh file is named with the description and its field (found by fuzzing: it
        // was named as its own file, field `file`).
        for name in ["missing.obj", "missing.gltf"] {
            let err = parse(&format!("[[mesh]]\nfile = \"{name}\"\n"), p).unwrap_err();
            assert_eq!((err.file.as_path(), err.field.as_str()), (p, "mesh[0].file"), "{err}");
            assert!(err.message.contains(name) && err.message.contains("file not found"), "{err}");
        }
        let err = parse("[render]\nwidht = 3\n", p).unwrap_err();
        assert!(err.message.contains("widht"), "{err}");
        let mut zero = parse("[render]\nwidth = 0\n", p).unwrap();
        assert!(zero.validate().unwrap_err().field.contains("resolution"));
    }
}
