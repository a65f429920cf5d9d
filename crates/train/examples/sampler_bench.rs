//! The ray sampler's cost and accuracy on a trained run (issue 12): times `renderer::sample`
//! (the samples of a stage-1 batch of training rays, as training draws them) beside the
//! differentiable forward at those samples, counts its SDF evaluations, and measures what the
//! samples lose against a dense reference (4096 uniform samples per ray): opacity, depth and
//! colour.
//!
//! `cargo run --release -p i2sdf-train --example sampler_bench -- RUN DATA [rays] [reps] [--time-only] [upsample=N coarse=N rounds=N eps=X] [occupancy=RES [margin=K]]`

use i2sdf_model::occupancy::OccupancyGrid;
use i2sdf_model::renderer::{self, sphere_exit, RenderWorkspace};
use i2sdf_model::volume::deltas_from_t;
use i2sdf_model::{NeuralScene, RunDir};
use i2sdf_train::config::TrainConfig;
use i2sdf_train::maps::TrainingMaps;
use i2sdf_train::stage1::rays::train_images;
use i2sdf_train::stage1::render_settings;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: sampler_bench RUN DATA [rays] [reps]".into());
    }
    let rays: usize = args.get(3).map_or(Ok(1024), |s| s.parse())?;
    let reps: usize = args.get(4).map_or(Ok(10), |s| s.parse())?;
    let run = RunDir::new(std::path::Path::new(&args[1]));
    let dataset = i2sdf_data::load(std::path::Path::new(&args[2]))?;
    let config = TrainConfig::load(Some(&run.config_path()), &[])?;
    let mut settings = render_settings(&config);
    // `KEY=VALUE` arguments override the sampler: upsample, coarse, rounds, eps.
    for a in args.iter().filter_map(|a| a.split_once('=')) {
        let s = &mut settings.sampler;
        match a.0 {
            "upsample" => s.num_samples_upsample = a.1.parse()?,
            "coarse" => s.num_samples_eval = a.1.parse()?,
            "rounds" => s.max_total_iters = a.1.parse()?,
            "eps" => s.eps = a.1.parse()?,
            "occupancy" | "margin" => {}
            k => return Err(format!("unknown override {k}").into()),
        }
    }
    let (scene, _) = NeuralScene::load(&run.checkpoint_path())?;
    // `occupancy=RES [margin=K]`: empty-space skipping with a RES³ grid, margin K·β (default 15).
    let value = |key: &str| args.iter().find_map(|a| a.strip_prefix(key).map(str::to_string));
    if let Some(res) = value("occupancy=") {
        let margin: f32 = value("margin=").map_or(Ok(15.0), |m| m.parse())?;
        let t = Instant::now();
        let grid = OccupancyGrid::for_scene(&scene, res.parse()?, settings.bound_radius, margin);
        println!(
            "occupancy {res}³, margin {:.4} ({margin} β, at least a cell): built in {:.0} ms, {:.1} % of the cells occupied",
            grid.margin(),
            t.elapsed().as_secs_f64() * 1e3,
            100.0 * grid.occupied_fraction()
        );
        settings.occupancy = Some(std::sync::Arc::new(grid));
    }
    let images = train_images(&dataset, &TrainingMaps::prepare(&dataset, &config)?);
    let mut rng = Pcg64::seed_from_u64(7);
    let (mut origins, mut dirs) = (Vec::new(), Vec::new());
    for _ in 0..rays {
        let im = &images[rng.gen_range(0..images.len())];
        let p = rng.gen_range(0..im.pixels());
        origins.push(im.origin);
        dirs.push(im.dirs[p]);
    }
    // The stage-1 batch's extra points (eikonal, bubble and smoothness pairs): random in the
    // unit sphere's cube, as many as the run's config draws.
    let t = &config.train;
    let extra: Vec<f32> = (0..3 * (t.eikonal_points + t.bubble_points + 2 * rays))
        .map(|_| rng.gen_range(-0.9..0.9f32))
        .collect();
    let mut grads = i2sdf_model::SceneGrads::new(&scene);
    let mut ws = RenderWorkspace::default();
    let (mut t_sample, mut t_forward, mut t_backward) = (Vec::new(), Vec::new(), Vec::new());
    let mut evaluations = 0;
    for rep in 0..reps {
        let mut r = Pcg64::seed_from_u64(rep as u64);
        let t = Instant::now();
        renderer::sample(&scene, &settings, &origins, &dirs, &mut ws, Some(&mut r));
        t_sample.push(t.elapsed().as_secs_f64() * 1e3);
        evaluations = ws.samples.sdf_evaluations;
        let t = Instant::now();
        renderer::forward_with_samples(&scene, &origins, &dirs, &extra, &mut ws);
        t_forward.push(t.elapsed().as_secs_f64() * 1e3);
        // Upstream gradients of every output and of every point's SDF and ∇SDF (the eikonal
        // term touches them all), as a training step has; the values do not matter for time.
        let n = ws.sdf.len();
        let (g_rays, g_rays3) = (vec![1e-3f32; rays], vec![1e-3f32; 3 * rays]);
        let (mut d_sdf, mut d_grad) = (vec![1e-3f32; n], vec![1e-3f32; 3 * n]);
        let t = Instant::now();
        renderer::backward(
            &scene,
            &mut ws,
            &renderer::RayGrads {
                rgb: &g_rays3,
                depth: &g_rays,
                normal: &g_rays3,
                emitter: &g_rays,
                opacity: &g_rays,
            },
            &mut d_sdf,
            &mut d_grad,
            &mut grads,
        );
        t_backward.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let converged = ws.samples.converged.iter().filter(|c| **c).count();
    let (ts, tf, tb) = (median(t_sample), median(t_forward), median(t_backward));
    println!(
        "beta {:.5}  rays {rays}  sampler {ts:.1} ms (median of {reps}, {:.0} % of the three)  forward {tf:.1} ms  backward {tb:.1} ms  SDF evaluations/ray {:.1}  samples/ray {:.1}  converged {:.1} %",
        scene.beta.value(),
        100.0 * ts / (ts + tf + tb),
        evaluations as f64 / rays as f64,
        ws.samples.t.len() as f64 / rays as f64,
        100.0 * converged as f64 / rays as f64
    );
    if args.iter().any(|a| a == "--time-only") {
        return Ok(());
    }
    // Accuracy: the sampler's (deterministic) samples against a dense uniform reference.
    renderer::sample::<Pcg64>(&scene, &settings, &origins, &dirs, &mut ws, None);
    renderer::forward_with_samples(&scene, &origins, &dirs, &[], &mut ws);
    let ours = ws.out.clone();
    let dense = 4096;
    let mut reference = renderer::RayOutputs::default();
    let mut dense_ws = RenderWorkspace::default();
    for chunk in (0..rays).step_by(32) {
        let r = chunk..(chunk + 32).min(rays);
        let s = &mut dense_ws.samples;
        s.ray_offsets = vec![0];
        s.t.clear();
        for i in r.clone() {
            let far = sphere_exit(origins[i], dirs[i], settings.bound_radius).max(2.0 * settings.near);
            for k in 0..dense {
                s.t.push(settings.near + (far - settings.near) * (k as f32 + 0.5) / dense as f32);
            }
            s.ray_offsets.push(s.t.len() as u32);
        }
        s.delta = vec![0.0; s.t.len()];
        deltas_from_t(&s.ray_offsets, &s.t, 1e10, &mut s.delta);
        renderer::forward_with_samples(&scene, &origins[r.clone()], &dirs[r], &[], &mut dense_ws);
        let o = &dense_ws.out;
        reference.rgb.extend_from_slice(&o.rgb);
        reference.depth.extend_from_slice(&o.depth);
        reference.opacity.extend_from_slice(&o.opacity);
    }
    let n = rays as f64;
    let mean = |f: &dyn Fn(usize) -> f64| (0..rays).map(f).sum::<f64>() / n;
    let opacity = mean(&|i| (ours.opacity[i] - reference.opacity[i]).abs() as f64);
    let opacity_max = (0..rays)
        .map(|i| (ours.opacity[i] - reference.opacity[i]).abs())
        .fold(0.0f32, f32::max);
    let scale = dataset.normalization.scale;
    let depth_cm = mean(&|i| (ours.depth[i] - reference.depth[i]).abs() as f64) * scale * 100.0;
    let mse = mean(&|i| {
        (0..3)
            .map(|c| ((ours.rgb[i * 3 + c] - reference.rgb[i * 3 + c]) as f64).powi(2))
            .sum::<f64>()
            / 3.0
    });
    println!(
        "against {dense} uniform samples: |Δopacity| mean {opacity:.5} max {opacity_max:.4}  |Δdepth| mean {depth_cm:.3} cm  colour PSNR {:.1} dB",
        i2sdf_eval::image_metrics::psnr_from_mse(mse.max(1e-12))
    );
    Ok(())
}
