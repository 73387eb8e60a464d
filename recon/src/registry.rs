//! Every method `lfr compare` can run, described as data: its name, the effects it handles,
//! its options with their defaults and ranges, and one line of description. This is the only
//! file that names the concrete methods; the harness finds them here by a spec
//! `NAME[:key=value...]` (options parsed by `crate::options`).

use crate::auxiliary::AuxiliaryMode;
use crate::baselines::box_filter::BoxFilter;
use crate::baselines::oidn::Oidn;
use crate::error::Error;
use crate::gif::filtered_indirect::{FilterOptions, FilteredIndirect};
use crate::ilfr::choices::{GatherChoice, IlfrChoices, Variant};
use crate::ilfr::method::IlfrMethod;
use crate::ilfr::robust::RobustMode;
use crate::ilfr::shrink::Trim;
use crate::ilfr::sparse::SparseParams;
use crate::ilfr::surfaces::ConflictTest;
use crate::method::{Effect, Method};
use crate::options::{OptionKind, OptionSpec, Options};
use crate::pipeline::Denoised;
use crate::tlfr::global_illumination::{GiMode, DEFAULT_GI_RADIUS};
use crate::tlfr::method::{TLFR, TLFR_BANDWIDTH, TLFR_NEAREST};
use crate::tlfr::settings::Kernel;

/// One method as data.
pub struct MethodSpec {
    /// The `--methods` name.
    pub name: &'static str,
    /// The effects it reconstructs.
    pub effects: &'static [Effect],
    /// The options it takes as `NAME:key=value`.
    pub options: &'static [OptionSpec],
    /// One line for `--list-methods` and reports.
    pub description: &'static str,
    /// The method with `options` applied (already checked against `options`' ranges).
    build: fn(&Options) -> Result<Box<dyn Method>, Error>,
}

/// A method resolved from a spec: its canonical name (with the options it was given, in
/// declared order: `gif:radius=8:subsample=2`), its description and the method itself.
pub struct Registered {
    pub name: String,
    pub spec: &'static MethodSpec,
    pub method: Box<dyn Method>,
}

impl Registered {
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Whether it reconstructs `effect`: one of its declared effects that its options keep.
    pub fn supports(&self, effect: Effect) -> bool {
        self.spec.effects.contains(&effect) && self.method.handles(effect)
    }
}

impl std::ops::Deref for Registered {
    type Target = dyn Method;

    fn deref(&self) -> &(dyn Method + 'static) {
        self.method.as_ref()
    }
}

const ALL_EFFECTS: &[Effect] = &Effect::ALL;
const INDIRECT: &[Effect] = &[Effect::Indirect, Effect::Glossy];
const INDIRECT_AND_AO: &[Effect] = &[Effect::Indirect, Effect::Glossy, Effect::Ao];
const DEFOCUS_AND_MOTION: &[Effect] = &[Effect::Dof, Effect::Motion, Effect::DofMotion];
const DEFOCUS_MOTION_AND_SHADOWS: &[Effect] = &[Effect::Dof, Effect::Motion, Effect::DofMotion, Effect::SoftShadow];

