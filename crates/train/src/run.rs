//! Opening and starting runs: a run directory opened for training (fresh, or resumed after its
//! configuration and dataset are checked: [`open_run`]), each stage built from its checkpoint or
//! anew and handed to the generic [`drive`] loop ([`train_geometry`], [`train_materials`]), and a
//! trained run opened for inference ([`open_trained`]). The stages themselves know nothing of run
//! directories; the driver knows nothing of stages.

use crate::config::TrainConfig;
use crate::driver::{drive, DriveOptions, Event, Trainer};
use crate::maps::TrainingMaps;
use crate::resume::{check_config, check_dataset, check_trained_fields, repair};
use crate::stage1::{render_settings, Stage1, StepStats};
use crate::stage2::{radiometry, target_views, Stage2, Stage2Stats};
use i2sdf_data::{DataError, Dataset};
use i2sdf_model::run_dir::{RunDir, RunInfo};
use i2sdf_model::{InferenceConfig, OpenedRun};
use std::path::Path;
use std::time::Instant;

/// Writes `text` to `path` atomically unless it holds exactly that already (a finished run
/// resumed rewrites nothing).
fn write_if_changed(path: &Path, text: &str) -> Result<(), DataError> {
    if std::fs::read_to_string(path).is_ok_and(|t| t == text) {
        return Ok(());
    }
    i2sdf_data::imageio::write_bytes_atomic(path, text.as_bytes())
}

/// The run's data is `dataset`: the stage-1 checkpoint's fingerprint of the data (and the
/// normalization `run.json` records) agree with it.
fn check_same_dataset(run: &RunDir, info: &RunInfo, data_arg: &str, dataset: &Dataset) -> Result<(), DataError> {
    if run.checkpoint_path().is_file() {
        check_dataset(&run.checkpoint_path(), &info.data, data_arg, dataset)?;
    }
    if let Some(n) = info.normalization {
        if !n.same_as(&dataset.normalization) {
            return Err(DataError::invalid(format!(
                "--data {data_arg}: the dataset's normalization differs from the run's ({}, as {} records): is this the same dataset?",
                info.data,
                run.info_path().display()
            )));
        }
    }
    Ok(())
}

/// Records in `info` where the dataset (checked to be the run's) is now, as an absolute path, and
/// its fingerprint: a run trained from one folder opens from any other, and follows its dataset
/// when a resume or stage 2 names it at a new place.
fn record_dataset(info: &mut RunInfo, data_arg: &str, dataset: &Dataset) {
    info.data = i2sdf_data::output::absolute(Path::new(data_arg)).display().to_string();
    info.data_fingerprint = Some(i2sdf_data::fingerprint::DatasetFingerprint::of(dataset));
}

/// The run's configuration, as `RUN/config.toml` holds it.
pub fn read_run_config(run: &RunDir) -> Result<TrainConfig, DataError> {
    TrainConfig::load(Some(&run.config_path()), &[])
}

/// What inference reads of a run's configuration: its volume-render settings
/// ([`render_settings`]) and stage 2's emitter labelling and bake.
pub fn inference_config(config: &TrainConfig) -> InferenceConfig {
    InferenceConfig {
        render: render_settings(config),
        emitter_threshold: config.stage2.emitter_threshold,
        label_unobserved: config.stage2.label_unobserved,
        bake_resolution: config.stage2.bake_resolution,
    }
}

/// Opens a trained run at `root` for `render`, `eval`, `report` and `edit`
/// ([`OpenedRun::open`] with the run's own configuration, `RUN/config.toml`).
pub fn open_trained(root: &Path) -> Result<OpenedRun, DataError> {
    let config = read_run_config(&RunDir::new(root))?;
    OpenedRun::open(root, inference_config(&config))
}

/// The configuration a run continues with: its own, or `config` (its "auto" settings standing
/// for what the run resolved them to) once checked to change nothing the checkpoints depend on.
fn continued_config(
    run: &RunDir,
    dataset: &Dataset,
    config: Option<TrainConfig>,
    frozen_stage2: bool,
) -> Result<TrainConfig, DataError> {
    let own = read_run_config(run)?;
    let config = match config {
        Some(mut c) => {
            let _ = c.resolve(dataset);
            check_config(&run.config_path(), &own, &c, frozen_stage2)?;
            c
        }
        None => own,
    };
    check_trained_fields(
        &run.config_path(),
        &config,
        &run.checkpoint_path(),
        &run.stage2_checkpoint_path(),
    )?;
    Ok(config)
}

