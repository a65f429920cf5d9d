//! Thin, safe wrappers for the three products of a dense layer — on the engine's AVX-512 kernel
//! ([`crate::smallgemm`]), `matrixmultiply::sgemm`, or in half precision on AMX tiles
//! ([`crate::amx`], per [`MatmulPrecision`]) — and the small slice utilities the tile loops share.
//!
//! All matrices are row-major with an explicit leading dimension (row stride). The engine calls these
//! from inside rayon tasks, one tile per call, so matrixmultiply's own threading must stay off: it
//! would split a 64×256×64 weight-gradient product over a second thread pool and fight rayon for the
//! same two cores. The workspace builds it without its `threading` feature, so it is single-threaded
//! by construction (no environment variable to set before first use); the sgemm peak of the
//! benchmark splits its product over rayon instead, so it measures the same kernel the engine runs.

/// Whether a product with inner dimension `k` and output width `n` runs on [`crate::smallgemm`]:
/// on AVX-512 builds, unless both are wide (the paper's 256-wide layers), where matrixmultiply's
/// cache blocking wins (measured, one thread: 256³ `A·Bᵀ` 135–185 vs 86 GFLOP/s; at 256×64×64
/// the small kernel does 240 vs 120). `I2SDF_GEMM=matrixmultiply` forces matrixmultiply.
fn small_gemm_for(k: usize, n: usize) -> bool {
    use_small_gemm() && (k <= 128 || n <= 128)
}

/// Operand precision of a network's matrix products ([`crate::Mlp::precision`], set by stage 1 from
/// `train.matmul_precision`). Sums are f32 in every mode; the half-precision modes run on AMX tiles
/// ([`crate::amx`]) where the CPU has them and fall back to f32 elsewhere
/// ([`effective_precision`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MatmulPrecision {
    /// f32 operands (AVX-512 or matrixmultiply kernels).
    #[default]
    F32,
    /// bf16 operands, each rounded once (8-bit mantissa).
    Bf16,
    /// Each operand split into two bf16 parts, three tile products (~16-bit mantissa).
    Bf16x3,
}

impl MatmulPrecision {
    pub fn name(self) -> &'static str {
        match self {
            MatmulPrecision::F32 => "f32",
            MatmulPrecision::Bf16 => "bf16",
            MatmulPrecision::Bf16x3 => "bf16x3",
        }
    }
}

/// The precision a product asked for `p` runs at: `p`, or f32 where the CPU has no AMX.
pub fn effective_precision(p: MatmulPrecision) -> MatmulPrecision {
    match p {
        MatmulPrecision::Bf16 | MatmulPrecision::Bf16x3 if crate::amx::available() => p,
        _ => MatmulPrecision::F32,
    }
}

/// `Some(split)` when an `m×k×n` product runs on AMX tiles: half precision is set and the CPU has
/// them, and the output is at least one tile (16 × 16) — narrower outputs (the radiance MLP's
/// three colours) keep the f32 kernels, where a tile would be mostly padding.
fn amx_for(m: usize, n: usize, precision: MatmulPrecision) -> Option<bool> {
    if m < 16 || n < 16 || precision == MatmulPrecision::F32 {
        return None;
    }
    match effective_precision(precision) {
        MatmulPrecision::F32 => None,
        MatmulPrecision::Bf16 => Some(false),
        MatmulPrecision::Bf16x3 => Some(true),
    }
}

/// The engine's own kernels, which share one calling convention (strided `A`, row-major `B`,
/// overwrite or accumulate); everything else goes to matrixmultiply.
#[derive(Clone, Copy)]
enum Kernel {
    /// AMX tiles; `true`: bf16x3.
    Amx(bool),
    /// The AVX-512 f32 kernel.
    Small,
}

/// The kernel for a product, when one of ours takes it: AMX where `precision` asks for half
/// precision and the shape suits it, else the f32 kernel where `small` says so.
fn kernel_for(m: usize, n: usize, precision: MatmulPrecision, small: bool) -> Option<Kernel> {
    amx_for(m, n, precision)
        .map(Kernel::Amx)
        .or(small.then_some(Kernel::Small))
}

