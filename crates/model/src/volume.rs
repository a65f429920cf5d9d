//! VolSDF volume rendering (paper Sec. 3, eq:density, eq:rgb and eq:depth, and the emitter mask of
//! Sec. 4.2): the Laplace density of the SDF with its derivatives, compositing of any number of
//! per-sample channels along packed rays with an O(M) backward pass, and the ray samplers' parts
//! (uniform and inverse-CDF samples); VolSDF's error-bounded sampler (Yariv et al. 2021, Sec. 3.3
//! and Alg. 1) built on them is in `volume/error_bounded.rs`.
//!
//! Layout of a batch: rays are packed ray-major; `ray_offsets` (length rays + 1) says that ray `r`
//! owns samples `ray_offsets[r]..ray_offsets[r + 1]` of every per-sample array, and per-sample
//! channels are sample-major (`channels[s * k + c]`). Callers own every buffer; the compositing
//! loops allocate nothing.

use rand::Rng;
use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

/// The float types the per-ray kernels run in: f32 in training, f64 in the gradient tests.
pub trait Real:
    Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
{
    const ZERO: Self;
    const ONE: Self;
    const HALF: Self;
    fn exp(self) -> Self;
    /// `exp(self) - 1`, accurate near 0 (α of a thin sample).
    fn exp_m1(self) -> Self;
    fn abs(self) -> Self;
}

macro_rules! impl_real {
    ($t:ty) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const HALF: Self = 0.5;
            #[inline]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline]
            fn exp_m1(self) -> Self {
                <$t>::exp_m1(self)
            }
            #[inline]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
        }
    };
}
impl_real!(f32);
impl_real!(f64);

// ---------------------------------------------------------------------------------------------
// Density

/// VolSDF density, paper eq:density: σ(d) = (1/β) Ψ_β(−d), Ψ_β the CDF of the zero-mean Laplace
/// distribution with scale β. Written with e = exp(−|d|/β) ≤ 1 so that neither sign overflows:
/// σ = e / (2β) for d ≥ 0, (1 − e/2) / β for d < 0.
#[inline]
pub fn laplace_density<T: Real>(sdf: T, beta: T) -> T {
    let e = (-(sdf.abs() / beta)).exp();
    if sdf >= T::ZERO {
        T::HALF * e / beta
    } else {
        (T::ONE - T::HALF * e) / beta
    }
}

/// σ with its partial derivatives with respect to the SDF value and β.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DensityWithGrad<T> {
    pub sigma: T,
    /// ∂σ/∂d = −e / (2β²) for both signs (−1/β times the Laplace pdf): always ≤ 0.
    pub d_sdf: T,
    /// ∂σ/∂β = e (|d| − β) / (2β³) for d ≥ 0; −(1 − e/2)/β² − e |d| / (2β³) for d < 0.
    pub d_beta: T,
}

#[inline]
pub fn laplace_density_with_grad<T: Real>(sdf: T, beta: T) -> DensityWithGrad<T> {
    let abs_d = sdf.abs();
    let e = (-(abs_d / beta)).exp();
    let beta2 = beta * beta;
    let beta3 = beta2 * beta;
    let d_sdf = -(T::HALF * e / beta2);
    if sdf >= T::ZERO {
        DensityWithGrad {
            sigma: T::HALF * e / beta,
            d_sdf,
            d_beta: T::HALF * e * (abs_d - beta) / beta3,
        }
    } else {
        let sigma = (T::ONE - T::HALF * e) / beta;
        DensityWithGrad {
            sigma,
            d_sdf,
            d_beta: -(sigma / beta) - T::HALF * e * abs_d / beta3,
        }
    }
}

/// σ for a batch of SDF values.
pub fn laplace_density_batch(sdf: &[f32], beta: f32, sigma: &mut [f32]) {
    assert_eq!(sdf.len(), sigma.len());
    for (s, &d) in sigma.iter_mut().zip(sdf) {
        *s = laplace_density(d, beta);
    }
}

