//! Reading `indirect` and `ao` sample files (docs/sample-format.md) into a struct of arrays,
//! through `sampleio` only. Paper Section 2.1: each record is one secondary ray from a primary
//! hit o in direction ω to a secondary hit h, with the radiance L it carried (`indirect`) or
//! its length (`ao`), the normals at both ends and the lobe concentration κ at h.
//!
//! Every record is kept, in file order, so that sample i belongs to pixel i / spp; its
//! [`SampleClass`] says which parts exist. A non-finite value in a field that a record of its
//! class needs is an error naming the file, the field and the sample (the tracer never writes
//! one; a tree built on NaN would fail silently much later). The only non-finite value
//! accepted is `distance` = +inf, the escape marker of `ao` files.

use sampleio::{SampleFile, SampleKind};

use crate::error::Error;

/// What one record holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum SampleClass {
    /// The camera ray escaped: no primary hit, only `direct` (the environment).
    CameraMiss,
    /// A primary hit without a secondary ray (the BSDF sample failed or fell below the surface).
    NoSecondaryRay,
    /// The secondary ray escaped the scene: a primary hit and an infinite ray, no secondary hit.
    Escaped,
    /// A secondary ray that hit a surface: a primary hit, a finite ray and a splat.
    Hit,
}

/// An `indirect` or `ao` file in memory, one entry per record in file order.
#[derive(Clone, Debug)]
pub struct IndirectSamples {
    /// The file, for messages.
    pub path: String,
    pub kind: SampleKind,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub class: Vec<SampleClass>,
    /// Film position, pixels.
    pub film: Vec<[f32; 2]>,
    /// o, world space (zero for a camera miss).
    pub primary_hit: Vec<[f32; 3]>,
    /// Unit shading normal at o facing the camera (zero for a camera miss).
    pub primary_normal: Vec<[f32; 3]>,
    /// ω, unit, from o towards h (zero without a secondary ray).
    pub direction: Vec<[f32; 3]>,
    /// h, world space (o when the ray escaped or was not traced).
    pub secondary_hit: Vec<[f32; 3]>,
    /// Unit shading normal at h facing o (zero unless `Hit`).
    pub secondary_normal: Vec<[f32; 3]>,
    /// L arriving at o from ω (`indirect` files).
    pub radiance: Option<Vec<[f32; 3]>>,
    /// |h − o|, +inf for an escaped ray (`ao` files).
    pub distance: Option<Vec<f32>>,
    /// κ of the vMF lobe at h (glossy `indirect` files; absent means 0 everywhere).
    pub kappa: Option<Vec<f32>>,
    /// Reflectance at o (`indirect`).
    pub albedo: Option<Vec<[f32; 3]>>,
    /// f·|cos|/pdf of ω at o (glossy `indirect`; `albedo` stands in for it when absent).
    pub weight: Option<Vec<[f32; 3]>>,
    /// Direct light at o towards the camera (`indirect`).
    pub direct: Option<Vec<[f32; 3]>>,
    /// Reflectance at h (`indirect`).
    pub secondary_albedo: Option<Vec<[f32; 3]>>,
    /// The part of L that h reflects straight from emitters (`indirect`).
    pub secondary_direct: Option<Vec<[f32; 3]>>,
    /// o's BSDF, geometric normal and view direction (glossy `indirect` files; zeros for a camera
    /// miss).
    pub primary_shading: Option<Vec<PrimaryShading>>,
    /// h's BSDF (glossy `indirect` files; neutral unless the sample is a `Hit`), for recursive
    /// filtering at glossy secondary hits.
    pub secondary_bsdf: Option<Vec<shading::Bsdf>>,
    /// Time of each ray over the shutter, and the displacement of its hit over the whole
    /// shutter (moving `lens-time` input of the lens mode; `None`: nothing moves).
    pub time: Option<Vec<f32>>,
    pub secondary_motion: Option<Vec<[f32; 3]>>,
}

/// What the final gather needs to shade a primary hit with its own BSDF (paper Eq. 3; design
/// gaps G1, G2): read from the `origin_*` BSDF fields, the header's camera and `u`, `v`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimaryShading {
    pub bsdf: shading::Bsdf,
    /// Unit geometric normal at o, on the side of the shading normal: no direction below it.
    pub geometric_normal: [f32; 3],
    /// ωo: unit direction from o to the point on the lens its camera ray left from.
    pub to_eye: [f32; 3],
}

