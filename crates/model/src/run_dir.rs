//! The run directory: everything a run writes, in one place, so `mesh`, `render`, `eval`, `edit`
//! and `--resume` find it without depending on the trainer.
//!
//! ```text
//! RUN/config.toml                the full configuration in force (defaults filled in)
//! RUN/run.json                   dataset path, normalization, per-stage progress and timings
//! RUN/checkpoint.safetensors     fields + optimizer state, written atomically
//! RUN/log.jsonl                  one JSON object of losses per logged step
//! RUN/poses.json                 the training views' corrected poses (when stage 1 corrects them)
//! RUN/emitter_masks/NAME.png     emitter masks found from the images (datasets without them)
//! ```
//!
//! The configuration is stored as TOML text: its type (the trainer's `TrainConfig`) lives above
//! this crate, so the trainer parses it back; commands that only read fields never need it.

use i2sdf_data::fingerprint::DatasetFingerprint;
use i2sdf_data::{imageio, Bounds, DataError, Normalization};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Progress of one training stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StageProgress {
    /// Iterations completed (the checkpoint's).
    pub iterations: u64,
    pub done: bool,
    /// Wall-clock seconds of training, summed over resumed sessions.
    pub seconds: f64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(from = "RunInfoFile")]
pub struct RunInfo {
    /// The dataset the run was trained on: its absolute path (runs written before this was so
    /// hold the path as typed, relative to where `train` ran).
    pub data: String,
    /// What identifies that dataset whatever its path (training views, cameras, images), so that
    /// a `--data` naming other data is said; `None` in runs written before it was kept.
    pub data_fingerprint: Option<DatasetFingerprint>,
    pub normalization: Option<Normalization>,
    /// The dataset's scene bounds in world units (where `mesh` looks for the surface).
    pub bounds: Option<Bounds>,
    /// Stage 1 (geometry, radiance, emitters).
    pub stage1: StageProgress,
    /// Stage 2 (materials, emissions); `None` until it starts.
    pub stage2: Option<StageProgress>,
}

impl RunInfo {
    /// A warning when `dataset` is not the data the run was trained on (by the fingerprint that
    /// `run.json` keeps; runs without one are not checked).
    pub fn dataset_mismatch(&self, dataset: &i2sdf_data::Dataset, data: &Path) -> Option<String> {
        let run = self.data_fingerprint.as_ref()?;
        let diff = DatasetFingerprint::of(dataset).differences(run);
        (!diff.is_empty()).then(|| {
            format!(
                "warning: {} is not the dataset the run was trained on ({}): {}",
                data.display(),
                self.data,
                diff.join("; ")
            )
        })
    }

    /// The progress record of a stage by its key (`"stage1"`, `"stage2"`), created on first use.
    pub fn stage_mut(&mut self, key: &str) -> Result<&mut StageProgress, DataError> {
        match key {
            "stage1" => Ok(&mut self.stage1),
            "stage2" => Ok(self.stage2.get_or_insert_with(StageProgress::default)),
            other => Err(DataError::failed(format!("unknown training stage {other:?}"))),
        }
    }

    /// The progress of a stage by its key, if it has started.
    pub fn stage(&self, key: &str) -> Option<&StageProgress> {
        match key {
            "stage1" => Some(&self.stage1),
            "stage2" => self.stage2.as_ref(),
            _ => None,
        }
    }
}

/// What `run.json` may hold: the current layout, and the flat `stage1_*` keys that runs written
/// before the per-stage records used (so an existing run still opens).
#[derive(Deserialize)]
struct RunInfoFile {
    data: String,
    #[serde(default)]
    data_fingerprint: Option<DatasetFingerprint>,
    #[serde(default)]
    normalization: Option<Normalization>,
    #[serde(default)]
    bounds: Option<Bounds>,
    #[serde(default)]
    stage1: Option<StageProgress>,
    #[serde(default)]
    stage2: Option<StageProgress>,
    #[serde(default)]
    stage1_iterations: Option<u64>,
    #[serde(default)]
    stage1_done: Option<bool>,
    #[serde(default)]
    stage1_seconds: Option<f64>,
    #[serde(default)]
    stage2_seconds: Option<f64>,
}

impl From<RunInfoFile> for RunInfo {
    fn from(f: RunInfoFile) -> Self {
        let stage1 = f.stage1.unwrap_or(StageProgress {
            iterations: f.stage1_iterations.unwrap_or(0),
            done: f.stage1_done.unwrap_or(false),
            seconds: f.stage1_seconds.unwrap_or(0.0),
        });
        let stage2 = f.stage2.or(f.stage2_seconds.map(|seconds| StageProgress {
            seconds,
            ..Default::default()
        }));
        RunInfo {
            data: f.data,
            data_fingerprint: f.data_fingerprint,
            normalization: f.normalization,
            bounds: f.bounds,
            stage1,
            stage2,
        }
    }
}

