//! What every reader of sample files in this crate needs of their fields: one declaration per
//! consumer (field name, accepted types, component count, required or not), checked by
//! `sampleio`'s one function, [`SampleFile::check_needs`](sampleio::SampleFile::check_needs),
//! before the consumer reads a value. A field the format allows but the consumer cannot read
//! (`radiance` as `u8 × 1`, `motion` with 2 components) is then an error naming the file and the
//! field, never a read past the field's end or bytes taken as colours.
//!
//! Types follow `docs/sample-format.md`: real values are `f32` or `f16` (`sampleio::REAL`; the
//! format itself stores some in either), unit vectors are octahedral `u16 × 2`. The consumers'
//! own checks on values (finite, in range) and on combinations (`u` with `v`, all or none of a
//! BSDF) stay where they are.

use sampleio::{FieldNeed, Needs, SampleKind};

const fn real(name: &'static str, components: u32) -> FieldNeed {
    FieldNeed::real(name, components)
}

const fn optional(name: &'static str, components: u32) -> FieldNeed {
    FieldNeed::real(name, components).optional()
}

/// TLFR (`tlfr`, `tlfr-nn`, `tlfr-bw`, `lfr reconstruct`): `lens-time` samples
/// (`tlfr::samples::read_lens_time`).
pub const TLFR: Needs = Needs {
    consumer: "TLFR",
    fields: &[
        real("x", 1),
        real("y", 1),
        real("z", 1),
        real("radiance", 3),
        optional("u", 1),
        optional("v", 1),
        optional("t", 1),
        optional("motion", 3),
        optional("bandwidth", 1),
    ],
};

/// TLFR's soft shadows: the shading fields of the camera's `lens-time` file
/// (`tlfr::shadows::read_shading`), on top of [`TLFR`].
pub const TLFR_SOFT_SHADOW: Needs = Needs {
    consumer: "TLFR soft shadows",
    fields: &[real("albedo", 3), FieldNeed::octahedral("normal"), real("radiance_without_light", 3)],
};

/// TLFR's soft shadows: the `light` file (`tlfr::shadows::read_light`).
pub const TLFR_LIGHT: Needs = Needs {
    consumer: "TLFR soft shadows (light samples)",
    fields: &[
        real("lu", 1),
        real("lv", 1),
        real("lx", 1),
        real("ly", 1),
        real("z", 1),
        real("radiance", 3),
        real("density", 1),
        optional("t", 1),
        optional("motion", 3),
    ],
};

/// The fields of `indirect` and `ao` files ILFR reads, then the kind's own ones.
macro_rules! ilfr_fields {
    ($($own:expr),*) => {
        &[
            real("x", 1),
            real("y", 1),
            FieldNeed::octahedral("direction"),
            real("origin", 3),
            real("hit", 3),
            FieldNeed::octahedral("origin_normal"),
            FieldNeed::octahedral("hit_normal"),
            $($own,)*
            optional("u", 1),
            optional("v", 1),
            optional("bandwidth", 1),
            optional("albedo", 3),
            optional("weight", 3),
            optional("direct", 3),
            optional("secondary_albedo", 3),
            optional("secondary_direct", 3),
            FieldNeed::octahedral("origin_geometric_normal").optional(),
            optional("origin_base_color", 3),
            optional("origin_metallic", 1),
            optional("origin_roughness", 1),
            optional("origin_specular", 1),
            optional("origin_f0", 1),
            optional("hit_base_color", 3),
            optional("hit_metallic", 1),
            optional("hit_roughness", 1),
            optional("hit_specular", 1),
            optional("hit_f0", 1),
        ]
    };
}

/// ILFR (`ilfr`, `ilfr-recursive`, `lfr bench-ilfr`): `indirect` samples
/// (`ilfr::samples::read_indirect`).
pub const ILFR_INDIRECT: Needs = Needs { consumer: "ILFR", fields: ilfr_fields!(real("radiance", 3)) };

/// ILFR's ambient occlusion: `ao` samples (`ilfr::samples::read_indirect`).
pub const ILFR_AO: Needs = Needs { consumer: "ILFR", fields: ilfr_fields!(real("distance", 1)) };

