//! Stage 2, the reference: the image every run is measured against, with the tone map of the
//! measures and the reference's own error. It is read from `--reference` (`external`, checked
//! before anything is written), or from the cache, or traced and cached (`reference`); it fixes
//! the tone map (`--exposure`, else the reference's 99th-percentile luminance maps to 1), is
//! written as `images/reference.exr`, and its own PSNR is estimated from its two halves and,
//! unless `--reference-check off`, from a sparse set of pixels traced with more samples
//! (`reference_check`).

use anyhow::Result;
use recon::metrics::ToneMap;

use super::super::effect::{image_layer, Tracing};
use super::super::reference::Reference;
use super::super::reference_check::{self, Check, CheckEstimate};
use super::super::{external, images, reference, results};
use super::plan::Plan;

/// Where the reference comes from: a reference rendered elsewhere, read and checked, or the
/// cache (or a trace).
pub struct Source(Option<Reference>);

impl Source {
    /// Reads and checks `--reference`'s files, if given, before anything is written or traced.
    pub fn open(plan: &Plan, tracing: &Tracing) -> Result<Source> {
        let scene_sha256 = crate::fingerprint::scene_sha256(&plan.scene_text, &plan.scene);
        let external = plan
            .args
            .reference
            .as_ref()
            .map(|files| external::external_reference(tracing, &scene_sha256, plan.seed, files))
            .transpose()?;
        Ok(Source(external))
    }
}

/// The reference as the runs are measured against it.
pub struct Measure {
    pub reference: Reference,
    pub tone: ToneMap,
    /// `"auto"` or `"given"` (`--exposure`).
    pub exposure_source: &'static str,
    /// PSNR(half A, half B) + 6.02 dB, when there are halves.
    pub halves_psnr_db: Option<f64>,
    /// The check and its estimate, unless `--reference-check off`.
    pub checked: Option<(Check, CheckEstimate)>,
}

impl Measure {
    /// The reference's own PSNR: the check's estimate, else the halves'.
    pub fn estimated_psnr_db(&self) -> Option<f64> {
        self.checked.as_ref().map(|(_, estimate)| estimate.psnr_db).or(self.halves_psnr_db)
    }
}

/// The reference stage (module doc): into `plan.dir`, which is ready for the comparison's files.
pub fn settle(plan: &Plan, tracing: &Tracing, source: Source) -> Result<Measure> {
    let args = plan.args;
    let (width, height, effect) = (plan.width, plan.height, plan.effect);
    let reference = match source.0 {
        Some(reference) => {
            eprintln!(
                "compare: {} --effect {} at {width}x{height}; external reference",
                plan.scene.source.display(),
                effect.name()
            );
            reference
        }
        None => {
            eprintln!(
                "compare: {} --effect {} at {width}x{height}; reference {} spp (cache {})",
                plan.scene.source.display(),
                effect.name(),
                args.reference_spp,
                plan.cache.display()
            );
            reference::reference(
                tracing,
                &plan.scene_text,
                args.reference_spp,
                plan.seed,
                &plan.cache,
                !args.no_cache,
                plan.progress,
            )?
        }
    };
    eprintln!(
        "  reference: {} spp, {:.1} s{}",
        reference.spp,
        reference.seconds,
        if reference.from_cache {
            " (cached)"
        } else if args.reference.is_some() {
            " (external)"
        } else {
            ""
        }
    );
    let (tone, exposure_source) = match plan.tone_given {
        Some(tone) => (tone, "given"),
        None => (ToneMap::auto(&reference.image), "auto"),
    };
    images::write_image(&plan.dir.join("images"), "reference", image_layer(effect).name, &reference.image, &tone)?;
    let halves_psnr_db = match &reference.halves {
        Some((a, b)) => Some(reference::estimated_psnr_db(a, b, &tone)?),
        None => None,
    };
    let checked = match args.reference_check.0 {
        Some(factor) => {
            let check = reference_check::check(
                tracing,
                &plan.scene_text,
                reference_check::CheckOf { spp: reference.spp, seeds: reference.seeds, factor },
                plan.seed,
                &plan.cache,
                !args.no_cache,
                plan.progress,
            )?;
            let estimate = check.estimate(&reference.image, reference.spp, &tone)?;
            eprintln!(
                "  reference check: {} at {} spp, {:.1} s{}; the reference's own PSNR ≈ {:.1} dB ({:.1}–{:.1}){}",
                results::pixels_text(check.pixels.len()),
                check.spp,
                check.seconds,
                if check.from_cache { " (cached)" } else { "" },
                estimate.psnr_db,
                estimate.interval_db[0],
                estimate.interval_db[1],
                match halves_psnr_db {
                    Some(db) => format!(" ({db:.1} dB from its two halves)"),
                    None => String::new(),
                }
            );
            Some((check, estimate))
        }
        None => {
            eprintln!(
                "  reference check: off; {}",
                match halves_psnr_db {
                    Some(db) => format!("the reference's own PSNR ≈ {db:.1} dB from its two halves (an upper bound)"),
                    None => "the reference's own PSNR is unknown (one image, no halves)".to_string(),
                }
            );
            None
        }
    };
    Ok(Measure { reference, tone, exposure_source, halves_psnr_db, checked })
}
