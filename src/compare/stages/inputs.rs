//! Stage 3, the inputs: everything traced for the runs, each trace timed as the `trace_s` of
//! the runs that read it. The path-tracing ladder (1, 2, 4, ... `--pt-max-spp` spp plus every
//! input spp): its images are path tracing's runs, and those at an input spp with their albedo
//! and normal are the `Image` input. Then, once per input spp, the sample files of each field
//! selection the methods read (each method pays for the fields it reads: `Method::sample_needs`)
//! in `OUT/inputs` (removed at the end unless `--keep-samples`), with soft shadows' light
//! samples beside them, and the guide buffers when a method reads them. The repetitions trace
//! them again ([`Traced::retrace`]) for their timings.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::{Context, Result};
use recon::method::{GuideInput, ImageInput, Input, InputData, Inputs};
use recon::registry::Registered;
use recon::{Effect, Image};
use tracer::samples::FieldSelection;

use super::super::effect::{Dumped, Tracing};
use super::super::memory;
use super::plan::Plan;

/// A trace that the runs share: the ladder's image at some spp (also the `Image` input), the
/// input samples or the guide buffers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum TraceKey {
    Pt(u32),
    /// The input samples at an spp with the fields of one selection (an index into
    /// [`Traced::selections`]).
    Samples(u32, usize),
    /// The light samples that soft shadows' samples pair with (traced with `Samples`).
    LightSamples(u32, usize),
    Guide(u32),
}

impl TraceKey {
    pub fn label(self) -> String {
        match self {
            TraceKey::Pt(spp) => format!("path tracing, {spp} spp"),
            TraceKey::Samples(spp, selection) => format!("input samples, {spp} spp, fields {}", selection + 1),
            TraceKey::LightSamples(spp, selection) => format!("light samples, {spp} spp, fields {}", selection + 1),
            TraceKey::Guide(spp) => format!("guide buffers, {spp} spp"),
        }
    }
}

/// One rung of the path-tracing ladder: path tracing's run at `spp`.
pub struct Rung {
    pub spp: u32,
    pub image: Image,
    pub seconds: f64,
    /// The process's peak memory during the trace (MiB).
    pub peak_rss_mb: Option<f64>,
}

/// What was traced, and the times of every trace, one per repetition.
pub struct Traced {
    /// The ladder, cheapest first; path tracing's runs.
    pub rungs: Vec<Rung>,
    /// The distinct field selections of the methods that read samples ([`input_selections`]).
    pub selections: Vec<FieldSelection>,
    /// The trace keys in the order they were traced (the repetitions keep it).
    pub order: Vec<TraceKey>,
    /// Each trace's timings, one per repetition.
    pub times: BTreeMap<TraceKey, Vec<f64>>,
    /// Whether each run's peak memory is its own (`memory::reset_peak`).
    pub peak_rss_per_run: bool,
    frames: BTreeMap<u32, ImageInput>,
    samples: BTreeMap<(u32, usize), Dumped>,
    guides: BTreeMap<u32, GuideInput>,
    /// `OUT/inputs`, the sample files' folder.
    dir: PathBuf,
    keep_samples: bool,
    /// An interrupt removes the input samples too, unless they are to be kept.
    _interrupt_registration: Option<sampleio::interrupt::Registered>,
}

/// The fields `method` reads of its sample files for `effect` (all when it does not say).
pub fn input_fields(method: &Registered, effect: Effect) -> FieldSelection {
    match method.sample_needs(effect) {
        Some(needs) => FieldSelection::reading(&needs),
        None => FieldSelection::All,
    }
}

/// The distinct field selections of the methods that read samples, in the methods' order: each
/// is traced once per input spp, and each method pays for the one it reads.
pub fn input_selections(methods: &[Registered], effect: Effect) -> Vec<FieldSelection> {
    let mut selections: Vec<FieldSelection> = Vec::new();
    for method in methods.iter().filter(|m| m.input() == Input::Samples) {
        let fields = input_fields(method, effect);
        if !selections.contains(&fields) {
            selections.push(fields);
        }
    }
    selections
}

