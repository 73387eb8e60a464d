//! Our bounding volume hierarchy over the splats, paper Section 2.3: "we organize the secondary
//! hit points into a … bounding volume hierarchy … During reconstruction, the hierarchy is used
//! in a standard fashion by walking the BVH and intersecting the reconstruction ray with the
//! splats in the intersected leaf nodes" (design: docs/ilfr-design.md §3 #8, §4 candidate A).
//!
//! Paper → code:
//! - the hierarchy: [`DiscBvh::build`] — binned SAH (16 bins, all three axes) over each disc's
//!   exact box ([`Disc::bounds`]), leaves of at most [`MAX_LEAF`] discs stored contiguously in
//!   leaf order, 2-wide nodes of 32 bytes. Sequential and a pure function of the input, hence the
//!   same tree for any thread count. (The paper's streaming Morton builder and motion boxes are
//!   not used; motion is slice 10 of the design.)
//! - "collect all input samples whose spatial support overlaps the reconstruction ray"
//!   (§2.3.2) and the retrace of input rays (§2.3.1): [`DiscBvh::for_each_hit`] /
//!   [`DiscBvh::collect_hits`] — *every* disc the ray hits within (t_min, t_max), not the
//!   nearest; an unordered stack walk of a 4-wide hierarchy collapsed from the binary one (same
//!   leaves and boxes; four child boxes per step in one slab test, 128-byte nodes) over 32-byte
//!   disc records in leaf order. The binary walk of before,
//!   `DiscBvh::for_each_hit_binary` (built for tests only), is kept as its oracle: the same hits bit for bit.
//! - "the bounding boxes of the BVH nodes are recomputed to accommodate the new sizes"
//!   (§2.3.1): [`DiscBvh::set_radii`] (bottom-up refit, same topology); splats trimmed wedge by
//!   wedge: [`DiscBvh::set_wedge_radii`], boxed by their wedges, a hit kept only
//!   within the radius of the wedge it lands in.
//!
//! Boxes are padded by a small scene-relative margin so that rounding in the box test can never
//! drop a disc that [`intersect`] accepts: the walk returns exactly the set a scan of all discs
//! returns (tested bit for bit).

use super::disc::{intersect, intersect_placed, wedge_at, wedge_extent, Disc, DiscHit, Ray, WEDGES};
use super::PARALLEL_ITEMS;
use crate::error::Error;
use rayon::prelude::*;

/// Discs per leaf at most.
pub const MAX_LEAF: usize = 8;
/// SAH bins per axis.
const BINS: usize = 16;
/// Relative slack of the box test and the box padding (both far above f32 rounding).
const BOX_SLACK: f32 = 1e-5;

/// A node: its box, then either two children at `first`, `first + 1` (`count` = 0) or the leaf
/// range `first .. first + count` of the discs in leaf order.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    first: u32,
    count: u32,
}

/// Children per node of the wide hierarchy that reconstruction rays walk.
pub const WIDTH: usize = 4;

/// A lane of a [`WideNode`] that holds nothing.
const EMPTY_LANE: u32 = u32::MAX;

/// A node of the wide hierarchy: the boxes of up to [`WIDTH`] children side by side, one array
/// per axis and bound (so one box test covers all four), then per lane either a wide node's
/// index (`count` = 0), a leaf range `first .. first + count` of the discs in leaf order, or
/// nothing (`count` = [`EMPTY_LANE`]). 128 bytes: two cache lines.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct WideNode {
    lo: [[f32; WIDTH]; 3],
    hi: [[f32; WIDTH]; 3],
    first: [u32; WIDTH],
    count: [u32; WIDTH],
}

/// A wide node with every lane empty: NaN boxes, which the slab test of [`boxes_overlap`] never
/// accepts (every comparison with NaN is false).
const EMPTY_WIDE: WideNode =
    WideNode { lo: [[f32::NAN; WIDTH]; 3], hi: [[f32::NAN; WIDTH]; 3], first: [0; WIDTH], count: [EMPTY_LANE; WIDTH] };

/// What the disc test reads, 32 bytes per disc in leaf order (a leaf of 8 is 4 cache lines);
/// `moving` sends the test to the full [`Disc`] (its centre depends on the ray's time);
/// `trimmed` says its wedges' radii differ (only then is a hit's wedge looked up).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
struct DiscRecord {
    centre: [f32; 3],
    radius: f32,
    normal: [f32; 3],
    moving: u16,
    trimmed: u16,
}

