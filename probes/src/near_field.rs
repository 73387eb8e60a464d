//! The near field, gathered from the senders directly (not in the paper): of each receiver's M
//! transport directions, those whose hit is nearer than a radius r_near (a share of the probes'
//! support radius, `TransportSettings::near`) are left out of α_x (`transport`) and kept here as
//! a sparse list of (sender, weight), each hit read through the relight rays' lookup
//! (`relight::read_senders`: at most 4 senders, weights summing to 1) and weighted π / M, the
//! weights of one sender summed. Each bounce a receiver's irradiance is then
//! E = α_far · λ + Σ_near w · B(sender): exact Monte Carlo over the same directions for the
//! light of the surfaces next to it (the sharp sunlit patches that order-7 probes at their
//! spacing cannot carry), the probes carrying only the smooth far field.
//!
//! Hidden receivers (no transport) get no list; a hit that reads a hidden sender beside a valid
//! one reads the valid ones only, renormalised (as `RelightTable::drop_hidden_senders`; hidden
//! senders mostly lie inside geometry, where no light reaches them). The directions, origins
//! and hits are the transport's own (the same sampler, seed and rays), so a direction is either
//! the near field's or α's, never both and never neither. Sums run in f64 in a fixed order: the
//! same list for any thread count.
//!
//! The weights are rounded to fp16 once built (stored 6 B an entry: u32 sender, fp16 weight;
//! widened to f32 in memory for the gather): each within 2⁻¹¹ of itself relatively (normal
//! fp16), or 2⁻²⁵ absolutely below fp16's normal range (2⁻¹⁴), so with non-negative radiance
//! B a receiver's near light Σ w B moves by at most 2⁻¹¹ Σ w B + 2⁻²⁵ Σ B.

use glam::Vec3;
use half::f16;
use rayon::prelude::*;
use shading::Frame;

use crate::relight::read_senders;
use crate::surfels::Surfels;
use crate::transport::TransportContext;
use crate::ProbesError;

/// Every receiver's near-field senders.
#[derive(Clone, Debug, PartialEq)]
pub struct NearField {
    /// Receiver r reads `entries[offsets[r]..offsets[r + 1]]`; one more offset than receivers.
    pub offsets: Vec<u32>,
    /// (sender, weight), senders increasing within a receiver; weight = π / M × the summed
    /// lookup weights of the sender over the receiver's near hits.
    pub entries: Vec<(u32, f32)>,
    /// Near hits over all receivers, and those that read a lookup hole (no light).
    pub hits: u64,
    pub holes: u64,
}

impl NearField {
    /// Traces the transport's directions from every receiver of `surfels` with `valid[r]`
    /// (not hidden) and keeps the hits nearer than the context's near distance. An empty list
    /// for every receiver when the near field is off.
    pub fn build(ctx: &TransportContext, surfels: &Surfels, valid: &[bool]) -> Result<NearField, ProbesError> {
        let mut field = NearField::build_f32(ctx, surfels, valid)?;
        field.entries.iter_mut().for_each(|e| e.1 = round_weight(e.1));
        Ok(field)
    }

