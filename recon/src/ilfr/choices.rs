//! The choices the paper leaves open for the ILFR methods (`ilfr:variant=…:gather=…:conflict=…`,
//! `crate::registry`) and the rules that settle each one per effect where it is not chosen
//! (`*_for`): [`IlfrChoices::apply`] turns them into the pipeline's [`IlfrSettings`].

use super::cache::CacheParams;
use super::pipeline::{IlfrSettings, RayModelChoice};
use super::robust::{RobustMode, RobustParams};
use super::shrink::{ShrinkParams, Trim};
use super::sparse::SparseParams;
use super::surfaces::{ConflictTest, SurfaceParams};
use crate::method::Effect;

/// The choices the paper leaves open that a user can switch (`ilfr:conflict=…:shrink=…`);
/// docs/history/ilfr.md measures each.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IlfrChoices {
    /// `None`: [`conflict_test_for`] the effect.
    pub conflict_test: Option<ConflictTest>,
    /// Whether escaped input rays shrink splats ([`ShrinkParams::escaped_rays`]).
    pub shrink_with_escaped_rays: bool,
    /// What a blocked input ray trims ([`ShrinkParams::trim`]); `None`: [`trim_for`] the effect.
    pub trim: Option<Trim>,
    /// What is done with outliers of the splat radiance ([`super::robust`]).
    pub robust: RobustMode,
    /// Whether the small-surface rule (§2.5) runs; `None`: [`merge_small_surfaces_for`] the
    /// effect.
    pub merge_small_surfaces: Option<bool>,
    /// Whether the final gather's grain is filtered ([`super::grain`]; indirect light only).
    pub filter_grain: bool,
    /// The gather's design; `None`: [`variant_for`] the effect.
    pub variant: Option<Variant>,
    /// Where the final gather runs for indirect light at Lambertian hits (`ilfr:gather=…`).
    pub gather: GatherChoice,
    /// The sparse gather's grid ([`super::sparse`]) where it runs.
    pub sparse: SparseParams,
}

/// Where the final gather runs for indirect light at Lambertian hits (`ilfr:gather=…`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GatherChoice {
    /// The sparse gather where the design is not chosen ([`IlfrChoices::resolved_sparse`]),
    /// otherwise every pixel.
    Auto,
    /// Every pixel.
    Full,
    /// A grid of pixels, the others interpolated or refined ([`super::sparse`]).
    Sparse,
}

/// The final gather's design (`ilfr:variant=…`; docs/ilfr.md measures each).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variant {
    /// The paper's: every primary hit gathers its own rays, and every ray groups the splats it
    /// meets into apparent surfaces and filters the nearest
    /// ([`super::reconstruct::RayModel::ApparentSurfaces`]).
    Paper,
    /// Every primary hit gathers its own rays; a ray reads the nearest splat it meets, whose
    /// radiance is prefiltered over its neighbours
    /// ([`super::reconstruct::RayModel::NearestSplat`]).
    NearestSplat,
    /// As [`Variant::NearestSplat`], but at Lambertian hits of indirect light records gather at
    /// a subset of the hits and the others interpolate them ([`super::cache`]).
    Records,
}

impl Variant {
    pub fn name(self) -> &'static str {
        match self {
            Variant::Paper => "paper",
            Variant::NearestSplat => "nearest-splat",
            Variant::Records => "records",
        }
    }
}

/// The gather's design for `effect` unless one is chosen (with `filter_grain`, the grain filter,
/// which needs the per-pixel variances of a gather at every hit): records for indirect light
/// (Cornell 128², 4 spp: 5.3–6.6× path tracing's speed to equal PSNR against the paper's
/// gather's 0.9–1.3×; Sponza 160 × 90, 8 spp: 1.2–2.8× against 1.2–2.3×, level with the nearest
/// splat at every hit within the spread), the nearest splat at every hit with the grain filter
/// (5.0× / 6.8× against the paper's gather's 3.9× / 6.0×) and for ambient occlusion (the paper's
/// PSNR within 0.2 dB at a half to a third of its time), the paper's gather for glossy
/// reflections, whose anisotropic nearest neighbour the prefiltered splats do not reproduce
/// (docs/ilfr.md, "Variants and today's results").
pub fn variant_for(effect: Effect, filter_grain: bool) -> Variant {
    match effect {
        Effect::Indirect if !filter_grain => Variant::Records,
        Effect::Indirect | Effect::Ao => Variant::NearestSplat,
        _ => Variant::Paper,
    }
}

impl Default for IlfrChoices {
    fn default() -> Self {
        IlfrChoices {
            conflict_test: None,
            shrink_with_escaped_rays: ShrinkParams::default().escaped_rays,
            trim: None,
            robust: RobustParams::default().mode,
            merge_small_surfaces: None,
            filter_grain: false,
            variant: None,
            gather: GatherChoice::Auto,
            sparse: SparseParams::default(),
        }
    }
}

