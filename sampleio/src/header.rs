//! The JSON header: what the file holds (kind, image size, samples per pixel, the field list),
//! the camera and light it was made with, and the validation every reader applies.

use std::collections::{BTreeMap, HashSet};
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::error::InvalidHeader;
use crate::field::{self, Field, FieldSpec, MAX_COMPONENTS};

/// Magic at the start of every sample file.
pub const MAGIC: [u8; 8] = *b"LFRSAMP\0";
/// Magic at the start of the trailer.
pub const TRAILER_MAGIC: [u8; 8] = *b"LFRTAIL\0";
/// Version of the sample format this crate reads and writes.
pub const FORMAT_VERSION: u32 = 1;
/// The header's `"format"` value.
pub const FORMAT_NAME: &str = "lfr-samples";
/// Bytes of the preamble (magic, version, header length).
pub const PREAMBLE_LEN: u64 = 16;
/// Bytes of the trailer.
pub const TRAILER_LEN: u64 = 32;
/// The data area starts at a multiple of this many bytes from the start of the file.
pub const DATA_ALIGN: u64 = 64;
/// Longest header text, in bytes (16 MiB).
pub const MAX_HEADER_LEN: u64 = 16 << 20;
/// Largest image width or height.
pub const MAX_DIMENSION: u32 = 65536;
/// Most samples per pixel.
pub const MAX_SPP: u32 = 1 << 20;
/// Most fields per record.
pub const MAX_FIELDS: usize = 64;
/// Largest record, in bytes.
pub const MAX_RECORD_SIZE: u32 = 65536;
/// Samples per checksum chunk unless the header says otherwise.
pub const DEFAULT_CHUNK_SAMPLES: u32 = 65536;

/// What the samples are samples of. The per-kind field lists are defined by the tracer's dump
/// command; this crate only names the kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SampleKind {
    /// Camera samples over pixel, lens and shutter (temporal light field).
    LensTime,
    /// Samples over an area light (soft shadows).
    Light,
    /// Indirect illumination samples.
    Indirect,
    /// Ambient-occlusion samples.
    Ao,
}

impl SampleKind {
    pub const ALL: [SampleKind; 4] = [SampleKind::LensTime, SampleKind::Light, SampleKind::Indirect, SampleKind::Ao];

    /// The name used in the header.
    pub const fn name(self) -> &'static str {
        match self {
            SampleKind::LensTime => "lens-time",
            SampleKind::Light => "light",
            SampleKind::Indirect => "indirect",
            SampleKind::Ao => "ao",
        }
    }
}

impl fmt::Display for SampleKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SampleKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        SampleKind::ALL.into_iter().find(|k| k.name() == s).ok_or_else(|| {
            let known: Vec<&str> = SampleKind::ALL.iter().map(|k| k.name()).collect();
            format!("unknown sample kind {s:?} (known: {})", known.join(", "))
        })
    }
}

impl Serialize for SampleKind {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for SampleKind {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// Order of the samples in the data area. Version 1 knows one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SampleOrder {
    /// The samples of pixel (x, y) are at indices `(y * width + x) * spp + s`, `s < spp`.
    #[default]
    PixelMajor,
}

/// Which image side `fov_deg` spans.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FovAxis {
    X,
    #[default]
    Y,
    /// The shorter image side.
    Smaller,
    /// The longer image side.
    Larger,
}

/// Signed circle of confusion in pixels as a function of camera-space depth z:
/// `C(z) = c1 / z + c2`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Coc {
    pub c1: f64,
    pub c2: f64,
}

impl Coc {
    /// `c1 / z + c2`.
    pub fn at(&self, z: f64) -> f64 {
        self.c1 / z + self.c2
    }
}

