//! Stage 2's loss terms: the re-render loss per channel ([`rerender_channel`], eq:train2's first
//! term) and the material regularizers (eq:material, plus our roughness prior), each as a value
//! plus its gradient. Batch means, as stage 1's terms ([`crate::stage1::losses`]).

use crate::config::Stage2Loss;

/// Stage 2's re-render loss of one channel (linear radiance) and its slope ∂/∂pred, with the
/// saturation rule of a clipped LDR target: it only bounds the prediction from below. `scale`:
/// the mean surface target, L2's denominator (so that its slope is 1 at a residual of that size).
#[inline]
pub fn rerender_channel(kind: Stage2Loss, pred: f32, target: f32, saturated: bool, scale: f32) -> (f32, f32) {
    let d = pred - target;
    if saturated && d >= 0.0 {
        return (0.0, 0.0);
    }
    match kind {
        Stage2Loss::L1 => (d.abs(), d.signum()),
        Stage2Loss::L2 => (d * d / (2.0 * scale), d / scale),
    }
}

/// The weights of stage 2's material regularizers (`[stage2]` keys of the same names).
#[derive(Clone, Copy, Debug)]
pub struct MaterialPriors {
    /// eq:material's smoothness ‖M(x) − M(x+ε)‖₂, per parameter (Kd, Ks, ρ).
    pub smooth: f32,
    /// eq:material's energy term (Kd + Ks − 1)₊ per channel.
    pub energy: f32,
    /// Weight of the roughness prior w(Ks)·(ρ − `rho_target`)².
    pub rho_prior: f32,
    pub rho_target: f32,
}

/// Luminance of Ks at which the roughness prior's weight falls to 1/e: the 4 % reflectance of a
/// common dielectric, whose highlight the images do show.
pub const RHO_PRIOR_KS: f32 = 0.04;

/// Stage 2's material regularizers on a batch: `out` holds `b` materials (Kd, Ks, ρ per
/// `MATERIAL_CHANNELS`) and then their ε-neighbours. Returns the batch means of
/// - eq:material's smoothness, Σ over Kd, Ks and ρ of ‖M(x) − M(x+ε)‖₂;
/// - eq:material's energy term, Σ_c (Kd + Ks − 1)₊;
/// - the roughness prior w(Ks)·(ρ − ρ₀)², w = exp(−lum(Ks)/[`RHO_PRIOR_KS`]) held constant.
///
/// The prior is ours, not the paper's: where Ks is near zero no pixel depends on ρ, so without
/// it ρ keeps whatever it started at — and the fit must start at a moderate ρ to find glossy
/// surfaces at all (from a rough start, Ks drains away before ρ can fall). Held constant, w
/// does not reward a larger Ks for escaping the prior.
/// Adds the weighted gradients into `d_out` (laid out as `out`).
pub fn material_regularizers(out: &[f32], b: usize, w: &MaterialPriors, d_out: &mut [f32]) -> [f32; 3] {
    use i2sdf_model::material_field::MATERIAL_CHANNELS as C;
    let (mut smooth, mut energy, mut prior) = (0.0f32, 0.0f32, 0.0f32);
    let (ls, le, lp) = (w.smooth / b as f32, w.energy / b as f32, w.rho_prior / b as f32);
    for j in 0..b {
        let (a, e) = (j * C, (b + j) * C);
        for (lo, hi) in [(0, 3), (3, 6), (6, 7)] {
            let mut diff = [0.0f32; 3];
            for c in lo..hi {
                diff[c - lo] = out[a + c] - out[e + c];
            }
            let diff = &diff[..hi - lo];
            let norm = diff.iter().map(|v| v * v).sum::<f32>().sqrt();
            smooth += norm;
            if norm > 1e-8 {
                for (c, dv) in (lo..hi).zip(diff) {
                    d_out[a + c] += ls * dv / norm;
                    d_out[e + c] -= ls * dv / norm;
                }
            }
        }
        for c in 0..3 {
            let excess = out[a + c] + out[a + 3 + c] - 1.0;
            if excess > 0.0 {
                energy += excess;
                d_out[a + c] += le;
                d_out[a + 3 + c] += le;
            }
        }
        prior += rho_pull(&out[a..a + C], w.rho_target, lp, &mut d_out[a + 6]);
    }
    [smooth / b as f32, energy / b as f32, prior / b as f32]
}

/// The roughness prior's pull of one material (Kd, Ks, ρ) towards ρₜ: w(Ks)·(ρ − ρₜ)², w =
/// exp(−lum(Ks)/[`RHO_PRIOR_KS`]) held constant; adds `scale` × its slope into `d_rho`.
fn rho_pull(m: &[f32], target: f32, scale: f32, d_rho: &mut f32) -> f32 {
    let ks = i2sdf_render::luminance(glam::Vec3::from_slice(&m[3..6])).max(0.0);
    let wk = (-ks / RHO_PRIOR_KS).exp();
    let d = m[6] - target;
    *d_rho += scale * 2.0 * wk * d;
    wk * d * d
}

/// How far a held pixel's Ks may rise above the default fit's before [`lobe_terms`] holds it.
pub const HELD_KS_SLACK: f32 = 0.01;