impl DiscRecord {
    fn of(disc: &Disc, wedges: Option<&[f32; WEDGES]>) -> DiscRecord {
        let trimmed = wedges.is_some_and(|w| w.iter().any(|&r| r != disc.radius));
        DiscRecord {
            centre: disc.centre,
            radius: disc.radius,
            normal: disc.normal,
            moving: disc.moves() as u16,
            trimmed: trimmed as u16,
        }
    }
}

/// What [`DiscBvh::nearest_hit`] makes of a hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kept {
    No,
    /// Only where no hit is kept [`Kept::Yes`].
    Fallback,
    Yes,
}

/// A hit found by the walk.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplatHit {
    /// The disc's index in the input of [`DiscBvh::build`].
    pub id: u32,
    /// Its position in leaf order ([`DiscBvh::disc_at`]).
    pub slot: u32,
    pub hit: DiscHit,
    /// The radius in force where the ray meets the disc: the disc's, or that of the wedge it
    /// meets when shrinking trimmed wedges ([`DiscBvh::set_wedge_radii`]).
    pub radius: f32,
}

/// Counts of one walk, for statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WalkCounts {
    pub nodes: u64,
    pub discs_tested: u64,
}

/// The hierarchy; it owns the discs, in leaf order.
#[derive(Clone, Debug)]
pub struct DiscBvh {
    nodes: Vec<Node>,
    discs: Vec<Disc>,
    /// Input index of each disc in leaf order.
    ids: Vec<u32>,
    /// Absolute padding of every box (scene-relative).
    pad: f32,
    /// The wide hierarchy over the same leaves (what the walk uses), rebuilt with every refit.
    wide: Vec<WideNode>,
    /// The discs' compact records, in leaf order.
    records: Vec<DiscRecord>,
    /// Per slot, the radius of each wedge ([`wedge_at`]) where shrinking trimmed wedges one by
    /// one; empty where every disc is whole (its record's radius, the largest wedge's, bounds it).
    wedges: Vec<[f32; WEDGES]>,
}

struct BuildRef {
    centre: [f32; 3],
    lo: [f32; 3],
    hi: [f32; 3],
    id: u32,
}

#[derive(Clone, Copy)]
struct Bin {
    lo: [f32; 3],
    hi: [f32; 3],
    count: u32,
}

const EMPTY_BIN: Bin = Bin { lo: [f32::INFINITY; 3], hi: [f32::NEG_INFINITY; 3], count: 0 };

fn grow(lo: &mut [f32; 3], hi: &mut [f32; 3], other_lo: [f32; 3], other_hi: [f32; 3]) {
    for axis in 0..3 {
        lo[axis] = lo[axis].min(other_lo[axis]);
        hi[axis] = hi[axis].max(other_hi[axis]);
    }
}

fn half_area(lo: [f32; 3], hi: [f32; 3]) -> f32 {
    let e = [(hi[0] - lo[0]).max(0.0), (hi[1] - lo[1]).max(0.0), (hi[2] - lo[2]).max(0.0)];
    e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
}

