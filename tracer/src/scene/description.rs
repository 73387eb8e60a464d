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
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::Deserialize;
use toml::Spanned;

use super::input::{confine, shared_scenes_dir, FileAccess};
use super::obj::ObjOptions;
use super::shapes;
use super::{Material, PunctualLight, Scene};
use crate::camera::{Camera, FovAxis};
use crate::error::SceneError;
use crate::texture::TextureRef;

/// What an array of fixed length holds, for its messages ("expected 3 numbers, found 4").
trait Noun {
    const PLURAL: &'static str;
}

impl Noun for f32 {
    const PLURAL: &'static str = "numbers";
}

impl Noun for Fixed<f32, 4> {
    const PLURAL: &'static str = "rows of 4 numbers";
}

/// An array of exactly `N` items. Serde's `[T; N]` reads the first `N` items of a longer array
/// and drops the rest; this type rejects every other length with
/// `expected N numbers, found M`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Fixed<T, const N: usize>([T; N]);

type Vec3Desc = Fixed<f32, 3>;

impl<T: Default + Copy, const N: usize> Default for Fixed<T, N> {
    fn default() -> Self {
        Fixed([T::default(); N])
    }
}

impl<T: Copy, const N: usize> Fixed<T, N> {
    fn get(self) -> [T; N] {
        self.0
    }
}

impl From<Vec3Desc> for Vec3 {
    fn from(v: Vec3Desc) -> Vec3 {
        Vec3::from(v.0)
    }
}

impl<'de, T: Deserialize<'de> + Noun + Copy + Default, const N: usize> Deserialize<'de> for Fixed<T, N> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct FixedVisitor<T, const N: usize>(std::marker::PhantomData<T>);
        impl<'de, T: Deserialize<'de> + Noun + Copy + Default, const N: usize> Visitor<'de> for FixedVisitor<T, N> {
            type Value = Fixed<T, N>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "an array of {N} {}", T::PLURAL)
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut items = [T::default(); N];
                let mut found = 0usize;
                while let Some(item) = seq.next_element::<T>()? {
                    if found < N {
                        items[found] = item;
                    }
                    found += 1;
                }
                if found != N {
                    return Err(de::Error::custom(format!("expected {N} {}, found {found}", T::PLURAL)));
                }
                Ok(Fixed(items))
            }
        }
        deserializer.deserialize_seq(FixedVisitor::<T, N>(std::marker::PhantomData))
    }
}

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
    #[serde(default = "black")]
    environment: Vec3Desc,
}

