//! Fields: the named, typed columns of a sample record, their layout inside the record and the
//! conversion of values to and from their stored types.

use std::fmt;

use serde::{Deserialize, Serialize};

/// Most components a field may have.
pub const MAX_COMPONENTS: u32 = 4;
/// Longest field name, in bytes.
pub const MAX_FIELD_NAME_LEN: usize = 64;

/// The stored type of a field's components. All multi-byte types are little-endian.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FieldType {
    /// IEEE 754 binary32.
    F32,
    /// IEEE 754 binary16.
    F16,
    U32,
    U16,
    U8,
}

impl FieldType {
    /// Every type, in the order of the table in `docs/sample-format.md`.
    pub const ALL: [FieldType; 5] = [FieldType::F32, FieldType::F16, FieldType::U32, FieldType::U16, FieldType::U8];

    /// Bytes per component; also the alignment of the field inside the record.
    pub const fn size(self) -> usize {
        match self {
            FieldType::F32 | FieldType::U32 => 4,
            FieldType::F16 | FieldType::U16 => 2,
            FieldType::U8 => 1,
        }
    }

    /// The name used in the header (`"f32"`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            FieldType::F32 => "f32",
            FieldType::F16 => "f16",
            FieldType::U32 => "u32",
            FieldType::U16 => "u16",
            FieldType::U8 => "u8",
        }
    }

    /// The numpy type string (`"<f4"`, ...).
    pub const fn numpy(self) -> &'static str {
        match self {
            FieldType::F32 => "<f4",
            FieldType::F16 => "<f2",
            FieldType::U32 => "<u4",
            FieldType::U16 => "<u2",
            FieldType::U8 => "|u1",
        }
    }

    /// Whether the type is a floating-point type (NaN and infinities are storable).
    pub const fn is_float(self) -> bool {
        matches!(self, FieldType::F32 | FieldType::F16)
    }

    /// Largest storable integer, for integer types.
    const fn int_max(self) -> u32 {
        match self {
            FieldType::U32 => u32::MAX,
            FieldType::U16 => u16::MAX as u32,
            FieldType::U8 => u8::MAX as u32,
            FieldType::F32 | FieldType::F16 => 0,
        }
    }

    /// Writes `value` as this type into `out` (exactly `self.size()` bytes). Floats: f32 as is,
    /// f16 rounded to nearest (overflow to infinity); NaN and infinities are kept. Integers: the
    /// value is rounded to the nearest integer (ties away from zero) and must then lie in the
    /// type's range; NaN never fits. Returns `false` (and leaves `out` alone) when it does not fit.
    pub fn encode(self, value: f32, out: &mut [u8]) -> bool {
        match self {
            FieldType::F32 => out.copy_from_slice(&value.to_le_bytes()),
            FieldType::F16 => out.copy_from_slice(&half::f16::from_f32(value).to_le_bytes()),
            FieldType::U32 | FieldType::U16 | FieldType::U8 => {
                if value.is_nan() {
                    return false;
                }
                let r = f64::from(value.round());
                if !(0.0..=f64::from(self.int_max())).contains(&r) {
                    return false;
                }
                // In range and integral: the cast is exact.
                let v = r as u32;
                out.copy_from_slice(&v.to_le_bytes()[..self.size()]);
            }
        }
        true
    }

    /// Reads one component of this type from `bytes` (exactly `self.size()` bytes), as f64
    /// (exact for every type).
    pub fn decode_f64(self, bytes: &[u8]) -> f64 {
        match self {
            FieldType::F32 => f64::from(f32::from_le_bytes(le4(bytes))),
            FieldType::F16 => f64::from(half::f16::from_le_bytes(le2(bytes))),
            FieldType::U32 => f64::from(u32::from_le_bytes(le4(bytes))),
            FieldType::U16 => f64::from(u16::from_le_bytes(le2(bytes))),
            FieldType::U8 => f64::from(bytes[0]),
        }
    }

    /// Reads one component of this type from `bytes` (exactly `self.size()` bytes), as f32
    /// (exact except for `u32` values above 2^24).
    #[inline]
    pub fn decode(self, bytes: &[u8]) -> f32 {
        match self {
            FieldType::F32 => f32::from_le_bytes(le4(bytes)),
            FieldType::F16 => half::f16::from_le_bytes(le2(bytes)).to_f32(),
            FieldType::U32 => u32::from_le_bytes(le4(bytes)) as f32,
            FieldType::U16 => f32::from(u16::from_le_bytes(le2(bytes))),
            FieldType::U8 => f32::from(bytes[0]),
        }
    }
}

fn le4(bytes: &[u8]) -> [u8; 4] {
    [bytes[0], bytes[1], bytes[2], bytes[3]]
}

fn le2(bytes: &[u8]) -> [u8; 2] {
    [bytes[0], bytes[1]]
}

