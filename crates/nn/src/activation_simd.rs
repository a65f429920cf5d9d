//! AVX-512 Softplus: the forward, its derivative and its backward on 16 lanes.
//!
//! Why by hand: LLVM vectorizes the scalar loops of `activation.rs`, but with 256-bit vectors only
//! (the `prefer-256-bit` tuning of these CPUs), and the Softplus forward alone was 9 % of a stage-1
//! iteration and 31 % of a marching-cubes sweep. These are the same operations in the same order
//! as the scalar `exp_fast` / `log1p_unit` (the same FMAs, the mul and add left uncontracted where
//! the scalar code has them, the same NaN handling), so the results are bitwise those of the
//! scalar path; the tests check that lane by lane.

use super::activation::{LN2_HI, LN2_LO, LOG2E};
use std::arch::x86_64::*;

/// `exp_fast` on 16 lanes.
#[inline]
#[target_feature(enable = "avx512f")]
fn exp16(x: __m512) -> __m512 {
    // `_mm512_max_ps(x, b)` returns `b` when `x` is NaN, as `f32::max` does.
    let xc = _mm512_min_ps(_mm512_max_ps(x, _mm512_set1_ps(-87.0)), _mm512_set1_ps(88.0));
    let t = _mm512_add_ps(_mm512_mul_ps(xc, _mm512_set1_ps(LOG2E)), _mm512_set1_ps(0.5));
    let n = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(t);
    let neg_n = _mm512_castsi512_ps(_mm512_xor_si512(_mm512_castps_si512(n), _mm512_set1_epi32(i32::MIN)));
    let r = _mm512_fmadd_ps(neg_n, _mm512_set1_ps(LN2_HI), xc);
    let r = _mm512_fmadd_ps(neg_n, _mm512_set1_ps(LN2_LO), r);
    let mut p = _mm512_set1_ps(1.987_569_1e-4);
    for c in [1.398_199_9e-3, 8.333_452e-3, 4.166_579_6e-2, 1.666_666_5e-1, 0.5] {
        p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(c));
    }
    let p = _mm512_fmadd_ps(_mm512_mul_ps(p, r), r, _mm512_add_ps(r, _mm512_set1_ps(1.0)));
    let ni = _mm512_cvttps_epi32(n);
    let scale = _mm512_castsi512_ps(_mm512_slli_epi32::<23>(_mm512_add_epi32(ni, _mm512_set1_epi32(127))));
    let nan = _mm512_cmp_ps_mask::<_CMP_UNORD_Q>(x, x);
    _mm512_mask_blend_ps(nan, _mm512_mul_ps(p, scale), x)
}

/// `log1p_unit` on 16 lanes.
#[inline]
#[target_feature(enable = "avx512f")]
fn log1p_unit16(e: __m512) -> __m512 {
    let mut q = _mm512_set1_ps(0.005_253_458);
    for c in [
        -0.029_588_508,
        0.078_361_67,
        -0.136_747_7,
        0.191_114_3,
        -0.248_443_7,
        0.333_192_7,
        -0.499_995,
        1.0,
    ] {
        q = _mm512_fmadd_ps(q, e, _mm512_set1_ps(c));
    }
    _mm512_mul_ps(e, q)
}

/// `1 − e^{−β a}` on 16 lanes (`-beta * a` as the scalar code computes it: `(−β)·a`).
#[inline]
#[target_feature(enable = "avx512f")]
fn derivative16(a: __m512, neg_beta: __m512) -> __m512 {
    _mm512_sub_ps(_mm512_set1_ps(1.0), exp16(_mm512_mul_ps(neg_beta, a)))
}

/// Softplus forward in place on the first `16·⌊n/16⌋` values; returns how many were done.
#[target_feature(enable = "avx512f")]
pub(super) fn softplus_forward(z: &mut [f32], beta: f32) -> usize {
    let (b, inv) = (_mm512_set1_ps(beta), _mm512_set1_ps(1.0 / beta));
    let abs_mask = _mm512_set1_epi32(0x7fff_ffff);
    let sign = _mm512_set1_epi32(i32::MIN);
    let n = z.len() / 16 * 16;
    for c in z[..n].chunks_exact_mut(16) {
        // SAFETY: `c` holds exactly 16 floats; unaligned loads and stores.
        let v = unsafe { _mm512_loadu_ps(c.as_ptr()) };
        let y = _mm512_mul_ps(v, b);
        let neg_abs = _mm512_castsi512_ps(_mm512_or_si512(
            _mm512_and_si512(_mm512_castps_si512(y), abs_mask),
            sign,
        ));
        let out = _mm512_mul_ps(
            _mm512_add_ps(_mm512_max_ps(y, _mm512_setzero_ps()), log1p_unit16(exp16(neg_abs))),
            inv,
        );
        unsafe { _mm512_storeu_ps(c.as_mut_ptr(), out) };
    }
    n
}