/// Backward of [`laplace_density_batch`]: writes dL/dd into `grad_sdf` and returns dL/dβ (summed
/// over the batch; chain it through the caller's β parametrization, e.g. β = β_min + |β_param|).
pub fn laplace_density_backward(sdf: &[f32], beta: f32, grad_sigma: &[f32], grad_sdf: &mut [f32]) -> f32 {
    assert_eq!(sdf.len(), grad_sigma.len());
    assert_eq!(sdf.len(), grad_sdf.len());
    let mut grad_beta = 0.0f64;
    for ((g_d, &d), &g) in grad_sdf.iter_mut().zip(sdf).zip(grad_sigma) {
        let grad = laplace_density_with_grad(d, beta);
        *g_d = g * grad.d_sdf;
        grad_beta += (g * grad.d_beta) as f64;
    }
    grad_beta as f32
}

// ---------------------------------------------------------------------------------------------
// Compositing

/// The scalar outputs of one ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayComposite<T> {
    /// Expected depth Σ w_i t_i (eq:depth), not normalized by the opacity.
    pub depth: T,
    /// Accumulated opacity Σ w_i = 1 − T_{M+1}.
    pub opacity: T,
}

/// Composites one ray (eq:rgb and eq:depth, and the emitter mask M̂_e of Sec. 4.2, for any K
/// channels):
/// α_i = 1 − exp(−σ_i δ_i), T_i = Π_{j<i} (1 − α_j), w_i = T_i α_i; `out_channels[c] = Σ w_i
/// channels[i K + c]`; `weights[i] = w_i`. K is `out_channels.len()`.
pub fn composite_ray<T: Real>(
    t: &[T],
    delta: &[T],
    sigma: &[T],
    channels: &[T],
    out_channels: &mut [T],
    weights: &mut [T],
) -> RayComposite<T> {
    let m = t.len();
    let k = out_channels.len();
    debug_assert!(delta.len() == m && sigma.len() == m && weights.len() == m && channels.len() == m * k);
    out_channels.fill(T::ZERO);
    let mut transmittance = T::ONE;
    let (mut depth, mut opacity) = (T::ZERO, T::ZERO);
    for i in 0..m {
        let tau = sigma[i] * delta[i];
        let alpha = -(-tau).exp_m1();
        let w = transmittance * alpha;
        weights[i] = w;
        depth += w * t[i];
        opacity += w;
        for c in 0..k {
            out_channels[c] += w * channels[i * k + c];
        }
        transmittance = transmittance * (-tau).exp();
    }
    RayComposite { depth, opacity }
}

/// Backward of [`composite_ray`] in O(M K). With L's gradients `grad_out_channels` (K),
/// `grad_depth`, `grad_opacity`, and g_i = Σ_c ∂L/∂C_c c_ic + ∂L/∂D t_i + ∂L/∂A, the weights
/// w_i = T_i − T_{i+1} give ∂L/∂τ_j = g_j T_{j+1} − Σ_{i>j} g_i w_i (a suffix sum), so
/// `grad_sigma[j] = δ_j ∂L/∂τ_j` and `grad_channels[j K + c] = w_j ∂L/∂C_c`.
/// `grad_sigma` doubles as scratch for T_{j+1} between the two passes.
#[allow(clippy::too_many_arguments)]
pub fn composite_ray_backward<T: Real>(
    t: &[T],
    delta: &[T],
    sigma: &[T],
    channels: &[T],
    grad_out_channels: &[T],
    grad_depth: T,
    grad_opacity: T,
    grad_sigma: &mut [T],
    grad_channels: &mut [T],
) {
    let m = t.len();
    let k = grad_out_channels.len();
    debug_assert!(delta.len() == m && sigma.len() == m && grad_sigma.len() == m);
    debug_assert!(channels.len() == m * k && grad_channels.len() == m * k);
    // Forward pass: T_{j+1} into grad_sigma[j].
    let mut transmittance = T::ONE;
    for j in 0..m {
        transmittance = transmittance * (-(sigma[j] * delta[j])).exp();
        grad_sigma[j] = transmittance;
    }
    // Backward pass: suffix = Σ_{i>j} g_i w_i.
    let mut suffix = T::ZERO;
    for j in (0..m).rev() {
        let t_next = grad_sigma[j];
        let t_here = if j == 0 { T::ONE } else { grad_sigma[j - 1] };
        let tau = sigma[j] * delta[j];
        let w = t_here * -(-tau).exp_m1();
        let mut g = grad_depth * t[j] + grad_opacity;
        for c in 0..k {
            g += grad_out_channels[c] * channels[j * k + c];
            grad_channels[j * k + c] = w * grad_out_channels[c];
        }
        grad_sigma[j] = (g * t_next - suffix) * delta[j];
        suffix += g * w;
    }
}

