//! Nearest neighbours of a secondary hit under the metric of paper Section 2.2: a kd-tree over
//! points and an incremental walk that yields the other points in increasing order of
//! (Mahalanobis distance, index). The metric depends on the query (its normal), so it is not a
//! fixed distance a generic k-NN crate could index; the walk uses the Euclidean distance to a
//! node's box as an admissible lower bound (the metric is never shorter than the Euclidean
//! distance for α ≥ 1) and emits a point only when nothing closer can remain.
//!
//! The order of the walk is a property of the point set alone (ties broken by index), not of
//! the tree, so a brute-force sort gives the same sequence bit for bit.
//!
//! Callers mostly need a few nearest points (splat sizing k = 12, the robust radiance's jury
//! of 12), so [`KdTree::walk`] first finds the `expected` nearest by a bounded depth-first
//! search (nearer child first, a node skipped once its box cannot beat the worst kept point),
//! which touches a handful of leaves, and only when the caller wants more than those does it
//! continue with the incremental heap walk ([`KdTree::walk_incremental`], the simple version
//! and the tests' oracle), which yields the same order, past the points already given.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use crate::vector::sub;

/// Points per leaf.
const LEAF_SIZE: usize = 8;

/// Squared distance of the offset `d` = candidate − query under the metric that counts the
/// component along the query's unit normal `normal` α times: |d|² + (α² − 1)(d·n)²
/// (= |d + (α − 1)(d·n)n|², paper Section 2.2). `alpha_squared_minus_one` = α² − 1.
#[inline]
pub fn metric_distance_squared(d: [f32; 3], normal: [f32; 3], alpha_squared_minus_one: f32) -> f32 {
    let along_normal = d[0] * normal[0] + d[1] * normal[1] + d[2] * normal[2];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) + alpha_squared_minus_one * (along_normal * along_normal)
}

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    /// Range of points in tree order (leaves), or the children (inner nodes, `left` > 0).
    start: u32,
    end: u32,
    left: u32,
    right: u32,
}

/// Whose neighbours a walk yields: the point `position` (not itself in the tree, or skipped as
/// `skip`), its unit `normal` and the metric's α² − 1 ≥ 0 ([`metric_distance_squared`]).
#[derive(Clone, Copy, Debug)]
pub struct MetricQuery {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub alpha_squared_minus_one: f32,
    /// The index of a point the walk leaves out (the query's own); `u32::MAX` for none.
    pub skip: u32,
}

impl MetricQuery {
    fn key(&self, point: [f32; 3]) -> f32 {
        metric_distance_squared(sub(point, self.position), self.normal, self.alpha_squared_minus_one)
    }
}

/// A kd-tree over a fixed set of points.
#[derive(Clone, Debug)]
pub struct KdTree {
    nodes: Vec<Node>,
    /// The points in tree order, and their indices in the input.
    points: Vec<[f32; 3]>,
    ids: Vec<u32>,
}

