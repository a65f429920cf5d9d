//! The run directory: everything a run writes, in one place, so `mesh`, `render`, `eval` and
//! `--resume` find it.
//!
//! ```text
//! RUN/config.toml                the full configuration in force (defaults filled in)
//! RUN/run.json                   dataset path, normalization, stage progress and timings
//! RUN/checkpoint.safetensors     fields + optimizer state, written atomically
//! RUN/log.jsonl                  one JSON object of losses per logged step
//! ```

use crate::config::TrainConfig;
use i2sdf_data::{imageio, Bounds, DataError, Normalization};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// The dataset the run was trained on (as given on the command line).
    pub data: String,
    pub normalization: Option<Normalization>,
    /// The dataset's scene bounds in world units (where `mesh` looks for the surface).
    pub bounds: Option<Bounds>,
    /// Iterations of stage 1 completed (the checkpoint's).
    pub stage1_iterations: u64,
    pub stage1_done: bool,
    /// Wall-clock seconds of training, summed over resumed sessions.
    pub stage1_seconds: f64,
    pub stage2_seconds: Option<f64>,
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
    pub fn checkpoint_path(&self) -> PathBuf {
        self.root.join("checkpoint.safetensors")
    }
    pub fn log_path(&self) -> PathBuf {
        self.root.join("log.jsonl")
    }

    pub fn exists(&self) -> bool {
        self.info_path().is_file()
    }

    pub fn create(&self) -> Result<(), DataError> {
        std::fs::create_dir_all(&self.root)
            .map_err(|e| DataError::io(&self.root, format!("cannot create the run directory: {e}")))
    }

    pub fn write_config(&self, c: &TrainConfig) -> Result<(), DataError> {
        imageio::write_bytes_atomic(&self.config_path(), c.to_toml().as_bytes())
    }

    pub fn read_config(&self) -> Result<TrainConfig, DataError> {
        TrainConfig::load(Some(&self.config_path()), &[])
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
        let mut c = TrainConfig::default();
        c.train.iterations = 123;
        run.write_config(&c).unwrap();
        assert_eq!(run.read_config().unwrap(), c);
        let info = RunInfo {
            data: "x".into(),
            stage1_iterations: 5,
            ..Default::default()
        };
        run.write_info(&info).unwrap();
        assert!(run.exists());
        assert_eq!(run.read_info().unwrap(), info);
        run.append_log(&serde_json::json!({"it": 1})).unwrap();
        run.append_log(&serde_json::json!({"it": 2})).unwrap();
        assert_eq!(std::fs::read_to_string(run.log_path()).unwrap().lines().count(), 2);
        let e = RunDir::new(dir.path()).read_info().unwrap_err().to_string();
        assert!(e.contains("run.json"), "{e}");
    }
}