const RADIUS: OptionSpec = OptionSpec {
    key: "radius",
    kind: OptionKind::Count { min: 1, max: 1024 },
    default: "24",
    help: "window radius in pixels at an 800-pixel image (scaled with the image)",
};
const EPS_NORMAL: OptionSpec = OptionSpec {
    key: "eps_normal",
    kind: OptionKind::Positive,
    default: "0.01",
    help: "regularisation ε of the normal channels",
};
const EPS_DEPTH: OptionSpec = OptionSpec {
    key: "eps_depth",
    kind: OptionKind::Positive,
    default: "0.02",
    help: "regularisation ε of the depth channel",
};
const SUBSAMPLE: OptionSpec = OptionSpec {
    key: "subsample",
    kind: OptionKind::Count { min: 1, max: 64 },
    default: "1",
    help: "fast guided filter's subsampling factor (1: the exact filter)",
};
const ITERATIONS: OptionSpec = OptionSpec {
    key: "iterations",
    kind: OptionKind::Count { min: 1, max: crate::baselines::atrous::MAX_ITERATIONS },
    default: "5",
    help: "À-Trous iterations (dilations 1, 2, 4, …)",
};
const LOOKUP: OptionSpec = OptionSpec {
    key: "lookup",
    kind: OptionKind::Choice(&["geometry", "own-pixel"]),
    default: "geometry",
    help: "how additional eye rays take filtered light: the geometry-aware lookup or their own pixel's",
};
const CONFLICT: OptionSpec = OptionSpec {
    key: "conflict",
    kind: OptionKind::Choice(&["auto", "event-line", "facing", "off-plane"]),
    default: "auto",
    help: "which splats belong to one apparent surface: the paper's event-line test (Figure 5), the authors' code's \
           facing/coplanar test, the event line asked only off the splats' tangent planes, or (auto) off-plane but \
           the event line for ambient occlusion",
};
const SHRINK: OptionSpec = OptionSpec {
    key: "shrink",
    kind: OptionKind::Choice(&["all-rays", "hit-rays"]),
    default: "all-rays",
    help: "which input rays shrink the splats they cross (§2.3.1): all, or only those that hit (the authors' code)",
};
const TRIM: OptionSpec = OptionSpec {
    key: "trim",
    kind: OptionKind::Choice(&["auto", "disc", "wedges"]),
    default: "auto",
    help: "what an input ray that crosses a splat trims (§2.3.1): the whole disc to the ray's distance (the paper), \
           or only the disc's 45° wedges towards the crossing, as far as a straight edge through it needs (beyond \
           the paper), or (auto) wedges for indirect light and glossy reflections, the whole disc otherwise",
};
const SMALL: OptionSpec = OptionSpec {
    key: "small",
    kind: OptionKind::Choice(&["auto", "merge", "keep"]),
    default: "auto",
    help: "one- to three-splat surfaces the ray passes near the rim of (§2.5): merged into the surface behind, \
           kept, or (auto) merged except for ambient occlusion",
};
const ROBUST: OptionSpec = OptionSpec {
    key: "robust",
    kind: OptionKind::Choice(&["spread", "clamp", "off"]),
    default: "spread",
    help: "splats far brighter than their neighbours: their excess shared with the neighbours (energy kept), \
           dropped, or left alone (the paper)",
};
const GRAIN: OptionSpec = OptionSpec {
    key: "grain",
    kind: OptionKind::Choice(&["keep", "filter"]),
    default: "keep",
    help: "the final gather's per-pixel grain in diffuse indirect light: kept (the paper) or taken out by three \
           edge-aware À-Trous levels on the primary hits' normals and positions and on luminance in units of each \
           pixel's standard error from its rays, light divided by albedo (beyond the paper; --effect indirect, \
           diffuse scenes)",
};
const VARIANT: OptionSpec = OptionSpec {
    key: "variant",
    kind: OptionKind::Choice(&["auto", "paper", "nearest-splat", "records"]),
    default: "auto",
    help: "the final gather: every hit gathers its own rays and every ray groups the splats it meets into apparent \
           surfaces (paper); every hit gathers its own rays and each ray reads the nearest splat it meets, its \
           radiance prefiltered over its neighbours (nearest-splat); or, for indirect light at Lambertian hits, records \
           of nearest-splat rays at a subset of the hits, interpolated to the others where their error estimate \
           allows (records; irradiance caching); auto: for indirect light nearest-splat under the sparse gather \
           (gather=auto) or with grain=filter, records under gather=full; nearest-splat for ambient occlusion, \
           paper for glossy reflections (ilfr-recursive: paper)",
};
const GATHER: OptionSpec = OptionSpec {
    key: "gather",
    kind: OptionKind::Choice(&["auto", "full", "sparse"]),
    default: "auto",
    help: "where the final gather runs for indirect light at Lambertian hits: every pixel (full), or a grid of \
           pixels `stride` apart (and the image's last row and column), the light before the albedo of the others \
           interpolated from their cell's corners with geometry-aware weights and a full gather where the \
           interpolation's error estimate says so (sparse; beyond the paper; with variant=auto the nearest splat); \
           auto: sparse for indirect light unless a variant or grain=filter is chosen, full otherwise",
};
const STRIDE: OptionSpec = OptionSpec {
    key: "stride",
    kind: OptionKind::Count { min: 2, max: 16 },
    default: "4",
    help: "where the sparse gather runs (not read otherwise): pixels between the grid's columns and rows",
};
const GRID_RAYS: OptionSpec = OptionSpec {
    key: "grid_rays",
    kind: OptionKind::Count { min: 1, max: 16 },
    default: "4",
    help: "where the sparse gather runs (not read otherwise): the grid pixels' reconstruction rays as a multiple \
           of the pixel budget",
};
const QUALITY: OptionSpec = OptionSpec {
    key: "quality",
    kind: OptionKind::Choice(&crate::baselines::oidn::QUALITIES),
    default: "high",
    help: "OIDN's filter quality",
};
const AUXILIARY: OptionSpec = OptionSpec {
    key: "aux",
    kind: OptionKind::Choice(&["integrated", "centre"]),
    default: "integrated",
    help: "the denoiser's albedo and normal from the same samples: each pixel's mean over the lens and shutter, or \
           its sample nearest the lens centre and mid-shutter (pinhole-like)",
};
const BANDWIDTH: OptionSpec = OptionSpec {
    key: "bandwidth",
    kind: OptionKind::Positive,
    default: "0.5",
    help: "scale of the lens-distance Gaussian matched to each sample's BRDF bandwidth",
};
const GI: OptionSpec = OptionSpec {
    key: "gi",
    kind: OptionKind::Choice(&["split", "whole"]),
    default: "split",
    help: "full global illumination: only each sample's `direct` part through the reconstruction, with the light \
           of longer paths averaged per pixel and smoothed (the default: +0.7 to +2.1 dB on full-GI input, \
           docs/tlfr.md), or the whole radiance (the paper)",
};
const GI_RADIUS: OptionSpec = OptionSpec {
    key: "gi_radius",
    kind: OptionKind::Count { min: 0, max: 64 },
    default: "3",
    help: "with gi=split: radius in pixels of the depth-aware smoothing of the longer paths' light (0: per pixel)",
};
const KERNEL: OptionSpec = OptionSpec {
    key: "kernel",
    kind: OptionKind::Choice(&["fused", "oracle"]),
    default: "fused",
    help: "how each location is evaluated: one SIMD pass per sample (fused) or the per-location code it is tested \
           against (oracle); the same images within f32 rounding (docs/tlfr.md)",
};
const PASSES: OptionSpec = OptionSpec {
    key: "passes",
    kind: OptionKind::Count { min: 1, max: 8 },
    default: "1",
    help: "passes of recursive filtering at the secondary hits before the final gather",
};