impl DiscBvh {
    /// Builds the hierarchy. Every centre and radius must be finite, radii ≥ 0, normals unit
    /// (make them with [`Disc::new`]); otherwise an error names the disc.
    pub fn build(discs: &[Disc]) -> Result<DiscBvh, Error> {
        let mut largest = 0.0f32;
        let bad = |message: String| Error::parameter("discs", message);
        for (i, disc) in discs.iter().enumerate() {
            if !disc.centre.iter().all(|c| c.is_finite()) {
                return Err(bad(format!("splat hierarchy: the centre of disc {i} is not finite: {:?}", disc.centre)));
            }
            if !(disc.radius.is_finite() && disc.radius >= 0.0) {
                return Err(bad(format!(
                    "splat hierarchy: the radius of disc {i} is {}, not finite and ≥ 0",
                    disc.radius
                )));
            }
            let l = crate::vector::length(disc.normal);
            if !(l.is_finite() && (l - 1.0).abs() <= 1e-3) {
                return Err(bad(format!(
                    "splat hierarchy: the normal of disc {i} is not a unit vector: {:?}",
                    disc.normal
                )));
            }
            largest = largest.max(disc.radius);
            for c in disc.centre {
                largest = largest.max(c.abs());
            }
        }
        let mut refs: Vec<BuildRef> = discs
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let (lo, hi) = d.bounds();
                BuildRef { centre: d.centre, lo, hi, id: i as u32 }
            })
            .collect();
        let nodes = if refs.is_empty() { Vec::new() } else { build_subtree(&mut refs, 0) };
        let mut bvh = DiscBvh {
            nodes,
            discs: refs.iter().map(|r| discs[r.id as usize]).collect(),
            ids: refs.iter().map(|r| r.id).collect(),
            pad: BOX_SLACK * largest,
            wide: Vec::new(),
            records: Vec::new(),
            wedges: Vec::new(),
        };
        bvh.refit();
        Ok(bvh)
    }

    pub fn len(&self) -> usize {
        self.discs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.discs.is_empty()
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Bytes held: binary and wide nodes, discs, ids and the compact records.
    pub fn memory_bytes(&self) -> usize {
        use std::mem::size_of;
        self.nodes.len() * size_of::<Node>()
            + self.wide.len() * size_of::<WideNode>()
            + self.discs.len() * (size_of::<Disc>() + size_of::<u32>() + size_of::<DiscRecord>())
            + self.wedges.len() * size_of::<[f32; WEDGES]>()
    }

    /// The disc at `slot` in leaf order, and its input index.
    pub fn disc_at(&self, slot: u32) -> (&Disc, u32) {
        (&self.discs[slot as usize], self.ids[slot as usize])
    }

    /// The disc at `slot` in leaf order placed at `time`: (centre then, unit normal), read from
    /// the compact record the walk has just tested (the full disc only if it moves). Its radius
    /// where a ray meets it is the hit's ([`SplatHit::radius`]).
    #[inline]
    pub fn placed_at(&self, slot: u32, time: f32) -> ([f32; 3], [f32; 3]) {
        let record = &self.records[slot as usize];
        let centre = if record.moving != 0 { self.discs[slot as usize].centre_at(time) } else { record.centre };
        (centre, record.normal)
    }

    /// The radius in force where `ray` meets the disc at `slot` (`hit`, found with the disc's
    /// whole radius): the disc's, or its wedge's when wedges are trimmed; the ray misses the
    /// disc unless `hit.spatial` is below it.
    #[inline]
    fn radius_at_hit(&self, slot: u32, ray: &Ray, hit: &DiscHit) -> f32 {
        let record = &self.records[slot as usize];
        if record.trimmed == 0 {
            return record.radius;
        }
        let (centre, normal) = self.placed_at(slot, ray.time);
        self.wedges[slot as usize][wedge_at(centre, normal, ray, hit.t)]
    }

    /// The discs in leaf order with their input indices.
    pub fn discs(&self) -> impl Iterator<Item = (u32, &Disc)> {
        self.ids.iter().copied().zip(self.discs.iter())
    }

    /// Radii by input index.
    pub fn radii(&self) -> Vec<f32> {
        let mut radius = vec![0.0; self.discs.len()];
        for (id, disc) in self.discs() {
            radius[id as usize] = disc.radius;
        }
        radius
    }

    /// Replaces every radius (by input index; finite, ≥ 0) and refits the boxes bottom-up.
    pub fn set_radii(&mut self, radius_by_id: &[f32]) -> Result<(), Error> {
        if radius_by_id.len() != self.discs.len() {
            let message = format!("splat hierarchy: {} radii for {} discs", radius_by_id.len(), self.discs.len());
            return Err(Error::size_mismatch("radii and discs", message));
        }
        if let Some(i) = radius_by_id.iter().position(|r| !(r.is_finite() && *r >= 0.0)) {
            let message = format!("splat hierarchy: radius {i} is {}, not finite and ≥ 0", radius_by_id[i]);
            return Err(Error::parameter("radius_by_id", message));
        }
        for (slot, disc) in self.discs.iter_mut().enumerate() {
            disc.radius = radius_by_id[self.ids[slot] as usize];
        }
        self.wedges.clear();
        self.refit();
        Ok(())
    }

    /// Replaces every disc by one whose wedges ([`wedge_at`]) have their own radii (by input
    /// index; finite, ≥ 0): a ray meets it iff it meets the disc within its wedge's radius. The
    /// disc's radius becomes the largest wedge's (its box), and the boxes are refitted.
    pub fn set_wedge_radii(&mut self, wedge_radii_by_id: &[[f32; WEDGES]]) -> Result<(), Error> {
        if wedge_radii_by_id.len() != self.discs.len() {
            let message =
                format!("splat hierarchy: {} wedge radii for {} discs", wedge_radii_by_id.len(), self.discs.len());
            return Err(Error::size_mismatch("wedge radii and discs", message));
        }
        if let Some(i) = wedge_radii_by_id.iter().position(|w| !w.iter().all(|r| r.is_finite() && *r >= 0.0)) {
            let message =
                format!("splat hierarchy: wedge radii {i} are {:?}, not all finite and ≥ 0", wedge_radii_by_id[i]);
            return Err(Error::parameter("wedge_radii_by_id", message));
        }
        self.wedges = self.ids.iter().map(|&id| wedge_radii_by_id[id as usize]).collect();
        for (disc, wedges) in self.discs.iter_mut().zip(&self.wedges) {
            disc.radius = wedges.iter().copied().fold(0.0, f32::max);
        }
        self.refit();
        Ok(())
    }

    /// By input index, the radius of each wedge ([`wedge_at`]): the disc's radius in every wedge
    /// of a whole disc.
    pub fn wedge_radii(&self) -> Vec<[f32; WEDGES]> {
        let mut wedges = vec![[0.0; WEDGES]; self.discs.len()];
        for (slot, (id, disc)) in self.discs().enumerate() {
            wedges[id as usize] = self.wedges.get(slot).copied().unwrap_or([disc.radius; WEDGES]);
        }
        wedges
    }

    /// By input index, the radius of the whole disc of the same area: the disc's radius, or the
    /// root mean square of its wedges' radii where wedges are trimmed.
    pub fn area_radii(&self) -> Vec<f32> {
        if self.wedges.is_empty() {
            return self.radii();
        }
        let mut radius = vec![0.0; self.discs.len()];
        for (slot, &id) in self.ids.iter().enumerate() {
            let wedges = &self.wedges[slot];
            radius[id as usize] = (wedges.iter().map(|r| r * r).sum::<f32>() / WEDGES as f32).sqrt();
        }
        radius
    }

    /// Recomputes every box from the discs: children come after their parent, so a reverse
    /// sweep sees children first.
    fn refit(&mut self) {
        let pad = self.pad;
        // The discs' boxes (wedge extents on trimmed discs: the costly part) on every thread.
        let disc_boxes: Vec<([f32; 3], [f32; 3])> = (0..self.discs.len() as u32)
            .into_par_iter()
            .with_max_len(PARALLEL_ITEMS)
            .map(|slot| self.disc_bounds(slot))
            .collect();
        for index in (0..self.nodes.len()).rev() {
            let Node { first, count, .. } = self.nodes[index];
            let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            if count > 0 {
                for &(dlo, dhi) in &disc_boxes[first as usize..(first + count) as usize] {
                    grow(&mut lo, &mut hi, dlo, dhi);
                }
                for axis in 0..3 {
                    lo[axis] -= pad + BOX_SLACK * lo[axis].abs();
                    hi[axis] += pad + BOX_SLACK * hi[axis].abs();
                }
            } else {
                for child in [first as usize, first as usize + 1] {
                    grow(&mut lo, &mut hi, self.nodes[child].lo, self.nodes[child].hi);
                }
            }
            self.nodes[index].lo = lo;
            self.nodes[index].hi = hi;
        }
        self.collapse();
    }

    /// The box of the disc at `slot`: [`Disc::bounds`], or where its wedges are trimmed the box
    /// of its wedges ([`wedge_extent`]) swept along its motion.
    fn disc_bounds(&self, slot: u32) -> ([f32; 3], [f32; 3]) {
        let disc = &self.discs[slot as usize];
        let Some(wedges) = self.wedges.get(slot as usize) else {
            return disc.bounds();
        };
        let (extent_lo, extent_hi) = wedge_extent(disc.normal, wedges);
        let (start, end) = (disc.centre_at(0.0), disc.centre_at(1.0));
        let lo = [0, 1, 2].map(|a| start[a].min(end[a]) + extent_lo[a]);
        let hi = [0, 1, 2].map(|a| start[a].max(end[a]) + extent_hi[a]);
        (lo, hi)
    }

    /// Rebuilds the wide hierarchy from the binary one (same leaves, same boxes): every wide
    /// node takes up to [`WIDTH`] descendants of a binary node, opening the inner one with the
    /// largest box area first (ties by the lower index), so the collapse is a pure function of
    /// the binary tree. Also refreshes the compact disc records.
    fn collapse(&mut self) {
        self.records = (self.discs.par_iter().enumerate().with_max_len(PARALLEL_ITEMS))
            .map(|(slot, disc)| DiscRecord::of(disc, self.wedges.get(slot)))
            .collect();
        self.wide.clear();
        if self.nodes.is_empty() {
            return;
        }
        self.wide.push(EMPTY_WIDE);
        // (wide node to fill, binary node whose descendants fill it)
        let mut work = vec![(0usize, 0usize)];
        let mut lanes: Vec<usize> = Vec::with_capacity(WIDTH);
        while let Some((target, root)) = work.pop() {
            lanes.clear();
            lanes.push(root);
            loop {
                let open = lanes
                    .iter()
                    .enumerate()
                    .filter(|(_, &b)| self.nodes[b].count == 0)
                    .map(|(k, &b)| (half_area(self.nodes[b].lo, self.nodes[b].hi), b, k))
                    .fold(None, |best: Option<(f32, usize, usize)>, c| match best {
                        Some(b) if b.0 > c.0 || (b.0 == c.0 && b.1 < c.1) => Some(b),
                        _ => Some(c),
                    });
                let Some((_, b, k)) = open else { break };
                // Opening replaces one lane by two: only while it fits (the root always opens).
                if lanes.len() + 1 > WIDTH && lanes.len() > 1 {
                    break;
                }
                let first = self.nodes[b].first as usize;
                lanes[k] = first;
                lanes.insert(k + 1, first + 1);
                if lanes.len() == WIDTH {
                    break;
                }
            }
            let mut node = EMPTY_WIDE;
            for (lane, &b) in lanes.iter().enumerate() {
                let binary = self.nodes[b];
                for axis in 0..3 {
                    node.lo[axis][lane] = binary.lo[axis];
                    node.hi[axis][lane] = binary.hi[axis];
                }
                if binary.count > 0 {
                    (node.first[lane], node.count[lane]) = (binary.first, binary.count);
                } else {
                    let child = self.wide.len();
                    self.wide.push(EMPTY_WIDE);
                    (node.first[lane], node.count[lane]) = (child as u32, 0);
                    work.push((child, b));
                }
            }
            self.wide[target] = node;
        }
    }

    /// Calls `visit` for every disc the ray hits with t in (t_min, t_max), in walk order (the
    /// set is that of `Self::for_each_hit_binary` and of a scan of every disc, tested).
    /// `stack` is scratch, reused between calls. Walks the wide hierarchy: four child boxes per
    /// step in one slab test, leaves' discs from their compact records.
    pub fn for_each_hit(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        stack: &mut Vec<u32>,
        mut visit: impl FnMut(SplatHit),
    ) -> WalkCounts {
        let mut counts = WalkCounts::default();
        if self.wide.is_empty() {
            return counts;
        }
        let inverse = inverse_direction(ray.direction);
        stack.clear();
        stack.push(0);
        while let Some(index) = stack.pop() {
            let node = &self.wide[index as usize];
            counts.nodes += 1;
            // Empty lanes have NaN boxes: never in the mask.
            let mut overlaps = boxes_overlap(node, ray.origin, inverse, t_min, t_max);
            while overlaps != 0 {
                let lane = overlaps.trailing_zeros() as usize;
                overlaps &= overlaps - 1;
                let (first, count) = (node.first[lane], node.count[lane]);
                if count == 0 {
                    stack.push(first);
                    continue;
                }
                counts.discs_tested += count as u64;
                for slot in first..first + count {
                    let record = &self.records[slot as usize];
                    let hit = if record.moving != 0 {
                        intersect(&self.discs[slot as usize], ray, t_min, t_max)
                    } else {
                        intersect_placed(record.centre, record.normal, record.radius, ray, t_min, t_max)
                    };
                    if let Some(hit) = hit {
                        let radius = self.radius_at_hit(slot, ray, &hit);
                        if hit.spatial < radius {
                            visit(SplatHit { id: self.ids[slot as usize], slot, hit, radius });
                        }
                    }
                }
            }
        }
        counts
    }

    /// The walk of the binary hierarchy, one box per step (the walk before the wide one, kept as
    /// its test oracle, built for tests only): the same hits as [`Self::for_each_hit`].
    #[cfg(test)]
    pub fn for_each_hit_binary(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        stack: &mut Vec<u32>,
        mut visit: impl FnMut(SplatHit),
    ) -> WalkCounts {
        let mut counts = WalkCounts::default();
        if self.nodes.is_empty() {
            return counts;
        }
        let inverse = inverse_direction(ray.direction);
        stack.clear();
        stack.push(0);
        while let Some(index) = stack.pop() {
            let node = &self.nodes[index as usize];
            counts.nodes += 1;
            if !box_overlaps(node, ray.origin, inverse, t_min, t_max) {
                continue;
            }
            if node.count == 0 {
                stack.push(node.first + 1);
                stack.push(node.first);
                continue;
            }
            counts.discs_tested += node.count as u64;
            for slot in node.first..node.first + node.count {
                let disc = &self.discs[slot as usize];
                if let Some(hit) = intersect(disc, ray, t_min, t_max) {
                    let radius = self.radius_at_hit(slot, ray, &hit);
                    if hit.spatial < radius {
                        visit(SplatHit { id: self.ids[slot as usize], slot, hit, radius });
                    }
                }
            }
        }
        counts
    }

    /// Among the hits of [`Self::for_each_hit`] in (t_min, t_max), the one with the least
    /// (t, slot) that `keep` calls [`Kept::Yes`], or where there is none the least that it calls
    /// [`Kept::Fallback`]; with `first`, any one hit that it keeps either way (the walk stops
    /// there). An ordered walk (a node's lanes nearest entry first) whose window closes at the
    /// best [`Kept::Yes`] hit so far, so that it skips the nodes behind it. `stack` is scratch.
    pub fn nearest_hit(
        &self,
        ray: &Ray,
        (t_min, t_max): (f32, f32),
        first: bool,
        stack: &mut Vec<(u32, f32)>,
        keep: impl Fn(&SplatHit) -> Kept,
    ) -> (Option<SplatHit>, WalkCounts) {
        let mut counts = WalkCounts::default();
        let (mut best, mut fallback): (Option<SplatHit>, Option<SplatHit>) = (None, None);
        if self.wide.is_empty() {
            return (None, counts);
        }
        let inverse = inverse_direction(ray.direction);
        let nearer =
            |hit: &SplatHit, than: &Option<SplatHit>| than.map_or(true, |b| (hit.hit.t, hit.slot) < (b.hit.t, b.slot));
        // The window's far end: the best hit's t, widened by one ulp so that a hit at the same
        // t with a lower slot (coincident discs) is still tested.
        let mut far = t_max;
        stack.clear();
        stack.push((0, t_min));
        while let Some((index, entry)) = stack.pop() {
            if entry > far + BOX_SLACK * (far.abs() + entry.abs()) {
                continue;
            }
            let node = &self.wide[index as usize];
            counts.nodes += 1;
            let (mut overlaps, near) = boxes_entry(node, ray.origin, inverse, t_min, far);
            // Child nodes pushed farthest first, so that the nearest is walked next.
            let mut children: [(f32, u32); WIDTH] = [(0.0, 0); WIDTH];
            let mut child_count = 0;
            while overlaps != 0 {
                let lane = overlaps.trailing_zeros() as usize;
                overlaps &= overlaps - 1;
                let (start, count) = (node.first[lane], node.count[lane]);
                if count == 0 {
                    children[child_count] = (near[lane], start);
                    child_count += 1;
                    continue;
                }
                counts.discs_tested += count as u64;
                for slot in start..start + count {
                    let record = &self.records[slot as usize];
                    let hit = if record.moving != 0 {
                        intersect(&self.discs[slot as usize], ray, t_min, far)
                    } else {
                        intersect_placed(record.centre, record.normal, record.radius, ray, t_min, far)
                    };
                    let Some(hit) = hit else { continue };
                    let radius = self.radius_at_hit(slot, ray, &hit);
                    if hit.spatial >= radius {
                        continue;
                    }
                    let candidate = SplatHit { id: self.ids[slot as usize], slot, hit, radius };
                    match keep(&candidate) {
                        Kept::No => {}
                        _ if first => return (Some(candidate), counts),
                        Kept::Yes => {
                            if nearer(&candidate, &best) {
                                best = Some(candidate);
                                far = next_up(hit.t);
                            }
                        }
                        Kept::Fallback => {
                            if nearer(&candidate, &fallback) {
                                fallback = Some(candidate);
                            }
                        }
                    }
                }
            }
            let children = &mut children[..child_count];
            children.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(b.1.cmp(&a.1)));
            for &(entry, child) in children.iter() {
                stack.push((child, entry));
            }
        }
        (best.or(fallback), counts)
    }

    /// Every hit of the ray with t in (t_min, t_max), appended to `out` (cleared first).
    pub fn collect_hits(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        stack: &mut Vec<u32>,
        out: &mut Vec<SplatHit>,
    ) -> WalkCounts {
        out.clear();
        self.for_each_hit(ray, t_min, t_max, stack, |hit| out.push(hit))
    }

    /// The same set by testing every disc: O(n) per ray, for tests and measurements.
    pub fn collect_hits_brute_force(&self, ray: &Ray, t_min: f32, t_max: f32, out: &mut Vec<SplatHit>) {
        out.clear();
        for (slot, disc) in self.discs.iter().enumerate() {
            if let Some(hit) = intersect(disc, ray, t_min, t_max) {
                let radius = self.radius_at_hit(slot as u32, ray, &hit);
                if hit.spatial < radius {
                    out.push(SplatHit { id: self.ids[slot], slot: slot as u32, hit, radius });
                }
            }
        }
    }
}

