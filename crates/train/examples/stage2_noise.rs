//! Noise and bias of stage 2's Monte Carlo estimator of eq:render on a trained run, at the
//! paper's N = 16, with and without emitter sampling (one-sample MIS with cones towards the
//! emitters), and of the cache's fixed proposal at its M: per-pixel standard deviation over
//! seeds, and bias against a 1024-sample estimate of the same fields (the same materials and
//! emissions), over random pixels of the test views.
//!
//! `cargo run --release -p i2sdf-train --example stage2_noise -- RUN DATA [PIXELS] [SEEDS]`

use glam::Vec3;
use i2sdf_data::Split;
use i2sdf_model::intrinsic::{FrozenScene, LabelledHit};
use i2sdf_model::intrinsic_io::load_run;
use i2sdf_model::material_field::{MaterialBackbone, MATERIAL_CHANNELS};
use i2sdf_model::RunDir;
use i2sdf_render::{GgxBrdf, Ray};
use i2sdf_train::run::read_run_config;
use i2sdf_train::stage2::shading::{shade, trace_incident, ShadingPoint};
use i2sdf_train::stage2::{cache_mixture, live_mixture};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: stage2_noise RUN DATA [PIXELS] [SEEDS]");
        std::process::exit(2);
    }
    let run = RunDir::new(std::path::Path::new(&args[1]));
    let dataset = i2sdf_data::load(std::path::Path::new(&args[2]))?;
    let pixels: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(2000);
    let seeds: usize = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(8);
    let config = read_run_config(&run)?;
    let (scene, fields) = load_run(&run)?;
    let fields = fields.ok_or("the run has no stage 2")?;
    let mut frozen = FrozenScene::new(&scene, &fields.emitters, fields.radiometry);
    frozen.emitter_threshold = config.stage2.emitter_threshold;
    // Random non-emitter pixels of the test views that hit the surface.
    let mut rng = Pcg32::seed_from_u64(5);
    let test: Vec<_> = dataset.split(Split::Test).collect();
    let mut rays = Vec::new();
    while rays.len() < pixels * 2 {
        let f = test[rng.gen_range(0..test.len())];
        let p = rng.gen_range(0..f.pixel_count());
        if f.emitter_mask.as_ref().is_some_and(|m| m.data[p] > 0.5) {
            continue;
        }
        let g = f.camera.ray_generator();
        let (x, y) = (p % f.camera.width, p / f.camera.width);
        rays.push(Ray::new(
            g.origin,
            g.dir(x as f32 + 0.5, y as f32 + 0.5),
            0.0,
            f32::INFINITY,
        ));
    }
    let mut hits: Vec<Option<LabelledHit>> = vec![None; rays.len()];
    frozen.cast(&rays, &mut hits);
    let pts: Vec<ShadingPoint> = rays
        .iter()
        .zip(&hits)
        .filter_map(|(r, h)| {
            let h = (*h)?;
            if h.emitter.is_some() {
                return None;
            }
            let view = -r.dir;
            let normal = if h.normal.dot(view) < 0.0 { -h.normal } else { h.normal };
            Some(ShadingPoint {
                position: h.position,
                normal,
                view,
            })
        })
        .take(pixels)
        .collect();
    let n = scene.normalization;
    let c = Vec3::from_array(n.center.map(|v| v as f32));
    let pos: Vec<f32> = pts
        .iter()
        .flat_map(|p| ((p.position - c) / n.scale as f32).to_array())
        .collect();
    let features = match fields.material.config.backbone {
        MaterialBackbone::FeatureMlp => {
            let mut z = vec![0.0; pts.len() * scene.feature_dim()];
            let world: Vec<Vec3> = pts.iter().map(|p| p.position).collect();
            frozen.features(&world, &mut z);
            z
        }
        MaterialBackbone::HashGrid => Vec::new(),
    };
    let mut m = vec![0.0; pts.len() * MATERIAL_CHANNELS];
    fields.material.infer(&pos, &features, &mut m);
    let brdfs: Vec<GgxBrdf> = m
        .chunks_exact(MATERIAL_CHANNELS)
        .map(|o| GgxBrdf::new(Vec3::new(o[0], o[1], o[2]), Vec3::new(o[3], o[4], o[5]), o[6]))
        .collect();
    let emission: Vec<Vec3> = (0..fields.emitters.len())
        .map(|k| fields.emitters.emission(k))
        .collect();
    let scale = n.scale as f32;
    // Estimates of every point with `count` samples from proposal `kind`, seed `seed`.
    let run_estimate = |count: usize, kind: u8, seed: u64| -> Vec<Vec3> {
        let mut rngs: Vec<Pcg32> = (0..pts.len())
            .map(|i| Pcg32::seed_from_u64(seed << 32 ^ i as u64))
            .collect();
        let table = &fields.emitters;
        let mix = |i: usize| match kind {
            0 => live_mixture(&brdfs[i], table, false),
            1 => live_mixture(&brdfs[i], table, true),
            _ => cache_mixture(table, config.stage2.emitter_sampling),
        };
        let s = trace_incident(&frozen, &pts, count, scale, &mix, &mut rngs);
        (0..pts.len())
            .map(|i| {
                shade(
                    &brdfs[i],
                    pts[i].normal.dot(pts[i].view),
                    &s[i * count..(i + 1) * count],
                    &emission,
                )
            })
            .collect()
    };
    eprintln!(
        "reference: 1024 samples per pixel (BRDF + emitter MIS) at {} pixels",
        pts.len()
    );
    let reference = run_estimate(1024, 1, 999);
    let mean_ref = reference.iter().map(|v| v.element_sum() / 3.0).sum::<f32>() / pts.len() as f32;
    println!(
        "{} pixels, {} seeds; mean reference radiance {:.4} (linear)",
        pts.len(),
        seeds,
        mean_ref
    );
    for (kind, count, name) in [
        (0u8, 16usize, "N=16, GGX mixture only (paper)"),
        (1, 16, "N=16, GGX mixture + emitter cones (MIS)"),
        (2, config.stage2.cache_samples, "cache proposal, M samples"),
    ] {
        let runs: Vec<Vec<Vec3>> = (0..seeds).map(|s| run_estimate(count, kind, s as u64 + 1)).collect();
        let (mut std_sum, mut rel_sum, mut bias_sum, mut bias_sq) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for i in 0..pts.len() {
            let vals: Vec<f32> = runs.iter().map(|r| r[i].element_sum() / 3.0).collect();
            let mean = vals.iter().sum::<f32>() / seeds as f32;
            let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / (seeds - 1) as f32;
            let refv = reference[i].element_sum() / 3.0;
            std_sum += var.sqrt() as f64;
            rel_sum += (var.sqrt() / refv.max(1e-4)) as f64;
            let b = (mean - refv) as f64;
            bias_sum += b;
            bias_sq += b * b;
        }
        let np = pts.len() as f64;
        let bias = bias_sum / np;
        let bias_se = ((bias_sq / np - bias * bias).max(0.0) / np).sqrt();
        println!(
            "{name} ({count} samples): per-pixel std {:.4} ({:.1} % of the pixel), bias {:+.5} ± {:.5} ({:+.2} % of the mean)",
            std_sum / np,
            100.0 * rel_sum / np,
            bias,
            bias_se,
            100.0 * bias / mean_ref as f64
        );
    }
    Ok(())
}
