//! The stage-1 driver behind `i2sdf train`: creates or resumes a run directory, runs the
//! iterations, logs, and writes checkpoints atomically; the CLI only displays progress.

use crate::config::TrainConfig;
use crate::run_dir::{RunDir, RunInfo};
use crate::stage1::{Stage1, StepStats};
use i2sdf_data::{DataError, Dataset};
use std::time::Instant;

/// What the driver reports to its caller (the CLI's progress bar).
pub enum Event<'a> {
    Started { iteration: u64, total: u64 },
    Step(&'a StepStats),
    PdfInitialising,
    Checkpoint { iteration: u64 },
}

/// Runs (or resumes) stage 1 into `run`. On resume the configuration is the run's own, with
/// `overrides` applied on top (e.g. more iterations).
pub fn train_geometry(
    run: &RunDir,
    dataset: &Dataset,
    data_arg: &str,
    config: Option<TrainConfig>,
    resume: bool,
    mut on_event: impl FnMut(Event),
) -> Result<Stage1, DataError> {
    let (mut stage, mut info) = if resume {
        if !run.checkpoint_path().is_file() {
            return Err(DataError::file(run.checkpoint_path(), "no checkpoint to resume from"));
        }
        let config = match config {
            Some(c) => c,
            None => run.read_config()?,
        };
        let info = run.read_info()?;
        let stage = Stage1::resume(dataset, config, &run.checkpoint_path())?;
        if let Some(n) = info.normalization {
            if n != dataset.normalization {
                return Err(DataError::invalid(format!(
                    "{}: the dataset's normalization differs from the run's: is this the same dataset?",
                    run.info_path().display()
                )));
            }
        }
        (stage, info)
    } else {
        if run.exists() || run.checkpoint_path().exists() {
            return Err(DataError::file(
                &run.root,
                "already holds a run: use --resume to continue it, or another --out",
            ));
        }
        run.create()?;
        let config = config.unwrap_or_default();
        let stage = Stage1::new(dataset, config);
        let info = RunInfo {
            data: data_arg.to_string(),
            normalization: Some(dataset.normalization),
            bounds: Some(dataset.bounds),
            ..Default::default()
        };
        (stage, info)
    };
    run.write_config(&stage.config)?;
    run.write_info(&info)?;
    let total = stage.config.train.iterations;
    on_event(Event::Started {
        iteration: stage.iteration,
        total,
    });
    let session_start = Instant::now();
    let base_seconds = info.stage1_seconds;
    let every = stage.config.train.checkpoint_every.max(1);
    let log_every = stage.config.train.log_every.max(1);
    while !stage.done() {
        if stage.phase() == crate::schedule::Phase::Bubble && stage.needs_pdf() {
            on_event(Event::PdfInitialising);
        }
        let stats = stage.step()?;
        if stats.iteration % log_every == 0 || stats.skipped {
            let mut record = serde_json::to_value(&stats).expect("stats serialize");
            record["time_s"] = serde_json::json!(base_seconds + session_start.elapsed().as_secs_f64());
            run.append_log(&record)?;
        }
        on_event(Event::Step(&stats));
        if stage.iteration % every == 0 || stage.done() {
            stage.save(&run.checkpoint_path())?;
            info.stage1_iterations = stage.iteration;
            info.stage1_seconds = base_seconds + session_start.elapsed().as_secs_f64();
            info.stage1_done = stage.done();
            run.write_info(&info)?;
            on_event(Event::Checkpoint {
                iteration: stage.iteration,
            });
        }
    }
    Ok(stage)
}
