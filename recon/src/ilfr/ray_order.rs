//! The reconstruction rays in direction order: a Morton code of each direction's octahedral
//! map sorts them (`direction_order`), so that consecutive walks of the splat hierarchy meet
//! the same nodes in the cache; `trace_in_direction_order` traces them in runs of
//! [`RAYS_PER_JOB`] on any thread and gives the results back in the rays' own order. Used by
//! the final gather (`gather`) and by the records' gathers (`cache`).

use rayon::prelude::*;

use super::bsdf_rays::WeightedRay;
use super::disc::Ray;
use super::reconstruct::{ReconstructStats, Scratch};

/// The positions of the rays that exist among `rays`, in the order of their directions on a
/// Morton curve over the octahedral map (ties by position): consecutive walks of the splat
/// hierarchy then meet the same nodes in the cache.
pub(super) fn direction_order(rays: &[WeightedRay]) -> impl Iterator<Item = usize> {
    let mut order: Vec<u64> = rays
        .iter()
        .enumerate()
        .filter_map(|(k, w)| w.ray.map(|ray| ((direction_key(ray.direction) as u64) << 32) | k as u64))
        .collect();
    order.sort_unstable();
    order.into_iter().map(|key| key as u32 as usize)
}

/// Rays per job when a tile's rays are reconstructed: runs of this many consecutive rays in
/// direction order, so that a thread that runs out of tiles takes part of the last tiles of
/// the other (a whole tile, about 60 ms of one core on Sponza, left one thread idle at the end
/// of the gather) while each run still walks the hierarchy coherently.
const RAYS_PER_JOB: usize = 1024;

/// `trace` of every ray that exists among `rays` (`None` entries give `T::default()`), in
/// [`direction_order`], in runs of [`RAYS_PER_JOB`] rays on any thread, each run with its own
/// scratch and counts; the results come back in the rays' own order, with the counts summed in
/// run order (each result is a pure function of its ray, so neither depends on the threads).
pub(super) fn trace_in_direction_order<T: Clone + Default + Send>(
    rays: &[WeightedRay],
    trace: impl Fn(&Ray, &mut Scratch, &mut ReconstructStats) -> T + Sync,
) -> (Vec<T>, ReconstructStats) {
    let order: Vec<usize> = direction_order(rays).collect();
    let runs: Vec<(Vec<T>, ReconstructStats)> = order
        .par_chunks(RAYS_PER_JOB)
        .with_max_len(1)
        .map(|run| {
            let (mut scratch, mut stats) = (Scratch::default(), ReconstructStats::default());
            let found = run
                .iter()
                .map(|&k| rays[k].ray.map(|ray| trace(&ray, &mut scratch, &mut stats)).unwrap_or_default())
                .collect();
            (found, stats)
        })
        .collect();
    let mut out = vec![T::default(); rays.len()];
    let mut stats = ReconstructStats::default();
    for (run, (found, run_stats)) in order.chunks(RAYS_PER_JOB).zip(runs) {
        for (&k, value) in run.iter().zip(found) {
            out[k] = value;
        }
        stats.add(&run_stats);
    }
    (out, stats)
}

/// A 32-bit Morton code of a unit direction's octahedral map (16 bits per coordinate); a NaN
/// or zero direction gets the key of +z.
pub(super) fn direction_key(d: [f32; 3]) -> u32 {
    let norm = d[0].abs() + d[1].abs() + d[2].abs();
    let (mut u, mut v) = if norm > 0.0 { (d[0] / norm, d[1] / norm) } else { (0.0, 0.0) };
    if d[2] < 0.0 {
        let (pu, pv) = (u, v);
        u = (1.0 - pv.abs()) * pu.signum();
        v = (1.0 - pu.abs()) * pv.signum();
    }
    // [-1, 1] → [0, 65535]; `as` saturates and maps NaN to 0.
    let quantize = |c: f32| ((c * 0.5 + 0.5) * 65535.0) as u32;
    spread_bits(quantize(u)) | (spread_bits(quantize(v)) << 1)
}

