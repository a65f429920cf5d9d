//! Where a command may write, checked before its first second of work.
//!
//! The rules every command keeps (the README's "Commands" states them for users):
//! - it writes only where the user said, and never into a dataset folder (one that holds
//!   `transforms.json`, `cameras_normalize.npz` or `cameras.npz`, at any depth below it);
//! - never over a run's own files (`run.json`, `config.toml`, the checkpoints, the log, …); a new
//!   output *inside* a run folder (`eval --out RUN/metrics.json`) is allowed, the run folder
//!   itself is not an output;
//! - an existing output is replaced only with `--force`, and a folder only when it looks like a
//!   previous output of the same command: `--force` never empties a folder of someone else's;
//! - folders are built in a staging folder beside the target and renamed into place at the end
//!   ([`StagedDir`]); files are written to a temporary and renamed ([`crate::imageio::write_atomic`]),
//!   so a refused or failed command leaves what was there byte-identical;
//! - before the work: the target's kind (file or folder), its extension, that its place can be
//!   written (a probe file created and removed in the nearest existing folder) and, where the
//!   size is known, the free space there.
//!
//! Refusals are bad input (exit 2, naming the flag and the path); a place that cannot be written
//! or a disk without room for an output of known size is the machine's (exit 1).

use crate::error::{DataError, Result};
use std::path::{Component, Path, PathBuf};

/// Files that make a folder a dataset.
pub const DATASET_MARKERS: [&str; 3] = ["transforms.json", "cameras_normalize.npz", "cameras.npz"];

/// The file that makes a folder a training run (`RunDir`'s `run.json`).
pub const RUN_MARKER: &str = "run.json";

/// A run's own files and folders, which no command but `train` writes (`RunDir`'s paths; its
/// test keeps the two lists equal).
pub const RUN_FILES: [&str; 8] = [
    "poses.json",
    "run.json",
    "config.toml",
    "checkpoint.safetensors",
    "stage2.safetensors",
    "log.jsonl",
    "emitters.json",
    "emitter_masks",
];

/// Room kept free beyond an output's estimated size (file-system metadata, the temporaries).
const FREE_MARGIN: u64 = 16 << 20;

/// `path` made absolute against the working directory, with `.` and `..` folded and the part
/// that exists resolved through symbolic links, so that two spellings of one place compare equal.
pub fn absolute(path: &Path) -> PathBuf {
    let joined = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .map(|d| d.join(path))
            .unwrap_or_else(|_| path.to_path_buf())
    };
    let mut lexical = PathBuf::new();
    for c in joined.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                lexical.pop();
            }
            c => lexical.push(c),
        }
    }
    // Resolve the longest existing prefix (symlinks), keep the rest as written.
    let mut rest = Vec::new();
    let mut head = lexical.clone();
    loop {
        if let Ok(canonical) = head.canonicalize() {
            let mut out = canonical;
            for part in rest.iter().rev() {
                out.push(part);
            }
            return out;
        }
        match (head.file_name().map(|n| n.to_os_string()), head.parent()) {
            (Some(name), Some(parent)) => {
                rest.push(name);
                head = parent.to_path_buf();
            }
            _ => return lexical,
        }
    }
}

/// Whether `dir` is a dataset folder.
pub fn is_dataset(dir: &Path) -> bool {
    DATASET_MARKERS.iter().any(|m| dir.join(m).is_file())
}

/// Whether `dir` is a training run's folder.
pub fn is_run(dir: &Path) -> bool {
    dir.join(RUN_MARKER).is_file()
}

/// Whether `abs` is one of a run's own files or folders ([`RUN_FILES`]) or lies inside one.
fn in_run_own(abs: &Path) -> bool {
    abs.ancestors().any(|a| {
        let name = a.file_name().and_then(|n| n.to_str()).unwrap_or("");
        RUN_FILES.contains(&name) && a.parent().is_some_and(is_run)
    })
}

/// The dataset folder that `path` is or lies inside, if any.
fn dataset_around(path: &Path) -> Option<PathBuf> {
    path.ancestors().find(|a| is_dataset(a)).map(Path::to_path_buf)
}

/// The nearest existing ancestor of `path` (itself included), which must be a folder for `path`
/// to be created.
fn existing_ancestor(path: &Path) -> Option<&Path> {
    path.ancestors().find(|a| a.exists())
}