/// Every method, in the order reports list them.
pub const METHODS: &[MethodSpec] = &[
    MethodSpec {
        name: "box",
        effects: ALL_EFFECTS,
        options: &[],
        description: "per-pixel average of the input samples: path tracing at the input spp, read back",
        build: |_| Ok(Box::new(BoxFilter)),
    },
    MethodSpec {
        name: "oidn",
        effects: ALL_EFFECTS,
        options: &[QUALITY],
        description: "Intel Open Image Denoise 2.5 (CPU, via pyoidn, HDR) on the box-filtered path-traced frame with \
                      albedo and normal",
        build: |options| {
            let default = Oidn::default();
            Ok(Box::new(Oidn { quality: options.choice("quality").map_or(default.quality, str::to_string) }))
        },
    },
    MethodSpec {
        name: "gif",
        effects: INDIRECT,
        options: &[RADIUS, EPS_NORMAL, EPS_DEPTH, SUBSAMPLE, LOOKUP],
        description: "guided image filter with the normal + depth guide (Bauszat et al. 2011)",
        build: |options| filter(FilteredIndirect::gif(), options),
    },
    MethodSpec {
        name: "gif-normal",
        effects: INDIRECT,
        options: &[RADIUS, EPS_NORMAL, SUBSAMPLE, LOOKUP],
        description: "guided image filter with the 3-channel normal guide (Bauszat et al. 2011, Figure 5b)",
        build: |options| filter(FilteredIndirect::gif_normal(), options),
    },
    MethodSpec {
        name: "gif-grey",
        effects: INDIRECT,
        options: &[RADIUS, EPS_NORMAL, SUBSAMPLE, LOOKUP],
        description: "guided image filter with the 1-channel grey-normal guide (Bauszat et al. 2011, Figure 5a)",
        build: |options| filter(FilteredIndirect::gif_grey(), options),
    },
    MethodSpec {
        name: "bilateral",
        effects: INDIRECT,
        options: &[RADIUS, LOOKUP],
        description: "cross-bilateral filter on normal and depth, the guided filter's quality baseline (Bauszat et \
                      al. 2011, Table 2)",
        build: |options| filter(FilteredIndirect::bilateral(), options),
    },
    MethodSpec {
        name: "atrous",
        effects: INDIRECT,
        options: &[ITERATIONS, LOOKUP],
        description: "edge-avoiding À-Trous wavelet filter on normal and position (Dammertz et al. 2010)",
        build: |options| filter(FilteredIndirect::atrous(), options),
    },
    MethodSpec {
        name: "atrous-sn",
        effects: INDIRECT,
        options: &[ITERATIONS, LOOKUP],
        description: "À-Trous with an extra range term on the secondary-hit normal (Lehtinen et al. 2012's baseline)",
        build: |options| filter(FilteredIndirect::atrous_secondary_normal(), options),
    },
    MethodSpec {
        name: "tlfr",
        effects: DEFOCUS_MOTION_AND_SHADOWS,
        options: &[GI, GI_RADIUS, KERNEL],
        description: "temporal light field reconstruction (Lehtinen et al. 2011)",
        build: |options| {
            let kernel = match options.choice("kernel") {
                Some("oracle") => Kernel::Oracle,
                _ => Kernel::Fused,
            };
            Ok(Box::new(TLFR.with_gi(tlfr_gi(options)?).with_kernel(kernel)))
        },
    },
    MethodSpec {
        name: "tlfr-nn",
        effects: DEFOCUS_AND_MOTION,
        options: &[],
        description: "temporal light field reconstruction, nearest reprojected sample of the covering surface instead \
                      of the filter",
        build: |_| Ok(Box::new(TLFR_NEAREST)),
    },
    MethodSpec {
        name: "tlfr-bw",
        effects: DEFOCUS_AND_MOTION,
        options: &[BANDWIDTH],
        description: "temporal light field reconstruction with the bandwidth extension (Figure 14) for glossy surfaces",
        build: |options| Ok(Box::new(TLFR_BANDWIDTH.with_bandwidth_scale(options.real("bandwidth")))),
    },
    MethodSpec {
        name: "ilfr",
        effects: INDIRECT_AND_AO,
        options: &[VARIANT, CONFLICT, SHRINK, TRIM, ROBUST, SMALL, GRAIN, GATHER, STRIDE, GRID_RAYS],
        description: "indirect light field reconstruction (Lehtinen et al. 2012)",
        build: |options| {
            let choices = ilfr_choices(options);
            check_sparse_gather(options, &choices)?;
            Ok(Box::new(IlfrMethod::ilfr(choices)))
        },
    },
    MethodSpec {
        name: "ilfr-recursive",
        effects: INDIRECT,
        options: &[PASSES, VARIANT, CONFLICT, SHRINK, TRIM, ROBUST],
        description: "indirect light field reconstruction with recursive filtering at the secondary hits (Lehtinen \
                      et al. 2012 §4)",
        build: |options| {
            let passes = options.count("passes").unwrap_or(1);
            Ok(Box::new(IlfrMethod::recursive(passes, ilfr_choices(options))))
        },
    },
    MethodSpec {
        name: "ilfr-dof",
        effects: DEFOCUS_AND_MOTION,
        options: &[CONFLICT, SHRINK, TRIM],
        description: "indirect light field reconstruction's machinery on camera rays: defocus and motion blur \
                      (Lehtinen et al. 2012 §3.4)",
        build: |options| Ok(Box::new(IlfrMethod::dof(ilfr_choices(options)))),
    },
];

/// A reconstruction followed by a denoiser (`crate::pipeline`), named `FIRST+LAST` and given as
/// `FIRST[:its options]+LAST[:options]`; it handles FIRST's effects.
pub struct PipelineSpec {
    /// The reconstruction: a method of [`METHODS`] that reads samples.
    pub first: &'static str,
    /// The denoiser.
    pub last: &'static str,
    /// The options after `+`: the denoiser's and the auxiliary images'.
    pub options: &'static [OptionSpec],
}

const DENOISER_OPTIONS: &[OptionSpec] = &[QUALITY, AUXILIARY];
/// After a filter of guide buffers the auxiliaries are the guide's (one ray per pixel centre):
/// nothing to integrate, so no `aux` option.
const GUIDE_DENOISER_OPTIONS: &[OptionSpec] = &[QUALITY];