/// The camera the samples were taken with. All keys are required when the object is present.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// World-space position of the lens center.
    pub position: [f64; 3],
    /// Unit viewing direction (world space).
    pub forward: [f64; 3],
    /// Unit up vector (world space), orthogonal to `forward`.
    pub up: [f64; 3],
    /// Unit right vector (world space): the direction of increasing pixel x.
    pub right: [f64; 3],
    /// Full field of view along `fov_axis`, degrees.
    pub fov_deg: f64,
    pub fov_axis: FovAxis,
    /// Lens radius, world units (0 for a pinhole).
    pub aperture_radius: f64,
    /// Distance to the plane in focus, world units.
    pub focus_distance: f64,
    pub coc: Coc,
    /// Shutter open and close times; the sample time t in [0, 1] maps linearly onto it.
    pub shutter: [f64; 2],
    /// 4x4 row-major matrix from homogeneous pixel coordinates (x, y, 1, 1) to camera space.
    pub pixel_to_camera: [[f64; 4]; 4],
    /// 4x4 row-major matrix from homogeneous world coordinates to camera space.
    pub world_to_camera: [[f64; 4]; 4],
}

/// Geometry of the area light that light samples are taken over. Every key is optional; what
/// a light needs beyond these belongs in `extra`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightGeometry {
    /// One corner of a parallelogram light (world space).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub corner: Option<[f64; 3]>,
    /// Edge from `corner` along the light's u axis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub edge_u: Option<[f64; 3]>,
    /// Edge from `corner` along the light's v axis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub edge_v: Option<[f64; 3]>,
    /// Unit normal of the emitting side.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal: Option<[f64; 3]>,
    /// Distance of the light's plane along `normal` from the origin (`dot(normal, corner)`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_distance: Option<f64>,
}

fn default_chunk_samples() -> u32 {
    DEFAULT_CHUNK_SAMPLES
}

/// The parsed header. Construct it through [`HeaderSpec`] (writer) or
/// [`SampleFile::open`](crate::SampleFile::open) (reader); both validate it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    /// Always `"lfr-samples"`.
    pub format: String,
    /// Always equal to the preamble's version.
    pub version: u32,
    pub kind: SampleKind,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// `width * height * spp`.
    pub sample_count: u64,
    pub order: SampleOrder,
    /// Bytes per record.
    pub record_size: u32,
    pub fields: Vec<Field>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<Camera>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<LightGeometry>,
    /// Free-text descriptions of conventions (`"x": "pixels, ..."`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coordinates: Option<BTreeMap<String, String>>,
    /// The scene the samples were taken of.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<String>,
    /// The tracer's seed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u32>,
    /// Samples per checksum chunk.
    #[serde(default = "default_chunk_samples")]
    pub chunk_samples: u32,
    /// Anything else, unchecked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extra: Option<serde_json::Value>,
}

impl Header {
    /// The field called `name`.
    pub fn field(&self, name: &str) -> Option<&Field> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// Values per sample given to [`SampleWriter::push`](crate::SampleWriter::push): the sum of
    /// the fields' components.
    pub fn values_per_sample(&self) -> usize {
        self.fields.iter().map(|f| f.components as usize).sum()
    }

    /// Number of checksum chunks: `ceil(sample_count / chunk_samples)`.
    pub fn chunk_count(&self) -> u64 {
        self.sample_count.div_ceil(u64::from(self.chunk_samples.max(1)))
    }

    /// Bytes of the data area, `None` on overflow.
    pub fn data_len(&self) -> Option<u64> {
        self.sample_count.checked_mul(u64::from(self.record_size))
    }

    /// Index of sample `s` of pixel (x, y) in pixel-major order.
    pub fn sample_index(&self, x: u32, y: u32, s: u32) -> u64 {
        (u64::from(y) * u64::from(self.width) + u64::from(x)) * u64::from(self.spp) + u64::from(s)
    }

