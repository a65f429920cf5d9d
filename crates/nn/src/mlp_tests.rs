//! Gradient tests of the MLP tile kernels against central finite differences.

use super::*;
use crate::gradcheck::{assert_grad_close, central_difference, Lcg};

fn small_mlp(hidden: Activation, output: Activation) -> Mlp {
    let config = MlpConfig {
        input_dim: 4,
        hidden_dim: 6,
        hidden_layers: 3,
        output_dim: 3,
        skip_layers: vec![2],
        hidden_activation: hidden,
        output_activation: output,
    };
    let mut mlp = Mlp::new(config, 7);
    let mut rng = Lcg(11);
    for (i, p) in mlp.params.iter_mut().enumerate() {
        *p = *p * 0.8 + 0.05 * rng.uniform_pm1() + if i % 7 == 0 { 0.1 } else { 0.0 };
    }
    mlp
}

const N: usize = 5;

fn forward(mlp: &Mlp, x: &[f32]) -> Vec<f32> {
    let mut acts = vec![0.0; N * mlp.activation_width()];
    let mut s = mlp.new_scratch();
    mlp.forward_tile(x, N, &mut acts, &mut s);
    acts
}

/// `Σ c⊙Y + Σ ḡ⊙G_X`, with `G_X = ∂y_1/∂X`, accumulated in f64.
fn loss(mlp: &Mlp, x: &[f32], c: &[f32], gbar: Option<&[f32]>) -> f64 {
    let acts = forward(mlp, x);
    let y = mlp.tile_output(&acts, N);
    let mut l: f64 = y.iter().zip(c).map(|(&y, &c)| y as f64 * c as f64).sum();
    if let Some(gbar) = gbar {
        let mut gacts = vec![0.0; acts.len()];
        let mut gx = vec![0.0; N * mlp.input_dim()];
        mlp.input_gradient_tile(N, &acts, 1, &mut gacts, &mut gx, &mut mlp.new_scratch());
        l += gx.iter().zip(gbar).map(|(&g, &b)| g as f64 * b as f64).sum::<f64>();
    }
    l
}

fn inputs(mlp: &Mlp, seed: u64) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut rng = Lcg(seed);
    let x = (0..N * mlp.input_dim()).map(|_| rng.uniform_pm1()).collect();
    let c = (0..N * mlp.output_dim()).map(|_| rng.uniform_pm1()).collect();
    let gbar = (0..N * mlp.input_dim()).map(|_| rng.uniform_pm1()).collect();
    (x, c, gbar)
}

/// The forward pass against a direct f64 evaluation of the layer equations.
#[test]
fn forward_matches_reference() {
    let mlp = small_mlp(Activation::Softplus { beta: 4.0 }, Activation::Sigmoid);
    let (x, _, _) = inputs(&mlp, 3);
    let acts = forward(&mlp, &x);
    let y = mlp.tile_output(&acts, N);
    let act64 = |act: Activation, z: f64| match act {
        Activation::Softplus { beta } => (1.0 + (z * beta as f64).exp()).ln() / beta as f64,
        Activation::Sigmoid => 1.0 / (1.0 + (-z).exp()),
        Activation::Relu => z.max(0.0),
        Activation::Identity => z,
    };
    for r in 0..N {
        let xr: Vec<f64> = x[r * 4..r * 4 + 4].iter().map(|&v| v as f64).collect();
        let mut h = xr.clone();
        for layer in &mlp.layers {
            let input: Vec<f64> = if layer.skip {
                h.iter().chain(&xr).map(|v| v / 2f64.sqrt()).collect()
            } else {
                h.clone()
            };
            h = (0..layer.out_dim)
                .map(|o| {
                    let w = &mlp.params[layer.weight_offset + o * layer.in_dim..];
                    let z = mlp.params[layer.bias_offset + o] as f64
                        + input.iter().enumerate().map(|(i, v)| w[i] as f64 * v).sum::<f64>();
                    act64(layer.activation, z)
                })
                .collect();
        }
        for o in 0..3 {
            assert!(
                (y[r * 3 + o] as f64 - h[o]).abs() < 1e-5,
                "row {r} out {o}: {} vs {}",
                y[r * 3 + o],
                h[o]
            );
        }
    }
}

#[test]
fn backward_matches_finite_differences() {
    for hidden in [
        Activation::Softplus { beta: 4.0 },
        Activation::Relu,
        Activation::Sigmoid,
    ] {
        let mlp = small_mlp(hidden, Activation::Sigmoid);
        let (x, c, _) = inputs(&mlp, 5);
        let acts = forward(&mlp, &x);
        let mut grad = vec![0.0; mlp.params.len()];
        let mut dx = vec![0.0; x.len()];
        mlp.backward_tile(&x, N, &acts, &c, &mut grad, Some(&mut dx), &mut mlp.new_scratch());
        let fd = central_difference(&mlp.params, 2e-3, |p| {
            let mut m = mlp.clone();
            m.params.copy_from_slice(p);
            loss(&m, &x, &c, None)
        });
        assert_grad_close("mlp params", &grad, &fd, 2e-3, 1e-2);
        let fdx = central_difference(&x, 2e-3, |xp| loss(&mlp, xp, &c, None));
        assert_grad_close("mlp input", &dx, &fdx, 2e-3, 1e-2);
    }
}

