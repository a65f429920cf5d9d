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

use glam::Vec3;
use i2sdf_data::TriangleMesh;

const BINS: usize = 16;
const MAX_LEAF: usize = 4;
/// Depth below which SAH splits give way to median splits (see the module doc).
pub const MAX_SAH_DEPTH: usize = 48;
/// Barycentric slack that closes cracks along shared edges (rays slipping between two triangles
/// of the closed room would otherwise escape it).
const EDGE_EPS: f32 = 1e-6;

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
        Bvh {
            nodes: collapse(&builder.nodes, &leaf_packs),
            packs,
            lane_triangle,
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

    /// Closest hit with t in (t_min, t_max). `stack` is scratch space (any contents; reuse one
    /// per thread or batch).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: &mut Vec<u32>) -> Option<BvhHit> {
        if self.packs.is_empty() {
            return None;
        }
        let ray = RayConsts::new(origin, dir);
        let mut best = t_max;
        let mut hit: Option<(f32, u32, f32, f32)> = None;
        // Entries are (entry distance bits, node) pairs, so that a popped node the best hit has
        // since ruled out is skipped without touching its boxes.
        stack.clear();
        let mut node = 0u32;
        let mut near = [0f32; WIDTH];
        loop {
            let nd = &self.nodes[node as usize];
            let mut mask = nd.slab(&ray, t_min, best, &mut near);
            // Leaves first, whatever their order: each hit shortens `best`, which prunes the
            // inner children below.
            let mut leaves = mask & nd.leaf_mask;
            while leaves != 0 {
                let i = leaves.trailing_zeros() as usize;
                leaves &= leaves - 1;
                let first = nd.index[i];
                for k in first..first + nd.count[i] {
                    let (mut lanes, t, u, v) = self.packs[k as usize].intersect(&ray, t_min, best);
                    while lanes != 0 {
                        let lane = lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        if t[lane] < best {
                            best = t[lane];
                            hit = Some((t[lane], k * PACK as u32 + lane as u32, u[lane], v[lane]));
                        }
                    }
                }
            }
            mask &= !nd.leaf_mask;
            // The inner children still in front of the best hit, nearest last on the stack.
            let mut order = [(0f32, 0u32); WIDTH];
            let mut n = 0;
            while mask != 0 {
                let i = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if near[i] <= best * (1.0 + 4.0 * f32::EPSILON) {
                    // Insertion sort, farthest first.
                    let mut j = n;
                    while j > 0 && order[j - 1].0 < near[i] {
                        order[j] = order[j - 1];
                        j -= 1;
                    }
                    order[j] = (near[i], nd.index[i]);
                    n += 1;
                }
            }
            if n > 0 {
                for &(t, c) in &order[..n - 1] {
                    stack.push(t.to_bits());
                    stack.push(c);
                }
                node = order[n - 1].1;
                continue;
            }
            // Pop the next node that the best hit has not already ruled out.
            loop {
                let Some(next) = stack.pop() else {
                    return hit.map(|(t, k, u, v)| BvhHit {
                        t,
                        triangle: self.lane_triangle[k as usize],
                        u,
                        v,
                    });
                };
                let t = f32::from_bits(stack.pop().expect("stack entries come in pairs"));
                if t <= best * (1.0 + 4.0 * f32::EPSILON) {
                    node = next;
                    break;
                }
            }
        }
    }

    /// True when anything lies on the ray within (t_min, t_max). `stack` as in [`Bvh::intersect`].
    pub fn occluded(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: &mut Vec<u32>) -> bool {
        if self.packs.is_empty() {
            return false;
        }
        let ray = RayConsts::new(origin, dir);
        let mut near = [0f32; WIDTH];
        stack.clear();
        stack.push(0);
        while let Some(node) = stack.pop() {
            let nd = &self.nodes[node as usize];
            let mask = nd.slab(&ray, t_min, t_max, &mut near);
            let mut leaves = mask & nd.leaf_mask;
            while leaves != 0 {
                let i = leaves.trailing_zeros() as usize;
                leaves &= leaves - 1;
                let first = nd.index[i];
                for k in first..first + nd.count[i] {
                    if self.packs[k as usize].intersect(&ray, t_min, t_max).0 != 0 {
                        return true;
                    }
                }
            }
            let mut inner = mask & !nd.leaf_mask;
            while inner != 0 {
                let i = inner.trailing_zeros() as usize;
                inner &= inner - 1;
                stack.push(nd.index[i]);
            }
        }
        false
    }
}

