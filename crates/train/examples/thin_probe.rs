//! Why a thin or small object is missing (issues 12, 29): for each thin, suspended or small shape of a synthetic
//! dataset (its `scene.toml`), which training pixels see it (their depth lands within 1 cm of the
//! shape's surface), what the trained fields make of those pixels, and what the smooth
//! large surfaces look like beside them:
//! - pixels: how many see the shape, out of all training pixels, and in how many views;
//! - SDF: the trained |SDF| at their back-projected depth points (the bubble loss's points), in cm;
//! - depth: the rendered depth against the GT at those pixels (share within 2 cm);
//! - colour: the rendered colour's L1 error there against the mean over all probed pixels;
//! - PDF: where the checkpoint was written inside the bubble step, the share of the error-guided
//!   PDF maps' mass on those pixels, and so the bubble points per iteration that land on them.
//!
//! `cargo run --release -p i2sdf-train --example thin_probe -- RUN DATA [max pixels per shape]`

use i2sdf_model::renderer::{self, RenderWorkspace};
use i2sdf_model::{NeuralScene, RunDir};
use i2sdf_nn::sdf::SdfInferWorkspace;
use i2sdf_synth::scene::SceneDesc;
use i2sdf_train::config::TrainConfig;
use i2sdf_train::maps::TrainingMaps;
use i2sdf_train::stage1::rays::train_images;
use i2sdf_train::stage1::render_settings;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// The PDF maps' per-pixel values of a bubble-step checkpoint (`adam.pdf_maps.value`), read from
/// the safetensors header directly (the tensor is trainer state that inference loads skip).
fn pdf_values(path: &std::path::Path) -> Result<Option<Vec<f32>>, Box<dyn std::error::Error>> {
    let bytes = std::fs::read(path)?;
    let n = u64::from_le_bytes(bytes[..8].try_into()?) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n])?;
    let Some(t) = header.get("adam.pdf_maps.value") else {
        return Ok(None);
    };
    let off = &t["data_offsets"];
    let (a, b) = (
        off[0].as_u64().unwrap_or(0) as usize,
        off[1].as_u64().unwrap_or(0) as usize,
    );
    let data = &bytes[8 + n + a..8 + n + b];
    Ok(Some(
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
    ))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: thin_probe RUN DATA [max pixels per shape]".into());
    }
    let max_pixels: usize = args.get(3).map_or(Ok(3000), |s| s.parse())?;
    let run = RunDir::new(std::path::Path::new(&args[1]));
    let data = std::path::Path::new(&args[2]);
    let desc = SceneDesc::read(&data.join("scene.toml"))?;
    let dataset = i2sdf_data::load(data)?;
    let config = TrainConfig::load(Some(&run.config_path()), &[])?;
    let settings = render_settings(&config);
    let (scene, _) = NeuralScene::load(&run.checkpoint_path())?;
    let norm = &dataset.normalization;
    let scale = norm.scale as f32;
    let images = train_images(&dataset, &TrainingMaps::prepare(&dataset, &config)?);
    let total: usize = images.iter().map(|i| i.pixels()).sum();
    // The thin, suspended and small shapes, grouped by object.
    let groups = desc.solid_shapes_tagged(&["thin", "suspended", "small"]);
    // A random sample of all training pixels with depth, for the baseline colour error.
    let mut rng = Pcg64::seed_from_u64(3);
    let mut everywhere: Vec<(usize, usize)> = (0..max_pixels)
        .map(|_| {
            let i = rng.gen_range(0..images.len());
            (i, rng.gen_range(0..images[i].pixels()))
        })
        .collect();
    everywhere.retain(|&(i, p)| images[i].depth[p] > 0.0);
    let probe = |pixels: &[(usize, usize)]| -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        // (|SDF| at the depth points in cm, |depth error| in cm, colour L1) per pixel.
        let mut pts = Vec::new();
        let (mut origins, mut dirs) = (Vec::new(), Vec::new());
        for &(i, p) in pixels {
            pts.extend_from_slice(&images[i].surface_point(p).unwrap());
            origins.push(images[i].origin);
            dirs.push(images[i].dirs[p]);
        }
        let mut sdf = vec![0.0; pixels.len()];
        scene
            .sdf
            .infer(&pts, &mut SdfInferWorkspace::default(), &mut sdf, None, None);
        let mut ws = RenderWorkspace::default();
        let (mut depth_err, mut rgb_err) = (Vec::new(), Vec::new());
        for c in (0..pixels.len()).step_by(256) {
            let r = c..(c + 256).min(pixels.len());
            renderer::forward::<Pcg64>(
                &scene,
                &settings,
                &origins[r.clone()],
                &dirs[r.clone()],
                &[],
                &mut ws,
                None,
            );
            for (k, &(i, p)) in pixels[r].iter().enumerate() {
                depth_err.push((ws.out.depth[k] - images[i].depth[p]).abs() * scale * 100.0);
                let gt = images[i].rgb[p];
                rgb_err.push((0..3).map(|ch| (ws.out.rgb[k * 3 + ch] - gt[ch]).abs()).sum::<f32>() / 3.0);
            }
        }
        (
            sdf.iter().map(|d| d.abs() * scale * 100.0).collect(),
            depth_err,
            rgb_err,
        )
    };
    let median = |v: &[f32]| {
        let mut v = v.to_vec();
        v.sort_by(f32::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f32::NAN)
    };
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
    let share = |v: &[f32], t: f32| v.iter().filter(|x| **x <= t).count() as f32 / v.len().max(1) as f32;
    let (_, _, base_rgb) = probe(&everywhere);
    let pdf = pdf_values(&run.checkpoint_path())?;
    let offsets: Vec<usize> = images
        .iter()
        .scan(0, |o, im| {
            let start = *o;
            *o += im.pixels();
            Some(start)
        })
        .collect();
    let pdf_total: f64 = pdf.as_ref().map_or(0.0, |v| v.iter().map(|&x| x as f64).sum());
    if let Some(v) = &pdf {
        println!(
            "PDF maps: {} active pixels of {}, {} bubble points per iteration",
            v.iter().filter(|x| **x > 0.0).count(),
            v.len(),
            config.train.bubble_points
        );
    }
    println!(
        "run {} (β {:.2} cm), {} training pixels; colour L1 over {} random pixels: mean {:.4}",
        args[1],
        scene.beta.value() * scale * 100.0,
        total,
        everywhere.len(),
        mean(&base_rgb)
    );
    println!("object                 pixels   share    views  |SDF| med cm  ≤1cm   depth ≤2cm  colour L1 (× mean)   PDF share  bubble pts/it");
    for (name, shapes) in &groups {
        let mut seen = Vec::new();
        let mut views = std::collections::HashSet::new();
        for (i, im) in images.iter().enumerate() {
            for p in 0..im.pixels() {
                let Some(x) = im.surface_point(p) else { continue };
                let w = norm
                    .to_world(glam::DVec3::new(x[0] as f64, x[1] as f64, x[2] as f64))
                    .as_vec3();
                let near = shapes
                    .iter()
                    .any(|&s| desc.shapes[s].geometry.distance(w).is_some_and(|d| d.abs() < 0.01));
                if near {
                    seen.push((i, p));
                    views.insert(i);
                }
            }
        }
        let found = seen.len();
        let mass: f64 = pdf
            .as_ref()
            .map_or(0.0, |v| seen.iter().map(|&(i, p)| v[offsets[i] + p] as f64).sum());
        seen.shuffle(&mut rng);
        seen.truncate(max_pixels);
        let (sdf, depth, rgb) = probe(&seen);
        println!(
            "{name:22} {found:7} {:7.4}% {:6}   {:8.2}   {:5.2}   {:8.2}     {:.4} ({:.1}×)   {:8.4}%  {:6.2}",
            100.0 * found as f64 / total as f64,
            views.len(),
            median(&sdf),
            share(&sdf, 1.0),
            share(&depth, 2.0),
            mean(&rgb),
            mean(&rgb) / mean(&base_rgb),
            100.0 * mass / pdf_total.max(1e-30),
            mass / pdf_total.max(1e-30) * config.train.bubble_points as f64
        );
    }
    Ok(())
}