/// `C = (accumulate ? C : 0) + A·B` on `kernel`, `A(r, p) = a[r·rsa + p·csa]`.
///
/// # Safety
/// As [`crate::smallgemm::gemm`]: all three matrices in bounds for the strides.
#[allow(clippy::too_many_arguments)]
unsafe fn run_kernel(
    kernel: Kernel,
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
    // SAFETY: the caller's bounds; AMX is only chosen where `amx::available()`.
    unsafe {
        match kernel {
            Kernel::Amx(split) => crate::amx::gemm(m, k, n, a, rsa, csa, b, ldb, accumulate, c, ldc, split),
            Kernel::Small => crate::smallgemm::gemm(m, k, n, a, rsa, csa, b, ldb, accumulate, c, ldc),
        }
    }
}

fn use_small_gemm() -> bool {
    use std::sync::OnceLock;
    static CHOICE: OnceLock<bool> = OnceLock::new();
    *CHOICE.get_or_init(|| {
        crate::smallgemm::AVAILABLE && std::env::var("I2SDF_GEMM").map_or(true, |v| v != "matrixmultiply")
    })
}

std::thread_local! {
    /// `Bᵀ` of [`gemm_a_bt`] for the small kernel (a weight matrix; reused, never shrunk).
    static TRANSPOSED: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// `C[m×n] = beta·C + A[m×k] · Bᵀ`, with `B` stored `[n×k]` (a layer's weight `W[out×in]`).
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn gemm_a_bt(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    lda: usize,
    b: &[f32],
    ldb: usize,
    beta: f32,
    c: &mut [f32],
    ldc: usize,
    precision: MatmulPrecision,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(a.len() >= (m - 1) * lda + k && b.len() >= (n - 1) * ldb + k);
    assert!(c.len() >= (m - 1) * ldc + n);
    let kernel = kernel_for(m, n, precision, small_gemm_for(k, n)).filter(|_| beta == 0.0 || beta == 1.0);
    if let Some(kernel) = kernel {
        TRANSPOSED.with_borrow_mut(|bt| {
            if bt.len() < k * n {
                bt.resize(k * n, 0.0);
            }
            for j in 0..n {
                for p in 0..k {
                    bt[p * n + j] = b[j * ldb + p];
                }
            }
            // SAFETY: bounds asserted above; Bᵀ is [k×n] in `bt`.
            unsafe {
                run_kernel(
                    kernel,
                    m,
                    k,
                    n,
                    a.as_ptr(),
                    lda,
                    1,
                    bt.as_ptr(),
                    n,
                    beta == 1.0,
                    c.as_mut_ptr(),
                    ldc,
                )
            }
        });
        return;
    }
    // SAFETY: bounds asserted above; strides describe row-major storage inside the slices.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            lda as isize,
            1,
            b.as_ptr(),
            1,
            ldb as isize,
            beta,
            c.as_mut_ptr(),
            ldc as isize,
            1,
        )
    }
}

/// `C[m×n] = beta·C + A[m×k] · B[k×n]`.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn gemm_a_b(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    lda: usize,
    b: &[f32],
    ldb: usize,
    beta: f32,
    c: &mut [f32],
    ldc: usize,
    precision: MatmulPrecision,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(a.len() >= (m - 1) * lda + k && b.len() >= (k.max(1) - 1) * ldb + n);
    assert!(c.len() >= (m - 1) * ldc + n);
    if let Some(kernel) = kernel_for(m, n, precision, small_gemm_for(k, n)).filter(|_| beta == 0.0 || beta == 1.0) {
        // SAFETY: bounds asserted above.
        unsafe {
            run_kernel(
                kernel,
                m,
                k,
                n,
                a.as_ptr(),
                lda,
                1,
                b.as_ptr(),
                ldb,
                beta == 1.0,
                c.as_mut_ptr(),
                ldc,
            )
        };
        return;
    }
    // SAFETY: bounds asserted above.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            lda as isize,
            1,
            b.as_ptr(),
            ldb as isize,
            1,
            beta,
            c.as_mut_ptr(),
            ldc as isize,
            1,
        )
    }
}