    /// As `build` with the weights left in f32 (the test of the fp16 rounding's bound).
    pub(crate) fn build_f32(
        ctx: &TransportContext,
        surfels: &Surfels,
        valid: &[bool],
    ) -> Result<NearField, ProbesError> {
        let n = surfels.surfels.len();
        if valid.len() != n {
            return Err(ProbesError::parameter("valid", format!("{} flags for {n} receivers", valid.len())));
        }
        let Some(near) = ctx.near_distance() else {
            return Ok(NearField { offsets: vec![0; n + 1], entries: Vec::new(), hits: 0, holes: 0 });
        };
        let directions = ctx.settings.directions;
        let weight = std::f64::consts::PI / directions as f64;
        // Per receiver its (sender, weight) row, its near hits and its lookup holes.
        type Row = (Vec<(u32, f32)>, u64, u64);
        let rows: Vec<Row> = surfels
            .surfels
            .par_iter()
            .enumerate()
            .map(|(i, s)| {
                if !valid[i] {
                    return (Vec::new(), 0, 0);
                }
                let frame = Frame::new(s.normal);
                let origin = ctx.origin(s.position, s.normal);
                let mut reads: Vec<(u32, f32)> = Vec::new();
                let mut found = Vec::new();
                let (mut hits, mut holes) = (0u64, 0u64);
                for k in 0..directions {
                    let dir = ctx.direction(i as u32, &frame, k);
                    let Some(hit) = ctx.accel.intersect(origin, dir, 0.0, f32::INFINITY, 0.0) else { continue };
                    if !(hit.distance < near) {
                        continue;
                    }
                    hits += 1;
                    let ng = hit.geometric_normal.normalize_or_zero();
                    let side = if ng.dot(dir) > 0.0 { -ng } else { ng };
                    if !read_senders(surfels, origin + dir * hit.distance, side, &mut found) {
                        holes += 1;
                        continue;
                    }
                    drop_hidden(&mut found, valid);
                    reads.extend_from_slice(&found);
                }
                // One entry per sender, its weights summed in f64 in the order they were read.
                reads.sort_by_key(|&(s, _)| s);
                let mut row: Vec<(u32, f32)> = Vec::new();
                let mut k = 0;
                while k < reads.len() {
                    let s = reads[k].0;
                    let mut sum = 0.0f64;
                    while k < reads.len() && reads[k].0 == s {
                        sum += reads[k].1 as f64;
                        k += 1;
                    }
                    row.push((s, (sum * weight) as f32));
                }
                (row, hits, holes)
            })
            .collect();
        let total: usize = rows.iter().map(|r| r.0.len()).sum();
        if total > u32::MAX as usize {
            return Err(ProbesError::parameter("near-radius", format!("{total} near-field entries (over 2^32)")));
        }
        let mut field =
            NearField { offsets: Vec::with_capacity(n + 1), entries: Vec::with_capacity(total), hits: 0, holes: 0 };
        field.offsets.push(0);
        for (row, hits, holes) in rows {
            field.entries.extend(row);
            field.offsets.push(field.entries.len() as u32);
            field.hits += hits;
            field.holes += holes;
        }
        Ok(field)
    }

    /// The number of receivers.
    pub fn receivers(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Receiver `r`'s (sender, weight) entries.
    pub fn row(&self, r: usize) -> &[(u32, f32)] {
        &self.entries[self.offsets[r] as usize..self.offsets[r + 1] as usize]
    }

    /// Adds every receiver's near-field irradiance Σ w · B(sender) for sender radiance
    /// `radiance` (one RGB value per surfel) to `irradiance`.
    pub fn add_into(&self, radiance: &[Vec3], irradiance: &mut [Vec3]) {
        irradiance.par_iter_mut().enumerate().for_each(|(r, e)| {
            *e += self.row(r).iter().fold(Vec3::ZERO, |acc, &(s, w)| acc + radiance[s as usize] * w);
        });
    }

    /// Bytes as stored: the offsets (u32) and the entries (u32 sender, fp16 weight).
    pub fn bytes(&self) -> usize {
        self.offsets.len() * 4 + self.entries.len() * 6
    }

    /// Checks the list against `senders` surfels (for a list read from a cache).
    pub fn check(&self, senders: usize) -> Result<(), String> {
        if self.offsets.first() != Some(&0)
            || self.offsets.windows(2).any(|w| w[0] > w[1])
            || *self.offsets.last().unwrap_or(&0) as usize != self.entries.len()
        {
            return Err("near-field offsets out of order or range".into());
        }
        for r in 0..self.receivers() {
            let row = self.row(r);
            if row.windows(2).any(|w| w[0].0 >= w[1].0)
                || row.iter().any(|&(s, w)| s as usize >= senders || !(w.is_finite() && w >= 0.0))
            {
                return Err(format!("receiver {r}: near-field senders out of order or range, or a bad weight"));
            }
        }
        Ok(())
    }
}

/// A weight rounded to the nearest fp16 value (as stored), back in f32.
pub(crate) fn round_weight(w: f32) -> f32 {
    f16::from_f32(w).to_f32()
}

/// A hit's senders without the hidden ones (`valid` false) when it reads a valid one too, the
/// rest renormalised; unchanged when it reads only hidden ones or only valid ones.
fn drop_hidden(found: &mut Vec<(u32, f32)>, valid: &[bool]) {
    if found.iter().all(|&(s, _)| valid[s as usize]) {
        return;
    }
    let total: f32 = found.iter().filter(|&&(s, _)| valid[s as usize]).map(|&(_, w)| w).sum();
    if total > 0.0 {
        found.retain(|&(s, _)| valid[s as usize]);
        found.iter_mut().for_each(|f| f.1 /= total);
    }
}

#[cfg(test)]
mod tests;