/// Refuses an output `shown` (as the user wrote it) when `at` (absolute: the output itself, or
/// the folder it will be created in) is a dataset folder or lies in one.
pub fn check_outside_datasets(flag: &str, shown: &Path, at: &Path) -> Result<()> {
    match dataset_around(at) {
        Some(dataset) => Err(DataError::invalid(format!(
            "{flag} {}: lies in the dataset {}; i2sdf never writes into a dataset: choose a place outside it",
            shown.display(),
            dataset.display()
        ))),
        None => Ok(()),
    }
}

/// Refuses a `path` (absolute) that is, contains or lies in one of the `inputs`.
pub fn check_inputs(flag: &str, path: &Path, inputs: &[&Path]) -> Result<()> {
    for input in inputs {
        let input = absolute(input);
        if path.starts_with(&input) || input.starts_with(path) {
            return Err(DataError::invalid(format!(
                "{flag} {}: overlaps the input {} this command reads: choose another place",
                path.display(),
                input.display()
            )));
        }
    }
    Ok(())
}

/// That something can be created at `path` (absolute): the nearest existing folder above it is one
/// that accepts a new file, with `bytes` (if known) free there.
fn check_writable(flag: &str, path: &Path, bytes: Option<u64>) -> Result<()> {
    // The output itself may exist (to be replaced): what must accept new entries is above it.
    let Some(base) = path.parent().and_then(existing_ancestor) else {
        return Err(DataError::io(path, format!("{flag}: no existing folder above it")));
    };
    if !base.is_dir() {
        // A place that cannot be created is a failed write (exit 1), as when creating it fails.
        return Err(DataError::io(
            path,
            format!(
                "{flag}: {} is a file, so nothing can be created below it",
                base.display()
            ),
        ));
    }
    // Permission bits do not tell (root ignores them; a read-only mount or a full quota does not
    // show in them): try.
    let probe = base.join(format!(".i2sdf-write-probe-{}", std::process::id()));
    match std::fs::File::create(&probe) {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
        }
        Err(e) => {
            return Err(DataError::io(
                path,
                format!("{flag}: cannot write in {}: {e}", base.display()),
            ))
        }
    }
    if let (Some(need), Some(free)) = (bytes, free_bytes(base)) {
        if free < need + FREE_MARGIN {
            return Err(DataError::io(
                path,
                format!(
                    "{flag}: needs about {} but {} has {} free",
                    human_bytes(need),
                    base.display(),
                    human_bytes(free)
                ),
            ));
        }
    }
    Ok(())
}

/// Bytes available to this user on the file system holding `dir`.
pub fn free_bytes(dir: &Path) -> Option<u64> {
    let s = rustix::fs::statvfs(dir).ok()?;
    Some(s.f_bavail.saturating_mul(s.f_frsize))
}

/// A byte count for messages (`12.3 MiB`).
pub fn human_bytes(b: u64) -> String {
    let b = b as f64;
    let (v, unit) = if b >= (1u64 << 30) as f64 {
        (b / (1u64 << 30) as f64, "GiB")
    } else if b >= (1u64 << 20) as f64 {
        (b / (1u64 << 20) as f64, "MiB")
    } else {
        (b / 1024.0, "KiB")
    };
    format!("{v:.1} {unit}")
}

/// An output file a command was asked to write.
#[derive(Clone, Debug)]
pub struct OutputFile<'a> {
    /// The flag that named it (`--out`), for messages.
    pub flag: &'a str,
    pub path: &'a Path,
    /// Accepted extensions, lower case without the dot (`["json"]`); empty: any.
    pub extensions: &'a [&'a str],
    /// Replace an existing file (`--force`).
    pub force: bool,
    /// Paths the command reads (datasets, specs, metrics files): the output may not overlap them.
    /// A run is not among them: the run-folder rules above say what may be written in one.
    pub inputs: &'a [&'a Path],
    /// Estimated size, when known, for the free-space check.
    pub bytes: Option<u64>,
}

impl OutputFile<'_> {
    /// Every check of an output file, before any work. Returns the path as given.
    pub fn check(&self) -> Result<PathBuf> {
        let flag = self.flag;
        let path = self.path;
        if path.is_dir() {
            return Err(DataError::invalid(format!(
                "{flag} {}: is a folder; give a file name",
                path.display()
            )));
        }
        if !self.extensions.is_empty() {
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase)
                .unwrap_or_default();
            if !self.extensions.contains(&ext.as_str()) {
                let want: Vec<String> = self.extensions.iter().map(|e| format!(".{e}")).collect();
                return Err(DataError::invalid(format!(
                    "{flag} {}: must end in {} (the format written)",
                    path.display(),
                    want.join(" or ")
                )));
            }
        }
        let abs = absolute(path);
        check_outside_datasets(flag, path, &abs)?;
        check_inputs(flag, &abs, self.inputs)?;
        if in_run_own(&abs) {
            return Err(DataError::invalid(format!(
                "{flag} {}: is the run's own file; only `train` writes it",
                path.display()
            )));
        }
        if path.exists() && !self.force {
            return Err(DataError::invalid(format!(
                "{flag} {}: exists; pass --force to replace it",
                path.display()
            )));
        }
        check_writable(flag, &abs, self.bytes)?;
        Ok(path.to_path_buf())
    }
}

