//! Wavefront OBJ/MTL loader.
//!
//! Material mapping onto the metallic-roughness model:
//! - `Kd` (× `map_Kd`, sRGB) is the diffuse colour. A material without `Ks` (or with `Ks 0 0 0`)
//!   is pure Lambertian (specular weight 0): that is what OBJ scenes like the Cornell boxes mean.
//! - `Ks`/`Ns` make it glossy: metallic = lum(Ks) / (lum(Kd) + lum(Ks)) and base colour
//!   = min(Kd + Ks, 1), so the diffuse part reflects about Kd and the specular part about Ks.
//!   The Phong exponent maps to a microfacet width by the usual Beckmann correspondence
//!   α = sqrt(2 / (Ns + 2)), and glTF roughness = sqrt(α) (GGX α is roughness²).
//!   Ns 0 → roughness 1; Ns 40 → 0.46; Ns 1000 → 0.2; Ns 10⁶ → 0.035.
//! - `Ke` is emitted radiance (one-sided, front face by winding).
//! - `map_d` is an alpha cut-out at coverage 0.5 (its alpha channel when it has one,
//!   otherwise its grey value).
//! - Missing normals are computed with a 60° crease angle (see `shapes::compute_normals`).
//! - Texture v is flipped (OBJ's origin is bottom-left, our textures' top-left).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat4, Vec2, Vec3};

use super::input::{confine, read_input};
use super::shapes::compute_normals;
use super::{AlphaMask, Material, Mesh, NormalMap, Scene};
use crate::error::SceneError;
use crate::limits::MAX_MODEL_BYTES;
use crate::texture::{Texture, TextureRef};

#[derive(Clone, Debug)]
pub struct ObjOptions {
    /// Object-to-world transform applied to positions and normals.
    pub transform: Mat4,
    /// Use this scene material for every face, ignoring the MTL.
    pub material_override: Option<u32>,
    /// Replace MTL materials by name with scene materials.
    pub material_map: HashMap<String, u32>,
    /// World-space linear motion over the shutter for every mesh of the file.
    pub motion: Vec3,
}

impl Default for ObjOptions {
    fn default() -> Self {
        ObjOptions {
            transform: Mat4::IDENTITY,
            material_override: None,
            material_map: HashMap::new(),
            motion: Vec3::ZERO,
        }
    }
}

/// The glTF-style roughness for a Phong exponent.
pub fn phong_exponent_to_roughness(ns: f32) -> f32 {
    let ns = if ns.is_finite() { ns.max(0.0) } else { 0.0 };
    let alpha = (2.0 / (ns + 2.0)).sqrt();
    alpha.sqrt().clamp(0.0, 1.0)
}

fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

struct TextureCache<'a> {
    scene: &'a mut Scene,
    loaded: HashMap<(PathBuf, bool), u32>,
}

impl TextureCache<'_> {
    fn get(&mut self, path: &Path, srgb: bool, obj: &Path, field: &str) -> Result<u32, SceneError> {
        if let Some(&i) = self.loaded.get(&(path.to_path_buf(), srgb)) {
            return Ok(i);
        }
        let texture = Texture::load(path, srgb, obj, field)?;
        self.scene.textures.push(texture);
        let index = self.scene.textures.len() as u32 - 1;
        self.loaded.insert((path.to_path_buf(), srgb), index);
        Ok(index)
    }
}

