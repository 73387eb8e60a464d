//! The hierarchy of the reconstruction queries (paper Section 4, "Acceleration"): a bounding
//! volume hierarchy over the samples whose nodes bound their samples' reprojected screen
//! positions by planes linear in (t, u) and (t, v) (`bounds`), with leaves of at most
//! `MAX_LEAF_SAMPLES` samples of one surface each.
//!
//! Construction ("a push-pull procedure": leaves top-down, then the BVH bottom-up):
//! 1. every sample's bounds (`bounds::sample_bounds`); a sample that is never in front of the
//!    camera while potentially near the image is left out (`unplaced`);
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
//! 4. a quadtree leaf's samples sorted front to back (depth at the centre time; the authors'
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
//! 64 bytes (one cache line): four planes, the time span and two indices. The samples are
//! renumbered so that the leaves' samples follow each other in that same depth-first order
//! (`Hierarchy::build` returns the permutation; `reorder` applies it to any array aligned with
//! the samples).
//!
//! Known limit: a plane linear in t bounds a trajectory that nears the camera plane (x ∝ 1/z'
//! with z' → 0) only loosely over the whole of its span, so samples flying through the camera
//! are "near" many locations early in the shutter where they are far; queries stay exact
//! (the test below checks that against a scan) but visit many leaves in such scenes.
//!
//! Everything is deterministic: per-sample work runs in parallel but lands in sample order,
//! quadtree leaves are processed in parallel and collected in Morton order, and every sort and
//! every greedy choice breaks ties by index.

use rayon::prelude::*;

use super::bounds::{sample_bounds, Bounds, ScreenArea};
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
    /// Samples left out (never in front of the camera near the image).
    pub unplaced: usize,
}

/// A node under construction.
#[derive(Clone, Copy)]
struct BuildNode {
    bounds: Bounds,
    samples: u32,
    /// Children of an inner node, or the leaf's sample range.
    a: u32,
    b: u32,
    leaf: bool,
}

