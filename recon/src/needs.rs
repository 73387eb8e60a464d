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

/// TLFR (`tlfr`, `tlfr-nn`, `tlfr-bw`, `lfr reconstruct`): `lens-time` samples
/// (`tlfr::samples::read_lens_time`).
pub const TLFR: Needs = Needs {
    consumer: "TLFR",
    fields: &[
        FieldNeed::real("x", 1),
        FieldNeed::real("y", 1),
        FieldNeed::real("z", 1),
        FieldNeed::real("radiance", 3),
        FieldNeed::optional_real("u", 1),
        FieldNeed::optional_real("v", 1),
        FieldNeed::optional_real("t", 1),
        FieldNeed::optional_real("motion", 3),
        FieldNeed::optional_real("bandwidth", 1),
    ],
};

/// TLFR with `gi=split` (`tlfr::global_illumination`): the direct part of each sample's
/// radiance, on top of [`TLFR`].
pub const TLFR_GI_SPLIT: Needs = Needs { consumer: "TLFR gi=split", fields: &[FieldNeed::real("direct", 3)] };

/// TLFR's soft shadows: the shading fields of the camera's `lens-time` file
/// (`tlfr::shadows::read_shading`), on top of [`TLFR`].
pub const TLFR_SOFT_SHADOW: Needs = Needs {
    consumer: "TLFR soft shadows",
    fields: &[
        FieldNeed::real("albedo", 3),
        FieldNeed::octahedral("normal"),
        FieldNeed::real("radiance_without_light", 3),
    ],
};

/// TLFR's soft shadows: the `light` file (`tlfr::shadows::read_light`).
pub const TLFR_LIGHT: Needs = Needs {
    consumer: "TLFR soft shadows (light samples)",
    fields: &[
        FieldNeed::real("lu", 1),
        FieldNeed::real("lv", 1),
        FieldNeed::real("lx", 1),
        FieldNeed::real("ly", 1),
        FieldNeed::real("z", 1),
        FieldNeed::real("radiance", 3),
        FieldNeed::real("density", 1),
        FieldNeed::optional_real("t", 1),
        FieldNeed::optional_real("motion", 3),
    ],
};

/// The fields of `indirect` and `ao` files ILFR reads, then the kind's own ones.
macro_rules! ilfr_fields {
    ($($own:expr),*) => {
        &[
            FieldNeed::real("x", 1),
            FieldNeed::real("y", 1),
            FieldNeed::octahedral("direction"),
            FieldNeed::real("origin", 3),
            FieldNeed::real("hit", 3),
            FieldNeed::octahedral("origin_normal"),
            FieldNeed::octahedral("hit_normal"),
            $($own,)*
            FieldNeed::optional_real("u", 1),
            FieldNeed::optional_real("v", 1),
            FieldNeed::optional_real("bandwidth", 1),
            FieldNeed::optional_real("albedo", 3),
            FieldNeed::optional_real("weight", 3),
            FieldNeed::optional_real("direct", 3),
            FieldNeed::optional_real("secondary_albedo", 3),
            FieldNeed::optional_real("secondary_direct", 3),
            FieldNeed::octahedral("origin_geometric_normal").optional(),
            FieldNeed::optional_real("origin_base_color", 3),
            FieldNeed::optional_real("origin_metallic", 1),
            FieldNeed::optional_real("origin_roughness", 1),
            FieldNeed::optional_real("origin_specular", 1),
            FieldNeed::optional_real("origin_f0", 1),
            FieldNeed::optional_real("hit_base_color", 3),
            FieldNeed::optional_real("hit_metallic", 1),
            FieldNeed::optional_real("hit_roughness", 1),
            FieldNeed::optional_real("hit_specular", 1),
            FieldNeed::optional_real("hit_f0", 1),
        ]
    };
}

/// ILFR (`ilfr`, `ilfr-recursive`, `lfr-bench ilfr`): `indirect` samples
/// (`ilfr::samples::read_indirect`).
pub const ILFR_INDIRECT: Needs = Needs { consumer: "ILFR", fields: ilfr_fields!(FieldNeed::real("radiance", 3)) };

/// ILFR's ambient occlusion: `ao` samples (`ilfr::samples::read_indirect`).
pub const ILFR_AO: Needs = Needs { consumer: "ILFR", fields: ilfr_fields!(FieldNeed::real("distance", 1)) };

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
        FieldNeed::real("x", 1),
        FieldNeed::real("y", 1),
        FieldNeed::real("z", 1),
        FieldNeed::real("radiance", 3),
        FieldNeed::real("depth_gradient", 2),
        FieldNeed::optional_real("u", 1),
        FieldNeed::optional_real("v", 1),
        FieldNeed::optional_real("t", 1),
        FieldNeed::optional_real("motion", 3),
    ],
};

/// `box` on `indirect` samples: `weight · radiance`, `albedo` standing in for a missing `weight`
/// (`box` itself requires one of the two).
pub const BOX_INDIRECT: Needs = Needs {
    consumer: "box",
    fields: &[
        FieldNeed::real("radiance", 3),
        FieldNeed::optional_real("weight", 3),
        FieldNeed::optional_real("albedo", 3),
    ],
};

/// `box` on `ao` samples: the distance and whether the camera ray hit.
pub const BOX_AO: Needs =
    Needs { consumer: "box", fields: &[FieldNeed::real("distance", 1), FieldNeed::octahedral("origin_normal")] };

/// `box` on `lens-time` and `light` samples: the radiance.
pub const BOX_RADIANCE: Needs = Needs { consumer: "box", fields: &[FieldNeed::real("radiance", 3)] };

/// What `box` reads of a file of `kind`.
pub fn box_filter(kind: SampleKind) -> &'static Needs {
    match kind {
        SampleKind::Indirect => &BOX_INDIRECT,
        SampleKind::Ao => &BOX_AO,
        SampleKind::LensTime | SampleKind::Light => &BOX_RADIANCE,
    }
}

/// The auxiliary images of a pipeline's denoiser (`crate::auxiliary`) from `lens-time` samples:
/// each sample's first-hit albedo and normal, on top of the reconstruction's own fields.
pub const AUXILIARY_LENS_TIME: Needs = Needs {
    consumer: "the denoiser's auxiliary images (lens-time samples)",
    fields: &[FieldNeed::real("albedo", 3), FieldNeed::octahedral("normal")],
};

/// The auxiliary images from `indirect` samples: the primary hit's albedo and normal.
pub const AUXILIARY_INDIRECT: Needs = Needs {
    consumer: "the denoiser's auxiliary images (indirect samples)",
    fields: &[FieldNeed::real("albedo", 3), FieldNeed::octahedral("origin_normal")],
};

/// The auxiliary images from `ao` samples: the primary hit's normal (ambient occlusion is a
/// visibility, its albedo 1).
pub const AUXILIARY_AO: Needs = Needs {
    consumer: "the denoiser's auxiliary images (ao samples)",
    fields: &[FieldNeed::octahedral("origin_normal")],
};

/// The auxiliary declaration for samples of `kind` (`None` for `light` samples, which a
/// denoiser never reads).
pub fn auxiliary(kind: SampleKind) -> Option<&'static Needs> {
    match kind {
        SampleKind::LensTime => Some(&AUXILIARY_LENS_TIME),
        SampleKind::Indirect => Some(&AUXILIARY_INDIRECT),
        SampleKind::Ao => Some(&AUXILIARY_AO),
        SampleKind::Light => None,
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
