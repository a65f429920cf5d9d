//! Noise level of the ground-truth renders: renders one view of a preset at `spp` and at 4×`spp`
//! (independent seeds) and prints the PSNR between them, on the LDR encoding the dataset writes
//! and on the exposed HDR clamped to [0, 1].
//!
//! `cargo run --release -p i2sdf-synth --example noise_psnr -- [preset|scene.toml] [spp] [view] [seed]`

use glam::Vec3;
use i2sdf_synth::dataset::{auto_exposure, plan_views};
use i2sdf_synth::tracer::render_view;
use i2sdf_synth::{RenderScene, RoomPreset, SynthOptions};

fn main() {
    let args: Vec<String> = std::env::args().collect();
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
    let scene = RenderScene::new(desc);
    let views = plan_views(&scene, &opts).expect("cameras");
    let cam = &views[view].camera;
    let t = std::time::Instant::now();
    let lo = render_view(&scene, cam, spp, seed, view as u32, opts.max_depth, &|| {});
    let t_lo = t.elapsed().as_secs_f64();
    let hi = render_view(
        &scene,
        cam,
        4 * spp,
        seed + 1_000_003,
        view as u32,
        opts.max_depth,
        &|| {},
    );
    let exposure = auto_exposure(&[(&views[view], &hi)]);
    let ones = vec![Vec3::ONE; lo.emitters];
    let (a, b) = (lo.hdr(&ones), hi.hdr(&ones));
    let psnr = |f: &dyn Fn(f32) -> f32| {
        let mse = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (0..3).map(|c| ((f(x[c]) - f(y[c])) as f64).powi(2)).sum::<f64>())
            .sum::<f64>()
            / (3 * a.len()) as f64;
        10.0 * (1.0 / mse).log10()
    };
    let ldr = psnr(&|v| i2sdf_data::imageio::linear_to_srgb((v * exposure).clamp(0.0, 1.0)));
    let linear = psnr(&|v| (v * exposure).clamp(0.0, 1.0));
    println!("{name} view {view}: {spp} spp vs {} spp: PSNR {ldr:.2} dB (sRGB LDR), {linear:.2} dB (linear, clamped); {spp} spp took {t_lo:.1} s", 4 * spp);
}
