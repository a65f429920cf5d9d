pub mod bench;
pub mod check;
pub mod demo;
pub mod edit;
pub mod eval;
pub mod mesh;
pub mod render;
pub mod report;
pub mod synth;
pub mod train;

/// The exit codes of the README's "Command line": 2 for bad input (a `DataError` in the chain that says so: a file, field,
/// key or argument at fault), 1 for anything else (a failed write, a diverged run, an internal
/// error).
pub fn exit_code(e: &anyhow::Error) -> u8 {
    if e.chain().any(|c| {
        c.downcast_ref::<i2sdf_data::DataError>()
            .is_some_and(|d| d.is_bad_input())
    }) {
        2
    } else {
        1
    }
}

/// The dataset a command on a run reads, loaded: `data` (its `--data`) when given, else the one
/// the run's `run.json` records (refused, naming `run.json` and `--data`, when that is gone). A
/// dataset that is not the run's (by the fingerprint `run.json` keeps) is said on stderr.
pub fn run_dataset(
    run: &std::path::Path,
    data: Option<&std::path::Path>,
) -> Result<(std::path::PathBuf, i2sdf_data::Dataset), i2sdf_data::DataError> {
    let dir = i2sdf_model::RunDir::new(run);
    let info = dir.read_info()?;
    let path = dir.dataset_path(&info, data)?;
    let mut dataset = i2sdf_data::load(&path)?;
    match info.dataset_mismatch(&dataset, &path) {
        // Another dataset: the run's pose corrections are of other views, so none is used.
        Some(w) => crate::progress::line(&w),
        // Training views as stage 1 placed them (test views keep their given poses).
        None => {
            i2sdf_model::poses::with_corrected_poses(&dir, &mut dataset)?;
        }
    }
    Ok((path, dataset))
}

/// An output folder checked (before any work) and staged: `flag` names it in messages, `what`
/// says what the command writes ("a render"), `previous` tells a previous output of the same
/// command (which `--force` may replace) from anything else.
pub fn output_dir(
    flag: &str,
    path: &std::path::Path,
    force: bool,
    what: &str,
    previous: &dyn Fn(&std::path::Path) -> bool,
    inputs: &[&std::path::Path],
    bytes: Option<u64>,
) -> Result<i2sdf_data::output::StagedDir, i2sdf_data::DataError> {
    i2sdf_data::output::OutputDir {
        flag,
        path,
        force,
        previous,
        what,
        inputs,
        bytes,
    }
    .check()
}

/// An output file checked before any work (see `i2sdf_data::output`).
pub fn output_file(
    flag: &str,
    path: &std::path::Path,
    extensions: &[&str],
    force: bool,
    inputs: &[&std::path::Path],
    bytes: Option<u64>,
) -> Result<(), i2sdf_data::DataError> {
    i2sdf_data::output::OutputFile {
        flag,
        path,
        extensions,
        force,
        inputs,
        bytes,
    }
    .check()
    .map(|_| ())
}

/// Whether every entry of `dir` passes `ok` (its name, whether it is a folder): how a command
/// recognizes its own previous output. Hidden entries (staging leftovers) are ignored.
pub fn only_entries(dir: &std::path::Path, ok: impl Fn(&str, bool) -> bool) -> bool {
    std::fs::read_dir(dir).is_ok_and(|d| {
        d.filter_map(|e| e.ok()).all(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.starts_with('.') || ok(&name, e.path().is_dir())
        })
    })
}

/// A parser for a view index that says what is wrong with `-1` (clap would read it as a flag,
/// or say only "invalid digit").
pub fn view_index(s: &str) -> Result<usize, String> {
    match s.trim().parse::<i64>() {
        Ok(v) if v < 0 => Err(format!("{v}: a view index is 0 or more")),
        Ok(v) => usize::try_from(v).map_err(|_| format!("{v}: too large")),
        Err(_) => Err(format!("'{s}' is not a view index (0, 1, 2, …)")),
    }
}

/// A trained run's fields (from its checkpoint) and its run info.
pub fn load_run(
    run: &std::path::Path,
) -> Result<(i2sdf_model::NeuralScene, i2sdf_model::RunInfo), i2sdf_data::DataError> {
    let dir = i2sdf_model::RunDir::new(run);
    let info = dir.read_info()?;
    let (scene, _) = i2sdf_model::NeuralScene::load(&dir.checkpoint_path())?;
    Ok((scene, info))
}

/// A trained run's stage-1 scene, its stage-2 fields where `RUN/stage2.safetensors` exists, and
/// its run info.
pub fn load_run_intrinsic(
    run: &std::path::Path,
) -> Result<
    (
        i2sdf_model::NeuralScene,
        Option<i2sdf_model::intrinsic_io::IntrinsicFields>,
        i2sdf_model::RunInfo,
    ),
    i2sdf_data::DataError,
> {
    let dir = i2sdf_model::RunDir::new(run);
    let info = dir.read_info()?;
    let (scene, fields) = i2sdf_model::intrinsic_io::load_run(&dir)?;
    Ok((scene, fields, info))
}

/// The bad-input error for a stage-2 output asked of a run without stage 2.
pub fn no_stage2(run: &std::path::Path) -> i2sdf_data::DataError {
    i2sdf_data::DataError::file(
        i2sdf_model::RunDir::new(run).stage2_checkpoint_path(),
        "no stage 2: train --stage material first",
    )
}

/// The F_e threshold stage 2 labelled its emitters with (the run's `stage2.emitter_threshold`).
pub fn run_emitter_threshold(run: &std::path::Path) -> Result<f32, i2sdf_data::DataError> {
    let config = i2sdf_train::driver::read_run_config(&i2sdf_model::RunDir::new(run))?;
    Ok(config.stage2.emitter_threshold)
}

/// Whether stage 2 labelled the unobserved surface inside emitters as emitting (the run's
/// `stage2.label_unobserved`): the re-render, `render` and `edit` label hits the same way.
pub fn run_label_unobserved(run: &std::path::Path) -> Result<bool, i2sdf_data::DataError> {
    let config = i2sdf_train::driver::read_run_config(&i2sdf_model::RunDir::new(run))?;
    Ok(config.stage2.label_unobserved)
}

/// The volume renderer's settings the run was trained with (its `[sampling]` section), so
/// `render` and `eval` see what training saw.
pub fn run_render_settings(
    run: &std::path::Path,
) -> Result<i2sdf_model::renderer::RenderSettings, i2sdf_data::DataError> {
    let config = i2sdf_train::driver::read_run_config(&i2sdf_model::RunDir::new(run))?;
    Ok(i2sdf_train::driver::render_settings(&config))
}

/// The scene bounds recorded in the run.
pub fn run_bounds(
    run: &std::path::Path,
    info: &i2sdf_model::RunInfo,
) -> Result<i2sdf_data::Bounds, i2sdf_data::DataError> {
    info.bounds.ok_or_else(|| {
        i2sdf_data::DataError::field(
            run.join("run.json"),
            "bounds",
            "missing (run trained by an older version?)",
        )
    })
}
