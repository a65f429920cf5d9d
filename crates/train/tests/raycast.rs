//! Ray casting in the trained SDF: sphere tracing against the alternative of the extracted mesh
//! in the BVH (refined by one Newton step on the SDF), both measured against the volume-rendered
//! depth and the fixture's analytic room on a tiny scene trained long enough for β to sharpen.
//! Ignored by default (a minute of training); the figures of the docs come from
//! `cargo test --release -p i2sdf-train --test raycast -- --ignored --nocapture`.

mod common;

use glam::Vec3;
use i2sdf_data::fixture;
use i2sdf_model::SceneQuery;
use i2sdf_render::Bvh;
use i2sdf_train::config::TrainConfig;
use i2sdf_train::driver::Trainer;
use i2sdf_train::maps::TrainingMaps;
use i2sdf_train::stage1::render_settings;
use i2sdf_train::stage1::Stage1;
use rayon::prelude::*;
use std::time::Instant;

#[test]
#[ignore]
fn sphere_tracing_against_the_mesh_in_the_bvh() {
    let (_dir, ds) = common::dataset();
    let maps = TrainingMaps::prepare(&ds, &TrainConfig::default()).unwrap();
    let config = TrainConfig::load(
        None,
        &[
            "train.iterations=800".into(),
            "train.rays=512".into(),
            "train.eikonal_points=256".into(),
            "train.bubble_points=256".into(),
            "train.lr_warmup=20".into(),
            "train.lr_beta=0.05".into(),
            "model.hash_levels=8".into(),
            "model.hash_log2_table=14".into(),
            "model.hash_finest_resolution=128".into(),
            "sampling.samples=24".into(),
            "sampling.coarse=24".into(),
        ],
    )
    .unwrap();
    let settings = render_settings(&config);
    let mut trainer = Trainer::new(Stage1::new(&ds, config, &maps));
    while !trainer.done() {
        trainer.step().unwrap();
    }
    let scene = &trainer.stage.scene;
    let beta = scene.beta.value() as f64;
    let scale = scene.normalization.scale;
    let rays = common::view_rays(&ds);
    let n = rays.origins.len();
    let (t_volume, opacity, volume_rate) = common::volume_depths(scene, &settings, &rays);

    // Sphere tracing.
    let (hits, cast_rate) = common::cast(scene, &rays, 5);
    let a = common::agreement(scene, &rays, &hits, &t_volume, &opacity);
    eprintln!("β = {beta:.4}, scale {scale:.3}");
    eprintln!("sphere tracing: {a}");
    eprintln!(
        "  world units: median {:.5} p95 {:.5}; {cast_rate:.0} rays/s (volume renderer: {volume_rate:.0} rays/s)",
        a.median * scale,
        a.p95 * scale
    );

    // The mesh in the BVH: marching cubes (world units) + build, then closest hits, then one
    // Newton step on the SDF along the ray (t ← t − d / (∇d · v)).
    for resolution in [64usize, 128, 256] {
        let t0 = Instant::now();
        let mesh = i2sdf_model::extract_mesh(scene, &ds.bounds, resolution).unwrap();
        let t_mc = t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let bvh = Bvh::build(&mesh);
        let t_build = t0.elapsed().as_secs_f64();
        let mut t_mesh = vec![f32::NAN; n];
        let t0 = Instant::now();
        let reps = 5;
        for _ in 0..reps {
            t_mesh.par_chunks_mut(1024).enumerate().for_each(|(c, out)| {
                let mut stack = Vec::new();
                for (k, t) in out.iter_mut().enumerate() {
                    let (o, d) = rays.world[c * 1024 + k];
                    let (o, d) = (o.as_vec3(), d.as_vec3());
                    *t = bvh
                        .intersect(
                            Vec3::new(o.x, o.y, o.z),
                            Vec3::new(d.x, d.y, d.z),
                            1e-4,
                            f32::INFINITY,
                            &mut stack,
                        )
                        .map_or(f32::NAN, |h| h.t / scale as f32);
                }
            });
        }
        let bvh_rate = (reps * n) as f64 / t0.elapsed().as_secs_f64();
        // Newton refinement on the SDF: one batch with the gradient.
        let t0 = Instant::now();
        let mut pts = Vec::with_capacity(n * 3);
        for i in 0..n {
            let (o, d) = (rays.origins[i], rays.dirs[i]);
            let t = if t_mesh[i].is_finite() { t_mesh[i] } else { 0.0 };
            pts.extend_from_slice(&[o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
        }
        let (mut dist, mut grad) = (vec![0.0; n], vec![0.0; n * 3]);
        SceneQuery::new(scene).sdf_gradient(&pts, &mut dist, &mut grad);
        let refined: Vec<f32> = (0..n)
            .map(|i| {
                let g = &grad[i * 3..i * 3 + 3];
                let dv = g[0] * rays.dirs[i][0] + g[1] * rays.dirs[i][1] + g[2] * rays.dirs[i][2];
                if t_mesh[i].is_finite() && dv.abs() > 1e-3 {
                    t_mesh[i] - dist[i] / dv
                } else {
                    t_mesh[i]
                }
            })
            .collect();
        let refine_rate = n as f64 / t0.elapsed().as_secs_f64();
        for (what, ts) in [("mesh", &t_mesh), ("mesh + Newton", &refined)] {
            let (mut dv, mut dc, mut gt) = (Vec::new(), Vec::new(), Vec::new());
            for i in 0..n {
                if opacity[i] < 0.9 || !ts[i].is_finite() || !hits[i].hit {
                    continue;
                }
                dv.push((ts[i] - t_volume[i]).abs() as f64);
                dc.push((ts[i] - hits[i].t).abs() as f64);
                let (g, _) = fixture::room_hit(rays.world[i].0, rays.world[i].1);
                gt.push((ts[i] as f64 * scale - g).abs());
            }
            eprintln!(
                "{resolution}³ {what}: {} of {n} rays; vs volume median {:.5} p95 {:.5}; vs sphere tracing median \
                 {:.5} p95 {:.5} (normalized); vs the room median {:.4} p95 {:.4} (world)",
                dv.len(),
                common::quantile(&mut dv, 0.5),
                common::quantile(&mut dv, 0.95),
                common::quantile(&mut dc, 0.5),
                common::quantile(&mut dc, 0.95),
                common::quantile(&mut gt, 0.5),
                common::quantile(&mut gt, 0.95),
            );
        }
        eprintln!(
            "{resolution}³: marching cubes {t_mc:.2} s, BVH build {t_build:.3} s ({} triangles), {bvh_rate:.0} rays/s, \
             Newton step {refine_rate:.0} rays/s",
            mesh.faces.len()
        );
    }
    assert!(a.counted * 10 > 9 * n && a.misses * 100 < n, "{a}");
    assert!(a.median < 0.4 * beta && a.p95 < 1.5 * beta, "{a}");
}