/// `s = 1 − e^{−β a}` on the first `16·⌊n/16⌋` values; returns how many were done.
#[target_feature(enable = "avx512f")]
pub(super) fn softplus_derivative(a: &[f32], s: &mut [f32], beta: f32) -> usize {
    derivative_pass(a, s, beta, |d, _| d)
}

/// `g ← g · (1 − e^{−β a})` on the first `16·⌊n/16⌋` values; returns how many were done.
#[target_feature(enable = "avx512f")]
pub(super) fn softplus_backward(a: &[f32], g: &mut [f32], beta: f32) -> usize {
    derivative_pass(a, g, beta, |d, g| _mm512_mul_ps(g, d))
}

/// `out ← combine(1 − e^{−β a}, out)` over whole 16-lane chunks; returns how many were done.
#[inline]
#[target_feature(enable = "avx512f")]
fn derivative_pass(a: &[f32], out: &mut [f32], beta: f32, combine: impl Fn(__m512, __m512) -> __m512) -> usize {
    let neg_beta = _mm512_set1_ps(-beta);
    let n = a.len().min(out.len()) / 16 * 16;
    for (a, o) in a[..n].chunks_exact(16).zip(out[..n].chunks_exact_mut(16)) {
        // SAFETY: both chunks hold exactly 16 floats; unaligned loads and stores.
        let (av, ov) = unsafe { (_mm512_loadu_ps(a.as_ptr()), _mm512_loadu_ps(o.as_ptr())) };
        unsafe { _mm512_storeu_ps(o.as_mut_ptr(), combine(derivative16(av, neg_beta), ov)) };
    }
    n
}

#[cfg(test)]
mod tests {
    use crate::activation::Activation;
    use rand::{Rng, SeedableRng};

    /// Inputs across the whole range the networks see and beyond, with the special values.
    fn inputs(n: usize) -> Vec<f32> {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let mut v: Vec<f32> = (0..n)
            .map(|i| match i % 4 {
                0 => rng.gen_range(-0.05f32..0.05),
                1 => rng.gen_range(-2.0f32..2.0),
                2 => rng.gen_range(-1e3f32..1e3),
                _ => f32::from_bits(rng.gen::<u32>()),
            })
            .collect();
        let special = [
            0.0,
            -0.0,
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            1e-40,
            -1e-40,
            0.87,
            -0.88,
        ];
        v[..special.len()].copy_from_slice(&special);
        v
    }

    fn same_bits(a: &[f32], b: &[f32]) -> bool {
        a.iter()
            .zip(b)
            .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
    }

    #[test]
    fn softplus_forward_derivative_and_backward_equal_the_scalar_path_bit_for_bit() {
        let beta = 100.0;
        let act = Activation::Softplus { beta };
        // 16·k + 5 values: the tail goes through the scalar code in both.
        let z = inputs(16 * 640 + 5);
        let mut scalar = z.clone();
        act.forward_inplace_scalar(&mut scalar);
        let mut simd = z.clone();
        act.forward_inplace(&mut simd);
        assert!(same_bits(&scalar, &simd), "forward");

        let (mut s_scalar, mut s_simd) = (vec![0.0; z.len()], vec![0.0; z.len()]);
        act.derivative_into_scalar(&scalar, &mut s_scalar);
        act.derivative_into(&scalar, &mut s_simd);
        assert!(same_bits(&s_scalar, &s_simd), "derivative");

        let g = inputs(z.len());
        let (mut g_scalar, mut g_simd) = (g.clone(), g);
        act.backward_inplace_scalar(&scalar, &mut g_scalar);
        act.backward_inplace(&scalar, &mut g_simd);
        assert!(same_bits(&g_scalar, &g_simd), "backward");
    }
}
