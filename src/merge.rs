//! `lfr merge`: assembles the shards of `lfr render --shard I/N` into the image one process
//! would have rendered, bit for bit (docs/scale-out.md). Every shard's header record
//! (`render::RenderRecord`) must name the same scene, size, spp, seed, path length and shard
//! count, and the shards must be 0..N, each once; each pixel is taken from the shard whose tiles
//! hold it (`tracer::render::Shard::covers`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use glam::Vec3;
use tracer::output::Layer;
use tracer::render::Shard;

use crate::render::RenderRecord;

#[derive(clap::Args)]
pub struct MergeArgs {
    /// The shards' EXR files, in any order.
    #[arg(required = true, num_args = 1..)]
    shards: Vec<PathBuf>,
    /// The merged EXR; the PNG preview goes beside it.
    #[arg(long)]
    out: PathBuf,
}

/// The fields every shard must agree on.
fn agreement(record: &RenderRecord) -> (String, u32, u32, u32, u32, u32, u32) {
    (
        record.scene_sha256.clone(),
        record.width,
        record.height,
        record.spp,
        record.seed,
        record.max_bounces,
        record.shard[1],
    )
}

/// The agreed fields in words, for errors.
fn describe(record: &RenderRecord) -> String {
    format!(
        "scene {}…, {}x{}, {} spp, seed {}, {} bounces, {} shards",
        &record.scene_sha256[..12.min(record.scene_sha256.len())],
        record.width,
        record.height,
        record.spp,
        record.seed,
        record.max_bounces,
        record.shard[1]
    )
}

/// Reads and checks every shard's record before any pixel is read; returns them in shard order.
fn check_records(shards: &[PathBuf]) -> Result<Vec<(PathBuf, RenderRecord)>> {
    let mut records: BTreeMap<u32, (PathBuf, RenderRecord)> = BTreeMap::new();
    let mut first: Option<(PathBuf, RenderRecord)> = None;
    for path in shards {
        let record = RenderRecord::read(path)?.with_context(|| {
            format!("{}: no lfr.render record in its header: not an image of `lfr render`", path.display())
        })?;
        if let Some((first_path, first_record)) = &first {
            if agreement(&record) != agreement(first_record) {
                bail!(
                    "{} and {} are not shards of one render: {} against {}",
                    path.display(),
                    first_path.display(),
                    describe(&record),
                    describe(first_record)
                );
            }
        } else {
            first = Some((path.clone(), record.clone()));
        }
        let [index, count] = record.shard;
        if count == 0 || index >= count {
            bail!("{}: lfr.render: shard {index}/{count} is impossible", path.display());
        }
        if let Some((other, _)) = records.get(&index) {
            bail!("{} and {} are both shard {index}/{count}", other.display(), path.display());
        }
        records.insert(index, (path.clone(), record));
    }
    let count = first.as_ref().map_or(0, |(_, r)| r.shard[1]);
    let missing: Vec<String> = (0..count).filter(|i| !records.contains_key(i)).map(|i| i.to_string()).collect();
    if !missing.is_empty() {
        let shown: Vec<&str> = missing.iter().take(10).map(String::as_str).collect();
        bail!(
            "shard{} {}{} of {count} missing: the merged image would have holes",
            if missing.len() == 1 { "" } else { "s" },
            shown.join(", "),
            if missing.len() > shown.len() { ", …" } else { "" }
        );
    }
    Ok(records.into_values().collect())
}

pub fn run(args: &MergeArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("exr")) != Some(true) {
        bail!("--out {}: the output must be an .exr file", args.out.display());
    }
    let preview = args.out.with_extension("png");
    let inputs: Vec<&Path> = args.shards.iter().map(PathBuf::as_path).collect();
    crate::common::check_outputs(&[&args.out, &preview], &inputs)?;
    let shards = check_records(&args.shards)?;
    let first = &shards[0].1;
    let (width, height) = (first.width, first.height);
    let pixels = width as usize * height as usize;

    let mut channels: Vec<(String, Vec<f32>)> = Vec::new();
    let mut merged = RenderRecord { shard: [0, 1], rays: 0, seconds: 0.0, ..first.clone() };
    (merged.invalid_samples, merged.clamped_variances, merged.dropped_contributions) = (0, 0, 0);
    for (path, record) in &shards {
        let (w, h, found) = tracer::output::read_exr(path)?;
        if (w, h) != (width, height) {
            bail!("{}: the image is {w}x{h}, its record says {width}x{height}", path.display());
        }
        if channels.is_empty() {
            channels = found.iter().map(|(name, _)| (name.clone(), vec![0.0; pixels])).collect();
        }
        let names = |list: &[(String, Vec<f32>)]| list.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
        if names(&found) != names(&channels) {
            bail!("{}: channels {:?}, the first shard has {:?}", path.display(), names(&found), names(&channels));
        }
        let shard = Shard { index: record.shard[0], count: record.shard[1] };
        for ((_, into), (_, from)) in channels.iter_mut().zip(&found) {
            for y in 0..height {
                for x in 0..width {
                    if shard.covers(width, x, y) {
                        let p = (y * width + x) as usize;
                        into[p] = from[p];
                    }
                }
            }
        }
        merged.rays += record.rays;
        merged.seconds += record.seconds;
        merged.invalid_samples += record.invalid_samples;
        merged.clamped_variances += record.clamped_variances;
        merged.dropped_contributions += record.dropped_contributions;
    }

    // Back into named layers (`layer.channel`, or the bare channel of the unnamed layer).
    let mut layers: Vec<Layer> = Vec::new();
    for (name, values) in &channels {
        let (layer, channel) = name.rsplit_once('.').unwrap_or(("", name.as_str()));
        match layers.iter_mut().find(|l| l.name == layer) {
            Some(existing) => existing.channels.push((channel, values.clone())),
            None => layers.push(Layer { name: layer, channels: vec![(channel, values.clone())] }),
        }
    }
    tracer::output::write_exr_with_attributes(&args.out, width, height, &layers, &[merged.attribute()?])?;
    let find = |name: &str| channels.iter().find(|(n, _)| n == name).map(|(_, v)| v);
    if let (Some(r), Some(g), Some(b)) = (find("R"), find("G"), find("B")) {
        let beauty: Vec<Vec3> = (0..pixels).map(|i| Vec3::new(r[i], g[i], b[i])).collect();
        tracer::output::write_png(&preview, width, height, &beauty, 1.0)?;
    }
    println!(
        "merged {} shards into {} ({width}x{height}, {} spp, {} rays, {:.3} s of rendering)",
        shards.len(),
        args.out.display(),
        merged.spp,
        merged.rays,
        merged.seconds
    );
    Ok(())
}