/// A ray's origin, direction and reciprocal direction, per axis.
struct RayConsts {
    origin: [f32; 3],
    dir: [f32; 3],
    inv: [f32; 3],
}

impl RayConsts {
    /// A direction component under 1e-20 in size is taken as ±1e-20 for the reciprocal: a ray
    /// that lies in a box's face plane (a zero component, the origin on the plane) then meets
    /// that slab on [0, ∞) instead of making 0·∞ = NaN, which the box test's min and max would
    /// drop and the box with it (a ray along +z through a sphere's pole missed it).
    fn new(origin: Vec3, dir: Vec3) -> Self {
        let safe = dir
            .to_array()
            .map(|d| if d.abs() < 1e-20 { 1e-20f32.copysign(d) } else { d });
        RayConsts {
            origin: origin.to_array(),
            dir: dir.to_array(),
            inv: safe.map(|d| 1.0 / d),
        }
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

    /// [`intersect_tri`] in every lane, with the same operations in the same order (so the
    /// same results): bit `lane` of the mask is set where the ray meets that triangle within
    /// (t_min, t_max), with its t and barycentrics.
    #[inline(always)]
    fn intersect(&self, ray: &RayConsts, t_min: f32, t_max: f32) -> (u32, [f32; PACK], [f32; PACK], [f32; PACK]) {
        let (o, d) = (ray.origin, ray.dir);
        let (mut ts, mut us, mut vs) = ([0f32; PACK], [0f32; PACK], [0f32; PACK]);
        let mut mask = 0u32;
        for l in 0..PACK {
            let e1 = [self.e1[0][l], self.e1[1][l], self.e1[2][l]];
            let e2 = [self.e2[0][l], self.e2[1][l], self.e2[2][l]];
            let p = cross(d, e2);
            let det = dot(e1, p);
            let inv_det = 1.0 / det;
            let s = [o[0] - self.p0[0][l], o[1] - self.p0[1][l], o[2] - self.p0[2][l]];
            let u = dot(s, p) * inv_det;
            let q = cross(s, e1);
            let v = dot(d, q) * inv_det;
            let t = dot(e2, q) * inv_det;
            let ok = det.abs() >= 1e-12
                && u >= -EDGE_EPS
                && u <= 1.0 + EDGE_EPS
                && v >= -EDGE_EPS
                && u + v <= 1.0 + EDGE_EPS
                && t > t_min
                && t < t_max;
            mask |= (ok as u32) << l;
            ts[l] = t;
            us[l] = u;
            vs[l] = v;
        }
        (mask, ts, us, vs)
    }
}

/// glam's `Vec3::cross`, operation for operation.
#[inline(always)]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - b[1] * a[2],
        a[2] * b[0] - b[2] * a[0],
        a[0] * b[1] - b[0] * a[1],
    ]
}