    /// Checks every rule of `docs/sample-format.md` ("Validation") that concerns the header
    /// alone: format and version, sizes, the field list and its layout, finite camera and light
    /// numbers.
    pub fn validate(&self) -> Result<(), InvalidHeader> {
        if self.format != FORMAT_NAME {
            return Err(InvalidHeader::new("format", format!("is {:?}, expected {FORMAT_NAME:?}", self.format)));
        }
        if self.version != FORMAT_VERSION {
            return Err(InvalidHeader::new(
                "version",
                format!("the header says {}, the preamble says {FORMAT_VERSION}", self.version),
            ));
        }
        for (key, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_DIMENSION {
                return Err(InvalidHeader::new(key, format!("{v} is outside 1..={MAX_DIMENSION}")));
            }
        }
        if self.spp == 0 || self.spp > MAX_SPP {
            return Err(InvalidHeader::new("spp", format!("{} is outside 1..={MAX_SPP}", self.spp)));
        }
        let expected = u64::from(self.width) * u64::from(self.height) * u64::from(self.spp);
        if self.sample_count != expected {
            return Err(InvalidHeader::new(
                "sample_count",
                format!(
                    "{} is not width * height * spp = {} * {} * {} = {expected}",
                    self.sample_count, self.width, self.height, self.spp
                ),
            ));
        }
        if self.chunk_samples == 0 {
            return Err(InvalidHeader::new("chunk_samples", "must be at least 1"));
        }
        self.validate_fields()?;
        if self.data_len().is_none() {
            return Err(InvalidHeader::new("sample_count", "sample_count * record_size overflows 64 bits"));
        }
        if let Some(camera) = &self.camera {
            let mut numbers: Vec<(&str, f64)> = vec![
                ("fov_deg", camera.fov_deg),
                ("aperture_radius", camera.aperture_radius),
                ("focus_distance", camera.focus_distance),
                ("coc.c1", camera.coc.c1),
                ("coc.c2", camera.coc.c2),
            ];
            for (key, v) in [
                ("position", &camera.position),
                ("forward", &camera.forward),
                ("up", &camera.up),
                ("right", &camera.right),
            ] {
                numbers.extend(v.iter().map(|&x| (key, x)));
            }
            numbers.extend(camera.shutter.iter().map(|&x| ("shutter", x)));
            numbers.extend(camera.pixel_to_camera.iter().flatten().map(|&x| ("pixel_to_camera", x)));
            numbers.extend(camera.world_to_camera.iter().flatten().map(|&x| ("world_to_camera", x)));
            if let Some((key, v)) = numbers.into_iter().find(|(_, v)| !v.is_finite()) {
                return Err(InvalidHeader::new(format!("camera.{key}"), format!("{v} is not finite")));
            }
        }
        if let Some(light) = &self.light {
            let mut numbers: Vec<(&str, f64)> = Vec::new();
            for (key, v) in [
                ("corner", &light.corner),
                ("edge_u", &light.edge_u),
                ("edge_v", &light.edge_v),
                ("normal", &light.normal),
            ] {
                numbers.extend(v.iter().flatten().map(|&x| (key, x)));
            }
            numbers.extend(light.plane_distance.map(|x| ("plane_distance", x)));
            if let Some((key, v)) = numbers.into_iter().find(|(_, v)| !v.is_finite()) {
                return Err(InvalidHeader::new(format!("light.{key}"), format!("{v} is not finite")));
            }
        }
        Ok(())
    }

