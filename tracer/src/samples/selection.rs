//! Which of a kind's fields a dump writes: all of them (the default), or only those a consumer
//! reads. A reconstruction that reads three fields of a fourteen-field record should not pay
//! for tracing, encoding and writing the other eleven: `lfr compare` charges each method the
//! dump of the fields it declares (`recon::needs`), and `lfr dump --fields` gives external
//! tools smaller files.
//!
//! The selected fields keep the kind's record order, and each keeps its type and the values it
//! would have in a full dump, so a selected file is the full file with columns left out (tested
//! in `tests/samples_selection.rs`). A layout skips computing a value nobody reads where that
//! costs time (the depth gradient's extra camera rays, [`FieldSelection::wants`]).

use std::collections::BTreeSet;
use std::ops::Range;

use sampleio::HeaderSpec;

use crate::error::RenderError;

/// The value ranges of a full record that a selected record is made of, in order.
pub(crate) type SelectedRanges = Vec<Range<usize>>;

/// The fields a dump writes.
#[derive(Clone, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FieldSelection {
    /// Every field of the kind's layout.
    #[default]
    All,
    /// The named fields the layout has. With `strict`, a name the layout does not have is an
    /// error (a user's `--fields`); without, it is ignored (one consumer's declaration applied
    /// to the two files of soft shadows, or to a scene whose layout leaves an optional field
    /// out).
    Only { names: BTreeSet<String>, strict: bool },
}

impl FieldSelection {
    /// The fields named, ignoring names the layout does not have.
    pub fn named<I, S>(names: I) -> FieldSelection
    where
        I: IntoIterator<Item = S>,
        S: Into<String>,
    {
        FieldSelection::Only { names: names.into_iter().map(Into::into).collect(), strict: false }
    }

    /// Every field the consumers `needs` declare (`sampleio::Needs`), ignoring names the layout
    /// does not have.
    pub fn reading(needs: &[&sampleio::Needs]) -> FieldSelection {
        FieldSelection::named(needs.iter().flat_map(|needs| needs.fields.iter().map(|field| field.name)))
    }

    /// A user's list (`--fields a,b,c`): every name must be one of the layout's fields.
    pub fn parse_strict(list: &str) -> Result<FieldSelection, RenderError> {
        let names: BTreeSet<String> = list.split(',').map(|name| name.trim().to_string()).collect();
        if names.iter().any(String::is_empty) {
            return Err(RenderError::Settings(format!("--fields {list:?}: an empty field name")));
        }
        Ok(FieldSelection::Only { names, strict: true })
    }

    /// Whether the selection names `name` explicitly (`All` does not): a layout adds a field
    /// that full dumps leave out (`lens-time`'s `direct`) only then.
    pub fn names(&self, name: &str) -> bool {
        matches!(self, FieldSelection::Only { names, .. } if names.contains(name))
    }

    /// Whether the field `name` is written (a layout computes a costly value only then).
    pub fn wants(&self, name: &str) -> bool {
        match self {
            FieldSelection::All => true,
            FieldSelection::Only { names, .. } => names.contains(name),
        }
    }

    /// `spec` with only the selected fields, and the value ranges of a full record they come
    /// from (`None` when every field is kept). Errors, before any work, name the kind and its
    /// fields: a strict name the layout lacks, or a selection that keeps no field.
    pub(crate) fn apply(&self, spec: HeaderSpec) -> Result<(HeaderSpec, Option<SelectedRanges>), RenderError> {
        let FieldSelection::Only { names, strict } = self else {
            return Ok((spec, None));
        };
        let available = || spec.fields.iter().map(|f| f.name.as_str()).collect::<Vec<_>>().join(", ");
        if *strict {
            if let Some(unknown) = names.iter().find(|name| !spec.fields.iter().any(|f| &f.name == *name)) {
                return Err(RenderError::Settings(format!(
                    "--fields: `{unknown}` is not a field of this scene's `{}` samples (its fields: {})",
                    spec.kind.name(),
                    available()
                )));
            }
        }
        let mut kept = Vec::new();
        let mut ranges: SelectedRanges = Vec::new();
        let mut offset = 0usize;
        for field in &spec.fields {
            let components = field.components as usize;
            if names.contains(&field.name) {
                // Neighbouring fields make one range: fewer, longer copies per record.
                match ranges.last_mut() {
                    Some(last) if last.end == offset => last.end += components,
                    _ => ranges.push(offset..offset + components),
                }
                kept.push(field.clone());
            }
            offset += components;
        }
        if kept.is_empty() {
            return Err(RenderError::Settings(format!(
                "the field selection {:?} keeps none of the `{}` samples' fields ({})",
                names.iter().collect::<Vec<_>>(),
                spec.kind.name(),
                available()
            )));
        }
        let all_kept = kept.len() == spec.fields.len();
        let spec = HeaderSpec { fields: kept, ..spec };
        Ok((spec, (!all_kept).then_some(ranges)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sampleio::{FieldSpec, FieldType, SampleKind};

    fn spec() -> HeaderSpec {
        HeaderSpec::new(SampleKind::LensTime, 2, 2, 1)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("y", FieldType::F32, 1))
            .field(FieldSpec::new("z", FieldType::F32, 1))
            .field(FieldSpec::new("radiance", FieldType::F32, 3))
            .field(FieldSpec::new("depth_gradient", FieldType::F32, 2))
    }

    #[test]
    fn kept_fields_keep_their_order_and_their_value_ranges() {
        let (kept, ranges) =
            FieldSelection::named(["depth_gradient", "x", "radiance", "no_such"]).apply(spec()).unwrap();
        let names: Vec<_> = kept.fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["x", "radiance", "depth_gradient"]);
        // x is value 0; radiance (3..6) and depth_gradient (6..8) are neighbours: one range.
        assert_eq!(ranges, Some(vec![0..1, 3..8]));
    }

    #[test]
    fn all_and_a_selection_of_every_field_copy_nothing() {
        assert_eq!(FieldSelection::All.apply(spec()).unwrap().1, None);
        let every = FieldSelection::named(["x", "y", "z", "radiance", "depth_gradient"]);
        let (kept, ranges) = every.apply(spec()).unwrap();
        assert_eq!((kept.fields.len(), ranges), (5, None));
    }

    #[test]
    fn a_strict_unknown_name_and_an_empty_selection_are_errors_naming_the_fields() {
        let error = FieldSelection::parse_strict("x,colour").unwrap().apply(spec()).unwrap_err().to_string();
        assert!(
            error.contains("`colour`") && error.contains("lens-time") && error.contains("depth_gradient"),
            "{error}"
        );
        let error = FieldSelection::named(["colour"]).apply(spec()).unwrap_err().to_string();
        assert!(error.contains("keeps none") && error.contains("radiance"), "{error}");
        assert!(FieldSelection::parse_strict("x,,y").is_err());
        assert!(FieldSelection::parse_strict("radiance").unwrap().wants("radiance"));
        assert!(!FieldSelection::parse_strict("radiance").unwrap().wants("x"));
    }
}