/// glam's `Vec3::dot`, operation for operation.
#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    (a[0] * b[0]) + (a[1] * b[1]) + (a[2] * b[2])
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

    /// The slab test of all [`WIDTH`] children at once (the loop vectorizes: one lane per
    /// child): bit i of the result is set when the ray meets child i within (t_min, t_max),
    /// and `near[i]` is where it enters. [`RayConsts::new`] keeps 0·∞ out of it.
    #[inline(always)]
    fn slab(&self, ray: &RayConsts, t_min: f32, t_max: f32, near: &mut [f32; WIDTH]) -> u32 {
        let mut far = [0f32; WIDTH];
        for i in 0..WIDTH {
            let mut t0 = t_min;
            let mut t1 = t_max;
            for a in 0..3 {
                let x = (self.lo[a][i] - ray.origin[a]) * ray.inv[a];
                let y = (self.hi[a][i] - ray.origin[a]) * ray.inv[a];
                t0 = t0.max(x.min(y));
                t1 = t1.min(x.max(y));
            }
            near[i] = t0;
            far[i] = t1 * (1.0 + 4.0 * f32::EPSILON);
        }
        let mask = le_mask(&*near, &far);
        mask & self.used_mask
    }
}

/// Bit i set where `a[i] <= b[i]`. With AVX, one compare and a move-mask: the compiler's own
/// version of the loop stored the lanes and read them back at other offsets, a store-forwarding
/// stall that cost an eighth of the traversal's time.
#[inline(always)]
fn le_mask(a: &[f32; WIDTH], b: &[f32; WIDTH]) -> u32 {
    #[cfg(target_feature = "avx")]
    const _: () = assert!(WIDTH == 8, "one 256-bit vector of f32 lanes");
    #[cfg(target_feature = "avx")]
    // SAFETY: AVX is enabled at compile time; the loads read exactly the two 8-float arrays.
    unsafe {
        use std::arch::x86_64::*;
        let le = _mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_loadu_ps(a.as_ptr()), _mm256_loadu_ps(b.as_ptr()));
        _mm256_movemask_ps(le) as u32
    }
    #[cfg(not(target_feature = "avx"))]
    {
        (0..WIDTH).fold(0, |m, i| m | (((a[i] <= b[i]) as u32) << i))
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
            // Unbounded rays too: an empty slot of a wide node must not pass the box test there.
            let t_max = if rng.gen_bool(0.2) {
                f32::INFINITY
            } else {
                rng.gen_range(0.5..20.0)
            };
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

    /// Rays along an axis through vertices on a box's face plane (0·∞ in the slab test) still
    /// find the sphere they cross.
    #[test]
    fn axis_aligned_rays_in_face_planes_hit() {
        let mut mesh = TriangleMesh::unit_icosphere(3);
        mesh.positions
            .iter_mut()
            .for_each(|p| *p = (Vec3::new(3.0, 0.0, 5.0) + 0.5 * Vec3::from(*p)).to_array());
        let bvh = Bvh::build(&mesh);
        let mut stack = Vec::new();
        for (o, d) in [
            (Vec3::new(3.0, 0.0, 0.0), Vec3::Z),
            (Vec3::new(3.0, 0.0, 9.0), -Vec3::Z),
            (Vec3::new(0.0, 0.0, 5.0), Vec3::X),
            (Vec3::new(3.0, -4.0, 5.0), Vec3::Y),
        ] {
            let brute = brute_force(&mesh, o, d, f32::INFINITY);
            assert!(brute.is_some());
            let hit = bvh.intersect(o, d, 0.0, f32::INFINITY, &mut stack);
            assert_eq!(hit.map(|h| h.t), brute.map(|b| b.0), "{o} {d}");
            assert!(bvh.occluded(o, d, 0.0, f32::INFINITY, &mut stack), "{o} {d}");
        }
    }

    /// Traversal has no depth limit: a chain tree 700 binary levels deep, about a hundred wide
    /// ones (the old fixed 64-entry stack overflowed past 64 levels), answers like brute force.
    #[test]
    fn traversal_of_a_tree_deeper_than_any_fixed_stack() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(5);
        let mut mesh = clutter(&mut rng);
        mesh.faces.truncate(700);
        let bvh = Bvh::build_with(&mesh, Strategy::Chain);
        assert!(bvh.depth() >= 90, "depth {}", bvh.depth());
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