    fn validate_fields(&self) -> Result<(), InvalidHeader> {
        if self.fields.is_empty() {
            return Err(InvalidHeader::new("fields", "no fields"));
        }
        if self.fields.len() > MAX_FIELDS {
            return Err(InvalidHeader::new(
                "fields",
                format!("{} fields, at most {MAX_FIELDS} allowed", self.fields.len()),
            ));
        }
        if self.record_size > MAX_RECORD_SIZE {
            return Err(InvalidHeader::new("record_size", format!("{} exceeds {MAX_RECORD_SIZE}", self.record_size)));
        }
        let mut names = HashSet::new();
        let mut spans: Vec<(u64, u64, usize)> = Vec::with_capacity(self.fields.len());
        for (i, f) in self.fields.iter().enumerate() {
            let key = |k: &str| format!("fields[{i}].{k}");
            if !field::valid_name(&f.name) {
                return Err(InvalidHeader::new(
                    key("name"),
                    format!("{:?} is not [A-Za-z_][A-Za-z0-9_]* of at most 64 bytes", f.name),
                ));
            }
            if !names.insert(f.name.as_str()) {
                return Err(InvalidHeader::new(key("name"), format!("duplicate field name {:?}", f.name)));
            }
            if f.components == 0 || f.components > MAX_COMPONENTS {
                return Err(InvalidHeader::new(
                    key("components"),
                    format!("{} is outside 1..={MAX_COMPONENTS}", f.components),
                ));
            }
            if u64::from(f.offset) % f.ty.size() as u64 != 0 {
                return Err(InvalidHeader::new(
                    key("offset"),
                    format!("{} is not a multiple of the size of {} ({})", f.offset, f.ty, f.ty.size()),
                ));
            }
            if f.end() > u64::from(self.record_size) {
                return Err(InvalidHeader::new(
                    key("offset"),
                    format!("field `{}` ends at byte {}, past the record size {}", f.name, f.end(), self.record_size),
                ));
            }
            spans.push((u64::from(f.offset), f.end(), i));
        }
        spans.sort_unstable();
        for w in spans.windows(2) {
            if w[1].0 < w[0].1 {
                return Err(InvalidHeader::new(
                    format!("fields[{}].offset", w[1].2),
                    format!("field `{}` overlaps field `{}`", self.fields[w[1].2].name, self.fields[w[0].2].name),
                ));
            }
        }
        let end = spans.iter().map(|s| s.1).max().unwrap_or(0);
        let expected = end.next_multiple_of(4);
        if u64::from(self.record_size) != expected {
            return Err(InvalidHeader::new(
                "record_size",
                format!(
                    "{} does not match the fields, which need {expected} (end {end} rounded up to 4)",
                    self.record_size
                ),
            ));
        }
        Ok(())
    }

    /// The header text as stored: pretty-printed JSON padded with spaces so that
    /// `PREAMBLE_LEN + len` is a multiple of [`DATA_ALIGN`].
    pub fn to_padded_json(&self) -> Vec<u8> {
        // Serializing plain data (strings, numbers, arrays, maps, a serde_json::Value) cannot fail.
        let mut text = serde_json::to_vec_pretty(self).expect("the header serializes");
        let total = (PREAMBLE_LEN + text.len() as u64).next_multiple_of(DATA_ALIGN);
        text.resize((total - PREAMBLE_LEN) as usize, b' ');
        text
    }

    /// Parses (but does not validate) header text.
    pub fn from_json(bytes: &[u8]) -> Result<Header, InvalidHeader> {
        serde_json::from_slice(bytes).map_err(|e| InvalidHeader::new("header", format!("not a valid v1 header: {e}")))
    }
}

/// What the writer needs to know to lay out a file: everything in the header except what it
/// computes (format, version, sample count, order, offsets, record size).
#[derive(Clone, Debug, PartialEq)]
pub struct HeaderSpec {
    pub kind: SampleKind,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// In record order; `push` takes their components in this order.
    pub fields: Vec<FieldSpec>,
    pub camera: Option<Camera>,
    pub light: Option<LightGeometry>,
    pub coordinates: Option<BTreeMap<String, String>>,
    pub scene: Option<String>,
    pub seed: Option<u32>,
    /// Samples per checksum chunk (default 65536).
    pub chunk_samples: u32,
    pub extra: Option<serde_json::Value>,
}

impl HeaderSpec {
    /// A spec without fields or options.
    pub fn new(kind: SampleKind, width: u32, height: u32, spp: u32) -> Self {
        HeaderSpec {
            kind,
            width,
            height,
            spp,
            fields: Vec::new(),
            camera: None,
            light: None,
            coordinates: None,
            scene: None,
            seed: None,
            chunk_samples: DEFAULT_CHUNK_SAMPLES,
            extra: None,
        }
    }

    /// Appends a field.
    pub fn field(mut self, field: FieldSpec) -> Self {
        self.fields.push(field);
        self
    }

