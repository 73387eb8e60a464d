//! The one interface every reconstruction and baseline implements (`crate::registry` lists
//! them and builds them from `NAME:key=value` specs). A method names the inputs it reads (sample files of one
//! kind, or the path-traced image with its albedo and normal); the harness traces those inputs,
//! times the tracing, and hands the method their paths or buffers. The method returns the
//! reconstructed image of the effect's layer with its own time split into preprocess and
//! reconstruct.

use std::path::Path;

use crate::error::Error;
use crate::image::Image;

/// The effect a comparison measures: it fixes the image layer and the sample kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// Indirect illumination: light reflected after at least one more bounce.
    Indirect,
    /// Glossy reflections: the indirect layer of a scene with glossy materials.
    Glossy,
    /// Ambient occlusion: the fraction of cosine-weighted rays unoccluded within a radius.
    Ao,
    /// Depth of field: the full image through an open lens, motion disabled.
    Dof,
    /// Motion blur: the full image over the shutter, the lens closed.
    Motion,
    /// Depth of field and motion blur together.
    DofMotion,
    /// Area-light soft shadows: direct illumination only (emission plus one bounce).
    SoftShadow,
}

impl Effect {
    pub const ALL: [Effect; 7] = [
        Effect::Indirect,
        Effect::Glossy,
        Effect::Ao,
        Effect::Dof,
        Effect::Motion,
        Effect::DofMotion,
        Effect::SoftShadow,
    ];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Effect::Indirect => "indirect",
            Effect::Glossy => "glossy",
            Effect::Ao => "ao",
            Effect::Dof => "dof",
            Effect::Motion => "motion",
            Effect::DofMotion => "dof-motion",
            Effect::SoftShadow => "soft-shadow",
        }
    }

    pub fn from_name(name: &str) -> Option<Effect> {
        Effect::ALL.into_iter().find(|e| e.name() == name)
    }

    /// The sample kind whose per-pixel average estimates this effect's image.
    pub fn sample_kind(self) -> sampleio::SampleKind {
        match self {
            Effect::Indirect | Effect::Glossy => sampleio::SampleKind::Indirect,
            Effect::Ao => sampleio::SampleKind::Ao,
            Effect::Dof | Effect::Motion | Effect::DofMotion | Effect::SoftShadow => sampleio::SampleKind::LensTime,
        }
    }
}

/// What a method reads; the harness produces it with the tracer and times it as `trace_s`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Input {
    /// A sample file of the effect's sample kind (`Effect::sample_kind`).
    Samples,
    /// The path-traced image of the effect with per-pixel albedo and normal (box pixel filter).
    Image,
    /// Guide buffers of one guide ray per pixel centre with `spp` indirect estimates at its hit
    /// (the guided image filter's input; effects `indirect` and `glossy` only).
    Guide,
}

/// One guide ray per pixel through its centre: the geometry it hits, the reflectance there and
/// the noisy outgoing indirect light estimated at that very point with `spp` paths.
#[derive(Clone, Debug)]
pub struct GuideInput {
    pub guide: crate::guide::GuideBuffers,
    pub albedo: Image,
    /// Mean of `spp` estimates of the light the guide hit reflects after at least one more
    /// bounce (the indirect layer at the pixel centre).
    pub indirect: Image,
    /// Emitted plus directly reflected light at the guide hit (the environment for a miss).
    pub direct: Image,
    /// `spp − 1` additional eye rays per pixel (none at 1 spp).
    pub eye_rays: crate::guide::EyeRays,
}

/// A path-traced image: the effect's layer and the first-hit albedo and world-space normal.
#[derive(Clone, Debug)]
pub struct ImageInput {
    pub color: Image,
    pub albedo: Image,
    pub normal: Image,
}

/// The traced input of a run: the one its method asks for (`Method::input`).
#[derive(Clone, Copy, Debug)]
pub enum InputData<'a> {
    /// `Input::Samples`: a sample file of the effect's sample kind (`Effect::sample_kind`).
    Samples {
        samples: &'a Path,
        /// With `Effect::SoftShadow`: the `light` samples of the same seed and spp (sample i
        /// belongs to camera sample i of `samples`, which then carries the fields `albedo`,
        /// `normal` and `radiance_without_light`).
        light_samples: Option<&'a Path>,
    },
    /// `Input::Image`: the path-traced image.
    Image(&'a ImageInput),
    /// `Input::Guide`: the guide buffers.
    Guide(&'a GuideInput),
}

impl InputData<'_> {
    /// Which input this is.
    pub fn kind(&self) -> Input {
        match self {
            InputData::Samples { .. } => Input::Samples,
            InputData::Image(_) => Input::Image,
            InputData::Guide(_) => Input::Guide,
        }
    }
}

/// Everything a method run receives.
#[derive(Clone, Debug)]
pub struct Inputs<'a> {
    pub effect: Effect,
    pub width: u32,
    pub height: u32,
    /// Input samples per pixel.
    pub spp: u32,
    /// The traced input the method asked for.
    pub data: InputData<'a>,
    /// Ambient-occlusion radius in scene units (`Effect::Ao`).
    pub ao_radius: f32,
    /// Seed of the method's own random numbers (reconstruction locations and rays): the seed
    /// the inputs were traced with, so that one seed fixes every bit of a comparison.
    pub seed: u32,
    /// Worker threads; 0 = all cores.
    pub threads: usize,
}

