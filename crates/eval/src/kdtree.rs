//! A small static 3-d tree for nearest-neighbour distances between point samples (implicit layout:
//! the median of each range is the node, split on the axis of largest spread). Robust to many
//! points sharing a coordinate, which sampled walls and floors produce.

pub struct KdTree {
    points: Vec<[f32; 3]>,
    /// Split axis of the node stored at each position (meaningful for inner nodes only).
    axes: Vec<u8>,
}

const LEAF_SIZE: usize = 8;

impl KdTree {
    pub fn new(points: &[[f32; 3]]) -> KdTree {
        let mut tree = KdTree {
            points: points.to_vec(),
            axes: vec![0; points.len()],
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

    fn build(&mut self, lo: usize, hi: usize) {
        if hi - lo <= LEAF_SIZE {
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
        let axis = (0..3)
            .max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b])))
            .unwrap();
        let mid = (lo + hi) / 2;
        self.points[lo..hi].select_nth_unstable_by(mid - lo, |p, q| p[axis].total_cmp(&q[axis]));
        self.axes[mid] = axis as u8;
        self.build(lo, mid);
        self.build(mid + 1, hi);
    }

    /// Euclidean distance to the nearest stored point (`+inf` for an empty tree).
    pub fn nearest_distance(&self, query: [f32; 3]) -> f32 {
        let mut best = f32::INFINITY;
        self.search(query, 0, self.points.len(), &mut best);
        best.sqrt()
    }

    fn search(&self, q: [f32; 3], lo: usize, hi: usize, best: &mut f32) {
        if hi - lo <= LEAF_SIZE {
            for p in &self.points[lo..hi] {
                let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                *best = best.min(d);
            }
            return;
        }
        let mid = (lo + hi) / 2;
        let p = self.points[mid];
        let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
        *best = best.min(d);
        let axis = self.axes[mid] as usize;
        let diff = q[axis] - p[axis];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search(q, near.0, near.1, best);
        if diff * diff < *best {
            self.search(q, far.0, far.1, best);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

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
            let brute = points
                .iter()
                .map(|p| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2))
                .fold(f32::INFINITY, f32::min)
                .sqrt();
            assert_eq!(tree.nearest_distance(q), brute);
        }
        assert_eq!(KdTree::new(&[]).nearest_distance([0.0; 3]), f32::INFINITY);
    }
}
