//! The loss terms: stage 1's (paper Sec. 4.1–4.2, eq:bubble, "eikonal", "depth", "normal",
//! "smooth", "emitter BCE", eq:train1 "L_rgb") and stage 2's re-render loss per channel
//! ([`rerender_channel`]), each as a value plus its gradient with respect to what the renderer or
//! the SDF produced. Every term is a mean over its batch (as in VolSDF's
//! implementation) so that weights do not depend on the batch size. Callers add the weighted
//! gradients into their upstream buffers (`grad += w · ∂term`).

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
        let ks = i2sdf_render::luminance(glam::Vec3::from_slice(&out[a + 3..a + 6])).max(0.0);
        let wk = (-ks / RHO_PRIOR_KS).exp();
        let d = out[a + 6] - w.rho_target;
        prior += wk * d * d;
        d_out[a + 6] += lp * 2.0 * wk * d;
    }
    [smooth / b as f32, energy / b as f32, prior / b as f32]
}

/// L_rgb = mean over rays and channels of |Ĉ − C|. Adds w·∂L/∂Ĉ into `grad`.
pub fn rgb_l1(pred: &[[f32; 3]], target: &[[f32; 3]], w: f32, grad: &mut [[f32; 3]]) -> f32 {
    let n = pred.len().max(1) as f32 * 3.0;
    let mut loss = 0.0f64;
    for ((p, t), g) in pred.iter().zip(target).zip(grad.iter_mut()) {
        for c in 0..3 {
            let d = p[c] - t[c];
            loss += d.abs() as f64;
            g[c] += w * d.signum() / n;
        }
    }
    (loss / n as f64) as f32
}

/// L_depth = mean over rays with depth of |D̂ − D| (eq. "depth"). `valid` masks rays with depth.
pub fn depth_l1(pred: &[f32], target: &[f32], valid: &[bool], w: f32, grad: &mut [f32]) -> f32 {
    let n = valid.iter().filter(|v| **v).count();
    if n == 0 {
        return 0.0;
    }
    let mut loss = 0.0f64;
    for i in 0..pred.len() {
        if valid[i] {
            let d = pred[i] - target[i];
            loss += d.abs() as f64;
            grad[i] += w * d.signum() / n as f32;
        }
    }
    (loss / n as f64) as f32
}

/// L_normal = mean over rays with a normal of 1 − n̂·n with n̂ = N̂/‖N̂‖ (eq. "normal"; the rendered
/// normal is normalized first, as MonoSDF does, so the term measures only the angle).
pub fn normal_angular(pred: &[[f32; 3]], target: &[[f32; 3]], valid: &[bool], w: f32, grad: &mut [[f32; 3]]) -> f32 {
    let n = valid.iter().filter(|v| **v).count();
    if n == 0 {
        return 0.0;
    }
    let mut loss = 0.0f64;
    for i in 0..pred.len() {
        if !valid[i] {
            continue;
        }
        let p = pred[i];
        let t = target[i];
        let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt().max(1e-6);
        let u = [p[0] / len, p[1] / len, p[2] / len];
        let dot = u[0] * t[0] + u[1] * t[1] + u[2] * t[2];
        loss += (1.0 - dot) as f64;
        // ∂(−u·t)/∂p = −(t − (u·t) u) / ‖p‖
        for c in 0..3 {
            grad[i][c] += w * (-(t[c] - dot * u[c]) / len) / n as f32;
        }
    }
    (loss / n as f64) as f32
}

/// Binary cross-entropy of the rendered emitter probability against the mask (eq. "L_emi"),
/// mean over rays; probabilities are clamped away from 0 and 1 so the loss stays finite.
pub fn emitter_bce(pred: &[f32], target: &[f32], w: f32, grad: &mut [f32]) -> f32 {
    const EPS: f32 = 1e-4;
    let n = pred.len().max(1) as f32;
    let mut loss = 0.0f64;
    for i in 0..pred.len() {
        let p = pred[i].clamp(EPS, 1.0 - EPS);
        let m = target[i];
        loss += -(m * p.ln() + (1.0 - m) * (1.0 - p).ln()) as f64;
        if pred[i] > EPS && pred[i] < 1.0 - EPS {
            grad[i] += w * (-(m / p) + (1.0 - m) / (1.0 - p)) / n;
        }
    }
    (loss / n as f64) as f32
}

