//! Each image measured as its run finishes (used by `execute`, gathered by `score`): the
//! [`Scorer`] measures an image (PSNR, relMSE and SSIM through the tone map,
//! `recon::metrics`), writes it with its error map (`images`), and notes what limits the
//! measure (the reference's own error, non-finite pixels); [`Measured`] keeps it with its run's
//! timings until the verdicts.

use std::path::Path;

use anyhow::{Context, Result};
use recon::metrics::{evaluate, ToneMap};
use recon::Image;

use super::super::effect::image_layer;
use super::super::results::Run;
use super::super::{images, timing};
use super::inputs::TraceKey;
use super::plan::Plan;
use super::reference::Measure;

/// A measured image before its verdicts.
pub struct Measured {
    pub run: Run,
    pub image: Image,
    /// The trace whose timings are this run's trace times.
    pub trace: TraceKey,
    /// A second trace whose timings add to them (soft shadows' light samples, for the methods
    /// that read them).
    pub light_trace: Option<TraceKey>,
    /// (preprocess, reconstruct) seconds of each repetition; empty for path tracing.
    pub parts: Vec<[f64; 2]>,
    /// The method's statistics of each repetition (they hold stage times): the run reports the
    /// median repetition's, so that its stage times belong to its `recon_s`.
    pub stats: Vec<recon::method::Stats>,
}

impl Measured {
    /// Sets the run's times to its median repetition and records every repetition
    /// (`timing`); repetition i pairs `trace_times[i]` (or the last) with `parts[i]`.
    pub fn settle_timings(&mut self, trace_times: &[f64]) {
        let count = trace_times.len().max(self.parts.len()).max(1);
        let repetition = |i: usize| -> (f64, f64, f64) {
            let trace = trace_times.get(i.min(trace_times.len().saturating_sub(1))).copied().unwrap_or(0.0);
            let [pre, recon] = self.parts.get(i.min(self.parts.len().saturating_sub(1))).copied().unwrap_or([0.0; 2]);
            (trace, pre, recon)
        };
        let totals: Vec<f64> = (0..count).map(repetition).map(|(t, p, r)| t + p + r).collect();
        let median = timing::median_index(&totals).unwrap_or(0);
        let (trace, pre, recon) = repetition(median);
        if let Some(stats) = self.stats.get(median.min(self.stats.len().saturating_sub(1))) {
            self.run.stats = stats.clone();
        }
        let run = &mut self.run;
        (run.trace_s, run.preprocess_s, run.recon_s, run.total_s) = (trace, pre, recon, trace + pre + recon);
        run.timing_spread = timing::relative_spread(&totals);
        run.timings = totals;
    }
}

/// Scores images against the reference and writes them.
pub struct Scorer<'a> {
    pub dir: &'a Path,
    pub reference: &'a Image,
    pub tone: ToneMap,
    /// The EXR layer of the images (`effect::image_layer`).
    pub layer: &'static str,
    /// The reference's own PSNR (its check's estimate, else the halves'), if known.
    pub reference_psnr_db: Option<f64>,
    /// Lines are printed around it.
    pub bar: &'a indicatif::ProgressBar,
}

/// How close to the reference's own PSNR a run may score before its note says the reference's
/// error is at least half of what is measured: the measured MSE is the run's plus the
/// reference's, so a run as good as the reference reads 10·log10 2 ≈ 3 dB below it.
const REFERENCE_LIMITED_DB: f64 = 3.010_299_956_639_812; // 10·log10 2

/// The note of a run whose PSNR is within [`REFERENCE_LIMITED_DB`] of the reference's own.
fn reference_limited_note(psnr_db: f64, reference_psnr_db: f64) -> Option<String> {
    (psnr_db.is_finite() && psnr_db >= reference_psnr_db - REFERENCE_LIMITED_DB).then(|| {
        format!(
            "{}limited by the reference: {psnr_db:.2} dB is within {REFERENCE_LIMITED_DB:.1} dB of the reference's own \
             {reference_psnr_db:.2} dB, so the reference's error is at least half of the error measured; raise \
             --reference-spp to tell this run apart from better ones",
            recon::method::WARNING
        )
    })
}

/// " × N rays" for a run with reconstruction rays.
pub fn rays_label(recon_rays: u32) -> String {
    if recon_rays > 0 {
        format!(" × {recon_rays} rays")
    } else {
        String::new()
    }
}

