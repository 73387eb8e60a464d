//! `lfr merge`: assembles the shards of `lfr render --shard I/N` into the image one process
//! would have rendered (docs/scale-out.md). Every shard's header record
//! (`render::RenderRecord`) must name the same scene, size, spp, seed, path length, shard count
//! and split, and the shards must be 0..N, each once.
//! - By tiles, each pixel is taken from the shard whose tiles hold it
//!   (`tracer::render::Shard::covers`): bit for bit one process's image.
//! - By samples, each pixel's means are combined weighted by each shard's sample count, its
//!   variance from the shards' sums of squares (tested by `merged_sample_shards_equal_the_whole_pixel`): one process's image
//!   within float rounding (the sums are added in another order).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use glam::Vec3;
use tracer::output::Layer;
use tracer::render::{Shard, ShardBy};

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
fn agreement(record: &RenderRecord) -> (String, u32, u32, u32, u32, u32, u32, String) {
    (
        record.scene_sha256.clone(),
        record.width,
        record.height,
        record.spp,
        record.seed,
        record.max_bounces,
        record.shard[1],
        record.shard_by.clone(),
    )
}

/// The agreed fields in words, for errors.
fn describe(record: &RenderRecord) -> String {
    format!(
        "scene {}…, {}x{}, {} spp, seed {}, {} bounces, {} shards by {}",
        &record.scene_sha256[..12.min(record.scene_sha256.len())],
        record.width,
        record.height,
        record.spp,
        record.seed,
        record.max_bounces,
        record.shard[1],
        record.shard_by
    )
}

