//! The trained SDF along a world segment, in world units: whether a thin object the mesh lost is
//! in the field at all (a dip to ≤ 0), faint (a dip that stays positive) or absent (issue 12).
//!
//! `cargo run --release -p i2sdf-model --example sdf_probe -- RUN x y z dx dy dz HALF STEPS`
//! probes x + s·(dx, dy, dz)/|d| for s in [−HALF, HALF] (world units) and prints s, the SDF and
//! the Laplace density's opacity over one step at the run's β (world cm and a fraction).

use i2sdf_model::NeuralScene;
use i2sdf_nn::sdf::SdfInferWorkspace;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 10 {
        return Err("usage: sdf_probe RUN x y z dx dy dz HALF STEPS".into());
    }
    let f = |i: usize| a[i].parse::<f64>();
    let (p, d) = ([f(2)?, f(3)?, f(4)?], [f(5)?, f(6)?, f(7)?]);
    let (half, steps) = (f(8)?, a[9].parse::<usize>()?);
    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let (scene, _) = NeuralScene::load(&std::path::Path::new(&a[1]).join("checkpoint.safetensors"))?;
    let norm = &scene.normalization;
    let beta = scene.beta.value();
    let mut pts = Vec::new();
    let mut s_world = Vec::new();
    for k in 0..steps {
        let s = -half + 2.0 * half * k as f64 / (steps.max(2) - 1) as f64;
        let w = glam::DVec3::new(p[0] + s * d[0] / len, p[1] + s * d[1] / len, p[2] + s * d[2] / len);
        let n = norm.to_normalized(w);
        pts.extend_from_slice(&[n.x as f32, n.y as f32, n.z as f32]);
        s_world.push(s);
    }
    let mut sdf = vec![0.0; steps];
    scene
        .sdf
        .infer(&pts, &mut SdfInferWorkspace::default(), &mut sdf, None, None);
    let step = 2.0 * half / (steps.max(2) - 1) as f64 / norm.scale;
    println!("beta {:.2} cm (world)", beta as f64 * norm.scale * 100.0);
    for (s, d) in s_world.iter().zip(&sdf) {
        let alpha = 1.0 - (-(i2sdf_model::volume::laplace_density(*d, beta) as f64) * step).exp();
        println!(
            "{:8.2} cm  sdf {:8.2} cm  alpha/step {:.3}",
            s * 100.0,
            *d as f64 * norm.scale * 100.0,
            alpha
        );
    }
    Ok(())
}