/// Every pipeline: each reconstruction that reads samples (and `box`, their plain average),
/// then OIDN with albedo and normal from the same samples; the guided and the À-Trous filters
/// then OIDN with the guide's albedo and normal.
pub const PIPELINES: &[PipelineSpec] = &[
    PipelineSpec { first: "box", last: "oidn", options: DENOISER_OPTIONS },
    PipelineSpec { first: "tlfr", last: "oidn", options: DENOISER_OPTIONS },
    PipelineSpec { first: "tlfr-nn", last: "oidn", options: DENOISER_OPTIONS },
    PipelineSpec { first: "tlfr-bw", last: "oidn", options: DENOISER_OPTIONS },
    PipelineSpec { first: "ilfr", last: "oidn", options: DENOISER_OPTIONS },
    PipelineSpec { first: "ilfr-recursive", last: "oidn", options: DENOISER_OPTIONS },
    PipelineSpec { first: "ilfr-dof", last: "oidn", options: DENOISER_OPTIONS },
    PipelineSpec { first: "gif", last: "oidn", options: GUIDE_DENOISER_OPTIONS },
    PipelineSpec { first: "atrous", last: "oidn", options: GUIDE_DENOISER_OPTIONS },
];

impl PipelineSpec {
    /// `FIRST+LAST`.
    pub fn name(&self) -> String {
        format!("{}+{}", self.first, self.last)
    }

    /// The reconstruction's declaration (every pipeline's first is one of [`METHODS`]).
    pub fn first_spec(&self) -> &'static MethodSpec {
        spec(self.first).expect("a pipeline's first stage is a registered method")
    }

    fn description(&self) -> String {
        format!(
            "{}'s image denoised by Intel Open Image Denoise with albedo and normal from the same samples (for depth of \
             field and motion integrated over the lens and shutter); time and stats of both stages",
            self.first
        )
    }

    /// The pipeline of `first` (already built from its spec) with `options` (the part after
    /// `LAST:`) applied; its canonical name is FIRST's, `+LAST`, then the options.
    fn build(&'static self, first: Registered, options_text: &str) -> Result<Registered, Error> {
        let name = self.name();
        let known_elsewhere = |key: &str| METHODS.iter().any(|m| m.options.iter().any(|o| o.key == key));
        let options = Options::parse(&name, options_text, self.options, known_elsewhere)?;
        let default = Oidn::default();
        let denoiser = Oidn { quality: options.choice("quality").map_or(default.quality, str::to_string) };
        let auxiliary = match options.choice("aux") {
            Some("centre") => AuxiliaryMode::Centre,
            _ => AuxiliaryMode::Integrated,
        };
        let mut canonical = format!("{}+{}", first.name, self.last);
        if !options.is_empty() {
            canonical = format!("{canonical}:{}", options.canonical());
        }
        let method = Denoised { first: first.method, first_name: first.name, denoiser, auxiliary };
        Ok(Registered { name: canonical, spec: first.spec, method: Box::new(method) })
    }
}

/// The pipeline named `first+last`.
pub fn pipeline(first: &str, last: &str) -> Option<&'static PipelineSpec> {
    PIPELINES.iter().find(|p| p.first == first && p.last == last)
}

/// The `gi` and `gi_radius` options of `tlfr` (default `gi=split`); a radius with `gi=whole`
/// would be ignored, so it is refused.
fn tlfr_gi(options: &Options) -> Result<GiMode, Error> {
    let radius = options.count("gi_radius");
    match (options.choice("gi"), radius) {
        (Some("whole"), Some(_)) => Err(Error::Option {
            spec: format!("tlfr:{}", options.canonical()),
            message: "gi_radius applies only with gi=split (the whole radiance is not smoothed)".into(),
        }),
        (Some("whole"), None) => Ok(GiMode::Whole),
        (_, radius) => Ok(GiMode::Split { radius: radius.unwrap_or(DEFAULT_GI_RADIUS) }),
    }
}

/// The `conflict`, `shrink`, `trim`, `robust`, `small`, `grain`, `variant` and sparse gather
/// (`gather`, `stride`, `grid_rays`) options of the ILFR methods.
fn ilfr_choices(options: &Options) -> IlfrChoices {
    let defaults = IlfrChoices::default();
    IlfrChoices {
        conflict_test: match options.choice("conflict") {
            Some("event-line") => Some(ConflictTest::EventLine),
            Some("facing") => Some(ConflictTest::FacingOrCoplanar),
            Some("off-plane") => Some(ConflictTest::EventLineOffPlane),
            _ => defaults.conflict_test,
        },
        shrink_with_escaped_rays: options
            .choice("shrink")
            .map_or(defaults.shrink_with_escaped_rays, |c| c == "all-rays"),
        trim: match options.choice("trim") {
            Some("wedges") => Some(Trim::Wedges),
            Some("disc") => Some(Trim::Disc),
            _ => defaults.trim,
        },
        robust: match options.choice("robust") {
            Some("clamp") => RobustMode::Clamp,
            Some("off") => RobustMode::Off,
            Some("spread") => RobustMode::Spread,
            _ => defaults.robust,
        },
        merge_small_surfaces: match options.choice("small") {
            Some("merge") => Some(true),
            Some("keep") => Some(false),
            _ => defaults.merge_small_surfaces,
        },
        filter_grain: options.choice("grain").map_or(defaults.filter_grain, |c| c == "filter"),
        variant: match options.choice("variant") {
            Some("paper") => Some(Variant::Paper),
            Some("nearest-splat") => Some(Variant::NearestSplat),
            Some("records") => Some(Variant::Records),
            _ => defaults.variant,
        },
        gather: match options.choice("gather") {
            Some("full") => GatherChoice::Full,
            Some("sparse") => GatherChoice::Sparse,
            _ => defaults.gather,
        },
        sparse: SparseParams {
            stride: options.count("stride").unwrap_or(defaults.sparse.stride),
            grid_ray_factor: options.count("grid_rays").unwrap_or(defaults.sparse.grid_ray_factor),
            ..defaults.sparse
        },
    }
}