/// The scene material of MTL material `m`; `obj` is the OBJ file (texture maps are read
/// relative to its folder, and confined to it), `mtl_path` the library messages name.
fn convert_material(
    m: &tobj::Material,
    obj: &Path,
    mtl_path: &Path,
    cache: &mut TextureCache,
) -> Result<Material, SceneError> {
    let dir = obj.parent().unwrap_or(Path::new("."));
    let kd = m.diffuse.unwrap_or([0.8, 0.8, 0.8]);
    let ks = m.specular.unwrap_or([0.0; 3]);
    let field = |f: &str| format!("material '{}'.{f}", m.name);
    let mut material = Material { name: m.name.clone(), ..Material::default() };
    if luminance(ks) > 0.0 {
        let metallic = luminance(ks) / (luminance(kd) + luminance(ks));
        material.metallic = metallic.clamp(0.0, 1.0);
        material.base_color = Vec3::new(kd[0] + ks[0], kd[1] + ks[1], kd[2] + ks[2]).min(Vec3::ONE);
        material.roughness = phong_exponent_to_roughness(m.shininess.unwrap_or(0.0));
        material.specular = 1.0;
    } else {
        material.base_color = Vec3::from(kd);
        material.roughness = 1.0;
        material.specular = 0.0;
    }
    if let Some(ke) = m.emissive {
        material.emission = Vec3::from(ke).max(Vec3::ZERO);
    }
    let access = cache.scene.file_access;
    if let Some(name) = m.diffuse_texture.as_ref().filter(|s| !s.is_empty()) {
        let file = dir.join(name.replace('\\', "/"));
        confine(&file, name, obj, &field("map_Kd"), access)?;
        let index = cache.get(&file, true, mtl_path, &field("map_Kd"))?;
        material.base_color_texture = Some(TextureRef::new(index));
    }
    if let Some(name) = m.dissolve_texture.as_ref().filter(|s| !s.is_empty()) {
        let file = dir.join(name.replace('\\', "/"));
        confine(&file, name, obj, &field("map_d"), access)?;
        let index = cache.get(&file, false, mtl_path, &field("map_d"))?;
        let texture = &cache.scene.textures[index as usize];
        let has_alpha = texture.texels.iter().any(|t| t[3] != 255);
        material.alpha = Some(AlphaMask {
            texture: TextureRef::new(index),
            channel: if has_alpha { 3 } else { 0 },
            factor: 1.0,
            cutoff: 0.5,
        });
    }
    // `norm` is a tangent-space normal map; `map_Bump`/`bump` (tobj's `normal_texture`) too when
    // its image has colour, since exporters write normal maps there: a grey image is the
    // classic height (bump) map, which the tracer does not use (a warning).
    let normal_maps = [("norm", m.unknown_param.get("norm")), ("map_Bump", m.normal_texture.as_ref())];
    for (key, value) in normal_maps {
        let Some(value) = value.filter(|v| !v.trim().is_empty()) else { continue };
        if material.normal_map.is_some() {
            cache.scene.warnings.push(format!(
                "{}: {} ignored: the material already has a normal map (`norm`)",
                mtl_path.display(),
                field(key)
            ));
            continue;
        }
        let (name, scale) = map_options(value).map_err(|message| SceneError::new(mtl_path, field(key), message))?;
        let file = dir.join(name.replace('\\', "/"));
        confine(&file, &name, obj, &field(key), access)?;
        let index = cache.get(&file, false, mtl_path, &field(key))?;
        let texture = &cache.scene.textures[index as usize];
        if key != "norm" && texture.texels.iter().all(|t| t[0] == t[1] && t[1] == t[2]) {
            cache.scene.warnings.push(format!(
                "{}: {}: a grey image, read as a height (bump) map, which is not supported; ignored",
                mtl_path.display(),
                field(key)
            ));
            continue;
        }
        material.normal_map = Some(NormalMap { texture: TextureRef::new(index), scale });
    }
    for key in ["map_Ks", "map_Ns"] {
        if m.unknown_param.contains_key(key) {
            cache.scene.warnings.push(format!("{}: {} ignored (not supported)", mtl_path.display(), field(key)));
        }
    }
    Ok(material)
}

