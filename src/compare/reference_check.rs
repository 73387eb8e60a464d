//! An independent check of the reference's own error. The two halves' estimate
//! (`reference::estimated_psnr_db`) is blind where rare paths carry the light: a pixel whose
//! halves both missed them reads low in both, so they agree while both are wrong (1.7–2.1 dB
//! optimistic on the glossy monkeys; docs/history/ilfr.md, "The reference's self-estimate"). Only more
//! samples than the reference has can see that, and a whole image of them would cost more than
//! the reference; so the check traces a sparse, stratified set of pixels — one per
//! [`BLOCK`] × [`BLOCK`] block, at a hashed place in it — with [`DEFAULT_FACTOR`] times the
//! reference's samples (`--reference-check`) and a seed of its own: a quarter of the
//! reference's time. Against it, the reference's mean squared error at those pixels is
//! measured directly, in the comparison's display space: MSE(reference, check) =
//! MSE_reference + MSE_check, the check's 1 / factor of the reference's. Cached beside the
//! reference under a hash of everything that determines it; used for traced and external
//! references alike.

use std::path::Path;

use anyhow::{Context, Result};
use recon::metrics::{psnr_db, ToneMap, PSNR_CEILING_DB};
use recon::Image;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use tracer::limits::MAX_SPP;
use tracer::output::write_atomically;

use super::effect::Tracing;
use super::reference::{cache_key, derived_seed, hashed, SeedPurpose};

/// One checked pixel per `BLOCK` × `BLOCK` pixels (a partial block at the right or bottom edge
/// has one too).
pub const BLOCK: u32 = 4;

/// By default the check traces this many times the reference's samples per pixel
/// (`--reference-check`): a quarter of the reference's time.
pub const DEFAULT_FACTOR: &str = "4";

/// The largest `--reference-check` factor.
pub const MAX_FACTOR: u32 = 64;

/// `--reference-check`: the check's spp factor, or `None` for `off`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CheckSetting(pub Option<u32>);

/// Parses `--reference-check`: `off` or a factor in 1..=[`MAX_FACTOR`].
pub fn parse_factor(text: &str) -> Result<CheckSetting, String> {
    if text == "off" {
        return Ok(CheckSetting(None));
    }
    match text.parse::<u32>() {
        Ok(factor) if (1..=MAX_FACTOR).contains(&factor) => Ok(CheckSetting(Some(factor))),
        _ => Err(format!("expected `off` or a whole number in 1..={MAX_FACTOR}, got `{text}`")),
    }
}

/// The reference a check is for: its spp and seeds, and the check's spp factor.
#[derive(Clone, Copy, Debug)]
pub struct CheckOf {
    pub spp: u32,
    pub seeds: [u32; 2],
    pub factor: u32,
}

/// Bumped whenever what the check traces or how its pixels are chosen changes.
const CHECK_VERSION: &str = "reference-check/1";

/// The traced check.
pub struct Check {
    pub pixels: Vec<(u32, u32)>,
    /// The effect's value at each of `pixels`.
    pub values: Vec<[f32; 3]>,
    pub spp: u32,
    pub seed: u32,
    /// Wall time of the check's render when it was made (also when read from the cache).
    pub seconds: f64,
    pub from_cache: bool,
}

#[derive(Serialize, Deserialize)]
struct CheckRecord {
    key: String,
    spp: u32,
    seed: u32,
    seconds: f64,
    pixels: Vec<(u32, u32)>,
    values: Vec<[f32; 3]>,
}

/// The checked pixels of a `width` × `height` image: one per block, row-major by block, at a
/// place in the block hashed from `seed`.
pub fn check_pixels(width: u32, height: u32, seed: u32) -> Vec<(u32, u32)> {
    let mut pixels = Vec::with_capacity(width.div_ceil(BLOCK) as usize * height.div_ceil(BLOCK) as usize);
    for by in (0..height).step_by(BLOCK as usize) {
        for bx in (0..width).step_by(BLOCK as usize) {
            let (w, h) = (BLOCK.min(width - bx), BLOCK.min(height - by));
            // (seed, by, bx) as one word: sides are below 2^16.
            let place = hashed((seed as u64) << 32 | (by as u64) << 16 | bx as u64, 0x4348_4543_4b50_4958);
            pixels.push((bx + place % w, by + (place / w) % h));
        }
    }
    pixels
}