/// [`ILFR_INDIRECT`] or [`ILFR_AO`] by the file's kind (`None` for a kind ILFR does not read).
pub fn ilfr(kind: SampleKind) -> Option<&'static Needs> {
    match kind {
        SampleKind::Indirect => Some(&ILFR_INDIRECT),
        SampleKind::Ao => Some(&ILFR_AO),
        SampleKind::LensTime | SampleKind::Light => None,
    }
}

/// ILFR's lens mode (`ilfr-dof`): `lens-time` samples as camera rays
/// (`ilfr::lens::read_primary_rays`).
pub const ILFR_LENS: Needs = Needs {
    consumer: "ILFR's lens mode",
    fields: &[
        real("x", 1),
        real("y", 1),
        real("z", 1),
        real("radiance", 3),
        real("depth_gradient", 2),
        optional("u", 1),
        optional("v", 1),
        optional("t", 1),
        optional("motion", 3),
    ],
};

/// `box` on `indirect` samples: `weight · radiance`, `albedo` standing in for a missing `weight`
/// (`box` itself requires one of the two).
pub const BOX_INDIRECT: Needs =
    Needs { consumer: "box", fields: &[real("radiance", 3), optional("weight", 3), optional("albedo", 3)] };

/// `box` on `ao` samples: the distance and whether the camera ray hit.
pub const BOX_AO: Needs =
    Needs { consumer: "box", fields: &[real("distance", 1), FieldNeed::octahedral("origin_normal")] };

/// `box` on `lens-time` and `light` samples: the radiance.
pub const BOX_RADIANCE: Needs = Needs { consumer: "box", fields: &[real("radiance", 3)] };

/// What `box` reads of a file of `kind`.
pub fn box_filter(kind: SampleKind) -> &'static Needs {
    match kind {
        SampleKind::Indirect => &BOX_INDIRECT,
        SampleKind::Ao => &BOX_AO,
        SampleKind::LensTime | SampleKind::Light => &BOX_RADIANCE,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sampleio::{FieldSpec, FieldType, HeaderSpec, SampleFile, SampleWriter};

    /// Every declaration names each field once (a second entry would never be checked).
    #[test]
    fn every_declaration_names_each_field_once() {
        for needs in [
            &TLFR,
            &TLFR_SOFT_SHADOW,
            &TLFR_LIGHT,
            &ILFR_INDIRECT,
            &ILFR_AO,
            &ILFR_LENS,
            &BOX_INDIRECT,
            &BOX_AO,
            &BOX_RADIANCE,
        ] {
            let mut names: Vec<&str> = needs.fields.iter().map(|f| f.name).collect();
            names.sort_unstable();
            let count = names.len();
            names.dedup();
            assert_eq!(names.len(), count, "{}: {names:?}", needs.consumer);
        }
    }

    /// A `lens-time` file whose `radiance` is one byte is refused by every consumer reading it,
    /// naming the file, the field, what it is and what is needed.
    #[test]
    fn a_byte_radiance_is_refused_with_file_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bytes.lfrs");
        let spec = HeaderSpec::new(SampleKind::LensTime, 1, 1, 1)
            .field(FieldSpec::new("x", FieldType::F32, 1))
            .field(FieldSpec::new("y", FieldType::F32, 1))
            .field(FieldSpec::new("z", FieldType::F32, 1))
            .field(FieldSpec::new("radiance", FieldType::U8, 1))
            .field(FieldSpec::new("depth_gradient", FieldType::F32, 2));
        let mut writer = SampleWriter::create(&path, spec).unwrap();
        writer.push(&[0.5, 0.5, 1.0, 7.0, 0.0, 0.0]).unwrap();
        writer.finish().unwrap();
        let file = SampleFile::open(&path).unwrap();
        for (needs, consumer) in [(&TLFR, "TLFR"), (&ILFR_LENS, "ILFR's lens mode"), (&BOX_RADIANCE, "box")] {
            let error = file.check_needs(needs).unwrap_err().to_string();
            let expected = format!("{}: field `radiance` is u8×1, {consumer} needs f32×3 or f16×3", path.display());
            assert_eq!(error, expected);
        }
    }
}
