//! `i2sdf edit --run RUN --spec EDIT.toml --out DIR`: renders the dataset's views of the edited
//! intrinsic scene (stage 2's emitters, materials and the frozen SDF's surface, with the spec's
//! relight, material and insert ops) by Monte Carlo path tracing: `DIR/NAME.png` (tone-mapped as
//! the dataset's images), `DIR/NAME.exr` (linear HDR in the input images' units, as
//! `RUN/emitters.json`'s `emission`: divide by the dataset's exposure for its HDR units) and a
//! copy of the spec as `DIR/edit.toml`. An empty spec renders the unedited scene. Everything is
//! checked (run, spec, its textures and meshes, the arguments) before anything is written.
//! `--composite differential` forms the image by differential rendering, `--composite ratio` by
//! its ratio form where the edit dims (`i2sdf_edit::differential`).

use clap::Args as ClapArgs;
use i2sdf_data::edit_spec::EditOp;
use i2sdf_data::edit_spec::EditSpec;
use i2sdf_data::{imageio, Camera, DataError, ImageF32, Split};
use i2sdf_edit::{Composite, Denoiser, EditRenderer, EditSettings, RecoveredScene};
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// The stage-2 run to edit.
    #[arg(long)]
    pub run: PathBuf,
    /// The edit spec (TOML `[[op]]` list of relight, material and insert ops; docs/EDITING.md).
    #[arg(long)]
    pub spec: PathBuf,
    /// Output folder (created; built aside and moved into place when every view is written).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if it holds a previous edit's render.
    #[arg(long)]
    pub force: bool,
    /// Which views: test or train.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Only this view (its index within the split).
    #[arg(long, allow_negative_numbers = true, value_parser = super::view_index)]
    pub view: Option<usize>,
    /// Paths per pixel.
    #[arg(long, default_value_t = EditSettings::default().spp)]
    pub spp: u32,
    /// Most scattering events per path (Russian roulette from the third).
    #[arg(long, default_value_t = EditSettings::default().bounces)]
    pub bounces: u32,
    /// Denoise each render (an edge-avoiding à-trous filter guided by normal, depth, reflectance
    /// and the paths' variance, each emitter's light apart so that relighting stays exact).
    #[arg(long)]
    pub denoise: bool,
    /// Output width in pixels (with --height; the intrinsics are scaled to it).
    #[arg(long)]
    pub width: Option<usize>,
    /// Output height in pixels (with --width).
    #[arg(long)]
    pub height: Option<usize>,
    /// Seed of the path tracer's samples.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Marching-cubes resolution of the recovered surface (samples along the scene's longest side).
    #[arg(long, default_value_t = i2sdf_edit::MESH_RESOLUTION)]
    pub mesh_resolution: usize,
    /// Dataset (defaults to the one the run was trained on).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// How the image is formed: `path-traced` (the edited scene's render as it is),
    /// `differential` (stage 1's radiance field + the path-traced change, edited − unedited:
    /// the captured appearance where the edit leaves it; twice the path tracing unless the spec
    /// only relights) or `ratio` (as `differential`, but where the edit takes light away the
    /// radiance field × edited / unedited: the captured material kept under a dimmed light).
    #[arg(long, default_value = "path-traced")]
    pub composite: String,
    /// A camera path instead of the split's views (as `render --path`): frames plus `NAME.gif`
    /// (and `.mp4` with ffmpeg) of the edited scene.
    #[command(flatten)]
    pub path: super::render::PathArgs,
}

/// Largest output side, spp and bounce count accepted.
const MAX_SIDE: usize = 16384;
const MAX_SPP: u32 = 1 << 20;
const MAX_BOUNCES: u32 = 1024;

