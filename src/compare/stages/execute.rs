//! Stage 4, execute: every run, timed and measured as it finishes (`measure::Scorer`). Path
//! tracing's runs are the ladder's traces; each registry method runs at every input spp and
//! each of its reconstruction-ray counts on the inputs traced for it, its `trace_s` the time of
//! those traces; a method that finds a dependency missing when it runs is skipped whole. The
//! `probes` methods (`probes_method`) run once each, their `--repeats` frames timed inside.
//! Then the repetitions: up to `--repeats` passes over every trace and method run in the same
//! order (`timing::repetitions`: long runs fewer times), each checked to give the same image
//! as the first; each run's times are its median repetition's.

use anyhow::{bail, Context, Result};
use recon::method::{Input, Inputs, MethodError, Output};
use recon::registry::Registered;
use tracer::Accel;

use super::super::effect::Tracing;
use super::super::results::Skipped;
use super::super::{memory, probes_method, timing};
use super::inputs::{input_selections, needs, TraceKey, Traced};
use super::measure::{rays_label, Measured, Scorer};
use super::plan::Plan;

/// A timed unit that the repetitions run again.
enum Job {
    /// A trace, and the ladder run it is (none for the methods' inputs).
    Trace(TraceKey, Option<usize>),
    /// A method's run (index into the plan's methods) and its measured run.
    Method { method: usize, spp: u32, recon_rays: u32, measured: usize },
}

/// The runs of a comparison, measured, with their final timings.
pub struct Executed {
    /// Path tracing's runs, then each method's in the order named, then the `probes` methods'.
    pub measured: Vec<Measured>,
    /// The methods left out: a missing dependency found before or during their runs.
    pub skipped: Vec<Skipped>,
    /// Whether each run's peak memory is its own (`memory::reset_peak`).
    pub peak_rss_per_run: bool,
}

/// The comparison's progress bar over every timed step (hidden with --quiet).
pub fn progress_bar(show: bool) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(0);
    let style = indicatif::ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} runs, ETA {eta}: {msg}",
    )
    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
    bar.set_style(style);
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// How many timed steps the first pass takes (the progress bar's length before the
/// repetitions): the ladder, the inputs' traces, the methods' runs.
pub fn first_pass_steps(plan: &Plan) -> u64 {
    let traces_per_spp =
        input_selections(&plan.methods, plan.effect).len() + usize::from(needs(&plan.methods, Input::Guide));
    let method_runs: usize = plan.methods.iter().map(|m| plan.rays_of(m).len() * plan.spp_of(m).len()).sum();
    (plan.ladder.len() + plan.input_spp().len() * traces_per_spp + method_runs + plan.probe_methods.len()) as u64
}

fn not_deterministic(pass: u32) -> String {
    format!(
        "{}repetition {} gave a different image from the first with the same seed (not deterministic)",
        recon::method::WARNING,
        pass + 1
    )
}

/// One run of `method` on `inputs`, the bar showing `message` and, with `expected_s` (a
/// previous run's), about how long is left.
fn run_method(
    bar: &indicatif::ProgressBar,
    message: &str,
    expected_s: Option<f64>,
    method: &Registered,
    inputs: &Inputs,
    recon_rays: u32,
) -> Result<Output, MethodError> {
    crate::common::with_expected_progress(bar, message, expected_s, || method.run(inputs, recon_rays))
}

/// Runs everything (module doc) on `traced`, measuring each image with `scorer`.
pub fn execute(
    plan: &Plan,
    tracing: &Tracing,
    accel: &Accel,
    mut traced: Traced,
    scorer: &Scorer,
    bar: &indicatif::ProgressBar,
) -> Result<Executed> {
    let mut skipped = plan.skipped.clone();
    // Path tracing's runs, ladder rung i at `measured[i]`.
    let mut measured: Vec<Measured> = Vec::new();
    for rung in std::mem::take(&mut traced.rungs) {
        let times = (rung.seconds, 0.0, 0.0);
        measured.push(scorer.measure("pt", rung.spp, 0, times, rung.peak_rss_mb, rung.image, Default::default())?);
    }
    let mut jobs: Vec<Job> = Vec::new();
    for &key in &traced.order {
        let rung = match key {
            TraceKey::Pt(spp) => plan.ladder.iter().position(|&s| s == spp),
            _ => None,
        };
        jobs.push(Job::Trace(key, rung));
    }

    'methods: for (index, method) in plan.methods.iter().enumerate() {
        // The previous run of this method: how long the next one may take when it reports no
        // stage of its own (OIDN).
        let mut previous_s: Option<f64> = None;
        for &spp in plan.spp_of(method) {
            let (inputs, key, light_trace) = traced.for_method(plan, method, spp);
            for recon_rays in plan.rays_of(method) {
                let message = format!("{}, {spp} spp{}", method.name(), rays_label(recon_rays));
                bar.set_message(message.clone());
                memory::reset_peak();
                let output = match run_method(bar, &message, previous_s, method, &inputs, recon_rays) {
                    Ok(output) => output,
                    Err(MethodError::Unavailable(reason)) => {
                        bar.suspend(|| eprintln!("skipping {}: {reason}", method.name()));
                        skipped.push(Skipped { method: method.name().to_string(), reason: reason.to_string() });
                        measured.retain(|m| m.run.method != method.name());
                        jobs.retain(|job| !matches!(job, Job::Method { method, .. } if *method == index));
                        continue 'methods;
                    }
                    Err(error) => bail!("{} at {spp} spp: {error}", method.name()),
                };
                let peak = match (memory::peak_rss_mb(), output.external_peak_rss_mb) {
                    (Some(a), Some(b)) => Some(a.max(b)),
                    (a, b) => a.or(b),
                };
                let trace_s = traced.trace_times(key, light_trace)[0];
                previous_s = Some(output.preprocess_s + output.recon_s);
                let parts = [output.preprocess_s, output.recon_s];
                let run = scorer.measure(
                    method.name(),
                    spp,
                    recon_rays,
                    (trace_s, output.preprocess_s, output.recon_s),
                    peak,
                    output.image,
                    (output.notes, output.stats),
                )?;
                let stats = vec![run.run.stats.clone()];
                measured.push(Measured { trace: key, light_trace, parts: vec![parts], stats, ..run });
                jobs.push(Job::Method { method: index, spp, recon_rays, measured: measured.len() - 1 });
                bar.inc(1);
            }
        }
    }

    let precomputed = run_probes(plan, accel, scorer, bar)?;
    repeat(plan, tracing, &mut traced, &jobs, &mut measured, bar)?;
    bar.finish_and_clear();
    for m in &mut measured {
        m.settle_timings(&traced.trace_times(m.trace, m.light_trace));
    }
    measured.extend(precomputed);
    if plan.args.repeats > 1 {
        eprintln!(
            "  timings: the lines above show each run's first timing; the verdicts and reports use the median of up to \
             {} repetitions per run (results.json `timings`)",
            plan.args.repeats
        );
    }
    let peak_rss_per_run = traced.peak_rss_per_run;
    traced.finish()?;
    Ok(Executed { measured, skipped, peak_rss_per_run })
}

