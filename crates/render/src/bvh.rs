//! A binned-SAH bounding volume hierarchy over triangles, with closest-hit and any-hit (shadow)
//! queries in f32. Moved from `i2sdf-synth` so that every physical renderer (synthetic ground
//! truth, inserted meshes of edited scenes) shares it.
//!
//! No fixed limits: traversal keeps its stack in a caller-provided `Vec` (reused across the rays
//! of a batch), and the build bounds the depth: binned SAH down to [`MAX_SAH_DEPTH`] levels, then
//! median splits along the longest centroid axis, which halve the triangle count per level, so
//! the tree is at most `MAX_SAH_DEPTH + ⌈log₂ n⌉` deep and the build recursion stays shallow
//! whatever the input (a large inserted mesh with a degenerate distribution included).
//!
//! Rays traverse an 8-wide tree collapsed from the binary one (as Embree's BVH8): one vector
//! operation tests a node's eight child boxes, and the tree has about a third of the levels.
//! On the synthetic room's ground-truth render, which spends three quarters of its time in
//! traversal (160×120, 6 views, 64 spp), the binary tree took 14.05 s and this one 8.25 s, at a
//! bench iteration of ~100 ms.
//!
//! This file builds the tree and lays it out; `traversal` walks it (one ray, or a batch
//! interleaved so that the rays' cache misses overlap) on the per-node tests of `kernels`.

mod kernels;
mod traversal;

use glam::Vec3;
use i2sdf_data::TriangleMesh;

const BINS: usize = 16;
const MAX_LEAF: usize = 4;
/// Depth below which SAH splits give way to median splits (see the module doc).
pub const MAX_SAH_DEPTH: usize = 48;
/// Barycentric slack that closes cracks along shared edges (rays slipping between two triangles
/// of the closed room would otherwise escape it).
const EDGE_EPS: f32 = 1e-6;

/// Asks for the cache line at `p` ahead of its read (a hint: it never faults, whatever the
/// address; nothing on other targets). The BVH's walks and [`crate::MeshGeometry`]'s hits use it.
#[inline(always)]
pub(crate) fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is a hint that never faults, whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p as *const i8);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// A node of the binary SAH tree the build makes (collapsed into [`WideNode`]s afterwards).
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle; inner: index of the second child (the first follows the node).
    offset: u32,
    /// Triangles in a leaf, 0 for inner nodes.
    count: u32,
}

/// One triangle for the scalar Möller–Trumbore test, the reference the packs are tested against.
#[cfg(test)]
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

/// Children per node of the traversed tree: the box tests of a node's children run as one
/// vector operation.
const WIDTH: usize = 8;

/// A node of the traversed tree: its children's boxes, per axis across children (one vector
/// each), and what each child is. An empty slot's bit in `used_mask` is clear.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct WideNode {
    lo: [[f32; WIDTH]; 3],
    hi: [[f32; WIDTH]; 3],
    /// Inner child: its node index; leaf child: its first triangle pack.
    index: [u32; WIDTH],
    /// Leaf child: its pack count.
    count: [u32; WIDTH],
    /// Bit i set: slot i holds a child.
    used_mask: u32,
    /// Bit i set: child i is a leaf.
    leaf_mask: u32,
}

pub struct Bvh {
    /// [`WIDTH`]-wide nodes collapsed from the binary SAH tree; the root is node 0.
    nodes: Vec<WideNode>,
    /// The triangles, leaf by leaf, in packs of [`PACK`].
    packs: Vec<TriPack>,
    /// The mesh's index of the triangle in each lane of `packs` (`u32::MAX` for padding).
    lane_triangle: Vec<u32>,
    /// Whether batches are walked interleaved ([`Bvh::intersect_each`]): only when the tree is
    /// larger than [`INTERLEAVE_BYTES`].
    interleave: bool,
}

/// Nodes and triangle packs above which a batch's rays are walked interleaved. Below it the
/// tree stays in the caches and one ray after the other is faster (`examples/bvh_bench.rs`, one
/// thread, closest hit / shadow Mrays/s, one at a time against interleaved): the synthetic
/// room's 7k triangles 6.2 / 8.7 against 4.6 / 6.1; 11k, 2.9 / 3.9 against 2.7 / 3.6; 23k
/// (~1.6 MB) 2.6 / 3.8 against 2.7 / 3.7; 40k 2.4 / 3.4 against 2.6 / 3.7; 90k 1.6 / 2.4 against
/// 2.5 / 3.4; 513k 0.65 / 1.1 against 2.5 / 3.4.
const INTERLEAVE_BYTES: usize = 3 << 19;

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
        // Each binary leaf's triangles in packs of [`PACK`], in leaf order; padding lanes are
        // degenerate (zero edges), which the test rejects.
        let mut leaves: Vec<(u32, u32)> = builder
            .nodes
            .iter()
            .filter(|n| n.count > 0)
            .map(|n| (n.offset, n.count))
            .collect();
        leaves.sort_unstable();
        let mut packs = Vec::with_capacity(n / PACK + leaves.len());
        let mut lane_triangle = Vec::with_capacity(packs.capacity() * PACK);
        let mut leaf_packs = vec![(0u32, 0u32); n];
        for &(offset, count) in &leaves {
            let first = packs.len() as u32;
            for chunk in order[offset as usize..(offset + count) as usize].chunks(PACK) {
                let mut pack = TriPack::EMPTY;
                for (lane, &t) in chunk.iter().enumerate() {
                    let (p0, p1, p2) = (
                        mesh.vertex(t as usize, 0),
                        mesh.vertex(t as usize, 1),
                        mesh.vertex(t as usize, 2),
                    );
                    let (e1, e2) = (p1 - p0, p2 - p0);
                    for a in 0..3 {
                        pack.p0[a][lane] = p0[a];
                        pack.e1[a][lane] = e1[a];
                        pack.e2[a][lane] = e2[a];
                    }
                }
                packs.push(pack);
                lane_triangle.extend((0..PACK).map(|lane| chunk.get(lane).copied().unwrap_or(u32::MAX)));
            }
            leaf_packs[offset as usize] = (first, packs.len() as u32 - first);
        }
        let nodes = collapse(&builder.nodes, &leaf_packs);
        let bytes = nodes.len() * std::mem::size_of::<WideNode>() + packs.len() * std::mem::size_of::<TriPack>();
        Bvh {
            nodes,
            packs,
            lane_triangle,
            interleave: bytes > INTERLEAVE_BYTES,
        }
    }

    /// Levels of the tree (a single leaf: 1).
    pub fn depth(&self) -> usize {
        if self.packs.is_empty() {
            return 1;
        }
        let mut deepest = 0;
        let mut stack = vec![(0u32, 1usize)];
        while let Some((node, d)) = stack.pop() {
            deepest = deepest.max(d);
            let nd = &self.nodes[node as usize];
            for i in 0..WIDTH {
                if nd.is_inner(i) {
                    stack.push((nd.index[i], d + 1));
                }
            }
        }
        deepest
    }
}