/// The cost of a node in the greedy merging.
fn cost(bounds: &Bounds, samples: u32) -> f64 {
    let (w, h) = bounds.extent();
    (w as f64 + 1.0) * (h as f64 + 1.0) * samples as f64
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

/// A sample ready for binning.
#[derive(Clone, Copy)]
struct Placed {
    code: u64,
    depth: f32,
    index: u32,
    bounds: Bounds,
}

impl Hierarchy {
    /// Builds the hierarchy over `samples` for lens model `lens`, near limit `z_near` and the
    /// image area `area`. Returns it with the permutation `order`: position k of the reordered
    /// samples (which the leaves index) holds `samples[order[k]]`; unplaced samples are not in it.
    pub fn build(
        samples: &[LensTimeSample],
        lens: &LensModel,
        z_near: f32,
        area: &ScreenArea,
    ) -> (Hierarchy, Vec<u32>) {
        let centre_of = |sample: &LensTimeSample, bounds: &Bounds| {
            let t = 0.5f32.clamp(bounds.span[0], bounds.span[1]);
            let p = reproject(sample, lens, LensTime { u: 0.0, v: 0.0, t }, z_near);
            p.map_or(([0.0, 0.0], f32::INFINITY), |p| ([p.x, p.y], p.z))
        };
        let bounded: Vec<Option<(Bounds, [f32; 2], f32)>> = samples
            .par_iter()
            .map(|s| {
                sample_bounds(s, lens, z_near, area).map(|b| {
                    let (position, depth) = centre_of(s, &b);
                    (b, position, depth)
                })
            })
            .collect();
        let placed_count = bounded.iter().flatten().count();
        let unplaced = samples.len() - placed_count;
        if placed_count == 0 {
            return (Hierarchy { nodes: Vec::new(), leaves: 0, unplaced }, Vec::new());
        }
        // The bin grid: a square of 2^levels bins a side over the image.
        let density = placed_count as f32 / (area.width * area.height).max(1.0);
        let bin = (SAMPLES_PER_BIN / density).sqrt();
        let side = area.width.max(area.height).max(1.0);
        let mut levels = 0u32;
        while (1u32 << levels) < MAX_BINS_PER_SIDE && bin * ((1u32 << levels) as f32) < side {
            levels += 1;
        }
        let bins = 1u32 << levels;
        let scale = bins as f32 / side;
        let to_bin = |v: f32| ((v * scale).floor().max(0.0) as u32).min(bins - 1);
        let mut placed: Vec<Placed> = bounded
            .par_iter()
            .enumerate()
            .filter_map(|(index, entry)| {
                entry.map(|(bounds, position, depth)| Placed {
                    code: morton(to_bin(position[0]), to_bin(position[1])),
                    depth,
                    index: index as u32,
                    bounds,
                })
            })
            .collect();
        drop(bounded);
        placed.par_sort_unstable_by_key(|p| (p.code, p.index));

        // The quadtree as a walk: inner nodes opened and closed, leaves (ranges of `placed`) in
        // Morton order.
        let mut walk = Vec::new();
        quadtree(&placed, (0, placed.len()), 0, levels, 0, &mut walk);
        let quad_leaves: Vec<(usize, usize)> =
            walk.iter().filter_map(|step| if let Walk::Leaf(a, b) = step { Some((*a, *b)) } else { None }).collect();
        // Runs of one surface in each quadtree leaf.
        let runs: Vec<Vec<Vec<Placed>>> = quad_leaves
            .par_iter()
            .map(|&(start, end)| split_into_runs(&placed[start..end], samples, lens, z_near))
            .collect();
        drop(placed);

        // The BVH, bottom-up along the same walk: each open quadtree node collects a frontier.
        let mut builder = Builder { nodes: Vec::new(), order: Vec::with_capacity(placed_count) };
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
        let (nodes, leaves, order) = layout(&builder.nodes, root, &builder.order);
        (Hierarchy { nodes, leaves, unplaced }, order)
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

    /// Memory of the nodes, bytes.
    pub fn node_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node>()
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

/// Records the walk over the quadtree node holding `placed[start..end]`, at depth `level` of
/// `levels`, whose Morton codes start at `code`.
fn quadtree(placed: &[Placed], (start, end): (usize, usize), level: u32, levels: u32, code: u64, walk: &mut Vec<Walk>) {
    if end - start <= MAX_LEAF_SAMPLES || level == levels {
        walk.push(Walk::Leaf(start, end));
        return;
    }
    walk.push(Walk::Open);
    let quarter = 1u64 << (2 * (levels - level - 1));
    let mut child_start = start;
    for k in 0..4u64 {
        let limit = code + (k + 1) * quarter;
        let child_end = child_start + placed[child_start..end].partition_point(|p| p.code < limit);
        if child_end > child_start {
            quadtree(placed, (child_start, child_end), level + 1, levels, code + k * quarter, walk);
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

/// A quadtree leaf's samples, front to back, cut into runs of one surface of at most
/// `MAX_LEAF_SAMPLES`.
fn split_into_runs(cell: &[Placed], samples: &[LensTimeSample], lens: &LensModel, z_near: f32) -> Vec<Vec<Placed>> {
    let mut sorted = cell.to_vec();
    sorted.sort_unstable_by(|a, b| a.depth.total_cmp(&b.depth).then(a.index.cmp(&b.index)));
    let mut runs: Vec<Vec<Placed>> = Vec::new();
    let mut current: Vec<Placed> = Vec::new();
    for p in sorted {
        let fits = current.len() < MAX_LEAF_SAMPLES
            && current.iter().all(|q| same_surface_throughout(&p, q, samples, lens, z_near));
        if !fits && !current.is_empty() {
            runs.push(std::mem::take(&mut current));
        }
        current.push(p);
    }
    if !current.is_empty() {
        runs.push(current);
    }
    runs
}

struct Builder {
    nodes: Vec<BuildNode>,
    order: Vec<u32>,
}

impl Builder {
    /// BVH leaves for the runs of a quadtree leaf; their samples join the order.
    fn leaves(&mut self, runs: Vec<Vec<Placed>>) -> Vec<u32> {
        runs.into_iter()
            .map(|run| {
                let first = self.order.len() as u32;
                self.order.extend(run.iter().map(|p| p.index));
                let bounds = Bounds::merge_all(run.iter().map(|p| &p.bounds));
                let count = run.len() as u32;
                self.push(BuildNode { bounds, samples: count, a: first, b: count, leaf: true })
            })
            .collect()
    }

    fn push(&mut self, node: BuildNode) -> u32 {
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
        let own = |nodes: &[BuildNode], i: u32| cost(&nodes[i as usize].bounds, nodes[i as usize].samples);
        let added = |nodes: &[BuildNode], i: u32, j: u32| {
            let (a, b) = (&nodes[i as usize], &nodes[j as usize]);
            cost(&a.bounds.merge(&b.bounds), a.samples + b.samples) - own(nodes, i) - own(nodes, j)
        };
        // costs[i][j] for i < j, over positions in `frontier`.
        let mut costs: Vec<Vec<f64>> = (0..frontier.len())
            .map(|i| {
                (0..frontier.len())
                    .map(|j| if j > i { added(&self.nodes, frontier[i], frontier[j]) } else { 0.0 })
                    .collect()
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
                    costs[lo][hi] = added(&self.nodes, frontier[lo], frontier[hi]);
                }
            }
        }
    }

    fn merge(&mut self, a: u32, b: u32) -> u32 {
        let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
        let node =
            BuildNode { bounds: na.bounds.merge(&nb.bounds), samples: na.samples + nb.samples, a, b, leaf: false };
        self.push(node)
    }
}

/// The tree below `root` depth first, each inner node knowing where its subtree ends, with the
/// samples renumbered so that the leaves' samples follow each other in that order; the number of
/// leaves and the new sample order (`order` maps build positions to samples).
fn layout(built: &[BuildNode], root: u32, order: &[u32]) -> (Vec<Node>, usize, Vec<u32>) {
    let mut nodes: Vec<Node> = Vec::with_capacity(built.len());
    let mut new_order = Vec::with_capacity(order.len());
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
            let first = new_order.len() as u32;
            new_order.extend_from_slice(&order[node.a as usize..(node.a + node.b) as usize]);
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
    (nodes, leaves, new_order)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tlfr::reprojection::near_limit;
    use crate::tlfr::same_surface::same_surface;
    use crate::tlfr::test_scenes::{layered_scene, sample_scene, Lcg, MovingRect, ThinLens};

    /// A scene of random moving rectangles over a `width` × `height` image with defocus; one of
    /// them moves through the camera plane.
    fn random_scene(seed: u64, width: u32, height: u32) -> (ThinLens, Vec<MovingRect>) {
        let mut rng = Lcg(seed);
        let lens = ThinLens {
            f: width as f32,
            a: 0.02 + 0.1 * rng.uniform(),
            focus: 1.5 + 4.0 * rng.uniform(),
            width,
            height,
        };
        let mut rects = Vec::new();
        for k in 0..6 {
            let z = 1.0 + 8.0 * rng.uniform();
            let (x, y) = (z * (rng.uniform() - 0.6), z * (rng.uniform() - 0.6));
            let size = z * (0.1 + 0.5 * rng.uniform());
            let motion = if k == 0 {
                // Through the camera plane within the shutter.
                [0.2 * (rng.uniform() - 0.5), 0.2 * (rng.uniform() - 0.5), -z / (0.3 + 0.6 * rng.uniform())]
            } else {
                [0.3 * (rng.uniform() - 0.5), 0.3 * (rng.uniform() - 0.5), 2.0 * (rng.uniform() - 0.5)]
            };
            rects.push(MovingRect {
                x: [x, x + size],
                y: [y, y + size * (0.5 + rng.uniform())],
                z,
                motion,
                colour: [rng.uniform(), rng.uniform(), rng.uniform()],
            });
        }
        (lens, rects)
    }

    fn build(
        lens: &ThinLens,
        rects: &[MovingRect],
        spp: u32,
        seed: u64,
        max_reach: f32,
    ) -> (Vec<LensTimeSample>, Hierarchy, Vec<u32>, f32) {
        let (samples, _) = sample_scene(lens, rects, spp, [0.0; 3], seed);
        let z_near = near_limit(samples.iter().map(|s| s.z));
        let area = ScreenArea { width: lens.width as f32, height: lens.height as f32, max_reach };
        let (hierarchy, order) = Hierarchy::build(&samples, &lens.model(), z_near, &area);
        (samples, hierarchy, order, z_near)
    }

    /// The samples within `reach` of `location` at `at` (by index into the original samples),
    /// through the tree and by scanning every sample.
    #[test]
    fn the_tree_finds_exactly_the_samples_a_scan_finds() {
        let radius = 0.6;
        let max_reach = 16.0 * radius;
        for seed in 0..4u64 {
            let (lens, rects) = if seed == 0 { layered_scene(64, 40, true) } else { random_scene(seed, 64, 40) };
            let (samples, hierarchy, order, z_near) = build(&lens, &rects, 6, seed, max_reach);
            let model = lens.model();
            assert!(hierarchy.leaf_count() > samples.len() / MAX_LEAF_SAMPLES);
            let mut rng = Lcg(seed + 100);
            let (mut leaves, mut found_total) = (Vec::new(), 0);
            for query in 0..300 {
                let location = [64.0 * rng.uniform(), 40.0 * rng.uniform()];
                let (u, v) = rng.disk();
                let at = LensTime { u, v, t: rng.uniform() };
                let reach = radius * [2.0f32, 4.0, 8.0, 16.0][query % 4];
                let within = |s: &LensTimeSample| {
                    reproject(s, &model, at, z_near).is_some_and(|p| {
                        let (dx, dy) = (p.x - location[0], p.y - location[1]);
                        dx * dx + dy * dy <= reach * reach
                    })
                };
                let mut scanned: Vec<u32> =
                    (0..samples.len() as u32).filter(|&i| within(&samples[i as usize])).collect();
                hierarchy.leaves_near(location, at, reach, &mut leaves);
                let mut through_tree: Vec<u32> = leaves
                    .iter()
                    .flat_map(|&leaf| hierarchy.node(leaf).samples())
                    .map(|k| order[k])
                    .filter(|&i| within(&samples[i as usize]))
                    .collect();
                scanned.sort_unstable();
                through_tree.sort_unstable();
                assert_eq!(through_tree, scanned, "scene {seed}, {location:?} {at:?} reach {reach}");
                found_total += scanned.len();
                // The pruning works: far fewer leaves than all.
                assert!(leaves.len() < hierarchy.leaf_count(), "{} of {}", leaves.len(), hierarchy.leaf_count());
            }
            assert!(found_total > 1000, "scene {seed}: {found_total}");
        }
    }

    #[test]
    fn every_leaf_holds_one_surface_of_at_most_32_samples() {
        for seed in 0..4u64 {
            let (lens, rects) = if seed == 0 { layered_scene(48, 32, true) } else { random_scene(seed + 10, 48, 32) };
            let (samples, hierarchy, order, z_near) = build(&lens, &rects, 8, seed, 8.0);
            let model = lens.model();
            let area = ScreenArea { width: 48.0, height: 32.0, max_reach: 8.0 };
            // Every placed sample is in exactly one leaf; the unplaced are never near the image.
            let mut seen = vec![0u32; samples.len()];
            let (mut pairs, mut split_leaves) = (0, 0);
            for node in hierarchy.nodes().iter().filter(|n| n.is_leaf()) {
                let range = node.samples();
                assert!((1..=MAX_LEAF_SAMPLES).contains(&range.len()));
                for k in range.clone() {
                    seen[order[k] as usize] += 1;
                }
                for a in range.clone() {
                    for b in range.start..a {
                        let (sa, sb) = (&samples[order[a] as usize], &samples[order[b] as usize]);
                        let span = |s: &LensTimeSample| sample_bounds(s, &model, z_near, &area).unwrap().span;
                        let (ta, tb) = (span(sa), span(sb));
                        let same = if ta == [0.0, 1.0] && tb == [0.0, 1.0] {
                            // The whole domain: δ = 1 around the cube's centre.
                            let centre = LensTime { u: 0.0, v: 0.0, t: 0.5 };
                            same_surface(sa, sb, &model, centre, 1.0, BUILD_CROSSING_TOLERANCE_PX, z_near)
                        } else {
                            let (t0, t1) = (ta[0].max(tb[0]), ta[1].min(tb[1]));
                            let corner = |w: f32, t: f32| LensTime { u: w, v: w, t };
                            let corners = [corner(-1.0, t0), corner(-1.0, t1), corner(1.0, t0), corner(1.0, t1)];
                            t0 <= t1 && same_surface_at(sa, sb, &model, corners, BUILD_CROSSING_TOLERANCE_PX, z_near)
                        };
                        assert!(same, "scene {seed}: {sa:?} and {sb:?} share a leaf");
                        pairs += 1;
                    }
                }
                split_leaves += (range.len() < MAX_LEAF_SAMPLES) as usize;
            }
            for (i, count) in seen.iter().enumerate() {
                let placed = sample_bounds(&samples[i], &model, z_near, &area).is_some();
                assert_eq!(*count, placed as u32, "sample {i}");
            }
            assert_eq!(hierarchy.unplaced, seen.iter().filter(|&&c| c == 0).count());
            assert!(pairs > 10_000 && split_leaves > 0, "{pairs} pairs");
        }
    }

    #[test]
    fn the_same_input_gives_the_same_tree_for_any_thread_count() {
        let (lens, rects) = random_scene(5, 64, 40);
        let (samples, _) = sample_scene(&lens, &rects, 8, [0.0; 3], 5);
        let z_near = near_limit(samples.iter().map(|s| s.z));
        let area = ScreenArea { width: 64.0, height: 40.0, max_reach: 10.0 };
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| Hierarchy::build(&samples, &lens.model(), z_near, &area))
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(3));
        assert!(one.0.leaf_count() > 0);
    }

    #[test]
    fn nodes_take_one_cache_line_and_the_layout_is_depth_first() {
        assert_eq!(std::mem::size_of::<Node>(), 64);
        let (lens, rects) = layered_scene(40, 30, false);
        let (samples, hierarchy, order, _) = build(&lens, &rects, 4, 1, 8.0);
        assert_eq!(order.len() + hierarchy.unplaced, samples.len());
        // Inner nodes are followed by their subtree; leaves cover the samples in order.
        let mut next_sample = 0;
        for (i, node) in hierarchy.nodes().iter().enumerate() {
            if node.is_leaf() {
                assert_eq!(node.samples().start, next_sample);
                next_sample = node.samples().end;
            } else {
                assert!(node.first_or_end as usize > i + 1 && node.first_or_end as usize <= hierarchy.nodes().len());
            }
        }
        assert_eq!(next_sample, order.len());
        // A binary tree: one fewer inner node than leaves.
        assert_eq!(hierarchy.nodes().len(), 2 * hierarchy.leaf_count() - 1);
        assert!(hierarchy.node_bytes() as f64 / samples.len() as f64 <= 16.0);
    }

    #[test]
    fn an_empty_or_unseen_input_has_no_leaves() {
        let lens = LensModel { c1: 0.0, c2: 0.0, fx: 10.0, fy: 10.0, cx: 5.0, cy: 5.0 };
        let area = ScreenArea { width: 10.0, height: 10.0, max_reach: 2.0 };
        let (h, order) = Hierarchy::build(&[], &lens, 1e-3, &area);
        assert!(h.nodes().is_empty() && order.is_empty());
        let far = LensTimeSample { x: 500.0, y: 5.0, t: 0.5, z: 1.0, ..LensTimeSample::default() };
        let (h, order) = Hierarchy::build(&[far], &lens, 1e-3, &area);
        assert!(h.nodes().is_empty() && order.is_empty() && h.unplaced == 1);
        let mut out = vec![7];
        h.leaves_near([5.0, 5.0], LensTime { u: 0.0, v: 0.0, t: 0.5 }, 2.0, &mut out);
        assert!(out.is_empty());
    }
}
