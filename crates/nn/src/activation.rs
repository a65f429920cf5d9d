//! Activations, their first and second derivatives, and the branch-free `exp`/`log1p` they need.
//!
//! Every derivative is expressed in terms of the activation's *output* `a = φ(z)`, so the backward
//! passes only keep the post-activation buffers: for Softplus(β), `φ'(z) = σ(βz) = 1 − e^{−βa}`
//! (because `e^{−softplus(y)} = 1 − σ(y)`), and `φ'' = β φ'(1 − φ')`. The second derivative is what
//! the double backward of the SDF spatial gradient (eikonal loss) needs.
//!
//! `libm`'s scalar `expf`/`log1pf` would cost more than the matrix products here (an 8×256 Softplus
//! MLP evaluates 2k activations per point), so `exp_fast` is a Cephes-style range reduction with a
//! degree-6 polynomial (≤ 2 ulp on the range used) written so that LLVM vectorizes it with AVX-512;
//! Softplus's `ln(1 + e^{−|y|})` is a division-free polynomial (`log1p_unit`).

use serde::{Deserialize, Serialize};

/// A pointwise activation function.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Activation {
    Identity,
    Relu,
    /// `softplus(βz)/β`; the paper's SDF MLP uses β = 100 (VolSDF, IDR).
    Softplus {
        beta: f32,
    },
    Sigmoid,
}

pub(crate) const LOG2E: f32 = std::f32::consts::LOG2_E;
pub(crate) const LN2_HI: f32 = 0.693_359_4;
pub(crate) const LN2_LO: f32 = -2.121_944_4e-4;

/// `e^x`, relative error ~2e-7, clamped to the normal f32 range; NaN stays NaN. Branch-free so
/// loops over slices vectorize.
#[inline(always)]
pub fn exp_fast(x: f32) -> f32 {
    // `max`/`min` (not `clamp`) map NaN to a finite bound, so `n` below is always in range; the
    // NaN is put back at the end with a select, which vectorizes like the rest.
    let xc = x.max(-87.0).min(88.0);
    let n = (xc * LOG2E + 0.5).floor();
    let r = (-n).mul_add(LN2_LO, (-n).mul_add(LN2_HI, xc));
    // Taylor/minimax polynomial of e^r on |r| ≤ ln2/2 (Cephes expf coefficients).
    // `mul_add` is one FMA (the build targets the native CPU): half the instructions of the
    // chain and one rounding per step; without FMA hardware it would be a slow libm call.
    let p = 1.987_569_1e-4_f32;
    let p = p.mul_add(r, 1.398_199_9e-3);
    let p = p.mul_add(r, 8.333_452e-3);
    let p = p.mul_add(r, 4.166_579_6e-2);
    let p = p.mul_add(r, 1.666_666_5e-1);
    let p = p.mul_add(r, 0.5);
    let p = (p * r).mul_add(r, r + 1.0);
    // SAFETY: `xc` is finite with |xc| ≤ 88 (NaN and ±∞ were mapped to the bounds above), which
    // keeps n in [−126, 127]: finite and in range, so the unchecked conversion (which vectorizes,
    // unlike `as` with its NaN/saturation checks) is exact.
    let ni: i32 = unsafe { n.to_int_unchecked() };
    let scale = f32::from_bits(((ni + 127) as u32) << 23);
    if x.is_nan() {
        x
    } else {
        p * scale
    }
}

/// `ln(1 + e)` for `e ∈ [0, 1]` as `e·q(e)`, `q` a degree-8 least-squares fit of `ln(1+e)/e` on
/// Chebyshev nodes of `[0, 1]`: |error| ≤ 1e-7 in f32 evaluation, and no division (a vector
/// divide costs as much as the whole polynomial).
#[inline(always)]
fn log1p_unit(e: f32) -> f32 {
    let q = 0.005_253_458_f32;
    let q = q.mul_add(e, -0.029_588_508);
    let q = q.mul_add(e, 0.078_361_67);
    let q = q.mul_add(e, -0.136_747_7);
    let q = q.mul_add(e, 0.191_114_3);
    let q = q.mul_add(e, -0.248_443_7);
    let q = q.mul_add(e, 0.333_192_7);
    let q = q.mul_add(e, -0.499_995);
    let q = q.mul_add(e, 1.0);
    e * q
}

impl Activation {
    /// `a = φ(z)` in place.
    pub fn forward_inplace(self, z: &mut [f32]) {
        #[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
        if let Activation::Softplus { beta } = self {
            // SAFETY: the build enables AVX-512F (checked by the cfg).
            let done = unsafe { crate::activation_simd::softplus_forward(z, beta) };
            return self.forward_inplace_scalar(&mut z[done..]);
        }
        self.forward_inplace_scalar(z)
    }

