//! The reference image of a comparison: the effect traced at many samples per pixel, as two
//! independent halves so that its own error can be estimated, with seeds derived from the
//! comparison's seed but never equal to it. Cached under a hash of everything that determines
//! it (scene file, geometry, effect, resolution, spp, seeds, path length, AO radius and the
//! estimator version), so reruns and other methods' runs reuse it.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use recon::{Effect, Image};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use tracer::output::{read_exr, write_atomically, write_exr, Layer};

use super::effect::Tracing;
use crate::convert::rgb_channels;

/// Bumped whenever the tracer's estimators change what a reference contains (4: normal maps,
/// single-sided materials, rectangle lights by solid angle, scale-free offsets).
const ESTIMATOR_VERSION: &str = "lfr-reference/4";

/// Added to the key of ambient-occlusion references only, bumped when the AO estimator changes
/// (2: a cosine direction below the geometric surface is occluded, no longer an escape).
const AO_ESTIMATOR_VERSION: &str = "ao/2";

/// A reference: the mean of two halves, and the halves (none for an external reference given as
/// one image).
pub struct Reference {
    pub image: Image,
    pub halves: Option<(Image, Image)>,
    pub spp: u32,
    pub seconds: f64,
    pub seeds: [u32; 2],
    pub key: String,
    pub from_cache: bool,
}

#[derive(Serialize, Deserialize)]
struct CacheRecord {
    key: String,
    spp: u32,
    seconds: f64,
    seeds: [u32; 2],
    /// SHA-256 of the EXR beside it: a cached image edited or damaged since is not used.
    exr_sha256: String,
}

fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// SplitMix64's finaliser of `value ^ salt`, its high 32 bits.
pub fn hashed(value: u64, salt: u64) -> u32 {
    let mut z = value ^ salt;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    (z >> 32) as u32
}

/// What a seed derived from the comparison's is for: each purpose its own, so that no two
/// comparisons' or purposes' seeds coincide by construction.
#[derive(Clone, Copy, Debug)]
pub enum SeedPurpose {
    ReferenceHalfA = 1,
    ReferenceHalfB = 2,
    ReferenceCheck = 3,
}

/// The seed for `purpose` derived from comparison seed `seed`: the hash of (purpose, seed) as
/// one 64-bit word, so distinct pairs hash distinct words (the finaliser is a bijection; only
/// the kept high half can collide, as any two random seeds can). Hashing `seed ^ salt` with
/// salts one bit apart instead would give seeds 1 and 2 the same two reference seeds, swapped.
pub fn derived_seed(seed: u32, purpose: SeedPurpose) -> u32 {
    hashed((purpose as u64) << 32 | seed as u64, 0x5245_4645_5245_4e43)
}

/// The two reference seeds for comparison seed `seed`: hashed, never `seed` itself, and not
/// each other.
pub fn reference_seeds(seed: u32) -> [u32; 2] {
    let mut a = derived_seed(seed, SeedPurpose::ReferenceHalfA);
    if a == seed {
        a = a.wrapping_add(1);
    }
    let mut b = derived_seed(seed, SeedPurpose::ReferenceHalfB);
    if b == a || b == seed {
        b = a.wrapping_add(2);
    }
    [a, b]
}

/// Where references are cached: `--cache-dir`, else `$LFR_CACHE_DIR`, else
/// `$XDG_CACHE_HOME/lfr`, else `~/.cache/lfr`, else `.lfr-cache` in the working directory.
/// Checks, before any tracing, that the reference can be stored in `dir`: it is (or can be
/// created as) a directory in which a file can be created. A regular file, or a directory
/// without write permission, is an error naming it, instead of a failure after the reference,
/// the ladder and the methods were traced.
pub fn check_cache_dir(dir: &Path) -> Result<()> {
    let problem = |why: String| anyhow::anyhow!("--cache-dir {}: {why}", dir.display());
    match std::fs::metadata(dir) {
        Ok(meta) if !meta.is_dir() => return Err(problem("not a directory".into())),
        Ok(_) => {}
        Err(_) => std::fs::create_dir_all(dir).map_err(|e| problem(format!("cannot create the directory: {e}")))?,
    }
    tempfile::Builder::new()
        .prefix(".lfr-write-test")
        .tempfile_in(dir)
        .map_err(|e| problem(format!("cannot write into the directory: {e}")))?;
    Ok(())
}

