//! The per-node kernels of the [`Bvh`]'s walks: a ray's constants, the slab test of a wide
//! node's eight child boxes (one AVX vector per axis) and the Möller–Trumbore test of a pack of
//! four triangles (one SSE vector per quantity), each beside the scalar loop it must equal
//! (targets without AVX run the loops; the tests compare the two bit for bit).

use super::{TriPack, WideNode, EDGE_EPS, PACK, WIDTH};
use glam::Vec3;

/// A ray's origin, direction and reciprocal direction, per axis.
pub(super) struct RayConsts {
    origin: [f32; 3],
    dir: [f32; 3],
    inv: [f32; 3],
}

impl RayConsts {
    /// A direction component under 1e-20 in size is taken as ±1e-20 for the reciprocal: a ray
    /// that lies in a box's face plane (a zero component, the origin on the plane) then meets
    /// that slab on [0, ∞) instead of making 0·∞ = NaN, which the box test's min and max would
    /// drop and the box with it (a ray along +z through a sphere's pole missed it).
    pub(super) fn new(origin: Vec3, dir: Vec3) -> Self {
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

impl TriPack {
    /// [`intersect_tri`] in every lane, with the same operations in the same order (so the
    /// same results): bit `lane` of the mask is set where the ray meets that triangle within
    /// (t_min, t_max), with its t and barycentrics.
    #[inline(always)]
    pub(super) fn intersect(
        &self,
        ray: &RayConsts,
        t_min: f32,
        t_max: f32,
    ) -> (u32, [f32; PACK], [f32; PACK], [f32; PACK]) {
        #[cfg(target_feature = "avx")]
        // SAFETY: AVX is enabled at compile time; the loads read the pack's 4-float rows and
        // the stores write the three 4-float arrays.
        // Why: the loop below ran lane by lane (a tenth of the traversal's time on a mesh that
        // fits the caches); here the four lanes are one vector each step, with the same
        // operations in the same order (IEEE multiplies, adds and the division, no fused ones),
        // so the same values.
        unsafe {
            use std::arch::x86_64::*;
            let ld = |r: &[f32; PACK]| _mm_loadu_ps(r.as_ptr());
            let (mul, sub, add) = (
                |a, b| _mm_mul_ps(a, b),
                |a, b| _mm_sub_ps(a, b),
                |a, b| _mm_add_ps(a, b),
            );
            let cross = |a: [__m128; 3], b: [__m128; 3]| {
                [
                    sub(mul(a[1], b[2]), mul(b[1], a[2])),
                    sub(mul(a[2], b[0]), mul(b[2], a[0])),
                    sub(mul(a[0], b[1]), mul(b[0], a[1])),
                ]
            };
            let dot = |a: [__m128; 3], b: [__m128; 3]| add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]));
            let e1 = [ld(&self.e1[0]), ld(&self.e1[1]), ld(&self.e1[2])];
            let e2 = [ld(&self.e2[0]), ld(&self.e2[1]), ld(&self.e2[2])];
            let d = ray.dir.map(|x| _mm_set1_ps(x));
            let p = cross(d, e2);
            let det = dot(e1, p);
            let inv_det = _mm_div_ps(_mm_set1_ps(1.0), det);
            let s = [0, 1, 2].map(|a| sub(_mm_set1_ps(ray.origin[a]), ld(&self.p0[a])));
            let u = mul(dot(s, p), inv_det);
            let q = cross(s, e1);
            let v = mul(dot(d, q), inv_det);
            let t = mul(dot(e2, q), inv_det);
            let abs_det = _mm_andnot_ps(_mm_set1_ps(-0.0), det);
            let (lo, hi) = (_mm_set1_ps(-EDGE_EPS), _mm_set1_ps(1.0 + EDGE_EPS));
            let ok = [
                _mm_cmp_ps::<_CMP_GE_OQ>(abs_det, _mm_set1_ps(1e-12)),
                _mm_cmp_ps::<_CMP_GE_OQ>(u, lo),
                _mm_cmp_ps::<_CMP_LE_OQ>(u, hi),
                _mm_cmp_ps::<_CMP_GE_OQ>(v, lo),
                _mm_cmp_ps::<_CMP_LE_OQ>(add(u, v), hi),
                _mm_cmp_ps::<_CMP_GT_OQ>(t, _mm_set1_ps(t_min)),
                _mm_cmp_ps::<_CMP_LT_OQ>(t, _mm_set1_ps(t_max)),
            ]
            .into_iter()
            .reduce(|a, b| _mm_and_ps(a, b))
            .expect("seven tests");
            let (mut ts, mut us, mut vs) = ([0f32; PACK], [0f32; PACK], [0f32; PACK]);
            _mm_storeu_ps(ts.as_mut_ptr(), t);
            _mm_storeu_ps(us.as_mut_ptr(), u);
            _mm_storeu_ps(vs.as_mut_ptr(), v);
            (_mm_movemask_ps(ok) as u32, ts, us, vs)
        }
        #[cfg(not(target_feature = "avx"))]
        self.intersect_scalar(ray, t_min, t_max)
    }

    /// [`TriPack::intersect`] lane by lane, without intrinsics (targets without AVX; the tests
    /// compare the two).
    #[cfg(any(test, not(target_feature = "avx")))]
    fn intersect_scalar(
        &self,
        ray: &RayConsts,
        t_min: f32,
        t_max: f32,
    ) -> (u32, [f32; PACK], [f32; PACK], [f32; PACK]) {
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
#[cfg(any(test, not(target_feature = "avx")))]
#[inline(always)]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - b[1] * a[2],
        a[2] * b[0] - b[2] * a[0],
        a[0] * b[1] - b[0] * a[1],
    ]
}