impl KdTree {
    /// Builds the tree; the points must be finite (the caller checks).
    pub fn build(points: &[[f32; 3]]) -> KdTree {
        let mut ids: Vec<u32> = (0..points.len() as u32).collect();
        let nodes = if points.is_empty() { Vec::new() } else { build_subtree(points, &mut ids, 0) };
        KdTree { nodes, points: ids.iter().map(|&i| points[i as usize]).collect(), ids }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The input indices in the tree's leaf order: neighbouring entries are near in space, so
    /// queries taken in this order walk the same nodes one after another (cache-friendly).
    pub fn leaf_order(&self) -> &[u32] {
        &self.ids
    }

    /// Calls `visit(index, metric distance²)` for every point except `query.skip`, in
    /// increasing order of (metric distance² from the query, index), until `visit` returns
    /// false: the sequence of [`KdTree::walk_incremental`], bit for bit. `expected` is how many
    /// points the caller likely takes: they come from a bounded depth-first search, cheaper
    /// than the heap walk, which runs only when `visit` asks for more.
    pub fn walk(
        &self,
        query: &MetricQuery,
        expected: usize,
        scratch: &mut WalkScratch,
        mut visit: impl FnMut(u32, f32) -> bool,
    ) {
        self.nearest(query, expected, scratch);
        for &(key, id) in &scratch.nearest {
            if !visit(id, key) {
                return;
            }
        }
        if scratch.nearest.len() < expected {
            return; // the search kept every other point
        }
        let mut given = 0usize;
        self.walk_incremental(query, &mut scratch.heap, |id, key| {
            given += 1;
            given <= expected || visit(id, key)
        });
    }

    /// The `count` first points of the walk's order into `scratch.nearest`, sorted by
    /// (metric distance², index): a depth-first search that opens the nearer child first and
    /// skips a subtree whose box lower bound exceeds the worst point kept once `count` are kept
    /// (a bound equal to it may still hold a point with a smaller index, so it is opened).
    fn nearest(&self, query: &MetricQuery, count: usize, scratch: &mut WalkScratch) {
        debug_assert!(query.alpha_squared_minus_one >= 0.0);
        let kept = &mut scratch.nearest;
        kept.clear();
        scratch.stack.clear();
        if self.nodes.is_empty() || count == 0 {
            return;
        }
        scratch.stack.push((0.0, 0));
        while let Some((bound, slot)) = scratch.stack.pop() {
            if kept.len() == count && bound > kept[count - 1].0 {
                continue;
            }
            let mut node = &self.nodes[slot as usize];
            // Down the nearer child, the farther one stacked with its bound.
            while node.left != 0 {
                let (left, right) = (&self.nodes[node.left as usize], &self.nodes[node.right as usize]);
                let (left_bound, right_bound) =
                    (box_lower_bound(left, query.position), box_lower_bound(right, query.position));
                let (near, far, far_bound) = if left_bound <= right_bound {
                    (left, node.right, right_bound)
                } else {
                    (right, node.left, left_bound)
                };
                if kept.len() < count || far_bound <= kept[count - 1].0 {
                    scratch.stack.push((far_bound, far));
                }
                node = near;
            }
            for slot in node.start..node.end {
                let id = self.ids[slot as usize];
                if id == query.skip {
                    continue;
                }
                let key = query.key(self.points[slot as usize]);
                // The walk's total order (a NaN key, from an overflow, included); a NaN worst
                // key never prunes a subtree above.
                let before = |&(k, i): &(f32, u32)| k.total_cmp(&key).then(i.cmp(&id)).is_lt();
                if kept.len() == count {
                    if before(&kept[count - 1]) {
                        continue; // full, and every kept point comes first
                    }
                    kept.pop();
                }
                let mut at = kept.len();
                while at > 0 && !before(&kept[at - 1]) {
                    at -= 1;
                }
                kept.insert(at, (key, id));
            }
        }
    }

    /// The walk by a heap of nodes and points ordered by (lower bound or distance, node before
    /// point, index): emits a point only when nothing closer can remain. The simple version of
    /// [`KdTree::walk`] and its oracle.
    pub fn walk_incremental(
        &self,
        query: &MetricQuery,
        heap: &mut BinaryHeap<Entry>,
        mut visit: impl FnMut(u32, f32) -> bool,
    ) {
        debug_assert!(query.alpha_squared_minus_one >= 0.0);
        heap.clear();
        if self.nodes.is_empty() {
            return;
        }
        heap.push(Entry { key: 0.0, is_point: false, order: 0, slot: 0 });
        while let Some(entry) = heap.pop() {
            if entry.is_point {
                if !visit(entry.order, entry.key) {
                    return;
                }
                continue;
            }
            let node = &self.nodes[entry.slot as usize];
            if node.left == 0 {
                for slot in node.start..node.end {
                    let id = self.ids[slot as usize];
                    if id == query.skip {
                        continue;
                    }
                    let key = query.key(self.points[slot as usize]);
                    heap.push(Entry { key, is_point: true, order: id, slot });
                }
            } else {
                for child in [node.left, node.right] {
                    let key = box_lower_bound(&self.nodes[child as usize], query.position);
                    heap.push(Entry { key, is_point: false, order: child, slot: child });
                }
            }
        }
    }
}

/// The squared Euclidean distance from `query` to the node's box, shrunk by a relative 1e-5 so
/// that rounding can never make it exceed a point's computed metric distance.
fn box_lower_bound(node: &Node, query: [f32; 3]) -> f32 {
    let mut sum = 0.0;
    for ((lo, hi), q) in node.lo.iter().zip(&node.hi).zip(&query) {
        let gap = (lo - q).max(q - hi).max(0.0);
        sum += gap * gap;
    }
    sum * (1.0 - 1e-5)
}

/// The node over `ids` (tree positions from `offset`) and, unless it is a leaf, where its ids
/// split: at the median along the box's longest axis, the ids reordered so that the left half
/// comes first (ties by index, so the split is a pure function of the points).
fn node_and_split(points: &[[f32; 3]], ids: &mut [u32], offset: u32) -> (Node, Option<usize>) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &id in ids.iter() {
        let p = points[id as usize];
        for axis in 0..3 {
            lo[axis] = lo[axis].min(p[axis]);
            hi[axis] = hi[axis].max(p[axis]);
        }
    }
    let count = ids.len() as u32;
    let node = Node { lo, hi, start: offset, end: offset + count, left: 0, right: 0 };
    let extent = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    if ids.len() <= LEAF_SIZE || extent.iter().all(|&e| e <= 0.0) {
        return (node, None);
    }
    let axis = (0..3).max_by(|&a, &b| extent[a].total_cmp(&extent[b]).then(b.cmp(&a))).unwrap_or(0);
    let middle = ids.len() / 2;
    ids.select_nth_unstable_by(middle, |&a, &b| {
        points[a as usize][axis].total_cmp(&points[b as usize][axis]).then(a.cmp(&b))
    });
    (node, Some(middle))
}