    /// Computes the layout and validates the result.
    pub fn to_header(&self) -> Result<Header, InvalidHeader> {
        if self.fields.len() > MAX_FIELDS {
            return Err(InvalidHeader::new("fields", format!("{} fields, at most {MAX_FIELDS}", self.fields.len())));
        }
        if let Some((i, f)) = self.fields.iter().enumerate().find(|(_, f)| f.components > MAX_COMPONENTS) {
            return Err(InvalidHeader::new(
                format!("fields[{i}].components"),
                format!("{} is outside 1..={MAX_COMPONENTS}", f.components),
            ));
        }
        let (fields, record_size) =
            field::layout(&self.fields).ok_or_else(|| InvalidHeader::new("fields", "record size overflows"))?;
        let header = Header {
            format: FORMAT_NAME.to_string(),
            version: FORMAT_VERSION,
            kind: self.kind,
            width: self.width,
            height: self.height,
            spp: self.spp,
            // Saturating: an overflowing product is rejected by `validate` below, never a panic.
            sample_count: u64::from(self.width)
                .checked_mul(u64::from(self.height))
                .and_then(|n| n.checked_mul(u64::from(self.spp)))
                .unwrap_or(u64::MAX),
            order: SampleOrder::PixelMajor,
            record_size,
            fields,
            camera: self.camera.clone(),
            light: self.light.clone(),
            coordinates: self.coordinates.clone(),
            scene: self.scene.clone(),
            seed: self.seed,
            chunk_samples: self.chunk_samples,
            extra: self.extra.clone(),
        };
        header.validate()?;
        Ok(header)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::FieldType;

    fn spec() -> HeaderSpec {
        HeaderSpec::new(SampleKind::LensTime, 4, 3, 2)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("radiance", FieldType::F16, 3))
    }

    /// Fuzz finding F2 (docs/fuzzing.md): an overflowing width × height × spp is an error.
    #[test]
    fn overflowing_sample_count_is_an_error_not_a_panic() {
        let huge =
            HeaderSpec::new(SampleKind::Ao, u32::MAX, u32::MAX, u32::MAX).field(FieldSpec::new("x", FieldType::F32, 1));
        assert!(huge.to_header().is_err());
    }

    /// Fuzz finding F1 (docs/fuzzing.md): header numbers read back bit for bit.
    #[test]
    fn header_floats_round_trip_exactly() {
        let mut extra = serde_json::Map::new();
        for (i, v) in
            [0.9856906946328695f64, 4.089549438285546e-41, 2.2595105365949866e-38, 1.0 / 3.0].iter().enumerate()
        {
            extra.insert(format!("v{i}"), serde_json::json!(v));
        }
        let mut spec = spec();
        spec.extra = Some(serde_json::Value::Object(extra.clone()));
        let header = spec.to_header().unwrap();
        let parsed = Header::from_json(&header.to_padded_json()).unwrap();
        let back = parsed.extra.unwrap();
        for (key, value) in &extra {
            assert_eq!(back[key].as_f64().unwrap().to_bits(), value.as_f64().unwrap().to_bits(), "{key}");
        }
    }

    #[test]
    fn kinds_round_trip_and_unknown_kinds_fail() {
        for k in SampleKind::ALL {
            assert_eq!(k.name().parse::<SampleKind>(), Ok(k));
            assert_eq!(serde_json::to_string(&k).unwrap(), format!("\"{k}\""));
        }
        assert!("lens_time".parse::<SampleKind>().is_err());
        assert!(serde_json::from_str::<SampleKind>("\"volume\"").is_err());
    }

    #[test]
    fn padded_json_parses_and_aligns() {
        let h = spec().to_header().unwrap();
        let text = h.to_padded_json();
        assert_eq!((PREAMBLE_LEN + text.len() as u64) % DATA_ALIGN, 0);
        assert_eq!(Header::from_json(&text).unwrap(), h);
        let v: serde_json::Value = serde_json::from_slice(&text).unwrap();
        assert_eq!(v["order"], "pixel-major");
        assert_eq!(v["fields"][1]["type"], "f16");
        assert_eq!(v["chunk_samples"], 65536);
    }

