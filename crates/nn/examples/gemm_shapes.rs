//! Single-thread GFLOP/s of the engine's tile-shaped products (`linalg::gemm_*`), to compare the
//! packing-free AVX-512 kernel with matrixmultiply (`I2SDF_GEMM=matrixmultiply`) and, where the
//! CPU has AMX tiles, with the bf16 and bf16x3 products:
//! `cargo run --release -p i2sdf-nn --example gemm_shapes`.

use i2sdf_nn::linalg::{gemm_a_b, gemm_a_bt, gemm_at_b_acc, MatmulPrecision};
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
    let precisions: &[MatmulPrecision] = if i2sdf_nn::amx::available() {
        &[MatmulPrecision::F32, MatmulPrecision::Bf16, MatmulPrecision::Bf16x3]
    } else {
        &[MatmulPrecision::F32]
    };
    for &(m, k, n, kind) in shapes {
        let rates: Vec<String> = precisions
            .iter()
            .map(|&p| format!("{} {:6.1}", p.name(), rate(m, k, n, kind, p)))
            .collect();
        println!("{kind:5} {m:5}×{k:5}×{n:5}: {} GFLOP/s", rates.join(", "));
    }
}

fn rate(m: usize, k: usize, n: usize, kind: &str, p: MatmulPrecision) -> f64 {
    {
        let a = vec![0.5f32; m * k];
        let b = vec![0.25f32; k * n];
        let mut c = vec![0.0f32; m * n];
        let reps = (2e9 / (2.0 * (m * k * n) as f64)) as usize + 1;
        let mut best = f64::MAX;
        for _ in 0..5 {
            let t = Instant::now();
            for _ in 0..reps {
                match kind {
                    "A·B" => gemm_a_b(m, k, n, &a, k, &b, n, 0.0, &mut c, n, p),
                    "A·Bᵀ" => gemm_a_bt(m, k, n, &a, k, &b, k, 0.0, &mut c, n, p),
                    _ => gemm_at_b_acc(m, k, n, &a, m, &b, n, &mut c, n, p),
                }
            }
            best = best.min(t.elapsed().as_secs_f64() / reps as f64);
        }
        2.0 * (m * k * n) as f64 / best / 1e9
    }
}
