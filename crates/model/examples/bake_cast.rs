//! Secondary-ray casting in the frozen SDF, traced vs baked ([`FrozenScene::bake`]): speed and
//! agreement on a real run.
//!
//! `cargo run --release -p i2sdf-model --example bake_cast [RUN [DATASET [RESOLUTION [RAYS]]]]`
//! (defaults `/tmp/s2a`, `/tmp/room_new`, 256, 200000). Loads `RUN/checkpoint.safetensors` and
//! `RUN/emitters.json` (when present), takes the dataset's bounds, casts camera rays of a few
//! training views (strided pixels) to the surface, and from each hit (offset 2e-3 × scale along
//! the normal, as stage 2 does) one cosine-distributed direction; then times `cast` of those
//! secondary rays unbaked, the bake, and `cast` baked, and compares the hits.
//!
//! # Measured: see `FrozenScene::bake`'s doc (2 shared cores, `/tmp/s2a`: traced ~50k rays/s,
//! bake at 256 ≈ 5.5 s, baked ~400k rays/s, 99.4 % of the hits within 1 cm).

use i2sdf_data::{Radiometry, Split};
use i2sdf_model::{EmitterTable, FrozenScene, LabelledHit, NeuralScene, SceneQuery};
use i2sdf_render::Ray;
use rand::{Rng, SeedableRng};
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let run = PathBuf::from(args.get(1).map_or("/tmp/s2a", |s| s.as_str()));
    let data = PathBuf::from(args.get(2).map_or("/tmp/room_new", |s| s.as_str()));
    let resolution: usize = args.get(3).map_or(Ok(256), |s| s.parse())?;
    let want: usize = args.get(4).map_or(Ok(200_000), |s| s.parse())?;

    let (scene, _) = NeuralScene::load(&run.join("checkpoint.safetensors"))?;
    let dataset = i2sdf_data::load(&data)?;
    let emitters_path = run.join("emitters.json");
    let emitters = if emitters_path.exists() {
        EmitterTable::read_json(&emitters_path)?
    } else {
        EmitterTable::new(vec![], &[])
    };
    let scale = scene.normalization.scale as f32;
    let centre = glam::Vec3::from_array(scene.normalization.center.map(|v| v as f32));
    println!(
        "scene scale {scale}, bounds {:?}..{:?}, {} emitters",
        dataset.bounds.min,
        dataset.bounds.max,
        emitters.len()
    );
    let mut frozen = FrozenScene::new(&scene, &emitters, Radiometry::default());

    // Camera rays of a few training views, strided so that about `want` of them are cast.
    let views: Vec<_> = dataset.split(Split::Train).collect();
    let per_view = views.first().map_or(1, |f| f.camera.width * f.camera.height);
    let count = (1.15 * want as f64 / per_view as f64).ceil().max(1.0) as usize;
    let picked: Vec<_> = views.iter().step_by((views.len() / count).max(1)).take(count).collect();
    let pixels: usize = picked.iter().map(|f| f.camera.width * f.camera.height).sum();
    let stride = ((pixels as f64 / (1.15 * want as f64)).sqrt().floor() as usize).max(1);
    let mut cam_rays = Vec::new();
    for f in &picked {
        let g = f.camera.ray_generator();
        for y in (0..f.camera.height).step_by(stride) {
            for x in (0..f.camera.width).step_by(stride) {
                cam_rays.push(Ray::new(
                    g.origin,
                    g.dir(x as f32 + 0.5, y as f32 + 0.5),
                    0.0,
                    f32::INFINITY,
                ));
            }
        }
    }
    let t0 = Instant::now();
    let mut cam_hits = vec![None; cam_rays.len()];
    frozen.cast(&cam_rays, &mut cam_hits);
    println!(
        "{} camera rays of {} views (stride {stride}): {:.2} s traced",
        cam_rays.len(),
        picked.len(),
        t0.elapsed().as_secs_f64()
    );

    // Secondary rays: cosine-distributed about the normal, from just off the surface.
    let mut rng = rand_pcg::Pcg32::seed_from_u64(7);
    let rays: Vec<Ray> = cam_hits
        .iter()
        .flatten()
        .take(want)
        .map(|h| {
            let n = h.normal;
            let (u1, u2): (f32, f32) = (rng.gen(), rng.gen());
            let (r, phi) = (u1.sqrt(), std::f32::consts::TAU * u2);
            let (t, b) = n.any_orthonormal_pair();
            let d = (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize();
            Ray::new(h.position + n * (2e-3 * scale), d, 0.0, f32::INFINITY)
        })
        .collect();
    let n = rays.len();

    let time_cast = |f: &FrozenScene, label: &str| {
        let mut out = vec![None; n];
        let t = Instant::now();
        f.cast(&rays, &mut out);
        let s = t.elapsed().as_secs_f64();
        println!("{label}: {n} secondary rays in {s:.2} s = {:.0} rays/s", n as f64 / s);
        out
    };
    let traced = time_cast(&frozen, "traced");
    let t = Instant::now();
    frozen.bake(&dataset.bounds, resolution)?;
    println!("bake at {resolution}: {:.2} s", t.elapsed().as_secs_f64());
    let baked = time_cast(&frozen, "baked");
    let _ = time_cast(&frozen, "baked (again)");
    // The floor of the baked cast: one SDF + gradient query at every hit.
    let pts: Vec<f32> = baked
        .iter()
        .flatten()
        .flat_map(|h| ((h.position - centre) / scale).to_array())
        .collect();
    let m = pts.len() / 3;
    let (mut d, mut g) = (vec![0.0; m], vec![0.0; 3 * m]);
    let t = Instant::now();
    SceneQuery::new(&scene).sdf_gradient(&pts, &mut d, &mut g);
    let s = t.elapsed().as_secs_f64();
    println!(
        "one sdf_gradient query at the {m} hits: {s:.2} s = {:.0} points/s",
        m as f64 / s
    );
    report(&traced, &baked);
    frozen.baked_exact_normals = true;
    let exact = time_cast(&frozen, "baked, exact normals");
    report(&traced, &exact);
    Ok(())
}