/// 1/d per axis, with |d| raised to 1e-20 (keeping its sign) so that the slabs stay finite.
#[inline]
fn inverse_direction(direction: [f32; 3]) -> [f32; 3] {
    direction.map(|d| {
        let d = if d.abs() > 1e-20 { d } else { 1e-20f32.copysign(d) };
        1.0 / d
    })
}

/// [`box_overlaps`] for the four boxes of a wide node at once, as a bit mask of the lanes (the
/// same arithmetic lane-wise, written with plain comparisons so that it compiles to packed SSE
/// min/max, and so that a NaN box never overlaps).
#[inline(always)]
fn boxes_overlap(node: &WideNode, origin: [f32; 3], inverse: [f32; 3], t_min: f32, t_max: f32) -> u32 {
    boxes_entry(node, origin, inverse, t_min, t_max).0
}

/// [`boxes_overlap`] with each lane's entry distance (the slab interval's near end, at least
/// `t_min`), for the ordered walk of [`DiscBvh::nearest_hit`].
#[inline(always)]
fn boxes_entry(node: &WideNode, origin: [f32; 3], inverse: [f32; 3], t_min: f32, t_max: f32) -> (u32, [f32; WIDTH]) {
    let mut near = [t_min; WIDTH];
    let mut far = [t_max; WIDTH];
    for axis in 0..3 {
        for lane in 0..WIDTH {
            let a = (node.lo[axis][lane] - origin[axis]) * inverse[axis];
            let b = (node.hi[axis][lane] - origin[axis]) * inverse[axis];
            let (entry, exit) = if a < b { (a, b) } else { (b, a) };
            near[lane] = if near[lane] > entry { near[lane] } else { entry };
            far[lane] = if far[lane] < exit { far[lane] } else { exit };
        }
    }
    let mut mask = 0;
    for lane in 0..WIDTH {
        let overlaps = near[lane] <= far[lane] + BOX_SLACK * (far[lane].abs() + near[lane].abs());
        mask |= (overlaps as u32) << lane;
    }
    (mask, near)
}