/// The file name and `-bm` multiplier of a texture map statement's value (what follows the
/// keyword): options come first, each with its number of arguments as in the MTL
/// specification (`-o`, `-s`, `-t` take one to three numbers); the rest is the file name.
pub fn map_options(value: &str) -> Result<(String, f32), String> {
    let words: Vec<&str> = value.split_whitespace().collect();
    let mut scale = 1.0;
    let mut i = 0;
    while i < words.len() && words[i].starts_with('-') && words[i].parse::<f32>().is_err() {
        let option = words[i];
        let number = |j: usize| words.get(j).and_then(|w| w.parse::<f32>().ok());
        i += 1;
        match option {
            "-bm" => {
                scale = number(i)
                    .filter(|s| s.is_finite())
                    .ok_or_else(|| format!("`-bm` needs a finite number in {value:?}"))?;
                i += 1;
            }
            "-blendu" | "-blendv" | "-boost" | "-cc" | "-clamp" | "-imfchan" | "-texres" | "-type" => {
                if i >= words.len() {
                    return Err(format!("`{option}` needs a value in {value:?}"));
                }
                i += 1;
            }
            "-mm" => {
                if number(i).is_none() || number(i + 1).is_none() {
                    return Err(format!("`-mm` needs two numbers in {value:?}"));
                }
                i += 2;
            }
            "-o" | "-s" | "-t" => {
                let start = i;
                while i < start + 3 && number(i).is_some() {
                    i += 1;
                }
                if i == start {
                    return Err(format!("`{option}` needs one to three numbers in {value:?}"));
                }
            }
            other => return Err(format!("unknown option `{other}` in {value:?}")),
        }
    }
    if i >= words.len() {
        return Err(format!("no file name in {value:?}"));
    }
    Ok((words[i..].join(" "), scale))
}

/// The first line of an MTL text that tobj would refuse, as (line number from 1, what is
/// wrong), so that the error can name it: tobj says only "material parse error", and it
/// panics on a colour of fewer than three numbers. The rules are tobj 4's (`parse_mtl_line`):
/// `Ka`/`Kd`/`Ks`/`Ke` need three numbers, `Ns`/`Ni`/`d` one, `illum` an integer 0..=255, a
/// texture map and `newmtl` a name; every line must be UTF-8.
pub fn check_mtl(text: &[u8]) -> Result<(), (usize, String)> {
    for (i, line) in text.split(|&b| b == b'\n').enumerate() {
        let number = i + 1;
        let line = std::str::from_utf8(line).map_err(|_| (number, "not UTF-8 text".to_string()))?;
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else { continue };
        let rest: Vec<&str> = words.collect();
        let is_number = |word: &&str| word.parse::<f32>().is_ok();
        let problem = match keyword {
            "Ka" | "Kd" | "Ks" | "Ke" if !(rest.len() >= 3 && rest[..3].iter().all(is_number)) => {
                Some(format!("`{keyword}` needs three numbers, got {:?}", rest.join(" ")))
            }
            "Ns" | "Ni" | "d" if !rest.first().is_some_and(is_number) => {
                Some(format!("`{keyword}` needs a number, got {:?}", rest.join(" ")))
            }
            "illum" if !rest.first().is_some_and(|w| w.parse::<u8>().is_ok()) => {
                Some(format!("`illum` needs an integer in 0..=255, got {:?}", rest.join(" ")))
            }
            "map_Ka" | "map_Kd" | "map_Ks" | "map_Bump" | "map_bump" | "map_Ns" | "map_ns" | "map_NS" | "bump"
            | "map_d"
                if rest.is_empty() =>
            {
                Some(format!("`{keyword}` needs a file name"))
            }
            "newmtl" if rest.is_empty() => Some("`newmtl` needs a material name".to_string()),
            _ => None,
        };
        if let Some(message) = problem {
            return Err((number, message));
        }
    }
    Ok(())
}

