//! `i2sdf eval --run RUN --data SCENE --out METRICS.json`: the metrics JSON (every figure that
//! cannot be computed is null; `i2sdf_eval::report`). With `--mesh-out FILE.ply` it also writes
//! the extracted mesh it scored; it writes nothing else. `--mesh FILE.ply` scores that mesh
//! instead of extracting one. Both outputs are checked before the work
//! (`i2sdf_data::output`) and an existing one is replaced only with `--force`. With
//! stage 2 (`RUN/stage2.safetensors`) it fills `rerender`, `material` and `emitters` from a Monte
//! Carlo re-render of the test views (`--spp` paths per pixel), and `relight` from path-traced
//! renders of the dataset's relit sets with their specs (`--spp`, `--bounces`), path traced and
//! by differential rendering; without, they stay null. With `--lpips-weights FILE.safetensors`
//! (`scripts/lpips_weights.py` writes it) it fills `novel_view.lpips`; without, that is null and
//! the notes say why. The weights are read and checked before any work.

use clap::Args as ClapArgs;
use i2sdf_data::{imageio, Split};
use i2sdf_edit::{Denoiser, EditSettings, RecoveredScene};
use i2sdf_eval::intrinsic::{intrinsic_metrics_with_progress, IntrinsicOptions};
use i2sdf_eval::neural::{evaluate_keeping_test_images, EvalOptions, ViewSplits};
use i2sdf_eval::progress::EvalProgress;
use i2sdf_eval::relight::{relight_frames, relight_metrics, relight_rows, RelightOptions};
use i2sdf_model::images::{stage1_maps_of, stage2_maps_of, write_maps, STAGE1_MAPS, STAGE2_MAPS};
use std::path::PathBuf;
use std::sync::RwLock;