/// Appends the subtree over `ids` to `nodes` on one thread, its root first, then its left
/// subtree's nodes, then its right's; returns the root's index.
fn build_node(points: &[[f32; 3]], ids: &mut [u32], offset: u32, nodes: &mut Vec<Node>) -> u32 {
    let (node, split) = node_and_split(points, ids, offset);
    let index = nodes.len() as u32;
    nodes.push(node);
    let Some(middle) = split else { return index };
    let (left_ids, right_ids) = ids.split_at_mut(middle);
    let left = build_node(points, left_ids, offset, nodes);
    let right = build_node(points, right_ids, offset + middle as u32, nodes);
    nodes[index as usize].left = left;
    nodes[index as usize].right = right;
    index
}

/// Subtrees over at least this many points build their two halves on two threads.
const PARALLEL_BUILD_MIN: usize = 4096;

/// The nodes of the subtree over `ids` in the order [`build_node`] appends them, child indices
/// counted from the subtree's root. Large subtrees build their halves in parallel and shift the
/// halves' child indices into place, so the layout is the sequential build's, node for node,
/// for any number of threads.
fn build_subtree(points: &[[f32; 3]], ids: &mut [u32], offset: u32) -> Vec<Node> {
    if ids.len() < PARALLEL_BUILD_MIN {
        let mut nodes = Vec::with_capacity(2 * ids.len() / LEAF_SIZE + 1);
        build_node(points, ids, offset, &mut nodes);
        return nodes;
    }
    let (mut root, split) = node_and_split(points, ids, offset);
    let Some(middle) = split else { return vec![root] };
    let (left_ids, right_ids) = ids.split_at_mut(middle);
    let (left, right) = rayon::join(
        || build_subtree(points, left_ids, offset),
        || build_subtree(points, right_ids, offset + middle as u32),
    );
    // Inner nodes have left > 0 (a child comes after its parent); leaves keep 0.
    let shift = |node: &Node, by: u32| {
        if node.left != 0 {
            Node { left: node.left + by, right: node.right + by, ..*node }
        } else {
            *node
        }
    };
    (root.left, root.right) = (1, 1 + left.len() as u32);
    let mut nodes = Vec::with_capacity(1 + left.len() + right.len());
    nodes.push(root);
    nodes.extend(left.iter().map(|n| shift(n, root.left)));
    nodes.extend(right.iter().map(|n| shift(n, root.right)));
    nodes
}

