//! `i2sdf render --run RUN --out DIR`: renders the dataset's views with the trained fields:
//! `rgb/NAME.png` (LDR as the dataset stores it), `depth/NAME.exr` (z-depth, world units) with a
//! `depth/NAME.png` preview, `normal/NAME.exr` (world-space) with a `normal/NAME.png` preview
//! ((n + 1)/2), `emitter/NAME.png` (probability). With stage 2 (`RUN/stage2.safetensors`), from
//! one Monte Carlo re-render per view (`--spp` paths per pixel): `albedo/NAME.exr` (Kd, linear)
//! with an sRGB-encoded `albedo/NAME.png`, `specular/` (Ks) likewise, `roughness/NAME.exr` and
//! `.png` (ρ as is), `emission/NAME.exr` (L\[k\] where the pixel sees emitter k, else 0; linear
//! image units) with a `.png` tone-mapped as the dataset's images, `rerender/NAME.exr` (linear
//! HDR, image units) with `rerender/NAME.png` in the dataset's tone mapping (compares with its
//! PNGs).
//!
//! `--path orbit|interpolate --frames N` renders a camera path instead of the dataset's views
//! (an orbit inside the room, or through the split's views — or `--keyframes` of them — like the
//! paper's view-interpolation videos): `MAP/frame_NNNN.*` as above, plus `MAP.gif` (animated,
//! looping) and `MAP.mp4` when `ffmpeg` is on the PATH.

use clap::Args as ClapArgs;
use i2sdf_data::{animation, camera_path, Camera, DataError, ImageF32, PathKind, Split};
use i2sdf_model::images::{stage1_maps, stage2_maps, write_maps, STAGE1_MAPS, STAGE2_MAPS};
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// The trained run to render.
    #[arg(long)]
    pub run: PathBuf,
    /// Output folder (created; built aside and moved into place when every view is written).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if it holds a previous render.
    #[arg(long)]
    pub force: bool,
    /// Which views: test or train.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Comma-separated maps: rgb, depth, normal, emitter (stage 1); albedo, specular, roughness,
    /// emission, rerender (stage 2).
    #[arg(long, default_value = "rgb,depth,normal,emitter")]
    pub what: String,
    /// Paths per pixel of the stage-2 re-render (albedo, specular, roughness, emission, rerender).
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Dataset (defaults to the one the run was trained on).
    #[arg(long)]
    pub data: Option<PathBuf>,
    #[command(flatten)]
    pub path: PathArgs,
}

/// A camera path instead of the dataset's views (shared by `render` and `edit`).
#[derive(ClapArgs, Clone, Debug)]
pub struct PathArgs {
    /// Render a camera path: `orbit` (a turn inside the room) or `interpolate` (through the
    /// split's views, or --keyframes of them).
    #[arg(long)]
    pub path: Option<String>,
    /// Frames of the path.
    #[arg(long, default_value_t = 48)]
    pub frames: usize,
    /// Comma-separated indices (within the split) of the views to interpolate through.
    #[arg(long)]
    pub keyframes: Option<String>,
    /// Frames per second of the animation.
    #[arg(long, default_value_t = 24)]
    pub fps: u32,
    /// Draw through an undistorted pinhole camera (the dataset's intrinsics and poses). By
    /// default views go through the dataset's own lens model, so they line up with its images.
    #[arg(long)]
    pub pinhole: bool,
}

impl Default for PathArgs {
    /// No path (the dataset's views); the flags' defaults otherwise.
    fn default() -> Self {
        PathArgs {
            path: None,
            frames: 48,
            keyframes: None,
            fps: 24,
            pinhole: false,
        }
    }
}

/// Longest path accepted (a day of video at 24 fps is far beyond any use).
const MAX_FRAMES: usize = 100_000;

impl PathArgs {
    /// The views to render, named: the split's frames as they are, or the path's frames.
    pub fn views(
        &self,
        frames: &[&i2sdf_data::Frame],
        bounds: &i2sdf_data::Bounds,
    ) -> Result<Vec<(String, Camera)>, DataError> {
        let views = self.views_through_lens(frames, bounds)?;
        Ok(match self.pinhole {
            true => views.into_iter().map(|(n, c)| (n, c.pinhole())).collect(),
            false => views,
        })
    }

