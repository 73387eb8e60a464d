//! Stage 5, score: every measured image (`measure`) gathered into the record. [`score`] adds
//! HDR-FLIP (one process for every image, when the Python package is there), reads the
//! verdicts off the path-tracing curve (`verdict`), and gathers `results.json`'s record.

use std::time::Instant;

use recon::metrics::ToneMap;
use recon::Image;

use super::super::results::{self, ReferenceCheckInfo, ReferenceInfo, Results, Run, ToneMapInfo};
use super::super::{budget, peer, timing, verdict};
use super::execute::Executed;
use super::measure::Measured;
use super::plan::Plan;
use super::reference::Measure;

/// HDR-FLIP of every image against the reference, at the tone map's exposure, when the Python
/// package is there (one process for all); returns whether it is.
fn add_flip(measured: &mut [Measured], reference: &Image, tone: &ToneMap) -> bool {
    let available = recon::metrics::flip::available();
    if !available {
        return false;
    }
    let scale = |image: &Image| {
        let pixels = image.pixels.iter().map(|p| p.map(|v| v * tone.exposure)).collect();
        Image::from_pixels(image.width, image.height, pixels)
    };
    let scaled: Vec<Image> = measured.iter().map(|m| scale(&m.image)).collect();
    match recon::metrics::flip::hdr_flip_many(&scale(reference), &scaled.iter().collect::<Vec<_>>()) {
        Ok(Some(values)) => {
            for (m, value) in measured.iter_mut().zip(values) {
                m.run.flip = Some(value);
            }
        }
        Ok(None) => {}
        Err(error) => {
            eprintln!("warning: HDR-FLIP failed: {error}");
            for m in measured {
                m.run.notes.push(format!("HDR-FLIP not computed: {error}"));
            }
        }
    }
    available
}

/// The comparison's record: `executed`'s runs with HDR-FLIP and their verdicts against path
/// tracing, and what was compared how; `start` is when the comparison began.
pub fn score(plan: &Plan, measure: &Measure, executed: Executed, start: Instant) -> Results {
    let Executed { mut measured, skipped, peak_rss_per_run } = executed;
    let flip_available = add_flip(&mut measured, &measure.reference.image, &measure.tone);
    let mut runs: Vec<Run> = measured.into_iter().map(|m| m.run).collect();
    let verdicts = verdict::verdicts_against_path_tracing(&mut runs);
    let verdicts_against_oidn = peer::verdicts_against_peer(&mut runs).into_iter().map(Into::into).collect();
    let budgets = budget::winners(&runs, measure.estimated_psnr_db());
    let headline = budget::headline(&budgets, measure.estimated_psnr_db());
    let reference = &measure.reference;
    let args = plan.args;
    Results {
        schema: results::SCHEMA,
        lfr_version: env!("CARGO_PKG_VERSION"),
        scene: plan.scene.source.display().to_string(),
        effect: plan.effect.name().to_string(),
        width: plan.width,
        height: plan.height,
        seed: plan.seed,
        threads: if plan.threads() == 0 { rayon::current_num_threads() } else { plan.threads() },
        max_bounces: plan.max_bounces,
        ao_radius: (plan.effect == recon::Effect::Ao).then_some(plan.ao_radius),
        tone_map: ToneMapInfo {
            exposure: measure.tone.exposure,
            gamma: measure.tone.gamma,
            exposure_source: measure.exposure_source,
        },
        reference: ReferenceInfo {
            spp: reference.spp,
            seconds: reference.seconds,
            seeds: reference.seeds,
            cache_key: reference.key.clone(),
            from_cache: reference.from_cache,
            external: args.reference.iter().flatten().map(|p| p.display().to_string()).collect(),
            estimated_psnr_db: measure.estimated_psnr_db(),
            halves_psnr_db: measure.halves_psnr_db,
            check: measure.checked.as_ref().map(|(check, estimate)| ReferenceCheckInfo {
                psnr_interval_db: estimate.interval_db,
                pixels: check.pixels.len(),
                spp: check.spp,
                seed: check.seed,
                seconds: check.seconds,
                from_cache: check.from_cache,
            }),
            image: "images/reference.exr".into(),
        },
        flip_available,
        peak_rss_per_run,
        between_runs_noise: timing::BETWEEN_RUNS_NOISE,
        headline,
        budgets,
        runs,
        skipped,
        verdicts,
        verdicts_against_oidn,
        total_seconds: start.elapsed().as_secs_f64(),
    }
}