/// The check's seed for comparison seed `seed`: hashed, and none of `taken` (the comparison's
/// own seed and the reference's).
pub fn check_seed(seed: u32, taken: &[u32]) -> u32 {
    let mut s = derived_seed(seed, SeedPurpose::ReferenceCheck);
    while taken.contains(&s) {
        s = s.wrapping_add(1);
    }
    s
}

/// The check's samples per pixel for a reference of `reference_spp` and spp factor `factor`.
pub fn check_spp(reference_spp: u32, factor: u32) -> u32 {
    reference_spp.saturating_mul(factor).min(MAX_SPP)
}

fn key(scene_text: &[u8], tracing: &Tracing, spp: u32, seed: u32) -> String {
    let mut hash = Sha256::new();
    hash.update(CHECK_VERSION.as_bytes());
    hash.update(format!("block={BLOCK} ").as_bytes());
    hash.update(cache_key(scene_text, tracing, spp, [seed, seed]).as_bytes());
    crate::fingerprint::hex(&hash.finalize())
}

/// Reads the cached check: `Ok(None)` when there is none, `Err(why)` when there is one that
/// cannot be trusted (another key, spp, seed or pixel set, a value that is not finite and
/// non-negative, a time that is not positive), which is then traced again.
fn read_cached(path: &Path, key: &str, spp: u32, seed: u32, pixels: &[(u32, u32)]) -> Result<Option<Check>, String> {
    let Ok(bytes) = std::fs::read(path) else { return Ok(None) };
    let untrusted = |what: &str| Err(format!("{}: {what}", path.display()));
    let record: CheckRecord = match serde_json::from_slice(&bytes) {
        Ok(record) => record,
        Err(e) => return untrusted(&format!("unreadable record: {e}")),
    };
    if record.key != key || record.spp != spp || record.seed != seed || record.pixels != pixels {
        return untrusted("its key, spp, seed or pixels are not this comparison's");
    }
    if record.values.len() != pixels.len() || record.values.iter().flatten().any(|v| !(v.is_finite() && *v >= 0.0)) {
        return untrusted("its values are not one finite, non-negative colour per pixel");
    }
    if !(record.seconds.is_finite() && record.seconds > 0.0) {
        return untrusted("its recorded time is not a positive number");
    }
    Ok(Some(Check {
        pixels: record.pixels,
        values: record.values,
        spp,
        seed,
        seconds: record.seconds,
        from_cache: true,
    }))
}

/// The check of `reference`, for comparison seed `seed`: from the cache in `dir` when
/// `use_cache`, else traced and stored.
pub fn check(
    tracing: &Tracing,
    scene_text: &[u8],
    reference: CheckOf,
    seed: u32,
    dir: &Path,
    use_cache: bool,
    progress: bool,
) -> Result<Check> {
    let spp = check_spp(reference.spp, reference.factor);
    let check_seed = check_seed(seed, &[seed, reference.seeds[0], reference.seeds[1]]);
    let pixels = check_pixels(tracing.width, tracing.height, check_seed);
    let key = key(scene_text, tracing, spp, check_seed);
    let path = dir.join(format!("{key}.check.json"));
    if use_cache {
        match read_cached(&path, &key, spp, check_seed, &pixels) {
            Ok(Some(check)) => return Ok(check),
            Ok(None) => {}
            Err(why) => eprintln!("warning: the cached reference check is not used, it is traced again: {why}"),
        }
    }
    let (values, seconds) = tracing.trace_pixels(spp, check_seed, &pixels, progress)?;
    let record = CheckRecord { key, spp, seed: check_seed, seconds, pixels, values };
    std::fs::create_dir_all(dir).with_context(|| format!("creating the reference cache {}", dir.display()))?;
    write_atomically(&path, |tmp| {
        std::fs::write(tmp, serde_json::to_vec(&record).map_err(|e| e.to_string())?).map_err(|e| e.to_string())
    })
    .with_context(|| format!("writing {}", path.display()))?;
    Ok(Check { pixels: record.pixels, values: record.values, spp, seed: check_seed, seconds, from_cache: false })
}