/// The fields of o's BSDF with their components, in record order.
pub const PRIMARY_BSDF_FIELDS: [(&str, usize); 6] = [
    ("origin_base_color", 3),
    ("origin_metallic", 1),
    ("origin_roughness", 1),
    ("origin_specular", 1),
    ("origin_f0", 1),
    ("origin_geometric_normal", 2),
];

impl IndirectSamples {
    /// No records yet, room for `capacity` in the always-present arrays, no optional field.
    pub fn empty(path: String, kind: SampleKind, (width, height, spp): (u32, u32, u32), capacity: usize) -> Self {
        IndirectSamples {
            path,
            kind,
            width,
            height,
            spp,
            class: Vec::with_capacity(capacity),
            film: Vec::with_capacity(capacity),
            primary_hit: Vec::with_capacity(capacity),
            primary_normal: Vec::with_capacity(capacity),
            direction: Vec::with_capacity(capacity),
            secondary_hit: Vec::with_capacity(capacity),
            secondary_normal: Vec::with_capacity(capacity),
            radiance: None,
            distance: None,
            kappa: None,
            albedo: None,
            weight: None,
            direct: None,
            secondary_albedo: None,
            secondary_direct: None,
            primary_shading: None,
            secondary_bsdf: None,
            time: None,
            secondary_motion: None,
        }
    }

    pub fn len(&self) -> usize {
        self.class.len()
    }

    pub fn is_empty(&self) -> bool {
        self.class.is_empty()
    }

    /// Indices of the samples whose secondary ray hit a surface (the splats), ascending.
    pub fn hits(&self) -> Vec<u32> {
        (0..self.len() as u32).filter(|&i| self.class[i as usize] == SampleClass::Hit).collect()
    }

    /// The time of sample i's ray (0 when nothing moves).
    pub fn time_of(&self, i: usize) -> f32 {
        self.time.as_ref().map_or(0.0, |t| t[i])
    }

    /// Where sample i's hit is at time 0.5, the time moving splats are indexed at.
    pub fn secondary_hit_at_middle(&self, i: usize) -> [f32; 3] {
        let h = self.secondary_hit[i];
        match &self.secondary_motion {
            Some(motion) => {
                let shift = 0.5 - self.time_of(i);
                [0, 1, 2].map(|a| h[a] + shift * motion[i][a])
            }
            None => h,
        }
    }

    /// κ of sample i (0 when the file has no `bandwidth`).
    pub fn kappa_of(&self, i: usize) -> f32 {
        self.kappa.as_ref().map_or(0.0, |k| k[i])
    }

    /// How many samples of each class, in the order of [`SampleClass`].
    pub fn class_counts(&self) -> [usize; 4] {
        let mut counts = [0; 4];
        for class in &self.class {
            counts[*class as usize] += 1;
        }
        counts
    }
}

/// Decodes an octahedral u16 pair (docs/sample-format.md); (0, 0) is "no vector" → `None`.
pub use crate::octahedral::decode as decode_octahedral;

