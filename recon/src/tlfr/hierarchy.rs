//! The hierarchy of the reconstruction queries (paper Section 4, "Acceleration"): a bounding
//! volume hierarchy over the samples whose nodes bound their samples' reprojected screen
//! positions by planes linear in (t, u) and (t, v) (`bounds`), with leaves of at most
//! `MAX_LEAF_SAMPLES` samples of one surface each.
//!
//! Construction ("a push-pull procedure": leaves top-down, then the BVH bottom-up):
//! 1. every sample's entries (`bounds::sample_segments`): one with the bounds over its whole
//!    span, or, for a sample whose depth changes enough that one plane pair bounds it loosely
//!    (it nears the camera plane), up to `bounds::MAX_SEGMENTS` time segments with half-open
//!    query times, each bounded on its own and entered as its own entry; a sample that is never
//!    in front of the camera while potentially near the image is left out (`unplaced`);
//! 2. the samples reprojected to the centre of the (u, v, t) cube (u = v = 0 and t = 0.5, or
//!    the nearest time of the sample's span, which differs for samples passing the camera
//!    plane) and bucketed into square bins of about
//!    `SAMPLES_PER_BIN` samples on average (at most 4096 a side; positions off the image are
//!    clamped to the border bins); bins in Morton order, so every quadtree node is a contiguous
//!    range of the samples sorted by bin;
//! 3. the quadtree of the bins: a node is a leaf when it holds at most `MAX_LEAF_SAMPLES`
//!    samples or is a single bin ("the subdivision stops whenever there are fewer than a
//!    specified number of samples (we use 32) inside the node, or the node consists of only one
//!    bin");
//! 4. a quadtree leaf's entries (whole samples and time segments apart) sorted front to back (depth at the centre time; the authors'
//!    code sorts by centre time first, which only differs for samples passing the camera plane,
//!    and those are told apart by the crossing test anyway) are cut into
//!    runs: a sample opens a new run when it fails SAMESURFACE against any member of the current
//!    run (`same_surface::same_surface_at` with the build tolerance of 2 px, at the corners
//!    u, v = ±1 and t at the ends of the time span both samples share: the whole domain for
//!    samples visible throughout; a pair never visible together counts as crossing), or when the
//!    run is full. Each run is a leaf of the BVH ("we split leaf nodes that contain samples from
//!    more than one surface");
//! 5. the BVH bottom-up along the quadtree (design §3 row 6, after the authors' code): each
//!    quadtree node gathers the BVH nodes its children left (at a quadtree leaf, its runs) and
//!    merges the pair whose merge adds the least cost until at most `FRONTIER` remain (one at
//!    the root); the cost of a node is (width + 1 px)·(height + 1 px)·samples, its extent over its
//!    span and the whole lens. This is the agglomerative clustering of Walter et al. 2008 the
//!    paper cites, restricted to the quadtree's neighbourhoods so that it stays cheap.
//!
//! The nodes are stored depth first, each inner node followed by its first child, and each
//! inner node knows where its subtree ends, so a query walks the tree without a stack. A node is
//! 64 bytes (one cache line): four planes, the time span and two indices. The entries are
//! renumbered so that the leaves' entries follow each other in that same depth-first order,
//! the whole samples' leaves first and then the time segments' (`Hierarchy::build` returns the
//! map from entries to samples; `reorder` applies it to any array aligned with the samples, a
//! segmented sample's record repeated once per segment). Only the time segments store their
//! query times (8 bytes each); `Hierarchy::entry_takes` tells a query which entry of a sample
//! takes its t̂, so a sample is never collected twice.
//!
//! Known limit: a plane linear in t and u bounds a trajectory that nears the camera plane
//! loosely: x ∝ 1/z'(t), and the lens term û·C(z'(t)) is bilinear in (û, t), which a plane
//! cannot bound closer than the change of C over the span (Eq. 4: C ∝ 1/z'). Time segments
//! shrink both per segment, but not to a pixel with a handful of segments: on the bench scene
//! with a card flying through the camera (docs/history/tlfr.md) 8 segments cut the leaves per location
//! from 517 to 428 at 3.7× the memory, with about the same locations per CPU second. Queries
//! stay exact either way (the tests check that against a scan).
//!
//! Everything is deterministic: per-sample work runs in parallel but lands in sample order,
//! quadtree leaves are processed in parallel and collected in Morton order, and every sort and
//! every greedy choice breaks ties by index.