/// Whether any of `methods` reads `input`.
pub fn needs(methods: &[Registered], input: Input) -> bool {
    methods.iter().any(|m| m.input() == input)
}

impl Traced {
    /// Traces the ladder and the methods' inputs (module doc), one progress step each.
    pub fn trace(plan: &Plan, tracing: &Tracing, bar: &indicatif::ProgressBar) -> Result<Traced> {
        let peak_rss_per_run = memory::reset_peak();
        let seed = plan.seed;
        let mut order = Vec::new();
        let mut times = BTreeMap::new();
        let mut rungs = Vec::new();
        let mut frames = BTreeMap::new();
        // The frame readers run on every rung (`Plan::spp_of`), so every rung's frame is kept.
        let keep_frames = needs(&plan.methods, Input::Image);
        for &spp in &plan.ladder {
            let message = TraceKey::Pt(spp).label();
            bar.set_message(message.clone());
            memory::reset_peak();
            let traced = crate::common::with_stage_progress(bar, &message, || tracing.trace(spp, seed, false))?;
            let peak_rss_mb = memory::peak_rss_mb();
            rungs.push(Rung { spp, image: traced.frame.color.clone(), seconds: traced.seconds, peak_rss_mb });
            times.insert(TraceKey::Pt(spp), vec![traced.seconds]);
            order.push(TraceKey::Pt(spp));
            if keep_frames {
                frames.insert(spp, traced.frame);
            }
            bar.inc(1);
        }

        let dir = plan.dir.join("inputs");
        let keep_samples = plan.args.keep_samples;
        let registration = (!keep_samples).then(|| sampleio::interrupt::remove_on_interrupt(&dir));
        let selections = input_selections(&plan.methods, plan.effect);
        let mut samples = BTreeMap::new();
        let mut guides = BTreeMap::new();
        for &spp in plan.input_spp() {
            for (selection, fields) in selections.iter().enumerate() {
                let message = format!("tracing the input samples, {spp} spp");
                bar.set_message(message.clone());
                std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
                let dumped = crate::common::with_stage_progress(bar, &message, || {
                    tracing.dump(spp, seed, &dir, fields, selection)
                })?;
                times.insert(TraceKey::Samples(spp, selection), vec![dumped.samples_s]);
                if let Some(seconds) = dumped.light_samples_s {
                    times.insert(TraceKey::LightSamples(spp, selection), vec![seconds]);
                }
                samples.insert((spp, selection), dumped);
                order.push(TraceKey::Samples(spp, selection));
                bar.inc(1);
            }
            if needs(&plan.methods, Input::Guide) {
                let message = format!("tracing the guide buffers, {spp} spp");
                bar.set_message(message.clone());
                let (guide, seconds) = crate::common::with_stage_progress(bar, &message, || tracing.guide(spp, seed))?;
                guides.insert(spp, guide);
                times.insert(TraceKey::Guide(spp), vec![seconds]);
                order.push(TraceKey::Guide(spp));
                bar.inc(1);
            }
        }
        Ok(Traced {
            rungs,
            selections,
            order,
            times,
            peak_rss_per_run,
            frames,
            samples,
            guides,
            dir,
            keep_samples,
            _interrupt_registration: registration,
        })
    }