/// Reads an `indirect` or `ao` file; errors name the file and the missing or bad field.
pub fn read_indirect(file: &SampleFile) -> Result<IndirectSamples, Error> {
    let path = file.path().display().to_string();
    let content = |message: String| Error::sample_content(file.path(), message);
    let header = file.header();
    let kind = header.kind;
    if kind != SampleKind::Indirect && kind != SampleKind::Ao {
        return Err(content(format!("ILFR reads `indirect` or `ao` samples, the file holds `{}`", kind.name())));
    }
    if let Some(needs) = crate::needs::ilfr(kind) {
        file.check_needs(needs)?;
    }
    let column = |name: &str, components: usize| -> Result<Option<Vec<f32>>, Error> {
        let Some(field) = file.field(name) else { return Ok(None) };
        if field.components as usize != components {
            return Err(content(format!("field `{name}` has {} components, {components} expected", field.components)));
        }
        Ok(Some(file.column(name)?))
    };
    let required = |name: &str, components: usize| -> Result<Vec<f32>, Error> {
        column(name, components)?.ok_or_else(|| content(format!("`{}` samples lack the field `{name}`", kind.name())))
    };
    let n = file.len();
    let film_x = required("x", 1)?;
    let film_y = required("y", 1)?;
    let direction_q = required("direction", 2)?;
    let origin = required("origin", 3)?;
    let hit = required("hit", 3)?;
    let origin_normal_q = required("origin_normal", 2)?;
    let hit_normal_q = required("hit_normal", 2)?;
    let (radiance, distance) = match kind {
        SampleKind::Indirect => (Some(required("radiance", 3)?), None),
        _ => (None, Some(required("distance", 1)?)),
    };
    let kappa = column("bandwidth", 1)?;
    let optional3 = |name: &str| column(name, 3);
    let (albedo, weight, direct) = (optional3("albedo")?, optional3("weight")?, optional3("direct")?);
    let (secondary_albedo, secondary_direct) = (optional3("secondary_albedo")?, optional3("secondary_direct")?);

    let bad = |name: &str, i: usize, what: &str| {
        let pixel = i / header.spp as usize;
        content(format!(
            "field `{name}` of sample {i} (pixel {}, {}) is {what}",
            pixel % header.width as usize,
            pixel / header.width as usize
        ))
    };
    let vec3 = |values: &[f32], i: usize| [values[3 * i], values[3 * i + 1], values[3 * i + 2]];
    let finite3 = |name: &str, values: &[f32], i: usize| -> Result<[f32; 3], Error> {
        let v = vec3(values, i);
        if v.iter().all(|c| c.is_finite()) {
            Ok(v)
        } else {
            Err(bad(name, i, &format!("not finite: {v:?}")))
        }
    };

    let mut samples = IndirectSamples::empty(path.clone(), kind, (header.width, header.height, header.spp), n);
    for i in 0..n {
        let (x, y) = (film_x[i], film_y[i]);
        if !(x.is_finite() && y.is_finite()) {
            return Err(bad(if x.is_finite() { "y" } else { "x" }, i, "not finite"));
        }
        let origin_normal = decode_octahedral([origin_normal_q[2 * i], origin_normal_q[2 * i + 1]]);
        let direction = decode_octahedral([direction_q[2 * i], direction_q[2 * i + 1]]);
        let hit_normal = decode_octahedral([hit_normal_q[2 * i], hit_normal_q[2 * i + 1]]);
        let escaped_ao = distance.as_ref().is_some_and(|d| d[i] == f32::INFINITY);
        let class = match (origin_normal, direction, hit_normal) {
            (None, _, _) => SampleClass::CameraMiss,
            (Some(_), None, _) => SampleClass::NoSecondaryRay,
            (Some(_), Some(_), None) => SampleClass::Escaped,
            (Some(_), Some(_), Some(_)) if escaped_ao => SampleClass::Escaped,
            (Some(_), Some(_), Some(_)) => SampleClass::Hit,
        };
        let zero = [0.0; 3];
        let (primary_hit, secondary_hit) = if class == SampleClass::CameraMiss {
            (zero, zero)
        } else {
            (finite3("origin", &origin, i)?, finite3("hit", &hit, i)?)
        };
        if class == SampleClass::Hit {
            if let Some(d) = &distance {
                if !d[i].is_finite() || d[i] < 0.0 {
                    return Err(bad("distance", i, &format!("{} for a ray that hit a surface", d[i])));
                }
            }
        }
        samples.class.push(class);
        samples.film.push([x, y]);
        samples.primary_hit.push(primary_hit);
        samples.primary_normal.push(origin_normal.unwrap_or(zero));
        samples.direction.push(if class == SampleClass::CameraMiss { zero } else { direction.unwrap_or(zero) });
        samples.secondary_hit.push(secondary_hit);
        samples.secondary_normal.push(if class == SampleClass::Hit { hit_normal.unwrap_or(zero) } else { zero });
    }

    // Per-sample optional values: finite wherever the class uses them.
    let uses_ray = |i: usize| matches!(samples.class[i], SampleClass::Hit | SampleClass::Escaped);
    let has_primary = |i: usize| samples.class[i] != SampleClass::CameraMiss;
    let check3 = |name: &str, values: Option<Vec<f32>>, needed: &dyn Fn(usize) -> bool| {
        values
            .map(|values| {
                (0..n)
                    .map(|i| if needed(i) { finite3(name, &values, i) } else { Ok(vec3(&values, i)) })
                    .collect::<Result<Vec<_>, Error>>()
            })
            .transpose()
    };
    let always = |_: usize| true;
    samples.radiance = check3("radiance", radiance, &uses_ray)?;
    samples.albedo = check3("albedo", albedo, &has_primary)?;
    samples.weight = check3("weight", weight, &has_primary)?;
    samples.direct = check3("direct", direct, &always)?;
    samples.secondary_albedo = check3("secondary_albedo", secondary_albedo, &uses_ray)?;
    samples.secondary_direct = check3("secondary_direct", secondary_direct, &uses_ray)?;
    if let Some(kappa) = &kappa {
        for (i, &k) in kappa.iter().enumerate() {
            if !(k.is_finite() && k >= 0.0) {
                return Err(bad("bandwidth", i, &format!("{k}, not a concentration κ ≥ 0")));
            }
        }
    }
    samples.kappa = kappa;
    samples.distance = distance;
    samples.primary_shading = read_primary_shading(file, &samples, &column, &bad)?;
    let is_hit = |i: usize| samples.class[i] == SampleClass::Hit;
    samples.secondary_bsdf = read_bsdfs("hit", &samples, &column, &bad, &is_hit)?;
    Ok(samples)
}

