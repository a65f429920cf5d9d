//! Noise level of the ground-truth renders: renders one view of a preset at `spp` and at 4×`spp`
//! (independent seeds) and prints the PSNR between them, on the LDR encoding the dataset writes
//! and on the exposed HDR clamped to [0, 1], and counts firefly pixels of each (LDR luminance above
//! the 3×3 median by more than 0.3). With an output directory, writes both LDR images there.
//! `--unbiased` renders with the plain path tracer instead of the dataset's default estimator,
//! `--regularize=RHO` with another regularization roughness. With a biased estimator it also
//! renders the low-spp image with the same samples through the unbiased estimator and prints the
//! PSNR between the two (the bias, nearly free of noise since the paths agree until a vertex is
//! regularized).
//!
//! `--relit=SPEC.toml` scores the view relit by that edit spec (a dataset's `relight/*.toml`: the
//! emitters' gains applied to both renders, as `synth` writes its relit test views) and
//! `--exposure=E` exposes with E (a dataset's `ldr.exposure`) instead of the view's own.
//!
//! `cargo run --release -p i2sdf-synth --example noise_psnr -- [preset|scene.toml] [spp] [view] [seed] [out_dir] [--unbiased] [--regularize=RHO] [--relit=SPEC.toml] [--exposure=E]`

use glam::Vec3;
use i2sdf_eval::image_metrics::psnr_from_mse;
use i2sdf_render::render_view;
use i2sdf_synth::dataset::{auto_exposure, plan_views};
use i2sdf_synth::tracer::Estimator;
use i2sdf_synth::{RenderScene, RoomPreset, SynthOptions};