pub struct RunDir {
    pub root: PathBuf,
}

impl RunDir {
    pub fn new(root: &Path) -> Self {
        RunDir {
            root: root.to_path_buf(),
        }
    }

    pub fn config_path(&self) -> PathBuf {
        self.root.join("config.toml")
    }
    pub fn info_path(&self) -> PathBuf {
        self.root.join("run.json")
    }
    /// Stage 1's checkpoint: the geometry, radiance and emitter fields (frozen afterwards).
    pub fn checkpoint_path(&self) -> PathBuf {
        self.root.join("checkpoint.safetensors")
    }
    /// Stage 2's checkpoint: material fields, emission table and its optimizer state. A file of
    /// its own, so that stage 2 never rewrites the frozen stage-1 fields it stands on (and can be
    /// run again from them).
    pub fn stage2_checkpoint_path(&self) -> PathBuf {
        self.root.join("stage2.safetensors")
    }
    /// The checkpoint of the stage with this key (`stage1`, `stage2`).
    pub fn stage_checkpoint_path(&self, key: &str) -> PathBuf {
        match key {
            "stage2" => self.stage2_checkpoint_path(),
            _ => self.checkpoint_path(),
        }
    }
    /// `RUN/poses.json`: the training views' poses as stage 1 corrected them.
    pub fn poses_path(&self) -> PathBuf {
        self.root.join("poses.json")
    }
    /// `RUN/emitters.json`: stage 2's emitters in world units.
    pub fn emitters_path(&self) -> PathBuf {
        self.root.join("emitters.json")
    }
    pub fn log_path(&self) -> PathBuf {
        self.root.join("log.jsonl")
    }
    /// `RUN/emitter_masks/`: the emitter masks training found from the images, one PNG per
    /// training view (`i2sdf_train::maps`), which every later session of the run reads back.
    pub fn emitter_masks_dir(&self) -> PathBuf {
        self.root.join("emitter_masks")
    }

    /// The bad-input error for a stage-2 product asked of a run without stage 2.
    pub fn no_stage2(&self) -> DataError {
        DataError::file(
            self.stage2_checkpoint_path(),
            "no stage 2: train --stage material first",
        )
    }

    pub fn exists(&self) -> bool {
        self.info_path().is_file()
    }

    /// The dataset a command on this run reads: `data` (its `--data`) when given, else the one
    /// `run.json` records — refused, saying where that path came from and that `--data`
    /// overrides it, when nothing is there any more.
    pub fn dataset_path(&self, info: &RunInfo, data: Option<&Path>) -> Result<PathBuf, DataError> {
        if let Some(d) = data {
            return Ok(d.to_path_buf());
        }
        let recorded = PathBuf::from(&info.data);
        if recorded.exists() {
            return Ok(recorded);
        }
        Err(DataError::field(
            self.info_path(),
            "data",
            format!(
                "the dataset the run was trained on, {} (as recorded here), is not there{}: pass --data SCENE to use it where it is now",
                recorded.display(),
                if recorded.is_relative() {
                    " (a relative path, read from the current folder)"
                } else {
                    ""
                }
            ),
        ))
    }

    /// The files of this run that no other command may write ([`i2sdf_data::output::RUN_FILES`]
    /// lists their names for the output checks).
    pub fn own_files(&self) -> [PathBuf; 8] {
        [
            self.poses_path(),
            self.info_path(),
            self.config_path(),
            self.checkpoint_path(),
            self.stage2_checkpoint_path(),
            self.log_path(),
            self.emitters_path(),
            self.emitter_masks_dir(),
        ]
    }

    /// `RUN/snapshots/KEY-SECONDSs/`: a snapshot of stage `key` at that wall time, itself a run
    /// directory (`train.snapshot_seconds`).
    pub fn snapshot(&self, key: &str, seconds: f32) -> RunDir {
        // Whole seconds zero-padded, so that the folders sort by time.
        let at = if seconds.fract() == 0.0 {
            format!("{:05}", seconds as u64)
        } else {
            format!("{seconds}")
        };
        RunDir::new(&self.root.join("snapshots").join(format!("{key}-{at}s")))
    }