/// The reference's PSNR as the check measures it, with a two-standard-error interval from the
/// spread of the per-pixel squared errors (the pixels are a sample of the image's).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CheckEstimate {
    pub psnr_db: f64,
    /// `[low, high]` dB: the PSNR at the mean squared error plus and minus two standard errors
    /// (high is the ceiling where two standard errors reach zero; `[0, ceiling]` for a single
    /// pixel, whose spread is unknown).
    pub interval_db: [f64; 2],
}

impl Check {
    /// The PSNR of `reference` (of `reference_spp`) against the truth, in display space through
    /// `tone`, from the checked pixels: PSNR(check, reference there) + 10·log10((k + 1) / k),
    /// k = the check's spp over the reference's, since the check's own squared error is 1/k of
    /// the reference's and adds to it.
    pub fn estimate(&self, reference: &Image, reference_spp: u32, tone: &ToneMap) -> Result<CheckEstimate> {
        let at: Vec<[f32; 3]> =
            self.pixels.iter().map(|&(x, y)| reference.pixels[(y * reference.width + x) as usize]).collect();
        let n = at.len() as u32;
        let between =
            psnr_db(&Image::from_pixels(n, 1, self.values.clone()), &Image::from_pixels(n, 1, at.clone()), tone)?;
        let k = self.spp as f64 / reference_spp.max(1) as f64;
        let own = 10.0 * ((k + 1.0) / k).log10();
        let psnr = (between + own).min(PSNR_CEILING_DB);
        // Per-pixel squared display errors (mean over the channels): their mean is the MSE
        // behind `between`, their spread gives its standard error.
        let squared: Vec<f64> = at
            .iter()
            .zip(&self.values)
            .map(|(r, c)| {
                (0..3).map(|i| (tone.apply(c[i]) as f64 - tone.apply(r[i]) as f64).powi(2)).sum::<f64>() / 3.0
            })
            .collect();
        let count = squared.len().max(1) as f64;
        let mse = squared.iter().sum::<f64>() / count;
        let variance = squared.iter().map(|d| (d - mse).powi(2)).sum::<f64>() / (count - 1.0).max(1.0);
        let standard_error = (variance / count).sqrt();
        let at_mse = |m: f64| {
            if m > 0.0 {
                (10.0 * (1.0 / m).log10() + own).min(PSNR_CEILING_DB)
            } else {
                PSNR_CEILING_DB
            }
        };
        let interval_db = if squared.len() < 2 {
            [0.0, PSNR_CEILING_DB] // one pixel says nothing of the spread
        } else {
            [at_mse(mse + 2.0 * standard_error).min(psnr), at_mse(mse - 2.0 * standard_error).max(psnr)]
        };
        Ok(CheckEstimate { psnr_db: psnr, interval_db })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_checked_pixel_per_block_inside_it_also_at_partial_edges() {
        for (width, height) in [(1, 1), (4, 4), (5, 3), (17, 9), (160, 90)] {
            let pixels = check_pixels(width, height, 3);
            assert_eq!(pixels.len() as u32, width.div_ceil(BLOCK) * height.div_ceil(BLOCK), "{width}x{height}");
            for &(x, y) in &pixels {
                assert!(x < width && y < height, "({x}, {y}) outside {width}x{height}");
            }
            let mut blocks: Vec<(u32, u32)> = pixels.iter().map(|&(x, y)| (x / BLOCK, y / BLOCK)).collect();
            blocks.dedup();
            assert_eq!(blocks.len(), pixels.len(), "{width}x{height}: two pixels in one block");
        }
        // Places vary within the blocks and with the seed (not always the same corner).
        let a = check_pixels(160, 90, 3);
        let corners = a.iter().filter(|&&(x, y)| x % BLOCK == 0 && y % BLOCK == 0).count();
        assert!(corners < a.len() / 8, "{corners} of {} at the block's corner", a.len());
        assert_ne!(a, check_pixels(160, 90, 4));
        assert_eq!(a, check_pixels(160, 90, 3));
    }

    /// Where the halves' estimate fails — the glossy monkeys' floor, lit by rare paths both
    /// halves miss alike, measured 1.7–2.1 dB optimistic — the check must not: over three
    /// comparison seeds, against a truth of 16 times the reference's samples (its own error,
    /// 1/16 of the reference's, taken out), its mean error stays within 0.7 dB and each truth lies
    /// inside its two-standard-error interval. Measured with these seeds: check −0.08 / +1.30 /
    /// −0.83 dB (mean +0.13), halves +2.01 / +1.68 / +1.93 dB.
    #[test]
    fn the_check_sees_the_rare_path_error_the_two_halves_miss() {
        use crate::compare::effect::prepare_scene;
        use crate::compare::reference::{estimated_psnr_db, reference_seeds};
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut scene = tracer::Scene::load(&root.join("scenes/monkeys.toml")).unwrap();
        let max_bounces = prepare_scene(recon::Effect::Glossy, &mut scene, Some(2)).unwrap();
        let accel = tracer::Accel::build(&scene).unwrap();
        let (width, height, reference_spp) = (80, 44, 512);
        let tracing = Tracing {
            scene: &scene,
            accel: &accel,
            effect: recon::Effect::Glossy,
            width,
            height,
            max_bounces,
            ao_radius: 1.0,
            threads: 0,
        };
        let trace = |spp: u32, seed: u32| tracing.trace(spp, seed, false).unwrap().frame.color;
        let mean = |a: &Image, b: &Image| {
            let pixels = a.pixels.iter().zip(&b.pixels).map(|(p, q)| [0, 1, 2].map(|c| 0.5 * (p[c] + q[c])));
            Image::from_pixels(a.width, a.height, pixels.collect())
        };
        let truth = mean(&trace(8 * reference_spp, 301), &trace(8 * reference_spp, 302));
        let (mut check_error, mut halves_error) = (0.0, 0.0);
        for seed in [1u32, 4, 5] {
            let seeds = reference_seeds(seed);
            let (a, b) = (trace(reference_spp / 2, seeds[0]), trace(reference_spp / 2, seeds[1]));
            let reference = mean(&a, &b);
            let tone = ToneMap::auto(&reference);
            let measured = psnr_db(&truth, &reference, &tone).unwrap() + 10.0 * (17.0f64 / 16.0).log10();
            let spp = check_spp(reference_spp, 4);
            let check_seed = check_seed(seed, &[seed, seeds[0], seeds[1]]);
            let pixels = check_pixels(width, height, check_seed);
            let (values, seconds) = tracing.trace_pixels(spp, check_seed, &pixels, false).unwrap();
            let check = Check { pixels, values, spp, seed: check_seed, seconds, from_cache: false };
            let estimate = check.estimate(&reference, reference_spp, &tone).unwrap();
            let [low, high] = estimate.interval_db;
            assert!(
                low <= measured && measured <= high,
                "seed {seed}: truth {measured:.2} dB outside {low:.2}–{high:.2}"
            );
            check_error += (estimate.psnr_db - measured) / 3.0;
            halves_error += (estimated_psnr_db(&a, &b, &tone).unwrap() - measured) / 3.0;
        }
        assert!(check_error.abs() < 0.7, "the check is off by {check_error:.2} dB on average");
        assert!(halves_error > 1.2, "the halves were optimistic here ({halves_error:.2} dB): a test of nothing else");
    }

    /// An analytic case: a black reference and a check that is white (display 1) at half of the
    /// pixels: MSE 1/2 exactly, so PSNR 10·log10 2 plus the check's own share 10·log10(5/4)
    /// (k = 4), and an interval from the standard error of a 0/1 mean. Stiff cases: a check equal
    /// to the reference reads the ceiling with no spread; one pixel has an unknown spread.
    #[test]
    fn the_estimate_and_its_interval_in_an_analytic_case() {
        let tone = ToneMap::with_exposure(1.0).unwrap();
        let (width, height) = (32u32, 32u32);
        let reference = Image::from_pixels(width, height, vec![[0.0; 3]; 1024]);
        let pixels = check_pixels(width, height, 9);
        let n = pixels.len();
        let values = (0..n).map(|i| [(i % 2) as f32; 3]).collect();
        let check = Check { pixels: pixels.clone(), values, spp: 4 * 64, seed: 9, seconds: 1.0, from_cache: false };
        let estimate = check.estimate(&reference, 64, &tone).unwrap();
        let own = 10.0 * 1.25f64.log10();
        assert!((estimate.psnr_db - (10.0 * 2f64.log10() + own)).abs() < 1e-9, "{estimate:?}");
        let standard_error = (0.25 * n as f64 / (n as f64 - 1.0) / n as f64).sqrt();
        let at = |mse: f64| 10.0 * (1.0 / mse).log10() + own;
        let expected = [at(0.5 + 2.0 * standard_error), at(0.5 - 2.0 * standard_error)];
        for (got, want) in estimate.interval_db.iter().zip(expected) {
            assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        }
        assert!(estimate.interval_db[0] < estimate.psnr_db && estimate.psnr_db < estimate.interval_db[1]);

        let same = Check { values: vec![[0.0; 3]; n], ..check };
        let exact = same.estimate(&reference, 64, &tone).unwrap();
        assert_eq!((exact.psnr_db, exact.interval_db), (PSNR_CEILING_DB, [PSNR_CEILING_DB; 2]));
        let one =
            Check { pixels: vec![(0, 0)], values: vec![[1.0; 3]], spp: 256, seed: 9, seconds: 1.0, from_cache: false };
        let single = one.estimate(&Image::from_pixels(1, 1, vec![[0.0; 3]]), 64, &tone).unwrap();
        assert!((single.psnr_db - own).abs() < 1e-9 && single.interval_db == [0.0, PSNR_CEILING_DB], "{single:?}");
    }

    /// Stiff scales: the estimate is read in the display space of the reference's own tone map,
    /// so a scene whose radiance is 1e-6 or 1e9 times another's gets the same estimate and
    /// interval (within f32 rounding), finite.
    #[test]
    fn the_estimate_is_the_same_at_1e_minus_6_and_1e9_scale() {
        let (width, height) = (16u32, 12u32);
        let value = |i: u32, salt: u32| 0.05 + (i.wrapping_mul(2654435761).wrapping_add(salt) % 1000) as f32 / 1000.0;
        let reference: Vec<[f32; 3]> = (0..width * height).map(|i| [value(i, 1), value(i, 2), value(i, 3)]).collect();
        let pixels = check_pixels(width, height, 5);
        let values: Vec<[f32; 3]> = pixels
            .iter()
            .map(|&(x, y)| reference[(y * width + x) as usize].map(|v| v * (1.0 + 0.1 * (x as f32 - 7.5) / 8.0)))
            .collect();
        let at_scale = |scale: f32| {
            let image = Image::from_pixels(width, height, reference.iter().map(|p| p.map(|v| v * scale)).collect());
            let check = Check {
                pixels: pixels.clone(),
                values: values.iter().map(|p| p.map(|v| v * scale)).collect(),
                spp: 64,
                seed: 5,
                seconds: 1.0,
                from_cache: false,
            };
            check.estimate(&image, 16, &ToneMap::auto(&image)).unwrap()
        };
        let unit = at_scale(1.0);
        assert!(unit.psnr_db.is_finite() && unit.psnr_db < PSNR_CEILING_DB, "{unit:?}");
        for scale in [1e-6, 1e9] {
            let scaled = at_scale(scale);
            assert!((scaled.psnr_db - unit.psnr_db).abs() < 1e-3, "{scale}: {scaled:?} vs {unit:?}");
            for (a, b) in scaled.interval_db.iter().zip(unit.interval_db) {
                assert!(a.is_finite() && (a - b).abs() < 1e-3, "{scale}: {scaled:?} vs {unit:?}");
            }
        }
    }

    #[test]
    fn the_check_seed_is_none_of_the_taken_ones() {
        for seed in [0, 1, 5, u32::MAX] {
            let free = check_seed(seed, &[seed]);
            assert_ne!(free, seed);
            // Taken: whatever it would have been, and the next one: it moves past both.
            let moved = check_seed(seed, &[seed, free, free.wrapping_add(1)]);
            assert!(![seed, free, free.wrapping_add(1)].contains(&moved));
        }
        assert_eq!(check_spp(2048, 4), 8192);
        assert_eq!(parse_factor(DEFAULT_FACTOR), Ok(CheckSetting(Some(4))));
        assert_eq!(check_spp(MAX_SPP, 2), MAX_SPP);
        assert_eq!(parse_factor("off"), Ok(CheckSetting(None)));
        assert_eq!(parse_factor("1"), Ok(CheckSetting(Some(1))));
        assert_eq!(parse_factor("64"), Ok(CheckSetting(Some(64))));
        for bad in ["0", "65", "-1", "x", ""] {
            assert!(parse_factor(bad).unwrap_err().contains("`off` or a whole number in 1..=64"), "{bad}");
        }
    }
}