/// The least f32 above `t` (finite `t`).
#[inline]
fn next_up(t: f32) -> f32 {
    if t == 0.0 {
        f32::from_bits(1)
    } else if t > 0.0 {
        f32::from_bits(t.to_bits() + 1)
    } else {
        f32::from_bits(t.to_bits() - 1)
    }
}

/// The slab test against the ray's (t_min, t_max), with a relative slack so that it is
/// conservative with respect to [`intersect`]; NaN-free for any finite box (|1/d| ≤ 1e20). The
/// binary walk's (the oracle) test; the wide walk tests four boxes at once.
#[cfg(test)]
#[inline]
fn box_overlaps(node: &Node, origin: [f32; 3], inverse: [f32; 3], t_min: f32, t_max: f32) -> bool {
    let mut near = t_min;
    let mut far = t_max;
    for axis in 0..3 {
        let a = (node.lo[axis] - origin[axis]) * inverse[axis];
        let b = (node.hi[axis] - origin[axis]) * inverse[axis];
        near = near.max(a.min(b));
        far = far.min(a.max(b));
    }
    near <= far + BOX_SLACK * (far.abs() + near.abs())
}

/// Subtrees over at least this many discs split their two halves on two threads.
const PARALLEL_BUILD_MIN: usize = 4096;