fn report(traced: &[Option<LabelledHit>], baked: &[Option<LabelledHit>]) {
    let n = traced.len();
    let (mut both, mut only_traced, mut only_baked, mut none) = (0, 0, 0, 0);
    let (mut within_1cm, mut labels_differ, mut nearer) = (0, 0, 0);
    let (mut dts, mut angles, mut farther_t) = (Vec::new(), Vec::new(), Vec::new());
    for (a, b) in traced.iter().zip(baked) {
        match (a, b) {
            (Some(a), Some(b)) => {
                both += 1;
                let dp = (a.position - b.position).length();
                within_1cm += (dp <= 0.01) as usize;
                nearer += (dp > 0.01 && b.t < a.t) as usize;
                if dp > 0.01 && b.t > a.t {
                    farther_t.push(a.t);
                }
                labels_differ += (a.emitter != b.emitter) as usize;
                dts.push(dp);
                if dp <= 0.01 {
                    angles.push(a.normal.dot(b.normal).clamp(-1.0, 1.0).acos().to_degrees());
                }
            }
            (Some(_), None) => only_traced += 1,
            (None, Some(_)) => only_baked += 1,
            (None, None) => none += 1,
        }
    }
    let pct = |v: &mut Vec<f32>, q: f64| {
        v.sort_by(f32::total_cmp);
        v.get(((v.len() as f64 - 1.0) * q) as usize)
            .copied()
            .unwrap_or(f32::NAN)
    };
    println!("hits: both {both}, traced only {only_traced}, baked only {only_baked}, neither {none} (of {n})");
    println!(
        "baked hit within 1 cm of the traced one: {within_1cm} of {both} ({:.3} %; of the others {nearer} nearer, {} \
         farther); labels differ: {labels_differ}",
        100.0 * within_1cm as f64 / both.max(1) as f64,
        both - within_1cm - nearer
    );
    println!(
        "traced t of the farther ones: p10 {:.3} median {:.3} p90 {:.3}",
        pct(&mut farther_t, 0.1),
        pct(&mut farther_t, 0.5),
        pct(&mut farther_t, 0.9)
    );
    let over5 = angles.iter().filter(|&&a| a > 5.0).count();
    println!(
        "|Δx| median {:.2e} p99 {:.2e} max {:.2e}; normal angle (hits within 1 cm) median {:.3}° p99 {:.3}°, {over5} over 5°",
        pct(&mut dts, 0.5),
        pct(&mut dts, 0.99),
        pct(&mut dts, 1.0),
        pct(&mut angles, 0.5),
        pct(&mut angles, 0.99)
    );
}