use rayon::prelude::*;

use super::bounds::{sample_segments, Bounds, ScreenArea, Window};
use super::lens::LensModel;
use super::reprojection::{reproject, LensTime, LensTimeSample};
use super::same_surface::{same_surface_at, BUILD_CROSSING_TOLERANCE_PX};

/// Samples per leaf at most (paper: 32).
pub const MAX_LEAF_SAMPLES: usize = 32;
/// Average samples per bin of the quadtree's bin grid.
pub const SAMPLES_PER_BIN: f32 = 8.0;
/// Bins per side at most.
pub const MAX_BINS_PER_SIDE: u32 = 4096;
/// BVH nodes each quadtree node hands up to its parent.
pub const FRONTIER: usize = 4;

/// A node: bounds, and either a leaf's sample range or where the subtree ends.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Node {
    pub bounds: Bounds,
    /// A leaf: its first sample. An inner node: the index just past its subtree.
    first_or_end: u32,
    /// A leaf: its number of samples (≥ 1). An inner node: 0.
    count: u32,
}

impl Node {
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }

    /// The leaf's samples (indices into the reordered samples); empty for an inner node.
    pub fn samples(&self) -> std::ops::Range<usize> {
        if self.is_leaf() {
            self.first_or_end as usize..(self.first_or_end + self.count) as usize
        } else {
            0..0
        }
    }
}

/// The hierarchy over a set of samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Hierarchy {
    /// Depth first; the root is node 0.
    nodes: Vec<Node>,
    leaves: usize,
    /// Entries below this index are whole samples (one entry each, any query time); the
    /// entries from it on are time segments, entry k taking the query times
    /// `segment_times[k − whole_entries]` (half-open).
    whole_entries: usize,
    segment_times: Vec<[f32; 2]>,
    /// Samples left out (never in front of the camera near the image).
    pub unplaced: usize,
}

/// A node under construction.
#[derive(Clone, Copy)]
struct BuildNode {
    bounds: Bounds,
    samples: u32,
    /// Children of an inner node, or the leaf's entry range.
    a: u32,
    b: u32,
    leaf: bool,
    /// A leaf of time segments.
    segmented: bool,
}

/// The cost of a node in the greedy merging, from its extent box (`Bounds::extent_box`).
fn box_cost(extent: &[f64; 4], samples: u32) -> f64 {
    let (w, h) = ((extent[1] - extent[0]).max(0.0), (extent[3] - extent[2]).max(0.0));
    (w + 1.0) * (h + 1.0) * samples as f64
}

