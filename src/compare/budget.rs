//! The headline: which method wins at each time budget, across every run (path tracing and the
//! denoiser included). At a budget of T seconds the winner is the valid run with the highest
//! PSNR among those that took at most T (median total time, trace included); HDR-FLIP's winner
//! (the lowest FLIP) is given beside it, and the sentence says when the two disagree. The
//! budgets are the runs' own total times, so each budget is a moment where the answer can
//! change; consecutive budgets with the same winners are merged into one span.
//!
//! A winner whose PSNR lies within 10·log10 2 ≈ 3 dB of the reference's own PSNR is measured
//! against a reference whose error is at least half of the error measured: the headline says
//! the ranking there is limited by the reference (raise `--reference-spp`).

use super::results::{Entry, Run, Span};

/// How close to the reference's own PSNR a winner may be before the headline says the
/// reference limits the ranking (10·log10 2: the reference's error is then at least half).
pub const REFERENCE_LIMITED_DB: f64 = 3.010_299_956_639_812;

impl Entry {
    fn of(run: &Run) -> Entry {
        Entry {
            method: run.method.clone(),
            input_spp: run.input_spp,
            recon_rays: run.recon_rays,
            total_s: run.total_s,
            psnr_db: run.psnr_db,
            flip: run.flip,
        }
    }

    /// "ilfr+oidn (4 spp × 16 rays, 33.20 dB, FLIP 0.081)".
    pub fn label(&self) -> String {
        let name = if self.method == "pt" { "path tracing" } else { &self.method };
        let rays = if self.recon_rays > 0 { format!(" × {} rays", self.recon_rays) } else { String::new() };
        let flip = self.flip.map(|f| format!(", FLIP {f:.3}")).unwrap_or_default();
        format!("{name} ({} spp{rays}, {:.2} dB{flip})", self.input_spp, self.psnr_db)
    }
}

fn same_run(a: &Entry, b: &Entry) -> bool {
    (a.method.as_str(), a.input_spp, a.recon_rays) == (b.method.as_str(), b.input_spp, b.recon_rays)
}

/// The winners at every budget, merged into spans (module doc); `reference_psnr_db` is the
/// reference's own PSNR, if known.
pub fn winners(runs: &[Run], reference_psnr_db: Option<f64>) -> Vec<Span> {
    let valid: Vec<&Run> = runs.iter().filter(|r| r.valid && r.total_s.is_finite() && r.psnr_db.is_finite()).collect();
    let mut budgets: Vec<f64> = valid.iter().map(|r| r.total_s).collect();
    budgets.sort_by(f64::total_cmp);
    budgets.dedup();
    let mut spans: Vec<Span> = Vec::new();
    for budget in budgets {
        let within: Vec<&&Run> = valid.iter().filter(|r| r.total_s <= budget).collect();
        let Some(best) =
            within.iter().max_by(|a, b| a.psnr_db.total_cmp(&b.psnr_db).then(b.total_s.total_cmp(&a.total_s)))
        else {
            continue;
        };
        let by_flip = within
            .iter()
            .filter(|r| r.flip.is_some_and(f64::is_finite))
            .min_by(|a, b| a.flip.unwrap_or(f64::INFINITY).total_cmp(&b.flip.unwrap_or(f64::INFINITY)))
            .map(|r| Entry::of(r));
        let by_psnr = Entry::of(best);
        let reference_limited = reference_psnr_db.is_some_and(|own| by_psnr.psnr_db >= own - REFERENCE_LIMITED_DB);
        match spans.last_mut() {
            Some(last)
                if same_run(&last.by_psnr, &by_psnr)
                    && match (&last.by_flip, &by_flip) {
                        (Some(a), Some(b)) => same_run(a, b),
                        (None, None) => true,
                        _ => false,
                    } =>
            {
                continue
            }
            Some(last) => last.to_s = Some(budget),
            None => {}
        }
        spans.push(Span { from_s: budget, to_s: None, by_psnr, by_flip, reference_limited });
    }
    spans
}