/// Per-sample inputs of a batch of packed rays (see the module doc for the layout).
#[derive(Clone, Copy, Debug)]
pub struct PackedSamples<'a> {
    pub ray_offsets: &'a [u32],
    pub t: &'a [f32],
    pub delta: &'a [f32],
    pub sigma: &'a [f32],
    pub channels: &'a [f32],
    pub num_channels: usize,
}

impl PackedSamples<'_> {
    pub fn num_rays(&self) -> usize {
        self.ray_offsets.len().saturating_sub(1)
    }

    fn check(&self) {
        let n = *self.ray_offsets.last().expect("ray_offsets has rays + 1 entries") as usize;
        assert!(
            self.ray_offsets.windows(2).all(|w| w[0] <= w[1]),
            "ray_offsets must not decrease"
        );
        assert!(self.t.len() == n && self.delta.len() == n && self.sigma.len() == n);
        assert_eq!(self.channels.len(), n * self.num_channels);
    }

    fn ray(&self, r: usize) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
        let (a, b) = (self.ray_offsets[r] as usize, self.ray_offsets[r + 1] as usize);
        (a..b, a * self.num_channels..b * self.num_channels)
    }
}

/// Per-ray outputs of [`composite_batch`].
#[derive(Debug)]
pub struct CompositeOutputs<'a> {
    /// rays × K.
    pub channels: &'a mut [f32],
    pub depth: &'a mut [f32],
    pub opacity: &'a mut [f32],
    /// One weight per sample (for losses on weights, or to pick surface points).
    pub weights: &'a mut [f32],
}

pub fn composite_batch(samples: &PackedSamples, out: CompositeOutputs) {
    samples.check();
    let (rays, k) = (samples.num_rays(), samples.num_channels);
    assert!(out.channels.len() == rays * k && out.depth.len() == rays && out.opacity.len() == rays);
    assert_eq!(out.weights.len(), samples.t.len());
    for r in 0..rays {
        let (s, c) = samples.ray(r);
        let result = composite_ray(
            &samples.t[s.clone()],
            &samples.delta[s.clone()],
            &samples.sigma[s.clone()],
            &samples.channels[c],
            &mut out.channels[r * k..(r + 1) * k],
            &mut out.weights[s],
        );
        out.depth[r] = result.depth;
        out.opacity[r] = result.opacity;
    }
}

/// Gradients of the loss with respect to [`composite_batch`]'s per-ray outputs.
#[derive(Clone, Copy, Debug)]
pub struct CompositeGrads<'a> {
    /// rays × K.
    pub channels: &'a [f32],
    pub depth: &'a [f32],
    pub opacity: &'a [f32],
}

/// Backward of [`composite_batch`]: dL/dσ per sample and dL/d(per-sample channels). Chain
/// `grad_sigma` through [`laplace_density_backward`] for dL/dd and dL/dβ.
pub fn composite_batch_backward(
    samples: &PackedSamples,
    grads: &CompositeGrads,
    grad_sigma: &mut [f32],
    grad_channels: &mut [f32],
) {
    samples.check();
    let (rays, k) = (samples.num_rays(), samples.num_channels);
    assert!(grads.channels.len() == rays * k && grads.depth.len() == rays && grads.opacity.len() == rays);
    assert!(grad_sigma.len() == samples.t.len() && grad_channels.len() == samples.channels.len());
    for r in 0..rays {
        let (s, c) = samples.ray(r);
        composite_ray_backward(
            &samples.t[s.clone()],
            &samples.delta[s.clone()],
            &samples.sigma[s.clone()],
            &samples.channels[c.clone()],
            &grads.channels[r * k..(r + 1) * k],
            grads.depth[r],
            grads.opacity[r],
            &mut grad_sigma[s],
            &mut grad_channels[c],
        );
    }
}