/// The first line of an OBJ text at fault, with what is wrong there: a `v`, `vt` or `vn`
/// without its numbers or with one that is not finite (`nan`, `1e999`), a `v` weight of 0, a
/// face (`f`) of fewer than 3 elements or a line (`l`) of fewer than 2, an element that is not
/// an integer, or an index out of range (0, beyond the elements the file defines, or a
/// relative index reaching before its first element). `None` when every line is sound.
///
/// Run before tobj reads the text: tobj takes an index of 0 for a missing one, lets a face of
/// two elements drop without a word, and panics on a relative texture-coordinate index that
/// reaches before the first. Two passes over the bytes, linear in the file.
pub fn locate_obj_problem(text: &[u8]) -> Option<(usize, String)> {
    let lines = || text.split(|&b| b == b'\n').map(String::from_utf8_lossy);
    // (positions, texture coordinates, normals): in the whole file and before the current line.
    let mut total = [0usize; 3];
    for line in lines() {
        match line.split_whitespace().next() {
            Some("v") => total[0] += 1,
            Some("vt") => total[1] += 1,
            Some("vn") => total[2] += 1,
            _ => {}
        }
    }
    const ELEMENTS: [(&str, &str, usize); 3] =
        [("v", "vertex", 3), ("vt", "texture coordinate", 2), ("vn", "normal", 3)];
    const PLURALS: [&str; 3] = ["vertices", "texture coordinates", "normals"];
    let mut seen = [0usize; 3];
    for (i, line) in lines().enumerate() {
        let number = i + 1;
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else { continue };
        if let Some(kind) = ELEMENTS.iter().position(|(k, _, _)| *k == keyword) {
            let (_, name, needed) = ELEMENTS[kind];
            let numbers = words.clone().take(needed).filter(|w| w.parse::<f32>().is_ok()).count();
            if numbers < needed {
                let given = words.collect::<Vec<_>>().join(" ");
                return Some((number, format!("`{keyword}` (a {name}) needs {needed} numbers, got {given:?}")));
            }
            if let Some(word) = words.clone().find(|w| w.parse::<f32>().is_ok_and(|x| !x.is_finite())) {
                return Some((number, format!("`{keyword}` (a {name}): `{word}` is not a finite number")));
            }
            if keyword == "v" {
                // x y z, then nothing, a w that divides them, or a colour r g b.
                let extra: Vec<&str> = words.skip(3).collect();
                let problem = match extra.as_slice() {
                    [] => None,
                    [w] => match w.parse::<f32>() {
                        Ok(w) if w != 0.0 => None,
                        Ok(_) => Some("`v` with a weight w of 0 (the position would be divided by it)".to_string()),
                        Err(_) => Some(format!("`v`: the weight `{w}` is not a number")),
                    },
                    [_, _, _] => None,
                    _ => Some(format!("`v` takes x y z, x y z w or x y z r g b; got {} values", 3 + extra.len())),
                };
                if let Some(problem) = problem {
                    return Some((number, problem));
                }
            }
            seen[kind] += 1;
            continue;
        }
        let least = match keyword {
            "f" => 3,
            "l" => 2,
            _ => continue,
        };
        let elements = words.clone().count();
        if elements < least {
            let what = if keyword == "f" { "a face" } else { "a line" };
            return Some((number, format!("`{keyword}` ({what}) needs at least {least} elements, got {elements}")));
        }
        for element in words {
            for (kind, part) in element.split('/').enumerate() {
                if part.is_empty() {
                    continue;
                }
                if kind > 2 {
                    return Some((number, format!("`{keyword}` element `{element}` has more than three parts")));
                }
                let (name, plural) = (ELEMENTS[kind].1, PLURALS[kind]);
                let Ok(index) = part.parse::<i64>() else {
                    return Some((
                        number,
                        format!("`{keyword}` element `{element}`: `{part}` is not an integer index"),
                    ));
                };
                let problem = if index == 0 {
                    Some(format!("{name} index 0: OBJ indices start at 1 (or count back from -1)"))
                } else if index > 0 && index as u64 > total[kind] as u64 {
                    Some(format!("{name} index {index}, but the file defines {} {plural}", total[kind]))
                } else if index < 0 && index.unsigned_abs() > seen[kind] as u64 {
                    Some(format!(
                        "{name} index {index} reaches before the first: {} {plural} precede this line",
                        seen[kind]
                    ))
                } else {
                    None
                };
                if let Some(problem) = problem {
                    return Some((number, format!("`{keyword}` element `{element}`: {problem}")));
                }
            }
        }
    }
    None
}