/// `N` values of `S` bytes each from `record[start..]`, converted by `convert`: sizes known at
/// compile time, so one bounds check covers them all.
#[inline(always)]
fn read_array<const N: usize, const S: usize>(
    record: &[u8],
    start: usize,
    convert: impl Fn([u8; S]) -> f32,
) -> [f32; N] {
    let bytes = &record[start..start + N * S];
    std::array::from_fn(|c| {
        let mut value = [0u8; S];
        value.copy_from_slice(&bytes[c * S..c * S + S]);
        convert(value)
    })
}

impl fmt::Display for FieldType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A field as the header records it: name, type, component count and byte offset inside the
/// record.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Field {
    /// Unique within the file; `[A-Za-z_][A-Za-z0-9_]*`, at most 64 bytes.
    pub name: String,
    #[serde(rename = "type")]
    pub ty: FieldType,
    /// 1 to 4.
    pub components: u32,
    /// Byte offset of the first component inside the record, a multiple of `ty.size()`.
    pub offset: u32,
    /// Free text: what the value is.
    pub meaning: String,
    /// Free text: its unit (`"px"`, `"world"`, `"W/(m^2 sr)"`, `""` for none).
    pub unit: String,
}

impl Field {
    /// Bytes the field takes in the record.
    pub fn byte_len(&self) -> usize {
        self.ty.size() * self.components as usize
    }

    /// One past the last byte of the field inside the record (u64: the header's values are not
    /// trusted to fit anything smaller).
    pub fn end(&self) -> u64 {
        u64::from(self.offset) + self.ty.size() as u64 * u64::from(self.components)
    }

    /// Component `component` of this field in `record` (one record of a file with this field),
    /// converted to f32 like [`FieldType::decode`]: the per-record form of
    /// [`SampleFile::value`](crate::SampleFile::value) for loops over
    /// [`SampleFile::pixel_records`](crate::SampleFile::pixel_records).
    ///
    /// # Panics
    /// If the component lies outside `record`.
    #[inline]
    pub fn decode_from(&self, record: &[u8], component: usize) -> f32 {
        self.ty.decode(&record[self.component_range(component)])
    }

    /// Components `0..N` of this field in `record` at once: what `N` calls of
    /// [`Self::decode_from`] give, with one type dispatch and one bounds check for the `N`
    /// (the per-record form for loops that read whole vectors, such as the box filter's).
    ///
    /// # Panics
    /// If the `N` components lie outside `record`.
    #[inline]
    pub fn decode_array_from<const N: usize>(&self, record: &[u8]) -> [f32; N] {
        debug_assert!(N <= self.components as usize, "{N} components of a field of {}", self.components);
        let start = self.offset as usize;
        match self.ty {
            FieldType::F32 => read_array(record, start, f32::from_le_bytes),
            FieldType::F16 => read_array(record, start, |b| half::f16::from_le_bytes(b).to_f32()),
            FieldType::U32 => read_array(record, start, |b| u32::from_le_bytes(b) as f32),
            FieldType::U16 => read_array(record, start, |b| f32::from(u16::from_le_bytes(b))),
            FieldType::U8 => read_array(record, start, |b: [u8; 1]| f32::from(b[0])),
        }
    }

    /// Byte range of component `component` inside the record.
    #[inline]
    pub(crate) fn component_range(&self, component: usize) -> std::ops::Range<usize> {
        let start = self.offset as usize + component * self.ty.size();
        start..start + self.ty.size()
    }
}

/// A field as the writer is given it; the offset is computed (see [`layout`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FieldSpec {
    pub name: String,
    pub ty: FieldType,
    pub components: u32,
    pub meaning: String,
    pub unit: String,
}

impl FieldSpec {
    /// A field with empty meaning and unit.
    pub fn new(name: impl Into<String>, ty: FieldType, components: u32) -> Self {
        FieldSpec { name: name.into(), ty, components, meaning: String::new(), unit: String::new() }
    }

    /// Sets the free-text meaning.
    pub fn meaning(mut self, meaning: impl Into<String>) -> Self {
        self.meaning = meaning.into();
        self
    }

    /// Sets the free-text unit.
    pub fn unit(mut self, unit: impl Into<String>) -> Self {
        self.unit = unit.into();
        self
    }
}

/// Lays the fields out in the given order: each at the next offset aligned to its type size,
/// the record size rounded up to a multiple of 4. Returns the fields with offsets and the record
/// size, or `None` if the sizes overflow `u32` (only possible with component counts the header
/// validation rejects anyway).
pub fn layout(specs: &[FieldSpec]) -> Option<(Vec<Field>, u32)> {
    let mut offset: u32 = 0;
    let mut fields = Vec::with_capacity(specs.len());
    for spec in specs {
        let size = spec.ty.size() as u32;
        offset = offset.checked_next_multiple_of(size)?;
        fields.push(Field {
            name: spec.name.clone(),
            ty: spec.ty,
            components: spec.components,
            offset,
            meaning: spec.meaning.clone(),
            unit: spec.unit.clone(),
        });
        offset = offset.checked_add(size.checked_mul(spec.components)?)?;
    }
    Some((fields, offset.checked_next_multiple_of(4)?))
}