impl<'a> Scorer<'a> {
    /// Measures against `measure`'s reference into `plan.dir`'s images.
    pub fn new(plan: &'a Plan, measure: &'a Measure, bar: &'a indicatif::ProgressBar) -> Scorer<'a> {
        Scorer {
            dir: plan.dir,
            reference: &measure.reference.image,
            tone: measure.tone,
            layer: image_layer(plan.effect).name,
            reference_psnr_db: measure.estimated_psnr_db(),
            bar,
        }
    }

    /// Measures `image`, the run of `method` at `input_spp` and `recon_rays` taking `times`
    /// (trace, preprocess, reconstruct seconds), writes it and its error map, and prints its
    /// line.
    #[allow(clippy::too_many_arguments)]
    pub fn measure(
        &self,
        method: &str,
        input_spp: u32,
        recon_rays: u32,
        times: (f64, f64, f64),
        peak_rss_mb: Option<f64>,
        image: Image,
        (notes, stats): (Vec<String>, recon::method::Stats),
    ) -> Result<Measured> {
        self.reference.check_same_size(&image).with_context(|| {
            format!("{method} at {input_spp} spp returned an image of the wrong size for this comparison")
        })?;
        let metrics = evaluate(self.reference, &image, &self.tone)?;
        // Method names with options (`gif:radius=8`) become `gif_radius-8` in file names.
        let file_name = method.replace(':', "_").replace('=', "-");
        let stem = if recon_rays > 0 {
            format!("{file_name}-{input_spp}spp-{recon_rays}rays")
        } else {
            format!("{file_name}-{input_spp}spp")
        };
        let images = self.dir.join("images");
        images::write_image(&images, &stem, self.layer, &image, &self.tone)?;
        images::write_error_map(&images, &format!("{stem}-error"), self.reference, &image, &self.tone)?;
        let (trace_s, preprocess_s, recon_s) = times;
        let mut notes = notes;
        if let Some(reference_psnr_db) = self.reference_psnr_db {
            notes.extend(reference_limited_note(metrics.psnr_db, reference_psnr_db));
        }
        if metrics.nonfinite_pixels > 0 {
            notes.push(format!(
                "INVALID: {} pixels are NaN or infinite; they are scored as worst-case errors and the run is left out of the verdicts",
                metrics.nonfinite_pixels
            ));
        }
        self.bar.suspend(|| {
            eprintln!(
                "  {method:>10} {input_spp:>5} spp{}: {:>8.3} s, {:6.2} dB, relMSE {:.3e}, SSIM {:.4}{}",
                rays_label(recon_rays),
                trace_s + preprocess_s + recon_s,
                metrics.psnr_db,
                metrics.rel_mse,
                metrics.ssim,
                if metrics.nonfinite_pixels > 0 { " (INVALID: non-finite pixels)" } else { "" }
            )
        });
        Ok(Measured {
            run: Run {
                method: method.to_string(),
                input_spp,
                recon_rays,
                trace_s,
                preprocess_s,
                recon_s,
                total_s: trace_s + preprocess_s + recon_s,
                timings: vec![trace_s + preprocess_s + recon_s],
                timing_spread: 0.0,
                psnr_db: metrics.psnr_db,
                rel_mse: metrics.rel_mse,
                ssim: metrics.ssim,
                flip: None,
                peak_rss_mb,
                nonfinite_pixels: metrics.nonfinite_pixels,
                valid: metrics.nonfinite_pixels == 0,
                equal_time_psnr_gain_db: None,
                speedup: None,
                speedup_range: None,
                verdict_extrapolated: false,
                speedup_over_oidn: None,
                speedup_over_oidn_range: None,
                oidn_curve_position: None,
                precompute_from_cache: None,
                per_frame_speedup: None,
                break_even_frames: None,
                image: format!("images/{stem}.exr"),
                preview: format!("images/{stem}.png"),
                error_map: format!("images/{stem}-error.png"),
                notes,
                stats,
            },
            image,
            trace: TraceKey::Pt(input_spp),
            light_trace: None,
            parts: Vec::new(),
            stats: Vec::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(method: &str, spp: u32, total_s: f64, psnr_db: f64) -> Run {
        Run::example(method, spp, total_s, psnr_db)
    }

    fn scorer<'a>(dir: &'a Path, reference: &'a Image, bar: &'a indicatif::ProgressBar) -> Scorer<'a> {
        Scorer { dir, reference, tone: ToneMap::auto(reference), layer: "beauty", reference_psnr_db: None, bar }
    }

    #[test]
    fn nonfinite_outputs_are_counted_flagged_and_never_score_well() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("images")).unwrap();
        let pixels = (0..16).map(|i| [0.1 + 0.05 * i as f32; 3]).collect();
        let reference = Image::from_pixels(4, 4, pixels);
        let bar = indicatif::ProgressBar::hidden();
        let mut image = reference.clone();
        image.set(1, 1, [f32::NAN, 0.0, 0.0]);
        image.set(2, 1, [f32::INFINITY; 3]);
        let measured = scorer(dir.path(), &reference, &bar)
            .measure("nan-maker", 4, 0, (1.0, 0.5, 0.25), Some(10.0), image, Default::default())
            .unwrap();
        let run = &measured.run;
        assert_eq!(run.nonfinite_pixels, 2);
        assert!(!run.valid);
        assert!(run.psnr_db.is_finite() && run.psnr_db < 40.0, "{}", run.psnr_db);
        assert!(run.notes.iter().any(|n| n.contains("INVALID")));
        assert_eq!(run.total_s, 1.75);
        assert!(dir.path().join(&run.error_map).is_file() && dir.path().join(&run.image).is_file());
    }

