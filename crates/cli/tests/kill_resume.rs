//! Runs that survive being killed (issue 11): a tiny fixture run of both stages killed with SIGKILL
//! at 20 seeded moments — some of them while a checkpoint is being written — and resumed each time
//! finishes with the checkpoints of the uninterrupted run, tensor for tensor; a fixed seed and
//! thread count gives identical checkpoints; a full disk stops a run with exit 1 and keeps its
//! last good checkpoint; `--resume` refuses other data or an incompatible configuration, naming
//! what differs; a finished run resumed is a no-op; stage 2 refuses an unfinished stage 1.

use i2sdf_data::fixture::{self, FixtureOptions};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// A run of both stages that takes a second or two uninterrupted, checkpointing every iteration
/// (5 MB for stage 1: its hash table is large for the scene) so that a fair share of the kills
/// lands inside a checkpoint write.
const SETTINGS: [&str; 12] = [
    "train.iterations=60",
    "model.hash_levels=4",
    "model.hash_log2_table=16",
    "train.rays=64",
    "train.eikonal_points=64",
    "train.bubble_points=64",
    "train.checkpoint_every=1",
    "stage2.iterations=30",
    "stage2.cache_samples=4",
    "stage2.bake_resolution=32",
    "material.hash_levels=2",
    "material.hash_log2_table=13",
];

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `i2sdf ARGS` with the thread count fixed (checkpoints are bit-identical for a given seed and
/// thread count).
fn i2sdf(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_i2sdf"));
    c.args(args).env("RAYON_NUM_THREADS", "2");
    c
}

fn output(args: &[&str]) -> Output {
    i2sdf(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[track_caller]
fn expect(o: &Output, code: i32, needles: &[&str]) {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(code), "expected exit {code}; stderr: {err}");
    for n in needles {
        assert!(err.contains(n), "expected '{n}' in: {err}");
    }
}

/// `train --stage all` of `data` into `run` with [`SETTINGS`] (or `--resume`, which takes the
/// run's own configuration), plus `extra`.
fn train_args<'a>(data: &'a Path, run: &'a Path, resume: bool, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["train", "--quiet", "--stage", "all", "--data", s(data), "--out", s(run)];
    if resume {
        a.push("--resume");
    } else {
        for kv in SETTINGS {
            a.extend(["--set", kv]);
        }
    }
    a.extend_from_slice(extra);
    a
}

/// A safetensors file as (header JSON, tensor bytes): equal when every tensor and metadata entry
/// is (also what a resumed run is compared by: its files' bytes are checked where identical
/// runs are).
fn tensors(path: &Path) -> (serde_json::Value, Vec<u8>) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let n = u64::from_le_bytes(b[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&b[8..8 + n]).expect("a complete header");
    let end = header
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .map(|(_, v)| v["data_offsets"][1].as_u64().unwrap() as usize)
        .max()
        .unwrap_or(0);
    assert_eq!(b.len(), 8 + n + end, "{}: truncated", path.display());
    (header, b[8 + n..].to_vec())
}

#[track_caller]
fn assert_same_checkpoints(a: &Path, b: &Path) {
    for f in ["checkpoint.safetensors", "stage2.safetensors"] {
        assert!(
            tensors(&a.join(f)) == tensors(&b.join(f)),
            "{f} of {} differs from {}",
            b.display(),
            a.display()
        );
    }
}

fn info(run: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("run.json")).unwrap()).unwrap()
}