/// Whether `name` is an allowed field name.
pub(crate) fn valid_name(name: &str) -> bool {
    let mut chars = name.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && name.len() <= MAX_FIELD_NAME_LEN
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_aligns_each_field_and_pads_the_record() {
        let specs = [
            FieldSpec::new("a", FieldType::U8, 3),
            FieldSpec::new("b", FieldType::F32, 1),
            FieldSpec::new("c", FieldType::U8, 1),
            FieldSpec::new("d", FieldType::F16, 3),
            FieldSpec::new("e", FieldType::U16, 1),
        ];
        let (fields, record) = layout(&specs).unwrap();
        let offsets: Vec<u32> = fields.iter().map(|f| f.offset).collect();
        assert_eq!(offsets, [0, 4, 8, 10, 16]);
        assert_eq!(record, 20);
        let (_, record) = layout(&[FieldSpec::new("a", FieldType::U8, 1)]).unwrap();
        assert_eq!(record, 4);
    }

    #[test]
    fn integers_round_and_check_their_range() {
        let mut b = [0u8; 4];
        assert!(FieldType::U8.encode(254.6, &mut b[..1]));
        assert_eq!(b[0], 255);
        assert!(!FieldType::U8.encode(255.5, &mut b[..1]));
        assert!(!FieldType::U8.encode(-0.5, &mut b[..1]));
        assert!(FieldType::U8.encode(-0.49, &mut b[..1]));
        assert_eq!(b[0], 0);
        assert!(!FieldType::U16.encode(f32::NAN, &mut b[..2]));
        assert!(!FieldType::U16.encode(65536.0, &mut b[..2]));
        assert!(FieldType::U16.encode(65535.0, &mut b[..2]));
        assert_eq!(FieldType::U16.decode(&b[..2]), 65535.0);
        assert!(FieldType::U32.encode(4_294_967_040.0, &mut b));
        assert_eq!(u32::from_le_bytes(b), 4_294_967_040);
        assert!(!FieldType::U32.encode(4_294_967_296.0, &mut b));
        assert!(!FieldType::U32.encode(f32::INFINITY, &mut b));
    }

    proptest::proptest! {
        /// The whole-vector read gives what the per-component read gives, bit for bit (NaN
        /// payloads included), for every type, component count and offset, on any bytes.
        #[test]
        fn reading_a_vector_at_once_is_reading_each_component(
            type_index in 0usize..5,
            components in 1u32..=4,
            slot in 0u32..4,
            bytes in proptest::collection::vec(proptest::num::u8::ANY, 64),
        ) {
            let ty = [FieldType::F32, FieldType::F16, FieldType::U32, FieldType::U16, FieldType::U8][type_index];
            let offset = slot * ty.size() as u32;
            let field = Field { name: "v".into(), ty, components, offset, meaning: String::new(), unit: String::new() };
            let record = &bytes[..field.end() as usize];
            let one_by_one = |n: usize| (0..n).map(|c| field.decode_from(record, c).to_bits()).collect::<Vec<_>>();
            let bits = |values: &[f32]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            proptest::prop_assert_eq!(bits(&field.decode_array_from::<1>(record)), one_by_one(1));
            if components >= 3 {
                proptest::prop_assert_eq!(bits(&field.decode_array_from::<3>(record)), one_by_one(3));
            }
            if components == 4 {
                proptest::prop_assert_eq!(bits(&field.decode_array_from::<4>(record)), one_by_one(4));
            }
        }
    }

    #[test]
    fn floats_keep_nan_and_infinities() {
        let mut b = [0u8; 4];
        for ty in [FieldType::F32, FieldType::F16] {
            let out = &mut b[..ty.size()];
            assert!(ty.encode(f32::NAN, out));
            assert!(ty.decode(out).is_nan());
            assert!(ty.encode(f32::NEG_INFINITY, out));
            assert_eq!(ty.decode(out), f32::NEG_INFINITY);
        }
        assert!(FieldType::F16.encode(1e6, &mut b[..2]));
        assert_eq!(FieldType::F16.decode(&b[..2]), f32::INFINITY);
        assert!(FieldType::F16.encode(0.1, &mut b[..2]));
        assert_eq!(FieldType::F16.decode(&b[..2]), half::f16::from_f32(0.1).to_f32());
    }

    #[test]
    fn names() {
        assert!(valid_name("x"));
        assert!(valid_name("_radiance2"));
        assert!(!valid_name(""));
        assert!(!valid_name("2x"));
        assert!(!valid_name("a-b"));
        assert!(!valid_name("é"));
        assert!(!valid_name(&"a".repeat(65)));
    }
}