#[test]
fn input_gradient_matches_finite_differences() {
    let mlp = small_mlp(Activation::Softplus { beta: 4.0 }, Activation::Identity);
    let (x, _, _) = inputs(&mlp, 9);
    let acts = forward(&mlp, &x);
    let mut gacts = vec![0.0; acts.len()];
    let mut gx = vec![0.0; x.len()];
    mlp.input_gradient_tile(N, &acts, 1, &mut gacts, &mut gx, &mut mlp.new_scratch());
    // d y_1 / d x summed over rows (rows are independent, so per-row entries are recovered)
    let mut c = vec![0.0; N * 3];
    for r in 0..N {
        c[r * 3 + 1] = 1.0;
    }
    let fd = central_difference(&x, 2e-3, |xp| loss(&mlp, xp, &c, None));
    assert_grad_close("G_X", &gx, &fd, 1e-3, 1e-2);
}

/// The double backward: gradient of `⟨c, Y⟩ + ⟨ḡ, ∂y_1/∂X⟩` w.r.t. parameters and input. With the
/// second-order term (`φ''`) removed, Softplus and Sigmoid cases fail this test.
#[test]
fn double_backward_matches_finite_differences() {
    for (hidden, output) in [
        (Activation::Softplus { beta: 4.0 }, Activation::Identity),
        (Activation::Sigmoid, Activation::Sigmoid),
        (Activation::Softplus { beta: 2.0 }, Activation::Softplus { beta: 2.0 }),
    ] {
        // ReLU is left out: its G_X jumps where a pre-activation crosses 0, so finite differences
        // are meaningless there; its (first-order) path is the Identity-output case above.
        let mlp = small_mlp(hidden, output);
        let (x, c, gbar) = inputs(&mlp, 13);
        let acts = forward(&mlp, &x);
        let mut s = mlp.new_scratch();
        let mut gacts = vec![0.0; acts.len()];
        let mut gx = vec![0.0; x.len()];
        mlp.input_gradient_tile(N, &acts, 1, &mut gacts, &mut gx, &mut s);
        let mut grad = vec![0.0; mlp.params.len()];
        let mut dx = vec![0.0; x.len()];
        mlp.double_backward_tile(&x, N, &acts, &gacts, 1, &c, &gbar, &mut grad, Some(&mut dx), &mut s);
        let fd = central_difference(&mlp.params, 2e-3, |p| {
            let mut m = mlp.clone();
            m.params.copy_from_slice(p);
            loss(&m, &x, &c, Some(&gbar))
        });
        assert_grad_close(&format!("double backward params {hidden:?}"), &grad, &fd, 3e-3, 2e-2);
        let fdx = central_difference(&x, 2e-3, |xp| loss(&mlp, xp, &c, Some(&gbar)));
        assert_grad_close(&format!("double backward input {hidden:?}"), &dx, &fdx, 3e-3, 2e-2);
    }
}

#[test]
fn geometric_init_is_an_inverted_sphere() {
    let config = MlpConfig {
        input_dim: 3 + 12,
        hidden_dim: 256,
        hidden_layers: 8,
        output_dim: 4,
        skip_layers: vec![4],
        hidden_activation: Activation::Softplus { beta: 100.0 },
        output_activation: Activation::Identity,
    };
    let mut mlp = Mlp::new(config, 1);
    mlp.geometric_init(
        GeometricInit {
            radius: 0.8,
            inside_out: true,
        },
        3,
        2,
    );
    let mut rng = Lcg(4);
    let n = 64;
    let mut x = vec![0.0; n * 15];
    for r in 0..n {
        for k in 0..15 {
            x[r * 15 + k] = rng.uniform_pm1() * if k < 3 { 0.6 } else { 1.0 };
        }
    }
    let mut acts = vec![0.0; n * mlp.activation_width()];
    mlp.forward_tile(&x, n, &mut acts, &mut mlp.new_scratch());
    let y = mlp.tile_output(&acts, n);
    let mut mean_err = 0.0f32;
    for r in 0..n {
        let norm = (x[r * 15..r * 15 + 3].iter().map(|v| v * v).sum::<f32>()).sqrt();
        let err = (y[r * 4] - (0.8 - norm)).abs();
        // SAL's init is a sphere up to the random features' spread (~0.1 at width 256).
        assert!(err < 0.25, "|sdf − (r − ‖x‖)| = {err} at ‖x‖ = {norm}");
        mean_err += err / n as f32;
    }
    assert!(mean_err < 0.08, "mean |sdf − (r − ‖x‖)| = {mean_err}");
}