/// The headline sentence: the winner per span, FLIP's where it disagrees, and the reference's
/// limit where it applies.
pub fn headline(spans: &[Span], reference_psnr_db: Option<f64>) -> String {
    if spans.is_empty() {
        return "No valid run: no winner at any time budget.".to_string();
    }
    let mut parts = Vec::new();
    for span in spans {
        let range = match span.to_s {
            Some(to) => format!("from {:.3} s to {:.3} s", span.from_s, to),
            None if spans.len() == 1 => format!("at every budget from {:.3} s", span.from_s),
            None => format!("from {:.3} s on", span.from_s),
        };
        let mut part = format!("{range}: {}", span.by_psnr.label());
        if let Some(flip) = span.by_flip.as_ref().filter(|f| !same_run(f, &span.by_psnr)) {
            part.push_str(&format!(" — HDR-FLIP disagrees and prefers {}", flip.label()));
        }
        if span.reference_limited {
            part.push_str(" (within 3 dB of the reference's own PSNR: limited by the reference)");
        }
        parts.push(part);
    }
    let mut text = format!("Winner by PSNR at each time budget (trace included): {}.", parts.join("; "));
    if let Some(own) = reference_psnr_db.filter(|_| spans.iter().any(|s| s.reference_limited)) {
        text.push_str(&format!(
            " The reference's own PSNR is about {own:.1} dB: above {:.1} dB path tracing's curve flattens against it and \
             rankings and speedups there are limited by the reference; raise --reference-spp to separate them.",
            own - REFERENCE_LIMITED_DB
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(method: &str, spp: u32, total_s: f64, psnr_db: f64, flip: Option<f64>) -> Run {
        let mut run = Run::example(method, spp, total_s, psnr_db);
        run.flip = flip;
        run
    }

    #[test]
    fn the_winner_at_each_budget_is_the_best_psnr_within_it() {
        let runs = vec![
            run("pt", 1, 0.05, 20.0, Some(0.30)),
            run("oidn", 1, 0.1, 30.0, Some(0.10)),
            run("ilfr+oidn", 4, 0.4, 33.0, Some(0.12)),
            run("pt", 64, 3.2, 32.0, Some(0.09)),
            run("pt", 256, 12.8, 36.0, Some(0.05)),
            {
                let mut broken = run("broken", 1, 0.01, 99.0, Some(0.0));
                broken.valid = false;
                broken
            },
        ];
        let spans = winners(&runs, None);
        let summary: Vec<(f64, Option<f64>, &str, Option<&str>)> = spans
            .iter()
            .map(|s| (s.from_s, s.to_s, s.by_psnr.method.as_str(), s.by_flip.as_ref().map(|f| f.method.as_str())))
            .collect();
        assert_eq!(
            summary,
            [
                (0.05, Some(0.1), "pt", Some("pt")),
                (0.1, Some(0.4), "oidn", Some("oidn")),
                (0.4, Some(3.2), "ilfr+oidn", Some("oidn")),
                (3.2, Some(12.8), "ilfr+oidn", Some("pt")),
                (12.8, None, "pt", Some("pt")),
            ]
        );
        let text = headline(&spans, None);
        assert!(text.contains("HDR-FLIP disagrees and prefers oidn (1 spp, 30.00 dB, FLIP 0.100)"), "{text}");
        assert!(text.contains("from 12.800 s on: path tracing (256 spp, 36.00 dB, FLIP 0.050)"), "{text}");
        assert!(!text.contains("broken"));
    }

    #[test]
    fn a_winner_near_the_references_own_psnr_is_said_to_be_limited_by_it() {
        let runs = vec![run("pt", 1, 0.1, 30.0, None), run("pt", 256, 10.0, 38.5, None)];
        let spans = winners(&runs, Some(40.0));
        assert!(!spans[0].reference_limited && spans[1].reference_limited);
        let text = headline(&spans, Some(40.0));
        assert!(text.contains("limited by the reference") && text.contains("flattens"), "{text}");
        assert!(!headline(&winners(&runs, Some(45.0)), Some(45.0)).contains("limited"));
        assert_eq!(headline(&[], None), "No valid run: no winner at any time budget.");
    }
}
