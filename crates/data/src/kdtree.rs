//! The one point-neighbour structure of the house: a small static 3-d tree over points in f32 or
//! f64 (implicit layout: the median of each range is the node, split on the axis of largest
//! spread; each range's bounding box is stored). Robust to many points sharing a coordinate,
//! which sampled walls and floors produce. It answers two questions:
//!
//! - the distance to the nearest point ([`KdTree::nearest_distance`], batched in
//!   [`KdTree::nearest_distances`]): `eval`'s mesh accuracy, completeness and F-score;
//! - the points within a radius ([`KdTree::within`], [`KdTree::for_each_within`]): stage 2's
//!   connected pieces of emitter points (f64) and its pooling of diffuse sums over a surface
//!   (f32).
//!
//! The nearest search enters a subtree only when the subtree's bounding box is nearer to the
//! query than the best distance so far, nearer child first. Pruning by the splitting plane alone
//! (what this tree did first) prunes nothing once the best distance exceeds the distance to most
//! planes, which is every query far from the points: a poorly trained run's mesh floating metres
//! from the ground truth made `eval` enter nearly the whole tree per point (5 min 46 s where a
//! trained run takes 12 s). The cells of Arya & Mount's incremental distance (the root's box cut
//! by the splitting planes above) fix queries outside the points' box but not those inside a
//! room, whose cells on a wall keep the room's whole extent across the wall: with 200k points on
//! a room's walls and queries on a sphere in its middle, those cells still had each query enter
//! ~7,000 nodes, the tight boxes ~40 (the eval crate's `examples/kdtree_bench.rs` has the old
//! search and the cases). The boxes cost 6 coordinates a point; the input index of each point
//! (what the radius queries report) 4 bytes more.
//!
//! The radius search enters a subtree when its box is within the radius, and reports a point when
//! its squared distance, computed as [`KdTree`]'s own (x, then y, then z, in the points'
//! precision), is at most the radius squared in that precision: exactly the points a caller
//! finds testing `d² <= r²` on every point with the same arithmetic (the box bound never exceeds
//! the distance of a point inside, see `box_distance_sq`; a subtree whose box lies wholly
//! inside the radius, `box_far_sq`, is reported without testing). [`KdTree::within`] lists them in
//! ascending input index, so sums over neighbours do not depend on the tree's layout, the run or
//! the number of threads. (Exact for any points, NaN coordinates included, and a finite or NaN
//! query.)

use rayon::prelude::*;
use std::cmp::Ordering;
use std::ops::{Add, Div, Mul, Sub};

/// A coordinate type of the tree: `f32` or `f64`.
pub trait Coordinate:
    Copy
    + PartialOrd
    + Send
    + Sync
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + 'static
{
    const ZERO: Self;
    const INFINITY: Self;
    const NEG_INFINITY: Self;
    const NAN: Self;
    fn is_nan(self) -> bool;
    fn min(self, other: Self) -> Self;
    fn max(self, other: Self) -> Self;
    fn total_cmp(&self, other: &Self) -> Ordering;
    fn sqrt(self) -> Self;
    /// Exact for both types (Morton keys are computed in the points' precision, then widened).
    fn to_f64(self) -> f64;
    /// Used for constants exact in both types.
    fn from_f64(v: f64) -> Self;
}

