//! Traversal of the [`Bvh`]: closest-hit and any-hit (shadow) queries, one ray at a time or
//! many interleaved ([`Bvh::intersect_each`], [`Bvh::occluded_each`]: the renderers' batches),
//! on the per-node kernels of `kernels.rs` (the slab test of a node's eight children, the
//! Möller–Trumbore test of a pack of four triangles).
//!
//! One walk per ray, advanced a step at a time ([`ClosestWalk`], [`AnyWalk`]): one ray alone
//! steps until done; a batch steps [`LANES`] rays in turn, each step prefetching what the ray
//! reads next, so that the cache misses of one ray overlap the others' work.

use super::kernels::RayConsts;
use super::{prefetch, Bvh, BvhHit, TriPack, WideNode, PACK, WIDTH};
use glam::Vec3;

impl Bvh {
    /// Closest hit with t in (t_min, t_max). `stack` is scratch space (any contents; reuse one
    /// per thread or batch). For many rays, [`Bvh::intersect_each`] is faster.
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: &mut Vec<u32>) -> Option<BvhHit> {
        if self.packs.is_empty() {
            return None;
        }
        let mut walk = ClosestWalk::start(origin, dir, t_min, t_max, std::mem::take(stack));
        while self.closest_step::<false>(&mut walk) {}
        let hit = self.closest_hit(&walk);
        *stack = walk.stack;
        hit
    }

    /// True when anything lies on the ray within (t_min, t_max). `stack` as in
    /// [`Bvh::intersect`]; for many rays, [`Bvh::occluded_each`] is faster.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: &mut Vec<u32>) -> bool {
        if self.packs.is_empty() {
            return false;
        }
        let mut walk = AnyWalk::start(origin, dir, t_min, t_max, std::mem::take(stack));
        let blocked = loop {
            if let Some(blocked) = self.any_step::<false>(&mut walk) {
                break blocked;
            }
        };
        *stack = walk.stack;
        blocked
    }

    /// Whether [`Bvh::intersect_each`] walks its batches interleaved (the tree is larger than
    /// the caches hold: `INTERLEAVE_BYTES`).
    pub fn interleaves(&self) -> bool {
        self.interleave
    }

    /// [`Bvh::intersect`] for rays `0..n`: `ray(i)` gives ray i's (origin, dir, t_min, t_max),
    /// or None to skip it; `found(i, hit)` is called for each ray that hits, in no particular
    /// order. The hits are those of [`Bvh::intersect`], bit for bit.
    ///
    /// Why batched: one ray's traversal is a chain of dependent loads (node, then the child
    /// it picks), and on a mesh larger than L2 each waits on memory: a 90k-triangle room took
    /// ~670 ns a ray at ~12 nodes a ray. Here `LANES` rays are walked in turn, one node each,
    /// and the node a ray will visit next is prefetched while the others take their step, so
    /// their misses overlap. A tree that fits the caches is walked one ray after the other
    /// (`INTERLEAVE_BYTES`).
    pub fn intersect_each(
        &self,
        n: usize,
        ray: impl Fn(usize) -> Option<(Vec3, Vec3, f32, f32)>,
        mut found: impl FnMut(usize, BvhHit),
    ) {
        if self.packs.is_empty() {
            return;
        }
        if !self.interleave {
            let mut stack = Vec::with_capacity(64);
            for i in 0..n {
                if let Some(h) = ray(i).and_then(|(o, d, t0, t1)| self.intersect(o, d, t0, t1, &mut stack)) {
                    found(i, h);
                }
            }
            return;
        }
        self.walk_interleaved::<ClosestWalk>(n, ray, |i, hit| {
            if let Some(h) = hit {
                found(i, h);
            }
        });
    }

    /// [`Bvh::occluded`] for rays `0..n`, interleaved as [`Bvh::intersect_each`]: `ray(i)` as
    /// there; `blocked(i)` is called for each ray that something blocks, in no particular order.
    pub fn occluded_each(
        &self,
        n: usize,
        ray: impl Fn(usize) -> Option<(Vec3, Vec3, f32, f32)>,
        mut blocked: impl FnMut(usize),
    ) {
        if self.packs.is_empty() {
            return;
        }
        if !self.interleave {
            let mut stack = Vec::with_capacity(64);
            for i in 0..n {
                if ray(i).is_some_and(|(o, d, t0, t1)| self.occluded(o, d, t0, t1, &mut stack)) {
                    blocked(i);
                }
            }
            return;
        }
        self.walk_interleaved::<AnyWalk>(n, ray, |i, hit| {
            if hit {
                blocked(i);
            }
        });
    }

    /// Walks rays `0..n` (`ray(i)`: as in [`Bvh::intersect_each`]) [`LANES`] at a time, each in
    /// turn one step ([`Walk::step`]), a finished ray's lane taking the next ray; `done(i,
    /// answer)` for every ray walked.
    fn walk_interleaved<W: Walk>(
        &self,
        n: usize,
        ray: impl Fn(usize) -> Option<(Vec3, Vec3, f32, f32)>,
        mut done: impl FnMut(usize, W::Answer),
    ) {
        let mut next = 0;
        let mut start = |stack: Vec<u32>| -> Option<(usize, W)> {
            while next < n {
                let i = next;
                next += 1;
                if let Some((o, d, t0, t1)) = ray(i) {
                    return Some((i, W::start(o, d, t0, t1, stack)));
                }
            }
            None
        };
        let mut lanes: Vec<(usize, W)> = Vec::with_capacity(LANES);
        while lanes.len() < LANES {
            match start(Vec::with_capacity(64)) {
                Some(lane) => lanes.push(lane),
                None => break,
            }
        }
        let mut k = 0;
        while !lanes.is_empty() {
            if k >= lanes.len() {
                k = 0;
            }
            let (i, walk) = &mut lanes[k];
            let Some(answer) = walk.step(self) else {
                k += 1;
                continue;
            };
            done(*i, answer);
            match start(walk.take_stack()) {
                Some(lane) => lanes[k] = lane,
                None => {
                    lanes.swap_remove(k);
                }
            }
        }
    }

    /// One step of `walk`, of two kinds in turn where a node has leaf children: the visit of
    /// its current node (the slab test of its children; their leaves' triangle packs are
    /// prefetched and their test left to the next step, so that their misses too overlap other
    /// rays' work), then the test of those packs (each hit shortens `best`). Either ends, once
    /// the leaves are done, by stacking the inner children still in front of the best hit
    /// (nearest last) and moving to the nearest, or by popping the next stacked node the best
    /// hit has not ruled out; the node moved to is prefetched. False when the walk is over.
    /// Without `DEFER` (one ray alone) a node's leaves are tested in its visit, unprefetched.
    #[inline(always)]
    fn closest_step<const DEFER: bool>(&self, walk: &mut ClosestWalk) -> bool {
        // The node's visit is written out here and in `any_step`: shared as one helper, the
        // closest-hit walk of one ray lost 16 % (`bvh_bench`, the synthetic room).
        if walk.leaves.is_empty() {
            let nd = &self.nodes[walk.node as usize];
            let mut near = [0f32; WIDTH];
            let mask = nd.slab(&walk.ray, walk.t_min, walk.best, &mut near);
            walk.inner.clear();
            walk.leaves.clear();
            self.children::<DEFER>(nd, mask, &near, &mut walk.inner, &mut walk.leaves);
            if DEFER && !walk.leaves.is_empty() {
                return true;
            }
        }
        if !walk.leaves.is_empty() {
            // Leaves first, whatever their order: each hit shortens `best`, which prunes the
            // inner children below.
            for &(first, count) in walk.leaves.iter() {
                for k in first..first + count {
                    let (mut lanes, t, u, v) = self.packs[k as usize].intersect(&walk.ray, walk.t_min, walk.best);
                    while lanes != 0 {
                        let lane = lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        if t[lane] < walk.best {
                            walk.best = t[lane];
                            walk.hit = Some((t[lane], k * PACK as u32 + lane as u32, u[lane], v[lane]));
                        }
                    }
                }
            }
            walk.leaves.clear();
        }
        let best = walk.best * (1.0 + 4.0 * f32::EPSILON);
        // The inner children still in front of the best hit, nearest last on the stack.
        let mut order = [(0f32, 0u32); WIDTH];
        let mut n = 0;
        for &(t, c) in walk.inner.iter() {
            if t <= best {
                // Insertion sort, farthest first.
                let mut j = n;
                while j > 0 && order[j - 1].0 < t {
                    order[j] = order[j - 1];
                    j -= 1;
                }
                order[j] = (t, c);
                n += 1;
            }
        }
        if n > 0 {
            for &(t, c) in &order[..n - 1] {
                walk.stack.push(t.to_bits());
                walk.stack.push(c);
            }
            walk.node = order[n - 1].1;
            self.prefetch_node(walk.node);
            return true;
        }
        // Pop the next node that the best hit has not already ruled out.
        while let Some(next) = walk.stack.pop() {
            let t = f32::from_bits(walk.stack.pop().expect("stack entries come in pairs"));
            if t <= best {
                walk.node = next;
                self.prefetch_node(next);
                return true;
            }
        }
        false
    }

    /// The children of `nd` that the ray meets (`mask` and `near` of its slab test): the inner
    /// ones' entry distances and nodes into `inner`, in slot order; the leaves' first pack and
    /// pack count into `leaves`, their packs prefetched.
    #[inline(always)]
    fn children<const PREFETCH: bool>(
        &self,
        nd: &WideNode,
        mask: u32,
        near: &[f32; WIDTH],
        inner: &mut Children,
        leaves: &mut Leaves,
    ) {
        let mut m = mask & nd.leaf_mask;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            leaves.push((nd.index[i], nd.count[i]));
            if PREFETCH {
                self.prefetch_packs(nd.index[i], nd.count[i]);
            }
        }
        let mut m = mask & !nd.leaf_mask;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            inner.push((near[i], nd.index[i]));
        }
    }

    /// The finished `walk`'s closest hit.
    fn closest_hit(&self, walk: &ClosestWalk) -> Option<BvhHit> {
        walk.hit.map(|(t, k, u, v)| BvhHit {
            t,
            triangle: self.lane_triangle[k as usize],
            u,
            v,
        })
    }

    /// One step of an any-hit `walk`, of two kinds as in [`Bvh::closest_step`]: a node's visit
    /// (its leaves' packs prefetched), then the test of those packs, Some(true) as soon as a
    /// triangle lies on the ray. Then the inner children are stacked and the next node popped
    /// and prefetched (None: go on), or Some(false) when none is left.
    #[inline(always)]
    fn any_step<const DEFER: bool>(&self, walk: &mut AnyWalk) -> Option<bool> {
        if walk.leaves.is_empty() {
            let nd = &self.nodes[walk.node as usize];
            let mut near = [0f32; WIDTH];
            let mask = nd.slab(&walk.ray, walk.t_min, walk.t_max, &mut near);
            walk.inner.clear();
            self.children::<DEFER>(nd, mask, &near, &mut walk.inner, &mut walk.leaves);
            if DEFER && !walk.leaves.is_empty() {
                return None;
            }
        }
        if !walk.leaves.is_empty() {
            for &(first, count) in walk.leaves.iter() {
                for k in first..first + count {
                    if self.packs[k as usize].intersect(&walk.ray, walk.t_min, walk.t_max).0 != 0 {
                        return Some(true);
                    }
                }
            }
            walk.leaves.clear();
        }
        for &(_, c) in walk.inner.iter() {
            walk.stack.push(c);
        }
        let Some(next) = walk.stack.pop() else {
            return Some(false);
        };
        walk.node = next;
        self.prefetch_node(next);
        None
    }

    /// Asks for the cache lines of packs `first..first + count` ahead of their test.
    #[inline(always)]
    fn prefetch_packs(&self, first: u32, count: u32) {
        let lo = self.packs.as_ptr().wrapping_add(first as usize) as usize;
        let hi = lo + count as usize * std::mem::size_of::<TriPack>();
        let mut line = lo & !63;
        while line < hi {
            prefetch(line as *const i8);
            line += 64;
        }
    }

    /// Asks for node `node`'s cache lines ahead of its visit (a hint: nothing on other
    /// targets).
    #[inline(always)]
    fn prefetch_node(&self, node: u32) {
        let p = self.nodes.as_ptr().wrapping_add(node as usize) as *const i8;
        for line in 0..std::mem::size_of::<WideNode>().div_ceil(64) {
            prefetch(p.wrapping_add(64 * line));
        }
    }
}