/// Opens a run directory for training: a fresh one (refused if it already holds a run) or, with
/// `resume`, an existing one whose configuration (`config` if given, else the run's own) and
/// dataset normalization are checked. Writes the configuration, its `"auto"` settings resolved
/// against the dataset (and says what a sensor's depth filled), and `run.json`; any stage then
/// [`drive`]s into it.
pub fn open_run(
    run: &RunDir,
    dataset: &Dataset,
    data_arg: &str,
    config: Option<TrainConfig>,
    resume: bool,
) -> Result<(TrainConfig, RunInfo, Option<String>), DataError> {
    let (config, info) = if resume {
        // A run killed before its first checkpoint resumes from iteration 0: its initial state,
        // which a fresh stage 1 with the run's seed rebuilds exactly.
        let unstarted = run.exists() && run.read_info().is_ok_and(|i| i.stage1.iterations == 0);
        if !run.checkpoint_path().is_file() && !unstarted {
            return Err(DataError::file(run.checkpoint_path(), "no checkpoint to resume from"));
        }
        let mut info = run.read_info()?;
        check_same_dataset(run, &info, data_arg, dataset)?;
        record_dataset(&mut info, data_arg, dataset);
        let config = continued_config(run, dataset, config, run.stage2_checkpoint_path().is_file())?;
        repair(&run.root, &run.log_path())?;
        (config, info)
    } else {
        if run.exists() || run.checkpoint_path().exists() {
            return Err(DataError::file(
                &run.root,
                "already holds a run: use --resume to continue it, or another --out",
            ));
        }
        run.create()?;
        let mut info = RunInfo {
            normalization: Some(dataset.normalization),
            bounds: Some(dataset.bounds),
            ..Default::default()
        };
        record_dataset(&mut info, data_arg, dataset);
        (config.unwrap_or_default(), info)
    };
    // The run's file holds the numbers its dataset called for, not "auto".
    let mut config = config;
    let filled = config.resolve(dataset);
    write_if_changed(&run.config_path(), &config.to_toml())?;
    if run.read_info().ok().as_ref() != Some(&info) {
        run.write_info(&info)?;
    }
    Ok((config, info, filled))
}

/// Runs (or resumes) stage 1 into `run`. On resume the configuration is the run's own unless
/// `config` is given (the CLI applies `--set` overrides on top of the run's). The maps in force
/// (`TrainingMaps::for_run`: emitter masks found from the images are written into the run, or read
/// back from it) are said first, one [`Event::Note`] per map.
pub fn train_geometry(
    run: &RunDir,
    dataset: &Dataset,
    data_arg: &str,
    config: Option<TrainConfig>,
    resume: bool,
    mut on_event: impl FnMut(Event<StepStats>),
) -> Result<Stage1, DataError> {
    let (config, mut info, filled) = open_run(run, dataset, data_arg, config, resume)?;
    let maps = TrainingMaps::for_run(run, dataset, &config)?;
    for line in maps.describe(dataset) {
        on_event(Event::Note(line.to_string()));
    }
    if let Some(line) = filled {
        on_event(Event::Note(line));
    }
    let snapshots = config.train.snapshot_seconds.clone();
    let options = DriveOptions {
        checkpoint_every: config.train.checkpoint_every,
        log_every: config.train.log_every,
        snapshot_seconds: &snapshots,
    };
    let precision = config.train.matmul_precision;
    if i2sdf_nn::linalg::effective_precision(precision) != precision {
        on_event(Event::Note(format!(
            "train.matmul_precision = \"{}\": this CPU has no AMX tiles (or the OS refused them), stage 1's products run in f32",
            precision.name()
        )));
    }
    let stage = if resume && run.checkpoint_path().is_file() {
        Stage1::resume(dataset, config, &maps, &run.checkpoint_path())?
    } else {
        Stage1::new(dataset, config, &maps)
    };
    let mut trainer = Trainer::new(stage);
    drive(run, &mut info, &mut trainer, options, on_event)?;
    Ok(trainer.stage)
}