/// The methods with a precompute, each run once: its `--repeats` frames are timed inside.
fn run_probes(plan: &Plan, accel: &Accel, scorer: &Scorer, bar: &indicatif::ProgressBar) -> Result<Vec<Measured>> {
    let mut precomputed = Vec::new();
    for method in &plan.probe_methods {
        bar.set_message(method.name.clone());
        memory::reset_peak();
        let out = probes_method::run(
            method,
            &plan.scene,
            accel,
            (plan.width, plan.height),
            plan.max_bounces,
            plan.seed,
            plan.threads(),
            &plan.cache,
            plan.args.repeats,
            bar,
        )
        .with_context(|| method.name.clone())?;
        let peak = memory::peak_rss_mb();
        let mut m = scorer.measure(
            &method.name,
            0,
            method.pixel_samples,
            (0.0, out.preprocess_s, out.recon_s),
            peak,
            out.image,
            (out.notes, out.stats),
        )?;
        m.run.precompute_from_cache = Some(out.precompute_from_cache);
        m.run.timings = out.timings.iter().map(|t| t + out.preprocess_s).collect();
        m.run.timing_spread = timing::relative_spread(&m.run.timings);
        precomputed.push(m);
        bar.inc(1);
    }
    Ok(precomputed)
}

/// The repetitions, alternating over every job (module `timing`).
fn repeat(
    plan: &Plan,
    tracing: &Tracing,
    traced: &mut Traced,
    jobs: &[Job],
    measured: &mut [Measured],
    bar: &indicatif::ProgressBar,
) -> Result<()> {
    let first_total = |job: &Job| -> f64 {
        match job {
            Job::Trace(key, _) => traced.times[key][0],
            Job::Method { measured: m, .. } => measured[*m].run.total_s,
        }
    };
    let repeats: Vec<u32> = jobs.iter().map(|job| timing::repetitions(first_total(job), plan.args.repeats)).collect();
    bar.set_length(bar.position() + repeats.iter().map(|&r| u64::from(r - 1)).sum::<u64>());
    for pass in 1..plan.args.repeats {
        for (job, _) in jobs.iter().zip(&repeats).filter(|(_, &r)| pass < r) {
            match *job {
                Job::Trace(key, rung) => {
                    let message = format!("repetition {}: {}", pass + 1, key.label());
                    bar.set_message(message.clone());
                    let image =
                        crate::common::with_stage_progress(bar, &message, || traced.retrace(tracing, plan.seed, key))?;
                    if let (Some(image), Some(rung)) = (image, rung) {
                        if image != measured[rung].image {
                            measured[rung].run.notes.push(not_deterministic(pass));
                        }
                    }
                }
                Job::Method { method, spp, recon_rays, measured: m } => {
                    let method = &plan.methods[method];
                    let message =
                        format!("repetition {}: {}, {spp} spp{}", pass + 1, method.name(), rays_label(recon_rays));
                    bar.set_message(message.clone());
                    let (inputs, _, _) = traced.for_method(plan, method, spp);
                    let first = measured[m].parts.first().map(|[pre, recon]| pre + recon);
                    let output = run_method(bar, &message, first, method, &inputs, recon_rays)
                        .map_err(|e| anyhow::anyhow!("{} at {spp} spp: {e}", method.name()))?;
                    if output.image != measured[m].image {
                        measured[m].run.notes.push(not_deterministic(pass));
                    }
                    measured[m].parts.push([output.preprocess_s, output.recon_s]);
                    measured[m].stats.push(output.stats);
                }
            }
            bar.inc(1);
        }
    }
    Ok(())
}