pub fn cache_dir(given: Option<&Path>) -> PathBuf {
    if let Some(dir) = given {
        return dir.to_path_buf();
    }
    if let Some(dir) = std::env::var_os("LFR_CACHE_DIR").filter(|d| !d.is_empty()) {
        return PathBuf::from(dir);
    }
    if let Some(dir) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(dir).join("lfr");
    }
    if let Some(home) = std::env::var_os("HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(home).join(".cache/lfr");
    }
    PathBuf::from(".lfr-cache")
}

/// The cache key: SHA-256 over the scene text, its geometry and the settings.
pub fn cache_key(scene_text: &[u8], tracing: &Tracing, spp: u32, seeds: [u32; 2]) -> String {
    let mut hash = Sha256::new();
    hash.update(ESTIMATOR_VERSION.as_bytes());
    if tracing.effect == Effect::Ao {
        hash.update(AO_ESTIMATOR_VERSION.as_bytes());
    }
    crate::fingerprint::hash_scene(&mut hash, scene_text, tracing.scene);
    let settings = format!(
        "effect={} width={} height={} spp={} seeds={:?} max_bounces={} ao_radius={}",
        tracing.effect.name(),
        tracing.width,
        tracing.height,
        spp,
        seeds,
        tracing.max_bounces,
        tracing.ao_radius
    );
    hash.update(settings.as_bytes());
    crate::fingerprint::hex(&hash.finalize())
}

fn layer_image(path: &Path, width: u32, height: u32, channels: &[(String, Vec<f32>)], layer: &str) -> Result<Image> {
    let find = |name: &str| {
        let full = format!("{layer}.{name}");
        channels
            .iter()
            .find(|(n, _)| *n == full)
            .map(|(_, v)| v)
            .with_context(|| format!("{}: no channel {full}", path.display()))
    };
    let (r, g, b) = (find("R")?, find("G")?, find("B")?);
    let n = width as usize * height as usize;
    anyhow::ensure!(r.len() == n && g.len() == n && b.len() == n, "{}: channel sizes", path.display());
    Ok(Image::from_pixels(width, height, (0..n).map(|i| [r[i], g[i], b[i]]).collect()))
}

/// The PSNR of the reference (the mean of its two halves) against the truth, estimated from
/// the halves alone: for independent halves the mean's error is half of either's in linear
/// space, so its display-space MSE is a quarter of the halves' mutual one, hence their PSNR
/// plus 10·log10 4. Checked against renders of 16 times the samples (test below; docs/history/ilfr.md,
/// "The reference's self-estimate"): right within ±0.8 dB on Cornell and Sponza, but 1.4–1.8 dB
/// optimistic where rare paths carry the light (the glossy monkeys' dark floor), which both
/// halves miss alike; no statistic of two halves can see that deficit.
pub fn estimated_psnr_db(half_a: &Image, half_b: &Image, tone: &recon::metrics::ToneMap) -> Result<f64> {
    let between = recon::metrics::psnr_db(half_a, half_b, tone)?;
    Ok((between + 10.0 * 4f64.log10()).min(recon::metrics::PSNR_CEILING_DB))
}

fn mean(a: &Image, b: &Image) -> Image {
    let pixels = a.pixels.iter().zip(&b.pixels).map(|(p, q)| [0, 1, 2].map(|c| 0.5 * (p[c] + q[c]))).collect();
    Image::from_pixels(a.width, a.height, pixels)
}

