//! What the CLI's test files share: running the real binary, asserting its exit code and what
//! stderr names, and the settings that make a fixture run take a second or two.
// Each test file is its own crate and uses only some of these.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

pub struct Outcome {
    pub code: i32,
    pub stdout: String,
    pub stderr: String,
}

/// Runs `i2sdf ARGS` to completion.
pub fn i2sdf(args: &[&str]) -> Outcome {
    let out = Command::new(env!("CARGO_BIN_EXE_i2sdf")).args(args).output().unwrap();
    Outcome {
        code: out.status.code().unwrap_or(-1),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Asserts exit code `code` and that stderr names every needle.
#[track_caller]
pub fn expect(o: Outcome, code: i32, needles: &[&str]) {
    assert_eq!(o.code, code, "expected exit {code}; stderr: {}", o.stderr);
    for n in needles {
        assert!(o.stderr.contains(n), "expected '{n}' in: {}", o.stderr);
    }
}

/// Settings that make a stage-1 run of the fixture take a second or two.
pub const TINY: [&str; 12] = [
    "--set",
    "train.iterations=4",
    "--set",
    "model.hash_levels=4",
    "--set",
    "model.hash_log2_table=12",
    "--set",
    "train.rays=64",
    "--set",
    "train.eikonal_points=64",
    "--set",
    "train.bubble_points=64",
];

/// Settings that make stage 2 on the tiny run take a second.
pub const TINY_STAGE2: [&str; 10] = [
    "--set",
    "stage2.iterations=3",
    "--set",
    "stage2.cache_samples=4",
    "--set",
    "stage2.bake_resolution=32",
    "--set",
    "material.hash_levels=2",
    "--set",
    "material.hash_log2_table=10",
];

/// [`TINY_STAGE2`] made to make emitters of whatever F_e marks: threshold 0, and neither the
/// masks' agreement (the fixture's mark nothing) nor a second view (each of its four views sees
/// its own wall) asked for. Meaningless as lights, but they carry relight ops through edit, eval
/// and the report.
pub fn tiny_stage2_any_emitters() -> Vec<&'static str> {
    let any = [
        "--set",
        "stage2.emitter_threshold=0",
        "--set",
        "stage2.emitter_mask_agreement=0",
        "--set",
        "stage2.emitter_min_views=1",
    ];
    [&TINY_STAGE2[..], &any[..]].concat()
}

/// `i2sdf train --quiet --stage material` of `data` into `out`.
pub fn train_material(data: &Path, out: &Path, extra: &[&str]) -> Outcome {
    let mut args = vec![
        "train",
        "--quiet",
        "--stage",
        "material",
        "--data",
        s(data),
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    i2sdf(&args)
}

/// A finished stage-1 run's files (and its log, where it has one) copied into a new run
/// directory `dest`.
pub fn copy_stage1(run: &Path, dest: &Path) {
    std::fs::create_dir(dest).unwrap();
    for f in ["checkpoint.safetensors", "config.toml", "run.json"] {
        std::fs::copy(run.join(f), dest.join(f)).unwrap();
    }
    if run.join("log.jsonl").is_file() {
        std::fs::copy(run.join("log.jsonl"), dest.join("log.jsonl")).unwrap();
    }
}

/// A path whose parent is a regular file: creating it fails whoever runs the test (root too).
pub fn unwritable(dir: &Path, name: &str) -> PathBuf {
    let blocker = dir.join("not_a_directory");
    std::fs::write(&blocker, b"x").unwrap();
    blocker.join(name)
}

/// A fixture dataset (`DIR/data`) and a finished tiny stage-1 run on it (`DIR/run`).
pub fn tiny_stage1() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    i2sdf_data::fixture::write_native(&data, &i2sdf_data::fixture::FixtureOptions::default());
    let run = dir.path().join("run");
    let mut args = vec!["train", "--quiet", "--data", s(&data), "--out", s(&run)];
    args.extend_from_slice(&TINY);
    let o = i2sdf(&args);
    assert_eq!(o.code, 0, "{}", o.stderr);
    (dir, data, run)
}

/// A copy `dest` of the finished tiny stage-1 run `stage1`, with a tiny stage 2 trained on it.
pub fn tiny_stage2(data: &Path, stage1: &Path, dest: &Path) {
    copy_stage1(stage1, dest);
    let o = train_material(data, dest, &TINY_STAGE2);
    assert_eq!(o.code, 0, "{}", o.stderr);
}

/// `eval --run RUN --data DATA --out OUT` followed by `extra`.
pub fn eval_args<'a>(run: &'a Path, data: &'a Path, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["eval", "--run", s(run), "--data", s(data), "--out", s(out)];
    args.extend_from_slice(extra);
    args
}

/// Every file below `dir` (recursively) with its bytes: what "byte-identical" is checked against.
pub fn tree(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut std::collections::BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(root).unwrap().display().to_string();
            if p.is_dir() {
                out.insert(format!("{rel}/"), Vec::new());
                walk(root, &p, out);
            } else {
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = std::collections::BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// What differs between two trees, in words (empty: byte-identical).
pub fn tree_diff(
    before: &std::collections::BTreeMap<String, Vec<u8>>,
    after: &std::collections::BTreeMap<String, Vec<u8>>,
) -> Vec<String> {
    let mut out = Vec::new();
    for (k, v) in before {
        match after.get(k) {
            None => out.push(format!("{k} removed")),
            Some(w) if w != v => out.push(format!("{k} changed")),
            _ => {}
        }
    }
    out.extend(
        after
            .keys()
            .filter(|k| !before.contains_key(*k))
            .map(|k| format!("{k} added")),
    );
    out
}

/// The fixture dataset, a tiny stage-1 run and a copy of it with a tiny stage 2, made once per
/// test file and shared by its tests.
pub struct Trained {
    pub _dir: tempfile::TempDir,
    pub data: PathBuf,
    pub stage1: PathBuf,
    pub stage2: PathBuf,
}

/// [`Trained`], built on first use (the stage-2 copy is `DIR/run2`).
pub fn trained_stages() -> &'static Trained {
    static RUN: std::sync::OnceLock<Trained> = std::sync::OnceLock::new();
    RUN.get_or_init(|| {
        let (dir, data, stage1) = tiny_stage1();
        let stage2 = dir.path().join("run2");
        tiny_stage2(&data, &stage1, &stage2);
        Trained {
            _dir: dir,
            data,
            stage1,
            stage2,
        }
    })
}