/// An output folder a command was asked to fill.
pub struct OutputDir<'a> {
    pub flag: &'a str,
    pub path: &'a Path,
    /// Replace a previous output of the same command (`--force`).
    pub force: bool,
    /// Whether an existing, non-empty folder is a previous output of this command (and so may be
    /// replaced with `--force`).
    pub previous: &'a dyn Fn(&Path) -> bool,
    /// What this command's output is called in messages ("a render", "a report").
    pub what: &'a str,
    pub inputs: &'a [&'a Path],
    pub bytes: Option<u64>,
}

impl OutputDir<'_> {
    /// Every check of an output folder, before any work; then a staging folder beside it, where
    /// the command writes and which [`StagedDir::commit`] moves into place.
    pub fn check(&self) -> Result<StagedDir> {
        let flag = self.flag;
        let path = self.path;
        if path.is_file() {
            return Err(DataError::invalid(format!(
                "{flag} {}: is a file; give a folder (created if absent)",
                path.display()
            )));
        }
        let abs = absolute(path);
        // The folder itself may be a dataset only to be replaced as a previous output (a
        // `synth --force`); below, the non-empty rules decide that.
        check_outside_datasets(flag, path, abs.parent().unwrap_or(&abs))?;
        if is_dataset(&abs) && !(self.previous)(&abs) {
            return Err(DataError::invalid(format!(
                "{flag} {}: is a dataset; i2sdf never writes into a dataset: choose a new folder",
                path.display()
            )));
        }
        check_inputs(flag, &abs, self.inputs)?;
        if is_run(&abs) {
            return Err(DataError::invalid(format!(
                "{flag} {}: is a training run; choose a folder of its own (a new subfolder of the run is fine)",
                path.display()
            )));
        }
        if in_run_own(&abs) {
            return Err(DataError::invalid(format!(
                "{flag} {}: is the run's own folder; only `train` writes it",
                path.display()
            )));
        }
        let replace = non_empty(&abs);
        if replace {
            if !self.force {
                return Err(DataError::invalid(format!(
                    "{flag} {}: exists and is not empty; pass --force to replace {} there, or choose a new folder",
                    path.display(),
                    self.what
                )));
            }
            if !(self.previous)(&abs) {
                return Err(DataError::invalid(format!(
                    "{flag} {}: holds files that are not {}; --force replaces only a previous output: choose a new folder",
                    path.display(),
                    self.what
                )));
            }
        }
        check_writable(flag, &abs, self.bytes)?;
        StagedDir::new(&abs, path)
    }
}

/// Whether `dir` exists and holds anything.
fn non_empty(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|mut d| d.next().is_some())
}

/// The names in `dir` (none if it cannot be read).
pub fn entries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default()
}

/// A folder being built aside: `stage` (a hidden sibling of the target, or inside its nearest
/// existing ancestor, so on the same file system) until [`StagedDir::commit`] renames it into
/// place. Dropped without a commit, it removes the stage: the target is as it was.
#[derive(Debug)]
pub struct StagedDir {
    /// The final folder, absolute.
    target: PathBuf,
    /// As the user wrote it, for messages.
    shown: PathBuf,
    stage: PathBuf,
    committed: bool,
}

impl StagedDir {
    fn new(target: &Path, shown: &Path) -> Result<Self> {
        let base = existing_ancestor(target)
            .filter(|b| *b != target)
            .unwrap_or_else(|| target.parent().unwrap_or(target));
        let name = target.file_name().and_then(|n| n.to_str()).unwrap_or("out");
        remove_stale_stages(base, name);
        let stage = base.join(format!(".{name}.{}.partial", std::process::id()));
        if stage.exists() {
            std::fs::remove_dir_all(&stage).map_err(|e| DataError::io(&stage, format!("cannot clear: {e}")))?;
        }
        std::fs::create_dir(&stage).map_err(|e| DataError::io(&stage, format!("cannot create: {e}")))?;
        Ok(StagedDir {
            target: target.to_path_buf(),
            shown: shown.to_path_buf(),
            stage,
            committed: false,
        })
    }