/// Reads the cached reference for `key`: `Ok(None)` when there is none, `Err(why)` when there is
/// one that cannot be trusted (its record disagrees with what was asked, the image does not
/// match its checksum, or holds a non-finite or negative value), which is then traced again.
fn read_cached(
    dir: &Path,
    key: &str,
    tracing: &Tracing,
    spp: u32,
    seeds: [u32; 2],
) -> Result<Option<Reference>, String> {
    let json = dir.join(format!("{key}.json"));
    let path = dir.join(format!("{key}.exr"));
    let Ok(record_bytes) = std::fs::read(&json) else { return Ok(None) };
    let record: CacheRecord =
        serde_json::from_slice(&record_bytes).map_err(|e| format!("{}: unreadable record: {e}", json.display()))?;
    let untrusted = |what: String| Err(format!("{}: {what}", json.display()));
    if record.key != key || record.seeds != seeds || record.spp != spp {
        return untrusted(format!(
            "the record says key {}, {} spp, seeds {:?}; this comparison needs {key}, {spp} spp, seeds {seeds:?}",
            record.key, record.spp, record.seeds
        ));
    }
    if !(record.seconds.is_finite() && record.seconds > 0.0) {
        return untrusted(format!("the recorded time {} s is not a positive number", record.seconds));
    }
    let exr_bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    if sha256_hex(&exr_bytes) != record.exr_sha256 {
        return Err(format!("{}: the image does not match the checksum in its record", path.display()));
    }
    let (w, h, channels) = read_exr(&path).map_err(|e| e.to_string())?;
    if (w, h) != (tracing.width, tracing.height) {
        return Err(format!("{}: {w}x{h}, not {}x{}", path.display(), tracing.width, tracing.height));
    }
    let half_a = layer_image(&path, w, h, &channels, "half_a").map_err(|e| e.to_string())?;
    let half_b = layer_image(&path, w, h, &channels, "half_b").map_err(|e| e.to_string())?;
    if half_a.pixels.iter().chain(&half_b.pixels).flatten().any(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(format!("{}: holds a non-finite or negative value", path.display()));
    }
    Ok(Some(Reference {
        image: mean(&half_a, &half_b),
        halves: Some((half_a, half_b)),
        spp: record.spp,
        seconds: record.seconds,
        seeds: record.seeds,
        key: key.to_string(),
        from_cache: true,
    }))
}

