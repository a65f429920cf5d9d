//! `i2sdf synth`: render a procedural room (or a TOML scene description) into a dataset in the
//! native format, with full ground truth, or in the paper's release format (`--format paper`: the
//! native dataset is rendered into a hidden scratch folder inside the staged output, loaded, written
//! out by `i2sdf_data::paper_write` and removed). Argument parsing and progress display only; the
//! work is in `i2sdf-synth` and `i2sdf-data`.

use anyhow::Context;
use i2sdf_data::{paper_write, DataError};
use i2sdf_synth::capture::{self, CaptureOptions, PoseNoise};
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
    /// Depth noise of the paper's Sec. 6.3 applied to the written depth: none, sigma or 3sigma
    /// (default none; sigma with --capture).
    #[arg(long)]
    pub depth_noise: Option<String>,
    /// Most scattering events per path (Russian roulette ends most paths far earlier).
    #[arg(long, default_value_t = SynthOptions::default().max_depth)]
    pub max_depth: u32,
    /// Render with the plain unbiased path tracer, without the default path-space regularization
    /// of glossy lobes after a diffuse bounce (which removes caustic fireflies at a small bias;
    /// transforms.json records which estimator made the images).
    #[arg(long)]
    pub unbiased: bool,
    /// A phone capture of the room: every degradation below at its phone default (JPEG 90, the
    /// opencv lens, depth grid 4, sigma depth noise, confidence, no normals, masks or HDR, pose
    /// noise 1,0.5); the flags with values override it. Same room, cameras and test views as
    /// without it, so that `eval --data` the exact room scores it.
    #[arg(long)]
    pub capture: bool,
    /// Frames as JPEG at this quality, 1-100 (none: PNG).
    #[arg(long, value_name = "Q|none")]
    pub jpeg_quality: Option<String>,
    /// Render every view through a phone lens, declared in transforms.json: opencv (k1 -0.08,
    /// k2 0.02, p1 0.0005, p2 -0.0003), fisheye (k1 0.05, k2 -0.02, k3 0.004) or none.
    #[arg(long)]
    pub lens: Option<String>,
    /// Sensor depth at the image size / N per axis, traced at the grid's pixel centres, as a
    /// 16-bit PNG in millimetres (none: full-resolution float EXR).
    #[arg(long, value_name = "N|none")]
    pub depth_grid: Option<String>,
    /// A confidence map (0/1/2) per depth map; its low samples (depth edges, grazing, far) get
    /// large errors.
    #[arg(long)]
    pub confidence: bool,
    /// Leave out the normal maps.
    #[arg(long)]
    pub no_normals: bool,
    /// Leave out the emitter masks.
    #[arg(long)]
    pub no_masks: bool,
    /// Leave out the HDR frames and the declared LDR exposure.
    #[arg(long)]
    pub no_hdr: bool,
    /// Perturb the training poses written to transforms.json by CM centimetres and DEG degrees
    /// (true poses in poses_true.json; test poses exact).
    #[arg(long, value_name = "CM,DEG")]
    pub pose_noise: Option<String>,
    /// The dataset's format: native (transforms.json) or paper (the paper's release:
    /// cameras_normalize.npz, image/, val/, … with mesh.ply a point cloud sampled on the GT mesh
    /// and all-ones material masks, as every material of a synthetic room is GGX). The relit test
    /// views, GT emitters and objects have no place in the paper's format and are not written.
    #[arg(long, value_enum, default_value = "native")]
    pub format: OutputFormat,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OutputFormat {
    Native,
    Paper,
}

/// Points per square metre of the GT surface in a paper-format `mesh.ply` (about 2 cm apart, finer
/// than the scoring threshold of the mesh metrics).
const CLOUD_DENSITY: f64 = 2500.0;

/// The capture options the paper's format cannot hold, refused before anything is rendered: its
/// cameras are pinhole, and its reader takes every pose as exact.
fn check_paper_capture(capture: &CaptureOptions) -> Result<(), DataError> {
    if !capture.lens.is_pinhole() {
        return Err(DataError::invalid(format!(
            "--format paper: the paper's format has pinhole cameras only, not the {} lens (add --lens none)",
            capture.lens.model_name()
        )));
    }
    if capture.pose_perturbation().is_some() {
        return Err(DataError::invalid(
            "--format paper: the paper's format has no way to declare perturbed poses (leave out --pose-noise, \
             or give --pose-noise 0,0 with --capture)",
        ));
    }
    Ok(())
}