/// A small vector of at most [`WIDTH`] items on the stack (a node's children).
#[derive(Clone, Copy)]
struct Few<T: Copy + Default> {
    items: [T; WIDTH],
    len: usize,
}

impl<T: Copy + Default> Few<T> {
    fn new() -> Self {
        Few {
            items: [T::default(); WIDTH],
            len: 0,
        }
    }
    #[inline(always)]
    fn push(&mut self, x: T) {
        self.items[self.len] = x;
        self.len += 1;
    }
    #[inline(always)]
    fn clear(&mut self) {
        self.len = 0;
    }
    #[inline(always)]
    fn is_empty(&self) -> bool {
        self.len == 0
    }
    #[inline(always)]
    fn iter(&self) -> std::slice::Iter<'_, T> {
        self.items[..self.len].iter()
    }
}

/// A node's inner children that the ray meets: (entry distance, node).
type Children = Few<(f32, u32)>;
/// A node's leaf children that the ray meets: (first pack, pack count).
type Leaves = Few<(u32, u32)>;

/// Rays walked in turn by [`Bvh::intersect_each`] and [`Bvh::occluded_each`]: enough that the
/// prefetched node has arrived when a ray's turn comes again. On a 513k-triangle room
/// (`examples/bvh_bench.rs`, closest hits): 4 → 1.63 Mrays/s, 8 → 2.35, 12 → 2.58, 16 → 2.60;
/// on the same room simplified to 90k triangles, which fits the caches better, all within 4 %.
const LANES: usize = 12;

