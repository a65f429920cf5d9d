//! `i2sdf render --run RUN --out DIR`: renders the dataset's views with the trained fields:
//! `rgb/NAME.png` (LDR as the dataset stores it), `depth/NAME.exr` (z-depth, world units) with a
//! `depth/NAME.png` preview, `normal/NAME.exr` (world-space) with a `normal/NAME.png` preview
//! ((n + 1)/2), `emitter/NAME.png` (probability).

use clap::Args as ClapArgs;
use i2sdf_data::{imageio, DataError, ImageF32, Split};
use i2sdf_model::images::render_volume_view;
use indicatif::ProgressBar;
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    #[arg(long)]
    pub run: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Which views: test or train.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Comma-separated maps: rgb, depth, normal, emitter.
    #[arg(long, default_value = "rgb,depth,normal,emitter")]
    pub what: String,
    /// Dataset (defaults to the one the run was trained on).
    #[arg(long)]
    pub data: Option<PathBuf>,
}

const MAPS: [&str; 4] = ["rgb", "depth", "normal", "emitter"];

pub fn run(args: Args) -> anyhow::Result<()> {
    let split = Split::parse(&args.split)
        .ok_or_else(|| DataError::invalid(format!("--split {}: expected train or test", args.split)))?;
    let what: Vec<&str> = args.what.split(',').map(str::trim).filter(|s| !s.is_empty()).collect();
    for w in &what {
        if !MAPS.contains(w) {
            return Err(DataError::invalid(format!(
                "--what {w}: not available (available: {}; albedo and roughness come with stage 2)",
                MAPS.join(", ")
            ))
            .into());
        }
    }
    let (scene, info) = super::load_run(&args.run)?;
    let data = args.data.clone().unwrap_or_else(|| PathBuf::from(&info.data));
    let dataset = i2sdf_data::load(&data)?;
    let frames: Vec<_> = dataset.split(split).collect();
    let settings = super::run_render_settings(&args.run)?;
    let bar = ProgressBar::new(frames.len() as u64);
    for f in frames {
        let v = render_volume_view(&scene, &settings, &f.camera);
        let dir = |m: &str| args.out.join(m);
        if what.contains(&"rgb") {
            imageio::write_png(&dir("rgb").join(format!("{}.png", f.name)), &v.rgb)?;
        }
        if what.contains(&"depth") {
            imageio::write_exr(&dir("depth").join(format!("{}.exr", f.name)), &v.depth)?;
            imageio::write_png(&dir("depth").join(format!("{}.png", f.name)), &depth_preview(&v.depth))?;
        }
        if what.contains(&"normal") {
            imageio::write_exr(&dir("normal").join(format!("{}.exr", f.name)), &v.normal)?;
            let mut vis = v.normal.clone();
            vis.data.iter_mut().for_each(|x| *x = 0.5 * (*x + 1.0));
            imageio::write_png(&dir("normal").join(format!("{}.png", f.name)), &vis)?;
        }
        if what.contains(&"emitter") {
            imageio::write_png(&dir("emitter").join(format!("{}.png", f.name)), &v.emitter)?;
        }
        bar.inc(1);
    }
    bar.finish();
    println!(
        "rendered {} {} views into {}",
        bar.position(),
        split.name(),
        args.out.display()
    );
    Ok(())
}

/// Depth scaled to [0, 1] by the view's own 99th percentile, near = bright.
fn depth_preview(depth: &ImageF32) -> ImageF32 {
    let mut sorted: Vec<f32> = depth.data.iter().copied().filter(|d| d.is_finite()).collect();
    sorted.sort_by(f32::total_cmp);
    let far = sorted.get(sorted.len() * 99 / 100).copied().unwrap_or(1.0).max(1e-6);
    let mut out = depth.clone();
    out.data.iter_mut().for_each(|d| *d = 1.0 - (*d / far).clamp(0.0, 1.0));
    out
}