    /// Where the command writes until the commit.
    pub fn path(&self) -> &Path {
        &self.stage
    }

    /// The folder as the user named it.
    pub fn shown(&self) -> &Path {
        &self.shown
    }

    /// Moves the staged folder into place, replacing a previous output (checked when staged):
    /// the old one is renamed aside first and removed last, so at every moment the target is
    /// either the old output or the new one.
    pub fn commit(mut self) -> Result<PathBuf> {
        if let Some(parent) = self.target.parent() {
            std::fs::create_dir_all(parent).map_err(|e| DataError::io(parent, format!("cannot create: {e}")))?;
        }
        let old = self.target.exists().then(|| {
            let name = self.target.file_name().and_then(|n| n.to_str()).unwrap_or("out");
            self.target
                .with_file_name(format!(".{name}.{}.old", std::process::id()))
        });
        if let Some(old) = &old {
            // An empty folder (the only kind allowed here without --force) is simply removed.
            let moved = if non_empty(&self.target) {
                std::fs::rename(&self.target, old)
            } else {
                std::fs::remove_dir(&self.target)
            };
            moved.map_err(|e| DataError::io(&self.target, format!("cannot move the previous output aside: {e}")))?;
        }
        if let Err(e) = std::fs::rename(&self.stage, &self.target) {
            if let Some(old) = old.as_ref().filter(|o| o.exists()) {
                let _ = std::fs::rename(old, &self.target);
            }
            return Err(DataError::io(&self.target, format!("cannot move into place: {e}")));
        }
        self.committed = true;
        if let Some(old) = old.filter(|o| o.exists()) {
            let _ = std::fs::remove_dir_all(old);
        }
        Ok(self.shown.clone())
    }
}

