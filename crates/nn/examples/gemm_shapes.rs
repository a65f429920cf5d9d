//! Single-thread GFLOP/s of the engine's tile-shaped products (`linalg::gemm_*`), to compare the
//! packing-free AVX-512 kernel with matrixmultiply (`I2SDF_GEMM=matrixmultiply`):
//! `cargo run --release -p i2sdf-nn --example gemm_shapes`.

use i2sdf_nn::linalg::{gemm_a_b, gemm_a_bt, gemm_at_b_acc};
use std::time::Instant;

fn main() {
    let shapes: &[(usize, usize, usize, &str)] = &[
        (256, 64, 64, "A·B"),
        (256, 35, 64, "A·Bᵀ"),
        (256, 64, 35, "A·B"),
        (64, 256, 64, "Aᵀ·B"),
        (64, 256, 35, "Aᵀ·B"),
        (256, 64, 16, "A·Bᵀ"),
        (16, 256, 64, "Aᵀ·B"),
        (256, 256, 256, "A·Bᵀ"),
        (35, 256, 64, "Aᵀ·B"),
        (1024, 1024, 1024, "A·B"),
    ];
    for &(m, k, n, kind) in shapes {
        let a = vec![0.5f32; m * k];
        let b = vec![0.25f32; k * n];
        let mut c = vec![0.0f32; m * n];
        let reps = (2e9 / (2.0 * (m * k * n) as f64)) as usize + 1;
        let mut best = f64::MAX;
        for _ in 0..5 {
            let t = Instant::now();
            for _ in 0..reps {
                match kind {
                    "A·B" => gemm_a_b(m, k, n, &a, k, &b, n, 0.0, &mut c, n),
                    "A·Bᵀ" => gemm_a_bt(m, k, n, &a, k, &b, k, 0.0, &mut c, n),
                    _ => gemm_at_b_acc(m, k, n, &a, m, &b, n, &mut c, n),
                }
            }
            best = best.min(t.elapsed().as_secs_f64() / reps as f64);
        }
        let flop = 2.0 * (m * k * n) as f64;
        println!("{kind:5} {m:5}×{k:5}×{n:5}: {:6.1} GFLOP/s", flop / best / 1e9);
    }
}