/// The shard a record describes, its split and sample range checked.
fn shard_of(path: &Path, record: &RenderRecord) -> Result<Shard> {
    let by = ShardBy::parse(&record.shard_by)
        .map_err(|e| anyhow::anyhow!("{}: lfr.render: shard_by: {e}", path.display()))?;
    let shard = Shard { index: record.shard[0], count: record.shard[1], by };
    let range = shard.sample_range(record.spp);
    if let Some([start, end]) = record.samples {
        if (start, end) != (range.start, range.end) {
            bail!(
                "{}: lfr.render: samples {start}..{end}, but shard {}/{} by {} of {} spp traces {}..{}",
                path.display(),
                shard.index,
                shard.count,
                by.name(),
                record.spp,
                range.start,
                range.end
            );
        }
    }
    Ok(shard)
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
        shard_of(path, &record)?;
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
    let preview = crate::outputs::preview_of(&args.out);
    let mut plan = crate::outputs::OutputPlan::new();
    plan.file(&args.out, "--out").file(&preview, "the PNG preview beside --out");
    for shard in &args.shards {
        plan.input(shard, "a shard");
    }
    plan.check()?;
    let shards = check_records(&args.shards)?;
    let first = &shards[0].1;
    let (width, height) = (first.width, first.height);
    let pixels = width as usize * height as usize;

    let by = shard_of(&shards[0].0, first)?.by;
    let mut by_samples: Option<SampleMerge> = None;
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
        let shard = shard_of(path, record)?;
        if by == ShardBy::Samples {
            let merge = by_samples.get_or_insert_with(|| SampleMerge::new(&found, pixels));
            merge.add(shard.sample_range(record.spp).len() as u32, &found);
        }
        for ((_, into), (_, from)) in channels.iter_mut().zip(&found).filter(|_| by == ShardBy::Tiles) {
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

    if let Some(merge) = by_samples {
        channels = merge.finish();
    }
    merged.shard_by = ShardBy::Tiles.name().into();
    merged.samples = Some([0, merged.spp]);

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

/// Combines the layers of shards by samples: every channel a mean weighted by each shard's
/// sample count; `normal.*` the direction of the weighted sum; `variance.C` (of the mean of C)
/// from each shard's sum of squares, n·v·(n − 1) + n·m² (v = s²/n the shard's variance of the
/// mean, m its mean), as one process would have summed them.
///
/// Beauty, direct, indirect and variance are exact but for float rounding where every sample of
/// a pixel is valid (the record's `invalid_samples` counts those that were not). The guide
/// layers (albedo, normal, position, depth: means over a pixel's hits) are weighted by the
/// shards' sample counts, not their hits, and normals add the shards' unit normals, not every
/// sample's: exact where a pixel's samples all hit one flat surface, close elsewhere.
struct SampleMerge {
    names: Vec<String>,
    sums: Vec<Vec<f64>>,
    squares: Vec<Vec<f64>>,
    samples: f64,
}

impl SampleMerge {
    fn new(layout: &[(String, Vec<f32>)], pixels: usize) -> SampleMerge {
        let names: Vec<String> = layout.iter().map(|(n, _)| n.clone()).collect();
        SampleMerge {
            sums: vec![vec![0.0; pixels]; names.len()],
            squares: vec![vec![0.0; pixels]; names.len()],
            names,
            samples: 0.0,
        }
    }

    /// The beauty channel whose variance `name` is (`variance.R` → `R`).
    fn mean_of(&self, name: &str) -> Option<usize> {
        let channel = name.strip_prefix("variance.")?;
        self.names.iter().position(|n| n == channel)
    }

    fn add(&mut self, samples: u32, channels: &[(String, Vec<f32>)]) {
        let n = samples as f64;
        self.samples += n;
        for (c, (name, values)) in channels.iter().enumerate() {
            let mean = self.mean_of(name).map(|m| &channels[m].1);
            for (p, &value) in values.iter().enumerate() {
                match mean {
                    Some(mean) => {
                        let m = mean[p] as f64;
                        self.squares[c][p] += n * value as f64 * (n - 1.0) + n * m * m;
                    }
                    None => self.sums[c][p] += n * value as f64,
                }
            }
        }
    }

    fn finish(self) -> Vec<(String, Vec<f32>)> {
        let total = self.samples;
        let mut out: Vec<(String, Vec<f32>)> =
            self.names.iter().map(|n| (n.clone(), vec![0.0; self.sums[0].len()])).collect();
        for (c, name) in self.names.iter().enumerate() {
            match self.mean_of(name) {
                Some(m) => {
                    for (p, value) in out[c].1.iter_mut().enumerate() {
                        let mean = self.sums[m][p] / total;
                        let sample_variance = if total > 1.0 {
                            ((self.squares[c][p] - total * mean * mean) / (total - 1.0)).max(0.0)
                        } else {
                            0.0
                        };
                        *value = (sample_variance / total).min(f32::MAX as f64) as f32;
                    }
                }
                None => {
                    for (p, value) in out[c].1.iter_mut().enumerate() {
                        *value = (self.sums[c][p] / total) as f32;
                    }
                }
            }
        }
        // Normals: the direction of the weighted sum, as one process normalises its sum.
        let axis = |a: &str| self.names.iter().position(|n| n == &format!("normal.{a}"));
        if let (Some(x), Some(y), Some(z)) = (axis("X"), axis("Y"), axis("Z")) {
            for p in 0..out[x].1.len() {
                let n = Vec3::new(out[x].1[p], out[y].1[p], out[z].1[p]).normalize_or_zero();
                (out[x].1[p], out[y].1[p], out[z].1[p]) = (n.x, n.y, n.z);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mean and variance of the mean of `values`, as `tracer::render` assembles a pixel.
    fn pixel(values: &[f64]) -> (f32, f32) {
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let square = values.iter().map(|v| v * v).sum::<f64>();
        let variance = if n > 1.0 { ((square - n * mean * mean) / (n - 1.0)).max(0.0) / n } else { 0.0 };
        (mean as f32, variance as f32)
    }

    #[test]
    fn merged_sample_shards_equal_the_whole_pixel() {
        // Two pixels of 11 samples each (a spike in one), split 1 + 4 + 6.
        let samples: [Vec<f64>; 2] = [
            (0..11).map(|i| 0.1 * i as f64 + 0.05).collect(),
            (0..11).map(|i| if i == 7 { 1000.0 } else { 0.3 + 0.01 * i as f64 }).collect(),
        ];
        let normals = [Vec3::new(0.0, 0.6, 0.8), Vec3::new(1.0, 0.0, 0.0)];
        let mut merge = None;
        for range in [0..1, 1..5, 5..11] {
            let parts: Vec<(f32, f32)> = samples.iter().map(|s| pixel(&s[range.clone()])).collect();
            let channels: Vec<(String, Vec<f32>)> = vec![
                ("R".into(), parts.iter().map(|p| p.0).collect()),
                ("normal.X".into(), normals.iter().map(|n| n.x).collect()),
                ("normal.Y".into(), normals.iter().map(|n| n.y).collect()),
                ("normal.Z".into(), normals.iter().map(|n| n.z).collect()),
                ("variance.R".into(), parts.iter().map(|p| p.1).collect()),
            ];
            merge.get_or_insert_with(|| SampleMerge::new(&channels, 2)).add(range.len() as u32, &channels);
        }
        let merged = merge.unwrap().finish();
        for (p, values) in samples.iter().enumerate() {
            let (mean, variance) = pixel(values);
            let close = |a: f32, b: f32| ((a - b) / b).abs() < 1e-5;
            assert!(close(merged[0].1[p], mean), "pixel {p}: {} vs {mean}", merged[0].1[p]);
            assert!(close(merged[4].1[p], variance), "pixel {p}: {} vs {variance}", merged[4].1[p]);
            let n = Vec3::new(merged[1].1[p], merged[2].1[p], merged[3].1[p]);
            assert!((n - normals[p]).length() < 1e-6, "pixel {p}: {n}");
        }
    }
}