impl<'a> Inputs<'a> {
    /// The sample file, for `method` (named in the error when the input is another).
    pub fn samples(&self, method: &str) -> Result<&'a Path, Error> {
        match self.data {
            InputData::Samples { samples, .. } => Ok(samples),
            _ => Err(Error::missing_input("samples", format!("{method} needs a sample file"))),
        }
    }

    /// Soft shadows' light samples beside the sample file, for `method`.
    pub fn light_samples(&self, method: &str) -> Result<&'a Path, Error> {
        match self.data {
            InputData::Samples { light_samples: Some(light_samples), .. } => Ok(light_samples),
            _ => Err(Error::missing_input(
                "light samples",
                format!("{method} soft shadows need the light samples of the same seed and spp"),
            )),
        }
    }

    /// The path-traced image, for `method`.
    pub fn image(&self, method: &str) -> Result<&'a ImageInput, Error> {
        match self.data {
            InputData::Image(image) => Ok(image),
            _ => Err(Error::missing_input("image", format!("{method} needs a path-traced image"))),
        }
    }

    /// The guide buffers, for `method`.
    pub fn guide(&self, method: &str) -> Result<&'a GuideInput, Error> {
        match self.data {
            InputData::Guide(guide) => Ok(guide),
            _ => Err(Error::missing_input("guide buffers", format!("{method} needs guide buffers"))),
        }
    }
}

/// A note of [`Output::notes`] that starts with this is a warning: the method dropped or
/// replaced input it could not use, so the image may be wrong (darker, black). Commands print
/// warnings to standard error; [`warning`] builds one.
pub const WARNING: &str = "warning: ";

/// The note `text` as a warning ([`WARNING`]).
pub fn warning(text: impl std::fmt::Display) -> String {
    format!("{WARNING}{text}")
}

/// What a method run returns.
#[derive(Clone, Debug)]
pub struct Output {
    pub image: Image,
    /// Seconds spent before reconstruction proper (reading, sorting, hierarchies, k-NN).
    pub preprocess_s: f64,
    /// Seconds spent reconstructing.
    pub recon_s: f64,
    /// Peak resident memory of an external process the method ran in (MiB), if any; the
    /// harness measures its own process itself.
    pub external_peak_rss_mb: Option<f64>,
    /// Anything the report should say about this run.
    pub notes: Vec<String>,
    /// The run's statistics as named numbers (`results.json`'s `stats`; empty for methods
    /// without any), beside the notes that say them in words.
    pub stats: Stats,
}

/// Named numbers a method reports about a run (counts, fractions, seconds), in name order.
pub type Stats = std::collections::BTreeMap<String, f64>;

/// Why a method could not run. The harness skips a method that is `Unavailable` and fails on
/// the others.
#[derive(Debug)]
pub enum MethodError {
    /// The method does not handle this effect (or this kind of input file).
    Unsupported(String),
    /// A dependency (e.g. a Python package) is missing; the harness skips the method.
    Unavailable(Error),
    /// The input was bad or the method failed.
    Failed(Error),
}

impl std::fmt::Display for MethodError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MethodError::Unsupported(m) => write!(f, "unsupported: {m}"),
            MethodError::Unavailable(m) => write!(f, "unavailable: {m}"),
            MethodError::Failed(m) => write!(f, "{m}"),
        }
    }
}

impl std::error::Error for MethodError {}

impl From<Error> for MethodError {
    fn from(error: Error) -> Self {
        MethodError::Failed(error)
    }
}

impl From<sampleio::SampleError> for MethodError {
    fn from(error: sampleio::SampleError) -> Self {
        MethodError::Failed(Error::Samples(error))
    }
}

/// A reconstruction or baseline `lfr compare` can run. What it is called, the effects it
/// handles, its options and description are data in `crate::registry`, which builds it.
pub trait Method: Send + Sync + std::fmt::Debug {
    /// What it reads.
    fn input(&self) -> Input;
    /// Reconstruction rays (or locations) per pixel to sweep by default for `effect`; `[0]` for
    /// methods without such a parameter.
    fn default_recon_rays(&self, _effect: Effect) -> Vec<u32> {
        vec![0]
    }
    /// Whether it reads soft shadows' light samples (`InputData::Samples`) for `effect` (their tracing counts in its time).
    fn reads_light_samples(&self, _effect: Effect) -> bool {
        false
    }
    /// With `Input::Samples`: every field it reads of the sample files for `effect` (of the
    /// light samples too, where it reads them), as the declarations it checks files against
    /// (`crate::needs`); `None` when it does not say, and then reads any field. `lfr compare`
    /// traces its input with these fields only, so that it pays for what it reads.
    fn sample_needs(&self, _effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        None
    }
    /// Whether this instance, with its options, reconstructs `effect`, beyond the method's
    /// declared effects (`crate::registry`): an option may narrow them. Checked before any run.
    fn handles(&self, _effect: Effect) -> bool {
        true
    }
    /// Whether it blurs glossy reflections (a screen-space filter of the indirect light, ILFR's
    /// grain filter): on a scene with glossy materials its indirect image would lose them, so
    /// `lfr compare` skips it there with a notice.
    fn blurs_glossy_reflections(&self) -> bool {
        false
    }
    /// `Err(reason)` when a dependency is missing; checked once before any run.
    fn available(&self) -> Result<(), Error> {
        Ok(())
    }
    /// Reconstructs the effect's image from `inputs`.
    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effect_names_round_trip() {
        for effect in Effect::ALL {
            assert_eq!(Effect::from_name(effect.name()), Some(effect));
        }
        assert_eq!(Effect::from_name("bokeh"), None);
    }
}