/// Reads an optional column with its expected components (`None` when the file lacks it).
type ColumnReader<'a> = dyn Fn(&str, usize) -> Result<Option<Vec<f32>>, Error> + 'a;

/// The five BSDF fields `{prefix}_base_color`, `_metallic`, `_roughness`, `_specular`, `_f0`
/// (all or none: `None` when the file has none), parsed for every sample where `used(i)`; a
/// neutral BSDF elsewhere. Values out of the BSDF's ranges are errors naming field and sample.
fn read_bsdfs(
    prefix: &str,
    samples: &IndirectSamples,
    column: &ColumnReader,
    bad: &dyn Fn(&str, usize, &str) -> Error,
    used: &dyn Fn(usize) -> bool,
) -> Result<Option<Vec<shading::Bsdf>>, Error> {
    let names = ["base_color", "metallic", "roughness", "specular", "f0"].map(|n| format!("{prefix}_{n}"));
    let mut columns = Vec::with_capacity(5);
    for (k, name) in names.iter().enumerate() {
        columns.push(column(name, if k == 0 { 3 } else { 1 })?);
    }
    if columns.iter().all(Option::is_none) {
        return Ok(None);
    }
    if let Some(k) = columns.iter().position(Option::is_none) {
        let message = format!("the file has some of the fields of {prefix}'s BSDF but lacks `{}`", names[k]);
        return Err(Error::sample_content(&samples.path, message));
    }
    let columns: Vec<Vec<f32>> = columns.into_iter().map(Option::unwrap_or_default).collect();
    let [base, metallic, roughness, specular, f0] = &columns[..] else { unreachable!("five columns") };
    let neutral = shading::Bsdf { base_color: glam::Vec3::ZERO, metallic: 0.0, alpha: 1.0, specular: 0.0, f0: 0.0 };
    let mut bsdfs = Vec::with_capacity(samples.len());
    for i in 0..samples.len() {
        if !used(i) {
            bsdfs.push(neutral);
            continue;
        }
        let base_color = [base[3 * i], base[3 * i + 1], base[3 * i + 2]];
        if !base_color.iter().all(|c| c.is_finite() && *c >= 0.0) {
            return Err(bad(&names[0], i, &format!("{base_color:?}, not a colour ≥ 0")));
        }
        let unit = |k: usize, values: &[f32]| {
            let value = values[i];
            if (0.0..=1.0).contains(&value) {
                Ok(value)
            } else {
                Err(bad(&names[k], i, &format!("{value}, not in [0, 1]")))
            }
        };
        let roughness = unit(2, roughness)?;
        bsdfs.push(shading::Bsdf {
            base_color: glam::Vec3::from(base_color),
            metallic: unit(1, metallic)?,
            alpha: (roughness * roughness).max(shading::MIN_ALPHA),
            specular: unit(3, specular)?,
            f0: unit(4, f0)?,
        });
    }
    Ok(Some(bsdfs))
}

