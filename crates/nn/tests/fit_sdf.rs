//! The engine end to end: a hash-grid SDF network, starting from the inverted-sphere init, fits the
//! SDF of a room (an inside-out box: positive inside, the cameras' side) with an L2 distance loss
//! and the eikonal term, in a few hundred Adam steps.

use i2sdf_nn::{
    Adam, AdamConfig, HashGridConfig, LrSchedule, SdfEncoding, SdfEncodingConfig, SdfGrad, SdfNetwork,
    SdfNetworkConfig, SdfWorkspace,
};
use rand::{Rng, SeedableRng};

const HALF: [f32; 3] = [0.6, 0.5, 0.4];

/// Signed distance of the room: `−sdf_box`, positive inside.
fn room_sdf(p: &[f32]) -> f32 {
    let q: Vec<f32> = (0..3).map(|k| p[k].abs() - HALF[k]).collect();
    let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f32>().sqrt();
    let inside = q[0].max(q[1]).max(q[2]).min(0.0);
    -(outside + inside)
}

#[test]
fn fits_an_inside_out_box_with_eikonal_term() {
    let config = SdfNetworkConfig {
        encoding: SdfEncodingConfig::HashGrid(HashGridConfig {
            levels: 8,
            features_per_level: 2,
            log2_table_size: 15,
            base_resolution: 8,
            finest_resolution: 128,
            bound: 1.0,
        }),
        hidden_dim: 64,
        hidden_layers: 2,
        skip_layers: vec![],
        activation: i2sdf_nn::Activation::Softplus { beta: 100.0 },
        feature_dim: 3,
        geometric_init: Some(i2sdf_nn::GeometricInit {
            radius: 0.5,
            inside_out: true,
        }),
    };
    let mut net = SdfNetwork::new(config, 1);
    let mut grad = SdfGrad::new(&net);
    let mut adam = Adam::new(AdamConfig {
        beta1: 0.9,
        beta2: 0.99,
        eps: 1e-15,
    });
    let iterations = 400;
    let schedule = LrSchedule::Exponential {
        rate: 0.1,
        steps: iterations,
    };
    let g_mlp = adam.add_group("sdf.mlp", net.mlp.params.len(), 5e-3, schedule);
    let g_hash = match &net.encoding {
        SdfEncoding::HashGrid(g) => adam.add_group("sdf.hash_grid", g.params.len(), 1e-2, schedule),
        _ => unreachable!(),
    };
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
    let n = 4096;
    let mut ws = SdfWorkspace::default();
    let (mut x, mut sdf, mut feat, mut g) = (vec![0.0; n * 3], vec![0.0; n], vec![0.0; n * 3], vec![0.0; n * 3]);
    let (mut d_sdf, mut d_grad) = (vec![0.0; n], vec![0.0; n * 3]);
    let lambda_eik = 0.1;
    let started = std::time::Instant::now();
    for _ in 0..iterations {
        // half the samples uniform, half near the walls, where the normals matter
        for i in 0..n {
            loop {
                let p: [f32; 3] = std::array::from_fn(|_| rng.gen_range(-0.8..0.8));
                if i % 2 == 0 || room_sdf(&p).abs() < 0.1 {
                    x[i * 3..i * 3 + 3].copy_from_slice(&p);
                    break;
                }
            }
        }
        net.forward_with_gradient(&x, &mut ws, &mut sdf, &mut feat, &mut g);
        for i in 0..n {
            d_sdf[i] = 2.0 * (sdf[i] - room_sdf(&x[i * 3..i * 3 + 3])) / n as f32;
            let gi = &g[i * 3..i * 3 + 3];
            let norm = (gi[0] * gi[0] + gi[1] * gi[1] + gi[2] * gi[2]).sqrt().max(1e-8);
            for k in 0..3 {
                d_grad[i * 3 + k] = lambda_eik * 2.0 * (norm - 1.0) * gi[k] / norm / n as f32;
            }
        }
        net.backward(&mut ws, &d_sdf, None, Some(&d_grad), &mut grad);
        adam.begin_step();
        adam.update(g_mlp, &mut net.mlp.params, &mut grad.mlp);
        if let SdfEncoding::HashGrid(hg) = &mut net.encoding {
            adam.update_sparse(g_hash, &mut hg.params, grad.hash_grid.as_mut().unwrap(), 2);
        }
    }
    let elapsed = started.elapsed().as_secs_f32();
    // held-out evaluation
    let m = 8192;
    let xs: Vec<f32> = (0..m * 3).map(|_| rng.gen_range(-0.75..0.75)).collect();
    let (mut s, mut f, mut gr) = (vec![0.0; m], vec![0.0; m * 3], vec![0.0; m * 3]);
    net.forward_with_gradient(&xs, &mut ws, &mut s, &mut f, &mut gr);
    let (mut abs_err, mut eik, mut near, mut normal_err) = (0.0f64, 0.0f64, 0usize, 0.0f64);
    for i in 0..m {
        let p = &xs[i * 3..i * 3 + 3];
        let gt = room_sdf(p);
        abs_err += (s[i] - gt).abs() as f64 / m as f64;
        let gi = &gr[i * 3..i * 3 + 3];
        let norm = (gi.iter().map(|v| v * v).sum::<f32>()).sqrt();
        eik += (norm - 1.0).abs() as f64 / m as f64;
        // near a face (not an edge), the normal is the face's inward axis
        let q: Vec<f32> = (0..3).map(|k| HALF[k] - p[k].abs()).collect();
        let k = (0..3).min_by(|&a, &b| q[a].total_cmp(&q[b])).unwrap();
        let second = (0..3).filter(|&j| j != k).map(|j| q[j]).fold(f32::MAX, f32::min);
        if gt.abs() < 0.05 && second - q[k] > 0.05 {
            near += 1;
            let inward = -p[k].signum();
            normal_err += (1.0 - gi[k] * inward / norm.max(1e-8)) as f64;
        }
    }
    let normal_err = normal_err / near.max(1) as f64;
    eprintln!("fit: {elapsed:.2} s, mean |d − d*| = {abs_err:.4}, mean |‖∇d‖ − 1| = {eik:.4}, normal 1 − cos = {normal_err:.4} ({near} pts)");
    assert!(abs_err < 0.01, "mean |d − d*| = {abs_err}");
    assert!(eik < 0.05, "mean |‖∇d‖ − 1| = {eik}");
    assert!(
        near > 100 && normal_err < 0.015,
        "near-wall normals: 1 − cos = {normal_err} over {near}"
    );
}