pub fn run(args: Args) -> anyhow::Result<()> {
    let (split, composite, size) = check_args(&args)?;
    let spec = EditSpec::read(&args.spec)?;
    let assets = spec.load_assets()?;
    if !i2sdf_model::RunDir::new(&args.run).stage2_checkpoint_path().is_file() {
        return Err(i2sdf_model::RunDir::new(&args.run).no_stage2().into());
    }
    let (data, dataset) = super::run_dataset(&args.run, args.data.as_deref())?;
    let frames: Vec<_> = dataset.split(split).collect();
    let shots = shots(&args, split, &frames, &dataset.bounds, size)?;
    let spec_text = std::fs::read(&args.spec).map_err(|e| DataError::file(&args.spec, e.to_string()))?;
    let pixels: u64 = shots.iter().map(|(_, c, _)| (c.width * c.height) as u64).sum();
    let staged = super::output_dir(
        "--out",
        &args.out,
        args.force,
        "an edit's render",
        &|dir| super::only_entries(dir, |name, is_dir| !is_dir && previous_edit(name)),
        &[&data, &args.spec],
        Some(pixels * 16 + spec_text.len() as u64),
    )?;
    let run = super::open_run(&args.run)?;
    check_relight_ops(&args.spec, &spec, &run.stage2()?.emitters)?;

    eprintln!("extracting the recovered surface at {}…", args.mesh_resolution);
    let recovered = RecoveredScene::of_run(&run, &dataset, args.mesh_resolution)?;
    let renderer = EditRenderer::new(&recovered, &spec, &assets, composite, &run.config.render);
    let out = staged.path().to_path_buf();
    imageio::write_bytes_atomic(&out.join("edit.toml"), &spec_text)?;
    let anim = render_shots(&args, &renderer, &shots, &out)?;
    let written = if args.path.path.is_some() {
        // The frames sit in DIR itself: the animation is DIR/edit.gif (and edit.mp4).
        args.path.animate_frames(&out, &out.join("edit"), &anim)?
    } else {
        Vec::new()
    };
    staged.commit()?;
    for p in written {
        println!("wrote {}", args.out.join(p.strip_prefix(&out).unwrap_or(&p)).display());
    }
    println!(
        "rendered {} edited {} view(s) ({} op(s), {} light(s), {}) into {}",
        shots.len(),
        split.name(),
        spec.ops.len(),
        renderer.lights(),
        composite.name(),
        args.out.display()
    );
    Ok(())
}

/// The arguments that need no file: the split, the composite and the output size (`None`: the
/// views' own), with spp, bounces and mesh resolution in range.
fn check_args(args: &Args) -> Result<(Split, Composite, Option<(usize, usize)>), DataError> {
    let split = Split::parse(&args.split)
        .ok_or_else(|| DataError::invalid(format!("--split {}: expected train or test", args.split)))?;
    if !(1..=MAX_SPP).contains(&args.spp) {
        return Err(DataError::invalid(format!(
            "--spp {}: must be in [1, {MAX_SPP}]",
            args.spp
        )));
    }
    if !(1..=MAX_BOUNCES).contains(&args.bounces) {
        return Err(DataError::invalid(format!(
            "--bounces {}: must be in [1, {MAX_BOUNCES}]",
            args.bounces
        )));
    }
    if !(16..=2048).contains(&args.mesh_resolution) {
        return Err(DataError::invalid(format!(
            "--mesh-resolution {}: must be in [16, 2048]",
            args.mesh_resolution
        )));
    }
    let composite =
        Composite::from_name(&args.composite).map_err(|e| DataError::invalid(format!("--composite {e}")))?;
    let size = match (args.width, args.height) {
        (None, None) => None,
        (Some(w), Some(h)) if (1..=MAX_SIDE).contains(&w) && (1..=MAX_SIDE).contains(&h) => Some((w, h)),
        (Some(_), Some(_)) => {
            return Err(DataError::invalid(format!(
                "--width/--height: each must be in [1, {MAX_SIDE}]"
            )))
        }
        _ => return Err(DataError::invalid("--width and --height go together")),
    };
    Ok((split, composite, size))
}