    fn views_through_lens(
        &self,
        frames: &[&i2sdf_data::Frame],
        bounds: &i2sdf_data::Bounds,
    ) -> Result<Vec<(String, Camera)>, DataError> {
        let Some(kind) = &self.path else {
            return Ok(frames.iter().map(|f| (f.name.clone(), f.camera.clone())).collect());
        };
        let kind = PathKind::from_name(kind).map_err(|e| DataError::invalid(format!("--path {e}")))?;
        if !(1..=MAX_FRAMES).contains(&self.frames) {
            return Err(DataError::invalid(format!(
                "--frames {}: must be in [1, {MAX_FRAMES}]",
                self.frames
            )));
        }
        if !(1..=240).contains(&self.fps) {
            return Err(DataError::invalid(format!("--fps {}: must be in [1, 240]", self.fps)));
        }
        let keys: Vec<Camera> = match &self.keyframes {
            None => frames.iter().map(|f| f.camera.clone()).collect(),
            Some(list) => list
                .split(',')
                .map(|k| {
                    k.trim()
                        .parse::<usize>()
                        .ok()
                        .and_then(|i| frames.get(i))
                        .map(|f| f.camera.clone())
                        .ok_or_else(|| {
                            DataError::invalid(format!(
                                "--keyframes {list}: {k:?} is not a view index of the split (0 to {})",
                                frames.len().saturating_sub(1)
                            ))
                        })
                })
                .collect::<Result<_, _>>()?,
        };
        let path = camera_path(kind, &keys, bounds, self.frames)?;
        Ok(path
            .into_iter()
            .enumerate()
            .map(|(i, c)| (format!("frame_{i:04}"), c))
            .collect())
    }

    /// After a path's frames are written: `DIR/MAP.gif` of each map's PNG frames (in `DIR/MAP/`)
    /// and, with ffmpeg, `DIR/MAP.mp4`. Returns what was written.
    pub fn animate(&self, out: &std::path::Path, maps: &[(String, Vec<ImageF32>)]) -> Result<Vec<PathBuf>, DataError> {
        let mut written = Vec::new();
        for (m, frames) in maps {
            written.extend(self.animate_frames(&out.join(m), &out.join(m.as_str()), frames)?);
        }
        Ok(written)
    }

    /// `STEM.gif` of `frames` and, with ffmpeg, `STEM.mp4` from their PNGs
    /// `frames_dir/frame_NNNN.png`. Returns what was written.
    pub fn animate_frames(
        &self,
        frames_dir: &std::path::Path,
        stem: &std::path::Path,
        frames: &[ImageF32],
    ) -> Result<Vec<PathBuf>, DataError> {
        let gif = stem.with_extension("gif");
        animation::write_gif(&gif, frames, self.fps)?;
        let mut written = vec![gif];
        let mp4 = stem.with_extension("mp4");
        if animation::write_mp4(&frames_dir.join("frame_%04d.png"), &mp4, self.fps)? {
            written.push(mp4);
        }
        Ok(written)
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let split = Split::parse(&args.split)
        .ok_or_else(|| DataError::invalid(format!("--split {}: expected train or test", args.split)))?;
    let maps = chosen_maps(&args.what)?;
    if args.spp == 0 {
        return Err(DataError::invalid("--spp 0: must be at least 1").into());
    }
    if maps.stage2 && !i2sdf_model::RunDir::new(&args.run).stage2_checkpoint_path().is_file() {
        return Err(i2sdf_model::RunDir::new(&args.run).no_stage2().into());
    }
    let (data, dataset) = super::run_dataset(&args.run, args.data.as_deref())?;
    let frames: Vec<_> = dataset.split(split).collect();
    let views = args.path.views(&frames, &dataset.bounds)?;
    // Each map of each view: a PNG, and an EXR of up to 3 floats per pixel.
    let pixels: u64 = views.iter().map(|(_, c)| (c.width * c.height) as u64).sum();
    let staged = super::output_dir(
        "--out",
        &args.out,
        args.force,
        "a render",
        &|dir| super::only_entries(dir, |name, is_dir| previous_render(name, is_dir)),
        &[&data],
        Some(pixels * maps.names.len() as u64 * 16),
    )?;
    let run = super::open_run(&args.run)?;
    let frozen = match maps.stage2 {
        true => run.frozen(&dataset)?,
        false => None,
    };
    let animated = args.path.path.is_some();
    let anim = render_views(&run, frozen.as_ref(), &views, &maps, args.spp, animated, staged.path())?;
    let written = if animated {
        args.path.animate(staged.path(), &anim)?
    } else {
        Vec::new()
    };
    let stage = staged.path().to_path_buf();
    staged.commit()?;
    if animated {
        for p in written {
            println!(
                "wrote {}",
                args.out.join(p.strip_prefix(&stage).unwrap_or(&p)).display()
            );
        }
        println!("rendered a {}-frame path into {}", views.len(), args.out.display());
        return Ok(());
    }
    println!(
        "rendered {} {} views into {}",
        views.len(),
        split.name(),
        args.out.display()
    );
    Ok(())
}

/// The maps `--what` names, and which stages they come from.
struct ChosenMaps<'w> {
    names: Vec<&'w str>,
    stage1: bool,
    stage2: bool,
}