/// The buffers of [`KdTree::walk`], kept across queries of one thread.
#[derive(Debug, Default)]
pub struct WalkScratch {
    heap: BinaryHeap<Entry>,
    nearest: Vec<(f32, u32)>,
    stack: Vec<(f32, u32)>,
}

/// A heap entry of the walk: a node with its lower bound or a point with its distance. The heap
/// pops the smallest (key, node before point, index) first.
#[derive(Clone, Copy, Debug)]
pub struct Entry {
    key: f32,
    is_point: bool,
    /// The point's input index, or the node's index.
    order: u32,
    slot: u32,
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Entry {}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Entry {
    /// Reversed, so that `BinaryHeap` (a max-heap) pops the smallest entry.
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .key
            .total_cmp(&self.key)
            .then(other.is_point.cmp(&self.is_point))
            .then(other.order.cmp(&self.order))
            .then(other.slot.cmp(&self.slot))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lcg::Lcg;

    fn random_points(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = Lcg(seed);
        let mut next = move || rng.uniform();
        (0..n).map(|_| [next() * 4.0, next() * 4.0, (next() * 4.0).floor() * 0.25]).collect()
    }

    #[test]
    fn the_walk_visits_every_other_point_in_metric_order() {
        let points = random_points(700, 7);
        let tree = KdTree::build(&points);
        let mut heap = BinaryHeap::new();
        for (query, normal, alpha) in [(5usize, [0.0, 0.0, 1.0], 3.0f32), (123, [0.6, 0.0, 0.8], 1.0)] {
            let a = alpha * alpha - 1.0;
            let mut walked = Vec::new();
            let q = MetricQuery { position: points[query], normal, alpha_squared_minus_one: a, skip: query as u32 };
            tree.walk_incremental(&q, &mut heap, |i, key| {
                walked.push((key, i));
                true
            });
            let mut expected: Vec<(f32, u32)> = (0..points.len() as u32)
                .filter(|&i| i as usize != query)
                .map(|i| (metric_distance_squared(sub(points[i as usize], points[query]), normal, a), i))
                .collect();
            expected.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            assert_eq!(walked.len(), points.len() - 1);
            assert!(walked.iter().zip(&expected).all(|(w, e)| w.0.to_bits() == e.0.to_bits() && w.1 == e.1));
        }
    }

    /// The parallel build lays out the sequential build's nodes, node for node, on trees of
    /// one to several parallel levels, with repeated coordinates and coincident points.
    #[test]
    fn the_parallel_build_lays_out_the_sequential_builds_nodes() {
        for (n, seed) in [(PARALLEL_BUILD_MIN - 1, 3u64), (PARALLEL_BUILD_MIN, 4), (5 * PARALLEL_BUILD_MIN + 17, 5)] {
            let mut points = random_points(n, seed);
            for i in (0..n).step_by(97) {
                points[i] = points[i / 2];
            }
            let mut ids: Vec<u32> = (0..n as u32).collect();
            let mut sequential = Vec::new();
            build_node(&points, &mut ids, 0, &mut sequential);
            let pool = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
            let tree = pool.install(|| KdTree::build(&points));
            assert_eq!(tree.nodes.len(), sequential.len(), "{n} points");
            for (a, b) in tree.nodes.iter().zip(&sequential) {
                assert_eq!(
                    (a.lo, a.hi, a.start, a.end, a.left, a.right),
                    (b.lo, b.hi, b.start, b.end, b.left, b.right)
                );
            }
            assert_eq!(tree.ids, ids, "{n} points: the leaf order");
        }
    }

    #[test]
    fn the_metric_counts_the_normal_component_alpha_times() {
        let up = [0.0, 0.0, 1.0];
        assert_eq!(metric_distance_squared([0.0, 0.0, 2.0], up, 8.0), 36.0, "(3 · 2)²");
        assert_eq!(metric_distance_squared([2.0, 0.0, 0.0], up, 8.0), 4.0, "tangent offsets are unchanged");
        // |d + (α − 1)(d·n)n|² for a tilted normal, computed directly.
        let (d, n, alpha) = ([0.3f32, -1.2, 0.5], [0.0f32, 0.6, 0.8], 3.0f32);
        let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
        let stretched: Vec<f32> = (0..3).map(|c| d[c] + (alpha - 1.0) * dn * n[c]).collect();
        let direct: f32 = stretched.iter().map(|v| v * v).sum();
        assert!((metric_distance_squared(d, n, alpha * alpha - 1.0) - direct).abs() < 1e-5);
    }

    #[test]
    fn degenerate_sets_build() {
        assert!(KdTree::build(&[]).is_empty());
        let same = vec![[1.0, 2.0, 3.0]; 50];
        let tree = KdTree::build(&same);
        let mut heap = BinaryHeap::new();
        let mut order = Vec::new();
        let q =
            MetricQuery { position: [1.0, 2.0, 3.0], normal: [0.0, 0.0, 1.0], alpha_squared_minus_one: 8.0, skip: 10 };
        tree.walk_incremental(&q, &mut heap, |i, _| {
            order.push(i);
            true
        });
        let expected: Vec<u32> = (0..50).filter(|&i| i != 10).collect();
        assert_eq!(order, expected, "equal distances come in index order");
        for wanted in [0, 1, 7, 12, 49, 60] {
            let mut order = Vec::new();
            tree.walk(&q, 12, &mut WalkScratch::default(), |i, _| {
                order.push(i);
                order.len() < wanted
            });
            let count = wanted.clamp(1, 49);
            assert_eq!(
                order,
                expected[..count],
                "ties in index order through the search and the heap, {wanted} wanted"
            );
        }
        let mut nothing = Vec::new();
        KdTree::build(&[]).walk(&q, 12, &mut WalkScratch::default(), |i, _| {
            nothing.push(i);
            true
        });
        assert!(nothing.is_empty());
    }

    /// The walk (bounded search, then the heap walk past what it gave) against the heap walk
    /// alone, for every split of the work: prefix sizes from 0 to past the point count, visitors
    /// stopping before, at and after the prefix, clustered points with duplicates and ties.
    #[test]
    fn the_walk_gives_the_incremental_walks_order_for_any_prefix() {
        let mut points = random_points(500, 11);
        points.extend_from_within(0..40); // exact duplicates: equal keys, told apart by index
        points.extend((0..60).map(|i| [2.0, 2.0, 0.001 * (i % 3) as f32])); // a tight cluster
        let tree = KdTree::build(&points);
        let mut heap = BinaryHeap::new();
        let mut scratch = WalkScratch::default();
        let mut rng = Lcg(3);
        for query in [0usize, 17, 499, 505, 560, 599] {
            let z = rng.uniform() * 2.0 - 1.0;
            let r = (1.0 - z * z).sqrt();
            let normal = [r, 0.0, z];
            for alpha in [1.0f32, 3.0] {
                let a = alpha * alpha - 1.0;
                let mut all = Vec::new();
                let q = MetricQuery { position: points[query], normal, alpha_squared_minus_one: a, skip: query as u32 };
                tree.walk_incremental(&q, &mut heap, |i, key| {
                    all.push((key.to_bits(), i));
                    true
                });
                assert_eq!(all.len(), points.len() - 1);
                for expected in [0usize, 1, 5, 12, 16, 64, 599, 700] {
                    for stop_after in [1usize, 4, 12, 13, 40, 599, usize::MAX] {
                        let mut got = Vec::new();
                        tree.walk(&q, expected, &mut scratch, |i, key| {
                            got.push((key.to_bits(), i));
                            got.len() < stop_after
                        });
                        let count = stop_after.min(all.len());
                        assert_eq!(
                            got,
                            all[..count],
                            "query {query}, α {alpha}, expected {expected}, stop {stop_after}"
                        );
                    }
                }
            }
        }
    }
}
