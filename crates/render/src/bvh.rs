//! A binned-SAH bounding volume hierarchy over triangles, with closest-hit and any-hit (shadow)
//! queries in f32. Moved from `i2sdf-synth` so that every physical renderer (synthetic ground
//! truth, inserted meshes of edited scenes) shares it.
//!
//! No fixed limits: traversal keeps its stack in a caller-provided `Vec` (reused across the rays
//! of a batch), and the build bounds the depth: binned SAH down to [`MAX_SAH_DEPTH`] levels, then
//! median splits along the longest centroid axis, which halve the triangle count per level, so
//! the tree is at most `MAX_SAH_DEPTH + ⌈log₂ n⌉` deep and the build recursion stays shallow
//! whatever the input (a large inserted mesh with a degenerate distribution included).

use glam::Vec3;
use i2sdf_data::TriangleMesh;

const BINS: usize = 16;
const MAX_LEAF: usize = 4;
/// Depth below which SAH splits give way to median splits (see the module doc).
pub const MAX_SAH_DEPTH: usize = 48;
/// Barycentric slack that closes cracks along shared edges (rays slipping between two triangles
/// of the closed room would otherwise escape it).
const EDGE_EPS: f32 = 1e-6;

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle; inner: index of the second child (the first follows the node).
    offset: u32,
    /// Triangles in a leaf, 0 for inner nodes.
    count: u32,
}