fn black() -> Vec3Desc {
    Fixed([0.0; 3])
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
            environment: black(),
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraDesc {
    position: Vec3Desc,
    look_at: Vec3Desc,
    #[serde(default = "default_up")]
    up: Vec3Desc,
    /// Full field of view in degrees.
    fov: f32,
    #[serde(default)]
    fov_axis: FovAxis,
    #[serde(default)]
    aperture_radius: f32,
    /// Defaults to the distance to `look_at`.
    focus_distance: Option<f32>,
    #[serde(default = "default_shutter")]
    shutter: Fixed<f32, 2>,
}

fn default_up() -> Vec3Desc {
    Fixed([0.0, 1.0, 0.0])
}
fn default_shutter() -> Fixed<f32, 2> {
    Fixed([0.0, 1.0])
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialDesc {
    name: String,
    #[serde(default = "default_base")]
    base_color: Vec3Desc,
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
    #[serde(default = "black")]
    emission: Vec3Desc,
    #[serde(default)]
    two_sided_emission: bool,
}

fn default_base() -> Vec3Desc {
    Fixed([0.8, 0.8, 0.8])
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
    translate: Option<Vec3Desc>,
    /// Uniform or per-axis scale.
    #[serde(default)]
    scale: Option<ScaleDesc>,
    /// Rotation about an axis: [x, y, z, degrees].
    #[serde(default)]
    rotate: Option<Fixed<f32, 4>>,
    /// A full 4x4 matrix, row-major; applied after scale, rotate and translate are ignored.
    #[serde(default)]
    matrix: Option<Fixed<Fixed<f32, 4>, 4>>,
}

/// A uniform scale (one number) or one per axis (3 numbers).
enum ScaleDesc {
    Uniform(f32),
    Axes([f32; 3]),
}

impl<'de> Deserialize<'de> for ScaleDesc {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct ScaleVisitor;
        impl<'de> Visitor<'de> for ScaleVisitor {
            type Value = ScaleDesc;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number (uniform scale) or an array of 3 numbers (per axis)")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<ScaleDesc, E> {
                Ok(ScaleDesc::Uniform(v as f32))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<ScaleDesc, E> {
                Ok(ScaleDesc::Uniform(v as f32))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<ScaleDesc, E> {
                Ok(ScaleDesc::Uniform(v as f32))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<ScaleDesc, A::Error> {
                let axes = Vec3Desc::deserialize(de::value::SeqAccessDeserializer::new(seq))?;
                Ok(ScaleDesc::Axes(axes.get()))
            }
        }
        deserializer.deserialize_any(ScaleVisitor)
    }
}

impl TransformDesc {
    /// The transform, or the name of the key that makes it impossible (`Err((key, why))`): a
    /// rotation about a zero or non-finite axis, a matrix whose last row is not [0, 0, 0, 1]
    /// (projective transforms are not supported).
    fn matrix(&self) -> Result<Mat4, (&'static str, String)> {
        if let Some(m) = self.matrix {
            let m = m.get().map(Fixed::get);
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
            Some(Fixed([x, y, z, deg])) => {
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
        Ok(Mat4::from_scale_rotation_translation(scale, rotation, self.translate.map_or(Vec3::ZERO, Vec3::from)))
    }
}

fn default_subdivisions() -> u32 {
    4
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshDesc {
    /// An OBJ, glTF, GLB or PLY file.
    file: Option<String>,
    /// An inline shape when there is no file.
    shape: Option<String>,
    points: Option<Vec<Vec3Desc>>,
    min: Option<Vec3Desc>,
    max: Option<Vec3Desc>,
    center: Option<Vec3Desc>,
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
    #[serde(default = "black")]
    motion: Vec3Desc,
}

/// A `[[light]]` table. Flat rather than a tagged enum so that every key keeps its place in
/// the file: an error about a key names the key's line, not the table's. Which keys each `type`
/// takes is checked in [`LightDesc::check_keys`].
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LightDesc {
    #[serde(rename = "type")]
    kind: Spanned<String>,
    position: Option<Spanned<Vec3Desc>>,
    direction: Option<Spanned<Vec3Desc>>,
    intensity: Option<Spanned<Vec3Desc>>,
    irradiance: Option<Spanned<Vec3Desc>>,
    center: Option<Spanned<Vec3Desc>>,
    radiance: Option<Spanned<Vec3Desc>>,
    radius: Option<Spanned<f32>>,
    subdivisions: Option<Spanned<u32>>,
    inner_cone_deg: Option<Spanned<f32>>,
    outer_cone_deg: Option<Spanned<f32>>,
}

/// The keys of each light type: (type, required keys, optional keys).
const LIGHT_KEYS: [(&str, &[&str], &[&str]); 4] = [
    ("point", &["position", "intensity"], &[]),
    ("spot", &["position", "direction", "intensity"], &["inner_cone_deg", "outer_cone_deg"]),
    ("directional", &["direction", "irradiance"], &[]),
    ("sphere", &["center", "radius", "radiance"], &["subdivisions"]),
];

impl LightDesc {
    /// The keys present besides `type`, with where their values start in the text.
    fn present(&self) -> Vec<(&'static str, usize)> {
        let vectors = [
            ("position", &self.position),
            ("direction", &self.direction),
            ("intensity", &self.intensity),
            ("irradiance", &self.irradiance),
            ("center", &self.center),
            ("radiance", &self.radiance),
        ];
        let mut keys: Vec<(&'static str, usize)> =
            vectors.iter().filter_map(|(k, v)| v.as_ref().map(|v| (*k, v.span().start))).collect();
        for (k, v) in [
            ("radius", &self.radius),
            ("inner_cone_deg", &self.inner_cone_deg),
            ("outer_cone_deg", &self.outer_cone_deg),
        ] {
            if let Some(v) = v {
                keys.push((k, v.span().start));
            }
        }
        if let Some(v) = &self.subdivisions {
            keys.push(("subdivisions", v.span().start));
        }
        keys
    }

    /// Checks that the keys fit the type: an unknown type is named at `type`'s line, a key that
    /// the type does not take at that key's line, a missing key by its name.
    fn check_keys(&self, i: usize, text: &str, path: &Path) -> Result<(), SceneError> {
        let kind = self.kind.get_ref().as_str();
        let Some((_, required, optional)) = LIGHT_KEYS.iter().find(|(k, _, _)| *k == kind) else {
            return Err(SceneError::new(
                path,
                locate(text, self.kind.span().start),
                format!("unknown light type '{kind}' (expected point, spot, directional or sphere)"),
            ));
        };
        let present = self.present();
        for (key, at) in &present {
            if !required.contains(key) && !optional.contains(key) {
                let keys: Vec<&str> = required.iter().chain(optional.iter()).copied().collect();
                return Err(SceneError::new(
                    path,
                    locate(text, *at),
                    format!("a {kind} light takes no `{key}` (its keys: type, {})", keys.join(", ")),
                ));
            }
        }
        if let Some(key) = required.iter().find(|k| !present.iter().any(|(p, _)| p == *k)) {
            return Err(SceneError::new(
                path,
                format!("{} light[{i}].{key}", locate(text, self.kind.span().start)),
                format!("a {kind} light needs `{key}`"),
            ));
        }
        Ok(())
    }
}

fn default_outer() -> f32 {
    45.0
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
    // The command-line limits, checked here so that a value from the file is named by its key
    // (not by the option the user never gave).
    let side = 1..=crate::limits::MAX_IMAGE_SIDE;
    for (key, value, range) in [
        ("render.width", desc.render.width, &side),
        ("render.height", desc.render.height, &side),
        ("render.spp", desc.render.spp, &(1..=crate::limits::MAX_SPP)),
    ] {
        if !range.contains(&value) {
            return Err(SceneError::new(
                path,
                key,
                format!("must be in {}..={}, got {value}", range.start(), range.end()),
            ));
        }
    }
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
                        let imported = super::gltf::load_with_transform(&file_path, &mut scene, transform)?;
                        // Kept for `--camera N`; the scene's own camera stays the `[camera]` table's.
                        scene.file_cameras.extend(imported.cameras);
                        for mesh in &mut scene.meshes[first_new_mesh..] {
                            if let Some(mat) = material_override {
                                mesh.material = mat;
                            }
                            mesh.motion = motion;
                        }
                    }
                    "ply" => {
                        let options =
                            super::ply::PlyOptions { transform, material: material_override.unwrap_or(0), motion };
                        super::ply::load(&file_path, &mut scene, &options)?;
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
                if transform != Mat4::IDENTITY {
                    mesh.sphere = None;
                }
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
        light.check_keys(i, text, path)?;
        // check_keys made sure that the type's required keys are present.
        let v = |value: &Option<Spanned<Vec3Desc>>| value.as_ref().map_or(Vec3::ZERO, |v| Vec3::from(*v.get_ref()));
        let number = |value: &Option<Spanned<f32>>, default: f32| value.as_ref().map_or(default, |v| *v.get_ref());
        match light.kind.get_ref().as_str() {
            "point" => {
                scene.lights.push(PunctualLight::Point { position: v(&light.position), intensity: v(&light.intensity) })
            }
            "spot" => scene.lights.push(PunctualLight::Spot {
                position: v(&light.position),
                direction: v(&light.direction).normalize_or_zero(),
                intensity: v(&light.intensity),
                inner_cone: number(&light.inner_cone_deg, 0.0).to_radians(),
                outer_cone: number(&light.outer_cone_deg, default_outer()).to_radians(),
            }),
            "directional" => scene.lights.push(PunctualLight::Directional {
                direction: v(&light.direction).normalize_or_zero(),
                irradiance: v(&light.irradiance),
            }),
            _ => {
                let radius = number(&light.radius, 0.0);
                if !(radius > 0.0) {
                    return Err(SceneError::new(path, format!("light[{i}].radius"), "must be > 0"));
                }
                scene.materials.push(Material {
                    name: format!("light[{i}]"),
                    base_color: Vec3::ZERO,
                    specular: 0.0,
                    emission: v(&light.radiance),
                    ..Material::default()
                });
                let material = scene.materials.len() as u32 - 1;
                let subdivisions = light.subdivisions.as_ref().map_or(default_subdivisions(), |s| *s.get_ref());
                scene.meshes.push(shapes::sphere(
                    &format!("light[{i}]"),
                    v(&light.center),
                    radius,
                    subdivisions,
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
            camera.focus_distance = c.focus_distance.unwrap_or(camera.focus_distance);
            camera.shutter = c.shutter.get();
            camera
        }
        None => Camera::framing(&scene.bounds(), scene.aspect()),
    };
    Ok(scene)
}

/// "line N (key)" for a byte offset, for messages. The key is the one whose value holds
/// `offset` (`key = value`, also inside an inline table or for an item of an array), else the
/// key that starts the line.
fn locate(text: &str, offset: usize) -> String {
    let offset = offset.min(text.len());
    let line = text[..offset].matches('\n').count() + 1;
    let key = value_key(text, offset).unwrap_or_else(|| {
        text.lines().nth(line - 1).and_then(|l| l.split('=').next()).map(|k| k.trim().to_string()).unwrap_or_default()
    });
    if key.is_empty() {
        format!("line {line}")
    } else {
        format!("line {line} ({key})")
    }
}

/// The key whose value starts at `offset`, or holds it as an item of an array at any depth.
fn value_key(text: &str, mut offset: usize) -> Option<String> {
    loop {
        let before = text[..offset].trim_end();
        if let Some(rest) = before.strip_suffix('=') {
            let rest = rest.trim_end_matches([' ', '\t']);
            let start = rest
                .rfind(|c: char| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '"' | '\'')))
                .map_or(0, |i| i + 1);
            return Some(rest[start..].to_string()).filter(|k| !k.is_empty());
        }
        if !(before.ends_with('[') || before.ends_with(',')) {
            return None;
        }
        // An array item: go to the array's opening bracket.
        let mut depth = 0usize;
        let open = before.char_indices().rev().find(|&(_, c)| match c {
            ']' => {
                depth += 1;
                false
            }
            '[' if depth == 0 => true,
            '[' => {
                depth -= 1;
                false
            }
            _ => false,
        })?;
        offset = open.0;
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
        // Out-of-range values are named by file and key, not by the command's options.
        for (text, key) in [
            ("[render]\nwidth = 0\n", "render.width"),
            ("[render]\nheight = 40000\n", "render.height"),
            ("[render]\nspp = 2000000\n", "render.spp"),
            ("[render]\nspp = 0\n", "render.spp"),
        ] {
            let err = parse(text, p).unwrap_err();
            assert_eq!(err.field, key, "{err}");
            assert!(err.to_string().starts_with("/tmp/bad.toml: render.") && !err.to_string().contains("--"), "{err}");
        }
    }

    /// The error of `text`, which must fail to parse.
    fn error_of(text: &str) -> String {
        match parse(text, Path::new("/tmp/bad.toml")) {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    /// The 1-based line of `text` that holds `needle` (the expectation, found independently of
    /// the parser's spans).
    fn line_of(text: &str, needle: &str) -> usize {
        text.lines().position(|l| l.contains(needle)).expect("needle in text") + 1
    }

    /// Every fixed-length array of the format, with a minimal scene around it: (key, scene
    /// text with `@` where the array goes, length the key needs).
    const ARRAY_KEYS: [(&str, &str, usize); 17] = [
        ("environment", "[render]\nenvironment = @\n", 3),
        ("position", "[camera]\nposition = @\nlook_at = [0, 0, 0]\nfov = 40\n", 3),
        ("look_at", "[camera]\nposition = [0, 0, 5]\nlook_at = @\nfov = 40\n", 3),
        ("up", "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nup = @\nfov = 40\n", 3),
        ("shutter", "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 40\nshutter = @\n", 2),
        ("base_color", "[[material]]\nname = \"m\"\nbase_color = @\n", 3),
        ("emission", "[[material]]\nname = \"m\"\nemission = @\n", 3),
        ("min", "[[mesh]]\nshape = \"box\"\nmin = @\nmax = [1, 1, 1]\n", 3),
        ("max", "[[mesh]]\nshape = \"box\"\nmin = [0, 0, 0]\nmax = @\n", 3),
        ("center", "[[mesh]]\nshape = \"sphere\"\ncenter = @\nradius = 1\n", 3),
        ("motion", "[[mesh]]\nshape = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\nmotion = @\n", 3),
        (
            "translate",
            "[[mesh]]\nshape = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\ntransform = { translate = @ }\n",
            3,
        ),
        ("rotate", "[[mesh]]\nshape = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\n[mesh.transform]\nrotate = @\n", 4),
        ("position", "[[light]]\ntype = \"point\"\nposition = @\nintensity = [1, 1, 1]\n", 3),
        ("intensity", "[[light]]\ntype = \"point\"\nposition = [0, 1, 0]\nintensity = @\n", 3),
        ("irradiance", "[[light]]\ntype = \"directional\"\ndirection = [0, -1, 0]\nirradiance = @\n", 3),
        ("radiance", "[[light]]\ntype = \"sphere\"\ncenter = [0, 1, 0]\nradius = 1\nradiance = @\n", 3),
    ];

    #[test]
    fn arrays_of_the_wrong_length_are_named_at_their_key() {
        for (key, template, n) in ARRAY_KEYS {
            // The right length parses (the template is otherwise valid).
            let right: Vec<String> = (0..n).map(|i| format!("{}", i + 1)).collect();
            let text = template.replace('@', &format!("[{}]", right.join(", ")));
            parse(&text, Path::new("/tmp/good.toml")).unwrap_or_else(|e| panic!("{key}: {e}"));
            for found in [n - 1, n + 1, 0] {
                let values: Vec<String> = (0..found).map(|i| format!("0.{}", i + 1)).collect();
                let text = template.replace('@', &format!("[{}]", values.join(", ")));
                let line = line_of(&text, &format!("{key} ="));
                let expected = format!("/tmp/bad.toml: line {line} ({key}): expected {n} numbers, found {found}");
                assert_eq!(error_of(&text), expected, "{text}");
            }
        }
        // A polygon's points: each one, and a 4x4 matrix's rows.
        let text = "[[mesh]]\nshape = \"polygon\"\npoints = [[0, 0, 0], [1, 0, 0, 9], [0, 1, 0]]\n";
        assert_eq!(error_of(text), "/tmp/bad.toml: line 3 (points): expected 3 numbers, found 4");
        let text = "[[mesh]]\nshape = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\n\
                    transform = { matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]] }\n";
        assert_eq!(error_of(text), "/tmp/bad.toml: line 5 (matrix): expected 4 rows of 4 numbers, found 3");
        let text = "[[mesh]]\nshape = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\n\
                    transform = { matrix = [[1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]] }\n";
        assert_eq!(error_of(text), "/tmp/bad.toml: line 5 (matrix): expected 4 numbers, found 3");
    }

    #[test]
    fn a_bad_scale_says_what_a_scale_is() {
        let template = "[[mesh]]\nshape = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\ntransform = { scale = @ }\n";
        for good in ["2", "0.5", "[1, 2, 3]"] {
            parse(&template.replace('@', good), Path::new("/tmp/good.toml")).unwrap();
        }
        assert_eq!(
            error_of(&template.replace('@', "[1, 2, 3, 4]")),
            "/tmp/bad.toml: line 5 (scale): expected 3 numbers, found 4"
        );
        let message = error_of(&template.replace('@', "\"big\""));
        assert!(message.starts_with("/tmp/bad.toml: line 5 (scale): invalid type: string"), "{message}");
        assert!(
            message.ends_with("expected a number (uniform scale) or an array of 3 numbers (per axis)"),
            "{message}"
        );
    }

    #[test]
    fn light_errors_name_the_key_not_the_table() {
        // A bad value, a key the type does not take, and an unknown type: each at its own line.
        let text = "[[light]]\ntype = \"point\"\nposition = [0, 1, 0]\nintensity = \"bright\"\n";
        let message = error_of(text);
        assert!(message.starts_with("/tmp/bad.toml: line 4 (intensity): invalid type: string"), "{message}");
        let text = "[[light]]\ntype = \"point\"\nposition = [0, 1, 0]\nintensity = [1, 1, 1]\nradius = 2\n";
        assert_eq!(
            error_of(text),
            "/tmp/bad.toml: line 5 (radius): a point light takes no `radius` (its keys: type, position, intensity)"
        );
        let text = "[[light]]\ntype = \"area\"\nposition = [0, 1, 0]\n";
        assert_eq!(
            error_of(text),
            "/tmp/bad.toml: line 2 (type): unknown light type 'area' (expected point, spot, directional or sphere)"
        );
        let text = "[[light]]\ntype = \"directional\"\ndirection = [0, -1, 0]\n";
        assert_eq!(
            error_of(text),
            "/tmp/bad.toml: line 2 (type) light[0].irradiance: a directional light needs `irradiance`"
        );
        let text = "[[light]]\ntype = \"spot\"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\nintensity = [1, 1, 1]\nbeam = 3\n";
        assert!(error_of(text).starts_with("/tmp/bad.toml: line 6 (beam): unknown field `beam`"), "{}", error_of(text));
        // The keys that a type does take still load as before.
        let text = "[[light]]\ntype = \"spot\"\nposition = [0, 1, 0]\ndirection = [0, -2, 0]\nintensity = [1, 2, 3]\n\
                    inner_cone_deg = 10\nouter_cone_deg = 20\n";
        let scene = parse(text, Path::new("/tmp/good.toml")).unwrap();
        assert_eq!(
            scene.lights,
            vec![PunctualLight::Spot {
                position: Vec3::Y,
                direction: -Vec3::Y,
                intensity: Vec3::new(1.0, 2.0, 3.0),
                inner_cone: 10f32.to_radians(),
                outer_cone: 20f32.to_radians(),
            }]
        );
    }
}