/// Parses `--what`: at least one map, each one of [`STAGE1_MAPS`] or [`STAGE2_MAPS`].
fn chosen_maps(what: &str) -> Result<ChosenMaps<'_>, DataError> {
    let names: Vec<&str> = what.split(',').map(str::trim).filter(|s| !s.is_empty()).collect();
    if names.is_empty() {
        return Err(DataError::invalid(format!(
            "--what '{}': names no map (available: {}, {})",
            what,
            STAGE1_MAPS.join(", "),
            STAGE2_MAPS.join(", ")
        )));
    }
    for w in &names {
        if !STAGE1_MAPS.contains(w) && !STAGE2_MAPS.contains(w) {
            return Err(DataError::invalid(format!(
                "--what {w}: not available (available: {}, {})",
                STAGE1_MAPS.join(", "),
                STAGE2_MAPS.join(", ")
            )));
        }
    }
    Ok(ChosenMaps {
        stage1: names.iter().any(|w| STAGE1_MAPS.contains(w)),
        stage2: names.iter().any(|w| STAGE2_MAPS.contains(w)),
        names,
    })
}

/// Renders the chosen maps of every view into `out` (`MAP/NAME.png`, and `MAP/NAME.exr` where
/// the map has one) with a progress bar in rows; stage 2's maps come from `frozen` (`None`: none
/// asked for). Returns each map's PNG frames when `animated` (a path), for its animation.
fn render_views(
    run: &i2sdf_model::OpenedRun,
    frozen: Option<&i2sdf_model::FrozenScene>,
    views: &[(String, Camera)],
    maps: &ChosenMaps,
    spp: u32,
    animated: bool,
    out: &std::path::Path,
) -> Result<Vec<(String, Vec<ImageF32>)>, DataError> {
    let what = &maps.names;
    let rows: usize = views.iter().map(|(_, c)| c.height).sum();
    let passes = maps.stage1 as usize + maps.stage2 as usize;
    let bar = crate::progress::Step::new(
        &format!("rendering {} view(s) ({})", views.len(), what.join(", ")),
        (rows * passes) as u64,
        "rows",
    );
    // Each map's PNG frames of a path, for its animation.
    let mut anim: Vec<(String, Vec<ImageF32>)> = Vec::new();
    for (view, (name, camera)) in views.iter().enumerate() {
        let mut images = Vec::new();
        if maps.stage1 {
            images.extend(stage1_maps(&run.scene, &run.config.render, camera, what));
            bar.inc(camera.height as u64);
        }
        if let (Some(frozen), Some(fields)) = (frozen, &run.fields) {
            let spp_view = (spp, view as u32);
            images.extend(stage2_maps(frozen, fields, camera, spp_view, what, &|| bar.inc(1)));
        }
        write_maps(out, name, &images)?;
        for m in images {
            if animated {
                match anim.iter_mut().find(|(k, _)| k == m.map) {
                    Some((_, v)) => v.push(m.png),
                    None => anim.push((m.map.to_string(), vec![m.png])),
                }
            }
        }
    }
    bar.finish();
    Ok(anim)
}

/// Whether an entry of an existing folder is what `render` writes there: a map's folder, or a
/// path's animation of one (`MAP.gif`, `MAP.mp4`).
pub(crate) fn previous_render(name: &str, is_dir: bool) -> bool {
    let is_map = |m: &str| STAGE1_MAPS.contains(&m) || STAGE2_MAPS.contains(&m);
    if is_dir {
        return is_map(name);
    }
    matches!(name.rsplit_once('.'), Some((m, "gif" | "mp4")) if is_map(m))
}
