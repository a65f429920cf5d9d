//! A packing-free AVX-512 kernel for the skinny products of the tile loops.
//!
//! The per-tile products are `256 × 64 × 64`-sized. A general sgemm (matrixmultiply) packs both
//! operands on every call; at `k = 64` that copy costs 15–30 % of the multiply (measured: 8 % of
//! the whole iteration in `pack_avx512`). Here `B` (`[k × n]`, row-major, ≤ 64 KiB for a tile) is
//! read in place, one row of 4 vectors per step, and `A` is read by scalar broadcasts with arbitrary
//! strides, so `Aᵀ·B` (weight gradients) needs no transpose either. The register block is up to 6
//! rows × 64 columns (24 accumulators of 16 lanes), 16 rows × 16 columns for narrow outputs;
//! partial blocks use smaller instantiations and masked loads/stores. Only `A·Bᵀ` copies `Bᵀ` (a weight matrix, ≤ 64 KiB) into a thread-local buffer.

#![allow(clippy::too_many_arguments)]

/// Whether this build has the kernel (x86-64 with AVX-512F enabled at compile time).
pub const AVAILABLE: bool = cfg!(all(target_arch = "x86_64", target_feature = "avx512f"));

#[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
mod imp {
    use std::arch::x86_64::*;

    type Kernel = unsafe fn(usize, *const f32, usize, usize, *const f32, usize, bool, *mut f32, usize, u16);

    /// `C[MR × 16·NV] (+)= A[MR × k] · B[k × 16·NV]`, last vector masked by `mask`.
    #[inline(always)]
    unsafe fn kernel<const MR: usize, const NV: usize>(
        k: usize,
        a: *const f32,
        rsa: usize,
        csa: usize,
        b: *const f32,
        ldb: usize,
        accumulate: bool,
        c: *mut f32,
        ldc: usize,
        mask: u16,
    ) {
        unsafe {
            let mut acc = [[_mm512_setzero_ps(); NV]; MR];
            for p in 0..k {
                let brow = b.add(p * ldb);
                let mut bv = [_mm512_setzero_ps(); NV];
                for (v, bvv) in bv.iter_mut().enumerate() {
                    *bvv = if v + 1 == NV {
                        _mm512_maskz_loadu_ps(mask, brow.add(16 * v))
                    } else {
                        _mm512_loadu_ps(brow.add(16 * v))
                    };
                }
                let ap = a.add(p * csa);
                for (r, accr) in acc.iter_mut().enumerate() {
                    let av = _mm512_set1_ps(*ap.add(r * rsa));
                    for v in 0..NV {
                        accr[v] = _mm512_fmadd_ps(av, bv[v], accr[v]);
                    }
                }
            }
            for (r, accr) in acc.iter().enumerate() {
                for (v, &x) in accr.iter().enumerate() {
                    let cp = c.add(r * ldc + 16 * v);
                    let m = if v + 1 == NV { mask } else { 0xffff };
                    let x = if accumulate {
                        _mm512_add_ps(x, _mm512_maskz_loadu_ps(m, cp))
                    } else {
                        x
                    };
                    _mm512_mask_storeu_ps(cp, m, x);
                }
            }
        }
    }

    unsafe fn k_entry<const MR: usize, const NV: usize>(
        k: usize,
        a: *const f32,
        rsa: usize,
        csa: usize,
        b: *const f32,
        ldb: usize,
        accumulate: bool,
        c: *mut f32,
        ldc: usize,
        mask: u16,
    ) {
        unsafe { kernel::<MR, NV>(k, a, rsa, csa, b, ldb, accumulate, c, ldc, mask) }
    }

    /// Rows per register block for `NV` vectors of columns: as many as the 32 registers allow
    /// (`MR·NV` accumulators + `NV` B vectors + a broadcast), and at least 8 independent FMA chains
    /// (2 FMA units × 4 cycles latency) so narrow outputs are not latency-bound.
    pub const MR_MAX: [usize; 4] = [16, 12, 8, 6];

