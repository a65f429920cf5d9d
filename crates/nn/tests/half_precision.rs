//! The SDF network's forward, spatial gradient and backward with the products in half precision
//! on AMX tiles, against the same network in f32 (whose gradients the unit tests check against
//! finite differences). Skipped where the CPU has no AMX.

use i2sdf_nn::linalg::MatmulPrecision;
use i2sdf_nn::{HashGridConfig, SdfEncoding, SdfEncodingConfig, SdfGrad, SdfNetwork, SdfNetworkConfig, SdfWorkspace};
use rand::{Rng, SeedableRng};

struct Outputs {
    sdf: Vec<f32>,
    feature: Vec<f32>,
    gradient: Vec<f32>,
    grad_mlp: Vec<f32>,
    grad_table: Vec<f32>,
}

fn run(net: &SdfNetwork, x: &[f32], cot: &[Vec<f32>; 3]) -> Outputs {
    let n = x.len() / 3;
    let mut ws = SdfWorkspace::default();
    let (mut sdf, mut feature, mut gradient) = (vec![0.0; n], vec![0.0; n * net.feature_dim()], vec![0.0; n * 3]);
    net.forward_with_gradient(x, &mut ws, &mut sdf, &mut feature, &mut gradient);
    let mut grad = SdfGrad::new(net);
    net.backward(&mut ws, &cot[0], Some(&cot[1]), Some(&cot[2]), &mut grad);
    let grad_table = grad.hash_grid.take().unwrap().values;
    Outputs {
        sdf,
        feature,
        gradient,
        grad_mlp: grad.mlp,
        grad_table,
    }
}

/// max |a − b| / max |b|.
fn rel(a: &[f32], b: &[f32]) -> f32 {
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-30);
    a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
}

#[test]
fn half_precision_products_agree_with_f32() {
    if !i2sdf_nn::amx::available() {
        eprintln!("no AMX tiles on this CPU: skipped");
        return;
    }
    let config = SdfNetworkConfig {
        encoding: SdfEncodingConfig::HashGrid(HashGridConfig {
            levels: 8,
            features_per_level: 2,
            log2_table_size: 12,
            base_resolution: 4,
            finest_resolution: 64,
            bound: 1.0,
        }),
        hidden_dim: 64,
        hidden_layers: 2,
        skip_layers: vec![],
        activation: i2sdf_nn::Activation::Softplus { beta: 100.0 },
        feature_dim: 15,
        geometric_init: Some(i2sdf_nn::GeometricInit {
            radius: 0.5,
            inside_out: true,
        }),
    };
    let mut net = SdfNetwork::new(config, 3);
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
    // features and their weights away from their zero init, so every product carries signal
    if let SdfEncoding::HashGrid(g) = &mut net.encoding {
        g.params.iter_mut().for_each(|p| *p = rng.gen_range(-0.1..0.1));
    }
    net.mlp.params.iter_mut().for_each(|p| *p += rng.gen_range(-0.05..0.05));
    let n = 1000; // several tiles, the last one ragged
    let x: Vec<f32> = (0..n * 3).map(|_| rng.gen_range(-0.9..0.9)).collect();
    let cot = [
        (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect(),
        (0..n * 15).map(|_| rng.gen_range(-1.0..1.0)).collect(),
        (0..n * 3).map(|_| rng.gen_range(-1.0..1.0)).collect(),
    ];
    let reference = run(&net, &x, &cot);
    // bf16x3 keeps ~16 bits of every operand; bf16 8 (2⁻⁹ relative rounding per operand)
    for (precision, tol) in [(MatmulPrecision::Bf16x3, 2e-4), (MatmulPrecision::Bf16, 3e-2)] {
        net.mlp.precision = precision;
        let got = run(&net, &x, &cot);
        for (name, a, b) in [
            ("sdf", &got.sdf, &reference.sdf),
            ("feature", &got.feature, &reference.feature),
            ("gradient", &got.gradient, &reference.gradient),
            ("mlp gradient", &got.grad_mlp, &reference.grad_mlp),
            ("table gradient", &got.grad_table, &reference.grad_table),
        ] {
            assert!(
                b.iter().any(|&v| v != 0.0),
                "{name}: all zero, the comparison would say nothing"
            );
            let e = rel(a, b);
            eprintln!("{}: {name} relative error {e:.2e}", precision.name());
            assert!(
                e < tol,
                "{}: {name} differs from f32 by {e:e} (> {tol:e})",
                precision.name()
            );
        }
    }
}