/// glam's `Vec3::dot`, operation for operation.
#[cfg(any(test, not(target_feature = "avx")))]
#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    (a[0] * b[0]) + (a[1] * b[1]) + (a[2] * b[2])
}

impl WideNode {
    /// The slab test of all [`WIDTH`] children at once (the loop vectorizes: one lane per
    /// child): bit i of the result is set when the ray meets child i within (t_min, t_max),
    /// and `near[i]` is where it enters. [`RayConsts::new`] keeps 0·∞ out of it.
    #[inline(always)]
    pub(super) fn slab(&self, ray: &RayConsts, t_min: f32, t_max: f32, near: &mut [f32; WIDTH]) -> u32 {
        #[cfg(target_feature = "avx")]
        // SAFETY: AVX is enabled at compile time; the loads read the node's 8-float rows and
        // the store writes the 8 floats of `near`.
        // Why not the loop below: its `f32::min`/`max` keep NaN semantics that cost a compare
        // and a blend per operation, and no lane can be NaN here (finite boxes and origins,
        // reciprocals bounded by `RayConsts::new`): the raw `vminps`/`vmaxps` give the same
        // values for a sixth less traversal time.
        unsafe {
            use std::arch::x86_64::*;
            let mut t0 = _mm256_set1_ps(t_min);
            let mut t1 = _mm256_set1_ps(t_max);
            for a in 0..3 {
                let o = _mm256_set1_ps(ray.origin[a]);
                let inv = _mm256_set1_ps(ray.inv[a]);
                let x = _mm256_mul_ps(_mm256_sub_ps(_mm256_loadu_ps(self.lo[a].as_ptr()), o), inv);
                let y = _mm256_mul_ps(_mm256_sub_ps(_mm256_loadu_ps(self.hi[a].as_ptr()), o), inv);
                t0 = _mm256_max_ps(t0, _mm256_min_ps(x, y));
                t1 = _mm256_min_ps(t1, _mm256_max_ps(x, y));
            }
            let far = _mm256_mul_ps(t1, _mm256_set1_ps(1.0 + 4.0 * f32::EPSILON));
            _mm256_storeu_ps(near.as_mut_ptr(), t0);
            let le = _mm256_cmp_ps::<_CMP_LE_OQ>(t0, far);
            (_mm256_movemask_ps(le) as u32) & self.used_mask
        }
        #[cfg(not(target_feature = "avx"))]
        self.slab_scalar(ray, t_min, t_max, near)
    }