/// `gather=sparse` is refused where it cannot apply: with records (which interpolate on their
/// own) or with the grain filter (which needs every pixel's own spread). `stride` and
/// `grid_rays` are read only where the sparse gather runs (spelled out where it does not, they
/// are accepted: the listing's round trip spells out every default).
fn check_sparse_gather(options: &Options, choices: &IlfrChoices) -> Result<(), Error> {
    let refuse =
        |message: &str| Err(Error::Option { spec: format!("ilfr:{}", options.canonical()), message: message.into() });
    let sparse = choices.gather == GatherChoice::Sparse;
    if sparse && choices.variant == Some(Variant::Records) {
        return refuse("gather=sparse replaces the records' interpolation: choose variant=nearest-splat or paper");
    }
    if sparse && choices.filter_grain {
        return refuse("grain=filter needs a gather at every pixel: it does not combine with gather=sparse");
    }
    Ok(())
}

/// A filter of the filtered path-tracing pipeline with `options` applied.
fn filter(variant: FilteredIndirect, options: &Options) -> Result<Box<dyn Method>, Error> {
    let name = variant.name.clone();
    let filter = variant.with_options(&FilterOptions::from_options(options)).map_err(|error| Error::Option {
        spec: format!("{name}:{}", options.canonical()),
        message: error.to_string(),
    })?;
    Ok(Box::new(filter))
}

/// The method called `name` (no options), as data.
pub fn spec(name: &str) -> Option<&'static MethodSpec> {
    METHODS.iter().find(|m| m.name == name)
}

impl MethodSpec {
    /// Parses `text` (`key=value` pairs separated by `:`) against this method's options.
    pub fn parse_options(&'static self, text: &str) -> Result<Options, Error> {
        let known_elsewhere = |key: &str| METHODS.iter().any(|m| m.options.iter().any(|o| o.key == key));
        Options::parse(self.name, text, self.options, known_elsewhere)
    }

    /// This method with `options` applied.
    pub fn build(&'static self, options: &Options) -> Result<Registered, Error> {
        let name =
            if options.is_empty() { self.name.to_string() } else { format!("{}:{}", self.name, options.canonical()) };
        Ok(Registered { name, spec: self, method: (self.build)(options)? })
    }
}

/// The method `spec` names: `NAME` or `NAME:key=value:...`. `Ok(None)` when no method has that
/// name; `Err` for options that do not parse or apply.
pub fn find(spec_text: &str) -> Result<Option<Registered>, Error> {
    if let Some((first_text, last_text)) = spec_text.split_once('+') {
        let first_name = first_text.split_once(':').map_or(first_text, |(name, _)| name);
        let (last_name, last_options) = last_text.split_once(':').unwrap_or((last_text, ""));
        let Some(pipeline) = pipeline(first_name, last_name) else {
            if spec(first_name).is_none() {
                return Ok(None);
            }
            let known: Vec<String> = PIPELINES.iter().map(PipelineSpec::name).collect();
            return Err(Error::Option {
                spec: spec_text.to_string(),
                message: format!("no such pipeline; the pipelines are {}", known.join(", ")),
            });
        };
        let Some(first) = find(first_text)? else { return Ok(None) };
        return pipeline.build(first, last_options).map(Some);
    }
    let (name, options) = spec_text.split_once(':').unwrap_or((spec_text, ""));
    let Some(spec) = spec(name) else { return Ok(None) };
    let options = spec.parse_options(options)?;
    spec.build(&options).map(Some)
}

/// One method's block of `--list-methods`: its name, description, effects and options (range,
/// default, help). The harness lists its scene-level methods with it too.
pub fn method_block(name: &str, description: &str, effects: &[Effect], options: &[OptionSpec]) -> String {
    let effects: Vec<&str> = effects.iter().map(|e| e.name()).collect();
    let mut text = format!("{name}\n    {description}\n    effects: {}\n", effects.join(", "));
    if options.is_empty() {
        text.push_str("    options: none\n");
    } else {
        text.push_str(&format!("    options ({name}:key=value:...):\n"));
    }
    for option in options {
        let (key, range, default, help) = (option.key, option.range(), option.default, option.help);
        text.push_str(&format!("      {key} = {range}, default {default}: {help}\n"));
    }
    text
}