/// What the `[lobes]` terms ([`lobe_terms`]) hold a pixel's material to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LobeTarget {
    /// Nothing.
    Free,
    /// A forced lobe of roughness ρₜ: ρ at ρₜ where Ks is small, Ks at `ks_min` or above.
    Lobe(f32),
    /// The default fit's specular at the pixel (its segment chose no lobe): Ks as a ceiling, ρ
    /// where Ks is small.
    Held { ks: [f32; 3], rho: f32 },
}

/// The `[lobes]` terms ([`crate::stage2::lobe_choice`]) on the first `b` materials of `out`:
/// - [`LobeTarget::Lobe`]: w(Ks)·(ρ − ρₜ)², w as the roughness prior's (held constant), plus
///   Σ_c ((`ks_min` − Ks_c)₊ / `ks_min`)², which holds Ks at `ks_min` or above (relative to
///   `ks_min`, so that its slope there dwarfs the re-render's);
/// - [`LobeTarget::Held`]: Σ_c (Ks_c − Ks₀_c − [`HELD_KS_SLACK`])₊² + w(Ks)·(ρ − ρ₀)²: Ks no
///   higher than the default fit gave the pixel, and its ρ where Ks is small, which a matte wall
///   would otherwise let drift (its pixels barely depend on them) while the shared field bends
///   towards the lobes forced elsewhere. Gentle (absolute, Ks one-sided with slack): the last
///   fit starts from the defaults' field, where it holds already; a hold relative to `ks_min`
///   on a fresh field (its Ks starts at `material.ks_init`) outweighed the re-render and spoilt
///   Kd (22.1 → 16.1 dB on the default room).
///
/// Returns the batch mean; adds `weight` × its gradient into `d_out`.
pub fn lobe_terms(out: &[f32], b: usize, targets: &[LobeTarget], ks_min: f32, weight: f32, d_out: &mut [f32]) -> f32 {
    use i2sdf_model::material_field::MATERIAL_CHANNELS as C;
    let lw = weight / b as f32;
    let mut total = 0.0f32;
    for (j, t) in targets.iter().enumerate().take(b) {
        let a = j * C;
        match *t {
            LobeTarget::Free => {}
            LobeTarget::Lobe(t) => {
                total += rho_pull(&out[a..a + C], t, lw, &mut d_out[a + 6]);
                for c in 3..6 {
                    let short = (ks_min - out[a + c]).max(0.0) / ks_min;
                    total += short * short;
                    d_out[a + c] -= lw * 2.0 * short / ks_min;
                }
            }
            LobeTarget::Held { ks, rho } => {
                total += rho_pull(&out[a..a + C], rho, lw, &mut d_out[a + 6]);
                for c in 0..3 {
                    let e = (out[a + 3 + c] - ks[c] - HELD_KS_SLACK).max(0.0);
                    total += e * e;
                    d_out[a + 3 + c] += lw * 2.0 * e;
                }
            }
        }
    }
    total / b as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_nn::gradcheck::{assert_close as close, numeric_gradient as numeric};

    /// The regularizers' gradients match central differences of their weighted sum (with the
    /// prior's weight w(Ks) frozen at the point, as the gradient holds it).
    #[test]
    fn material_regularizer_gradients_match_finite_differences() {
        use i2sdf_model::material_field::MATERIAL_CHANNELS as C;
        let b = 5;
        let mut x = vec![0.0f32; 2 * b * C];
        for (i, v) in x.iter_mut().enumerate() {
            // Kd + Ks above 1 on some points (energy active), ρ spread over (0, 1).
            *v = 0.05 + 0.9 * ((i as f32 * 0.618).fract());
        }
        let w = MaterialPriors {
            smooth: 0.3,
            energy: 0.7,
            rho_prior: 0.5,
            rho_target: 0.9,
        };
        let mut g = vec![0.0f32; x.len()];
        let terms = material_regularizers(&x, b, &w, &mut g);
        assert!(terms.iter().all(|t| *t > 0.0), "every term active: {terms:?}");
        // The weights at x, frozen.
        let wk: Vec<f32> = (0..b)
            .map(|j| (-i2sdf_render::luminance(glam::Vec3::from_slice(&x[j * C + 3..j * C + 6])) / RHO_PRIOR_KS).exp())
            .collect();
        let total = |y: &[f32]| -> f32 {
            let mut scratch = vec![0.0f32; y.len()];
            let no_prior = MaterialPriors { rho_prior: 0.0, ..w };
            let t = material_regularizers(y, b, &no_prior, &mut scratch);
            let p: f32 = (0..b)
                .map(|j| wk[j] * (y[j * C + 6] - w.rho_target).powi(2))
                .sum::<f32>()
                / b as f32;
            w.smooth * t[0] + w.energy * t[1] + w.rho_prior * p
        };
        let fd = numeric(&total, &x);
        for (i, (a, n)) in g.iter().zip(&fd).enumerate() {
            assert!(
                (a - n).abs() < 2e-3 + 1e-2 * n.abs(),
                "component {i}: analytic {a}, numeric {n}"
            );
        }
        // A glossy point is nearly free of the prior, a matte one is not.
        let mut y = x.clone();
        y[3..6].copy_from_slice(&[0.5; 3]);
        y[C + 3..C + 6].copy_from_slice(&[0.0; 3]);
        let mut g2 = vec![0.0f32; y.len()];
        material_regularizers(
            &y,
            b,
            &MaterialPriors {
                smooth: 0.0,
                energy: 0.0,
                ..w
            },
            &mut g2,
        );
        let (glossy, matte) = (g2[6] / (y[6] - 0.9), g2[C + 6] / (y[C + 6] - 0.9));
        assert!(glossy < 1e-4 * matte && matte > 0.0, "glossy {glossy} vs matte {matte}");
    }

    /// The `[lobes]` terms' gradient matches central differences (w(Ks) frozen, as it is
    /// held), for a forced lobe and a held specular, and a free pixel costs nothing.
    #[test]
    fn lobe_term_gradients_match_finite_differences() {
        use i2sdf_model::material_field::MATERIAL_CHANNELS as C;
        let b = 4;
        let mut x = vec![0.0f32; b * C];
        for (i, v) in x.iter_mut().enumerate() {
            // Ks channels on both sides of ks_min = 0.04 (kept off the kink), ρ over (0, 1).
            *v = 0.013 + 0.06 * ((i as f32 * 0.618).fract());
        }
        for j in 0..b {
            x[j * C + 6] = 0.2 + 0.2 * j as f32;
            for v in &mut x[j * C + 3..j * C + 6] {
                if (*v - 0.04).abs() < 0.003 {
                    *v += 0.006;
                }
            }
        }
        let held = LobeTarget::Held {
            ks: [0.0, 0.0, 0.3],
            rho: 0.6,
        };
        let targets = [LobeTarget::Lobe(0.5), LobeTarget::Free, held, LobeTarget::Lobe(1.0)];
        let (ks_min, weight) = (0.04, 3.0);
        let mut g = vec![0.0f32; x.len()];
        let t = lobe_terms(&x, b, &targets, ks_min, weight, &mut g);
        assert!(t > 0.0);
        let wk: Vec<f32> = (0..b)
            .map(|j| (-i2sdf_render::luminance(glam::Vec3::from_slice(&x[j * C + 3..j * C + 6])) / RHO_PRIOR_KS).exp())
            .collect();
        let total = |y: &[f32]| -> f32 {
            let mut s = 0.0;
            for (j, t) in targets.iter().enumerate() {
                match *t {
                    LobeTarget::Free => {}
                    LobeTarget::Lobe(t) => {
                        s += wk[j] * (y[j * C + 6] - t).powi(2);
                        for c in 3..6 {
                            s += ((ks_min - y[j * C + c]).max(0.0) / ks_min).powi(2);
                        }
                    }
                    LobeTarget::Held { ks, rho } => {
                        s += wk[j] * (y[j * C + 6] - rho).powi(2);
                        for c in 0..3 {
                            s += (y[j * C + 3 + c] - ks[c] - HELD_KS_SLACK).max(0.0).powi(2);
                        }
                    }
                }
            }
            weight * s / b as f32
        };
        let fd = numeric(&total, &x);
        for (i, (a, n)) in g.iter().zip(&fd).enumerate() {
            assert!(
                (a - n).abs() < 2e-2 + 1e-2 * n.abs(),
                "component {i}: analytic {a}, numeric {n}"
            );
        }
        assert!(g[C..2 * C].iter().all(|v| *v == 0.0), "no target, no gradient");
        assert!(g[..C].iter().any(|v| *v != 0.0) && g[2 * C..3 * C].iter().any(|v| *v != 0.0));
    }

    // Inputs are kept away from the kinks of |·| so central differences are exact enough.
    const P: [f32; 6] = [0.3, -0.7, 1.2, 0.9, 0.2, -0.4];
    const T: [f32; 6] = [0.1, 0.2, -0.3, 0.5, -0.6, 0.7];

    #[test]
    fn rerender_channel_slopes_match_finite_differences_and_saturation_only_bounds_below() {
        for kind in [Stage2Loss::L1, Stage2Loss::L2] {
            for (&p, &t) in P.iter().zip(&T) {
                let f = |x: &[f32]| rerender_channel(kind, x[0], t, false, 0.4).0;
                close(&[rerender_channel(kind, p, t, false, 0.4).1], &numeric(&f, &[p]), 1e-2);
                // A clipped target: no loss and no slope above it, the unclipped ones below.
                let above = rerender_channel(kind, t + 0.1, t, true, 0.4);
                assert_eq!(above, (0.0, 0.0));
                let below = rerender_channel(kind, t - 0.1, t, true, 0.4);
                assert_eq!(below, rerender_channel(kind, t - 0.1, t, false, 0.4));
                assert!(below.1 < 0.0);
            }
        }
        // L2's slope is 1 at a residual of `scale`, like L1's.
        assert!((rerender_channel(Stage2Loss::L2, 0.9, 0.5, false, 0.4).1 - 1.0).abs() < 1e-6);
    }
}