/// The capture options of the flags: `--capture`'s phone defaults (or the exact room), then each
/// flag given.
fn capture_options(args: &Args) -> Result<(CaptureOptions, DepthNoise), DataError> {
    let mut c = if args.capture {
        CaptureOptions::phone()
    } else {
        CaptureOptions::default()
    };
    let mut depth_noise = if args.capture {
        capture::PHONE_DEPTH_NOISE
    } else {
        DepthNoise::None
    };
    if let Some(s) = &args.depth_noise {
        depth_noise = DepthNoise::parse(s)
            .ok_or_else(|| DataError::invalid(format!("--depth-noise: '{s}' is not none, sigma or 3sigma")))?;
    }
    if let Some(q) = &args.jpeg_quality {
        c.jpeg_quality = match q.as_str() {
            "none" => None,
            _ => Some(
                q.parse::<u8>()
                    .ok()
                    .filter(|q| (1..=100).contains(q))
                    .ok_or_else(|| DataError::invalid(format!("--jpeg-quality: '{q}' is not 1-100 or none")))?,
            ),
        };
    }
    if let Some(l) = &args.lens {
        c.lens = capture::lens_preset(l)?;
    }
    if let Some(g) = &args.depth_grid {
        c.depth_grid =
            match g.as_str() {
                "none" => None,
                _ => Some(g.parse::<usize>().ok().filter(|n| *n >= 1).ok_or_else(|| {
                    DataError::invalid(format!("--depth-grid: '{g}' is not a positive integer or none"))
                })?),
            };
    }
    if let Some(p) = &args.pose_noise {
        c.pose_noise = Some(PoseNoise::parse(p)?);
    }
    c.confidence |= args.confidence;
    c.normals &= !args.no_normals;
    c.masks &= !args.no_masks;
    c.hdr &= !args.no_hdr;
    Ok((c, depth_noise))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (capture, depth_noise) = capture_options(&args)?;
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
        capture,
    };
    opts.validate()?;
    if args.format == OutputFormat::Paper {
        check_paper_capture(&opts.capture)?;
    }
    let inputs: Vec<&std::path::Path> = args.scene.iter().map(PathBuf::as_path).collect();
    let staged = crate::cmd::output_dir(
        "--out",
        &args.out,
        args.force,
        "a dataset made by synth",
        &made_by_synth,
        &inputs,
        // The paper format's native scratch copy is on disk beside it until the end.
        Some(opts.estimated_bytes() * if args.format == OutputFormat::Paper { 2 } else { 1 }),
    )?;
    let bar = crate::progress::Step::new(
        &format!(
            "rendering {} ({} views, {}×{}, {} spp)",
            desc.name, opts.views, opts.width, opts.height, opts.spp
        ),
        (opts.views * opts.height) as u64,
        "rows",
    );
    let native_dir = match args.format {
        OutputFormat::Native => staged.path().to_path_buf(),
        OutputFormat::Paper => staged.path().join(NATIVE_SCRATCH),
    };
    let summary = generate(desc, &opts, &native_dir, &|| bar.inc(1))
        .with_context(|| format!("synthesizing {}", args.out.display()))?;
    bar.finish();
    if args.format == OutputFormat::Paper {
        convert_to_paper(&native_dir, staged.path())?;
    }
    staged.commit()?;
    println!(
        "wrote {} ({} format): {} train + {} test views, {} triangles, {} emitters, exposure {:.4}, rendered in {:.1} s",
        args.out.display(),
        match args.format {
            OutputFormat::Native => "native",
            OutputFormat::Paper => "the paper's",
        },
        summary.train_views,
        summary.test_views,
        summary.triangles,
        summary.emitters,
        summary.exposure,
        summary.render_seconds
    );
    Ok(())
}

/// The hidden folder of the staged output that a paper-format run renders the native dataset into
/// (hidden: the staging and `--force` checks ignore it; removed before the commit).
const NATIVE_SCRATCH: &str = ".native";

/// Loads the native dataset in `native` and writes it into `out` in the paper's format, with the
/// scene description beside it (provenance, and how `--force` recognizes the folder); then removes
/// `native`.
fn convert_to_paper(native: &std::path::Path, out: &std::path::Path) -> anyhow::Result<()> {
    let dataset = i2sdf_data::load(native)?;
    let options = paper_write::WriteOptions {
        point_cloud_density: Some(CLOUD_DENSITY),
    };
    let written = paper_write::write(&dataset, out, &options)?;
    std::fs::copy(native.join("scene.toml"), out.join("scene.toml"))
        .with_context(|| format!("copying {}", native.join("scene.toml").display()))?;
    std::fs::remove_dir_all(native).with_context(|| format!("removing {}", native.display()))?;
    for note in &written.left_out {
        crate::progress::line(&format!("not in the paper's format: {note}"));
    }
    Ok(())
}

/// Whether a folder is a dataset `synth` wrote, the only kind `--force` replaces: a native one
/// whose transforms.json names the generator, or a paper-format one (its cameras and scene.toml,
/// and nothing but the release's entries beside them).
fn made_by_synth(dir: &std::path::Path) -> bool {
    let native = std::fs::read_to_string(dir.join("transforms.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .is_some_and(|v| v["generator"]["name"] == "i2sdf synth");
    let paper = dir.join("cameras_normalize.npz").is_file()
        && dir.join("scene.toml").is_file()
        && crate::cmd::only_entries(dir, |name, _| {
            name == "scene.toml" || paper_write::RELEASE_ENTRIES.contains(&name)
        });
    native || paper
}