/// The conflict test used for `effect` unless one is chosen: the event line asked off the
/// tangent planes ([`SurfaceParams::default`]), except for ambient occlusion, where the paper's
/// plain event line measured better (Sponza's foliage: +0.4 to +0.5 dB at 4 and 16 spp;
/// docs/history/ilfr.md, "The conflict test").
pub fn conflict_test_for(effect: Effect) -> ConflictTest {
    match effect {
        Effect::Ao => ConflictTest::EventLine,
        _ => SurfaceParams::default().conflict_test,
    }
}

/// Whether the small-surface rule of §2.5 runs for `effect` unless chosen: yes, except for
/// ambient occlusion. There a one- to three-splat surface in front is far more often a real
/// occluder within the radius than a spurious one: on Sponza (160 × 90, 4 spp) the rule turned
/// 1.8 % of the rays from occluded to visible against 1.2 % from spuriously occluded to
/// visible, and without it ILFR gains 1.2 dB at 4 spp and 2.3 dB at 16 spp, relative MSE −42 %
/// and −51 % (docs/history/ilfr.md, "ambient occlusion (Deliver 4)").
pub fn merge_small_surfaces_for(effect: Effect) -> bool {
    effect != Effect::Ao
}

/// What a blocked input ray trims for `effect` unless chosen: for indirect light and glossy
/// reflections the wedges towards the crossing ([`Trim::Wedges`]: no holes behind trimmed rim
/// splats; +0.6 to +3 dB on Sponza, the glossy monkeys, the roughness sweep and the bunny,
/// Cornell unchanged), otherwise the whole disc (the paper): for ambient occlusion, which has
/// no small-surface rule, the wedges left whole beside a trimmed one overhang silhouettes as
/// false occluders (Sponza −3.4 dB), and in the lens mode they measured no better (docs/history/ilfr.md,
/// "trimming wedges, not whole discs").
pub fn trim_for(effect: Effect) -> Trim {
    match effect {
        Effect::Indirect | Effect::Glossy => Trim::Wedges,
        _ => Trim::Disc,
    }
}

impl IlfrChoices {
    /// `settings` with these choices, for `effect`.
    pub fn apply(&self, settings: IlfrSettings, effect: Effect) -> IlfrSettings {
        let conflict_test = self.conflict_test.unwrap_or_else(|| conflict_test_for(effect));
        let merge_small_surfaces = self.merge_small_surfaces.unwrap_or_else(|| merge_small_surfaces_for(effect));
        let variant = self.resolved_variant(effect);
        IlfrSettings {
            surfaces: SurfaceParams { conflict_test, merge_small_surfaces, ..settings.surfaces },
            shrink: ShrinkParams {
                escaped_rays: self.shrink_with_escaped_rays,
                trim: self.trim.unwrap_or_else(|| trim_for(effect)),
                ..settings.shrink
            },
            robust: RobustParams { mode: self.robust, ..settings.robust },
            filter_grain: self.filter_grain,
            ray_model: match variant {
                Variant::Paper => RayModelChoice::ApparentSurfaces,
                Variant::NearestSplat | Variant::Records => RayModelChoice::NearestSplat,
            },
            cache: (variant == Variant::Records).then(CacheParams::default),
            sparse: self.resolved_sparse(effect),
            ..settings
        }
    }

    /// The variant that runs for `effect`: the chosen one, else [`variant_for`] the effect, with
    /// the nearest splat in place of records under the sparse gather (records interpolate
    /// themselves).
    pub fn resolved_variant(&self, effect: Effect) -> Variant {
        match (self.variant, variant_for(effect, self.filter_grain)) {
            (Some(chosen), _) => chosen,
            (None, Variant::Records) if self.resolved_sparse(effect).is_some() => Variant::NearestSplat,
            (None, auto) => auto,
        }
    }

    /// The sparse gather's grid for `effect`, `None` where every pixel gathers: chosen with
    /// `gather=sparse`; with `gather=auto` for indirect light when neither the variant nor the
    /// grain filter is chosen. Against the records at every hit, in two runs each (`lfr compare
    /// --effect indirect`, 2048-spp references, 2026-12-07 and 2026-12-08, loaded machine), a
    /// 4-pixel grid gathering 4× the rays reached equal PSNR 1.1× (Cornell 128², 4 spp: 35.08
    /// dB at 64 rays against 34.99 dB at 16) and 1.2× (Sponza 160 × 90, 8 spp: 27.89 dB at 64
    /// rays against 25.85 dB at 64) sooner than path tracing and 1.1× / 3.4× sooner against OIDN
    /// (docs/ilfr.md, "The sparse gather").
    pub fn resolved_sparse(&self, effect: Effect) -> Option<SparseParams> {
        let auto = effect == Effect::Indirect && self.variant.is_none() && !self.filter_grain;
        match self.gather {
            GatherChoice::Sparse => Some(self.sparse),
            GatherChoice::Auto if auto => Some(self.sparse),
            GatherChoice::Auto | GatherChoice::Full => None,
        }
    }
}
