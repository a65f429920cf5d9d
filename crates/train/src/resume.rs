//! What makes a run safe to continue: the checks `--resume` (and stage 2 on a stage-1 run) makes
//! before anything is written — the same dataset ([`DatasetFingerprint`], kept in the stage-1
//! checkpoint's metadata) and a compatible configuration ([`config_changes`]) — and the repairs of
//! what a killed process leaves: temporaries of atomic writes and a torn last log line.

use crate::config::TrainConfig;
pub use i2sdf_data::fingerprint::DatasetFingerprint;
use i2sdf_data::{DataError, Dataset};
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Write};
use std::path::Path;

/// The checkpoint metadata key of the dataset's fingerprint.
pub const DATASET_META: &str = "dataset";

/// The metadata of a safetensors file, reading only its header.
pub fn checkpoint_metadata(path: &Path) -> Result<HashMap<String, String>, DataError> {
    let bad = |m: String| DataError::file(path, m);
    let mut f = std::fs::File::open(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let mut len = [0u8; 8];
    f.read_exact(&mut len)
        .map_err(|e| bad(format!("not a checkpoint: {e}")))?;
    let len = u64::from_le_bytes(len);
    let size = f.metadata().map(|m| m.len()).unwrap_or(0);
    if len > size.saturating_sub(8) || len > 100 << 20 {
        return Err(bad(format!("not a checkpoint: a header of {len} bytes")));
    }
    let mut header = vec![0u8; len as usize];
    f.read_exact(&mut header)
        .map_err(|e| bad(format!("not a checkpoint: {e}")))?;
    #[derive(Deserialize)]
    struct Header {
        #[serde(rename = "__metadata__", default)]
        metadata: HashMap<String, String>,
    }
    let h: Header = serde_json::from_slice(&header).map_err(|e| bad(format!("not a checkpoint: {e}")))?;
    Ok(h.metadata)
}

/// Refuses `dataset` as bad input when the stage-1 checkpoint at `checkpoint` was trained on
/// other data: names both datasets (`run_data` as the run recorded it) and what differs.
/// Checkpoints written before fingerprints were kept are not checked here (the caller still
/// compares the normalization).
pub fn check_dataset(checkpoint: &Path, run_data: &str, data_arg: &str, dataset: &Dataset) -> Result<(), DataError> {
    let meta = checkpoint_metadata(checkpoint)?;
    let Some(text) = meta.get(DATASET_META) else {
        return Ok(());
    };
    let run: DatasetFingerprint = serde_json::from_str(text)
        .map_err(|e| DataError::field(checkpoint, DATASET_META, format!("invalid fingerprint: {e}")))?;
    let diff = DatasetFingerprint::of(dataset).differences(&run);
    if diff.is_empty() {
        return Ok(());
    }
    Err(DataError::invalid(format!(
        "--data {data_arg}: not the dataset the run was trained on ({run_data}, as {} records): {}",
        checkpoint.display(),
        diff.join("; ")
    )))
}

/// Keys that may change on resume: how often to checkpoint and log and on how many threads
/// (none changes what is computed), and the iteration totals (the user extends or shortens a
/// run; the schedules follow the new total).
const FREE_KEYS: [&str; 5] = [
    "train.checkpoint_every",
    "train.log_every",
    "train.threads",
    "train.iterations",
    "stage2.iterations",
];

/// The sections only stage 2 reads: free to change until stage 2 has a checkpoint.
pub const STAGE2_SECTIONS: [&str; 3] = ["stage2", "material", "lobes"];

/// Every leaf of a configuration as `section.key` → its TOML text.
fn leaves(config: &TrainConfig) -> BTreeMap<String, String> {
    fn walk(prefix: &str, v: &toml::Value, out: &mut BTreeMap<String, String>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let key = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    walk(&key, v, out);
                }
            }
            other => {
                out.insert(prefix.to_string(), other.to_string());
            }
        }
    }
    let mut out = BTreeMap::new();
    // Through the file's text: its f32 values print as written (0.1, not 0.10000000149…).
    let v: toml::Value = toml::from_str(&config.to_toml()).expect("the config's TOML parses");
    walk("", &v, &mut out);
    out
}

/// The keys of `new` that differ from `old` and may not, as `key: old → new`; `frozen_stage2`:
/// stage 2 has a checkpoint, so its sections are fixed too, and so is `stage2.iterations` where
/// stage 2 runs several fits (`[lobes]`): their boundaries follow it.
pub fn config_changes(old: &TrainConfig, new: &TrainConfig, frozen_stage2: bool) -> Vec<String> {
    let (a, b) = (leaves(old), leaves(new));
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    let missing = "(unset)".to_string();
    keys.into_iter()
        .filter(|k| {
            !FREE_KEYS.contains(&k.as_str())
                || (frozen_stage2 && k.as_str() == "stage2.iterations" && old.lobes.fits() > 1)
        })
        .filter(|k| frozen_stage2 || !STAGE2_SECTIONS.iter().any(|s| k.starts_with(&format!("{s}."))))
        .filter_map(|k| {
            let (x, y) = (a.get(k).unwrap_or(&missing), b.get(k).unwrap_or(&missing));
            (x != y).then(|| format!("{k}: {x} → {y}"))
        })
        .collect()
}

/// Refuses, as bad input, a configuration that changes what the run's checkpoints were trained
/// with; `what` says which run (for the message).
pub fn check_config(
    run_config: &Path,
    old: &TrainConfig,
    new: &TrainConfig,
    frozen_stage2: bool,
) -> Result<(), DataError> {
    refuse_changes(
        run_config,
        &format!(
            "the resumed run was trained with other values (only {} may change)",
            FREE_KEYS.join(", ")
        ),
        config_changes(old, new, frozen_stage2),
    )
}