/// Runs (or resumes) stage 2 on a run whose stage 1 has finished: the frozen fields come from
/// its checkpoint, the configuration is the run's own unless `config` is given (the CLI applies
/// `--set` overrides on top of it; it may change only stage 2's sections, and those only until
/// stage 2 has a checkpoint). Refused, as bad input, when stage 1 has not finished, when the
/// data or the configuration is not the run's, or when stage 2 has a checkpoint already and
/// `resume` is not set. Writes `RUN/emitters.json` once the emitters are clustered and again at
/// the end. `progress` hears the slow setup steps; the emitter masks and HDR images in force are
/// said first ([`Event::Note`]; masks found from the images are the run's, as stage 1 wrote them).
/// `None`: stage 2 had finished already (with `resume`; nothing is written).
pub fn train_materials(
    run: &RunDir,
    dataset: &Dataset,
    data_arg: &str,
    config: Option<TrainConfig>,
    resume: bool,
    progress: &dyn Fn(&str),
    mut on_event: impl FnMut(Event<Stage2Stats>),
) -> Result<Option<Stage2>, DataError> {
    if !run.exists() || !run.checkpoint_path().is_file() {
        return Err(DataError::file(
            &run.root,
            "holds no stage-1 run: train --stage geometry (or --stage all) first",
        ));
    }
    let mut info = run.read_info()?;
    if !info.stage("stage1").is_some_and(|s| s.done) {
        return Err(DataError::file(
            run.info_path(),
            "stage 1 has not finished: resume it with train --stage geometry --resume first",
        ));
    }
    check_same_dataset(run, &info, data_arg, dataset)?;
    record_dataset(&mut info, data_arg, dataset);
    // Stage 2 sees the training views where stage 1 put them (a copy of the dataset: its
    // fingerprint, checked above, is of the poses as given).
    let corrected;
    let dataset = match i2sdf_model::poses::PoseCorrections::read(run)? {
        Some(p) => {
            let mut d = dataset.clone();
            p.apply(&mut d, &run.poses_path())?;
            corrected = d;
            &corrected
        }
        None => dataset,
    };
    let ckpt = run.stage2_checkpoint_path();
    if ckpt.is_file() && !resume {
        return Err(DataError::file(
            &ckpt,
            "stage 2 has a checkpoint already: use --resume to continue it (or delete the file to start over)",
        ));
    }
    if resume && !ckpt.is_file() && info.stage("stage2").is_some_and(|s| s.iterations > 0) {
        return Err(DataError::file(&ckpt, "missing: no stage-2 checkpoint to resume from"));
    }
    let config = continued_config(run, dataset, config, ckpt.is_file())?;
    let finished = info
        .stage("stage2")
        .is_some_and(|s| s.done && s.iterations == crate::stage2::total_iterations(&config));
    if resume && ckpt.is_file() && finished {
        return Ok(None);
    }
    repair(&run.root, &run.log_path())?;
    write_if_changed(&run.config_path(), &config.to_toml())?;
    let maps = TrainingMaps::for_run(run, dataset, &config)?;
    for line in maps.describe(dataset) {
        if matches!(line.map, "emitter masks" | "hdr") {
            on_event(Event::Note(line.to_string()));
        }
    }
    let (scene, _) = i2sdf_model::NeuralScene::load(&run.checkpoint_path())?;
    let views = target_views(dataset, config.stage2.use_hdr, &maps);
    let rm = radiometry(dataset);
    // Snapshots are stage 1's (`train.snapshot_seconds`); stage 2 has its own wall time.
    let options = DriveOptions {
        checkpoint_every: config.train.checkpoint_every,
        log_every: config.train.log_every,
        snapshot_seconds: &[],
    };
    let built = Instant::now();
    let stage = if resume && ckpt.is_file() {
        Stage2::resume(config, scene, &views, rm, &ckpt, progress)?
    } else {
        Stage2::new(config, scene, &views, rm, None, progress)?
    };
    // Building the cache is stage-2 time (most of it): `time_s.stage2` counts it with the loop.
    info.stage_mut("stage2")?.seconds += built.elapsed().as_secs_f64();
    stage.fields.emitters.write_json(&run.emitters_path(), rm.exposure)?;
    let mut trainer = Trainer::new(stage);
    drive(run, &mut info, &mut trainer, options, on_event)?;
    trainer
        .stage
        .fields
        .emitters
        .write_json(&run.emitters_path(), rm.exposure)?;
    Ok(Some(trainer.stage))
}