    pub fn create(&self) -> Result<(), DataError> {
        std::fs::create_dir_all(&self.root)
            .map_err(|e| DataError::io(&self.root, format!("cannot create the run directory: {e}")))
    }

    /// Writes the configuration (TOML text), atomically.
    pub fn write_config_toml(&self, toml: &str) -> Result<(), DataError> {
        imageio::write_bytes_atomic(&self.config_path(), toml.as_bytes())
    }

    /// The configuration's TOML text (parsed by the trainer's config type).
    pub fn read_config_toml(&self) -> Result<String, DataError> {
        let p = self.config_path();
        std::fs::read_to_string(&p)
            .map_err(|e| DataError::file(&p, format!("cannot read (is this a run directory?): {e}")))
    }

    pub fn write_info(&self, info: &RunInfo) -> Result<(), DataError> {
        let text = serde_json::to_string_pretty(info).expect("run info serializes");
        imageio::write_bytes_atomic(&self.info_path(), text.as_bytes())
    }

    pub fn read_info(&self) -> Result<RunInfo, DataError> {
        let p = self.info_path();
        let text = std::fs::read_to_string(&p)
            .map_err(|e| DataError::file(&p, format!("cannot read (is this a run directory?): {e}")))?;
        serde_json::from_str(&text).map_err(|e| DataError::file(&p, format!("invalid run info: {e}")))
    }

    /// Appends one record to the loss log. The log is advisory: a resumed run appends after the
    /// last checkpoint's records, so the log may repeat the steps between the last checkpoint and
    /// the interruption (each record carries its iteration).
    pub fn append_log(&self, record: &serde_json::Value) -> Result<(), DataError> {
        let p = self.log_path();
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&p)
            .map_err(|e| DataError::io(&p, format!("cannot open: {e}")))?;
        writeln!(f, "{record}").map_err(|e| DataError::io(&p, format!("cannot write: {e}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(&dir.path().join("run"));
        assert!(!run.exists());
        run.create().unwrap();
        run.write_config_toml("[train]\niterations = 123\n").unwrap();
        assert_eq!(run.read_config_toml().unwrap(), "[train]\niterations = 123\n");
        let mut info = RunInfo {
            data: "x".into(),
            ..Default::default()
        };
        info.stage_mut("stage1").unwrap().iterations = 5;
        info.stage_mut("stage2").unwrap().seconds = 2.5;
        assert!(info.stage_mut("stage3").is_err());
        run.write_info(&info).unwrap();
        assert!(run.exists());
        assert_eq!(run.read_info().unwrap(), info);
        run.append_log(&serde_json::json!({"it": 1})).unwrap();
        run.append_log(&serde_json::json!({"it": 2})).unwrap();
        assert_eq!(std::fs::read_to_string(run.log_path()).unwrap().lines().count(), 2);
        let e = RunDir::new(dir.path()).read_info().unwrap_err().to_string();
        assert!(e.contains("run.json"), "{e}");
    }

    #[test]
    fn the_output_checks_know_every_run_file() {
        let run = RunDir::new(Path::new("r"));
        for p in run.own_files() {
            let name = p.file_name().unwrap().to_str().unwrap();
            assert!(i2sdf_data::output::RUN_FILES.contains(&name), "{name}");
        }
        assert_eq!(run.own_files().len(), i2sdf_data::output::RUN_FILES.len());
        assert_eq!(i2sdf_data::output::RUN_MARKER, "run.json");
    }

    #[test]
    fn a_missing_dataset_names_run_json_and_the_override() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        let info = RunInfo {
            data: dir.path().join("gone").display().to_string(),
            ..Default::default()
        };
        let e = run.dataset_path(&info, None).unwrap_err();
        let msg = e.to_string();
        assert!(
            e.is_bad_input() && msg.contains("run.json") && msg.contains("--data") && msg.contains("gone"),
            "{msg}"
        );
        assert_eq!(
            run.dataset_path(&info, Some(Path::new("x"))).unwrap(),
            PathBuf::from("x")
        );
    }

    /// A `run.json` written before the per-stage records still opens.
    #[test]
    fn reads_the_flat_layout() {
        let old = r#"{"data": "scene", "normalization": null, "bounds": null,
            "stage1_iterations": 500, "stage1_done": true, "stage1_seconds": 12.5, "stage2_seconds": null}"#;
        let info: RunInfo = serde_json::from_str(old).unwrap();
        assert_eq!(
            info.stage1,
            StageProgress {
                iterations: 500,
                done: true,
                seconds: 12.5
            }
        );
        assert_eq!(info.stage2, None);
    }
}