/// Precomputed triangle for Möller–Trumbore.
#[derive(Clone, Copy, Debug)]
struct Tri {
    p0: Vec3,
    e1: Vec3,
    e2: Vec3,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BvhHit {
    pub t: f32,
    pub triangle: u32,
    /// Barycentrics of vertices 1 and 2.
    pub u: f32,
    pub v: f32,
}

pub struct Bvh {
    nodes: Vec<Node>,
    tris: Vec<Tri>,
    /// Original triangle index of each reordered triangle.
    order: Vec<u32>,
}

#[derive(Clone, Copy)]
struct Aabb {
    lo: Vec3,
    hi: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: Vec3::splat(f32::INFINITY),
        hi: Vec3::splat(f32::NEG_INFINITY),
    };
    fn grow(&mut self, o: &Aabb) {
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
    }
    fn grow_point(&mut self, p: Vec3) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }
    fn area(&self) -> f32 {
        let d = (self.hi - self.lo).max(Vec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

/// How inner nodes are split: the real builder, or (tests only) a chain that peels one triangle
/// per level, to exercise traversal of trees far deeper than any fixed stack.
#[derive(Clone, Copy, PartialEq)]
enum Strategy {
    Sah,
    #[cfg(test)]
    Chain,
}

struct Builder<'a> {
    boxes: &'a [Aabb],
    cents: &'a [Vec3],
    nodes: Vec<Node>,
    #[cfg_attr(not(test), allow(dead_code))]
    strategy: Strategy,
}

impl Bvh {
    pub fn build(mesh: &TriangleMesh) -> Self {
        Self::build_with(mesh, Strategy::Sah)
    }

    fn build_with(mesh: &TriangleMesh, strategy: Strategy) -> Self {
        let n = mesh.faces.len();
        let boxes: Vec<Aabb> = (0..n)
            .map(|t| {
                let mut b = Aabb::EMPTY;
                for k in 0..3 {
                    b.grow_point(mesh.vertex(t, k));
                }
                b
            })
            .collect();
        let centroids: Vec<Vec3> = boxes.iter().map(|b| 0.5 * (b.lo + b.hi)).collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut builder = Builder {
            boxes: &boxes,
            cents: &centroids,
            nodes: Vec::with_capacity(2 * n / MAX_LEAF + 1),
            strategy,
        };
        builder.build(&mut order, 0, n, 0);
        let tris = order
            .iter()
            .map(|&t| {
                let (p0, p1, p2) = (
                    mesh.vertex(t as usize, 0),
                    mesh.vertex(t as usize, 1),
                    mesh.vertex(t as usize, 2),
                );
                Tri {
                    p0,
                    e1: p1 - p0,
                    e2: p2 - p0,
                }
            })
            .collect();
        Bvh {
            nodes: builder.nodes,
            tris,
            order,
        }
    }

    /// Levels of the tree (a single leaf: 1).
    pub fn depth(&self) -> usize {
        let mut deepest = 0;
        let mut stack = vec![(0u32, 1usize)];
        while let Some((node, d)) = stack.pop() {
            deepest = deepest.max(d);
            let nd = &self.nodes[node as usize];
            if nd.count == 0 && !self.tris.is_empty() {
                stack.push((node + 1, d + 1));
                stack.push((nd.offset, d + 1));
            }
        }
        deepest
    }

    /// Closest hit with t in (t_min, t_max). `stack` is scratch space (any contents; reuse one
    /// per thread or batch).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: &mut Vec<u32>) -> Option<BvhHit> {
        if self.tris.is_empty() {
            return None;
        }
        let inv = dir.recip();
        let mut best = t_max;
        let mut hit = None;
        stack.clear();
        let mut node = 0u32;
        slab(&self.nodes[0], origin, inv, t_min, best)?;
        loop {
            let nd = &self.nodes[node as usize];
            if nd.count > 0 {
                for i in nd.offset..nd.offset + nd.count {
                    if let Some((t, u, v)) = intersect_tri(&self.tris[i as usize], origin, dir, t_min, best) {
                        best = t;
                        hit = Some(BvhHit {
                            t,
                            triangle: self.order[i as usize],
                            u,
                            v,
                        });
                    }
                }
            } else {
                let (c0, c1) = (node + 1, nd.offset);
                let t0 = slab(&self.nodes[c0 as usize], origin, inv, t_min, best);
                let t1 = slab(&self.nodes[c1 as usize], origin, inv, t_min, best);
                match (t0, t1) {
                    (Some(a), Some(b)) => {
                        let (near, far) = if a <= b { (c0, c1) } else { (c1, c0) };
                        stack.push(far);
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = c0;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = c1;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next far child that the current best hit has not already ruled out.
            loop {
                let Some(next) = stack.pop() else {
                    return hit;
                };
                if slab(&self.nodes[next as usize], origin, inv, t_min, best).is_some() {
                    node = next;
                    break;
                }
            }
        }
    }

    /// True when anything lies on the ray within (t_min, t_max). `stack` as in [`Bvh::intersect`].
    pub fn occluded(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: &mut Vec<u32>) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let inv = dir.recip();
        stack.clear();
        stack.push(0);
        while let Some(node) = stack.pop() {
            let nd = &self.nodes[node as usize];
            if slab(nd, origin, inv, t_min, t_max).is_none() {
                continue;
            }
            if nd.count > 0 {
                for i in nd.offset..nd.offset + nd.count {
                    if intersect_tri(&self.tris[i as usize], origin, dir, t_min, t_max).is_some() {
                        return true;
                    }
                }
            } else {
                stack.push(nd.offset);
                stack.push(node + 1);
            }
        }
        false
    }
}

#[inline]
fn slab(n: &Node, o: Vec3, inv: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
    let a = (n.lo - o) * inv;
    let b = (n.hi - o) * inv;
    let t0 = a.min(b).max_element().max(t_min);
    let t1 = a.max(b).min_element().min(t_max);
    // NaN (0·∞ for rays in a slab plane) compares false, so such boxes are kept, conservatively.
    if t0 <= t1 * (1.0 + 4.0 * f32::EPSILON) {
        Some(t0)
    } else {
        None
    }
}

#[inline]
fn intersect_tri(tri: &Tri, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
    let p = d.cross(tri.e2);
    let det = tri.e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = o - tri.p0;
    let u = s.dot(p) * inv_det;
    if !(-EDGE_EPS..=1.0 + EDGE_EPS).contains(&u) {
        return None;
    }
    let q = s.cross(tri.e1);
    let v = d.dot(q) * inv_det;
    if v < -EDGE_EPS || u + v > 1.0 + EDGE_EPS {
        return None;
    }
    let t = tri.e2.dot(q) * inv_det;
    if t > t_min && t < t_max {
        Some((t, u, v))
    } else {
        None
    }
}

impl Builder<'_> {
    /// Builds the subtree over `order[start..end]` at tree level `depth` (root 0); returns its
    /// node index.
    fn build(&mut self, order: &mut [u32], start: usize, end: usize, depth: usize) -> u32 {
        let (boxes, cents) = (self.boxes, self.cents);
        let idx = self.nodes.len() as u32;
        let mut bounds = Aabb::EMPTY;
        let mut cb = Aabb::EMPTY;
        for &t in &order[start..end] {
            bounds.grow(&boxes[t as usize]);
            cb.grow_point(cents[t as usize]);
        }
        self.nodes.push(Node {
            lo: bounds.lo,
            hi: bounds.hi,
            offset: start as u32,
            count: (end - start) as u32,
        });
        let count = end - start;
        #[cfg(test)]
        if self.strategy == Strategy::Chain {
            if count <= 1 {
                return idx;
            }
            return self.finish_inner(order, start, start + 1, end, depth, idx);
        }
        if count <= MAX_LEAF {
            return idx;
        }
        if depth >= MAX_SAH_DEPTH {
            return self.split_median(order, start, end, &cb, depth, idx);
        }
        // Binned SAH along each axis; split at the cheapest bin boundary.
        let mut best = (f32::INFINITY, 0usize, 0usize);
        let extent = cb.hi - cb.lo;
        for axis in 0..3 {
            if extent[axis] <= 0.0 {
                continue;
            }
            let mut bins = [(Aabb::EMPTY, 0usize); BINS];
            let scale = BINS as f32 / extent[axis];
            for &t in &order[start..end] {
                let b = (((cents[t as usize][axis] - cb.lo[axis]) * scale) as usize).min(BINS - 1);
                bins[b].0.grow(&boxes[t as usize]);
                bins[b].1 += 1;
            }
            let mut right_area = [0f32; BINS];
            let mut right_count = [0usize; BINS];
            let (mut acc, mut cnt) = (Aabb::EMPTY, 0);
            for b in (1..BINS).rev() {
                acc.grow(&bins[b].0);
                cnt += bins[b].1;
                right_area[b] = acc.area();
                right_count[b] = cnt;
            }
            let (mut acc, mut cnt) = (Aabb::EMPTY, 0);
            for b in 0..BINS - 1 {
                acc.grow(&bins[b].0);
                cnt += bins[b].1;
                if cnt == 0 || right_count[b + 1] == 0 {
                    continue;
                }
                let cost = acc.area() * cnt as f32 + right_area[b + 1] * right_count[b + 1] as f32;
                if cost < best.0 {
                    best = (cost, axis, b + 1);
                }
            }
        }
        if !best.0.is_finite() {
            // No bin boundary separates the centroids (they coincide): split the list in half.
            let mid = (start + end) / 2;
            return self.finish_inner(order, start, mid, end, depth, idx);
        }
        // SAH with a traversal cost of one triangle test: keep small nodes as leaves when
        // splitting does not pay.
        if best.0 + bounds.area() >= bounds.area() * count as f32 && count <= 16 {
            return idx;
        }
        let (_, axis, split_bin) = best;
        let scale = BINS as f32 / extent[axis];
        let slice = &mut order[start..end];
        let mut i = 0;
        let mut j = slice.len();
        while i < j {
            let b = (((cents[slice[i] as usize][axis] - cb.lo[axis]) * scale) as usize).min(BINS - 1);
            if b < split_bin {
                i += 1;
            } else {
                j -= 1;
                slice.swap(i, j);
            }
        }
        let mid = start + i;
        self.finish_inner(order, start, mid, end, depth, idx)
    }

    /// Median split along the longest centroid axis: both halves have at most ⌈count/2⌉
    /// triangles, which is what bounds the depth past [`MAX_SAH_DEPTH`].
    fn split_median(&mut self, order: &mut [u32], start: usize, end: usize, cb: &Aabb, depth: usize, idx: u32) -> u32 {
        let axis = (cb.hi - cb.lo).max_position();
        let cents = self.cents;
        let mid = (start + end) / 2;
        order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
            cents[a as usize][axis].total_cmp(&cents[b as usize][axis])
        });
        self.finish_inner(order, start, mid, end, depth, idx)
    }

    fn finish_inner(&mut self, order: &mut [u32], start: usize, mid: usize, end: usize, depth: usize, idx: u32) -> u32 {
        self.build(order, start, mid, depth + 1);
        let right = self.build(order, mid, end, depth + 1);
        self.nodes[idx as usize].offset = right;
        self.nodes[idx as usize].count = 0;
        idx
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Random spheres, boxes and loose triangles.
    fn clutter(rng: &mut impl Rng) -> TriangleMesh {
        let mut parts = Vec::new();
        for _ in 0..40 {
            let c = Vec3::new(
                rng.gen_range(-3.0..3.0),
                rng.gen_range(-3.0..3.0),
                rng.gen_range(-3.0..3.0),
            );
            let r = rng.gen_range(0.05..0.6);
            let mut s = TriangleMesh::unit_icosphere(1);
            s.positions
                .iter_mut()
                .for_each(|p| *p = (c + r * Vec3::from(*p)).to_array());
            parts.push(s);
            let lo = c + Vec3::splat(0.7);
            parts.push(TriangleMesh::axis_box(lo.to_array(), (lo + Vec3::splat(r)).to_array()));
        }
        let mut loose = TriangleMesh::default();
        for i in 0..200u32 {
            for _ in 0..3 {
                loose
                    .positions
                    .push(std::array::from_fn(|_| rng.gen_range(-4.0f32..4.0)));
            }
            loose.faces.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        parts.push(loose);
        TriangleMesh::concat(&parts)
    }

    fn brute_force(mesh: &TriangleMesh, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, u32)> {
        (0..mesh.faces.len())
            .filter_map(|f| {
                let tri = Tri {
                    p0: mesh.vertex(f, 0),
                    e1: mesh.vertex(f, 1) - mesh.vertex(f, 0),
                    e2: mesh.vertex(f, 2) - mesh.vertex(f, 0),
                };
                intersect_tri(&tri, o, d, 0.0, t_max).map(|h| (h.0, f as u32))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }

    fn check_against_brute_force(mesh: &TriangleMesh, bvh: &Bvh, rays: usize, rng: &mut impl Rng) {
        let mut stack = Vec::new();
        for _ in 0..rays {
            let o = Vec3::new(
                rng.gen_range(-4.0..4.0),
                rng.gen_range(-4.0..4.0),
                rng.gen_range(-4.0..4.0),
            );
            let d = Vec3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            )
            .normalize();
            let t_max = rng.gen_range(0.5..20.0);
            let brute = brute_force(mesh, o, d, t_max);
            let fast = bvh.intersect(o, d, 0.0, t_max, &mut stack);
            assert_eq!(brute.map(|b| b.1), fast.map(|h| h.triangle));
            assert_eq!(brute.is_some(), bvh.occluded(o, d, 0.0, t_max, &mut stack));
        }
    }

    #[test]
    fn bvh_agrees_with_brute_force() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(3);
        let mesh = clutter(&mut rng);
        let bvh = Bvh::build(&mesh);
        check_against_brute_force(&mesh, &bvh, 2000, &mut rng);
    }

    /// Traversal has no depth limit: a chain tree 700 levels deep (the old fixed 64-entry stack
    /// overflowed past 64 levels) answers like brute force.
    #[test]
    fn traversal_of_a_tree_deeper_than_any_fixed_stack() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(5);
        let mut mesh = clutter(&mut rng);
        mesh.faces.truncate(700);
        let bvh = Bvh::build_with(&mesh, Strategy::Chain);
        assert!(bvh.depth() >= 700, "depth {}", bvh.depth());
        check_against_brute_force(&mesh, &bvh, 500, &mut rng);
    }

    /// 1.2M triangles of a degenerate distribution (every sliver through one axis, centroids on
    /// a geometric progression) build within the proven depth bound and trace correctly.
    #[test]
    fn degenerate_million_triangle_mesh_stays_within_the_depth_bound() {
        let n = 1_200_000u32;
        let mut mesh = TriangleMesh::default();
        for i in 0..n {
            // Long slivers along x, all overlapping, centred at 1.0001^-i along y: SAH bins see
            // almost every centroid in one bin, level after level.
            let y = 1.0001f32.powi(-(i as i32 % 60_000)) + (i / 60_000) as f32 * 1e-3;
            let z = (i % 7) as f32 * 1e-4;
            mesh.positions.push([-10.0, y, z]);
            mesh.positions.push([10.0, y + 1e-4, z]);
            mesh.positions.push([0.0, y, z + 1e-4]);
            mesh.faces.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        let bvh = Bvh::build(&mesh);
        let bound = MAX_SAH_DEPTH + (n as f64).log2().ceil() as usize + 1;
        assert!(bvh.depth() <= bound, "depth {} > {bound}", bvh.depth());
        // Rays across the slivers hit the nearest one.
        let mut stack = Vec::new();
        let mut rng = rand_pcg::Pcg32::seed_from_u64(9);
        for _ in 0..200 {
            let o = Vec3::new(rng.gen_range(-5.0..5.0), rng.gen_range(0.0..1.0), -1.0);
            let h = bvh.intersect(o, Vec3::Z, 0.0, f32::INFINITY, &mut stack);
            let brute = brute_force(&mesh, o, Vec3::Z, f32::INFINITY);
            assert_eq!(h.map(|h| h.t), brute.map(|b| b.0));
        }
    }
}