#[derive(ClapArgs)]
pub struct Args {
    /// The trained run to evaluate.
    #[arg(long)]
    pub run: PathBuf,
    /// The dataset to score against (defaults to the one the run was trained on, as its run.json
    /// records).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Output JSON file (.json).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the extracted mesh that was scored (binary PLY, world units).
    #[arg(long)]
    pub mesh_out: Option<PathBuf>,
    /// Score this mesh (PLY, world units) instead of extracting one at --mesh-resolution: what
    /// `i2sdf mesh` wrote from this run (the demo's mesh.ply), or another method's mesh of the
    /// scene. The metrics' notes name it.
    #[arg(long, value_name = "FILE.ply")]
    pub mesh: Option<PathBuf>,
    /// Also write the test views as they were scored into this folder, laid out as `i2sdf render
    /// --split test --what rgb,depth,normal,emitter` writes them (with stage 2, also albedo,
    /// specular, roughness, emission and the re-render at --spp): the images cost nothing more,
    /// where a separate `render` would render them again.
    #[arg(long, value_name = "DIR")]
    pub renders: Option<PathBuf>,
    /// Replace --out (and --mesh-out, --renders) if they exist.
    #[arg(long)]
    pub force: bool,
    /// Marching-cubes resolution of the evaluated mesh; the relit sets are traced in the
    /// recovered surface at this resolution, at most 256.
    #[arg(long, default_value_t = i2sdf_eval::neural::MESH_RESOLUTION)]
    pub mesh_resolution: usize,
    /// F-score threshold in scene (world) units.
    #[arg(long, default_value_t = 0.05)]
    pub threshold: f64,
    /// Paths per pixel of stage 2's re-render of the test views and of the relit sets' renders.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Most scattering events per path of the relit sets' renders (the edit renderer's).
    #[arg(long, default_value_t = EditSettings::default().bounces)]
    pub bounces: u32,
    /// Denoise the re-render and the relit sets' renders before scoring them (an edge-avoiding
    /// à-trous filter guided by normal, depth, reflectance and the paths' variance, each
    /// emitter's light apart).
    #[arg(long)]
    pub denoise: bool,
    /// LPIPS (AlexNet, v0.1) weights as safetensors (scripts/lpips_weights.py) for
    /// novel_view.lpips; without them it is null.
    #[arg(long, value_name = "FILE.safetensors")]
    pub lpips_weights: Option<PathBuf>,
    /// Whose image metrics: test (novel_view), train (train_view: the paper's bracketed
    /// figures) or both.
    #[arg(long, default_value = "test", value_name = "test|train|both")]
    pub split: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let splits = ViewSplits::parse(&args.split).ok_or_else(|| {
        i2sdf_data::DataError::invalid(format!("--split {}: expected test, train or both", args.split))
    })?;
    if !(args.threshold.is_finite() && args.threshold > 0.0) {
        return Err(i2sdf_data::DataError::invalid(format!(
            "--threshold {}: must be a positive distance in world units",
            args.threshold
        ))
        .into());
    }
    if args.spp == 0 {
        return Err(i2sdf_data::DataError::invalid("--spp 0: must be at least 1").into());
    }
    if !(1..=1024).contains(&args.bounces) {
        return Err(i2sdf_data::DataError::invalid(format!("--bounces {}: must be in [1, 1024]", args.bounces)).into());
    }
    if args.mesh.is_some() && args.mesh_out.is_some() {
        return Err(i2sdf_data::DataError::invalid(
            "--mesh-out with --mesh: the scored mesh is the one --mesh names already",
        )
        .into());
    }
    // Read and checked now, not after the views are rendered.
    let given_mesh = match &args.mesh {
        Some(path) => {
            let mesh = i2sdf_data::ply::read_ply(path)?;
            if mesh.num_faces() == 0 {
                return Err(
                    i2sdf_data::DataError::field(path, "face", "no faces: --mesh needs a triangle mesh").into(),
                );
            }
            Some(mesh)
        }
        None => None,
    };
    let lpips = match &args.lpips_weights {
        Some(path) => Some(std::sync::Arc::new(i2sdf_eval::Lpips::load(path)?)),
        None => None,
    };
    let (data, dataset) = super::run_dataset(&args.run, args.data.as_deref())?;
    let inputs = [data.as_path()];
    super::output_file("--out", &args.out, &["json"], args.force, &inputs, Some(1 << 20))?;
    if let Some(mesh) = &args.mesh_out {
        super::output_file("--mesh-out", mesh, &["ply"], args.force, &inputs, None)?;
        if i2sdf_data::output::absolute(mesh) == i2sdf_data::output::absolute(&args.out) {
            return Err(i2sdf_data::DataError::invalid("--mesh-out and --out name the same file").into());
        }
    }
    let run = super::open_run(&args.run)?;
    let renders = match &args.renders {
        Some(dir) => {
            if i2sdf_data::output::absolute(dir) == i2sdf_data::output::absolute(&args.out) {
                return Err(i2sdf_data::DataError::invalid("--renders and --out name the same path").into());
            }
            let maps = STAGE1_MAPS.len() + if run.fields.is_some() { STAGE2_MAPS.len() } else { 0 };
            let pixels: u64 = dataset
                .split(Split::Test)
                .map(|f| (f.camera.width * f.camera.height) as u64)
                .sum();
            Some(super::output_dir(
                "--renders",
                dir,
                args.force,
                "a render",
                &|d| super::only_entries(d, super::render::previous_render),
                &inputs,
                Some(pixels * maps as u64 * 16),
            )?)
        }
        None => None,
    };
    // A mesh resolution that cannot fit is refused now, not after the views are rendered.
    i2sdf_model::sdf_mesh::sdf_grid(&run.scene, &dataset.bounds, args.mesh_resolution)?.check_fits(
        &i2sdf_model::McOptions::for_sdf(args.mesh_resolution),
        i2sdf_model::memory::MachineMemory::read().map(|m| m.available),
    )?;
    let mut options = EvalOptions {
        mesh_resolution: args.mesh_resolution,
        render: run.config.render.clone(),
        lpips,
        splits,
        given_mesh,
        ..Default::default()
    };
    options.mesh.threshold = args.threshold;
    let steps = EvalSteps::default();
    // The test views' images, which the relit sets' differential composites reuse.
    let mut test_images = Vec::new();
    // Stage 2's frozen scene (its surface bake) is built beside the test views and the mesh,
    // whose ends leave the cores part idle (the default room: 1.6 s less).
    let (evaluated, frozen) = rayon::join(
        || {
            evaluate_keeping_test_images(
                &run.scene,
                &dataset,
                &dataset.bounds,
                &options,
                &steps,
                &mut test_images,
            )
        },
        || run.frozen(&dataset),
    );
    let (mut report, mesh) = evaluated?;
    let frozen = frozen?;
    steps.end();
    if let Some(path) = &args.mesh {
        report.notes.push(format!(
            "geometry: the mesh scored is {} (eval --mesh), not one extracted from the run",
            path.display()
        ));
    }
    if let (Some(fields), Some(frozen)) = (&run.fields, frozen) {
        let intrinsic = IntrinsicOptions {
            spp: args.spp,
            denoise: args.denoise.then(Denoiser::default),
            ..Default::default()
        };
        let relight = RelightOptions {
            render: EditSettings {
                spp: args.spp,
                bounces: args.bounces,
                seed: 0,
                denoise: args.denoise.then(Denoiser::default),
            },
            // The recovered surface the sets are traced in: the edit renderer's, or coarser when
            // the mesh is (a report at the same settings then shows the same renders).
            mesh_resolution: args.mesh_resolution.min(i2sdf_edit::MESH_RESOLUTION),
            differential: true,
        };
        let relit = !fields.emitters.is_empty() && relight_frames(&dataset) > 0;
        let rows: usize = dataset.split(Split::Test).map(|f| f.camera.height).sum();
        let bar = crate::progress::Step::new("stage 2: re-rendering the test views", rows as u64, "rows");
        let mut rerenders = Vec::new();
        // The relit sets' recovered scene (its surface extracted and simplified, partly
        // serial) is built beside the re-render, which leaves the cores part idle at the end
        // of each view.
        let (intrinsic, prepared) = rayon::join(
            || {
                intrinsic_metrics_with_progress(
                    &frozen,
                    fields,
                    &dataset,
                    &intrinsic,
                    &|| bar.inc(1),
                    renders.is_some().then_some(&mut rerenders),
                )
            },
            || {
                relit
                    .then(|| RecoveredScene::of_run(&run, &dataset, relight.mesh_resolution))
                    .transpose()
            },
        );
        let (rerender, material, emitters) = intrinsic?;
        let prepared = prepared?;
        bar.finish();
        if let Some(staged) = &renders {
            for (v, f) in rerenders.iter().zip(dataset.split(Split::Test)) {
                let maps = stage2_maps_of(v, &frozen, fields, &f.camera, &STAGE2_MAPS);
                write_maps(staged.path(), &f.name, &maps)?;
            }
        }
        report.rerender = rerender;
        report.material = material;
        report.emitters = emitters;
        let captured: Vec<_> = test_images.iter().map(|(c, v)| (c.clone(), v.rgb.clone())).collect();
        if fields.emitters.is_empty() {
            // Nothing to relight: no black images are scored, the figures are null (the sets
            // listed with their frames) and a note says why.
            crate::progress::line(&format!("warning: {}", i2sdf_eval::report::zero_emitter_note()));
            report.relight = relight_metrics(&run, &dataset, &relight, None, &captured, &|| {})?;
            report.note_no_emitters();
        } else if relight_frames(&dataset) > 0 {
            let rows = relight_rows(&dataset, relight.differential)?;
            let bar = crate::progress::Step::new("relit sets: path tracing", rows as u64, "rows");
            report.relight = relight_metrics(&run, &dataset, &relight, prepared, &captured, &|| bar.inc(1))?;
            bar.finish();
        }
    }
    if let Some(staged) = renders {
        for (f, (_, v)) in dataset.split(Split::Test).zip(&test_images) {
            write_maps(staged.path(), &f.name, &stage1_maps_of(v, &STAGE1_MAPS))?;
        }
        staged.commit()?;
    }
    if let Some(corrections) = i2sdf_model::poses::PoseCorrections::read(&run.dir)? {
        report.poses = i2sdf_eval::poses::pose_metrics(&corrections, &dataset);
    }
    let info = &run.info;
    report.time_s.stage1 = (info.stage1.iterations > 0).then_some(info.stage1.seconds);
    report.time_s.stage2 = info.stage2.filter(|s| s.iterations > 0).map(|s| s.seconds);
    let json = report.to_json();
    // --mesh-out is refused with --mesh, so an extracted mesh is there to write.
    if let (Some(path), Some(mesh)) = (&args.mesh_out, &mesh) {
        i2sdf_eval::write_ply(path, mesh)?;
    }
    imageio::write_bytes_atomic(&args.out, json.as_bytes())?;
    println!("{json}");
    Ok(())
}

/// The evaluation's steps as labelled progress ([`crate::progress::Step`]), one after another.
#[derive(Default)]
struct EvalSteps(RwLock<Option<crate::progress::Step>>);

impl EvalSteps {
    /// The last step is done.
    fn end(&self) {
        if let Some(step) = self.0.write().unwrap_or_else(|p| p.into_inner()).take() {
            step.finish();
        }
    }
}

impl EvalProgress for EvalSteps {
    fn step(&self, name: &str, total: u64) {
        self.end();
        let unit = if [i2sdf_eval::progress::TEST_VIEWS, i2sdf_eval::progress::TRAIN_VIEWS].contains(&name) {
            "views"
        } else {
            "points"
        };
        let step = crate::progress::Step::new(&format!("eval: {name}"), total, unit);
        *self.0.write().unwrap_or_else(|p| p.into_inner()) = Some(step);
    }

    fn inc(&self, n: u64) {
        if let Some(step) = self.0.read().unwrap_or_else(|p| p.into_inner()).as_ref() {
            step.inc(n);
        }
    }
}