/// A ray's traversal, a step at a time, as [`Bvh::walk_interleaved`] drives it.
trait Walk: Sized {
    /// What the finished walk answers.
    type Answer;
    fn start(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: Vec<u32>) -> Self;
    /// One step, deferring leaves to the next (the walk is interleaved): None while it goes on.
    fn step(&mut self, bvh: &Bvh) -> Option<Self::Answer>;
    /// The walk's stack, for the next walk to reuse.
    fn take_stack(&mut self) -> Vec<u32>;
}

impl Walk for ClosestWalk {
    type Answer = Option<BvhHit>;
    fn start(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: Vec<u32>) -> Self {
        ClosestWalk::start(origin, dir, t_min, t_max, stack)
    }
    #[inline(always)]
    fn step(&mut self, bvh: &Bvh) -> Option<Option<BvhHit>> {
        (!bvh.closest_step::<true>(self)).then(|| bvh.closest_hit(self))
    }
    fn take_stack(&mut self) -> Vec<u32> {
        std::mem::take(&mut self.stack)
    }
}

impl Walk for AnyWalk {
    type Answer = bool;
    fn start(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, stack: Vec<u32>) -> Self {
        AnyWalk::start(origin, dir, t_min, t_max, stack)
    }
    #[inline(always)]
    fn step(&mut self, bvh: &Bvh) -> Option<bool> {
        bvh.any_step::<true>(self)
    }
    fn take_stack(&mut self) -> Vec<u32> {
        std::mem::take(&mut self.stack)
    }
}