/// L_eikonal = mean over points of (‖∇d‖ − 1)² (eq. "eikonal"). Adds w·∂L/∂∇d into `grad`.
pub fn eikonal(gradients: &[[f32; 3]], w: f32, grad: &mut [[f32; 3]]) -> f32 {
    let n = gradients.len().max(1) as f32;
    let mut loss = 0.0f64;
    for (g, out) in gradients.iter().zip(grad.iter_mut()) {
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let r = len - 1.0;
        loss += (r * r) as f64;
        let s = if len > 1e-12 { 2.0 * r / len } else { 0.0 };
        for c in 0..3 {
            out[c] += w * s * g[c] / n;
        }
    }
    (loss / n as f64) as f32
}

/// L_smooth = mean over pairs of ‖∇d(x) − ∇d(x + ε)‖₂ (eq:smooth). Adds gradients for both members.
pub fn smoothness(a: &[[f32; 3]], b: &[[f32; 3]], w: f32, grad_a: &mut [[f32; 3]], grad_b: &mut [[f32; 3]]) -> f32 {
    let n = a.len().max(1) as f32;
    let mut loss = 0.0f64;
    for i in 0..a.len() {
        let d = [a[i][0] - b[i][0], a[i][1] - b[i][1], a[i][2] - b[i][2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        loss += len as f64;
        if len > 1e-12 {
            for c in 0..3 {
                let g = w * d[c] / len / n;
                grad_a[i][c] += g;
                grad_b[i][c] -= g;
            }
        }
    }
    (loss / n as f64) as f32
}

/// L_bubble = mean over bubble points of |d(x)| (eq:bubble: surface points from depth must lie on the
/// zero level set).
pub fn bubble(sdf: &[f32], w: f32, grad: &mut [f32]) -> f32 {
    let n = sdf.len().max(1) as f32;
    let mut loss = 0.0f64;
    for (d, g) in sdf.iter().zip(grad.iter_mut()) {
        loss += d.abs() as f64;
        *g += w * d.signum() / n;
    }
    (loss / n as f64) as f32
}

/// L_inside = mean over points just behind the depth surface of max(0, d(x)) (beyond the paper):
/// a pixel's depth says where its ray enters a surface, so a point a few millimetres further
/// along the ray is inside whatever it entered (anything thicker than that), and its SDF must be
/// negative. eq:bubble only pins |d| = 0 on the surface, which a ridge of small positive d also
/// satisfies: that is what a 1–2 px lamp pole becomes (semi-transparent in volume rendering, no
/// zero crossing for marching cubes), as its partly covered pixels favour.
pub fn inside(sdf: &[f32], w: f32, grad: &mut [f32]) -> f32 {
    let n = sdf.len().max(1) as f32;
    let mut loss = 0.0f64;
    for (d, g) in sdf.iter().zip(grad.iter_mut()) {
        if *d > 0.0 {
            loss += *d as f64;
            *g += w / n;
        }
    }
    (loss / n as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// Central differences of a scalar function of a flat parameter vector.
    fn numeric(f: &dyn Fn(&[f32]) -> f32, x: &[f32]) -> Vec<f32> {
        let h = 1e-3;
        (0..x.len())
            .map(|i| {
                let mut a = x.to_vec();
                let mut b = x.to_vec();
                a[i] += h;
                b[i] -= h;
                (f(&a) - f(&b)) / (2.0 * h)
            })
            .collect()
    }

    fn close(a: &[f32], b: &[f32], tol: f32) {
        for (x, y) in a.iter().zip(b) {
            assert!(
                (x - y).abs() <= tol * (1.0 + y.abs()),
                "analytic {a:?} vs numeric {b:?}"
            );
        }
    }

    fn v3(x: &[f32]) -> Vec<[f32; 3]> {
        x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
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

    #[test]
    fn rgb_and_depth_gradients() {
        let t = v3(&T);
        let f = |x: &[f32]| rgb_l1(&v3(x), &t, 1.0, &mut vec![[0.0; 3]; 2]);
        let mut g = vec![[0.0; 3]; 2];
        rgb_l1(&v3(&P), &t, 1.0, &mut g);
        close(&g.concat(), &numeric(&f, &P), 1e-3);

        let valid = [true, false, true, true, true, false];
        let f = |x: &[f32]| depth_l1(x, &T, &valid, 1.0, &mut [0.0; 6]);
        let mut g = [0.0; 6];
        depth_l1(&P, &T, &valid, 1.0, &mut g);
        close(&g, &numeric(&f, &P), 1e-3);
        assert_eq!(g[1], 0.0);
    }

    #[test]
    fn normal_gradient_and_value() {
        let t: Vec<[f32; 3]> = vec![[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]];
        let valid = [true, true];
        let f = |x: &[f32]| normal_angular(&v3(x), &t, &valid, 1.0, &mut vec![[0.0; 3]; 2]);
        let mut g = vec![[0.0; 3]; 2];
        normal_angular(&v3(&P), &t, &valid, 1.0, &mut g);
        close(&g.concat(), &numeric(&f, &P), 2e-3);
        // Aligned normals of any length cost nothing.
        let v = normal_angular(&[[0.0, 0.0, 3.0]], &[[0.0, 0.0, 1.0]], &[true], 1.0, &mut [[0.0; 3]]);
        assert!(v.abs() < 1e-6);
    }

    #[test]
    fn bce_gradient() {
        let p = [0.2, 0.7, 0.95, 0.4];
        let m = [0.0, 1.0, 1.0, 0.0];
        let f = |x: &[f32]| emitter_bce(x, &m, 1.0, &mut [0.0; 4]);
        let mut g = [0.0; 4];
        emitter_bce(&p, &m, 1.0, &mut g);
        close(&g, &numeric(&f, &p), 2e-3);
        assert!(emitter_bce(&[0.0, 1.0], &[1.0, 0.0], 1.0, &mut [0.0; 2]).is_finite());
    }

    #[test]
    fn eikonal_smooth_bubble_gradients() {
        let f = |x: &[f32]| eikonal(&v3(x), 1.0, &mut vec![[0.0; 3]; 2]);
        let mut g = vec![[0.0; 3]; 2];
        eikonal(&v3(&P), 1.0, &mut g);
        close(&g.concat(), &numeric(&f, &P), 1e-3);
        assert!(eikonal(&[[0.6, 0.0, 0.8]], 1.0, &mut [[0.0; 3]]).abs() < 1e-6);

        let b = v3(&T);
        let f = |x: &[f32]| smoothness(&v3(x), &b, 1.0, &mut vec![[0.0; 3]; 2], &mut vec![[0.0; 3]; 2]);
        let (mut ga, mut gb) = (vec![[0.0; 3]; 2], vec![[0.0; 3]; 2]);
        smoothness(&v3(&P), &b, 1.0, &mut ga, &mut gb);
        close(&ga.concat(), &numeric(&f, &P), 1e-3);
        close(&gb.concat(), &ga.concat().iter().map(|x| -x).collect::<Vec<_>>(), 1e-6);

        let f = |x: &[f32]| bubble(x, 0.5, &mut [0.0; 6]);
        let mut g = [0.0; 6];
        bubble(&P, 0.5, &mut g);
        close(&g.iter().map(|x| x / 0.5).collect::<Vec<_>>(), &numeric(&f, &P), 1e-3);

        let f = |x: &[f32]| inside(x, 0.5, &mut [0.0; 6]);
        let mut g = [0.0; 6];
        inside(&P, 0.5, &mut g);
        close(&g.iter().map(|x| x / 0.5).collect::<Vec<_>>(), &numeric(&f, &P), 1e-3);
        // Points already inside cost nothing.
        assert_eq!(inside(&[-0.1, -2.0], 1.0, &mut [0.0; 2]), 0.0);
    }
}