    /// What `method` reads at `spp`, the trace whose timings are its trace times and, for a
    /// method that reads soft shadows' light samples, the light samples' trace.
    pub fn for_method(&self, plan: &Plan, method: &Registered, spp: u32) -> (Inputs<'_>, TraceKey, Option<TraceKey>) {
        let effect = plan.effect;
        let (data, key) = match method.input() {
            Input::Samples => {
                let fields = input_fields(method, effect);
                let selection =
                    self.selections.iter().position(|s| *s == fields).expect("every reader's selection is traced");
                let dumped = &self.samples[&(spp, selection)];
                let data =
                    InputData::Samples { samples: &dumped.samples, light_samples: dumped.light_samples.as_deref() };
                (data, TraceKey::Samples(spp, selection))
            }
            Input::Image => (InputData::Image(&self.frames[&spp]), TraceKey::Pt(spp)),
            Input::Guide => (InputData::Guide(&self.guides[&spp]), TraceKey::Guide(spp)),
        };
        let light = match key {
            TraceKey::Samples(spp, selection) if method.reads_light_samples(effect) => {
                Some(TraceKey::LightSamples(spp, selection)).filter(|light| self.times.contains_key(light))
            }
            _ => None,
        };
        let inputs = Inputs {
            effect,
            width: plan.width,
            height: plan.height,
            spp,
            data,
            ao_radius: plan.ao_radius,
            seed: plan.seed,
            threads: plan.threads(),
        };
        (inputs, key, light)
    }

    /// Traces `key` again for a repetition and records its time (soft shadows' light samples
    /// come with their samples); returns the image of a ladder rung, to check it is the same.
    pub fn retrace(&mut self, tracing: &Tracing, seed: u32, key: TraceKey) -> Result<Option<Image>> {
        let (seconds, image) = match key {
            TraceKey::Pt(spp) => {
                let traced = tracing.trace(spp, seed, false)?;
                (traced.seconds, Some(traced.frame.color))
            }
            TraceKey::Samples(spp, selection) => {
                let dumped = tracing.dump(spp, seed, &self.dir, &self.selections[selection], selection)?;
                if let Some(seconds) = dumped.light_samples_s {
                    let light = TraceKey::LightSamples(spp, selection);
                    self.times.get_mut(&light).expect("traced in the first pass").push(seconds);
                }
                (dumped.samples_s, None)
            }
            TraceKey::LightSamples(..) => unreachable!("traced with the samples"),
            TraceKey::Guide(spp) => (tracing.guide(spp, seed)?.1, None),
        };
        self.times.get_mut(&key).expect("traced in the first pass").push(seconds);
        Ok(image)
    }

    /// The trace times of a run that reads `key` and, when given, `light` too: repetition by
    /// repetition (both are traced in the same repetitions), the sum.
    pub fn trace_times(&self, key: TraceKey, light: Option<TraceKey>) -> Vec<f64> {
        trace_times(&self.times, key, light)
    }

    /// Removes the input samples unless `--keep-samples`.
    pub fn finish(self) -> Result<()> {
        if !self.keep_samples && self.dir.exists() {
            std::fs::remove_dir_all(&self.dir).with_context(|| format!("removing {}", self.dir.display()))?;
        }
        Ok(())
    }
}

fn trace_times(times: &BTreeMap<TraceKey, Vec<f64>>, key: TraceKey, light: Option<TraceKey>) -> Vec<f64> {
    let mut total = times[&key].clone();
    if let Some(extra) = light.and_then(|light| times.get(&light)) {
        for (time, extra) in total.iter_mut().zip(extra) {
            *time += extra;
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Soft shadows' light samples count only for the runs that read them, repetition by
    /// repetition.
    #[test]
    fn light_sample_times_add_to_the_runs_that_read_them() {
        let times = BTreeMap::from([
            (TraceKey::Samples(4, 0), vec![1.0, 2.0, 3.0]),
            (TraceKey::LightSamples(4, 0), vec![0.25, 0.5, 0.75]),
        ]);
        assert_eq!(trace_times(&times, TraceKey::Samples(4, 0), None), vec![1.0, 2.0, 3.0]);
        let with_light = trace_times(&times, TraceKey::Samples(4, 0), Some(TraceKey::LightSamples(4, 0)));
        assert_eq!(with_light, vec![1.25, 2.5, 3.75]);
    }
}