fn main() {
    let mut args: Vec<String> = std::env::args().collect();
    let unbiased = args.iter().any(|a| a == "--unbiased");
    let rho: Option<f32> = args
        .iter()
        .find_map(|a| a.strip_prefix("--regularize="))
        .map(|r| r.parse().expect("--regularize=ROUGHNESS"));
    let relit: Option<String> = args.iter().find_map(|a| a.strip_prefix("--relit=")).map(str::to_string);
    let fixed_exposure: Option<f32> = args
        .iter()
        .find_map(|a| a.strip_prefix("--exposure="))
        .map(|e| e.parse().expect("--exposure=E"));
    args.retain(|a| !a.starts_with("--"));
    let name = args.get(1).map(String::as_str).unwrap_or("livingroom");
    let spp: u32 = args
        .get(2)
        .map_or(SynthOptions::default().spp, |s| s.parse().expect("spp"));
    let view: usize = args.get(3).map_or(0, |s| s.parse().expect("view"));
    let seed: u64 = args.get(4).map_or(0, |s| s.parse().expect("seed"));
    let opts = SynthOptions {
        spp,
        seed,
        ..Default::default()
    };
    // A preset name, or a scene description file.
    let desc = if name.ends_with(".toml") {
        i2sdf_synth::SceneDesc::read(std::path::Path::new(name)).expect("scene")
    } else {
        RoomPreset::parse(name).expect("preset").build(seed)
    };
    let mut scene = RenderScene::new(desc);
    scene.estimator = if unbiased { Estimator::UNBIASED } else { opts.estimator };
    if let Some(rho) = rho {
        scene.estimator.regularize_roughness = Some(rho);
    }
    let views = plan_views(&scene, &opts).expect("cameras");
    let cam = &views[view].camera;
    let t = std::time::Instant::now();
    let render = |scene: &RenderScene, spp: u32, seed: u64| {
        render_view(
            &scene.scene(),
            cam,
            &scene.view_settings(spp, seed, view as u32, opts.max_depth),
            &|| {},
        )
    };
    let lo = render(&scene, spp, seed);
    let t_lo = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let hi = render(&scene, 4 * spp, seed + 1_000_003);
    let t_hi = t.elapsed().as_secs_f64();
    let exposure = fixed_exposure.unwrap_or_else(|| auto_exposure(&[(&views[view], &hi)]));
    let gains = match &relit {
        Some(spec) => {
            let spec = i2sdf_data::EditSpec::read(std::path::Path::new(spec)).expect("relight spec");
            i2sdf_synth::edit::emitter_gains(&spec, &scene.emitters)
        }
        None => vec![Vec3::ONE; lo.emitters],
    };
    let (a, b) = (lo.hdr(&gains), hi.hdr(&gains));
    let psnr = |f: &dyn Fn(f32) -> f32| {
        let mse = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (0..3).map(|c| ((f(x[c]) - f(y[c])) as f64).powi(2)).sum::<f64>())
            .sum::<f64>()
            / (3 * a.len()) as f64;
        psnr_from_mse(mse)
    };
    let ldr = psnr(&|v| i2sdf_data::imageio::linear_to_srgb((v * exposure).clamp(0.0, 1.0)));
    let linear = psnr(&|v| (v * exposure).clamp(0.0, 1.0));
    println!("estimator: {:?}", scene.estimator);
    println!("{name} view {view}: {spp} spp vs {} spp: PSNR {ldr:.2} dB (sRGB LDR), {linear:.2} dB (linear, clamped); {spp} spp took {t_lo:.1} s, {} spp {t_hi:.1} s", 4 * spp, 4 * spp);
    let (w, h) = (lo.width, lo.height);
    let ldr_lo = i2sdf_synth::output::ldr_image(w, h, &a, exposure);
    let ldr_hi = i2sdf_synth::output::ldr_image(w, h, &b, exposure);
    let (f_lo, f_hi) = (fireflies(&ldr_lo, 0.3), fireflies(&ldr_hi, 0.3));
    let (g_lo, g_hi) = (fireflies(&ldr_lo, 0.1), fireflies(&ldr_hi, 0.1));
    println!(
        "firefly pixels (LDR luminance > 3×3 median + 0.3 | + 0.1): {} | {} at {spp} spp, {} | {} at {} spp; \
         of these not in the {} spp image (noise, not structure): {} | {}",
        f_lo.len(),
        g_lo.len(),
        f_hi.len(),
        g_hi.len(),
        4 * spp,
        4 * spp,
        f_lo.iter().filter(|p| !f_hi.contains(p)).count(),
        g_lo.iter().filter(|p| !g_hi.contains(p)).count(),
    );
    if scene.estimator != Estimator::UNBIASED {
        // The same samples through the unbiased estimator: paths agree until regularization
        // changes a BRDF, so the difference is mostly the bias, not noise.
        let biased = scene.estimator;
        scene.estimator = Estimator::UNBIASED;
        let ub = render(&scene, spp, seed);
        scene.estimator = biased;
        let c = ub.hdr(&gains);
        let ldr = |v: f32| i2sdf_data::imageio::linear_to_srgb((v * exposure).clamp(0.0, 1.0));
        let mse = a
            .iter()
            .zip(&c)
            .map(|(x, y)| (0..3).map(|i| ((ldr(x[i]) - ldr(y[i])) as f64).powi(2)).sum::<f64>())
            .sum::<f64>()
            / (3 * a.len()) as f64;
        let mean_diff = a.iter().zip(&c).map(|(x, y)| (ldr(x.y) - ldr(y.y)) as f64).sum::<f64>() / a.len() as f64;
        println!(
            "same samples, unbiased estimator: PSNR {:.2} dB (sRGB LDR), mean LDR difference (G) {mean_diff:+.5}, fireflies {}",
            psnr_from_mse(mse),
            fireflies(&i2sdf_synth::output::ldr_image(w, h, &c, exposure), 0.3).len()
        );
    }
    if let Some(dir) = args.get(5) {
        let dir = std::path::Path::new(dir);
        std::fs::create_dir_all(dir).expect("output directory");
        i2sdf_data::imageio::write_png(&dir.join(format!("view{view}_{spp}spp.png")), &ldr_lo).expect("png");
        i2sdf_data::imageio::write_png(&dir.join(format!("view{view}_{}spp.png", 4 * spp)), &ldr_hi).expect("png");
    }
}

/// Pixels whose (sRGB-encoded) luminance exceeds the median of their 3×3 neighbourhood by more
/// than `threshold`: isolated bright speckles, not edges (a median keeps edges). Thin bright
/// structures (a lit rod one pixel wide) count too, which is why the caller also reports the
/// pixels that are not flagged in the 4× spp render.
fn fireflies(img: &i2sdf_data::imageio::ImageF32, threshold: f32) -> Vec<(usize, usize)> {
    let lum = |x: usize, y: usize| i2sdf_render::color::luminance(Vec3::from_slice(img.pixel(x, y)));
    let mut n = Vec::new();
    for y in 1..img.height - 1 {
        for x in 1..img.width - 1 {
            let mut nb: Vec<f32> = (0..9).map(|i| lum(x + i % 3 - 1, y + i / 3 - 1)).collect();
            nb.sort_by(f32::total_cmp);
            if lum(x, y) > nb[4] + threshold {
                n.push((x, y));
            }
        }
    }
    n
}
