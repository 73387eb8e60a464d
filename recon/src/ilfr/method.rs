//! `ilfr`, `ilfr-recursive` and `ilfr-dof` as `lfr compare` methods: one type, [`IlfrMethod`],
//! whose fields say what each reads and runs (like `crate::tlfr::method::TlfrMethod`); the
//! pipeline they share is [`super::pipeline`], the choices they take [`super::choices`].
//!
//! - `ilfr` ([`IlfrMethod::ilfr`]; effects `indirect`, `glossy`, `ao`) reads the effect's `indirect`,
//!   `glossy` or `ao` file and gathers at the primary hits (Eq. 3, §3.3).
//! - `ilfr-recursive` ([`IlfrMethod::recursive`]; effects `indirect`, `glossy`) is the same with passes
//!   of recursive filtering (§4, [`super::recursive`]) with 16 rays per secondary hit before the
//!   final gather: one by default, `ilfr-recursive:passes=N` for more (`crate::registry`).
//! - `ilfr-dof` ([`IlfrMethod::dof`]; effects `dof`, `motion`, `dof-motion`) runs on camera rays (§3.4):
//!   defocus and motion blur from a `lens-time` file, the input of `tlfr`, so that both
//!   reconstruct the very same samples ([`super::lens`]).

use super::choices::{IlfrChoices, Variant};
use super::pipeline::{grain_choice_handles, run_ilfr, run_lens, IlfrSettings};
use crate::method::{Effect, Input, Inputs, Method, MethodError, Output};

/// The rays an ILFR method takes as its input rays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputRays {
    /// The secondary rays of the effect's `indirect`, `glossy` or `ao` file
    /// ([`super::samples::read_indirect`]); the gather runs at the primary hits.
    Secondary,
    /// The camera rays of a `lens-time` file ([`super::lens::read_primary_rays`]); the gather
    /// runs through pixel, lens and shutter (effects `dof`, `motion`, `dof-motion`).
    Camera,
}

/// An ILFR method of `lfr compare`: the same pipeline ([`super::pipeline`]) on the input rays
/// `rays`, with `recursive_passes` passes of recursive filtering (§4) and the user's `choices`.
#[derive(Clone, Copy, Debug)]
pub struct IlfrMethod {
    name: &'static str,
    rays: InputRays,
    /// Passes of recursive filtering (§4) before the final gather; 0: none.
    recursive_passes: u32,
    /// The gather's design where `choices` chooses none; `None`: per effect
    /// ([`IlfrChoices::resolved_variant`]).
    variant_unless_chosen: Option<Variant>,
    /// The default reconstruction rays; `None`: per the design that runs (see
    /// [`Method::default_recon_rays`]).
    recon_rays: Option<u32>,
    choices: IlfrChoices,
}

impl IlfrMethod {
    /// `ilfr`: the paper's reconstruction (indirect light, glossy reflections, ambient
    /// occlusion), the gather's design and rays per effect.
    pub fn ilfr(choices: IlfrChoices) -> IlfrMethod {
        IlfrMethod {
            name: "ilfr",
            rays: InputRays::Secondary,
            recursive_passes: 0,
            variant_unless_chosen: None,
            recon_rays: None,
            choices,
        }
    }

    /// `ilfr-recursive`: `ilfr` with `passes` passes of recursive filtering (paper §4) before the
    /// final gather, with 256 rays and the paper's gather unless a variant is chosen (`auto` is
    /// measured for one pass only).
    pub fn recursive(passes: u32, choices: IlfrChoices) -> IlfrMethod {
        IlfrMethod {
            name: "ilfr-recursive",
            rays: InputRays::Secondary,
            recursive_passes: passes,
            variant_unless_chosen: Some(Variant::Paper),
            recon_rays: Some(256),
            choices,
        }
    }

    /// `ilfr-dof`: `ilfr` on camera rays (paper §3.4), with 128 rays.
    pub fn dof(choices: IlfrChoices) -> IlfrMethod {
        IlfrMethod {
            name: "ilfr-dof",
            rays: InputRays::Camera,
            recursive_passes: 0,
            variant_unless_chosen: None,
            recon_rays: Some(128),
            choices,
        }
    }

    pub fn name(&self) -> &'static str {
        self.name
    }

    /// The choices that run: the user's, with [`Self::variant_unless_chosen`] where they choose
    /// no variant.
    fn choices(&self) -> IlfrChoices {
        IlfrChoices { variant: self.choices.variant.or(self.variant_unless_chosen), ..self.choices }
    }
}

impl Method for IlfrMethod {
    fn input(&self) -> Input {
        Input::Samples
    }

    /// The method's own where it has one (`ilfr-recursive` 256, `ilfr-dof` 128); otherwise 256
    /// for the paper's gather; 16 and 64 under the sparse gather (whose grid gathers `grid_rays`
    /// times the budget); 16 and 128 otherwise (records gather 16 rays per ray of a pixel's
    /// budget, [`IlfrSettings::rays_per_record_ray`]).
    fn default_recon_rays(&self, effect: Effect) -> Vec<u32> {
        if let Some(rays) = self.recon_rays {
            return vec![rays];
        }
        match self.choices.resolved_variant(effect) {
            Variant::Paper => vec![256],
            Variant::NearestSplat if self.choices.resolved_sparse(effect).is_some() => vec![16, 64],
            Variant::NearestSplat | Variant::Records => vec![16, 128],
        }
    }

    /// With `grain=filter`, diffuse indirect light only ([`super::grain`]).
    fn handles(&self, effect: Effect) -> bool {
        grain_choice_handles(self.choices.filter_grain, effect)
    }

    /// The grain filter smooths the image across pixels by geometry alone ([`super::grain`]).
    fn blurs_glossy_reflections(&self) -> bool {
        self.choices.filter_grain
    }

    fn sample_needs(&self, effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        match self.rays {
            InputRays::Secondary => crate::needs::ilfr(effect.sample_kind()).map(|needs| vec![needs]),
            InputRays::Camera => Some(vec![&crate::needs::ILFR_LENS]),
        }
    }

    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError> {
        let settings = IlfrSettings {
            recon_rays,
            seed: inputs.seed,
            recursive_passes: self.recursive_passes,
            ..IlfrSettings::default()
        };
        let settings = self.choices().apply(settings, inputs.effect);
        match self.rays {
            InputRays::Secondary => run_ilfr(self.name, inputs, settings),
            InputRays::Camera => run_lens(self.name, inputs, settings),
        }
    }
}