/// Triangles per pack: a leaf's triangle tests run [`PACK`] at a time, one lane each.
const PACK: usize = 4;

/// [`PACK`] triangles for Möller–Trumbore, per axis across triangles.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
struct TriPack {
    p0: [[f32; PACK]; 3],
    e1: [[f32; PACK]; 3],
    e2: [[f32; PACK]; 3],
}

impl TriPack {
    /// Every lane degenerate (zero edges: det = 0, never hit).
    const EMPTY: TriPack = TriPack {
        p0: [[0.0; PACK]; 3],
        e1: [[0.0; PACK]; 3],
        e2: [[0.0; PACK]; 3],
    };
}

impl WideNode {
    /// A node with every slot empty (the slab test masks them out with `used_mask`; their
    /// boxes are finite, so that the test's lanes compute nothing odd).
    const EMPTY: WideNode = WideNode {
        lo: [[0.0; WIDTH]; 3],
        hi: [[0.0; WIDTH]; 3],
        index: [0; WIDTH],
        count: [0; WIDTH],
        used_mask: 0,
        leaf_mask: 0,
    };

    fn is_inner(&self, i: usize) -> bool {
        (self.used_mask & !self.leaf_mask) & (1 << i) != 0
    }
}

/// Collapses the binary tree into [`WIDTH`]-wide nodes: each wide node takes a binary node's
/// two children and keeps opening its largest inner child (by surface area) until it has
/// [`WIDTH`] children or only leaves; the binary leaves stay leaves.
/// `leaf_packs[offset]`: the first pack and the pack count of the binary leaf whose first
/// triangle is `offset`.
fn collapse(binary: &[Node], leaf_packs: &[(u32, u32)]) -> Vec<WideNode> {
    let area = |n: &Node| Aabb { lo: n.lo, hi: n.hi }.area();
    let mut wide = vec![WideNode::EMPTY];
    // (wide node to fill, binary node it stands for)
    let mut work = vec![(0usize, 0u32)];
    while let Some((w, b)) = work.pop() {
        let root = &binary[b as usize];
        let mut children: Vec<u32> = if root.count > 0 {
            vec![b]
        } else {
            vec![b + 1, root.offset]
        };
        while children.len() < WIDTH {
            let open = children
                .iter()
                .enumerate()
                .filter(|(_, &c)| binary[c as usize].count == 0)
                .max_by(|a, b| area(&binary[*a.1 as usize]).total_cmp(&area(&binary[*b.1 as usize])));
            let Some((k, &c)) = open else { break };
            children.swap_remove(k);
            children.push(c + 1);
            children.push(binary[c as usize].offset);
        }
        for (i, &c) in children.iter().enumerate() {
            let n = &binary[c as usize];
            wide[w].used_mask |= 1 << i;
            for a in 0..3 {
                wide[w].lo[a][i] = n.lo[a];
                wide[w].hi[a][i] = n.hi[a];
            }
            if n.count > 0 {
                (wide[w].index[i], wide[w].count[i]) = leaf_packs[n.offset as usize];
                wide[w].leaf_mask |= 1 << i;
            } else {
                wide[w].index[i] = wide.len() as u32;
                work.push((wide.len(), c));
                wide.push(WideNode::EMPTY);
            }
        }
    }
    wide
}

#[cfg(test)]
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
pub(crate) mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A ray's origin, uniform in the cube of half side `half` about 0, and its unit direction
    /// (a uniform point of [-1, 1]³, normalized): the BVH's and the mesh geometry's test rays.
    pub(crate) fn random_ray(rng: &mut impl Rng, half: f32) -> (Vec3, Vec3) {
        let mut v = |h: f32| Vec3::new(rng.gen_range(-h..h), rng.gen_range(-h..h), rng.gen_range(-h..h));
        let o = v(half);
        (o, v(1.0).normalize())
    }

    /// Random spheres, boxes and loose triangles.
    pub(super) fn clutter(rng: &mut impl Rng) -> TriangleMesh {
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

    pub(super) fn brute_force(mesh: &TriangleMesh, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, u32)> {
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