/// One ray's closest-hit traversal: the ray, the best hit so far, the node to visit next and
/// the stacked (entry distance bits, node) pairs, so that a popped node the best hit has since
/// ruled out is skipped without touching its boxes.
struct ClosestWalk {
    ray: RayConsts,
    t_min: f32,
    best: f32,
    /// (t, pack lane, u, v) of the best hit.
    hit: Option<(f32, u32, f32, f32)>,
    node: u32,
    /// The visited node's children met, while its leaves wait for their test.
    inner: Children,
    leaves: Leaves,
    stack: Vec<u32>,
}

impl ClosestWalk {
    fn start(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, mut stack: Vec<u32>) -> Self {
        stack.clear();
        ClosestWalk {
            ray: RayConsts::new(origin, dir),
            t_min,
            best: t_max,
            hit: None,
            node: 0,
            inner: Few::new(),
            leaves: Few::new(),
            stack,
        }
    }
}

/// One ray's any-hit traversal: the ray, its interval, the node to visit next and the stacked
/// nodes.
struct AnyWalk {
    ray: RayConsts,
    t_min: f32,
    t_max: f32,
    node: u32,
    inner: Children,
    leaves: Leaves,
    stack: Vec<u32>,
}

impl AnyWalk {
    fn start(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, mut stack: Vec<u32>) -> Self {
        stack.clear();
        AnyWalk {
            ray: RayConsts::new(origin, dir),
            t_min,
            t_max,
            node: 0,
            inner: Few::new(),
            leaves: Few::new(),
            stack,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{brute_force, clutter, random_ray};
    use super::super::Strategy;
    use super::*;
    use i2sdf_data::TriangleMesh;
    use rand::{Rng, SeedableRng};

    fn check_against_brute_force(mesh: &TriangleMesh, bvh: &Bvh, rays: usize, rng: &mut impl Rng) {
        let mut stack = Vec::new();
        for _ in 0..rays {
            let (o, d) = random_ray(rng, 4.0);
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

    /// The interleaved batches answer what one ray at a time answers, bit for bit, for every
    /// ray of batches of every size up to past [`LANES`] and beyond it, skipped rays included
    /// (never reported).
    #[test]
    fn batches_agree_with_one_ray_at_a_time() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(5);
        let mesh = clutter(&mut rng);
        let mut bvh = Bvh::build(&mesh);
        let mut stack = Vec::new();
        for (interleave, n) in [false, true]
            .into_iter()
            .flat_map(|i| [1, 3, LANES, LANES + 1, 500].map(|n| (i, n)))
        {
            bvh.interleave = interleave;
            let rays: Vec<(Vec3, Vec3, f32, f32)> = (0..n)
                .map(|_| {
                    let (o, d) = random_ray(&mut rng, 4.0);
                    let t_max = if rng.gen_bool(0.2) {
                        f32::INFINITY
                    } else {
                        rng.gen_range(0.5..20.0)
                    };
                    (o, d, rng.gen_range(0.0..0.3), t_max)
                })
                .collect();
            let skipped = |i: usize| i % 7 == 3;
            let ray = |i: usize| (!skipped(i)).then_some(rays[i]);
            let mut hits = vec![None; n];
            let mut reported = 0;
            bvh.intersect_each(n, ray, |i, h| {
                assert!(hits[i].is_none(), "ray {i} reported twice");
                hits[i] = Some(h);
                reported += 1;
            });
            let mut blocked = vec![false; n];
            bvh.occluded_each(n, ray, |i| {
                assert!(!blocked[i], "ray {i} reported twice");
                blocked[i] = true;
            });
            let mut hit_count = 0;
            for (i, &(o, d, t0, t1)) in rays.iter().enumerate() {
                if skipped(i) {
                    assert_eq!((hits[i], blocked[i]), (None, false), "skipped ray {i} reported");
                    continue;
                }
                let one = bvh.intersect(o, d, t0, t1, &mut stack);
                assert_eq!(hits[i], one, "batch of {n}, ray {i}");
                assert_eq!(
                    blocked[i],
                    bvh.occluded(o, d, t0, t1, &mut stack),
                    "batch of {n}, ray {i}"
                );
                hit_count += one.is_some() as usize;
            }
            assert_eq!(reported, hit_count);
            if n == 500 {
                assert!(
                    hit_count > 50 && hit_count < 450,
                    "{hit_count} of 500 rays hit: not a test of both"
                );
            }
        }
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
}