/// (name, camera, view index for the sampler) of every image to render: the chosen views of the
/// split (`--view`, else all), or the frames of `--path`; cameras resized to `size`.
fn shots(
    args: &Args,
    split: Split,
    frames: &[&i2sdf_data::Frame],
    bounds: &i2sdf_data::Bounds,
    size: Option<(usize, usize)>,
) -> Result<Vec<(String, Camera, u32)>, DataError> {
    if args.path.path.is_some() && args.view.is_some() {
        return Err(DataError::invalid("--view and --path: choose one"));
    }
    let views: Vec<usize> = match args.view {
        Some(v) if v < frames.len() => vec![v],
        Some(v) => {
            return Err(DataError::invalid(format!(
                "--view {v}: the {} split has {} views (0 to {})",
                split.name(),
                frames.len(),
                frames.len().saturating_sub(1)
            )))
        }
        None if frames.is_empty() => {
            return Err(DataError::invalid(format!("the {} split has no views", split.name())))
        }
        None => (0..frames.len()).collect(),
    };
    Ok(match &args.path.path {
        None => views
            .iter()
            .map(|&v| (frames[v].name.clone(), resized(&frames[v].camera, size), v as u32))
            .collect(),
        Some(_) => args
            .path
            .views(frames, bounds)?
            .into_iter()
            .enumerate()
            .map(|(i, (name, cam))| (name, resized(&cam, size), i as u32))
            .collect(),
    })
}

/// Renders every shot into `out` (`NAME.exr` and `NAME.png`) with a progress bar in rows;
/// returns the PNG frames of a path, for its animation (none otherwise).
fn render_shots(
    args: &Args,
    renderer: &EditRenderer,
    shots: &[(String, Camera, u32)],
    out: &std::path::Path,
) -> Result<Vec<ImageF32>, DataError> {
    let settings = EditSettings {
        spp: args.spp,
        bounces: args.bounces,
        seed: args.seed,
        denoise: args.denoise.then(Denoiser::default),
    };
    let rows: usize = shots.iter().map(|(_, c, _)| c.height).sum();
    let bar = crate::progress::Step::new(
        &format!("path tracing {} edited view(s)", shots.len()),
        (rows * renderer.passes()) as u64,
        "rows",
    );
    let mut anim = Vec::new();
    for (name, cam, v) in shots {
        let (hdr, ldr) = renderer.render(cam, &settings, *v, &|| bar.inc(1));
        imageio::write_exr(&out.join(format!("{name}.exr")), &hdr)?;
        imageio::write_png(&out.join(format!("{name}.png")), &ldr)?;
        if args.path.path.is_some() {
            anim.push(ldr);
        }
    }
    bar.finish();
    Ok(anim)
}

/// Whether a file of an existing folder is what `edit` writes there: the spec's copy, a view's
/// PNG and EXR, a path's animation.
fn previous_edit(name: &str) -> bool {
    name == "edit.toml" || matches!(name.rsplit_once('.'), Some((_, "png" | "exr" | "gif" | "mp4")))
}

/// Refuses a relight op when the run has no emitter for it to act on: its renders would be
/// those of the unedited scene, said nowhere.
fn check_relight_ops(
    spec_path: &std::path::Path,
    spec: &EditSpec,
    emitters: &i2sdf_model::EmitterTable,
) -> Result<(), DataError> {
    if !emitters.is_empty() {
        return Ok(());
    }
    match spec.ops.iter().position(|op| matches!(op, EditOp::Relight(_))) {
        Some(i) => Err(DataError::field(
            spec_path,
            format!("op[{i}]"),
            "a relight op, but the run's stage 2 found no emitters (RUN/emitters.json lists none): there is no light to change",
        )),
        None => Ok(()),
    }
}

/// The camera with its image resized to `size` (intrinsics scaled: the same field of view).
fn resized(cam: &Camera, size: Option<(usize, usize)>) -> Camera {
    let Some((w, h)) = size else {
        return cam.clone();
    };
    cam.resized(w, h)
}