/// Every regular file of a directory with its bytes.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap())
        .map(|e| {
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

/// Temporaries of atomic writes in a run directory: (checkpoints, other files).
fn temporaries(run: &Path) -> (usize, usize) {
    let names: Vec<String> = std::fs::read_dir(run)
        .map(|d| {
            d.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    let partial: Vec<&String> = names.iter().filter(|n| n.contains(".partial.")).collect();
    let ckpt = partial.iter().filter(|n| n.contains(".safetensors.")).count();
    (ckpt, partial.len() - ckpt)
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// The fixture dataset and its uninterrupted run (with its wall time), shared by the tests.
struct Reference {
    dir: tempfile::TempDir,
    data: PathBuf,
    run: PathBuf,
    seconds: f64,
}

fn reference() -> &'static Reference {
    static R: OnceLock<Reference> = OnceLock::new();
    R.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data");
        fixture::write_native(&data, &FixtureOptions::default());
        let run = dir.path().join("reference");
        let t = Instant::now();
        let o = output(&train_args(&data, &run, false, &[]));
        expect(&o, 0, &[]);
        let seconds = t.elapsed().as_secs_f64();
        Reference {
            dir,
            data,
            run,
            seconds,
        }
    })
}

/// SplitMix64: the kill moments from a seed (no dependency for a dozen numbers).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Waits up to `d` for `child` to exit; true if it did.
fn exited_within(child: &mut Child, d: Duration) -> bool {
    let end = Instant::now() + d;
    while Instant::now() < end {
        if child.try_wait().unwrap().is_some() {
            return true;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    false
}

/// `eval`'s novel-view and re-render PSNR of a run.
fn psnr(run: &Path, data: &Path) -> (f64, f64) {
    let out = run.with_extension("metrics.json");
    let o = output(&[
        "eval",
        "--run",
        s(run),
        "--data",
        s(data),
        "--out",
        s(&out),
        "--spp",
        "2",
        "--mesh-resolution",
        "64",
    ]);
    expect(&o, 0, &[]);
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    (
        m["novel_view"]["psnr"].as_f64().unwrap(),
        m["rerender"]["psnr"].as_f64().unwrap(),
    )
}

/// 20 SIGKILLs at seeded moments spread over a run of both stages — every fourth one as soon as
/// a checkpoint's temporary appears after its moment, so that some land inside a write — each
/// followed by `--resume` (or a fresh start when the killed process had not created its run
/// yet); then the last session finishes. After every kill the checkpoints on disk are complete;
/// stage 2 on the unfinished stage 1 is refused; the finished run equals the uninterrupted one.
#[test]
fn killed_anywhere_resumes_and_finishes_as_the_uninterrupted_run() {
    let r = reference();
    let start = Instant::now();
    let run = r.dir.path().join("killed");
    let mut rng = Rng(11);
    // Kill moments: 20 sorted fractions of the uninterrupted run's wall time; each session
    // is killed after the gap to the next one (a session also repeats the start-up, so the
    // moments cover the run and the last session finishes it).
    let mut moments: Vec<f64> = (0..20).map(|_| rng.next() * r.seconds).collect();
    moments.sort_by(f64::total_cmp);
    let (mut kills, mut in_checkpoint, mut in_other_write, mut finished_early) = (0, 0, 0, 0);
    let mut refused_stage2 = false;
    let mut last = 0.0;
    for (k, &m) in moments.iter().enumerate() {
        let gap = Duration::from_secs_f64(m - last);
        last = m;
        let resume = run.join("run.json").is_file();
        let mut child = i2sdf(&train_args(&r.data, &run, resume, &[]))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut done = exited_within(&mut child, gap);
        if !done && k % 4 == 3 {
            // Into the next checkpoint write.
            let end = Instant::now() + Duration::from_secs(5);
            while temporaries(&run).0 == 0 && Instant::now() < end {
                if child.try_wait().unwrap().is_some() {
                    done = true;
                    break;
                }
                std::hint::spin_loop();
            }
        }
        if done {
            let o = child.wait_with_output().unwrap();
            expect(&o, 0, &[]);
            finished_early += 1;
            continue;
        }
        child.kill().unwrap();
        child.wait().unwrap();
        kills += 1;
        let (c, other) = temporaries(&run);
        in_checkpoint += usize::from(c > 0);
        in_other_write += usize::from(other > 0);
        // Whatever the moment, the checkpoints on disk are whole.
        for f in ["checkpoint.safetensors", "stage2.safetensors"] {
            if run.join(f).is_file() {
                tensors(&run.join(f));
            }
        }
        let unfinished = run.join("checkpoint.safetensors").is_file()
            && run.join("run.json").is_file()
            && !info(&run)["stage1"]["done"].as_bool().unwrap();
        if unfinished && !refused_stage2 {
            let before = files(&run);
            for extra in [&[][..], &["--resume"][..]] {
                let mut a = vec![
                    "train",
                    "--quiet",
                    "--stage",
                    "material",
                    "--data",
                    s(&r.data),
                    "--out",
                    s(&run),
                ];
                a.extend_from_slice(extra);
                expect(&output(&a), 2, &["stage 1 has not finished"]);
            }
            assert!(files(&run) == before, "a refused stage 2 changed the run");
            refused_stage2 = true;
        }
    }
    let o = output(&train_args(&r.data, &run, run.join("run.json").is_file(), &[]));
    expect(&o, 0, &[]);
    let i = info(&run);
    assert!(
        i["stage1"]["done"].as_bool().unwrap() && i["stage2"]["done"].as_bool().unwrap(),
        "{i}"
    );
    assert_eq!(temporaries(&run), (0, 0), "temporaries left in the finished run");
    let log = std::fs::read_to_string(run.join("log.jsonl")).unwrap();
    assert!(
        log.lines()
            .all(|l| serde_json::from_str::<serde_json::Value>(l).is_ok()),
        "a torn log line"
    );
    let killed_s = start.elapsed().as_secs_f64();
    assert_same_checkpoints(&r.run, &run);
    let (a, b) = (psnr(&r.run, &r.data), psnr(&run, &r.data));
    eprintln!(
        "kill-anywhere: {kills} kills ({in_checkpoint} inside a checkpoint write, {in_other_write} inside another \
         write; {finished_early} sessions finished before their moment); uninterrupted run {:.2} s, killed \
         and resumed {killed_s:.2} s; PSNR novel view {:.3} dB uninterrupted, {:.3} dB killed; re-render \
         {:.3} / {:.3} dB; checkpoints identical",
        r.seconds, a.0, b.0, a.1, b.1
    );
    assert!((a.0 - b.0).abs() < 0.1 && (a.1 - b.1).abs() < 0.1);
    assert!(
        kills >= 15 && in_checkpoint >= 1,
        "{kills} kills, {in_checkpoint} in a checkpoint write"
    );
    assert!(refused_stage2, "no kill left stage 1 unfinished");
}

/// Two runs with the same seed and thread count write the same checkpoints.
#[test]
fn same_seed_and_threads_give_identical_checkpoints() {
    let r = reference();
    let run = r.dir.path().join("again");
    expect(&output(&train_args(&r.data, &run, false, &[])), 0, &[]);
    assert_same_checkpoints(&r.run, &run);
    // Byte for byte, header included (its metadata is written in key order).
    for f in ["checkpoint.safetensors", "stage2.safetensors"] {
        assert!(
            std::fs::read(r.run.join(f)).unwrap() == std::fs::read(run.join(f)).unwrap(),
            "{f}: the files' bytes differ"
        );
    }
    // Another seed does not (the comparison can fail).
    let other = r.dir.path().join("seed1");
    expect(
        &output(&train_args(&r.data, &other, false, &["--set", "train.seed=1"])),
        0,
        &[],
    );
    assert!(tensors(&r.run.join("checkpoint.safetensors")) != tensors(&other.join("checkpoint.safetensors")));
}

/// A finished run resumed is a no-op: exit 0, nothing written (whichever stages are named);
/// with a key that may change, only `config.toml` records the new value.
#[test]
fn resuming_a_finished_run_changes_nothing() {
    let r = reference();
    let run = r.dir.path().join("finished");
    copy_dir(&r.run, &run);
    let before = files(&run);
    for stage in ["all", "geometry", "material"] {
        let o = output(&[
            "train",
            "--quiet",
            "--stage",
            stage,
            "--data",
            s(&r.data),
            "--out",
            s(&run),
            "--resume",
        ]);
        expect(&o, 0, &[]);
        assert!(String::from_utf8_lossy(&o.stdout).contains("had finished"));
        assert!(
            files(&run) == before,
            "resuming a finished run (--stage {stage}) wrote to it"
        );
    }
    let o = output(&train_args(&r.data, &run, true, &["--set", "train.log_every=3"]));
    expect(&o, 0, &[]);
    let after = files(&run);
    for ((name, a), (_, b)) in before.iter().zip(&after) {
        assert!(a == b || name == "config.toml", "{name} changed");
    }
    assert!(std::fs::read_to_string(run.join("config.toml"))
        .unwrap()
        .contains("log_every = 3"));
}

/// `--resume` against other data or an incompatible configuration exits 2 and says what
/// differs; the same data under another path resumes; a run killed before its first checkpoint
/// resumes from iteration 0.
#[test]
fn resume_refuses_other_data_and_incompatible_configs() {
    let r = reference();
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    copy_dir(&r.run, &run);
    let before = files(&run);
    // Other views.
    let five = dir.path().join("five");
    fixture::write_native(
        &five,
        &FixtureOptions {
            train_views: 5,
            ..Default::default()
        },
    );
    let o = output(&train_args(&five, &run, true, &[]));
    expect(
        &o,
        2,
        &["--data", "five", "not the dataset", s(&r.data), "training views"],
    );
    // The same cameras, two training images swapped.
    let swapped = dir.path().join("swapped");
    copy_dir(&r.data, &swapped);
    let img = swapped.join("images");
    std::fs::rename(img.join("frame_000.png"), img.join("tmp.png")).unwrap();
    std::fs::rename(img.join("frame_001.png"), img.join("frame_000.png")).unwrap();
    std::fs::rename(img.join("tmp.png"), img.join("frame_001.png")).unwrap();
    let o = output(&train_args(&swapped, &run, true, &[]));
    expect(&o, 2, &["swapped", "images: fingerprint"]);
    assert!(!stderr(&o).contains("cameras"), "{}", stderr(&o));
    // Stage 2 on the same stage 1 with other data is refused too.
    let o = output(&[
        "train",
        "--quiet",
        "--stage",
        "material",
        "--resume",
        "--data",
        s(&swapped),
        "--out",
        s(&run),
    ]);
    expect(&o, 2, &["images: fingerprint"]);
    // Incompatible keys, each named with both values.
    let o = output(&train_args(
        &r.data,
        &run,
        true,
        &["--set", "model.hash_levels=8", "--set", "loss.depth=0.3"],
    ));
    expect(
        &o,
        2,
        &["config.toml", "model.hash_levels: 4 → 8", "loss.depth: 0.1 → 0.3"],
    );
    let o = output(&train_args(&r.data, &run, true, &["--set", "stage2.cache_samples=8"]));
    expect(&o, 2, &["stage2.cache_samples: 4 → 8"]);
    assert!(files(&run) == before, "a refused resume changed the run");
    // The run's own config.toml edited by hand: its [model] is checked against the checkpoint's
    // (the fields are rebuilt from the checkpoint's, so the edit would do nothing).
    let cfg = run.join("config.toml");
    let text = std::fs::read_to_string(&cfg).unwrap();
    let edited = text.replacen("beta_min = 0.0001", "beta_min = 0.002", 1);
    assert_ne!(edited, text, "the run's config.toml has model.beta_min = 0.0001");
    std::fs::write(&cfg, &edited).unwrap();
    let o = output(&train_args(&r.data, &run, true, &[]));
    expect(
        &o,
        2,
        &["config.toml", "model.beta_min: 0.0001 → 0.002", "cannot change"],
    );
    // And its [material] against the stage-2 checkpoint's.
    let edited = text.replacen("rho_min = 0.05", "rho_min = 0.1", 1);
    assert_ne!(edited, text, "the run's config.toml has material.rho_min = 0.05");
    std::fs::write(&cfg, &edited).unwrap();
    let o = output(&train_args(&r.data, &run, true, &[]));
    expect(&o, 2, &["config.toml", "material.rho_min: 0.05 → 0.1", "cannot change"]);
    std::fs::write(&cfg, &text).unwrap();
    assert!(files(&run) == before, "a refused resume changed the run");
    // The same data elsewhere: accepted (a no-op on the finished run).
    let moved = dir.path().join("moved");
    copy_dir(&r.data, &moved);
    expect(&output(&train_args(&moved, &run, true, &[])), 0, &[]);
    // Killed before its first checkpoint: run.json and config.toml only.
    let early = dir.path().join("early");
    std::fs::create_dir(&early).unwrap();
    std::fs::copy(r.run.join("config.toml"), early.join("config.toml")).unwrap();
    let mut i = info(&r.run);
    i["stage1"] = serde_json::json!({"iterations": 0, "done": false, "seconds": 0.0});
    i["stage2"] = serde_json::Value::Null;
    std::fs::write(early.join("run.json"), i.to_string()).unwrap();
    expect(&output(&train_args(&r.data, &early, true, &[])), 0, &[]);
    assert_same_checkpoints(&r.run, &early);
}

/// A tmpfs mounted on a directory, unmounted on drop.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(at: &Path, bytes: u64) -> Result<Tmpfs, String> {
        std::fs::create_dir_all(at).unwrap();
        let o = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={bytes}"), "tmpfs", s(at)])
            .output()
            .map_err(|e| format!("cannot run mount: {e}"))?;
        if !o.status.success() {
            return Err(String::from_utf8_lossy(&o.stderr).trim().to_string());
        }
        Ok(Tmpfs(at.to_path_buf()))
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// A run on a disk that fills up stops with exit 1, naming the write, and keeps its last good
/// checkpoint (whole, and resumable elsewhere to the uninterrupted result). Needs a tmpfs (root
/// with CAP_SYS_ADMIN); skipped with the reason where mounting is not allowed. (The driver's unit
/// test `a_full_disk_stops_the_run_and_keeps_the_last_checkpoint` covers the path without one.)
#[test]
fn a_full_disk_stops_with_exit_1_and_keeps_the_last_checkpoint() {
    let r = reference();
    let dir = tempfile::tempdir().unwrap();
    let size = std::fs::metadata(r.run.join("checkpoint.safetensors")).unwrap().len();
    // Room for one checkpoint and the small files, not for the second checkpoint's temporary.
    let fs = match Tmpfs::mount(&dir.path().join("disk"), (size * 3 / 2).div_ceil(4096) * 4096) {
        Ok(fs) => fs,
        Err(why) => {
            eprintln!(
                "SKIPPED a_full_disk_stops_with_exit_1_and_keeps_the_last_checkpoint: cannot mount a tmpfs: {why}"
            );
            return;
        }
    };
    let run = fs.0.join("run");
    let o = output(&train_args(&r.data, &run, false, &[]));
    expect(&o, 1, &["No space left on device"]);
    let (_, data) = tensors(&run.join("checkpoint.safetensors"));
    assert!(!data.is_empty());
    let i = info(&run);
    assert!(!i["stage1"]["done"].as_bool().unwrap(), "{i}");
    assert_eq!(temporaries(&run), (0, 0), "a failed write left its temporary");
    eprintln!(
        "disk full: stopped at stage-1 iteration {} with: {}",
        i["stage1"]["iterations"],
        stderr(&o).trim()
    );
    // Space again (the run copied to a disk that has it): the run resumes and finishes as the
    // uninterrupted one.
    let moved = dir.path().join("moved");
    copy_dir(&run, &moved);
    drop(fs);
    expect(&output(&train_args(&r.data, &moved, true, &[])), 0, &[]);
    assert_same_checkpoints(&r.run, &moved);
}
