pub mod bench;
pub mod check;
pub mod demo;
pub mod edit;
pub mod eval;
pub mod export;
pub mod mesh;
pub mod render;
pub mod report;
pub mod synth;
pub mod train;

/// The exit codes of the README's "Commands": 2 for bad input (a `DataError` in the chain that says so: a file, field,
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

/// A trained run opened once for `render`, `eval`, `report` and `edit`
/// ([`i2sdf_model::OpenedRun`]: its scene, stage-2 fields, run info and the configuration
/// inference reads); what it notes on opening is said on stderr.
pub fn open_run(run: &std::path::Path) -> Result<i2sdf_model::OpenedRun, i2sdf_data::DataError> {
    let opened = i2sdf_train::run::open_trained(run)?;
    for note in &opened.notes {
        crate::progress::line(note);
    }
    Ok(opened)
}