/// o's BSDF from the `origin_*` fields (all or none, `origin_geometric_normal` included), ωo
/// from the header's camera and the lens position.
fn read_primary_shading(
    file: &SampleFile,
    samples: &IndirectSamples,
    column: &ColumnReader,
    bad: &dyn Fn(&str, usize, &str) -> Error,
) -> Result<Option<Vec<PrimaryShading>>, Error> {
    let content = |message: &str| Error::sample_content(&samples.path, message);
    let has_primary = |i: usize| samples.class[i] != SampleClass::CameraMiss;
    let bsdfs = read_bsdfs("origin", samples, column, bad, &has_primary)?;
    let geometric = column("origin_geometric_normal", 2)?;
    let (bsdfs, geometric) = match (bsdfs, geometric) {
        (None, None) => return Ok(None),
        (Some(b), Some(g)) => (b, g),
        (Some(_), None) => return Err(content("the file has o's BSDF but lacks `origin_geometric_normal`")),
        (None, Some(_)) => return Err(content("the file has `origin_geometric_normal` but lacks `origin_base_color`")),
    };
    let camera =
        file.header().camera.as_ref().ok_or_else(|| {
            content("o's BSDF needs the header's `camera` (where the view direction at o comes from)")
        })?;
    let (u, v) = (column("u", 1)?, column("v", 1)?);
    let to_f32 = |a: [f64; 3]| a.map(|c| c as f32);
    let (position, right, up) = (to_f32(camera.position), to_f32(camera.right), to_f32(camera.up));
    let aperture = camera.aperture_radius as f32;
    let mut per_sample = Vec::with_capacity(samples.len());
    for (i, bsdf) in bsdfs.into_iter().enumerate() {
        if !has_primary(i) {
            per_sample.push(PrimaryShading { bsdf, geometric_normal: [0.0; 3], to_eye: [0.0; 3] });
            continue;
        }
        let geometric_normal = decode_octahedral([geometric[2 * i], geometric[2 * i + 1]])
            .ok_or_else(|| bad("origin_geometric_normal", i, "no vector at a primary hit"))?;
        let (lens_u, lens_v) = (u.as_ref().map_or(0.0, |u| u[i]), v.as_ref().map_or(0.0, |v| v[i]));
        if !(lens_u.is_finite() && lens_v.is_finite()) {
            return Err(bad(if lens_u.is_finite() { "v" } else { "u" }, i, "not finite"));
        }
        // The tracer stores v along image +y (down): the lens point is p + r (u·right − v·up).
        let eye = [0, 1, 2].map(|a| position[a] + aperture * (lens_u * right[a] - lens_v * up[a]));
        let o = samples.primary_hit[i];
        let to_eye = crate::vector::normalize([0, 1, 2].map(|a| eye[a] - o[a]));
        per_sample.push(PrimaryShading { bsdf, geometric_normal, to_eye });
    }
    Ok(Some(per_sample))
}

