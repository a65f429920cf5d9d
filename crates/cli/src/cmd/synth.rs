//! `i2sdf synth`: render a procedural room (or a TOML scene description) into a dataset in the
//! native format, with full ground truth. Argument parsing and progress display only; the work is
//! in `i2sdf-synth`.

use anyhow::Context;
use i2sdf_data::DataError;
use i2sdf_synth::tracer::Estimator;
use i2sdf_synth::{generate, DepthNoise, RoomPreset, SceneDesc, SynthOptions};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Output dataset folder (created; built aside and moved into place at the end).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if it holds a dataset made by `synth`.
    #[arg(long)]
    pub force: bool,
    /// Room preset: bedroom or livingroom.
    #[arg(long, default_value = "livingroom")]
    pub preset: String,
    /// Render this TOML scene description instead of a preset (see scene.toml in any output).
    #[arg(long, conflicts_with = "preset")]
    pub scene: Option<PathBuf>,
    /// Seed of the room layout, the cameras and the renderer's samples.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Image width in pixels.
    #[arg(long, default_value_t = 160)]
    pub width: usize,
    /// Image height in pixels.
    #[arg(long, default_value_t = 120)]
    pub height: usize,
    /// Total number of views; one in six is held out for testing (48 → 40 train + 8 test).
    #[arg(long, default_value_t = 48)]
    pub views: usize,
    /// Paths per pixel.
    #[arg(long, default_value_t = SynthOptions::default().spp)]
    pub spp: u32,
    /// Depth noise of the paper's Sec. 6.3 applied to the written depth: none, sigma or 3sigma.
    #[arg(long, default_value = "none")]
    pub depth_noise: String,
    /// Most scattering events per path (Russian roulette ends most paths far earlier).
    #[arg(long, default_value_t = SynthOptions::default().max_depth)]
    pub max_depth: u32,
    /// Render with the plain unbiased path tracer, without the default path-space regularization
    /// of glossy lobes after a diffuse bounce (which removes caustic fireflies at a small bias;
    /// transforms.json records which estimator made the images).
    #[arg(long)]
    pub unbiased: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let depth_noise = DepthNoise::parse(&args.depth_noise).ok_or_else(|| {
        DataError::invalid(format!(
            "--depth-noise: '{}' is not none, sigma or 3sigma",
            args.depth_noise
        ))
    })?;
    let (desc, preset) = match &args.scene {
        Some(path) => (SceneDesc::read(path)?, None),
        None => {
            let p = RoomPreset::parse(&args.preset)?;
            (p.build(args.seed), Some(p.name().to_string()))
        }
    };
    let opts = SynthOptions {
        width: args.width,
        height: args.height,
        views: args.views,
        spp: args.spp,
        seed: args.seed,
        max_depth: args.max_depth,
        depth_noise,
        preset,
        estimator: if args.unbiased {
            Estimator::UNBIASED
        } else {
            SynthOptions::default().estimator
        },
    };
    opts.validate()?;
    let inputs: Vec<&std::path::Path> = args.scene.iter().map(PathBuf::as_path).collect();
    let staged = crate::cmd::output_dir(
        "--out",
        &args.out,
        args.force,
        "a dataset made by synth",
        &made_by_synth,
        &inputs,
        Some(opts.estimated_bytes()),
    )?;
    let bar = crate::progress::Step::new(
        &format!(
            "rendering {} ({} views, {}×{}, {} spp)",
            desc.name, opts.views, opts.width, opts.height, opts.spp
        ),
        (opts.views * opts.height) as u64,
        "rows",
    );
    let summary = generate(desc, &opts, staged.path(), &|| bar.inc(1))
        .with_context(|| format!("synthesizing {}", args.out.display()))?;
    bar.finish();
    staged.commit()?;
    println!(
        "wrote {}: {} train + {} test views, {} triangles, {} emitters, exposure {:.4}, rendered in {:.1} s",
        args.out.display(),
        summary.train_views,
        summary.test_views,
        summary.triangles,
        summary.emitters,
        summary.exposure,
        summary.render_seconds
    );
    Ok(())
}

/// Whether a folder is a dataset `synth` wrote (its transforms.json names the generator), the
/// only kind `--force` replaces.
fn made_by_synth(dir: &std::path::Path) -> bool {
    std::fs::read_to_string(dir.join("transforms.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .is_some_and(|v| v["generator"]["name"] == "i2sdf synth")
}
