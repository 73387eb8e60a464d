//! Stage 6, write: the comparison's record into `--out`, each file written whole or not at all
//! (`tracer::output::write_atomically`): the error-against-time plot (`report::write_plot`),
//! `report.md` (`report`), `report.html` (`html`) and `results.json` (`results`), last, so that
//! a `results.json` always sits beside the images and reports it describes. The images were
//! written as they were measured (`measure::Scorer`). Prints the verdicts.

use std::path::Path;

use anyhow::{Context, Result};
use tracer::output::write_atomically;

use super::super::results::Results;
use super::super::{html, report};

/// Writes `bytes` to `path` through a temporary file; the error names the file.
fn write_whole(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |tmp| std::fs::write(tmp, bytes).map_err(|e| e.to_string()))
        .with_context(|| format!("writing {}", path.display()))
}

/// Writes `results`' plot, reports and record into `dir` and prints the verdicts.
pub fn write(dir: &Path, results: &Results) -> Result<()> {
    report::write_plot(dir, results)?;
    let report_path = dir.join("report.md");
    write_whole(&report_path, report::markdown(results).as_bytes())?;
    let html_path = dir.join("report.html");
    write_whole(&html_path, html::html(results).as_bytes())?;
    let json_path = dir.join("results.json");
    crate::common::write_json(&json_path, results)?;
    // The verdicts use the runs' median timings (the lines printed during the runs show each
    // run's first timing, and say so).
    println!("{}", results.headline);
    for verdict in &results.verdicts {
        println!("{}", verdict.summary);
    }
    for verdict in &results.verdicts_against_oidn {
        println!("{}", verdict.summary);
    }
    println!(
        "wrote {}, {} and {} in {:.1} s",
        report_path.display(),
        html_path.display(),
        json_path.display(),
        results.total_seconds
    );
    Ok(())
}