#[cfg(test)]
mod tests {
    use super::*;
    use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleWriter};

    /// Octahedral encoding, written independently of the decoder from the format's definition.
    fn encode(n: [f32; 3]) -> [f32; 2] {
        let l1 = n[0].abs() + n[1].abs() + n[2].abs();
        let (mut px, mut py) = (n[0] / l1, n[1] / l1);
        if n[2] < 0.0 {
            let (ox, oy) = (px, py);
            px = (1.0 - oy.abs()) * if ox >= 0.0 { 1.0 } else { -1.0 };
            py = (1.0 - ox.abs()) * if oy >= 0.0 { 1.0 } else { -1.0 };
        }
        [((px + 1.0) * 0.5 * 65534.0).round() + 1.0, ((py + 1.0) * 0.5 * 65534.0).round() + 1.0]
    }

    fn indirect_spec(glossy: bool) -> HeaderSpec {
        let mut spec = HeaderSpec::new(SampleKind::Indirect, 2, 1, 2)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("y", FieldType::F32, 1))
            .field(FieldSpec::new("direction", FieldType::U16, 2))
            .field(FieldSpec::new("radiance", FieldType::F32, 3))
            .field(FieldSpec::new("origin", FieldType::F32, 3))
            .field(FieldSpec::new("hit", FieldType::F32, 3))
            .field(FieldSpec::new("origin_normal", FieldType::U16, 2))
            .field(FieldSpec::new("hit_normal", FieldType::U16, 2));
        if glossy {
            spec = spec.field(FieldSpec::new("bandwidth", FieldType::F16, 1));
        }
        spec.field(FieldSpec::new("albedo", FieldType::F16, 3))
    }

    struct Record {
        direction: Option<[f32; 3]>,
        radiance: [f32; 3],
        origin: [f32; 3],
        hit: [f32; 3],
        origin_normal: Option<[f32; 3]>,
        hit_normal: Option<[f32; 3]>,
        kappa: f32,
    }

    fn row(r: &Record, glossy: bool) -> Vec<f32> {
        let oct = |v: Option<[f32; 3]>| v.map_or([0.0, 0.0], encode);
        let mut row = vec![0.5, 0.5];
        row.extend_from_slice(&oct(r.direction));
        row.extend_from_slice(&r.radiance);
        row.extend_from_slice(&r.origin);
        row.extend_from_slice(&r.hit);
        row.extend_from_slice(&oct(r.origin_normal));
        row.extend_from_slice(&oct(r.hit_normal));
        if glossy {
            row.push(r.kappa);
        }
        row.extend_from_slice(&[0.5, 0.5, 0.5]);
        row
    }

    fn write(dir: &std::path::Path, spec: HeaderSpec, rows: &[Vec<f32>]) -> std::path::PathBuf {
        let path = dir.join("samples.lfrs");
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        for r in rows {
            writer.push(r).unwrap();
        }
        writer.finish().unwrap()
    }

    fn four_records() -> Vec<Record> {
        let up = Some([0.0, 0.0, 1.0]);
        let s = 0.6f32.sqrt();
        vec![
            // Camera miss.
            Record {
                direction: None,
                radiance: [0.0; 3],
                origin: [0.0; 3],
                hit: [0.0; 3],
                origin_normal: None,
                hit_normal: None,
                kappa: 0.0,
            },
            // Failed BSDF sample.
            Record {
                direction: None,
                radiance: [0.0; 3],
                origin: [1.0, 2.0, 3.0],
                hit: [1.0, 2.0, 3.0],
                origin_normal: up,
                hit_normal: None,
                kappa: 0.0,
            },
            // Escaped.
            Record {
                direction: Some([0.0, s, (1.0f32 - 0.6).sqrt()]),
                radiance: [0.1, 0.2, 0.3],
                origin: [1.0, 2.0, 3.0],
                hit: [1.0, 2.0, 3.0],
                origin_normal: up,
                hit_normal: None,
                kappa: 0.0,
            },
            // Hit: from (0, 0, 0) straight up to (0, 0, 2) on a ceiling facing down.
            Record {
                direction: up,
                radiance: [1.0, 2.0, 3.0],
                origin: [0.0; 3],
                hit: [0.0, 0.0, 2.0],
                origin_normal: up,
                hit_normal: Some([0.0, 0.0, -1.0]),
                kappa: 40.0,
            },
        ]
    }

    #[test]
    fn classes_vectors_and_optional_fields_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let rows: Vec<_> = four_records().iter().map(|r| row(r, true)).collect();
        let path = write(dir.path(), indirect_spec(true), &rows);
        let samples = read_indirect(&SampleFile::open(&path).unwrap()).unwrap();
        assert_eq!(
            samples.class,
            [SampleClass::CameraMiss, SampleClass::NoSecondaryRay, SampleClass::Escaped, SampleClass::Hit]
        );
        assert_eq!(samples.class_counts(), [1, 1, 1, 1]);
        assert_eq!(samples.hits(), [3]);
        assert_eq!((samples.width, samples.height, samples.spp), (2, 1, 2));
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-4);
        assert!(close(samples.direction[3], [0.0, 0.0, 1.0]));
        assert!(close(samples.secondary_normal[3], [0.0, 0.0, -1.0]), "{:?}", samples.secondary_normal[3]);
        assert!(close(samples.direction[2], [0.0, 0.6f32.sqrt(), 0.4f32.sqrt()]), "{:?}", samples.direction[2]);
        assert_eq!(samples.secondary_normal[2], [0.0; 3], "an escaped ray has no secondary normal");
        assert_eq!(samples.secondary_hit[3], [0.0, 0.0, 2.0]);
        assert_eq!(samples.radiance.as_ref().unwrap()[3], [1.0, 2.0, 3.0]);
        assert_eq!(samples.kappa_of(3), 40.0);
        assert!(samples.distance.is_none() && samples.weight.is_none() && samples.albedo.is_some());

        let rows: Vec<_> = four_records().iter().map(|r| row(r, false)).collect();
        let path = write(dir.path(), indirect_spec(false), &rows);
        let samples = read_indirect(&SampleFile::open(&path).unwrap()).unwrap();
        assert!(samples.kappa.is_none());
        assert_eq!(samples.kappa_of(3), 0.0, "no `bandwidth`: κ = 0");
    }

    /// `four_records` with o's BSDF, the lens position and the camera block: rows and spec.
    fn with_primary_bsdf(metallic: f32, leave_out: Option<&str>) -> (HeaderSpec, Vec<Vec<f32>>) {
        let mut spec = indirect_spec(true);
        for (name, components) in PRIMARY_BSDF_FIELDS {
            if Some(name) != leave_out {
                let ty = if name == "origin_geometric_normal" { FieldType::U16 } else { FieldType::F16 };
                spec = spec.field(FieldSpec::new(name, ty, components as u32));
            }
        }
        spec = spec.field(FieldSpec::new("u", FieldType::F32, 1)).field(FieldSpec::new("v", FieldType::F32, 1));
        spec.camera = Some(crate::tlfr::lens::tests::camera());
        let rows = four_records()
            .iter()
            .map(|r| {
                let mut values = row(r, true);
                let bsdf: [(&str, Vec<f32>); 6] = [
                    ("origin_base_color", vec![0.5, 0.25, 1.0]),
                    ("origin_metallic", vec![metallic]),
                    ("origin_roughness", vec![0.5]),
                    ("origin_specular", vec![1.0]),
                    ("origin_f0", vec![0.04]),
                    ("origin_geometric_normal", encode([0.0, 0.6, 0.8]).to_vec()),
                ];
                for (name, v) in bsdf {
                    if Some(name) != leave_out {
                        values.extend(v);
                    }
                }
                values.extend([0.5, -0.5]); // u, v
                values
            })
            .collect();
        (spec, rows)
    }

    #[test]
    fn the_primary_bsdf_and_the_view_direction_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let (spec, rows) = with_primary_bsdf(0.75, None);
        let samples = read_indirect(&SampleFile::open(write(dir.path(), spec, &rows)).unwrap()).unwrap();
        let shading = samples.primary_shading.as_ref().expect("the file has o's BSDF");
        let hit = &shading[3];
        assert_eq!(hit.bsdf.metallic, 0.75);
        assert_eq!(hit.bsdf.alpha, 0.25, "α = roughness²");
        assert_eq!(hit.bsdf.base_color, glam::Vec3::new(0.5, 0.25, 1.0));
        assert!((hit.bsdf.f0 - 0.04).abs() < 1e-4 && hit.bsdf.specular == 1.0);
        assert!((glam::Vec3::from(hit.geometric_normal) - glam::Vec3::new(0.0, 0.6, 0.8)).length() < 1e-4);
        // Camera at the origin, right = +x, up = −y, lens radius 0.1: (u, v) = (0.5, −0.5) is
        // the lens point (0.05, −0.05, 0); o = (1, 2, 3) for the escaped record.
        let expected = glam::Vec3::new(0.05 - 1.0, -0.05 - 2.0, -3.0).normalize();
        assert!((glam::Vec3::from(shading[2].to_eye) - expected).length() < 1e-5, "{:?}", shading[2].to_eye);
        assert_eq!(shading[0].to_eye, [0.0; 3], "a camera miss has no view direction");
    }

    #[test]
    fn partial_or_out_of_range_primary_bsdfs_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let (spec, rows) = with_primary_bsdf(0.75, Some("origin_f0"));
        let error = read_indirect(&SampleFile::open(write(dir.path(), spec, &rows)).unwrap()).unwrap_err().to_string();
        assert!(error.contains("samples.lfrs") && error.contains("`origin_f0`"), "{error}");
        let (spec, rows) = with_primary_bsdf(1.5, None);
        let error = read_indirect(&SampleFile::open(write(dir.path(), spec, &rows)).unwrap()).unwrap_err().to_string();
        assert!(error.contains("`origin_metallic` of sample 1") && error.contains("not in [0, 1]"), "{error}");
        let (mut spec, rows) = with_primary_bsdf(0.5, None);
        spec.camera = None;
        let error = read_indirect(&SampleFile::open(write(dir.path(), spec, &rows)).unwrap()).unwrap_err().to_string();
        assert!(error.contains("`camera`"), "{error}");
    }

    #[test]
    fn octahedral_decoding_matches_the_definition_everywhere() {
        let mut worst = 0.0f32;
        for i in 0..48 {
            for j in 0..24 {
                let (phi, theta) = (i as f32 / 48.0 * std::f32::consts::TAU, j as f32 / 23.0 * std::f32::consts::PI);
                let n = [theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()];
                let d = decode_octahedral(encode(n)).unwrap();
                worst = worst.max(((d[0] - n[0]).powi(2) + (d[1] - n[1]).powi(2) + (d[2] - n[2]).powi(2)).sqrt());
            }
        }
        assert!(worst < 1e-4, "{worst}");
        assert_eq!(decode_octahedral([0.0, 0.0]), None);
    }

    #[test]
    fn ambient_occlusion_escapes_are_infinite_distances() {
        let dir = tempfile::tempdir().unwrap();
        let spec = HeaderSpec::new(SampleKind::Ao, 1, 1, 2)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("y", FieldType::F32, 1))
            .field(FieldSpec::new("direction", FieldType::U16, 2))
            .field(FieldSpec::new("distance", FieldType::F32, 1))
            .field(FieldSpec::new("origin", FieldType::F32, 3))
            .field(FieldSpec::new("hit", FieldType::F32, 3))
            .field(FieldSpec::new("origin_normal", FieldType::U16, 2))
            .field(FieldSpec::new("hit_normal", FieldType::U16, 2));
        let up = encode([0.0, 0.0, 1.0]);
        let down = encode([0.0, 0.0, -1.0]);
        let rows = [
            [&[0.5, 0.5][..], &up, &[f32::INFINITY], &[0.0; 3], &[0.0; 3], &up, &[0.0, 0.0]].concat(),
            [&[0.5, 0.5][..], &up, &[2.0], &[0.0; 3], &[0.0, 0.0, 2.0], &up, &down].concat(),
        ];
        let path = write(dir.path(), spec.clone(), &rows);
        let samples = read_indirect(&SampleFile::open(&path).unwrap()).unwrap();
        assert_eq!(samples.class, [SampleClass::Escaped, SampleClass::Hit]);
        assert!(samples.radiance.is_none());
        assert_eq!(samples.distance.as_ref().unwrap(), &[f32::INFINITY, 2.0]);

        // A hit whose distance is NaN is rejected, naming the field.
        let rows = [rows[0].clone(), [&[0.5, 0.5][..], &up, &[f32::NAN], &[0.0; 3], &[0.0; 3], &up, &down].concat()];
        let path = write(dir.path(), spec, &rows);
        let error = read_indirect(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
        assert!(error.contains("`distance`") && error.contains("sample 1"), "{error}");
    }

    #[test]
    fn bad_files_are_named_with_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let mut records = four_records();
        records[3].hit = [0.0, f32::NAN, 2.0];
        let rows: Vec<_> = records.iter().map(|r| row(r, true)).collect();
        let path = write(dir.path(), indirect_spec(true), &rows);
        let error = read_indirect(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
        assert!(error.contains("samples.lfrs") && error.contains("`hit`") && error.contains("sample 3"), "{error}");
        assert!(error.contains("pixel 1, 0"), "{error}");

        let mut records = four_records();
        records[3].radiance = [f32::INFINITY, 0.0, 0.0];
        let rows: Vec<_> = records.iter().map(|r| row(r, true)).collect();
        let path = write(dir.path(), indirect_spec(true), &rows);
        let error = read_indirect(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
        assert!(error.contains("`radiance`"), "{error}");

        // A camera miss may carry anything in the fields it does not use.
        let mut records = four_records();
        records[0].radiance = [f32::NAN; 3];
        let rows: Vec<_> = records.iter().map(|r| row(r, true)).collect();
        let path = write(dir.path(), indirect_spec(true), &rows);
        assert!(read_indirect(&SampleFile::open(&path).unwrap()).is_ok());

        let spec = HeaderSpec::new(SampleKind::Indirect, 1, 1, 1).field(FieldSpec::new("x", FieldType::F32, 1));
        let path = write(dir.path(), spec, &[vec![0.5]]);
        let error = read_indirect(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
        assert!(error.contains("`y`") && error.contains("samples.lfrs"), "{error}");

        let spec = HeaderSpec::new(SampleKind::LensTime, 1, 1, 1).field(FieldSpec::new("x", FieldType::F32, 1));
        let path = write(dir.path(), spec, &[vec![0.5]]);
        let error = read_indirect(&SampleFile::open(&path).unwrap()).unwrap_err().to_string();
        assert!(error.contains("lens-time"), "{error}");
    }
}