/// The reference for `tracing` at `spp` (even, ≥ 2): from the cache when `use_cache`, else
/// traced and stored.
pub fn reference(
    tracing: &Tracing,
    scene_text: &[u8],
    spp: u32,
    seed: u32,
    dir: &Path,
    use_cache: bool,
    progress: bool,
) -> Result<Reference> {
    let seeds = reference_seeds(seed);
    let key = cache_key(scene_text, tracing, spp, seeds);
    let half = (spp / 2).max(1);
    if use_cache {
        match read_cached(dir, &key, tracing, half * 2, seeds) {
            Ok(Some(reference)) => return Ok(reference),
            Ok(None) => {}
            Err(why) => eprintln!("warning: the cached reference is not used, it is traced again: {why}"),
        }
    }
    let a = tracing.trace(half, seeds[0], progress)?;
    let b = tracing.trace(half, seeds[1], progress)?;
    let seconds = a.seconds + b.seconds;
    let (half_a, half_b) = (a.frame.color, b.frame.color);
    std::fs::create_dir_all(dir).with_context(|| format!("creating the reference cache {}", dir.display()))?;
    let exr = dir.join(format!("{key}.exr"));
    write_exr(
        &exr,
        tracing.width,
        tracing.height,
        &[
            Layer { name: "half_a", channels: rgb_channels(&half_a) },
            Layer { name: "half_b", channels: rgb_channels(&half_b) },
        ],
    )
    .with_context(|| format!("writing the reference {}", exr.display()))?;
    let exr_bytes = std::fs::read(&exr).with_context(|| format!("reading back {}", exr.display()))?;
    let record = CacheRecord { key: key.clone(), spp: half * 2, seconds, seeds, exr_sha256: sha256_hex(&exr_bytes) };
    let json = dir.join(format!("{key}.json"));
    write_atomically(&json, |tmp| {
        std::fs::write(tmp, serde_json::to_vec_pretty(&record).map_err(|e| e.to_string())?).map_err(|e| e.to_string())
    })
    .with_context(|| format!("writing {}", json.display()))?;
    Ok(Reference {
        image: mean(&half_a, &half_b),
        halves: Some((half_a, half_b)),
        spp: half * 2,
        seconds,
        seeds,
        key,
        from_cache: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use recon::metrics::{psnr_db, ToneMap};
    use recon::Effect;

    /// The self-estimate against an independent one: Cornell's indirect light at 24 × 24,
    /// halves of 256 spp (a noisy reference, where the display map bends the most), and a
    /// truth of 16 times the reference's samples whose own error (1/16 of the reference's) is
    /// taken out. Measured spread of the estimate at this size: about ±0.5 dB on the branch that
    /// wrote it, −1.03 dB with the same seeds once rectangle lights were sampled by solid angle
    /// (that changes every path's random decisions, not the expectation); hence 1.5 dB.
    #[test]
    fn the_estimate_from_two_halves_matches_a_much_longer_render() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let scene = tracer::Scene::load(&root.join("scenes/cornell.toml")).unwrap();
        let accel = tracer::Accel::build(&scene).unwrap();
        let tracing = Tracing {
            scene: &scene,
            accel: &accel,
            effect: Effect::Indirect,
            width: 24,
            height: 24,
            max_bounces: scene.max_bounces,
            ao_radius: 1.0,
            threads: 0,
        };
        let trace = |spp: u32, seed: u32| tracing.trace(spp, seed, false).unwrap().frame.color;
        let (a, b) = (trace(256, 11), trace(256, 12));
        let reference = mean(&a, &b);
        let truth = mean(&trace(4096, 13), &trace(4096, 14));
        let tone = ToneMap::auto(&reference);
        let estimated = estimated_psnr_db(&a, &b, &tone).unwrap();
        // MSE(reference, truth) = MSE_reference + MSE_truth, the latter 1/16 of the former.
        let measured = psnr_db(&truth, &reference, &tone).unwrap() + 10.0 * (17.0f64 / 16.0).log10();
        assert!(
            (estimated - measured).abs() < 1.5,
            "estimated {estimated:.2} dB, against the long render {measured:.2} dB"
        );
        // A render of the reference's own spp is no truth: against it the reference reads about
        // 3 dB (10·log10 2) below its own PSNR (measured 1.86 dB below with these seeds: the same
        // spread of about a decibel as above).
        let twin = mean(&trace(256, 15), &trace(256, 16));
        let against_twin = psnr_db(&twin, &reference, &tone).unwrap();
        assert!(
            (estimated - against_twin - 10.0 * 2f64.log10()).abs() < 1.5,
            "estimated {estimated:.2} dB, against a twin {against_twin:.2} dB"
        );
    }

    #[test]
    fn reference_seeds_differ_from_the_input_seed_and_each_other() {
        for seed in [0, 1, 2, 7, 12345, u32::MAX] {
            let [a, b] = reference_seeds(seed);
            assert!(a != seed && b != seed && a != b, "{seed}: {a} {b}");
        }
        assert_eq!(reference_seeds(5), reference_seeds(5));
        // No two comparisons share a reference seed (seeds 1 and 2 once shared both, swapped),
        // nor a check seed with any reference seed.
        let mut all: Vec<u32> = (0..2000u32)
            .flat_map(|seed| {
                let [a, b] = reference_seeds(seed);
                [a, b, derived_seed(seed, SeedPurpose::ReferenceCheck)]
            })
            .collect();
        let count = all.len();
        all.sort_unstable();
        all.dedup();
        assert_eq!(all.len(), count, "derived seeds coincide");
    }
}
