//! A small static 3-d tree for nearest-neighbour distances between point samples (implicit layout:
//! the median of each range is the node, split on the axis of largest spread; each range's
//! bounding box is stored). Robust to many points sharing a coordinate, which sampled walls and
//! floors produce.
//!
//! The search enters a subtree only when the subtree's bounding box is nearer to the query than
//! the best distance so far, nearer child first. Pruning by the splitting plane alone (what this
//! tree did first) prunes nothing once the best distance exceeds the distance to most planes,
//! which is every query far from the points: a poorly trained run's mesh floating metres from the
//! ground truth made `eval` enter nearly the whole tree per point (5 min 46 s where a trained run
//! takes 12 s). The cells of Arya & Mount's incremental distance (the root's box cut by the
//! splitting planes above) fix queries outside the points' box but not those inside a room, whose
//! cells on a wall keep the room's whole extent across the wall: with 200k points on a room's
//! walls and queries on a sphere in its middle, those cells still had each query enter ~7,000
//! nodes, the tight boxes ~40 (`examples/kdtree_bench.rs` has the old search and the cases). The
//! boxes cost 24 bytes a point.

use rayon::prelude::*;

pub struct KdTree {
    points: Vec<[f32; 3]>,
    /// Bounding box `[min, max]` of each range's points, stored at its node's position for an
    /// inner range, at its first position for a leaf (no node sits there).
    boxes: Vec<[[f32; 3]; 2]>,
}

const LEAF_SIZE: usize = 8;

/// Squared distance, summed in the axis order of [`box_distance_sq`]: the box bound is then never
/// above the distance of a point inside the box, in floating point too, and the search stays
/// exactly the brute-force minimum.
fn dist_sq(p: [f32; 3], q: [f32; 3]) -> f32 {
    (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)
}

/// Squared distance from `q` to the box (0 inside). Each axis's offset is no more than the rounded
/// |p − q| on that axis of any point p in the box (rounding is monotonic), so this is no more than
/// [`dist_sq`] of any such point.
fn box_distance_sq(b: &[[f32; 3]; 2], q: [f32; 3]) -> f32 {
    let off = |a: usize| (b[0][a] - q[a]).max(q[a] - b[1][a]).max(0.0);
    off(0).powi(2) + off(1).powi(2) + off(2).powi(2)
}

/// Indices of `points` sorted along the Z-order curve of their bounding box (21 bits per axis).
fn morton_order(points: &[[f32; 3]]) -> Vec<usize> {
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
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
    let scale: [f32; 3] = std::array::from_fn(|a| {
        let extent = max[a] - min[a];
        if extent > 0.0 {
            ((1u32 << 21) - 1) as f32 / extent
        } else {
            0.0
        }
    });
    let key = |p: &[f32; 3]| {
        // Non-finite coordinates (never in a sampled mesh) cast to some cell; the order only
        // affects speed.
        (0..3).fold(0u64, |k, a| k | spread(((p[a] - min[a]) * scale[a]) as u64) << a)
    };
    let mut order: Vec<(u64, usize)> = points.iter().enumerate().map(|(i, p)| (key(p), i)).collect();
    order.par_sort_unstable();
    order.into_iter().map(|(_, i)| i).collect()
}

impl KdTree {
    pub fn new(points: &[[f32; 3]]) -> KdTree {
        let mut tree = KdTree {
            points: points.to_vec(),
            boxes: vec![[[0.0; 3]; 2]; points.len()],
        };
        let n = tree.points.len();
        tree.build(0, n);
        tree
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Position of the range's box in `boxes` (and of its node, for an inner range).
    fn slot(lo: usize, hi: usize) -> usize {
        if hi - lo <= LEAF_SIZE {
            lo
        } else {
            (lo + hi) / 2
        }
    }

    fn build(&mut self, lo: usize, hi: usize) {
        if lo == hi {
            return;
        }
        let mut min = [f32::INFINITY; 3];
        let mut max = [f32::NEG_INFINITY; 3];
        for p in &self.points[lo..hi] {
            for a in 0..3 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        self.boxes[Self::slot(lo, hi)] = [min, max];
        if hi - lo <= LEAF_SIZE {
            return;
        }
        let axis = (0..3)
            .max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b])))
            .unwrap();
        let mid = (lo + hi) / 2;
        self.points[lo..hi].select_nth_unstable_by(mid - lo, |p, q| p[axis].total_cmp(&q[axis]));
        self.build(lo, mid);
        self.build(mid + 1, hi);
    }

    /// Euclidean distance to the nearest stored point (`+inf` for an empty tree); exactly the
    /// brute-force minimum.
    pub fn nearest_distance(&self, query: [f32; 3]) -> f32 {
        self.nearest_distance_counted(query).0
    }

    /// [`KdTree::nearest_distance`] with the number of tree nodes (inner nodes and leaves) the
    /// search entered: the cost of the query, for tests and benchmarks.
    pub fn nearest_distance_counted(&self, query: [f32; 3]) -> (f32, usize) {
        let (mut best, mut visited) = (f32::INFINITY, 0);
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
    pub fn nearest_distances(&self, queries: &[[f32; 3]], on_done: &(dyn Fn(usize) + Sync)) -> Vec<f32> {
        const BATCH: usize = 4096;
        let order = morton_order(queries);
        let sorted: Vec<f32> = order
            .par_chunks(BATCH)
            .flat_map_iter(|batch| {
                let d: Vec<f32> = batch.iter().map(|&i| self.nearest_distance(queries[i])).collect();
                on_done(batch.len());
                d
            })
            .collect();
        let mut out = vec![0.0; queries.len()];
        for (&i, d) in order.iter().zip(sorted) {
            out[i] = d;
        }
        out
    }

    /// Searches the non-empty range `lo..hi` (its box already found nearer than `best`).
    fn search(&self, q: [f32; 3], lo: usize, hi: usize, best: &mut f32, visited: &mut usize) {
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
        let d = children.map(|(l, h)| box_distance_sq(&self.boxes[Self::slot(l, h)], q));
        let order = if d[0] <= d[1] { [0, 1] } else { [1, 0] };
        for k in order {
            // `best` may have shrunk in the first child: the second is tested after it.
            if d[k] < *best {
                self.search(q, children[k].0, children[k].1, best, visited);
            }
        }
    }
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
        assert_eq!(KdTree::new(&[]).nearest_distance([0.0; 3]), f32::INFINITY);
        assert_eq!(KdTree::new(&[[1.0, 2.0, 3.0]]).nearest_distance([1.0, 2.0, 7.0]), 4.0);
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
}