/// Removes what a killed command left in `base` while staging `name`: `.NAME.PID.partial` and
/// `.NAME.PID.old` folders of processes that no longer run (a live one's are its own).
fn remove_stale_stages(base: &Path, name: &str) {
    for entry in entries(base) {
        let Some(rest) = entry.strip_prefix(&format!(".{name}.")) else {
            continue;
        };
        let Some(pid) = rest.strip_suffix(".partial").or_else(|| rest.strip_suffix(".old")) else {
            continue;
        };
        let alive = Path::new("/proc").join(pid).exists();
        if pid.parse::<u32>().is_ok() && !alive {
            let _ = std::fs::remove_dir_all(base.join(&entry));
        }
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.stage);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn never(_: &Path) -> bool {
        false
    }

    fn file<'a>(path: &'a Path, force: bool) -> OutputFile<'a> {
        OutputFile {
            flag: "--out",
            path,
            extensions: &["json"],
            force,
            inputs: &[],
            bytes: None,
        }
    }

    #[test]
    fn absolute_folds_dots_and_keeps_missing_parts() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().canonicalize().unwrap();
        let p = dir.path().join("a/../b/./c.json");
        assert_eq!(absolute(&p), real.join("b/c.json"));
    }

    #[test]
    fn files_in_a_dataset_or_over_a_run_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("scene");
        std::fs::create_dir_all(data.join("depth")).unwrap();
        std::fs::write(data.join("transforms.json"), "{}").unwrap();
        let e = file(&data.join("depth/m.json"), true).check().unwrap_err();
        assert!(
            e.is_bad_input() && e.to_string().contains("never writes into a dataset"),
            "{e}"
        );
        let run = dir.path().join("run");
        std::fs::create_dir(&run).unwrap();
        std::fs::write(run.join("run.json"), "{}").unwrap();
        let e = file(&run.join("run.json"), true).check().unwrap_err();
        assert!(e.to_string().contains("run's own file"), "{e}");
        // Nor inside the run's own folders.
        let e = file(&run.join("emitter_masks").join("a.json"), true)
            .check()
            .unwrap_err();
        assert!(e.to_string().contains("run's own file"), "{e}");
        // A new file inside a run is fine.
        assert!(file(&run.join("metrics.json"), false).check().is_ok());
        assert!(!run.join("metrics.json").exists());
    }

    #[test]
    fn existing_files_need_force_and_extensions_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let m = dir.path().join("m.json");
        std::fs::write(&m, "old").unwrap();
        assert!(file(&m, false).check().unwrap_err().to_string().contains("--force"));
        file(&m, true).check().unwrap();
        let e = file(&dir.path().join("m.obj"), true).check().unwrap_err();
        assert!(e.to_string().contains("must end in .json"), "{e}");
        let e = file(dir.path(), true).check().unwrap_err();
        assert!(e.to_string().contains("is a folder"), "{e}");
        // Below a regular file nothing can be created.
        let e = file(&m.join("x.json"), true).check().unwrap_err();
        assert!(!e.is_bad_input() && e.to_string().contains("is a file"), "{e}");
        assert_eq!(std::fs::read(&m).unwrap(), b"old");
        // No probe left behind.
        assert_eq!(entries(dir.path()), vec!["m.json".to_string()]);
    }

    #[test]
    fn staged_folders_replace_only_previous_outputs_and_only_at_commit() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("mine.txt"), "user").unwrap();
        let looks = |d: &Path| entries(d).iter().all(|n| n.ends_with(".png"));
        let check = |force: bool, previous: &dyn Fn(&Path) -> bool| {
            OutputDir {
                flag: "--out",
                path: &out,
                force,
                previous,
                what: "a render",
                inputs: &[],
                bytes: None,
            }
            .check()
        };
        assert!(check(false, &looks).unwrap_err().to_string().contains("--force"));
        assert!(check(true, &looks).unwrap_err().to_string().contains("not a render"));
        std::fs::remove_file(out.join("mine.txt")).unwrap();
        std::fs::write(out.join("a.png"), "old").unwrap();
        // A failed command (the stage dropped) leaves the previous output.
        {
            let staged = check(true, &looks).unwrap();
            std::fs::write(staged.path().join("b.png"), "new").unwrap();
        }
        assert_eq!(entries(&out), vec!["a.png".to_string()]);
        let staged = check(true, &looks).unwrap();
        std::fs::write(staged.path().join("b.png"), "new").unwrap();
        staged.commit().unwrap();
        assert_eq!(entries(&out), vec!["b.png".to_string()]);
        assert_eq!(entries(dir.path()), vec!["out".to_string()]);
        // An empty folder, or none, needs no --force.
        let fresh = dir.path().join("deep/er/out");
        let staged = OutputDir {
            flag: "--out",
            path: &fresh,
            force: false,
            previous: &never,
            what: "a render",
            inputs: &[],
            bytes: None,
        }
        .check()
        .unwrap();
        assert!(
            !dir.path().join("deep").exists(),
            "nothing is created before the commit"
        );
        drop(staged);
        // What a killed process left (a PID that does not run) goes when the folder is staged again.
        let stale = dir.path().join(".out.4294967.partial");
        std::fs::create_dir(&stale).unwrap();
        let staged = OutputDir {
            flag: "--out",
            path: &fresh,
            force: false,
            previous: &never,
            what: "a render",
            inputs: &[],
            bytes: None,
        }
        .check()
        .unwrap();
        assert!(!stale.exists());
        staged.commit().unwrap();
        assert!(fresh.is_dir());
    }

    #[test]
    fn a_run_folder_or_an_input_is_not_an_output_folder() {
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("run");
        std::fs::create_dir(&run).unwrap();
        std::fs::write(run.join("run.json"), "{}").unwrap();
        let check = |path: &Path, inputs: &[&Path]| {
            OutputDir {
                flag: "--out",
                path,
                force: true,
                previous: &|_: &Path| true,
                what: "a render",
                inputs,
                bytes: None,
            }
            .check()
        };
        assert!(check(&run, &[]).unwrap_err().to_string().contains("is a training run"));
        assert!(check(&run.join("render"), &[]).is_ok());
        let e = check(&run.join("emitter_masks"), &[]).unwrap_err().to_string();
        assert!(e.contains("run's own folder"), "{e}");
        let spec = dir.path().join("spec");
        std::fs::create_dir(&spec).unwrap();
        assert!(check(&spec, &[&spec])
            .unwrap_err()
            .to_string()
            .contains("overlaps the input"));
        let e = check(&dir.path().join("x"), &[]).map(|_| ()).map_err(|e| e.to_string());
        assert!(e.is_ok());
    }

    #[test]
    fn free_space_is_checked_where_the_size_is_known() {
        let dir = tempfile::tempdir().unwrap();
        let m = dir.path().join("m.json");
        let mut f = file(&m, false);
        f.bytes = Some(u64::MAX / 4);
        let e = f.check().unwrap_err();
        assert!(!e.is_bad_input() && e.to_string().contains("free"), "{e}");
        f.bytes = Some(1);
        assert!(f.check().is_ok());
    }
}
