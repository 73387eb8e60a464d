//! What a consumer of sample files needs of their fields, and the one check of a file against
//! it.
//!
//! The format lets a file declare any field with any type and 1 to 4 components; `open` checks
//! only that the declarations are consistent with the file. A consumer that reads `radiance` as
//! three floats must not meet a `radiance` of one `u8`: it would index past the field's end or
//! read bytes as colours. So every consumer declares, once, the fields it reads (name, the types
//! it accepts, the component count, whether the field is required) as a [`Needs`], and calls
//! [`SampleFile::check_needs`](crate::SampleFile::check_needs) before any long work. The error
//! names the file, the field, what the file declares and what the consumer needs:
//! `x.lfrs: field `radiance` is u8×1, TLFR needs f32×3 or f16×3`.

use std::fmt::Write as _;

use crate::error::{Result, SampleError};
use crate::field::{Field, FieldType};

/// Types that hold real numbers: `f32`, or `f16` where the format stores a value in half
/// precision; a consumer reads both through the same decoding.
pub const REAL: &[FieldType] = &[FieldType::F32, FieldType::F16];

/// The type of the format's octahedral unit vectors (`u16 × 2`): their decoding assumes the
/// 16-bit quantisation.
pub const OCTAHEDRAL: &[FieldType] = &[FieldType::U16];

/// What a consumer needs of one field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FieldNeed {
    /// The field's name.
    pub name: &'static str,
    /// The types the consumer accepts.
    pub types: &'static [FieldType],
    /// The component count it reads.
    pub components: u32,
    /// Whether a file without the field is an error (else the consumer uses a default).
    pub required: bool,
}

impl FieldNeed {
    /// A required field of `components` real numbers ([`REAL`]).
    pub const fn real(name: &'static str, components: u32) -> FieldNeed {
        FieldNeed { name, types: REAL, components, required: true }
    }

    /// A required octahedral unit vector ([`OCTAHEDRAL`], 2 components).
    pub const fn octahedral(name: &'static str) -> FieldNeed {
        FieldNeed { name, types: OCTAHEDRAL, components: 2, required: true }
    }

    /// The same need for a field the file may leave out.
    pub const fn optional(self) -> FieldNeed {
        FieldNeed { required: false, ..self }
    }

    /// An optional field of `components` real numbers.
    pub const fn optional_real(name: &'static str, components: u32) -> FieldNeed {
        FieldNeed::real(name, components).optional()
    }

    /// Whether `field` (of this need's name) has an accepted type and component count.
    pub fn accepts(&self, field: &Field) -> bool {
        field.components == self.components && self.types.contains(&field.ty)
    }

    /// What the consumer needs, as text: `f32×3 or f16×3`.
    pub fn describe(&self) -> String {
        let mut text = String::new();
        for (k, ty) in self.types.iter().enumerate() {
            let separator = if k == 0 { "" } else { " or " };
            let _ = write!(text, "{separator}{}×{}", ty.name(), self.components);
        }
        text
    }
}

/// Everything one consumer reads of a file: who it is (for the message) and its fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Needs {
    /// The consumer, as the message names it: "TLFR", "`lfr export --format tlfr-1.3`", ...
    pub consumer: &'static str,
    pub fields: &'static [FieldNeed],
}

impl Needs {
    /// Checks the fields of a file at `path` against these needs: every required field is
    /// present, and every field the consumer reads that the file has has an accepted type and
    /// component count. The first problem, in the order of `self.fields`, is the error.
    pub fn check(&self, path: &std::path::Path, fields: &[Field]) -> Result<()> {
        for need in self.fields {
            match fields.iter().find(|f| f.name == need.name) {
                None if need.required => {
                    return Err(SampleError::MissingField {
                        path: path.to_path_buf(),
                        field: need.name.to_string(),
                        problem: format!("{} needs the field `{}` ({})", self.consumer, need.name, need.describe()),
                    })
                }
                None => {}
                Some(field) if !need.accepts(field) => {
                    return Err(SampleError::WrongField {
                        path: path.to_path_buf(),
                        field: need.name.to_string(),
                        problem: format!(
                            "is {}×{}, {} needs {}",
                            field.ty.name(),
                            field.components,
                            self.consumer,
                            need.describe()
                        ),
                    })
                }
                Some(_) => {}
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn field(name: &str, ty: FieldType, components: u32) -> Field {
        Field { name: name.into(), ty, components, offset: 0, meaning: String::new(), unit: String::new() }
    }

    const NEEDS: Needs = Needs {
        consumer: "the test",
        fields: &[FieldNeed::real("radiance", 3), FieldNeed::octahedral("normal").optional()],
    };

    #[test]
    fn wrong_type_or_count_and_missing_fields_are_named() {
        let path = Path::new("x.lfrs");
        let ok = [field("radiance", FieldType::F16, 3), field("normal", FieldType::U16, 2)];
        assert!(NEEDS.check(path, &ok).is_ok());
        assert!(NEEDS.check(path, &ok[..1]).is_ok(), "an optional field may be absent");
        let bytes = NEEDS.check(path, &[field("radiance", FieldType::U8, 1)]).unwrap_err();
        assert_eq!(bytes.to_string(), "x.lfrs: field `radiance` is u8×1, the test needs f32×3 or f16×3");
        assert_eq!(bytes.path(), path);
        let short = NEEDS.check(path, &[field("radiance", FieldType::F32, 2)]).unwrap_err();
        assert_eq!(short.to_string(), "x.lfrs: field `radiance` is f32×2, the test needs f32×3 or f16×3");
        let normal = NEEDS.check(path, &[ok[0].clone(), field("normal", FieldType::F32, 2)]).unwrap_err();
        assert_eq!(normal.to_string(), "x.lfrs: field `normal` is f32×2, the test needs u16×2");
        let missing = NEEDS.check(path, &[field("x", FieldType::F32, 1)]).unwrap_err();
        assert_eq!(
            missing.to_string(),
            "x.lfrs: the test needs the field `radiance` (f32×3 or f16×3); the file lacks it"
        );
    }
}
