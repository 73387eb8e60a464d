//! `lfr probes precompute`: the precompute (receivers, probes, transport, relight rays) built
//! and written to its cache, or read from it, and its report.

use std::path::{Path, PathBuf};

use anyhow::Result;
use probes::memory::MemoryEstimate;
use probes::pipeline::{Obtained, Stale};
use probes::precompute::Precompute;
use serde::Serialize;

use super::options::PrecomputeOptions;
use super::{check_common, check_memory, obtain, spinner};
use crate::common::{write_json, TraceArgs};
use crate::outputs::OutputPlan;

#[derive(clap::Args)]
pub(super) struct PrecomputeArgs {
    #[command(flatten)]
    trace: TraceArgs,
    #[command(flatten)]
    pre: PrecomputeOptions,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Serialize)]
pub(super) struct PrecomputeReport {
    scene: String,
    cache: String,
    cache_bytes: u64,
    precompute_from_cache: bool,
    precompute_s: f64,
    layout_s: f64,
    transport_s: f64,
    relight_rays_s: f64,
    receivers: usize,
    hidden_receivers: usize,
    probes: usize,
    support_radius: f64,
    dense_transport_bytes: usize,
    dense_transport_bytes_per_receiver: f64,
    /// The near field's lists (0 when it is off): hits, lookup holes among them, bytes.
    near_field_hits: u64,
    near_field_holes: u64,
    near_field_bytes: usize,
    near_field_bytes_per_receiver: f64,
}

pub(super) fn precompute_report(
    scene: &tracer::Scene,
    cache: &Path,
    pre: &Precompute,
    from_cache: bool,
    s: f64,
) -> PrecomputeReport {
    let n = pre.surfels.surfels.len();
    PrecomputeReport {
        scene: scene.source.display().to_string(),
        cache: cache.display().to_string(),
        cache_bytes: std::fs::metadata(cache).map(|m| m.len()).unwrap_or(0),
        precompute_from_cache: from_cache,
        precompute_s: s,
        layout_s: pre.timings.layout_s,
        transport_s: pre.timings.transport_s,
        relight_rays_s: pre.timings.relight_s,
        receivers: n,
        hidden_receivers: pre.hidden,
        probes: pre.probes.len(),
        support_radius: pre.radius,
        dense_transport_bytes: pre.dense_transport_bytes(),
        dense_transport_bytes_per_receiver: pre.dense_transport_bytes() as f64 / n.max(1) as f64,
        near_field_hits: pre.near.as_ref().map_or(0, |f| f.hits),
        near_field_holes: pre.near.as_ref().map_or(0, |f| f.holes),
        near_field_bytes: pre.near_field_bytes(),
        near_field_bytes_per_receiver: pre.near_field_bytes() as f64 / n.max(1) as f64,
    }
}

pub(super) fn print_precompute(r: &PrecomputeReport) {
    if r.precompute_from_cache {
        println!(
            "precompute  from the cache {} ({:.1} MB) in {:.2} s",
            r.cache,
            r.cache_bytes as f64 / 1e6,
            r.precompute_s
        );
    } else {
        println!(
            "precompute  {:.1} s (layout {:.1} s, transport {:.1} s, relight rays {:.1} s); cache {} ({:.1} MB)",
            r.precompute_s,
            r.layout_s,
            r.transport_s,
            r.relight_rays_s,
            r.cache,
            r.cache_bytes as f64 / 1e6
        );
    }
    println!(
        "            {} receivers ({} hidden), {} probes, radius {:.4e}; dense transport {:.1} MB = {:.0} B per receiver",
        r.receivers,
        r.hidden_receivers,
        r.probes,
        r.support_radius,
        r.dense_transport_bytes as f64 / 1e6,
        r.dense_transport_bytes_per_receiver
    );
    if r.near_field_bytes > 0 {
        println!(
            "near field  {} hits ({} lookup holes) in {:.1} MB = {:.0} B per receiver",
            r.near_field_hits,
            r.near_field_holes,
            r.near_field_bytes as f64 / 1e6,
            r.near_field_bytes_per_receiver
        );
    }
}

pub(super) fn run_precompute(args: &PrecomputeArgs) -> Result<()> {
    let mut plan = OutputPlan::new();
    if let Some(json) = &args.json {
        plan.file(json, "--json");
    }
    let (settings, mut plan) = check_common(&args.trace, &args.pre, plan)?;
    let scene = args.trace.load_scene()?;
    plan.scene(&scene).check()?;
    let threads = args.trace.run.thread_count()?;
    check_memory("the probes precompute", &MemoryEstimate::precompute(&settings, threads))?;
    let pool = tracer::render::thread_pool(threads)?;
    let bar = spinner(args.trace.quiet, "precompute");
    let Obtained { precompute: pre, from_cache, seconds: s } =
        obtain(&scene, &settings, &args.pre.cache, Stale::Replace, &pool, &bar)?;
    bar.finish_and_clear();
    let report = precompute_report(&scene, &args.pre.cache, &pre, from_cache, s);
    print_precompute(&report);
    if let Some(json) = &args.json {
        write_json(json, &report)?;
    }
    Ok(())
}