/// Appends the meshes (one per OBJ model and material) and materials of `path` to `scene`.
pub fn load(path: &Path, scene: &mut Scene, options: &ObjOptions) -> Result<(), SceneError> {
    let bytes = read_input(path, MAX_MODEL_BYTES, path, "file")?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let access = scene.file_access;
    // A material library goes through the same checks as every input: inside the folders a
    // scene may reach, a regular file, bounded.
    let read_mtl = |mtl: &Path| {
        let mtl_path = dir.join(mtl);
        confine(&mtl_path, &mtl.to_string_lossy(), path, "mtllib", access)?;
        read_input(&mtl_path, MAX_MODEL_BYTES, path, "mtllib")
    };
    load_from_bytes(path, &bytes, scene, options, &read_mtl)
}

/// [`load`] of the OBJ text `bytes` (named `path` in messages; texture maps are read relative
/// to its folder), with `read_mtl` giving the bytes of the material library an `mtllib` names
/// (the fuzz targets keep everything in memory this way).
pub fn load_from_bytes(
    path: &Path,
    bytes: &[u8],
    scene: &mut Scene,
    options: &ObjOptions,
    read_mtl: &dyn Fn(&Path) -> Result<Vec<u8>, SceneError>,
) -> Result<(), SceneError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    if let Some((line, problem)) = locate_obj_problem(bytes) {
        return Err(SceneError::new(path, format!("line {line}"), problem));
    }
    let load_options = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    // tobj would open the material library itself; `read_mtl` does, and the reason it could not
    // be read is kept.
    let mtl_problem = std::cell::RefCell::new(None::<String>);
    // The libraries read, to name the one a material came from in messages.
    let mtl_files = std::cell::RefCell::new(Vec::<PathBuf>::new());
    let (models, materials) = tobj::load_obj_buf(&mut std::io::Cursor::new(bytes), &load_options, |mtl| {
        let mtl_path = dir.join(mtl);
        mtl_files.borrow_mut().push(mtl_path.clone());
        match read_mtl(mtl) {
            Ok(mtl_bytes) => match check_mtl(&mtl_bytes) {
                Err((line, message)) => {
                    *mtl_problem.borrow_mut() = Some(format!("{}, line {line}: {message}", mtl_path.display()));
                    Err(tobj::LoadError::MaterialParseError)
                }
                Ok(()) => tobj::load_mtl_buf(&mut std::io::Cursor::new(mtl_bytes)).inspect_err(|e| {
                    *mtl_problem.borrow_mut() = Some(format!("{}: {e}", mtl_path.display()));
                }),
            },
            Err(e) => {
                *mtl_problem.borrow_mut() = Some(e.message);
                Err(tobj::LoadError::OpenFileFailed)
            }
        }
    })
    .map_err(|e| SceneError::new(path, "obj", format!("cannot parse: {e}")))?;

    // Materials from the MTL, unless the whole file is overridden.
    let mut material_index: Vec<u32> = Vec::new();
    if options.material_override.is_none() {
        let materials = match materials {
            Ok(m) => m,
            Err(e) => {
                let references_mtl = bytes.windows(6).any(|w| w == b"mtllib");
                if references_mtl {
                    let reason = mtl_problem.borrow_mut().take().unwrap_or_else(|| e.to_string());
                    return Err(SceneError::new(path, "mtllib", format!("cannot load the material library: {reason}")));
                }
                Vec::new()
            }
        };
        // With one library (the usual case) messages name it; with several, the OBJ.
        let mtl_path = match mtl_files.borrow().as_slice() {
            [one] => one.clone(),
            _ => path.to_path_buf(),
        };
        let mut cache = TextureCache { scene, loaded: HashMap::new() };
        for m in &materials {
            if let Some(&mapped) = options.material_map.get(&m.name) {
                material_index.push(mapped);
                continue;
            }
            let material = convert_material(m, path, &mtl_path, &mut cache)?;
            cache.scene.materials.push(material);
            material_index.push(cache.scene.materials.len() as u32 - 1);
        }
    }

    let normal_matrix = options.transform.inverse().transpose();
    let flips_winding = options.transform.determinant() < 0.0;
    for model in models {
        let m = &model.mesh;
        if m.indices.is_empty() {
            continue;
        }
        let material = match options.material_override {
            Some(i) => i,
            None => match m.material_id {
                Some(id) => *material_index.get(id).ok_or_else(|| {
                    SceneError::new(path, format!("object '{}'.usemtl", model.name), "material not found")
                })?,
                None => 0,
            },
        };
        let positions: Vec<Vec3> = m
            .positions
            .chunks_exact(3)
            .map(|p| options.transform.transform_point3(Vec3::new(p[0], p[1], p[2])))
            .collect();
        let normals = (m.normals.len() == m.positions.len() && !m.normals.is_empty()).then(|| {
            m.normals
                .chunks_exact(3)
                .map(|n| normal_matrix.transform_vector3(Vec3::new(n[0], n[1], n[2])).normalize_or_zero())
                .collect()
        });
        let uvs = (m.texcoords.len() / 2 == m.positions.len() / 3 && !m.texcoords.is_empty())
            .then(|| m.texcoords.chunks_exact(2).map(|t| Vec2::new(t[0], 1.0 - t[1])).collect());
        let indices = m
            .indices
            .chunks_exact(3)
            .map(|t| if flips_winding { [t[0], t[2], t[1]] } else { [t[0], t[1], t[2]] })
            .collect();
        let mut mesh = Mesh {
            name: format!("{}:{}", path.display(), model.name),
            positions,
            normals,
            uvs,
            tangents: None,
            indices,
            material,
            motion: options.motion,
            sphere: None,
        };
        if mesh.normals.is_none() && mesh.positions.iter().all(|p| p.is_finite()) {
            compute_normals(&mut mesh, 60.0);
        }
        scene.meshes.push(mesh);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error of loading the OBJ text `text` (which must fail).
    fn obj_error(text: &str) -> SceneError {
        let mut scene = Scene::empty("bad.obj");
        let no_mtl = |_: &Path| -> Result<Vec<u8>, SceneError> { Err(SceneError::new("bad.obj", "mtllib", "none")) };
        match load_from_bytes(Path::new("bad.obj"), text.as_bytes(), &mut scene, &ObjOptions::default(), &no_mtl) {
            Ok(()) => panic!("accepted:\n{text}"),
            Err(e) => e,
        }
    }

    #[test]
    fn a_bad_face_or_element_is_named_by_its_line() {
        let head = "# three vertices\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n";
        for (tail, line, needle) in [
            ("f -999999 1 2\n", 6, "vertex index -999999 reaches before the first: 3 vertices precede"),
            ("f 1 2 3\nf 0 1 2\n", 7, "vertex index 0: OBJ indices start at 1"),
            ("f 1 2 3\n\nf 1 2 4\n", 8, "vertex index 4, but the file defines 3 vertices"),
            ("f 1/1 2/7 3/1\n", 6, "texture coordinate index 7, but the file defines 1 texture coordinates"),
            ("f 1 2 x\n", 6, "`x` is not an integer"),
            ("v 1 2\nf 1 2 3\n", 6, "`v` (a vertex) needs 3 numbers"),
            ("v 1 2 3 0\nf 1 2 3\n", 6, "weight w of 0"),
            // What tobj would take silently or panic on: an index of 0 for a texture coordinate
            // or normal (read as missing), a relative one reaching before the first (a panic),
            // a face of two elements (dropped), non-finite numbers (zeroed or kept).
            ("vn 0 0 1\nf 1//0 2//1 3//1\n", 7, "normal index 0: OBJ indices start at 1"),
            ("f 1/0 2/1 3/1\n", 6, "texture coordinate index 0"),
            ("f 1/-9 2/-1 3/-1\n", 6, "texture coordinate index -9 reaches before the first: 1 texture"),
            ("vn 0 0 1\nf 1//1 2//-2 3//1\n", 7, "normal index -2 reaches before the first: 1 normals"),
            ("vn 0 0 1\nf 1//1 2//2 3//1\n", 7, "normal index 2, but the file defines 1 normals"),
            ("f 1 2\n", 6, "`f` (a face) needs at least 3 elements, got 2"),
            ("f\n", 6, "needs at least 3 elements, got 0"),
            ("l 1\n", 6, "`l` (a line) needs at least 2 elements, got 1"),
            ("vt 0.5 abc\nf 1 2 3\n", 6, "`vt` (a texture coordinate) needs 2 numbers"),
            ("vn 1 x 0\nf 1 2 3\n", 6, "`vn` (a normal) needs 3 numbers"),
            ("vt nan 0\nf 1/2 2/1 3/1\n", 6, "`vt` (a texture coordinate): `nan` is not a finite number"),
            ("vn 0 1e999 1\nf 1//1 2//1 3//1\n", 6, "`vn` (a normal): `1e999` is not a finite number"),
            ("v inf 0 0\nf 4 2 3\n", 6, "`v` (a vertex): `inf` is not a finite number"),
            ("v 0 0 0 NaN 1 1\nf 4 2 3\n", 6, "`NaN` is not a finite number"),
        ] {
            let text = format!("{head}{tail}");
            let error = obj_error(&text);
            assert_eq!(error.field, format!("line {line}"), "{text}: {error}");
            assert!(error.message.contains(needle), "{text}: {error}");
            assert!(error.to_string().starts_with("bad.obj: line "), "{error}");
        }
    }

    #[test]
    fn phong_mapping_is_monotone_and_bounded() {
        assert_eq!(phong_exponent_to_roughness(0.0), 1.0);
        let mut previous = 1.0;
        for ns in [1.0, 10.0, 40.0, 100.0, 1000.0, 1e6] {
            let r = phong_exponent_to_roughness(ns);
            assert!(r < previous && r > 0.0);
            previous = r;
        }
        assert!((phong_exponent_to_roughness(40.0) - (2.0f32 / 42.0).sqrt().sqrt()).abs() < 1e-6);
        assert_eq!(phong_exponent_to_roughness(f32::NAN), 1.0);
    }

    #[test]
    fn a_bad_mtl_line_is_named_with_the_file_and_its_number() {
        let dir = tempfile::tempdir().unwrap();
        let obj = dir.path().join("q.obj");
        std::fs::write(&obj, "mtllib q.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nusemtl a\nf 1 2 3\n").unwrap();
        let good = "# colours\nnewmtl a\n  Kd 0.5 0.5 0.5 \r\nKs 0 0 0\nNs 10\nillum 2\nmap_Kd\tdiffuse.png\n";
        // Each bad line replaces line 3 (a colour of two numbers made tobj panic).
        for (line, message) in [
            ("Kd 0.5 0.5", "`Kd` needs three numbers, got \"0.5 0.5\""),
            ("Ke 1 x 1", "`Ke` needs three numbers"),
            ("Ns", "`Ns` needs a number"),
            ("d one", "`d` needs a number"),
            ("illum 256", "`illum` needs an integer in 0..=255"),
            ("map_d   ", "`map_d` needs a file name"),
            ("newmtl", "`newmtl` needs a material name"),
        ] {
            let mut lines: Vec<&str> = good.lines().collect();
            lines[2] = line;
            std::fs::write(dir.path().join("q.mtl"), lines.join("\n")).unwrap();
            let error = load(&obj, &mut Scene::empty("test"), &ObjOptions::default()).unwrap_err();
            assert_eq!(error.field, "mtllib", "{line}");
            let expected = format!("{}, line 3: {message}", dir.path().join("q.mtl").display());
            assert!(error.to_string().contains(&expected), "{line}: expected {expected:?} in {error}");
        }
        let mut bytes = good.as_bytes().to_vec();
        bytes.extend_from_slice(b"newmtl \xff\n");
        assert_eq!(check_mtl(&bytes), Err((8, "not UTF-8 text".to_string())));
        assert_eq!(check_mtl(good.as_bytes()), Ok(()));
        // What the check accepts, tobj parses.
        assert!(tobj::load_mtl_buf(&mut std::io::Cursor::new(good)).is_ok());
    }

    #[test]
    fn texture_map_errors_name_the_material_library_read() {
        // Found by fuzzing: they named OBJ.mtl beside the OBJ, whatever `mtllib` said.
        let dir = tempfile::tempdir().unwrap();
        let obj = dir.path().join("q.obj");
        std::fs::write(&obj, "mtllib lib.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nusemtl a\nf 1 2 3\n").unwrap();
        std::fs::write(dir.path().join("lib.mtl"), "newmtl a\nmap_Kd missing.png\n").unwrap();
        let error = load(&obj, &mut Scene::empty("test"), &ObjOptions::default()).unwrap_err();
        assert_eq!(error.file, dir.path().join("lib.mtl"), "{error}");
        assert_eq!(error.field, "material 'a'.map_Kd", "{error}");
        assert!(error.message.contains("missing.png"), "{error}");
    }

    #[test]
    fn loads_a_quad_with_materials_and_flips_uv() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("q.mtl"),
            "newmtl lamp\nKd 0 0 0\nKe 5 4 3\nnewmtl shiny\nKd 0.5 0.5 0.5\nKs 0.5 0.5 0.5\nNs 40\n",
        )
        .unwrap();
        std::fs::write(
            dir.path().join("q.obj"),
            "mtllib q.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
             usemtl lamp\nf 1/1 2/2 3/3 4/4\no second\nusemtl shiny\nf 1/1 3/3 4/4\n",
        )
        .unwrap();
        let mut scene = Scene::empty("test");
        load(&dir.path().join("q.obj"), &mut scene, &ObjOptions::default()).unwrap();
        assert_eq!(scene.meshes.len(), 2);
        let lamp = &scene.materials[scene.meshes[0].material as usize];
        assert_eq!(lamp.emission, Vec3::new(5.0, 4.0, 3.0));
        assert_eq!(lamp.specular, 0.0);
        let shiny = &scene.materials[scene.meshes[1].material as usize];
        assert!((shiny.metallic - 0.5).abs() < 1e-6);
        assert_eq!(shiny.base_color, Vec3::ONE);
        assert_eq!(scene.meshes[0].indices.len(), 2);
        // v flipped: vertex 0 had vt (0, 0).
        let uvs = scene.meshes[0].uvs.as_ref().unwrap();
        assert!(uvs.iter().any(|uv| *uv == Vec2::new(0.0, 1.0)));
        // Normals were computed and face +z (counter-clockwise quad).
        assert!(scene.meshes[0].normals.as_ref().unwrap().iter().all(|n| (n.z - 1.0).abs() < 1e-6));
    }

    #[test]
    fn missing_texture_and_missing_file_name_the_culprit() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("t.mtl"), "newmtl m\nKd 1 1 1\nmap_Kd nothere.png\n").unwrap();
        std::fs::write(dir.path().join("t.obj"), "mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n")
            .unwrap();
        let mut scene = Scene::empty("test");
        let err = load(&dir.path().join("t.obj"), &mut scene, &ObjOptions::default()).unwrap_err();
        assert!(err.to_string().contains("nothere.png"), "{err}");
        assert!(err.field.contains("map_Kd"), "{err}");
        let err = load(&dir.path().join("absent.obj"), &mut scene, &ObjOptions::default()).unwrap_err();
        assert!(err.to_string().contains("absent.obj"));
    }

    #[test]
    fn malformed_obj_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("bad.obj"), "v 0 0 zero\nf 1 2 3\n").unwrap();
        let mut scene = Scene::empty("test");
        assert!(load(&dir.path().join("bad.obj"), &mut scene, &ObjOptions::default()).is_err());
        std::fs::write(dir.path().join("oob.obj"), "v 0 0 0\nf 1 2 7\n").unwrap();
        assert!(load(&dir.path().join("oob.obj"), &mut scene, &ObjOptions::default()).is_err());
    }

    #[test]
    fn nan_vertex_is_rejected_by_validation_with_the_field_named() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("nan.obj"), "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        let mut scene = Scene::empty("nan-test");
        match load(&dir.path().join("nan.obj"), &mut scene, &ObjOptions::default()) {
            Err(_) => {} // the parser may refuse "nan" outright, which is fine too
            Ok(()) => {
                let err = scene.validate().unwrap_err();
                assert!(err.field.contains("positions"), "{err}");
            }
        }
    }
}