/// `lfr compare --list-methods`: every method with its effects, options (range, default, help)
/// and description, one block per method.
pub fn listing() -> String {
    let mut text = String::new();
    for spec in METHODS {
        text.push_str(&method_block(spec.name, spec.description, spec.effects, spec.options));
    }
    for pipeline in PIPELINES {
        let first = pipeline.first_spec();
        let effects: Vec<&str> = first.effects.iter().map(|e| e.name()).collect();
        let name = pipeline.name();
        text.push_str(&format!("{name}\n    {}\n    effects: {}\n", pipeline.description(), effects.join(", ")));
        text.push_str(&format!(
            "    options: {}'s before the `+` ({}:key=value:...+{}), and after `{}`:\n",
            pipeline.first, pipeline.first, pipeline.last, pipeline.last
        ));
        for option in pipeline.options {
            let (key, range, default, help) = (option.key, option.range(), option.default, option.help);
            text.push_str(&format!("      {key} = {range}, default {default}: {help}\n"));
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_every_default_builds() {
        let mut names: Vec<_> = METHODS.iter().map(|m| m.name).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), METHODS.len());
        for spec in METHODS {
            let method = spec.build(&Options::default()).unwrap_or_else(|e| panic!("{}: {e}", spec.name));
            assert_eq!(method.name(), method.spec.name, "no options, plain name");
            assert!(!method.spec.effects.is_empty() && !method.spec.description.is_empty());
        }
    }

    #[test]
    fn every_pipeline_starts_with_a_method_that_reads_samples_or_guides_and_builds() {
        use crate::method::Input;
        for pipeline in PIPELINES {
            let first = pipeline.first_spec();
            let built = find(&pipeline.name()).unwrap().unwrap();
            assert_eq!(built.name(), pipeline.name(), "no options, plain name");
            let input = built.input();
            assert!(matches!(input, Input::Samples | Input::Guide), "{}: {input:?}", pipeline.name());
            // Only the sample readers' auxiliaries can be integrated over lens and time.
            let has_aux = pipeline.options.iter().any(|o| o.key == "aux");
            assert_eq!(has_aux, input == Input::Samples, "{}", pipeline.name());
            for effect in Effect::ALL {
                assert_eq!(built.supports(effect), first.effects.contains(&effect), "{}: {effect:?}", pipeline.name());
            }
        }
    }

    #[test]
    fn pipelines_parse_both_stages_options_and_name_them_canonically() {
        let built = find("ilfr:grain=filter+oidn:aux=centre:quality=fast").unwrap().unwrap();
        assert_eq!(built.name(), "ilfr:grain=filter+oidn:quality=fast:aux=centre");
        assert!(!built.supports(Effect::Glossy), "the first stage's options narrow the effects");
        let debug = format!("{:?}", built.method);
        assert!(
            debug.contains("quality: \"fast\"") && debug.contains("Centre") && debug.contains("filter_grain: true")
        );
        assert_eq!(find("ilfr+oidn").unwrap().unwrap().name(), "ilfr+oidn");
        // The denoiser's options are checked by the one parser, with its error format.
        let error = find("ilfr+oidn:quality=best").err().unwrap().to_string();
        assert!(error.contains("ilfr+oidn") && error.contains("quality"), "{error}");
        let error = find("ilfr+oidn:grain=filter").err().unwrap().to_string();
        assert!(error.contains("grain"), "{error}");
        // A pipeline that does not exist: an error listing the ones that do; an unknown first
        // stage is an unknown method.
        let error = find("bilateral+oidn").err().unwrap().to_string();
        assert!(error.contains("no such pipeline") && error.contains("tlfr+oidn"), "{error}");
        assert!(find("nonsense+oidn").unwrap().is_none());
        assert!(find("ilfr:grain=maybe+oidn").is_err());
        // After a guide filter there is nothing to integrate: `aux` is not its option.
        assert_eq!(find("gif:radius=8+oidn:quality=fast").unwrap().unwrap().name(), "gif:radius=8+oidn:quality=fast");
        assert!(find("gif+oidn:aux=centre").is_err());
    }

    #[test]
    fn the_listing_names_every_method_and_pipeline_with_its_options() {
        let listing = listing();
        for spec in METHODS {
            assert!(listing.lines().any(|l| l == spec.name), "{}", spec.name);
        }
        for pipeline in PIPELINES {
            assert!(listing.lines().any(|l| l == pipeline.name()), "{}", pipeline.name());
        }
        assert!(listing.contains("aux = integrated|centre, default integrated"), "{listing}");
    }

    #[test]
    fn ilfr_declares_its_effects() {
        let (ilfr, recursive) = (spec("ilfr").unwrap(), spec("ilfr-recursive").unwrap());
        assert!([Effect::Indirect, Effect::Ao, Effect::Glossy].iter().all(|e| ilfr.effects.contains(e)));
        assert!(!recursive.effects.contains(&Effect::Ao) && !ilfr.effects.contains(&Effect::Dof));
    }

    #[test]
    fn the_declared_defaults_are_the_methods_defaults() {
        // Spelling every default out must give the method the harness runs without options:
        // the data of the listing is what the code does (`gi=split:gi_radius=3` included).
        for spec in METHODS {
            let text: Vec<String> = (spec.options.iter()).map(|o| format!("{}={}", o.key, o.default)).collect();
            let explicit = spec.parse_options(&text.join(":")).unwrap_or_else(|e| panic!("{}: {e}", spec.name));
            let explicit = spec.build(&explicit).unwrap();
            let plain = spec.build(&Options::default()).unwrap();
            assert_eq!(format!("{:?}", explicit.method), format!("{:?}", plain.method), "{}", spec.name);
        }
    }

    #[test]
    fn specs_parse_apply_and_name_the_variant() {
        let gif = find("gif:eps_depth=0.002:radius=8:eps_normal=0.001").unwrap().unwrap();
        assert_eq!(gif.name(), "gif:radius=8:eps_normal=0.001:eps_depth=0.002", "canonical order");
        assert_eq!(find("gif:subsample=2").unwrap().unwrap().name(), "gif:subsample=2");
        assert_eq!(find("bilateral:lookup=own-pixel").unwrap().unwrap().name(), "bilateral:lookup=own-pixel");
        assert_eq!(find("tlfr-bw:bandwidth=2").unwrap().unwrap().name(), "tlfr-bw:bandwidth=2");
        assert_eq!(find("tlfr:kernel=oracle").unwrap().unwrap().name(), "tlfr:kernel=oracle");
        let oracle = find("tlfr:kernel=oracle").unwrap().unwrap();
        assert_ne!(format!("{:?}", oracle.method), format!("{:?}", find("tlfr").unwrap().unwrap().method));
        assert_eq!(find("ilfr-recursive:passes=2").unwrap().unwrap().name(), "ilfr-recursive:passes=2");
        let variant = find("ilfr:shrink=hit-rays:conflict=event-line").unwrap().unwrap();
        assert_eq!(variant.name(), "ilfr:conflict=event-line:shrink=hit-rays", "canonical order");
        let options = spec("ilfr").unwrap().parse_options("conflict=facing:shrink=hit-rays").unwrap();
        let choices = ilfr_choices(&options);
        assert_eq!(
            (choices.conflict_test, choices.shrink_with_escaped_rays),
            (Some(ConflictTest::FacingOrCoplanar), false),
            "the options reach the reconstruction's settings"
        );
        let settings = choices.apply(crate::ilfr::pipeline::IlfrSettings::default(), Effect::Indirect);
        assert_eq!(settings.robust.mode, RobustMode::Spread, "the default");
        assert!(!settings.filter_grain, "the paper's gather keeps its grain by default");
        let grain = ilfr_choices(&spec("ilfr").unwrap().parse_options("grain=filter").unwrap());
        assert!(grain.apply(crate::ilfr::pipeline::IlfrSettings::default(), Effect::Indirect).filter_grain);
        assert!(spec("ilfr").unwrap().parse_options("grain=maybe").is_err());
        let filtered = find("ilfr:grain=filter").unwrap().unwrap();
        assert!(filtered.supports(Effect::Indirect), "diffuse indirect light");
        assert!(!filtered.supports(Effect::Glossy) && !filtered.supports(Effect::Ao), "refused before any run");
        assert!(find("ilfr").unwrap().unwrap().supports(Effect::Glossy));
        for (option, mode) in [("robust=clamp", RobustMode::Clamp), ("robust=off", RobustMode::Off)] {
            let choices = ilfr_choices(&spec("ilfr-recursive").unwrap().parse_options(option).unwrap());
            let applied = choices.apply(crate::ilfr::pipeline::IlfrSettings::default(), Effect::Glossy);
            assert_eq!(applied.robust.mode, mode, "{option}");
        }
        assert_eq!(
            (settings.surfaces.conflict_test, settings.shrink.escaped_rays),
            (ConflictTest::FacingOrCoplanar, false)
        );
        for (option, effect, merge) in [
            ("conflict=auto", Effect::Ao, false),
            ("conflict=auto", Effect::Indirect, true),
            ("small=merge", Effect::Ao, true),
            ("small=keep", Effect::Indirect, false),
            ("small=auto", Effect::Glossy, true),
        ] {
            let choices = ilfr_choices(&spec("ilfr").unwrap().parse_options(option).unwrap());
            let applied = choices.apply(crate::ilfr::pipeline::IlfrSettings::default(), effect);
            assert_eq!(applied.surfaces.merge_small_surfaces, merge, "{option} for {effect:?}");
        }
        for (option, effect, trim) in [
            ("trim=auto", Effect::Ao, Trim::Disc),
            ("trim=auto", Effect::Indirect, Trim::Wedges),
            ("conflict=auto", Effect::Glossy, Trim::Wedges),
            ("trim=auto", Effect::Dof, Trim::Disc),
            ("trim=wedges", Effect::Ao, Trim::Wedges),
            ("trim=disc", Effect::Glossy, Trim::Disc),
        ] {
            let choices = ilfr_choices(&spec("ilfr").unwrap().parse_options(option).unwrap());
            let applied = choices.apply(crate::ilfr::pipeline::IlfrSettings::default(), effect);
            assert_eq!(applied.shrink.trim, trim, "{option} for {effect:?}");
        }
        assert_eq!(find("ilfr-dof:trim=disc").unwrap().unwrap().name(), "ilfr-dof:trim=disc");
        use crate::ilfr::pipeline::RayModelChoice::{ApparentSurfaces, NearestSplat};
        for (option, effect, model, records) in [
            ("variant=auto", Effect::Indirect, NearestSplat, false),
            ("gather=full", Effect::Indirect, NearestSplat, true),
            ("grain=filter", Effect::Indirect, NearestSplat, false),
            ("variant=auto", Effect::Ao, NearestSplat, false),
            ("variant=auto", Effect::Glossy, ApparentSurfaces, false),
            ("variant=paper", Effect::Indirect, ApparentSurfaces, false),
            ("variant=nearest-splat", Effect::Indirect, NearestSplat, false),
            ("variant=records", Effect::Glossy, NearestSplat, true),
        ] {
            let choices = ilfr_choices(&spec("ilfr").unwrap().parse_options(option).unwrap());
            let applied = choices.apply(crate::ilfr::pipeline::IlfrSettings::default(), effect);
            assert_eq!((applied.ray_model, applied.cache.is_some()), (model, records), "{option} for {effect:?}");
        }
        assert!(spec("ilfr").unwrap().parse_options("variant=fast").is_err());
        let rays = |name: &str, effect: Effect| find(name).unwrap().unwrap().default_recon_rays(effect);
        assert_eq!(rays("ilfr", Effect::Indirect), [16, 64]);
        assert_eq!(rays("ilfr:gather=full", Effect::Indirect), [16, 128]);
        assert_eq!(rays("ilfr", Effect::Ao), [16, 128]);
        assert_eq!(rays("ilfr", Effect::Glossy), [256]);
        assert_eq!(rays("ilfr:variant=paper", Effect::Indirect), [256]);
        assert_eq!(rays("ilfr:variant=records", Effect::Glossy), [16, 128]);
        assert_eq!(rays("ilfr+oidn", Effect::Indirect), [16, 64]);
        // The other two keep theirs whatever the variant.
        assert_eq!(rays("ilfr-recursive", Effect::Indirect), [256]);
        assert_eq!(rays("ilfr-recursive:variant=nearest-splat", Effect::Indirect), [256]);
        assert_eq!(rays("ilfr-dof", Effect::Dof), [128]);
        // The sparse gather: on by default for indirect light (a 4-pixel grid at 4× the rays),
        // over the nearest splat; off where a variant or the grain filter is chosen, and for
        // other effects.
        let indirect = |option: &str| {
            let choices = ilfr_choices(&spec("ilfr").unwrap().parse_options(option).unwrap());
            choices.apply(crate::ilfr::pipeline::IlfrSettings::default(), Effect::Indirect)
        };
        let grid = |option: &str| indirect(option).sparse.map(|p| (p.stride, p.grid_ray_factor));
        assert_eq!(grid(""), Some((4, 4)));
        assert_eq!(grid("variant=auto:gather=auto"), Some((4, 4)));
        for chosen in ["gather=full", "variant=nearest-splat", "variant=records", "variant=paper", "grain=filter"] {
            assert_eq!(grid(chosen), None, "{chosen}");
        }
        assert_eq!(grid("variant=paper:gather=sparse"), Some((4, 4)));
        let ao = ilfr_choices(&spec("ilfr").unwrap().parse_options("").unwrap());
        assert_eq!(ao.apply(crate::ilfr::pipeline::IlfrSettings::default(), Effect::Ao).sparse, None);
        let sparse = indirect("gather=sparse:stride=3:grid_rays=4");
        let params = sparse.sparse.unwrap();
        assert_eq!((params.stride, params.grid_ray_factor), (3, 4));
        assert_eq!((sparse.ray_model, sparse.cache), (NearestSplat, None));
        assert_eq!(indirect("gather=sparse:variant=paper").ray_model, ApparentSurfaces);
        assert_eq!(rays("ilfr:gather=sparse", Effect::Indirect), [16, 64]);
        assert_eq!(rays("ilfr:gather=sparse:variant=paper", Effect::Indirect), [256]);
        let gi = |text: &str| tlfr_gi(&spec("tlfr").unwrap().parse_options(text).unwrap()).unwrap();
        assert_eq!(gi(""), GiMode::Split { radius: DEFAULT_GI_RADIUS });
        assert_eq!(gi("gi=whole"), GiMode::Whole);
        assert_eq!(gi("gi_radius=2"), GiMode::Split { radius: 2 });
        assert_eq!(gi("gi=split"), GiMode::Split { radius: GI_RADIUS.default.parse().unwrap() });
        assert_eq!(gi("gi=split"), GiMode::Split { radius: DEFAULT_GI_RADIUS });
        assert_eq!(gi("gi=split:gi_radius=0"), GiMode::Split { radius: 0 });
        assert_eq!(find("tlfr:gi_radius=1:gi=split").unwrap().unwrap().name(), "tlfr:gi=split:gi_radius=1");
        // Only the split (the default) reads `direct`, so only it makes `lfr compare` write (and
        // pay for) it.
        let reads_direct = |text: &str| {
            let needs = find(text).unwrap().unwrap().sample_needs(Effect::DofMotion).unwrap();
            needs.iter().any(|n| n.fields.iter().any(|f| f.name == "direct"))
        };
        assert!(reads_direct("tlfr:gi=split") && reads_direct("tlfr") && !reads_direct("tlfr:gi=whole"));
        assert!(find("median:radius=3").unwrap().is_none());
        assert!(find("median").unwrap().is_none());
        for (spec, needle) in [
            ("gif:radius", "key=value"),
            ("gif:radius=-1", "radius=-1"),
            ("gif:radius=0", "at least 1"),
            ("gif:subsample=0", "at least 1"),
            ("gif:subsample=1.5", "subsample=1.5"),
            ("atrous:subsample=2", "does not apply"),
            ("bilateral:subsample=2", "does not apply"),
            ("gif:eps_normal=0", "positive"),
            ("gif:eps_normal=inf", "positive"),
            ("gif:sigma=2", "unknown option"),
            ("gif:iterations=3", "does not apply"),
            ("gif-normal:eps_depth=0.01", "does not apply"),
            ("bilateral:eps_normal=0.1", "does not apply"),
            ("atrous:radius=4", "does not apply"),
            ("atrous:iterations=99", "iteration"),
            ("gif:lookup=bilinear", "own-pixel"),
            ("tlfr:radius=3", "does not apply to tlfr"),
            ("tlfr:gi=both", "split"),
            ("tlfr:gi=split:gi_radius=65", "gi_radius"),
            ("tlfr:gi=whole:gi_radius=0", "only with gi=split"),
            ("box:x=1", "box takes no options"),
            ("tlfr-bw:bandwidth=0", "positive"),
            ("ilfr-recursive:passes=0", "at least 1"),
            ("ilfr:conflict=maybe", "off-plane"),
            ("ilfr:shrink=some", "hit-rays"),
            ("ilfr:trim=some", "wedges"),
            ("ilfr:small=some", "keep"),
            ("ilfr:gather=some", "sparse"),
            ("ilfr:gather=sparse:stride=1", "at least 2"),
            ("ilfr:gather=sparse:variant=records", "nearest-splat or paper"),
            ("ilfr:gather=sparse:grain=filter", "every pixel"),
            ("ilfr-recursive:gather=sparse", "does not apply"),
        ] {
            let error = find(spec).err().unwrap_or_else(|| panic!("{spec} must fail")).to_string();
            assert!(error.contains(needle) && error.contains(spec.split(':').next().unwrap()), "{spec}: {error}");
        }
    }

    #[test]
    fn the_listing_names_every_method_option_and_default() {
        let listing = listing();
        for spec in METHODS {
            assert!(listing.contains(&format!("{}\n    {}", spec.name, spec.description)), "{}", spec.name);
            for option in spec.options {
                let line = format!("      {} = {}, default {}: ", option.key, option.range(), option.default);
                assert!(listing.contains(&line), "{line}");
            }
        }
    }
}