    /// [`forward_inplace`](Self::forward_inplace) without the AVX-512 path.
    pub(crate) fn forward_inplace_scalar(self, z: &mut [f32]) {
        match self {
            Activation::Identity => {}
            Activation::Relu => z.iter_mut().for_each(|v| *v = v.max(0.0)),
            Activation::Softplus { beta } => {
                let inv = 1.0 / beta;
                z.iter_mut().for_each(|v| {
                    let y = *v * beta;
                    *v = (y.max(0.0) + log1p_unit(exp_fast(-y.abs()))) * inv;
                })
            }
            Activation::Sigmoid => z.iter_mut().for_each(|v| *v = 1.0 / (1.0 + exp_fast(-*v))),
        }
    }

    /// `φ'(z)` from the output `a = φ(z)`.
    #[inline(always)]
    pub fn derivative_from_output(self, a: f32) -> f32 {
        match self {
            Activation::Identity => 1.0,
            Activation::Relu => {
                if a > 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
            Activation::Softplus { beta } => 1.0 - exp_fast(-beta * a),
            Activation::Sigmoid => a * (1.0 - a),
        }
    }

    /// `φ''(z)` from the output `a = φ(z)`.
    #[inline(always)]
    pub fn second_derivative_from_output(self, a: f32) -> f32 {
        match self {
            Activation::Identity | Activation::Relu => 0.0,
            Activation::Softplus { beta } => {
                let s = 1.0 - exp_fast(-beta * a);
                beta * s * (1.0 - s)
            }
            Activation::Sigmoid => a * (1.0 - a) * (1.0 - 2.0 * a),
        }
    }

    /// Whether `φ'' ≡ 0`, so the second-order term of a double backward can be skipped.
    pub fn is_piecewise_linear(self) -> bool {
        matches!(self, Activation::Identity | Activation::Relu)
    }

    /// `s = φ'(z)` for every output `a = φ(z)`.
    pub fn derivative_into(self, a: &[f32], s: &mut [f32]) {
        debug_assert_eq!(a.len(), s.len());
        #[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
        if let Activation::Softplus { beta } = self {
            // SAFETY: the build enables AVX-512F (checked by the cfg).
            let done = unsafe { crate::activation_simd::softplus_derivative(a, s, beta) };
            return self.derivative_into_scalar(&a[done..], &mut s[done..]);
        }
        self.derivative_into_scalar(a, s)
    }

    /// [`derivative_into`](Self::derivative_into) without the AVX-512 path.
    pub(crate) fn derivative_into_scalar(self, a: &[f32], s: &mut [f32]) {
        match self {
            Activation::Identity => s.fill(1.0),
            Activation::Relu => s
                .iter_mut()
                .zip(a)
                .for_each(|(s, &a)| *s = if a > 0.0 { 1.0 } else { 0.0 }),
            Activation::Softplus { beta } => s.iter_mut().zip(a).for_each(|(s, &a)| *s = 1.0 - exp_fast(-beta * a)),
            Activation::Sigmoid => s.iter_mut().zip(a).for_each(|(s, &a)| *s = a * (1.0 - a)),
        }
    }

    /// The second-order step of a double backward, fused: given outputs `a`, first derivatives
    /// `s = φ'`, the forward cotangents `ga = G_A` and `gbar = Ḡ_Z`, writes
    /// `extra = φ'' ⊙ ga ⊙ gbar` and then `gbar ← s ⊙ gbar` (= `Ḡ_A`).
    pub fn second_order_step(self, a: &[f32], s: &[f32], ga: &[f32], gbar: &mut [f32], extra: &mut [f32]) {
        let n = a.len();
        debug_assert!(s.len() == n && ga.len() == n && gbar.len() == n && extra.len() == n);
        match self {
            Activation::Identity | Activation::Relu => {
                extra.fill(0.0);
                gbar.iter_mut().zip(s).for_each(|(g, &s)| *g *= s);
            }
            Activation::Softplus { beta } => {
                for i in 0..n {
                    extra[i] = beta * s[i] * (1.0 - s[i]) * ga[i] * gbar[i];
                    gbar[i] *= s[i];
                }
            }
            Activation::Sigmoid => {
                for i in 0..n {
                    extra[i] = s[i] * (1.0 - 2.0 * a[i]) * ga[i] * gbar[i];
                    gbar[i] *= s[i];
                }
            }
        }
    }

    /// `g ← g ⊙ φ'(z)` given the outputs `a`: the backward of the activation.
    pub fn backward_inplace(self, a: &[f32], g: &mut [f32]) {
        debug_assert_eq!(a.len(), g.len());
        #[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
        if let Activation::Softplus { beta } = self {
            // SAFETY: the build enables AVX-512F (checked by the cfg).
            let done = unsafe { crate::activation_simd::softplus_backward(a, g, beta) };
            return self.backward_inplace_scalar(&a[done..], &mut g[done..]);
        }
        self.backward_inplace_scalar(a, g)
    }

    /// [`backward_inplace`](Self::backward_inplace) without the AVX-512 path.
    pub(crate) fn backward_inplace_scalar(self, a: &[f32], g: &mut [f32]) {
        match self {
            Activation::Identity => {}
            Activation::Relu => g.iter_mut().zip(a).for_each(|(g, &a)| {
                if a <= 0.0 {
                    *g = 0.0
                }
            }),
            Activation::Softplus { beta } => g.iter_mut().zip(a).for_each(|(g, &a)| *g *= 1.0 - exp_fast(-beta * a)),
            Activation::Sigmoid => g.iter_mut().zip(a).for_each(|(g, &a)| *g *= a * (1.0 - a)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reference(act: Activation, z: f64) -> f64 {
        match act {
            Activation::Identity => z,
            Activation::Relu => z.max(0.0),
            Activation::Softplus { beta } => {
                let y = z * beta as f64;
                (y.max(0.0) + (-y.abs()).exp().ln_1p()) / beta as f64
            }
            Activation::Sigmoid => 1.0 / (1.0 + (-z).exp()),
        }
    }

    #[test]
    fn exp_fast_matches_std() {
        for i in -2000..2000 {
            let x = i as f32 * 0.043;
            let rel = ((exp_fast(x) as f64 - (x as f64).exp()) / (x as f64).exp()).abs();
            assert!(rel < 5e-7, "x={x} rel={rel}");
        }
    }

    /// NaN and infinities never reach the unchecked float-to-int conversion (that would be
    /// undefined behaviour); NaN propagates, ±∞ saturate like `exp`, and every activation passes
    /// NaN through (the trainer's divergence tests feed it NaN on purpose).
    #[test]
    fn exp_fast_handles_nan_and_infinities() {
        assert!(exp_fast(f32::NAN).is_nan());
        assert!(exp_fast(-f32::NAN).is_nan());
        assert_eq!(exp_fast(f32::NEG_INFINITY), exp_fast(-87.0));
        assert!(exp_fast(f32::INFINITY) > 1e38 && exp_fast(f32::INFINITY).is_finite());
        let v = [f32::NAN, 1.0, f32::NAN, -3.0];
        for act in [Activation::Softplus { beta: 100.0 }, Activation::Sigmoid] {
            let mut z = v;
            act.forward_inplace(&mut z);
            assert!(
                z[0].is_nan() && z[2].is_nan() && z[1].is_finite() && z[3].is_finite(),
                "{act:?}: {z:?}"
            );
        }
    }

    #[test]
    fn activations_match_f64_reference_and_finite_differences() {
        let acts = [
            Activation::Identity,
            Activation::Relu,
            Activation::Softplus { beta: 100.0 },
            Activation::Softplus { beta: 1.0 },
            Activation::Sigmoid,
        ];
        for act in acts {
            let scale = match act {
                Activation::Softplus { beta } => 1.0 / beta as f64,
                _ => 1.0,
            };
            for i in -40..=40 {
                // avoid the ReLU kink at 0
                let z = (i as f64 + 0.37) * 0.1 * scale * 2.0;
                let mut a = [z as f32];
                act.forward_inplace(&mut a);
                let want = reference(act, z);
                assert!((a[0] as f64 - want).abs() < 1e-6 * (1.0 + want.abs()), "{act:?} z={z}");
                let h = 1e-4 * scale;
                let d_fd = (reference(act, z + h) - reference(act, z - h)) / (2.0 * h);
                let d2_fd = (reference(act, z + h) - 2.0 * reference(act, z) + reference(act, z - h)) / (h * h);
                let d = act.derivative_from_output(a[0]) as f64;
                let d2 = act.second_derivative_from_output(a[0]) as f64;
                assert!((d - d_fd).abs() < 1e-4, "{act:?} z={z} d={d} fd={d_fd}");
                let d2_tol = 2e-3 / scale;
                assert!((d2 - d2_fd).abs() < d2_tol, "{act:?} z={z} d2={d2} fd={d2_fd}");
                let mut g = [1.5f32];
                act.backward_inplace(&a, &mut g);
                assert!((g[0] as f64 - 1.5 * d).abs() < 1e-6);
            }
        }
    }
}