/// δ_i = t_{i+1} − t_i for each ray, the last sample getting `last_delta` (VolSDF uses 1e10 so
/// that the last sample absorbs what is left; `0` leaves the ray's remaining transmittance).
pub fn deltas_from_t(ray_offsets: &[u32], t: &[f32], last_delta: f32, delta: &mut [f32]) {
    assert_eq!(t.len(), delta.len());
    for w in ray_offsets.windows(2) {
        let (a, b) = (w[0] as usize, w[1] as usize);
        for i in a..b {
            delta[i] = if i + 1 < b { t[i + 1] - t[i] } else { last_delta };
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Sampling along rays

/// `n` samples in [near, far]: evenly spaced (ends included) without an RNG; with one, each sample
/// is jittered uniformly within its stratum (VolSDF's training-time uniform sampler). Sorted.
pub fn uniform_samples<R: Rng + ?Sized>(near: f32, far: f32, rng: Option<&mut R>, out: &mut [f32]) {
    let n = out.len();
    if n == 0 {
        return;
    }
    if n == 1 {
        out[0] = 0.5 * (near + far);
        return;
    }
    let step = (far - near) / (n - 1) as f32;
    for (i, t) in out.iter_mut().enumerate() {
        *t = near + step * i as f32;
    }
    if let Some(rng) = rng {
        // Strata bounded by the midpoints between the evenly spaced samples.
        for i in 0..n {
            let lower = if i == 0 { near } else { near + step * (i as f32 - 0.5) };
            let upper = if i == n - 1 {
                far
            } else {
                near + step * (i as f32 + 0.5)
            };
            out[i] = lower + (upper - lower) * rng.gen::<f32>();
        }
    }
}

/// Fills `u` with sorted values in [0, 1]: evenly spaced with ends included without an RNG
/// (deterministic renders), sorted uniform draws with one.
pub fn sample_unit_values<R: Rng + ?Sized>(rng: Option<&mut R>, u: &mut [f32]) {
    let n = u.len();
    match rng {
        None => {
            for (i, x) in u.iter_mut().enumerate() {
                *x = if n > 1 { i as f32 / (n - 1) as f32 } else { 0.5 };
            }
        }
        Some(rng) => {
            u.iter_mut().for_each(|x| *x = rng.gen::<f32>());
            u.sort_unstable_by(f32::total_cmp);
        }
    }
}

/// Inverse-transform sampling of the piecewise-constant density that puts mass `weights[i]` on
/// `[bins[i], bins[i + 1]]` (`weights.len() == bins.len() − 1`), at the unit values `u`; outputs
/// follow `u`'s order (sorted for sorted `u`). An all-zero histogram samples uniformly.
pub fn sample_piecewise_constant(bins: &[f32], weights: &[f32], u: &[f32], out: &mut [f32]) {
    assert!(bins.len() >= 2 && weights.len() == bins.len() - 1 && u.len() == out.len());
    let total: f64 = weights.iter().map(|&w| w.max(0.0) as f64).sum();
    let uniform = total <= 0.0 || !total.is_finite();
    let mass = |i: usize| {
        if uniform {
            1.0 / weights.len() as f64
        } else {
            weights[i].max(0.0) as f64 / total
        }
    };
    // Walk the CDF once when u is sorted; fall back to a restart otherwise.
    let (mut bin, mut cdf_below) = (0usize, 0.0f64);
    for (x, &ui) in out.iter_mut().zip(u) {
        let ui = (ui as f64).clamp(0.0, 1.0);
        if ui < cdf_below {
            bin = 0;
            cdf_below = 0.0;
        }
        // Skip empty bins, and stop in the first bin whose CDF reaches u.
        while bin + 1 < weights.len() && (mass(bin) <= 0.0 || cdf_below + mass(bin) < ui) {
            cdf_below += mass(bin);
            bin += 1;
        }
        let m = mass(bin);
        let frac = if m > 1e-12 {
            ((ui - cdf_below) / m).clamp(0.0, 1.0)
        } else {
            0.5
        };
        *x = bins[bin] + (frac as f32) * (bins[bin + 1] - bins[bin]);
    }
}

mod error_bounded;
pub use error_bounded::{
    error_bounded_samples, error_bounded_samples_into, ErrorBoundedSamplerConfig, OccupiedStretches, RayBatchRef,
    RaySampleSet, SamplerScratch,
};
#[cfg(test)]
use error_bounded::{interval_distance_bound, interval_weights, merge_sorted, opacity_error_bound, RayState};

#[cfg(test)]
#[path = "volume_tests.rs"]
mod tests;