macro_rules! coordinate {
    ($t:ty) => {
        impl Coordinate for $t {
            const ZERO: Self = 0.0;
            const INFINITY: Self = <$t>::INFINITY;
            const NEG_INFINITY: Self = <$t>::NEG_INFINITY;
            const NAN: Self = <$t>::NAN;
            #[inline(always)]
            fn is_nan(self) -> bool {
                <$t>::is_nan(self)
            }
            #[inline(always)]
            fn min(self, other: Self) -> Self {
                <$t>::min(self, other)
            }
            #[inline(always)]
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
            #[inline(always)]
            fn total_cmp(&self, other: &Self) -> Ordering {
                <$t>::total_cmp(self, other)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
        }
    };
}
coordinate!(f32);
coordinate!(f64);

pub struct KdTree<T: Coordinate = f32> {
    points: Vec<[T; 3]>,
    /// Bounding box `[min, max]` of each range's points, stored at its node's position for an
    /// inner range, at its first position for a leaf (no node sits there).
    boxes: Vec<[[T; 3]; 2]>,
    /// The input index of each stored point.
    index: Vec<u32>,
}

const LEAF_SIZE: usize = 8;

/// Squared distance, summed in the axis order of [`box_distance_sq`]: the box bound is then never
/// above the distance of a point inside the box, in floating point too, and the searches stay
/// exactly the brute-force answers. (`x * x` is what `powi(2)` computes: one rounded product.)
#[inline(always)]
fn dist_sq<T: Coordinate>(p: [T; 3], q: [T; 3]) -> T {
    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// Squared distance from `q` to the box (0 inside). Each axis's offset is no more than the rounded
/// |p − q| on that axis of any point p in the box (rounding is monotonic), so this is no more than
/// [`dist_sq`] of any such point.
#[inline(always)]
fn box_distance_sq<T: Coordinate>(b: &[[T; 3]; 2], q: [T; 3]) -> T {
    let off = |a: usize| (b[0][a] - q[a]).max(q[a] - b[1][a]).max(T::ZERO);
    let o = [off(0), off(1), off(2)];
    o[0] * o[0] + o[1] * o[1] + o[2] * o[2]
}

/// Squared distance from `q` to the box's farthest corner: no less than [`dist_sq`] of any point
/// in the box (on each axis the rounded |p − q| is at most the larger of the corners' rounded
/// offsets, rounding being monotonic), so a box this near lies wholly within the radius.
#[inline(always)]
fn box_far_sq<T: Coordinate>(b: &[[T; 3]; 2], q: [T; 3]) -> T {
    let off = |a: usize| (q[a] - b[0][a]).max(b[1][a] - q[a]);
    let o = [off(0), off(1), off(2)];
    o[0] * o[0] + o[1] * o[1] + o[2] * o[2]
}

/// Indices of `points` sorted along the Z-order curve of their bounding box (21 bits per axis).
fn morton_order<T: Coordinate>(points: &[[T; 3]]) -> Vec<usize> {
    let mut min = [T::INFINITY; 3];
    let mut max = [T::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
            max[a] = max[a].max(p[a]);
        }
    }
    /// Spreads the low 21 bits of `v` to every third bit.
    fn spread(v: u64) -> u64 {
        let mut x = v & 0x1f_ffff;
        x = (x | x << 32) & 0x1f00000000ffff;
        x = (x | x << 16) & 0x1f0000ff0000ff;
        x = (x | x << 8) & 0x100f00f00f00f00f;
        x = (x | x << 4) & 0x10c30c30c30c30c3;
        (x | x << 2) & 0x1249249249249249
    }
    let scale: [T; 3] = std::array::from_fn(|a| {
        let extent = max[a] - min[a];
        if extent > T::ZERO {
            T::from_f64(((1u32 << 21) - 1) as f64) / extent
        } else {
            T::ZERO
        }
    });
    let key = |p: &[T; 3]| {
        // Non-finite coordinates (never in a sampled mesh) cast to some cell; the order only
        // affects speed.
        (0..3).fold(0u64, |k, a| {
            k | spread(((p[a] - min[a]) * scale[a]).to_f64() as u64) << a
        })
    };
    let mut order: Vec<(u64, usize)> = points.iter().enumerate().map(|(i, p)| (key(p), i)).collect();
    order.par_sort_unstable();
    order.into_iter().map(|(_, i)| i).collect()
}

impl<T: Coordinate> KdTree<T> {
    /// The tree of `points` (at most `u32::MAX` of them); the radius queries report their
    /// indices in this slice.
    pub fn new(points: &[[T; 3]]) -> KdTree<T> {
        assert!(u32::try_from(points.len()).is_ok(), "at most u32::MAX points");
        let n = points.len();
        let mut items: Vec<([T; 3], u32)> = points.iter().enumerate().map(|(i, &p)| (p, i as u32)).collect();
        let mut boxes = vec![[[T::ZERO; 3]; 2]; n];
        build(&mut items, &mut boxes, 0, n);
        let (points, index) = items.into_iter().unzip();
        KdTree { points, boxes, index }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The input indices of the points in the tree's storage order, where points near each other
    /// mostly are near each other: radius queries at the points themselves, taken in this order,
    /// find their neighbours' data still in cache (as [`KdTree::nearest_distances`] does with
    /// its Morton order).
    pub fn storage_order(&self) -> &[u32] {
        &self.index
    }

    /// Euclidean distance to the nearest stored point (`+inf` for an empty tree); exactly the
    /// brute-force minimum.
    pub fn nearest_distance(&self, query: [T; 3]) -> T {
        self.nearest_distance_counted(query).0
    }

    /// [`KdTree::nearest_distance`] with the number of tree nodes (inner nodes and leaves) the
    /// search entered: the cost of the query, for tests and benchmarks.
    pub fn nearest_distance_counted(&self, query: [T; 3]) -> (T, usize) {
        let (mut best, mut visited) = (T::INFINITY, 0);
        if !self.points.is_empty() {
            self.search(query, 0, self.points.len(), &mut best, &mut visited);
        }
        (best.sqrt(), visited)
    }

    /// The distance from each query to its nearest stored point, in the order of `queries`,
    /// computed in parallel; `on_done(k)` is called as each batch of `k` queries is answered.
    ///
    /// The queries are answered in Morton (Z-curve) order, so that consecutive queries walk the
    /// same part of the tree while it is in cache; in `queries`' own order (random, for points
    /// sampled on a mesh) a query entering a few hundred nodes waits on memory at nearly every
    /// one of them.
    pub fn nearest_distances(&self, queries: &[[T; 3]], on_done: &(dyn Fn(usize) + Sync)) -> Vec<T> {
        const BATCH: usize = 4096;
        let order = morton_order(queries);
        let sorted: Vec<T> = order
            .par_chunks(BATCH)
            .flat_map_iter(|batch| {
                let d: Vec<T> = batch.iter().map(|&i| self.nearest_distance(queries[i])).collect();
                on_done(batch.len());
                d
            })
            .collect();
        let mut out = vec![T::ZERO; queries.len()];
        for (&i, d) in order.iter().zip(sorted) {
            out[i] = d;
        }
        out
    }

    /// Searches the non-empty range `lo..hi` (its box already found nearer than `best`).
    fn search(&self, q: [T; 3], lo: usize, hi: usize, best: &mut T, visited: &mut usize) {
        *visited += 1;
        if hi - lo <= LEAF_SIZE {
            for p in &self.points[lo..hi] {
                *best = best.min(dist_sq(*p, q));
            }
            return;
        }
        let mid = (lo + hi) / 2;
        *best = best.min(dist_sq(self.points[mid], q));
        let children = [(lo, mid), (mid + 1, hi)];
        let d = children.map(|(l, h)| box_distance_sq(&self.boxes[slot(l, h)], q));
        let order = if d[0] <= d[1] { [0, 1] } else { [1, 0] };
        for k in order {
            // `best` may have shrunk in the first child: the second is tested after it.
            if d[k] < *best {
                self.search(q, children[k].0, children[k].1, best, visited);
            }
        }
    }

    /// Calls `f(i)` for the input index `i` of every point `p` with `dist²(p, query) <= radius²`
    /// (see the module doc: the squares and their sum in `T`, x then y then z), each once, in the
    /// tree's order: fixed for given points (no threads, no hashing), but no particular one. For
    /// sums over the neighbours, [`KdTree::within`] lists them in index order.
    pub fn for_each_within(&self, query: [T; 3], radius: T, mut f: impl FnMut(usize)) {
        let r2 = radius * radius;
        let n = self.points.len();
        if n > 0 && box_distance_sq(&self.boxes[slot(0, n)], query) <= r2 {
            self.visit_within(query, r2, 0, n, &mut f);
        }
    }

    /// The input indices of the points [`KdTree::for_each_within`] finds, in ascending order, in
    /// `out` (cleared first; reusing one buffer across queries saves its allocation).
    pub fn within(&self, query: [T; 3], radius: T, out: &mut Vec<usize>) {
        out.clear();
        self.for_each_within(query, radius, |i| out.push(i));
        out.sort_unstable();
    }

    /// Reports the points of the non-empty range `lo..hi` within `r2` (its box reaches it).
    fn visit_within<F: FnMut(usize)>(&self, q: [T; 3], r2: T, lo: usize, hi: usize, f: &mut F) {
        if box_far_sq(&self.boxes[slot(lo, hi)], q) <= r2 {
            // Wholly inside: every point passes the test, which is skipped (dense neighbourhoods,
            // such as emitter points a link apart, are reported at the cost of a copy).
            self.index[lo..hi].iter().for_each(|&i| f(i as usize));
            return;
        }
        if hi - lo <= LEAF_SIZE {
            for (p, &i) in self.points[lo..hi].iter().zip(&self.index[lo..hi]) {
                if dist_sq(*p, q) <= r2 {
                    f(i as usize);
                }
            }
            return;
        }
        let mid = (lo + hi) / 2;
        if dist_sq(self.points[mid], q) <= r2 {
            f(self.index[mid] as usize);
        }
        for (l, h) in [(lo, mid), (mid + 1, hi)] {
            if box_distance_sq(&self.boxes[slot(l, h)], q) <= r2 {
                self.visit_within(q, r2, l, h, f);
            }
        }
    }
}

/// Position of the range's box in `boxes` (and of its node, for an inner range).
fn slot(lo: usize, hi: usize) -> usize {
    if hi - lo <= LEAF_SIZE {
        lo
    } else {
        (lo + hi) / 2
    }
}

/// Builds the range `lo..hi` of `items` (points with their input indices) in place and stores
/// its boxes.
fn build<T: Coordinate>(items: &mut [([T; 3], u32)], boxes: &mut [[[T; 3]; 2]], lo: usize, hi: usize) {
    if lo == hi {
        return;
    }
    let mut min = [T::INFINITY; 3];
    let mut max = [T::NEG_INFINITY; 3];
    let mut nan = false;
    for (p, _) in &items[lo..hi] {
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
            max[a] = max[a].max(p[a]);
            nan |= p[a].is_nan();
        }
    }
    // A range holding a NaN coordinate gets a NaN box: never pruned (its distance bound is 0)
    // nor reported whole (its far bound is no number), so its NaN points stay unreported, as
    // their distance, NaN, is never within a radius.
    boxes[slot(lo, hi)] = if nan { [[T::NAN; 3]; 2] } else { [min, max] };
    if hi - lo <= LEAF_SIZE {
        return;
    }
    let axis = (0..3)
        .max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b])))
        .unwrap();
    let mid = (lo + hi) / 2;
    items[lo..hi].select_nth_unstable_by(mid - lo, |p, q| p.0[axis].total_cmp(&q.0[axis]));
    build(items, boxes, lo, mid);
    build(items, boxes, mid + 1, hi);
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn brute_force(points: &[[f32; 3]], q: [f32; 3]) -> f32 {
        points
            .iter()
            .map(|p| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2))
            .fold(f32::INFINITY, f32::min)
            .sqrt()
    }

    #[test]
    fn matches_brute_force_with_duplicates_and_planes() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let mut points: Vec<[f32; 3]> = (0..3000)
            .map(|_| [rng.gen_range(0.0..1.0), rng.gen_range(0.0..1.0), 0.0])
            .collect();
        points.extend(std::iter::repeat_n([0.5, 0.5, 0.5], 100));
        points.extend((0..500).map(|_| [rng.gen_range(0.0..1.0), 1.0, rng.gen_range(0.0..1.0)]));
        let tree = KdTree::new(&points);
        for _ in 0..500 {
            let q = [
                rng.gen_range(-0.2..1.2),
                rng.gen_range(-0.2..1.2),
                rng.gen_range(-0.2..1.2),
            ];
            assert_eq!(tree.nearest_distance(q), brute_force(&points, q));
        }
        assert_eq!(KdTree::<f32>::new(&[]).nearest_distance([0.0; 3]), f32::INFINITY);
        assert_eq!(
            KdTree::<f32>::new(&[[1.0, 2.0, 3.0]]).nearest_distance([1.0, 2.0, 7.0]),
            4.0
        );
        assert_eq!(
            KdTree::<f64>::new(&[[1.0, 2.0, 3.0]]).nearest_distance([1.0, 2.0, 7.0]),
            4.0
        );
    }

    /// Queries 10 units from a unit square of points (above it, beside it, off a corner): exact,
    /// and each enters a handful of nodes, where pruning by the splitting planes alone entered
    /// nearly all of them (every plane is nearer than the best distance).
    #[test]
    fn far_queries_are_exact_and_cheap() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let points: Vec<[f32; 3]> = (0..20_000)
            .map(|_| [rng.gen_range(0.0..1.0), rng.gen_range(0.0..1.0), 0.0])
            .collect();
        let tree = KdTree::new(&points);
        let nodes = 2 * points.len() / LEAF_SIZE;
        let mut most = 0;
        for k in 0..300 {
            let (u, v) = (rng.gen_range(-0.5..1.5), rng.gen_range(-0.5..1.5));
            let q = match k % 3 {
                0 => [u, v, 10.0],
                1 => [11.0, u, v],
                _ => [-9.0, -9.0 + u, -3.0 * v],
            };
            let (d, visited) = tree.nearest_distance_counted(q);
            assert_eq!(d, brute_force(&points, q), "{q:?}");
            most = most.max(visited);
        }
        assert!(most < 200, "{most} of about {nodes} nodes entered");
    }

    /// 200k points on the faces of a unit cube and 20k queries scattered through a box 21 units
    /// wide around it, nearly all of them metres away: a few dozen nodes per query on average
    /// (of 50k), and never many for a query outside the cube. (A query inside, near the centre, is
    /// nearly equidistant from several faces and may enter thousands: no tree avoids that.)
    #[test]
    fn a_large_cloud_answers_far_queries_in_few_nodes() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let points: Vec<[f32; 3]> = (0..200_000)
            .map(|i| {
                let mut p: [f32; 3] = std::array::from_fn(|_| rng.gen_range(0.0..1.0));
                p[i % 3] = (i % 2) as f32;
                p
            })
            .collect();
        let tree = KdTree::new(&points);
        let queries: Vec<[f32; 3]> = (0..20_000)
            .map(|_| std::array::from_fn(|_| rng.gen_range(-10.0..11.0)))
            .collect();
        let (mut total, mut most_outside) = (0, 0);
        for (k, &q) in queries.iter().enumerate() {
            let (d, visited) = tree.nearest_distance_counted(q);
            if k % 400 == 0 {
                assert_eq!(d, brute_force(&points, q), "{q:?}");
            }
            total += visited;
            if q.iter().any(|&x| !(0.0..=1.0).contains(&x)) {
                most_outside = most_outside.max(visited);
            }
        }
        let mean = total as f64 / queries.len() as f64;
        assert!(
            mean < 50.0 && most_outside < 400,
            "mean {mean}, at most {most_outside} nodes per query outside the cube"
        );
    }

    /// The batch answers in the queries' order (it works in Morton order inside) and reports
    /// every query once.
    #[test]
    fn batches_answer_in_the_queries_order() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        let mut cloud = || -> Vec<[f32; 3]> {
            (0..10_000)
                .map(|_| std::array::from_fn(|_| rng.gen_range(-2.0..2.0)))
                .collect()
        };
        let (points, queries) = (cloud(), cloud());
        let tree = KdTree::new(&points);
        let answered = std::sync::atomic::AtomicUsize::new(0);
        let d = tree.nearest_distances(&queries, &|k| {
            answered.fetch_add(k, std::sync::atomic::Ordering::Relaxed);
        });
        let one_by_one: Vec<f32> = queries.iter().map(|&q| tree.nearest_distance(q)).collect();
        assert_eq!(d, one_by_one);
        assert_eq!(answered.into_inner(), queries.len());
        assert!(KdTree::new(&points).nearest_distances(&[], &|_| {}).is_empty());
    }

    /// The points of `points` with `d² <= r²` by the tree's arithmetic, in index order.
    fn brute_within<T: Coordinate>(points: &[[T; 3]], q: [T; 3], r: T) -> Vec<usize> {
        (0..points.len()).filter(|&i| dist_sq(points[i], q) <= r * r).collect()
    }

    /// Checks `within` and `for_each_within` against brute force for every query and radius.
    fn check_within<T: Coordinate + std::fmt::Debug>(points: &[[T; 3]], queries: &[[T; 3]], radii: &[T]) -> usize {
        let tree = KdTree::new(points);
        let (mut buf, mut found) = (Vec::new(), 0);
        for &q in queries {
            for &r in radii {
                let expected = brute_within(points, q, r);
                tree.within(q, r, &mut buf);
                assert_eq!(buf, expected, "query {q:?}, radius {r:?}");
                let mut visited = Vec::new();
                tree.for_each_within(q, r, |i| visited.push(i));
                visited.sort_unstable();
                assert_eq!(visited, expected, "each point once, query {q:?}, radius {r:?}");
                found += expected.len();
            }
        }
        found
    }

    /// Random points with duplicates and planes, in f32 and f64, several radii (0 and one
    /// wider than the cloud included): the radius query finds exactly the brute-force set.
    #[test]
    fn radius_queries_match_brute_force() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let mut points: Vec<[f64; 3]> = (0..2000)
            .map(|_| std::array::from_fn(|_| rng.gen_range(-1.0..1.0)))
            .collect();
        points.extend((0..1000).map(|_| [rng.gen_range(-1.0..1.0), 0.25, rng.gen_range(-1.0..1.0)]));
        points.extend(std::iter::repeat_n([0.1, 0.2, 0.3], 50));
        let mut queries: Vec<[f64; 3]> = (0..150)
            .map(|_| std::array::from_fn(|_| rng.gen_range(-1.5..1.5)))
            .collect();
        // Queries on stored points (a point is its own neighbour at radius 0).
        queries.extend(points.iter().step_by(97).copied());
        queries.push([0.1, 0.2, 0.3]);
        let radii = [0.0, 0.01, 0.05, 0.1, 0.3, 4.0];
        let found = check_within(&points, &queries, &radii);
        let p32: Vec<[f32; 3]> = points.iter().map(|p| p.map(|x| x as f32)).collect();
        let q32: Vec<[f32; 3]> = queries.iter().map(|p| p.map(|x| x as f32)).collect();
        let found32 = check_within(&p32, &q32, &radii.map(|r| r as f32));
        assert!(found > 10 * queries.len() && found32 > 10 * queries.len());
        let mut order = KdTree::new(&points).storage_order().to_vec();
        order.sort_unstable();
        assert!(order.iter().enumerate().all(|(k, &i)| i as usize == k));
        // Points with NaN coordinates are never neighbours, and hide none.
        let mut with_nan = p32.clone();
        for k in (0..with_nan.len()).step_by(7) {
            with_nan[k][k % 3] = f32::NAN;
        }
        check_within(&with_nan, &q32, &[0.05, 0.3, 4.0, f32::INFINITY]);
        // Empty trees and a negative radius (its square is positive: as `d² <= r²` says).
        assert!(check_within::<f32>(&[], &q32, &[1.0]) == 0);
        assert_eq!(brute_within(&points, [0.0; 3], -4.0).len(), points.len());
        assert_eq!(check_within(&points, &[[0.0; 3]], &[-4.0]), points.len());
    }

    /// Points on an integer lattice and queries on and between its points: many squared
    /// distances equal the squared radius exactly, and those points are found (`<=`), in f32 and
    /// f64; the same points nudged by one ulp outward are not.
    #[test]
    fn points_exactly_at_the_radius_are_neighbours() {
        let lattice: Vec<[f64; 3]> = (0..7 * 7 * 7)
            .map(|i| [(i % 7) as f64, (i / 7 % 7) as f64, (i / 49) as f64])
            .collect();
        let queries = [[3.0, 3.0, 3.0], [0.0, 0.0, 0.0], [2.5, 3.0, 3.5], [6.0, 0.0, 3.0]];
        let radii = [1.0, 2.0, 3.0, 1.5, 5.0];
        check_within(&lattice, &queries, &radii);
        let l32: Vec<[f32; 3]> = lattice.iter().map(|p| p.map(|x| x as f32)).collect();
        check_within(&l32, &queries.map(|q| q.map(|x| x as f32)), &radii.map(|r| r as f32));
        let tree = KdTree::new(&lattice);
        let mut buf = Vec::new();
        // The 6 axis neighbours at distance 1, the point itself, and (2, 2, 1)-type points at 3.
        tree.within([3.0, 3.0, 3.0], 1.0, &mut buf);
        assert_eq!(buf.len(), 7);
        tree.within([3.0, 3.0, 3.0], 3.0, &mut buf);
        assert!(buf.contains(&(5 + 5 * 7 + 4 * 49)), "(5, 5, 4) is 3 from (3, 3, 3)");
        let nudged = [
            [f32::from_bits(4.0f32.to_bits() + 1), 3.0, 3.0],
            [3.0, 3.0, f32::from_bits(2.0f32.to_bits() - 1)],
        ];
        let t32 = KdTree::new(&nudged);
        t32.within([3.0, 3.0, 3.0], 1.0, &mut buf);
        assert!(buf.is_empty(), "{buf:?}");
    }
}