/// The low 16 bits of `x` moved to the even bit positions.
fn spread_bits(x: u32) -> u32 {
    let mut x = x & 0xffff;
    x = (x | (x << 8)) & 0x00ff_00ff;
    x = (x | (x << 4)) & 0x0f0f_0f0f;
    x = (x | (x << 2)) & 0x3333_3333;
    (x | (x << 1)) & 0x5555_5555
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;
    use crate::vector::normalize;

    /// Every existing ray is traced once, each run of [`RAYS_PER_JOB`] rays in non-decreasing
    /// direction key, runs one after another along the keys; its result comes back at its own
    /// position, missing rays give the default, and the counts are the runs' sums — the same
    /// on one thread and on four.
    #[test]
    fn rays_are_traced_in_direction_order_and_come_back_in_their_own() {
        let mut rng = Lcg(3);
        let rays: Vec<WeightedRay> = (0..3 * RAYS_PER_JOB + 500)
            .map(|k| {
                let d = normalize([rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5]);
                let ray = (k % 7 != 0).then_some(Ray { time: 0.0, origin: [k as f32, 0.0, 0.0], direction: d });
                WeightedRay { ray, weight: [1.0; 3] }
            })
            .collect();
        let existing = rays.iter().filter(|w| w.ray.is_some()).count();
        // Each run's keys in the order traced.
        let runs = std::sync::Mutex::new(Vec::new());
        let trace = |ray: &Ray, _: &mut Scratch, stats: &mut ReconstructStats| {
            stats.rays += 1;
            stats.nodes += ray.origin[0] as u64;
            let key = direction_key(ray.direction);
            // A run starts with fresh counts; on one thread the runs come one after another.
            let mut runs = runs.lock().unwrap();
            if stats.rays == 1 {
                runs.push(Vec::new());
            }
            runs.last_mut().unwrap().push(key);
            Some(ray.origin[0])
        };
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let (out, stats) = one.install(|| trace_in_direction_order(&rays, trace));
        let runs = runs.into_inner().unwrap();
        assert_eq!(runs.len(), existing.div_ceil(RAYS_PER_JOB));
        assert!(runs.iter().all(|r| r.windows(2).all(|w| w[0] <= w[1])), "each run in key order");
        assert!(runs.windows(2).all(|w| w[0].last() <= w[1].first()), "runs follow the keys");
        for (k, (w, o)) in rays.iter().zip(&out).enumerate() {
            assert_eq!(*o, w.ray.map(|_| k as f32), "ray {k}");
        }
        let origins: u64 = rays.iter().filter_map(|w| w.ray.map(|r| r.origin[0] as u64)).sum();
        assert_eq!((stats.rays, stats.nodes), (existing as u64, origins));
        let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
        let counted = |ray: &Ray, _: &mut Scratch, stats: &mut ReconstructStats| {
            stats.rays += 1;
            Some(ray.origin[0])
        };
        let (out_four, stats_four) = four.install(|| trace_in_direction_order(&rays, counted));
        assert_eq!((out_four, stats_four.rays), (out, existing as u64));
    }

    /// The key is a Morton code of the octahedral map: the six axis directions get six keys,
    /// directions a hair apart get nearly the same map coordinates, and NaN gets +z's key.
    #[test]
    fn direction_keys_keep_near_directions_near() {
        let axes =
            [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
        let mut keys: Vec<u32> = axes.iter().map(|&d| direction_key(d)).collect();
        keys.sort();
        keys.dedup();
        assert_eq!(keys.len(), 6);
        // The even and odd bits are the two quantised map coordinates (65535 per 2 units).
        let coordinates = |key: u32| {
            let gather = |k: u32| (0..16).fold(0i32, |c, bit| c | (((k >> (2 * bit)) & 1) << bit) as i32);
            (gather(key), gather(key >> 1))
        };
        for (a, b) in [([0.3, 0.5, 0.8], [0.3001, 0.5, 0.8]), ([0.3, -0.5, -0.8], [0.3, -0.5001, -0.8])] {
            let ((ua, va), (ub, vb)) =
                (coordinates(direction_key(normalize(a))), coordinates(direction_key(normalize(b))));
            assert!((ua - ub).abs() <= 8 && (va - vb).abs() <= 8, "{a:?} {b:?}: ({ua}, {va}) vs ({ub}, {vb})");
        }
        assert_eq!(direction_key([f32::NAN; 3]), direction_key([0.0, 0.0, 1.0]));
        assert_eq!(spread_bits(0xffff), 0x5555_5555);
    }
}
