//! A reconstruction followed by a denoiser, as one method: `A+oidn` (`crate::registry`). A runs
//! on its samples; its image is denoised by OIDN with auxiliary images made from **the same
//! samples** (`crate::auxiliary`: for depth of field and motion blur the lens- and
//! time-integrated first-hit albedo and normal, not a pinhole's). A filter that reads guide
//! buffers (`gif`, `atrous`) gives OIDN the guide's own albedo and normal.
//!
//! Its time is the sum of its stages': `preprocess_s` is A's preprocessing plus the auxiliary
//! images' making, `recon_s` is A's reconstruction plus OIDN's timed call. Its stats are A's
//! beside `pipeline_auxiliary_s` and `pipeline_denoise_s`; its notes are A's then OIDN's.

use std::time::Instant;

use crate::auxiliary::{self, AuxiliaryMode};
use crate::baselines::oidn::Oidn;
use crate::error::Error;
use crate::method::{Effect, Input, Inputs, Method, MethodError, Output};

/// `first`, then OIDN on its image.
#[derive(Debug)]
pub struct Denoised {
    /// The reconstruction (a method that reads samples or guide buffers).
    pub first: Box<dyn Method>,
    /// Its name, for messages.
    pub first_name: String,
    pub denoiser: Oidn,
    /// How the auxiliary images are made from the samples.
    pub auxiliary: AuxiliaryMode,
}

impl Method for Denoised {
    fn input(&self) -> Input {
        self.first.input()
    }

    fn default_recon_rays(&self, effect: Effect) -> Vec<u32> {
        self.first.default_recon_rays(effect)
    }

    fn reads_light_samples(&self, effect: Effect) -> bool {
        self.first.reads_light_samples(effect)
    }

    /// A's fields and the auxiliary fields of the effect's sample kind; `None` (every field)
    /// when A does not say.
    fn sample_needs(&self, effect: Effect) -> Option<Vec<&'static sampleio::Needs>> {
        let mut needs = self.first.sample_needs(effect)?;
        needs.extend(crate::needs::auxiliary(effect.sample_kind()));
        Some(needs)
    }

    fn handles(&self, effect: Effect) -> bool {
        self.first.handles(effect)
    }

    fn blurs_glossy_reflections(&self) -> bool {
        self.first.blurs_glossy_reflections()
    }

    fn available(&self) -> Result<(), Error> {
        self.first.available()?;
        self.denoiser.available()
    }

    fn run(&self, inputs: &Inputs, recon_rays: u32) -> Result<Output, MethodError> {
        let name = format!("{}+oidn", self.first_name);
        // The auxiliaries come from A's own input, checked before A runs: its guide buffers or
        // its samples.
        enum Source<'a> {
            Guide(&'a crate::method::GuideInput),
            Samples(&'a std::path::Path),
        }
        let source = match self.first.input() {
            Input::Guide => Source::Guide(inputs.guide(&name)?),
            _ => Source::Samples(inputs.samples(&name)?),
        };
        let first = self.first.run(inputs, recon_rays)?;
        let started = Instant::now();
        let aux = match source {
            Source::Guide(guide) => auxiliary::from_guide(guide),
            Source::Samples(samples) => auxiliary::from_samples(samples, inputs.effect, self.auxiliary)?,
        };
        let auxiliary_s = started.elapsed().as_secs_f64();
        let denoised = self.denoiser.denoise(&first.image, &aux.albedo, &aux.normal, inputs.effect)?;
        Ok(chain(first, denoised, auxiliary_s))
    }
}

/// The pipeline's output from its stages': times summed (module doc), stats and notes of both.
pub fn chain(first: Output, denoised: Output, auxiliary_s: f64) -> Output {
    let mut stats = first.stats;
    stats.insert("pipeline_auxiliary_s".into(), auxiliary_s);
    stats.insert("pipeline_denoise_s".into(), denoised.preprocess_s + denoised.recon_s);
    let mut notes = first.notes;
    notes.extend(denoised.notes);
    Output {
        image: denoised.image,
        preprocess_s: first.preprocess_s + auxiliary_s + denoised.preprocess_s,
        recon_s: first.recon_s + denoised.recon_s,
        external_peak_rss_mb: denoised.external_peak_rss_mb,
        notes,
        stats,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::method::Stats;

    fn output(value: f32, preprocess_s: f64, recon_s: f64, note: &str, stat: (&str, f64)) -> Output {
        Output {
            image: Image::from_pixels(1, 1, vec![[value; 3]]),
            preprocess_s,
            recon_s,
            external_peak_rss_mb: None,
            notes: vec![note.to_string()],
            stats: Stats::from([(stat.0.to_string(), stat.1)]),
        }
    }

    #[test]
    fn a_pipelines_time_is_the_sum_of_its_stages() {
        let first = output(1.0, 0.25, 1.5, "first", ("gather_s", 1.25));
        let mut denoised = output(2.0, 0.0, 0.125, "oidn", ("unused", 0.0));
        denoised.external_peak_rss_mb = Some(300.0);
        let chained = chain(first, denoised, 0.0625);
        assert_eq!(chained.preprocess_s, 0.25 + 0.0625);
        assert_eq!(chained.recon_s, 1.5 + 0.125);
        assert_eq!(chained.preprocess_s + chained.recon_s, 0.25 + 1.5 + 0.0625 + 0.125);
        assert_eq!(chained.image.get(0, 0), [2.0; 3], "the denoised image");
        assert_eq!(chained.notes, ["first", "oidn"]);
        assert_eq!(chained.stats["gather_s"], 1.25);
        assert_eq!(chained.stats["pipeline_auxiliary_s"], 0.0625);
        assert_eq!(chained.stats["pipeline_denoise_s"], 0.125);
        assert_eq!(chained.external_peak_rss_mb, Some(300.0));
    }
}
