//! `report.md` and the error-against-time plot: what a reader who never saw the project needs
//! to judge a comparison — the verdict first, then the set-up, the curve, the table and the
//! pictures, and what each number means.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;

use super::images::ERROR_MAP_MAX;
use super::plot::{self, Curve};
use super::results::{Results, Run};

/// One curve per method and reconstruction-ray count, PT first; invalid runs left out.
pub fn curves(results: &Results) -> Vec<Curve> {
    let mut keys: Vec<(String, u32)> = Vec::new();
    for run in &results.runs {
        let key = (run.method.clone(), run.recon_rays);
        if !keys.contains(&key) {
            keys.push(key);
        }
    }
    keys.sort_by_key(|(method, _)| method != "pt");
    keys.into_iter()
        .map(|(method, rays)| {
            let mut points: Vec<(f64, f64)> = results
                .runs
                .iter()
                .filter(|r| r.method == method && r.recon_rays == rays && r.valid)
                .map(|r| (r.total_s, r.psnr_db))
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            let label = match (method.as_str(), rays) {
                ("pt", _) => "path tracing".to_string(),
                (_, 0) => method.clone(),
                (_, rays) => format!("{method} ({rays} rays)"),
            };
            Curve { label, points }
        })
        .collect()
}

/// Writes `error-vs-time.png` and `.svg` and the error-map colour bar.
pub fn write_plot(dir: &Path, results: &Results) -> Result<()> {
    let title = format!("{}: {} at {}x{}", scene_name(&results.scene), results.effect, results.width, results.height);
    plot::error_vs_time(&curves(results), &title, &dir.join("error-vs-time.png"), &dir.join("error-vs-time.svg"))?;
    plot::colour_bar(ERROR_MAP_MAX, "RMS error of display values", &dir.join("images/error-scale.png"))
}

fn scene_name(source: &str) -> &str {
    Path::new(source).file_name().and_then(|n| n.to_str()).unwrap_or(source)
}

fn opt(value: Option<f64>, digits: usize) -> String {
    match value {
        Some(v) if v.is_finite() => format!("{v:.digits$}"),
        _ => "–".into(),
    }
}

/// What the report says of the reference's own PSNR: measured by its check, else estimated
/// from its halves, else unknown.
fn own_psnr_text(reference: &super::results::ReferenceInfo) -> String {
    let halves = |db: f64| format!("{db:.1} dB from its two halves, which miss rare paths alike");
    match (&reference.check, reference.estimated_psnr_db, reference.halves_psnr_db) {
        (Some(check), Some(db), halves_db) => format!(
            "its own PSNR is about {db:.1} dB ({:.1}–{:.1}; measured at {} traced at {} spp{})",
            check.psnr_interval_db[0],
            check.psnr_interval_db[1],
            super::results::pixels_text(check.pixels),
            check.spp,
            halves_db.map(|db| format!("; {}", halves(db))).unwrap_or_default()
        ),
        (_, _, Some(db)) => format!("its own PSNR is at most about {} (no check: `--reference-check off`)", halves(db)),
        _ => "its own PSNR is unknown (one image, no halves, `--reference-check off`)".to_string(),
    }
}

/// Whether a run's note is something the reader must see: a method's warning or an invalid run.
fn is_warning(note: &str) -> bool {
    note.starts_with(recon::method::WARNING) || note.starts_with("INVALID")
}

/// The run's speedup over OIDN, or where it lies outside OIDN's range.
fn oidn_cell(run: &Run) -> String {
    match (run.speedup_over_oidn, run.oidn_curve_position) {
        (Some(speedup), _) => format!(
            "{speedup:.2}{}",
            run.speedup_over_oidn_range.map(|[lo, hi]| format!(" ({lo:.2}–{hi:.2})")).unwrap_or_default()
        ),
        (None, Some("above")) => "above its range".into(),
        (None, Some("below")) => "below its range".into(),
        _ => "–".into(),
    }
}