    macro_rules! kernels {
        ($nv:literal; $($mr:literal)*) => {
            [$(k_entry::<$mr, $nv> as Kernel),*]
        };
    }
    const K1: [Kernel; 16] = kernels!(1; 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16);
    const K2: [Kernel; 12] = kernels!(2; 1 2 3 4 5 6 7 8 9 10 11 12);
    const K3: [Kernel; 8] = kernels!(3; 1 2 3 4 5 6 7 8);
    const K4: [Kernel; 6] = kernels!(4; 1 2 3 4 5 6);
    const KERNELS: [&[Kernel]; 4] = [&K1, &K2, &K3, &K4];

    /// `C[m×n] = (accumulate ? C : 0) + A·B`; `A(r, p) = a[r·rsa + p·csa]`, `B` row-major `[k×n]`.
    pub unsafe fn gemm(
        m: usize,
        k: usize,
        n: usize,
        a: *const f32,
        rsa: usize,
        csa: usize,
        b: *const f32,
        ldb: usize,
        accumulate: bool,
        c: *mut f32,
        ldc: usize,
    ) {
        unsafe {
            let mut j0 = 0;
            while j0 < n {
                let w = (n - j0).min(64);
                let nv = w.div_ceil(16);
                let rem = w % 16;
                let mask: u16 = if rem == 0 { 0xffff } else { (1u16 << rem) - 1 };
                let mut i0 = 0;
                while i0 < m {
                    let mr = (m - i0).min(MR_MAX[nv - 1]);
                    KERNELS[nv - 1][mr - 1](
                        k,
                        a.add(i0 * rsa),
                        rsa,
                        csa,
                        b.add(j0),
                        ldb,
                        accumulate,
                        c.add(i0 * ldc + j0),
                        ldc,
                        mask,
                    );
                    i0 += mr;
                }
                j0 += 64;
            }
        }
    }
}

/// `C = (accumulate ? C : 0) + A·B` (see the module docs); panics if the kernel is not available.
///
/// # Safety
/// `A(r, p) = a[r·rsa + p·csa]` for `r < m`, `p < k`, `B(p, j) = b[p·ldb + j]` for `j < n`, and
/// `C(r, j) = c[r·ldc + j]` must all be in bounds.
#[allow(unused_variables)]
pub unsafe fn gemm(
    m: usize,
    k: usize,
    n: usize,
    a: *const f32,
    rsa: usize,
    csa: usize,
    b: *const f32,
    ldb: usize,
    accumulate: bool,
    c: *mut f32,
    ldc: usize,
) {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
    unsafe {
        imp::gemm(m, k, n, a, rsa, csa, b, ldb, accumulate, c, ldc)
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx512f")))]
    panic!("smallgemm needs AVX-512F");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_naive_on_ragged_shapes() {
        if !AVAILABLE {
            return;
        }
        for &(m, k, n) in &[
            (1, 1, 1),
            (7, 5, 3),
            (13, 35, 64),
            (256, 64, 16),
            (6, 3, 65),
            (20, 9, 130),
        ] {
            let a: Vec<f32> = (0..m * k).map(|i| ((i * 7 % 13) as f32 - 6.0) * 0.1).collect();
            let b: Vec<f32> = (0..k * n).map(|i| ((i * 5 % 11) as f32 - 5.0) * 0.1).collect();
            for accumulate in [false, true] {
                // A row-major (rsa = k, csa = 1) and the same A read transposed from Aᵀ storage
                let at: Vec<f32> = (0..k * m).map(|i| a[(i % m) * k + i / m]).collect();
                for (ap, rsa, csa) in [(&a, k, 1), (&at, 1, m)] {
                    let mut c = vec![0.5f32; m * n + 3];
                    unsafe {
                        gemm(
                            m,
                            k,
                            n,
                            ap.as_ptr(),
                            rsa,
                            csa,
                            b.as_ptr(),
                            n,
                            accumulate,
                            c.as_mut_ptr(),
                            n,
                        )
                    };
                    for i in 0..m {
                        for j in 0..n {
                            let want = if accumulate { 0.5 } else { 0.0 }
                                + (0..k).map(|p| a[i * k + p] * b[p * n + j]).sum::<f32>();
                            assert!((c[i * n + j] - want).abs() < 1e-4, "({m},{k},{n}) [{i},{j}]");
                        }
                    }
                    assert_eq!(&c[m * n..], &[0.5; 3], "wrote past C");
                }
            }
        }
    }
}
