//! `lfr compare --reference FILE.exr[,FILE2.exr]`: a reference rendered elsewhere (`lfr render`,
//! or its shards assembled by `lfr merge`; docs/scale-out.md) instead of the traced or cached
//! one. Each file's header record (`render::RenderRecord`) must show that it is this
//! comparison's scene as set up for the effect (`fingerprint`), at this size and path length,
//! whole (not a shard), with a seed other than the comparison's (else the reference's noise
//! would be the inputs' noise). Two files with different seeds are the two halves that give
//! the reference's own error; one file has no such estimate.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use recon::{Effect, Image};
use sha2::{Digest, Sha256};

use super::effect::{image_layer, Tracing};
use super::reference::Reference;
use crate::render::RenderRecord;

/// The most files `--reference` takes (two halves).
pub const MAX_FILES: usize = 2;

/// The EXR layer of the effect's image in an `lfr render` output (`""`: beauty).
fn layer_of(effect: Effect) -> Result<&'static str> {
    match image_layer(effect).estimate.render_layer() {
        Some(layer) => Ok(layer),
        None => bail!("--reference: lfr render writes no ambient-occlusion layer; --effect ao traces its own"),
    }
}

/// Reads and checks the files (module doc); `scene_sha256` is the comparison's scene as set up
/// for the effect, `seed` the comparison's seed.
pub fn external_reference(tracing: &Tracing, scene_sha256: &str, seed: u32, files: &[PathBuf]) -> Result<Reference> {
    if files.is_empty() || files.len() > MAX_FILES {
        bail!("--reference takes one image or two halves with different seeds, got {} files", files.len());
    }
    let layer = layer_of(tracing.effect)?;
    let mut images = Vec::new();
    let mut records = Vec::new();
    let mut hash = Sha256::new();
    for path in files {
        let record = RenderRecord::read(path)?.with_context(|| {
            format!(
                "--reference {}: no lfr.render record in its header; render the reference with `lfr render` \
                 (or its shards and `lfr merge`) so that its scene, spp and seed are known",
                path.display()
            )
        })?;
        let problem = |why: String| anyhow::anyhow!("--reference {}: {why}", path.display());
        if record.scene_sha256 != scene_sha256 {
            return Err(problem(format!(
                "rendered from another scene or set-up than this comparison's (--effect {} as set up: {})",
                tracing.effect.name(),
                "same scene file, lens, lighting and geometry; dof removes motion, motion closes the lens"
            )));
        }
        if (record.width, record.height) != (tracing.width, tracing.height) {
            return Err(problem(format!(
                "{}x{}, this comparison is {}x{}",
                record.width, record.height, tracing.width, tracing.height
            )));
        }
        if record.max_bounces != tracing.max_bounces {
            return Err(problem(format!(
                "rendered with {} bounces, this comparison uses {}",
                record.max_bounces, tracing.max_bounces
            )));
        }
        if record.shard != [0, 1] {
            return Err(problem(format!(
                "shard {}/{} only; assemble the shards with `lfr merge` first",
                record.shard[0], record.shard[1]
            )));
        }
        if record.seed == seed {
            return Err(problem(format!(
                "rendered with seed {seed}, the comparison's own: its noise would be the inputs' noise; render it with another seed"
            )));
        }
        let (w, h, channels) = tracer::output::read_exr(path)?;
        let find = |c: &str| {
            let name = if layer.is_empty() { c.to_string() } else { format!("{layer}.{c}") };
            channels
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, v)| v)
                .ok_or_else(|| problem(format!("no channel {name}")))
        };
        let (r, g, b) = (find("R")?, find("G")?, find("B")?);
        let n = w as usize * h as usize;
        if (w, h) != (record.width, record.height) || r.len() != n || g.len() != n || b.len() != n {
            return Err(problem(format!("the image is {w}x{h}, its record says {}x{}", record.width, record.height)));
        }
        let pixels: Vec<[f32; 3]> = (0..n).map(|i| [r[i], g[i], b[i]]).collect();
        if pixels.iter().flatten().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(problem("holds a non-finite or negative value".into()));
        }
        hash.update(std::fs::read(path).with_context(|| format!("reading {}", path.display()))?);
        images.push(Image::from_pixels(w, h, pixels));
        records.push(record);
    }
    let key = crate::fingerprint::hex(&hash.finalize());
    let spp = records.iter().map(|r| r.spp).sum();
    let seconds = records.iter().map(|r| r.seconds).sum();
    match (images.as_slice(), records.as_slice()) {
        ([a, b], [ra, rb]) => {
            if ra.seed == rb.seed {
                bail!(
                    "--reference: both halves were rendered with seed {}: they are the same samples, not two halves",
                    ra.seed
                );
            }
            let image = Image::from_pixels(
                a.width,
                a.height,
                a.pixels.iter().zip(&b.pixels).map(|(x, y)| std::array::from_fn(|c| 0.5 * (x[c] + y[c]))).collect(),
            );
            let halves = Some((a.clone(), b.clone()));
            Ok(Reference { image, halves, spp, seconds, seeds: [ra.seed, rb.seed], key, from_cache: false })
        }
        ([a], [r]) => Ok(Reference {
            image: a.clone(),
            halves: None,
            spp,
            seconds,
            seeds: [r.seed, r.seed],
            key,
            from_cache: false,
        }),
        _ => unreachable!("one or two files, checked above"),
    }
}