fn run_label(run: &Run) -> String {
    let rays = if run.recon_rays > 0 { format!(" × {} rays", run.recon_rays) } else { String::new() };
    format!("{} {} spp{rays}", if run.method == "pt" { "path tracing" } else { &run.method }, run.input_spp)
}

/// The report's Markdown.
pub fn markdown(results: &Results) -> String {
    let mut md = String::new();
    let r = results;
    let _ = writeln!(md, "# {} — {} ({}×{})\n", scene_name(&r.scene), r.effect, r.width, r.height);

    let _ = writeln!(md, "## Verdict\n");
    let _ = writeln!(md, "**{}**\n", r.headline);
    if r.verdicts.is_empty() {
        let _ = writeln!(md, "Only path tracing ran; there is no method to judge.\n");
    }
    for verdict in &r.verdicts {
        // The summary starts with the method's name; set it in bold.
        let rest = verdict.summary.strip_prefix(verdict.method.as_str()).unwrap_or(&verdict.summary);
        let _ = writeln!(md, "- **{}**{}.", verdict.method, rest.trim_end_matches('.'));
        if let Some(gain) = verdict.best_equal_time_psnr_gain_db {
            let _ = writeln!(
                md,
                "  Best equal-time gain over path tracing: {gain:+.2} dB{}.",
                if gain < 0.0 { " (worse than tracing more samples in the same time)" } else { "" }
            );
        }
    }
    for skipped in &r.skipped {
        let _ = writeln!(md, "- **{}** was skipped: {}", skipped.method, skipped.reason);
    }
    let _ = writeln!(
        md,
        "\nSpeedup = path-tracing time to reach the method's PSNR (interpolated on the path-tracing curve in \
         log time) / the method's total time, trace included. Above 1, the method beats tracing more samples.\n"
    );
    if !r.verdicts_against_oidn.is_empty() {
        let _ = writeln!(md, "### Against the denoiser (OIDN on path tracing)\n");
        for verdict in &r.verdicts_against_oidn {
            let _ = writeln!(md, "- {}.", verdict.summary.trim_end_matches('.'));
        }
        let _ = writeln!(
            md,
            "\nSpeedup over OIDN = OIDN's time to reach the method's PSNR (interpolated on OIDN's own curve in log time, \
             never extended beyond its runs: outside them the run is \"below\" or \"above OIDN's range\") / the \
             method's total time.\n"
        );
    }

    let _ = writeln!(md, "## Set-up\n");
    let _ = writeln!(md, "| | |\n|---|---|");
    let _ = writeln!(md, "| scene | `{}` |", r.scene);
    let _ = writeln!(md, "| effect | `{}` |", r.effect);
    let _ = writeln!(md, "| resolution | {}×{} |", r.width, r.height);
    let _ =
        writeln!(md, "| seed | {} (reference seeds {} and {}) |", r.seed, r.reference.seeds[0], r.reference.seeds[1]);
    let _ = writeln!(md, "| path length | {} bounces |", r.max_bounces);
    if let Some(radius) = r.ao_radius {
        let _ = writeln!(md, "| AO radius | {radius} scene units |");
    }
    let _ = writeln!(md, "| threads | {} |", r.threads);
    let _ = writeln!(
        md,
        "| reference | {} spp in {:.1} s{}; {} |",
        r.reference.spp,
        r.reference.seconds,
        if r.reference.from_cache {
            ", from the cache".to_string()
        } else if r.reference.external.is_empty() {
            String::new()
        } else {
            format!(", rendered elsewhere ({})", r.reference.external.join(", "))
        },
        own_psnr_text(&r.reference)
    );
    let _ = writeln!(
        md,
        "| tone map for PSNR / SSIM | exposure {:.4} ({}), gamma {}, clamped to [0, 1], not quantised |",
        r.tone_map.exposure,
        if r.tone_map.exposure_source == "auto" { "the reference's 99th-percentile luminance → 1" } else { "given" },
        r.tone_map.gamma
    );
    let _ = writeln!(md, "| total run time | {:.1} s |\n", r.total_seconds);

    let _ = writeln!(md, "## Error against time\n");
    let _ = writeln!(md, "![PSNR against time](error-vs-time.png)\n");
    let _ = writeln!(md, "(Vector version: [error-vs-time.svg](error-vs-time.svg).)\n");

    let _ = writeln!(md, "## Every run\n");
    let _ = writeln!(
        md,
        "| run | trace s | preprocess s | reconstruct s | total s | timed | PSNR dB | rel. MSE | SSIM | FLIP | peak MiB | equal-time gain dB | speedup (range) | vs OIDN |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for run in &r.runs {
        let _ = writeln!(
            md,
            "| {}{} | {:.3} | {:.3} | {:.3} | {:.3} | {}× ±{:.0} % | {:.2} | {:.3e} | {:.4} | {} | {} | {} | {}{}{} | {} |",
            run_label(run),
            if run.valid { "" } else { " **INVALID**" },
            run.trace_s,
            run.preprocess_s,
            run.recon_s,
            run.total_s,
            run.timings.len(),
            50.0 * run.timing_spread,
            run.psnr_db,
            run.rel_mse,
            run.ssim,
            opt(run.flip, 4),
            opt(run.peak_rss_mb, 0),
            opt(run.equal_time_psnr_gain_db, 2),
            opt(run.speedup, 2),
            run.speedup_range.map(|[lo, hi]| format!(" ({lo:.2}–{hi:.2})")).unwrap_or_default(),
            if run.verdict_extrapolated { "*" } else { "" },
            oidn_cell(run),
        );
    }
    let _ = writeln!(
        md,
        "\n\\* the path-tracing curve was extended beyond its measured range at 10 dB per decade of time (MSE ∝ 1/time).\n"
    );
    // What a reader must know (warnings, invalid runs) in the open; the methods' internals
    // (stage times, counts) collapsed, and as numbers in results.json's `stats`.
    let notes: Vec<(String, &String)> =
        r.runs.iter().flat_map(|run| run.notes.iter().map(move |n| (run_label(run), n))).collect();
    let (warnings, internals): (Vec<_>, Vec<_>) = notes.into_iter().partition(|(_, note)| is_warning(note));
    if !warnings.is_empty() {
        let _ = writeln!(md, "Warnings:\n");
        for (label, note) in warnings {
            let _ = writeln!(md, "- {label}: {note}");
        }
        let _ = writeln!(md);
    }
    if !internals.is_empty() {
        let _ = writeln!(md, "<details><summary>Internals of each run (the methods' own notes)</summary>\n");
        for (label, note) in internals {
            let _ = writeln!(md, "- {label}: {note}");
        }
        let _ = writeln!(md, "\n</details>\n");
    }

    let _ = writeln!(md, "## Images\n");
    let _ = writeln!(
        md,
        "Each result beside its error map: per-pixel RMS difference of the tone-mapped values from the reference, \
         0 to {ERROR_MAP_MAX} on the scale below (magenta: NaN or infinite).\n\n![error scale](images/error-scale.png)\n"
    );
    let _ = writeln!(md, "| reference |\n|---|\n| ![reference](images/reference.png) |\n");
    let _ = writeln!(md, "| run | image | error |\n|---|---|---|");
    for run in &r.runs {
        let _ = writeln!(
            md,
            "| {} ({:.2} dB) | ![]({}) | ![]({}) |",
            run_label(run),
            run.psnr_db,
            run.preview,
            run.error_map
        );
    }

    let _ = writeln!(md, "\n## What the numbers mean\n");
    let _ = writeln!(
        md,
        "- **PSNR**: 10·log10(1/MSE) of the tone-mapped images (exposure, clamp to [0, 1], gamma {}), as the temporal \
         light field paper measured it (gamma, clamp to 0–255, before quantisation); 100 dB when identical (an all-black \
         reference and result included).\n\
         - **rel. MSE**: mean of (x − r)² / (r² + 0.01) over pixels and channels of the linear HDR images.\n\
         - **SSIM**: Wang et al. 2004 on the tone-mapped images, 11×11 Gaussian window (σ 1.5), mean over channels.\n\
         - **FLIP**: mean HDR-FLIP (Andersson et al. 2021), lower is better; `–` when `flip-evaluator` is not installed.\n\
         - **times**: trace = tracing the method's inputs (for sample-based methods, writing the sample file included); \
         preprocess and reconstruct as the method reports them; total = their sum. Path tracing's time is its render. \
         Each run was timed several times, alternating over the runs (\"timed\": repetitions and ± half the range over \
         the median); the times shown are the median repetition's, and the speedup's range pairs the fastest with the \
         slowest repetitions. A verdict whose range holds 1 says \"no clear difference\". The repetitions all ran in \
         this one process; the same command run again can measure a ratio a little differently (on a shared two-core \
         machine the same ratio moved by 5-15 % between runs), so read a verdict within about a tenth of 1 as a tie.\n\
         - **INVALID**: the output had NaN or infinite pixels; they are scored as worst-case errors and the run is \
         excluded from the verdicts.\n\
         \nFull definitions: `docs/compare.md` in the lfr repository.",
        r.tone_map.gamma
    );
    md
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compare::results::{ReferenceCheckInfo, ReferenceInfo, ToneMapInfo};

    fn run(method: &str, notes: &[&str]) -> Run {
        let mut run = Run::example(method, 4, 1.0, 30.0);
        run.notes = notes.iter().map(|n| n.to_string()).collect();
        run
    }

    #[test]
    fn warnings_stay_in_the_open_and_internals_are_collapsed() {
        let results = Results {
            schema: crate::compare::results::SCHEMA,
            lfr_version: "0",
            scene: "s.toml".into(),
            effect: "indirect".into(),
            width: 4,
            height: 4,
            seed: 1,
            threads: 1,
            max_bounces: 2,
            ao_radius: None,
            tone_map: ToneMapInfo { exposure: 1.0, gamma: 2.2, exposure_source: "auto" },
            reference: ReferenceInfo {
                spp: 8,
                seconds: 1.0,
                seeds: [2, 3],
                cache_key: String::new(),
                from_cache: false,
                external: Vec::new(),
                estimated_psnr_db: Some(31.5),
                halves_psnr_db: None,
                check: Some(ReferenceCheckInfo {
                    psnr_interval_db: [30.9, 32.2],
                    pixels: 225,
                    spp: 32,
                    seed: 4,
                    seconds: 0.5,
                    from_cache: false,
                }),
                image: String::new(),
            },
            flip_available: false,
            peak_rss_per_run: true,
            between_runs_noise: 0.1,
            headline: "Winner by PSNR at each time budget: x.".into(),
            budgets: Vec::new(),
            runs: vec![run("pt", &[]), run("ilfr", &["time: read 0.1 s", "warning: 3 samples dropped"])],
            skipped: Vec::new(),
            verdicts: Vec::new(),
            verdicts_against_oidn: Vec::new(),
            total_seconds: 1.0,
        };
        let md = markdown(&results);
        let details = md.find("<details>").expect("a collapsed section");
        let warning = md.find("warning: 3 samples dropped").expect("the warning");
        let internal = md.find("time: read 0.1 s").expect("the internal note");
        assert!(warning < details && details < internal, "{md}");
        assert!(
            md.contains("its own PSNR is about 31.5 dB (30.9–32.2; measured at 225 pixels traced at 32 spp)"),
            "{md}"
        );
        let mut one = results.clone();
        one.reference.check.as_mut().unwrap().pixels = 1;
        assert!(markdown(&one).contains("measured at 1 pixel traced"));
        // `--reference-check off`: the halves' estimate, called an upper bound; none for one image.
        let mut off = results.clone();
        (off.reference.check, off.reference.halves_psnr_db, off.reference.estimated_psnr_db) =
            (None, Some(33.0), Some(33.0));
        assert!(markdown(&off).contains("its own PSNR is at most about 33.0 dB from its two halves"));
        (off.reference.halves_psnr_db, off.reference.estimated_psnr_db) = (None, None);
        assert!(markdown(&off).contains("its own PSNR is unknown"));
    }
}