/// Ok without `changes`; else bad input naming `run_config`: `why`, then each change.
fn refuse_changes(run_config: &Path, why: &str, changes: Vec<String>) -> Result<(), DataError> {
    if changes.is_empty() {
        return Ok(());
    }
    Err(DataError::file(run_config, format!("{why}: {}", changes.join("; "))))
}

/// Refuses, as bad input, a run configuration (`run_config`, `RUN/config.toml`) whose `[model]`
/// or `[material]` is not the one the stage-1 or stage-2 checkpoint (where there is one) was
/// built with, as their metadata records it: the fields are rebuilt from the checkpoint's own,
/// so an edit of the file's section would otherwise be ignored without a word (a `model.beta_min`
/// edited before a resume changed nothing). The differences are [`config_changes`]'.
pub fn check_trained_fields(
    run_config: &Path,
    config: &TrainConfig,
    stage1: &Path,
    stage2: &Path,
) -> Result<(), DataError> {
    let mut trained = config.clone();
    if let Some(m) = trained_entry(stage1, "model_config")? {
        trained.model = m;
    }
    if let Some(m) = trained_entry(stage2, "material_config")? {
        trained.material = m;
    }
    refuse_changes(
        run_config,
        "differs from what the run's checkpoints were trained with, and a trained field cannot change",
        config_changes(&trained, config, true),
    )
}

/// A checkpoint's metadata entry `key` as a configuration section; `None` without the file or
/// the entry, or where it does not parse (loading the checkpoint reports that in its own words).
fn trained_entry<C: serde::de::DeserializeOwned>(checkpoint: &Path, key: &str) -> Result<Option<C>, DataError> {
    if !checkpoint.is_file() {
        return Ok(None);
    }
    Ok(checkpoint_metadata(checkpoint)?
        .get(key)
        .and_then(|s| serde_json::from_str(s).ok()))
}

/// Removes what killed writers left in the run directory: the temporaries of atomic writes
/// (`.NAME.PID.partial.EXT`, of processes other than this one; a run has one trainer at a time),
/// and a last log line cut short (the record of a step whose checkpoint never happened anyway).
pub fn repair(root: &Path, log: &Path) -> Result<(), DataError> {
    let me = format!(".{}.partial.", std::process::id());
    if let Ok(entries) = std::fs::read_dir(root) {
        for e in entries.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            if name.starts_with('.') && name.contains(".partial.") && !name.contains(&me) {
                let p = e.path();
                std::fs::remove_file(&p)
                    .map_err(|err| DataError::io(&p, format!("cannot remove a stale temporary: {err}")))?;
            }
        }
    }
    if let Ok(bytes) = std::fs::read(log) {
        if !bytes.is_empty() && bytes.last() != Some(&b'\n') {
            let keep = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            let f = std::fs::OpenOptions::new()
                .write(true)
                .open(log)
                .map_err(|e| DataError::io(log, format!("cannot open: {e}")))?;
            f.set_len(keep as u64)
                .map_err(|e| DataError::io(log, format!("cannot cut its torn last line: {e}")))?;
        }
    }
    Ok(())
}

/// Appends one JSON record to the log in a single write, so a kill leaves whole lines or one
/// torn last line (which [`repair`] cuts), never a line spliced from two records.
pub fn append_record(log: &Path, record: &serde_json::Value) -> Result<(), DataError> {
    let line = format!("{record}\n");
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(log)
        .map_err(|e| DataError::io(log, format!("cannot open: {e}")))?;
    f.write_all(line.as_bytes())
        .map_err(|e| DataError::io(log, format!("cannot write: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_changes_name_the_key_and_both_values() {
        let mut old = TrainConfig::default();
        old.lobes.rhos = vec![0.5, 1.0];
        let mut new = old.clone();
        assert!(config_changes(&old, &new, true).is_empty());
        new.train.log_every += 1;
        new.train.iterations = crate::auto::Auto::Value(1);
        new.stage2.iterations += 1;
        // Free while stage 2 has no checkpoint, or fits once; not between the lobe choice's fits.
        assert!(config_changes(&old, &new, false).is_empty());
        assert_eq!(config_changes(&old, &new, true).len(), 1);
        let (mut old, mut new) = (old.clone(), new.clone());
        old.lobes.rhos.clear();
        new.lobes.rhos.clear();
        assert!(config_changes(&old, &new, true).is_empty());
        new.train.seed = 7;
        new.stage2.pixels += 1;
        let c = config_changes(&old, &new, false);
        assert_eq!(c, [format!("train.seed: {} → 7", old.train.seed)]);
        let c = config_changes(&old, &new, true);
        assert_eq!(c.len(), 2, "{c:?}");
        assert!(c[0].starts_with("stage2.pixels: "), "{c:?}");
    }

    #[test]
    fn repair_removes_stale_temporaries_and_a_torn_line() {
        let dir = tempfile::tempdir().unwrap();
        let stale = dir.path().join(".checkpoint.safetensors.999999999.partial.safetensors");
        let mine = dir
            .path()
            .join(format!(".run.json.{}.partial.json", std::process::id()));
        std::fs::write(&stale, b"half").unwrap();
        std::fs::write(&mine, b"mine").unwrap();
        let log = dir.path().join("log.jsonl");
        std::fs::write(&log, b"{\"a\":1}\n{\"b\":").unwrap();
        repair(dir.path(), &log).unwrap();
        assert!(!stale.exists() && mine.exists());
        assert_eq!(std::fs::read_to_string(&log).unwrap(), "{\"a\":1}\n");
        append_record(&log, &serde_json::json!({"c": 2})).unwrap();
        assert_eq!(std::fs::read_to_string(&log).unwrap(), "{\"a\":1}\n{\"c\":2}\n");
    }
}
