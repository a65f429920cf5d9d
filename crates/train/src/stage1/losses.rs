//! Stage 1's loss terms (paper Sec. 4.1–4.2, eq:bubble, "eikonal", "depth", "normal", "smooth",
//! "emitter BCE", eq:train1 "L_rgb"), each as a value plus its gradient with respect to what the
//! renderer or the SDF produced. Every term is a mean over its batch (as in VolSDF's
//! implementation) so that weights do not depend on the batch size. Callers add the weighted
//! gradients into their upstream buffers (`grad += w · ∂term`).

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

/// L_depth = mean over rays with depth of |D̂ − D| (eq. "depth"), each ray's term times its
/// `weights` entry where given (the sensor's noise model, `maps.depth_noise_distance`; the
/// caller makes them average 1). `valid` masks rays with depth.
pub fn depth_l1(
    pred: &[f32],
    target: &[f32],
    valid: &[bool],
    weights: Option<&[f32]>,
    w: f32,
    grad: &mut [f32],
) -> f32 {
    let n = valid.iter().filter(|v| **v).count();
    if n == 0 {
        return 0.0;
    }
    let mut loss = 0.0f64;
    for i in 0..pred.len() {
        if valid[i] {
            let (d, k) = (pred[i] - target[i], weights.map_or(1.0, |v| v[i]));
            loss += (k * d.abs()) as f64;
            grad[i] += w * k * d.signum() / n as f32;
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
/// zero level set), each point's term times its `weights` entry where given; with `tolerance`,
/// max(0, |d| − τ) instead: a noisy depth point is only known to lie within τ of the surface.
pub fn bubble(sdf: &[f32], weights: Option<&[f32]>, tolerance: Option<&[f32]>, w: f32, grad: &mut [f32]) -> f32 {
    let n = sdf.len().max(1) as f32;
    let mut loss = 0.0f64;
    for (i, (d, g)) in sdf.iter().zip(grad.iter_mut()).enumerate() {
        let k = weights.map_or(1.0, |v| v[i]);
        let excess = d.abs() - tolerance.map_or(0.0, |t| t[i]);
        if excess > 0.0 {
            loss += (k * excess) as f64;
            *g += w * k * d.signum() / n;
        }
    }
    (loss / n as f64) as f32
}

/// L_inside = mean over points just behind the depth surface of max(0, d(x)) (beyond the paper):
/// a pixel's depth says where its ray enters a surface, so a point a few millimetres further
/// along the ray is inside whatever it entered (anything thicker than that), and its SDF must be
/// negative. eq:bubble only pins |d| = 0 on the surface, which a ridge of small positive d also
/// satisfies: that is what a 1–2 px lamp pole becomes (semi-transparent in volume rendering, no
/// zero crossing for marching cubes), as its partly covered pixels favour.
pub fn inside(sdf: &[f32], weights: Option<&[f32]>, w: f32, grad: &mut [f32]) -> f32 {
    let n = sdf.len().max(1) as f32;
    let mut loss = 0.0f64;
    for (i, (d, g)) in sdf.iter().zip(grad.iter_mut()).enumerate() {
        if *d > 0.0 {
            let k = weights.map_or(1.0, |v| v[i]);
            loss += (k * *d) as f64;
            *g += w * k / n;
        }
    }
    (loss / n as f64) as f32
}

/// How much a sensor's noise has grown at distance z from its value up close: 1 + (z / d)²
/// (`maps.depth_noise_distance` = d, in the same units as z).
pub fn noise_growth(z: f32, d: f32) -> f32 {
    1.0 + (z / d).powi(2)
}

/// Per-sample weights of a sensor whose noise grows as σ₀ (1 + (z / d)²): 1 / (1 + (z / d)²)
/// for each distance z (the L1 likelihood's 1 / σ up to a factor), scaled to average 1 over the
/// samples `counted` marks (all without it) so that a term's weight keeps its meaning. None where
/// `d` is 0 (every sample alike).
pub fn noise_weights(distances: &[f32], counted: Option<&[bool]>, d: f32) -> Option<Vec<f32>> {
    if d <= 0.0 {
        return None;
    }
    let w: Vec<f32> = distances.iter().map(|&z| 1.0 / noise_growth(z, d)).collect();
    let counts = |i: usize| counted.is_none_or(|c| c[i]);
    let (sum, n) = (0..w.len())
        .filter(|&i| counts(i))
        .fold((0.0f32, 0usize), |(s, n), i| (s + w[i], n + 1));
    let mean = sum / n.max(1) as f32;
    (mean > 0.0).then(|| w.iter().map(|v| v / mean).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_nn::gradcheck::{assert_close as close, numeric_gradient as numeric};

    fn v3(x: &[f32]) -> Vec<[f32; 3]> {
        x.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    }

    // Inputs are kept away from the kinks of |·| so central differences are exact enough.
    const P: [f32; 6] = [0.3, -0.7, 1.2, 0.9, 0.2, -0.4];
    const T: [f32; 6] = [0.1, 0.2, -0.3, 0.5, -0.6, 0.7];
    /// Per-sample weights (`noise_weights`' kind).
    const K: [f32; 6] = [1.6, 0.4, 1.0, 0.7, 1.9, 0.4];

    /// The noise weights fall with distance as 1 / (1 + (z/d)²), average 1, and are off at d = 0.
    #[test]
    fn noise_weights_follow_the_sensor_model() {
        let w = noise_weights(&[0.0, 1.0, 3.0], None, 1.0).unwrap();
        let raw = [1.0, 0.5, 0.1];
        let mean = raw.iter().sum::<f32>() / 3.0;
        for (a, r) in w.iter().zip(raw) {
            assert!((a - r / mean).abs() < 1e-6, "{w:?}");
        }
        assert!((w.iter().sum::<f32>() / 3.0 - 1.0).abs() < 1e-6);
        assert!(noise_weights(&[1.0], None, 0.0).is_none());
    }

    #[test]
    fn rgb_and_depth_gradients() {
        let t = v3(&T);
        let f = |x: &[f32]| rgb_l1(&v3(x), &t, 1.0, &mut vec![[0.0; 3]; 2]);
        let mut g = vec![[0.0; 3]; 2];
        rgb_l1(&v3(&P), &t, 1.0, &mut g);
        close(&g.concat(), &numeric(&f, &P), 1e-3);

        let valid = [true, false, true, true, true, false];
        for weights in [None, Some(&K[..])] {
            let f = |x: &[f32]| depth_l1(x, &T, &valid, weights, 1.0, &mut [0.0; 6]);
            let mut g = [0.0; 6];
            depth_l1(&P, &T, &valid, weights, 1.0, &mut g);
            close(&g, &numeric(&f, &P), 1e-3);
            assert_eq!(g[1], 0.0);
        }
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

        // Tolerances: |d| inside the dead zone for the 2nd, 5th and 6th point, outside for the rest.
        const TOL: [f32; 6] = [0.1, 0.8, 0.5, 0.3, 0.25, 0.5];
        for (weights, tol) in [(None, None), (Some(&K[..]), None), (Some(&K[..]), Some(&TOL[..]))] {
            let f = |x: &[f32]| bubble(x, weights, tol, 0.5, &mut [0.0; 6]);
            let mut g = [0.0; 6];
            bubble(&P, weights, tol, 0.5, &mut g);
            close(&g.iter().map(|x| x / 0.5).collect::<Vec<_>>(), &numeric(&f, &P), 1e-3);
            if tol.is_some() {
                assert!(g[1] == 0.0 && g[4] == 0.0 && g[5] == 0.0 && g[0] != 0.0, "{g:?}");
            }

            let f = |x: &[f32]| inside(x, weights, 0.5, &mut [0.0; 6]);
            let mut g = [0.0; 6];
            inside(&P, weights, 0.5, &mut g);
            close(&g.iter().map(|x| x / 0.5).collect::<Vec<_>>(), &numeric(&f, &P), 1e-3);
        }
        // Points already inside cost nothing.
        assert_eq!(inside(&[-0.1, -2.0], None, 1.0, &mut [0.0; 2]), 0.0);
    }
}