    #[test]
    fn a_wrong_size_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("images")).unwrap();
        let reference = Image::new(4, 4);
        let bar = indicatif::ProgressBar::hidden();
        let error = scorer(dir.path(), &reference, &bar)
            .measure("shrinker", 1, 0, (0.0, 0.0, 0.0), None, Image::new(3, 4), Default::default())
            .err()
            .unwrap();
        let message = format!("{error:#}");
        assert!(message.contains("shrinker") && message.contains("expected 4x4, found 3x4"), "{message}");
        assert_eq!(std::fs::read_dir(dir.path().join("images")).unwrap().count(), 0, "nothing written");
    }

    /// A run is flagged once the reference's error is at least half of what is measured:
    /// within 3 dB of the reference's own PSNR (the PSNR of MSE_run + MSE_reference with equal
    /// parts is 10·log10 2 below the reference's), and never for a non-finite score.
    #[test]
    fn runs_near_the_reference_s_own_psnr_are_flagged() {
        assert!(reference_limited_note(30.0, 36.5).is_none());
        assert!(reference_limited_note(33.4, 36.5).is_none());
        let note = reference_limited_note(33.6, 36.5).expect("within 3 dB");
        assert!(note.contains("33.60 dB") && note.contains("36.50 dB") && note.contains("--reference-spp"), "{note}");
        assert!(note.starts_with(recon::method::WARNING), "shown in the open: {note}");
        assert!(reference_limited_note(40.0, 36.5).is_some());
        assert!(reference_limited_note(f64::NAN, 36.5).is_none());
        // Equal MSEs read 10·log10 2 below the reference: flagged.
        assert!(reference_limited_note(36.5 - 10.0 * 2f64.log10(), 36.5).is_some());
    }

    #[test]
    fn settled_timings_pair_trace_and_reconstruction_repetitions() {
        let stats = |gather_s: f64| recon::method::Stats::from([("gather_s".to_string(), gather_s)]);
        let mut measured = Measured {
            run: run("ilfr", 4, 0.0, 30.0),
            image: Image::new(2, 2),
            trace: TraceKey::Samples(4, 0),
            light_trace: None,
            parts: vec![[0.1, 1.0], [0.1, 3.0], [0.1, 2.0]],
            stats: vec![stats(0.9), stats(2.9), stats(1.9)],
        };
        // Two trace repetitions: the third reconstruction pairs with the last trace time.
        measured.settle_timings(&[0.5, 0.7]);
        assert_eq!(measured.run.timings, vec![1.6, 3.8, 2.8]);
        assert_eq!((measured.run.trace_s, measured.run.recon_s, measured.run.total_s), (0.7, 2.0, 2.8));
        assert!((measured.run.timing_spread - 2.2 / 2.8).abs() < 1e-12);
        // The statistics (stage times) are the median repetition's too.
        assert_eq!(measured.run.stats["gather_s"], 1.9);
    }
}