    /// [`WideNode::slab`] without intrinsics (targets without AVX; the tests compare the two).
    #[cfg(any(test, not(target_feature = "avx")))]
    fn slab_scalar(&self, ray: &RayConsts, t_min: f32, t_max: f32, near: &mut [f32; WIDTH]) -> u32 {
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
        let mask = (0..WIDTH).fold(0, |m, i| m | (((near[i] <= far[i]) as u32) << i));
        mask & self.used_mask
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The vector triangle test gives the lane loop's mask, t and barycentrics bit for bit, on
    /// random packs (degenerate lanes included) and rays.
    #[test]
    fn pack_test_agrees_with_the_lane_loop() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(13);
        let mut v = || {
            Vec3::new(
                rng.gen_range(-2.0..2.0),
                rng.gen_range(-2.0..2.0),
                rng.gen_range(-2.0..2.0),
            )
        };
        let mut hits = 0;
        for n in 0..20000 {
            let mut pack = TriPack::EMPTY;
            let mut inside = Vec3::ZERO;
            for lane in 0..PACK - (n % 2) {
                let (p0, e1, e2) = (v(), 0.5 * v(), 0.5 * v());
                for a in 0..3 {
                    pack.p0[a][lane] = p0[a];
                    pack.e1[a][lane] = e1[a];
                    pack.e2[a][lane] = e2[a];
                }
                inside = p0 + 0.3 * e1 + 0.3 * e2;
            }
            // Half the rays aimed at a lane's triangle, half anywhere.
            let o = v();
            let d = if n % 4 < 2 { inside - o } else { v() };
            let ray = RayConsts::new(o, d.normalize_or(Vec3::X));
            let t_max = if n % 3 == 0 { f32::INFINITY } else { 3.0 };
            let fast = pack.intersect(&ray, 0.01, t_max);
            let slow = pack.intersect_scalar(&ray, 0.01, t_max);
            assert_eq!(fast.0, slow.0, "pack {n}");
            for l in 0..PACK {
                if fast.0 & (1 << l) != 0 {
                    assert_eq!(
                        (fast.1[l], fast.2[l], fast.3[l]),
                        (slow.1[l], slow.2[l], slow.3[l]),
                        "pack {n}"
                    );
                }
            }
            hits += fast.0.count_ones();
        }
        assert!(hits > 2000, "{hits} lane hits: not a test of hits");
    }

    /// The AVX slab test gives the loop's lanes, entry distances and mask alike, on random
    /// nodes and rays (axis-aligned and unbounded ones included).
    #[test]
    fn slab_agrees_with_the_scalar_loop() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(11);
        for _ in 0..2000 {
            let mut node = WideNode::EMPTY;
            for i in 0..WIDTH {
                for a in 0..3 {
                    let (x, y) = (rng.gen_range(-3.0f32..3.0), rng.gen_range(-3.0f32..3.0));
                    node.lo[a][i] = x.min(y);
                    node.hi[a][i] = x.max(y);
                }
            }
            node.used_mask = rng.gen_range(0..256);
            let mut d = Vec3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            );
            if rng.gen_bool(0.3) {
                d[rng.gen_range(0..3)] = 0.0;
            }
            let o = Vec3::new(
                rng.gen_range(-4.0..4.0),
                rng.gen_range(-4.0..4.0),
                rng.gen_range(-4.0..4.0),
            );
            let ray = RayConsts::new(o, d.normalize_or(Vec3::X));
            let t_max = if rng.gen_bool(0.3) {
                f32::INFINITY
            } else {
                rng.gen_range(0.1..10.0)
            };
            let (mut near, mut near_scalar) = ([0f32; WIDTH], [0f32; WIDTH]);
            let mask = node.slab(&ray, 0.0, t_max, &mut near);
            let scalar = node.slab_scalar(&ray, 0.0, t_max, &mut near_scalar);
            assert_eq!(mask, scalar);
            for i in 0..WIDTH {
                if mask & (1 << i) != 0 {
                    assert_eq!(near[i], near_scalar[i]);
                }
            }
        }
    }
}