/// `C[m×n] += Aᵀ · B` with `A` stored `[k×m]` and `B` `[k×n]`: the weight gradient `W̄ += Z̄ᵀ·I`
/// summed over the `k` points of a tile.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn gemm_at_b_acc(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    lda: usize,
    b: &[f32],
    ldb: usize,
    c: &mut [f32],
    ldc: usize,
    precision: MatmulPrecision,
) {
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    assert!(a.len() >= (k - 1) * lda + m && b.len() >= (k - 1) * ldb + n);
    assert!(c.len() >= (m - 1) * ldc + n);
    if let Some(kernel) = kernel_for(m, n, precision, small_gemm_for(m, n)) {
        // SAFETY: bounds asserted above; A(r, p) = a[p·lda + r].
        unsafe {
            run_kernel(
                kernel,
                m,
                k,
                n,
                a.as_ptr(),
                1,
                lda,
                b.as_ptr(),
                ldb,
                true,
                c.as_mut_ptr(),
                ldc,
            )
        };
        return;
    }
    // SAFETY: bounds asserted above.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            1,
            lda as isize,
            b.as_ptr(),
            ldb as isize,
            1,
            1.0,
            c.as_mut_ptr(),
            ldc as isize,
            1,
        )
    }
}

/// Split `s` into consecutive mutable pieces of the given lengths (the rest is dropped).
pub fn split_lengths_mut<'a, T>(mut s: &'a mut [T], lens: &[usize]) -> Vec<&'a mut [T]> {
    let mut out = Vec::with_capacity(lens.len());
    for &l in lens {
        let (head, tail) = std::mem::take(&mut s).split_at_mut(l);
        out.push(head);
        s = tail;
    }
    out
}

/// Contiguous ranges of `n_items` split into at most `n_parts` nearly equal parts (none empty).
pub fn even_ranges(n_items: usize, n_parts: usize) -> Vec<std::ops::Range<usize>> {
    let parts = n_parts.clamp(1, n_items.max(1));
    (0..parts)
        .map(|p| (p * n_items / parts)..((p + 1) * n_items / parts))
        .filter(|r| !r.is_empty())
        .collect()
}

/// Sum per-chunk accumulators into `out` (`out += Σ accs`), in parallel over slices of `out`.
pub fn reduce_into(out: &mut [f32], accs: &[Vec<f32>]) {
    use rayon::prelude::*;
    const BLOCK: usize = 1 << 14;
    out.par_chunks_mut(BLOCK).enumerate().for_each(|(b, o)| {
        let (start, len) = (b * BLOCK, o.len());
        for acc in accs {
            for (o, a) in o.iter_mut().zip(&acc[start..start + len]) {
                *o += a;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gemm_wrappers_match_naive_products() {
        let (m, k, n) = (5, 7, 3);
        let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let bt: Vec<f32> = (0..n * k).map(|i| (i as f32 * 0.91).cos()).collect();
        let bn: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.53).sin()).collect();
        let mut c = vec![1.0f32; m * n];
        gemm_a_bt(m, k, n, &a, k, &bt, k, 1.0, &mut c, n, MatmulPrecision::F32);
        for i in 0..m {
            for j in 0..n {
                let want: f32 = 1.0 + (0..k).map(|p| a[i * k + p] * bt[j * k + p]).sum::<f32>();
                assert!((c[i * n + j] - want).abs() < 1e-5);
            }
        }
        gemm_a_b(m, k, n, &a, k, &bn, n, 0.0, &mut c, n, MatmulPrecision::F32);
        for i in 0..m {
            for j in 0..n {
                let want: f32 = (0..k).map(|p| a[i * k + p] * bn[p * n + j]).sum();
                assert!((c[i * n + j] - want).abs() < 1e-5);
            }
        }
        // Aᵀ·B with A [m×k] seen as [k'=m × m'=k]
        let mut g = vec![0.5f32; k * n];
        let b2: Vec<f32> = (0..m * n).map(|i| i as f32 * 0.1).collect();
        gemm_at_b_acc(k, m, n, &a, k, &b2, n, &mut g, n, MatmulPrecision::F32);
        for i in 0..k {
            for j in 0..n {
                let want: f32 = 0.5 + (0..m).map(|p| a[p * k + i] * b2[p * n + j]).sum::<f32>();
                assert!((g[i * n + j] - want).abs() < 1e-4);
            }
        }
    }
}