/// The nodes of the subtree over `refs`, whose first disc goes to slot `start`: its root, then
/// the descendants in the order the sequential build ([`build_sequential`]) allocates them — a
/// split node's two children as a pair, depth first, the left subtree's before the right's —
/// with inner nodes' `first` counted from the root's position. Large subtrees build their two
/// halves in parallel and are joined by shifting those indices, so the layout is the
/// sequential build's, node for node, for any number of threads.
fn build_subtree(refs: &mut [BuildRef], start: usize) -> Vec<Node> {
    if refs.len() < PARALLEL_BUILD_MIN {
        return build_sequential(refs, start);
    }
    let Some(mid) = split(refs) else {
        return vec![Node { lo: [0.0; 3], hi: [0.0; 3], first: start as u32, count: refs.len() as u32 }];
    };
    let (left_refs, right_refs) = refs.split_at_mut(mid);
    let (left, right) = rayon::join(|| build_subtree(left_refs, start), || build_subtree(right_refs, start + mid));
    // Positions: root 0, the pair 1 and 2, left[1..] from 3, right[1..] after them.
    let shift = |node: &Node, by: usize| {
        if node.count == 0 {
            Node { first: node.first + by as u32, ..*node }
        } else {
            *node
        }
    };
    let right_shift = left.len() + 1;
    let mut nodes = Vec::with_capacity(1 + left.len() + right.len());
    nodes.push(Node { lo: [0.0; 3], hi: [0.0; 3], first: 1, count: 0 });
    nodes.push(shift(&left[0], 2));
    nodes.push(shift(&right[0], right_shift));
    nodes.extend(left[1..].iter().map(|n| shift(n, 2)));
    nodes.extend(right[1..].iter().map(|n| shift(n, right_shift)));
    nodes
}