    #[test]
    fn validation_rejects_bad_layouts() {
        let good = spec().to_header().unwrap();
        let check = |f: &dyn Fn(&mut Header), field: &str| {
            let mut h = good.clone();
            f(&mut h);
            let e = h.validate().unwrap_err();
            assert!(e.field.starts_with(field), "{e} (wanted {field})");
        };
        check(&|h| h.format = "other".into(), "format");
        check(&|h| h.version = 2, "version");
        check(&|h| h.width = 0, "width");
        check(&|h| h.height = 65537, "height");
        check(&|h| h.spp = (1 << 20) + 1, "spp");
        check(&|h| h.sample_count = 1 << 60, "sample_count");
        check(&|h| h.record_size = 16, "record_size");
        check(&|h| h.record_size = 8, "fields[1].offset");
        check(&|h| h.fields[1].offset = 3, "fields[1].offset");
        check(&|h| h.fields[1].offset = 2, "fields[1].offset");
        check(&|h| h.fields[1].components = 0, "fields[1].components");
        check(&|h| h.fields[1].components = 5, "fields[1].components");
        check(&|h| h.fields[1].name = "x".into(), "fields[1].name");
        check(&|h| h.fields[1].name = "a b".into(), "fields[1].name");
        check(&|h| h.fields.clear(), "fields");
        check(&|h| h.chunk_samples = 0, "chunk_samples");
        check(
            &|h| {
                let f = h.fields[0].clone();
                h.fields = (0..65).map(|i| Field { name: format!("f{i}"), offset: 4 * i, ..f.clone() }).collect();
                h.record_size = 4 * 65;
            },
            "fields",
        );
        check(&|h| h.record_size = MAX_RECORD_SIZE + 4, "record_size");
    }

    #[test]
    fn unknown_top_level_keys_are_errors_but_extra_is_free() {
        let h = spec().to_header().unwrap();
        let mut v = serde_json::to_value(&h).unwrap();
        v["extra"] = serde_json::json!({"anything": [1, {"goes": null}]});
        let ok = serde_json::to_vec(&v).unwrap();
        assert!(Header::from_json(&ok).is_ok());
        v["surprise"] = serde_json::json!(1);
        assert!(Header::from_json(&serde_json::to_vec(&v).unwrap()).is_err());
        let mut v = serde_json::to_value(&h).unwrap();
        v["fields"][0]["scale"] = serde_json::json!(1);
        assert!(Header::from_json(&serde_json::to_vec(&v).unwrap()).is_err());
        let mut v = serde_json::to_value(&h).unwrap();
        v["kind"] = serde_json::json!("volume");
        let e = Header::from_json(&serde_json::to_vec(&v).unwrap()).unwrap_err();
        assert!(e.message.contains("unknown sample kind"), "{e}");
    }

    #[test]
    fn non_finite_camera_numbers_are_rejected() {
        let camera = Camera {
            position: [0.0; 3],
            forward: [0.0, 0.0, -1.0],
            up: [0.0, 1.0, 0.0],
            right: [1.0, 0.0, 0.0],
            fov_deg: 40.0,
            fov_axis: FovAxis::Y,
            aperture_radius: 0.1,
            focus_distance: 5.0,
            coc: Coc { c1: -10.0, c2: 2.0 },
            shutter: [0.0, 1.0],
            pixel_to_camera: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
            world_to_camera: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        };
        let mut s = spec();
        s.camera = Some(camera.clone());
        assert!(s.to_header().is_ok());
        s.camera = Some(Camera { focus_distance: f64::NAN, ..camera });
        assert_eq!(s.to_header().unwrap_err().field, "camera.focus_distance");
        s.camera = None;
        s.light = Some(LightGeometry { normal: Some([0.0, f64::INFINITY, 0.0]), ..Default::default() });
        assert_eq!(s.to_header().unwrap_err().field, "light.normal");
    }
}