/// Interleaves the bits of x and y (x in the even bits).
fn morton(x: u32, y: u32) -> u64 {
    let spread = |v: u32| {
        let mut v = v as u64 & 0xffff_ffff;
        v = (v | (v << 16)) & 0x0000_ffff_0000_ffff;
        v = (v | (v << 8)) & 0x00ff_00ff_00ff_00ff;
        v = (v | (v << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
        v = (v | (v << 2)) & 0x3333_3333_3333_3333;
        (v | (v << 1)) & 0x5555_5555_5555_5555
    };
    spread(x) | (spread(y) << 1)
}

/// Samples per chunk of the entries' parallel construction.
const ENTRY_CHUNK: usize = 4096;

/// An entry (a sample, or one time segment of it).
#[derive(Clone, Copy)]
struct Placed {
    /// Its depth at the time it is binned at.
    depth: f32,
    /// The sample.
    index: u32,
    bounds: Bounds,
    /// The query times the entry takes (`bounds::Segment::times`).
    times: [f32; 2],
}

/// What the entries are sorted by (bin, sample, time), and where the entry is.
#[derive(Clone, Copy)]
struct SortKey {
    code: u64,
    index: u32,
    time: f32,
    chunk: u32,
    offset: u32,
}

impl Placed {
    /// One of several time segments of its sample.
    fn segmented(&self) -> bool {
        self.times != [f32::NEG_INFINITY, f32::INFINITY]
    }
}

impl Hierarchy {
    /// Builds the hierarchy over `samples` for lens model `lens`, near limit `z_near` and the
    /// image area `area`. Returns it with the map `order` from entries to samples: entry k of
    /// the reordered samples (which the leaves index) holds `samples[order[k]]`; unplaced
    /// samples are not in it, a sample split into time segments is in it once per segment.
    pub fn build(
        samples: &[LensTimeSample],
        lens: &LensModel,
        z_near: f32,
        area: &ScreenArea,
    ) -> (Hierarchy, Vec<u32>) {
        // A whole sample is binned at t = 0.5 (or its span's nearest time), a time segment at
        // the middle of its span.
        let centre_of = |sample: &LensTimeSample, bounds: &Bounds, segmented: bool| {
            let t = if segmented {
                0.5 * (bounds.span[0] + bounds.span[1])
            } else {
                0.5f32.clamp(bounds.span[0], bounds.span[1])
            };
            let p = reproject(sample, lens, LensTime { u: 0.0, v: 0.0, t }, z_near);
            p.map_or(([0.0, 0.0], f32::INFINITY), |p| ([p.x, p.y], p.z))
        };
        // Every sample's entries, in sample order, with their positions at the binning time (the
        // Morton codes follow once the bin grid is known). Chunks of the samples fill their own
        // vectors in parallel.
        let chunks: Vec<(Vec<Placed>, Vec<[f32; 2]>)> = samples
            .par_chunks(ENTRY_CHUNK)
            .enumerate()
            .map(|(chunk_index, chunk)| {
                let mut placed = Vec::with_capacity(chunk.len());
                let mut positions = Vec::with_capacity(chunk.len());
                for (k, s) in chunk.iter().enumerate() {
                    let index = (chunk_index * ENTRY_CHUNK + k) as u32;
                    let segments = sample_segments(s, lens, z_near, area);
                    let segmented = segments.len() > 1;
                    for segment in segments {
                        let (position, depth) = centre_of(s, &segment.bounds, segmented);
                        let times = if segmented { segment.times } else { [f32::NEG_INFINITY, f32::INFINITY] };
                        placed.push(Placed { depth, index, bounds: segment.bounds, times });
                        positions.push(position);
                    }
                }
                (placed, positions)
            })
            .collect();
        let entry_count: usize = chunks.iter().map(|c| c.0.len()).sum();
        // A sample's entries are consecutive: count the samples that have any.
        let placed_count = {
            let mut previous = None;
            let indices = chunks.iter().flat_map(|c| c.0.iter().map(|e| e.index));
            indices.filter(|&index| previous.replace(index) != Some(index)).count()
        };
        let unplaced = samples.len() - placed_count;
        if entry_count == 0 {
            let empty =
                Hierarchy { nodes: Vec::new(), leaves: 0, whole_entries: 0, segment_times: Vec::new(), unplaced };
            return (empty, Vec::new());
        }
        // The bin grid: a square of 2^levels bins a side over the image.
        let density = entry_count as f32 / (area.width * area.height).max(1.0);
        let bin = (SAMPLES_PER_BIN / density).sqrt();
        let side = area.width.max(area.height).max(1.0);
        let mut levels = 0u32;
        while (1u32 << levels) < MAX_BINS_PER_SIDE && bin * ((1u32 << levels) as f32) < side {
            levels += 1;
        }
        let bins = 1u32 << levels;
        let scale = bins as f32 / side;
        let to_bin = |v: f32| ((v * scale).floor().max(0.0) as u32).min(bins - 1);
        // The entries sorted by bin through small keys (each naming its chunk and place), then
        // gathered in that order.
        let key_chunks: Vec<Vec<SortKey>> = chunks
            .par_iter()
            .enumerate()
            .map(|(chunk, (entries, positions))| {
                let keys = entries.iter().zip(positions).enumerate();
                keys.map(|(offset, (entry, position))| SortKey {
                    code: morton(to_bin(position[0]), to_bin(position[1])),
                    index: entry.index,
                    time: entry.times[0],
                    chunk: chunk as u32,
                    offset: offset as u32,
                })
                .collect()
            })
            .collect();
        let mut keys: Vec<SortKey> = Vec::with_capacity(entry_count);
        for chunk in key_chunks {
            keys.extend_from_slice(&chunk);
        }
        // Entries of one sample are in time order: the time breaks ties between them.
        keys.par_sort_unstable_by(|a, b| (a.code, a.index).cmp(&(b.code, b.index)).then(a.time.total_cmp(&b.time)));
        let placed: Vec<Placed> =
            keys.par_iter().map(|key| chunks[key.chunk as usize].0[key.offset as usize]).collect();
        drop(chunks);

        // The quadtree as a walk: inner nodes opened and closed, leaves (ranges of `placed`) in
        // Morton order.
        let mut walk = Vec::new();
        let codes: Vec<u64> = keys.par_iter().map(|key| key.code).collect();
        drop(keys);
        quadtree(&codes, (0, codes.len()), 0, levels, 0, &mut walk);
        drop(codes);
        let quad_leaves: Vec<(usize, usize)> =
            walk.iter().filter_map(|step| if let Walk::Leaf(a, b) = step { Some((*a, *b)) } else { None }).collect();
        // Runs of one surface in each quadtree leaf, with their bounds and extent boxes (the BVH
        // leaves', computed here in parallel rather than in the serial build below).
        let runs: Vec<Vec<Run>> = quad_leaves
            .par_iter()
            .map(|&(start, end)| split_into_runs(&placed[start..end], samples, lens, z_near))
            .collect();
        drop(placed);

        // The BVH, bottom-up along the same walk: each open quadtree node collects a frontier.
        let mut builder = Builder {
            nodes: Vec::new(),
            boxes: Vec::new(),
            order: Vec::with_capacity(entry_count),
            times: Vec::with_capacity(entry_count),
        };
        let mut frontiers: Vec<Vec<u32>> = vec![Vec::new()];
        let mut runs = runs.into_iter();
        for step in walk {
            match step {
                Walk::Open => frontiers.push(Vec::new()),
                Walk::Leaf(..) => {
                    let mut frontier = builder.leaves(runs.next().expect("runs for every quadtree leaf"));
                    builder.reduce(&mut frontier, FRONTIER);
                    frontiers.last_mut().expect("an open quadtree node").extend(frontier);
                }
                Walk::Close => {
                    let mut frontier = frontiers.pop().expect("an open quadtree node");
                    builder.reduce(&mut frontier, FRONTIER);
                    frontiers.last_mut().expect("the quadtree's parent").extend(frontier);
                }
            }
        }
        let mut frontier = frontiers.pop().expect("the root's frontier");
        builder.reduce(&mut frontier, 1);
        let root = frontier[0];
        let laid_out = layout(&builder.nodes, root, &builder.order, &builder.times);
        let hierarchy = Hierarchy {
            nodes: laid_out.nodes,
            leaves: laid_out.leaves,
            whole_entries: laid_out.whole_entries,
            segment_times: laid_out.segment_times,
            unplaced,
        };
        (hierarchy, laid_out.order)
    }

    /// Whether entry `entry` (an index into the reordered samples) takes query time `t`: always
    /// for a whole sample, within its half-open times for a time segment. Of a sample's entries
    /// at most one takes any given time.
    #[inline]
    pub fn entry_takes(&self, entry: usize, t: f32) -> bool {
        match entry.checked_sub(self.whole_entries) {
            None => true,
            Some(k) => {
                let [start, end] = self.segment_times[k];
                start <= t && t < end
            }
        }
    }

    /// The query times entry `entry` takes, half-open: everything for a whole sample
    /// (`entry_takes` in array form).
    pub fn entry_times(&self, entry: usize) -> [f32; 2] {
        match entry.checked_sub(self.whole_entries) {
            None => [f32::NEG_INFINITY, f32::INFINITY],
            Some(k) => self.segment_times[k],
        }
    }

    /// The number of entries (the length of the reordered samples).
    pub fn entry_count(&self) -> usize {
        self.whole_entries + self.segment_times.len()
    }

    /// The number of time-segment entries.
    pub fn segment_entries(&self) -> usize {
        self.segment_times.len()
    }

    /// Appends to `out` (cleared first) the leaves whose bounds at `at` come within `reach`
    /// pixels of `location` with t̂ in their span, in depth-first order.
    pub fn leaves_near(&self, location: [f32; 2], at: LensTime, reach: f32, out: &mut Vec<u32>) {
        out.clear();
        let mut i = 0usize;
        while i < self.nodes.len() {
            let node = &self.nodes[i];
            if node.is_leaf() {
                if node.bounds.near(location, at, reach) {
                    out.push(i as u32);
                }
                i += 1;
            } else if node.bounds.near(location, at, reach) {
                i += 1;
            } else {
                i = node.first_or_end as usize;
            }
        }
    }

    /// Appends to `out` (cleared first) every leaf that `leaves_near` can return for some
    /// location of `window` with reach `reach`, in depth-first order (`Bounds::may_be_near`: a
    /// node is entered when its bounds can come within reach of some location of the window).
    pub fn leaves_near_window(&self, window: &Window, reach: f32, out: &mut Vec<u32>) {
        out.clear();
        let mut i = 0usize;
        while i < self.nodes.len() {
            let node = &self.nodes[i];
            let near = node.bounds.may_be_near(window, reach);
            if node.is_leaf() {
                if near {
                    out.push(i as u32);
                }
                i += 1;
            } else if near {
                i += 1;
            } else {
                i = node.first_or_end as usize;
            }
        }
    }

    /// The node `index`.
    #[inline]
    pub fn node(&self, index: u32) -> &Node {
        &self.nodes[index as usize]
    }

    /// All nodes, depth first.
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// The number of leaves.
    pub fn leaf_count(&self) -> usize {
        self.leaves
    }

    /// Memory of the nodes and the segments' times, bytes.
    pub fn node_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node>() + self.segment_times.len() * std::mem::size_of::<[f32; 2]>()
    }
}

/// Puts `items` in the hierarchy's sample order (`order` from `Hierarchy::build`).
pub fn reorder<T: Copy>(items: &[T], order: &[u32]) -> Vec<T> {
    order.iter().map(|&i| items[i as usize]).collect()
}

/// A step of the walk over the quadtree.
enum Walk {
    Open,
    /// A leaf: a range of the samples sorted by bin.
    Leaf(usize, usize),
    Close,
}

/// Records the walk over the quadtree node holding the entries `start..end` (`codes`: the sorted
/// entries' Morton codes), at depth `level` of `levels`, whose Morton codes start at `code`.
fn quadtree(codes: &[u64], (start, end): (usize, usize), level: u32, levels: u32, code: u64, walk: &mut Vec<Walk>) {
    if end - start <= MAX_LEAF_SAMPLES || level == levels {
        walk.push(Walk::Leaf(start, end));
        return;
    }
    walk.push(Walk::Open);
    let quarter = 1u64 << (2 * (levels - level - 1));
    let mut child_start = start;
    for k in 0..4u64 {
        let limit = code + (k + 1) * quarter;
        let child_end = child_start + codes[child_start..end].partition_point(|&c| c < limit);
        if child_end > child_start {
            quadtree(codes, (child_start, child_end), level + 1, levels, code + k * quarter, walk);
        }
        child_start = child_end;
    }
    walk.push(Walk::Close);
}

/// Whether two samples stay apart (SAMESURFACE with the build tolerance) over the whole lens and
/// the times both can be seen.
fn same_surface_throughout(a: &Placed, b: &Placed, samples: &[LensTimeSample], lens: &LensModel, z_near: f32) -> bool {
    let (sa, sb) = (&samples[a.index as usize], &samples[b.index as usize]);
    let motionless = sa.motion == [0.0; 3] && sb.motion == [0.0; 3];
    if motionless && (lens.coc(sa.z) - lens.coc(sb.z)).abs() < BUILD_CROSSING_TOLERANCE_PX {
        // x'a − x'b = d + û·(Ca − Cb) over û ∈ [−1, 1] spans less than twice the tolerance:
        // it cannot reach both −tolerance and +tolerance (the same for y).
        return true;
    }
    let t0 = a.bounds.span[0].max(b.bounds.span[0]);
    let t1 = a.bounds.span[1].min(b.bounds.span[1]);
    if t0 > t1 {
        return false;
    }
    let corners = [
        LensTime { u: -1.0, v: -1.0, t: t0 },
        LensTime { u: -1.0, v: -1.0, t: t1 },
        LensTime { u: 1.0, v: 1.0, t: t0 },
        LensTime { u: 1.0, v: 1.0, t: t1 },
    ];
    same_surface_at(sa, sb, lens, corners, BUILD_CROSSING_TOLERANCE_PX, z_near)
}

/// A leaf of the BVH under construction: its entries' samples and query times, whether they are
/// time segments, their merged bounds and its extent box (`Bounds::extent_box`).
struct Run {
    entries: Vec<(u32, [f32; 2])>,
    segmented: bool,
    bounds: Bounds,
    extent: [f64; 4],
}

/// A quadtree leaf's entries, front to back, cut into runs of one surface of at most
/// `MAX_LEAF_SAMPLES`; whole samples and time segments never share a run (the whole samples'
/// runs first).
fn split_into_runs(cell: &[Placed], samples: &[LensTimeSample], lens: &LensModel, z_near: f32) -> Vec<Run> {
    let mut sorted: Vec<&Placed> = cell.iter().collect();
    sorted.sort_unstable_by(|a, b| {
        (a.segmented().cmp(&b.segmented()))
            .then(a.depth.total_cmp(&b.depth))
            .then(a.index.cmp(&b.index))
            .then(a.times[0].total_cmp(&b.times[0]))
    });
    let finish = |run: &[&Placed]| {
        let bounds = Bounds::merge_all(run.iter().map(|p| &p.bounds));
        Run {
            entries: run.iter().map(|p| (p.index, p.times)).collect(),
            segmented: run[0].segmented(),
            bounds,
            extent: bounds.extent_box(),
        }
    };
    let mut runs = Vec::new();
    let mut current: Vec<&Placed> = Vec::with_capacity(MAX_LEAF_SAMPLES);
    for p in sorted {
        let fits = current.len() < MAX_LEAF_SAMPLES
            && current.first().map_or(true, |q| q.segmented() == p.segmented())
            && current.iter().all(|q| same_surface_throughout(p, q, samples, lens, z_near));
        if !fits && !current.is_empty() {
            runs.push(finish(&current));
            current.clear();
        }
        current.push(p);
    }
    if !current.is_empty() {
        runs.push(finish(&current));
    }
    runs
}

struct Builder {
    nodes: Vec<BuildNode>,
    /// Each node's extent over its span and the whole lens: [x_lo, x_hi, y_lo, y_hi].
    boxes: Vec<[f64; 4]>,
    /// The entries in build order: their samples and query times.
    order: Vec<u32>,
    times: Vec<[f32; 2]>,
}

impl Builder {
    /// BVH leaves for the runs of a quadtree leaf; their entries join the order.
    fn leaves(&mut self, runs: Vec<Run>) -> Vec<u32> {
        runs.into_iter()
            .map(|Run { entries, segmented, bounds, extent }| {
                let first = self.order.len() as u32;
                self.order.extend(entries.iter().map(|e| e.0));
                self.times.extend(entries.iter().map(|e| e.1));
                let count = entries.len() as u32;
                self.push_with_box(
                    BuildNode { bounds, samples: count, a: first, b: count, leaf: true, segmented },
                    extent,
                )
            })
            .collect()
    }

    fn push(&mut self, node: BuildNode) -> u32 {
        let extent = node.bounds.extent_box();
        self.push_with_box(node, extent)
    }

    /// `push` with the node's extent box (`Bounds::extent_box`) already computed.
    fn push_with_box(&mut self, node: BuildNode, extent: [f64; 4]) -> u32 {
        self.boxes.push(extent);
        self.nodes.push(node);
        (self.nodes.len() - 1) as u32
    }

    /// Merges nodes of `frontier` greedily (least added cost, ties by position) until at most
    /// `keep` remain.
    fn reduce(&mut self, frontier: &mut Vec<u32>, keep: usize) {
        // Large frontiers (many runs in one bin) first pair up neighbours in order.
        while frontier.len() > 64 {
            let mut paired = Vec::with_capacity(frontier.len() / 2 + 1);
            for pair in frontier.chunks(2) {
                paired.push(if pair.len() == 2 { self.merge(pair[0], pair[1]) } else { pair[0] });
            }
            *frontier = paired;
        }
        if frontier.len() <= keep {
            return;
        }
        // The cost of a merge is judged on the union of the two extents (the merged planes are
        // fitted only for the merges chosen). Queries find the same samples whatever the tree;
        // only the order of their sums changes (images within 0.001 dB, docs/tlfr.md).
        let own = |b: &Builder, i: u32| box_cost(&b.boxes[i as usize], b.nodes[i as usize].samples);
        let added = |b: &Builder, i: u32, j: u32| {
            let (x, y) = (&b.boxes[i as usize], &b.boxes[j as usize]);
            let union = [x[0].min(y[0]), x[1].max(y[1]), x[2].min(y[2]), x[3].max(y[3])];
            let samples = b.nodes[i as usize].samples + b.nodes[j as usize].samples;
            box_cost(&union, samples) - own(b, i) - own(b, j)
        };
        // costs[i][j] for i < j, over positions in `frontier`.
        let mut costs: Vec<Vec<f64>> = (0..frontier.len())
            .map(|i| {
                (0..frontier.len()).map(|j| if j > i { added(self, frontier[i], frontier[j]) } else { 0.0 }).collect()
            })
            .collect();
        while frontier.len() > keep {
            let mut best = (f64::INFINITY, 0, 1);
            for (i, row) in costs.iter().enumerate() {
                for (j, &added_cost) in row.iter().enumerate().skip(i + 1) {
                    if added_cost < best.0 {
                        best = (added_cost, i, j);
                    }
                }
            }
            let (_, i, j) = best;
            let merged = self.merge(frontier[i], frontier[j]);
            // The merged node takes position i; position j goes.
            frontier[i] = merged;
            frontier.remove(j);
            costs.remove(j);
            for row in costs.iter_mut() {
                row.remove(j);
            }
            for k in 0..frontier.len() {
                if k != i {
                    let (lo, hi) = (k.min(i), k.max(i));
                    costs[lo][hi] = added(self, frontier[lo], frontier[hi]);
                }
            }
        }
    }

    fn merge(&mut self, a: u32, b: u32) -> u32 {
        let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
        let node = BuildNode {
            bounds: na.bounds.merge(&nb.bounds),
            samples: na.samples + nb.samples,
            a,
            b,
            leaf: false,
            segmented: false,
        };
        self.push(node)
    }
}

/// The hierarchy's arrays as `layout` leaves them.
struct LaidOut {
    nodes: Vec<Node>,
    leaves: usize,
    /// Entry → sample; the whole samples' entries first, then the time segments'.
    order: Vec<u32>,
    whole_entries: usize,
    segment_times: Vec<[f32; 2]>,
}

/// The tree below `root` depth first, each inner node knowing where its subtree ends, with the
/// entries renumbered so that the leaves' entries follow each other in that order: first the
/// leaves of whole samples, then (after all of those) the leaves of time segments. `order` and
/// `times` give each build position's sample and query times.
fn layout(built: &[BuildNode], root: u32, order: &[u32], times: &[[f32; 2]]) -> LaidOut {
    let mut nodes: Vec<Node> = Vec::with_capacity(built.len());
    let (mut whole_order, mut segment_order, mut segment_times) =
        (Vec::with_capacity(order.len()), Vec::new(), Vec::new());
    // Nodes of segment leaves, whose first entry moves past the whole samples' at the end.
    let mut segment_leaves = Vec::new();
    let mut leaves = 0;
    // (build index, whether the inner node's subtree is finished)
    let mut stack: Vec<(u32, bool)> = vec![(root, false)];
    let mut open: Vec<usize> = Vec::new();
    while let Some((index, closing)) = stack.pop() {
        if closing {
            let position = open.pop().expect("an open inner node");
            nodes[position].first_or_end = nodes.len() as u32;
            continue;
        }
        let node = &built[index as usize];
        if node.leaf {
            let range = node.a as usize..(node.a + node.b) as usize;
            let first = if node.segmented {
                segment_leaves.push(nodes.len());
                let first = segment_order.len() as u32;
                segment_order.extend_from_slice(&order[range.clone()]);
                segment_times.extend_from_slice(&times[range]);
                first
            } else {
                let first = whole_order.len() as u32;
                whole_order.extend_from_slice(&order[range]);
                first
            };
            nodes.push(Node { bounds: node.bounds, first_or_end: first, count: node.b });
            leaves += 1;
        } else {
            open.push(nodes.len());
            nodes.push(Node { bounds: node.bounds, first_or_end: 0, count: 0 });
            stack.push((index, true));
            stack.push((node.b, false));
            stack.push((node.a, false));
        }
    }
    let whole_entries = whole_order.len();
    for position in segment_leaves {
        nodes[position].first_or_end += whole_entries as u32;
    }
    let mut order = whole_order;
    order.extend(segment_order);
    LaidOut { nodes, leaves, order, whole_entries, segment_times }
}

#[cfg(test)]
mod tests;