/// The subtree over `refs` (first disc at slot `start`) on one thread, root at index 0: a stack
/// of nodes still to split, each split appending its children as a pair.
fn build_sequential(refs: &mut [BuildRef], start: usize) -> Vec<Node> {
    let mut nodes = Vec::with_capacity(refs.len() / 2 + 1);
    nodes.push(Node { lo: [0.0; 3], hi: [0.0; 3], first: 0, count: 0 });
    // (node, start, end) still to split.
    let mut work = vec![(0usize, 0usize, refs.len())];
    while let Some((node, begin, end)) = work.pop() {
        match split(&mut refs[begin..end]) {
            None => {
                let first = (start + begin) as u32;
                nodes[node] = Node { lo: [0.0; 3], hi: [0.0; 3], first, count: (end - begin) as u32 }
            }
            Some(mid) => {
                let first = nodes.len();
                nodes[node] = Node { lo: [0.0; 3], hi: [0.0; 3], first: first as u32, count: 0 };
                nodes.push(nodes[node]);
                nodes.push(nodes[node]);
                work.push((first + 1, begin + mid, end));
                work.push((first, begin, begin + mid));
            }
        }
    }
    nodes
}

/// Chooses a split of `refs` by binned SAH and partitions it; `None` makes a leaf.
fn split(refs: &mut [BuildRef]) -> Option<usize> {
    let n = refs.len();
    if n <= 1 {
        return None;
    }
    let (mut box_lo, mut box_hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    let (mut centre_lo, mut centre_hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for r in refs.iter() {
        grow(&mut box_lo, &mut box_hi, r.lo, r.hi);
        grow(&mut centre_lo, &mut centre_hi, r.centre, r.centre);
    }
    let parent_area = half_area(box_lo, box_hi);
    // Cost in units of one disc test; a node visit costs about as much.
    let leaf_cost = n as f32;
    let mut best: Option<(f32, usize, usize)> = None; // (cost, axis, bins on the left)
    for axis in 0..3 {
        let extent = centre_hi[axis] - centre_lo[axis];
        let spread = extent > 0.0;
        if !spread {
            continue;
        }
        let scale = BINS as f32 / extent;
        let bin_of = |c: f32| (((c - centre_lo[axis]) * scale) as usize).min(BINS - 1);
        let mut bins = [EMPTY_BIN; BINS];
        for r in refs.iter() {
            let bin = &mut bins[bin_of(r.centre[axis])];
            grow(&mut bin.lo, &mut bin.hi, r.lo, r.hi);
            bin.count += 1;
        }
        // Sweep from the right for the right-side areas, then from the left.
        let mut right_area = [0.0f32; BINS];
        let (mut lo, mut hi, mut count) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3], 0u32);
        for b in (1..BINS).rev() {
            grow(&mut lo, &mut hi, bins[b].lo, bins[b].hi);
            count += bins[b].count;
            right_area[b] = half_area(lo, hi) * count as f32;
        }
        let (mut lo, mut hi, mut count) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3], 0u32);
        for b in 0..BINS - 1 {
            grow(&mut lo, &mut hi, bins[b].lo, bins[b].hi);
            count += bins[b].count;
            if count == 0 || count as usize == n {
                continue;
            }
            let cost =
                1.0 + (half_area(lo, hi) * count as f32 + right_area[b + 1]) / parent_area.max(f32::MIN_POSITIVE);
            if best.map_or(true, |(c, _, _)| cost < c) {
                best = Some((cost, axis, b + 1));
            }
        }
    }
    match best {
        Some((cost, axis, left_bins)) if cost < leaf_cost || n > MAX_LEAF => {
            let extent = centre_hi[axis] - centre_lo[axis];
            let scale = BINS as f32 / extent;
            let lo = centre_lo[axis];
            let mid = partition(refs, |r| ((((r.centre[axis] - lo) * scale) as usize).min(BINS - 1)) < left_bins);
            Some(mid)
        }
        _ if n > MAX_LEAF => {
            // All centres coincide (or a NaN-free degenerate spread): split by position in the
            // current order, which is deterministic.
            Some(n / 2)
        }
        _ => None,
    }
}

/// In-place partition: the elements satisfying `left` first; returns their count. A pure
/// function of the slice's order, so the build is deterministic.
fn partition(refs: &mut [BuildRef], left: impl Fn(&BuildRef) -> bool) -> usize {
    let mut write = 0;
    for read in 0..refs.len() {
        if left(&refs[read]) {
            refs.swap(write, read);
            write += 1;
        }
    }
    write
}

#[cfg(test)]
mod tests;
