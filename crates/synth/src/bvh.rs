//! A binned-SAH bounding volume hierarchy over the scene triangles, with closest-hit and
//! any-hit (shadow) queries in f32.

use crate::mesh::TriangleMesh;
use glam::Vec3;

const BINS: usize = 16;
const MAX_LEAF: usize = 4;
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

#[derive(Clone, Copy, Debug)]
pub struct Hit {
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

impl Bvh {
    pub fn build(mesh: &TriangleMesh) -> Self {
        let n = mesh.triangles.len();
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
        let mut nodes = Vec::with_capacity(2 * n / MAX_LEAF + 1);
        build_rec(&boxes, &centroids, &mut order, 0, n, &mut nodes);
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
        Bvh { nodes, tris, order }
    }

    /// Closest hit with t in (t_min, t_max).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<Hit> {
        let inv = dir.recip();
        let mut best = t_max;
        let mut hit = None;
        let mut stack = [0u32; 64];
        let mut sp = 0usize;
        let mut node = 0u32;
        loop {
            let nd = &self.nodes[node as usize];
            if nd.count > 0 {
                for i in nd.offset..nd.offset + nd.count {
                    if let Some((t, u, v)) = intersect_tri(&self.tris[i as usize], origin, dir, t_min, best) {
                        best = t;
                        hit = Some(Hit {
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
                        stack[sp] = far;
                        sp += 1;
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
            if sp == 0 {
                return hit;
            }
            sp -= 1;
            node = stack[sp];
        }
    }

    /// True when anything lies on the ray within (t_min, t_max).
    pub fn occluded(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> bool {
        let inv = dir.recip();
        let mut stack = [0u32; 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let node = stack[sp];
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
                stack[sp] = nd.offset;
                stack[sp + 1] = node + 1;
                sp += 2;
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

fn build_rec(
    boxes: &[Aabb],
    cents: &[Vec3],
    order: &mut [u32],
    start: usize,
    end: usize,
    nodes: &mut Vec<Node>,
) -> u32 {
    let idx = nodes.len() as u32;
    let mut bounds = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for &t in &order[start..end] {
        bounds.grow(&boxes[t as usize]);
        cb.grow_point(cents[t as usize]);
    }
    nodes.push(Node {
        lo: bounds.lo,
        hi: bounds.hi,
        offset: start as u32,
        count: (end - start) as u32,
    });
    let count = end - start;
    if count <= MAX_LEAF {
        return idx;
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
        return split_half(boxes, cents, order, start, end, nodes, idx);
    }
    // SAH with a traversal cost of one triangle test: keep small nodes as leaves when splitting
    // does not pay.
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
    finish_inner(boxes, cents, order, start, mid, end, nodes, idx)
}

fn split_half(
    boxes: &[Aabb],
    cents: &[Vec3],
    order: &mut [u32],
    start: usize,
    end: usize,
    nodes: &mut Vec<Node>,
    idx: u32,
) -> u32 {
    let mid = (start + end) / 2;
    finish_inner(boxes, cents, order, start, mid, end, nodes, idx)
}

#[allow(clippy::too_many_arguments)]
fn finish_inner(
    boxes: &[Aabb],
    cents: &[Vec3],
    order: &mut [u32],
    start: usize,
    mid: usize,
    end: usize,
    nodes: &mut Vec<Node>,
    idx: u32,
) -> u32 {
    build_rec(boxes, cents, order, start, mid, nodes);
    let right = build_rec(boxes, cents, order, mid, end, nodes);
    nodes[idx as usize].offset = right;
    nodes[idx as usize].count = 0;
    idx
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Geometry;
    use rand::{Rng, SeedableRng};

    #[test]
    fn bvh_agrees_with_brute_force() {
        let mut mesh = TriangleMesh::default();
        let mut rng = rand_pcg::Pcg32::seed_from_u64(3);
        for i in 0..60 {
            let c = [
                rng.gen_range(-3.0..3.0),
                rng.gen_range(-3.0..3.0),
                rng.gen_range(-3.0..3.0),
            ];
            mesh.add_geometry(
                &Geometry::Sphere {
                    center: c,
                    radius: rng.gen_range(0.05..0.6),
                    subdivisions: 1,
                },
                i,
            );
        }
        let bvh = Bvh::build(&mesh);
        let all: Vec<Tri> = (0..mesh.triangles.len())
            .map(|t| Tri {
                p0: mesh.vertex(t, 0),
                e1: mesh.vertex(t, 1) - mesh.vertex(t, 0),
                e2: mesh.vertex(t, 2) - mesh.vertex(t, 0),
            })
            .collect();
        for _ in 0..2000 {
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
            let brute = all
                .iter()
                .enumerate()
                .filter_map(|(i, t)| intersect_tri(t, o, d, 0.0, f32::INFINITY).map(|h| (h.0, i)))
                .min_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
            let fast = bvh.intersect(o, d, 0.0, f32::INFINITY);
            assert_eq!(brute.map(|b| b.1 as u32), fast.map(|h| h.triangle));
            assert_eq!(brute.is_some(), bvh.occluded(o, d, 0.0, f32::INFINITY));
        }
    }
}
