//! The training driver shared by the stages behind `i2sdf train`: a stage says how to take one
//! step and write its checkpoint ([`TrainStage`]); the driver owns everything around it — the RNG
//! of each iteration seeded from (seed, iteration), so a resumed run draws exactly what the
//! uninterrupted one would have; the streak of skipped non-finite steps; atomic checkpoints with
//! the optimizer state every N iterations and at the end; the JSONL log; the stage's progress and
//! time in `run.json`; progress events for the CLI. The CLI only displays them.

use crate::resume::append_record;
use i2sdf_data::DataError;
use i2sdf_model::run_dir::{RunDir, RunInfo};
use rand::SeedableRng;
use rand_pcg::Pcg64;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// Consecutive non-finite steps tolerated before training stops as diverged.
pub const MAX_NONFINITE_STREAK: u32 = 20;

/// What one step reports.
pub struct StepOutcome<S> {
    pub stats: S,
    /// False: the loss (or an output) was not finite and the step changed no parameter.
    pub finite: bool,
}

/// One training stage, as the driver runs it.
pub trait TrainStage {
    /// Per-step statistics (one JSON object of the log).
    type Stats: Serialize;
    /// The stage's key in `run.json` (`"stage1"`, `"stage2"`), also the progress label.
    fn key(&self) -> &'static str;
    /// Iterations done (the next step's index).
    fn iteration(&self) -> u64;
    /// Iterations in all.
    fn total(&self) -> u64;
    /// The run's seed, mixed with the iteration into each step's RNG.
    fn seed(&self) -> u64;
    /// A slow step about to run (e.g. initialising error maps), announced to the display.
    fn pending_pause(&self) -> Option<&'static str> {
        None
    }
    /// One iteration with its RNG. Advances [`TrainStage::iteration`] by one whether or not the
    /// step was finite; a non-finite step must leave every parameter and optimizer state as it was.
    fn step(&mut self, rng: &mut Pcg64) -> Result<StepOutcome<Self::Stats>, DataError>;
    /// Are the trained parameters finite?
    fn is_finite(&self) -> bool;
    /// Writes the parameters and the optimizer state (atomically) so that a stage resumed from
    /// it continues bit for bit.
    fn write_checkpoint(&self, path: &Path) -> Result<(), DataError>;
}

/// The RNG of iteration `i` of a run with `seed`.
pub fn iteration_rng(seed: u64, iteration: u64) -> Pcg64 {
    Pcg64::seed_from_u64(seed ^ iteration.wrapping_mul(0x9e37_79b9_7f4a_7c15))
}

/// A stage with the driver's per-step state: stepping it directly (tests, benchmarks) behaves
/// exactly as inside [`drive`].
pub struct Trainer<S> {
    pub stage: S,
    nonfinite_streak: u32,
}

impl<S: TrainStage> Trainer<S> {
    pub fn new(stage: S) -> Self {
        Trainer {
            stage,
            nonfinite_streak: 0,
        }
    }

    pub fn done(&self) -> bool {
        self.stage.iteration() >= self.stage.total()
    }

    /// One step with the iteration's RNG. A non-finite step is skipped; [`MAX_NONFINITE_STREAK`]
    /// of them in a row stop training with an error (the last good checkpoint stays).
    pub fn step(&mut self) -> Result<StepOutcome<S::Stats>, DataError> {
        let it = self.stage.iteration();
        let mut rng = iteration_rng(self.stage.seed(), it);
        let outcome = self.stage.step(&mut rng)?;
        debug_assert_eq!(self.stage.iteration(), it + 1, "a step advances one iteration");
        if outcome.finite {
            self.nonfinite_streak = 0;
        } else {
            self.nonfinite_streak += 1;
            if self.nonfinite_streak >= MAX_NONFINITE_STREAK {
                return Err(DataError::failed(format!(
                    "training diverged: {} consecutive non-finite losses at iteration {}",
                    self.nonfinite_streak,
                    it + 1
                )));
            }
        }
        Ok(outcome)
    }

    /// Writes the checkpoint; refuses parameters that are not finite (the last good checkpoint
    /// is kept).
    pub fn save(&self, path: &Path) -> Result<(), DataError> {
        if !self.stage.is_finite() {
            return Err(DataError::failed(
                "training diverged: non-finite parameters; checkpoint not written",
            ));
        }
        self.stage.write_checkpoint(path)
    }
}

/// What the driver reports to its caller (the CLI's progress bar).
pub enum Event<'a, T> {
    Started {
        key: &'static str,
        iteration: u64,
        total: u64,
    },
    /// A step finished (`stats` of iteration `iteration`).
    Step {
        iteration: u64,
        stats: &'a T,
        finite: bool,
    },
    /// A slow step is about to run.
    Pause(&'static str),
    /// A line the user should read before training starts (what each map of the dataset does).
    Note(String),
    Checkpoint {
        iteration: u64,
    },
}

/// How often the driver checkpoints and logs, and when it writes snapshots.
#[derive(Clone, Copy, Debug)]
pub struct DriveOptions<'a> {
    pub checkpoint_every: u64,
    pub log_every: u64,
    /// Wall times (seconds of the stage, increasing) at which the stage's fields are written to
    /// [`RunDir::snapshot`], a run directory of its own.
    pub snapshot_seconds: &'a [f32],
}

/// Runs `trainer` to its total into `run`: logs every `log_every` steps (and every skipped one),
/// checkpoints every `checkpoint_every` and at the end, and keeps the stage's progress and
/// wall-clock time (summed over resumed sessions) in `info`/`run.json`.
pub fn drive<S: TrainStage>(
    run: &RunDir,
    info: &mut RunInfo,
    trainer: &mut Trainer<S>,
    options: DriveOptions<'_>,
    mut on_event: impl FnMut(Event<S::Stats>),
) -> Result<(), DataError> {
    let key = trainer.stage.key();
    let base_seconds = info.stage_mut(key)?.seconds;
    on_event(Event::Started {
        key,
        iteration: trainer.stage.iteration(),
        total: trainer.stage.total(),
    });
    let session_start = Instant::now();
    let every = options.checkpoint_every.max(1);
    let log_every = options.log_every.max(1);
    // Snapshots already written by an earlier session are not written again.
    let mut next_snapshot = options
        .snapshot_seconds
        .partition_point(|&s| (s as f64) <= base_seconds);
    while !trainer.done() {
        if let Some(what) = trainer.stage.pending_pause() {
            on_event(Event::Pause(what));
        }
        let it = trainer.stage.iteration();
        let out = trainer.step()?;
        if it % log_every == 0 || !out.finite {
            let mut record = serde_json::to_value(&out.stats).expect("stats serialize");
            if let Some(obj) = record.as_object_mut() {
                obj.insert("stage".into(), key.into());
                obj.insert(
                    "time_s".into(),
                    (base_seconds + session_start.elapsed().as_secs_f64()).into(),
                );
            }
            append_record(&run.log_path(), &record)?;
        }
        on_event(Event::Step {
            iteration: it,
            stats: &out.stats,
            finite: out.finite,
        });
        let now = trainer.stage.iteration();
        let elapsed = base_seconds + session_start.elapsed().as_secs_f64();
        while let Some(&at) = options.snapshot_seconds.get(next_snapshot) {
            if at as f64 > elapsed {
                break;
            }
            let snap = run.snapshot(key, at);
            write_snapshot(run, &snap, info, trainer, elapsed)?;
            on_event(Event::Note(format!(
                "snapshot at {at} s (iteration {now}): {}",
                snap.root.display()
            )));
            next_snapshot += 1;
        }
        if now % every == 0 || trainer.done() {
            trainer.save(&run.stage_checkpoint_path(key))?;
            let progress = info.stage_mut(key)?;
            progress.iterations = now;
            progress.seconds = base_seconds + session_start.elapsed().as_secs_f64();
            progress.done = trainer.done();
            run.write_info(info)?;
            on_event(Event::Checkpoint { iteration: now });
        }
    }
    // A session killed between its final checkpoint and `run.json` left the stage unfinished on
    // record: the checkpoint holds the last iteration, so the record follows it (and a finished
    // run resumed writes nothing).
    let now = trainer.stage.iteration();
    let progress = info.stage_mut(key)?;
    if progress.iterations != now || !progress.done {
        progress.iterations = now;
        progress.done = true;
        run.write_info(info)?;
    }
    Ok(())
}

/// A snapshot of the stage as it is: its checkpoint, the run's configuration, and a `run.json`
/// that records the stage finished at this iteration and wall time (what it is, to a command
/// that opens it), each written atomically. A stage 2 snapshot takes stage 1's checkpoint and
/// the emitters with it.
fn write_snapshot<S: TrainStage>(
    run: &RunDir,
    snap: &RunDir,
    info: &RunInfo,
    trainer: &Trainer<S>,
    elapsed: f64,
) -> Result<(), DataError> {
    let key = trainer.stage.key();
    snap.create()?;
    trainer.save(&snap.stage_checkpoint_path(key))?;
    snap.write_config_toml(&run.read_config_toml()?)?;
    if key == "stage2" {
        for (from, to) in [
            (run.checkpoint_path(), snap.checkpoint_path()),
            (run.emitters_path(), snap.emitters_path()),
        ] {
            if from.is_file() {
                let bytes = std::fs::read(&from).map_err(|e| DataError::io(&from, format!("cannot read: {e}")))?;
                i2sdf_data::imageio::write_bytes_atomic(&to, &bytes)?;
            }
        }
    }
    let mut snap_info = info.clone();
    let progress = snap_info.stage_mut(key)?;
    progress.iterations = trainer.stage.iteration();
    progress.seconds = elapsed;
    progress.done = true;
    snap.write_info(&snap_info)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    /// A stage that is not stage 1: noisy gradient descent on ‖x‖², checkpointed as JSON. It
    /// uses the driver exactly as stage 2 will.
    struct Toy {
        x: Vec<f32>,
        iteration: u64,
        total: u64,
        /// Iterations from which every step is non-finite.
        poison_from: u64,
        /// Iterations from which the disk is full: a checkpoint write fails half-way with ENOSPC.
        full_disk_from: u64,
    }

    impl TrainStage for Toy {
        type Stats = serde_json::Value;
        fn key(&self) -> &'static str {
            "stage2"
        }
        fn iteration(&self) -> u64 {
            self.iteration
        }
        fn total(&self) -> u64 {
            self.total
        }
        fn seed(&self) -> u64 {
            7
        }
        fn step(&mut self, rng: &mut Pcg64) -> Result<StepOutcome<Self::Stats>, DataError> {
            self.iteration += 1;
            if self.iteration > self.poison_from {
                return Ok(StepOutcome {
                    stats: serde_json::json!({"loss": null}),
                    finite: false,
                });
            }
            for v in &mut self.x {
                *v -= 0.1 * (2.0 * *v + rng.gen_range(-0.5f32..0.5));
            }
            let loss: f32 = self.x.iter().map(|v| v * v).sum();
            Ok(StepOutcome {
                stats: serde_json::json!({ "iteration": self.iteration - 1, "loss": loss }),
                finite: true,
            })
        }
        fn is_finite(&self) -> bool {
            self.x.iter().all(|v| v.is_finite())
        }
        fn write_checkpoint(&self, path: &Path) -> Result<(), DataError> {
            let text = serde_json::json!({ "x": self.x, "iteration": self.iteration }).to_string();
            if self.iteration >= self.full_disk_from {
                // Half the file lands, then the device is full: /dev/full answers every write
                // with ENOSPC, the error a filled disk gives.
                return i2sdf_data::imageio::write_atomic(path, |tmp| {
                    std::fs::write(tmp, &text.as_bytes()[..text.len() / 2]).map_err(|e| e.to_string())?;
                    std::fs::write("/dev/full", text.as_bytes()).map_err(|e| e.to_string())
                });
            }
            i2sdf_data::imageio::write_bytes_atomic(path, text.as_bytes())
        }
    }

    fn toy(total: u64) -> Toy {
        Toy {
            x: vec![1.0, -2.0, 0.5],
            iteration: 0,
            total,
            poison_from: u64::MAX,
            full_disk_from: u64::MAX,
        }
    }

    fn resume(path: &Path, total: u64) -> Toy {
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        Toy {
            x: serde_json::from_value(v["x"].clone()).unwrap(),
            iteration: v["iteration"].as_u64().unwrap(),
            total,
            poison_from: u64::MAX,
            full_disk_from: u64::MAX,
        }
    }

    const OPTIONS: DriveOptions = DriveOptions {
        checkpoint_every: 10,
        log_every: 5,
        snapshot_seconds: &[],
    };

    /// Checkpoints, log, progress in run.json, events; a run stopped and resumed ends bit for bit
    /// where the uninterrupted one does.
    #[test]
    fn drives_any_stage_and_resumes_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let (full, part) = (RunDir::new(&dir.path().join("a")), RunDir::new(&dir.path().join("b")));
        let mut info = RunInfo::default();
        full.create().unwrap();
        let mut a = Trainer::new(toy(30));
        let mut events = Vec::new();
        drive(&full, &mut info, &mut a, OPTIONS, |e| {
            events.push(match e {
                Event::Started { key, iteration, total } => format!("start {key} {iteration}/{total}"),
                Event::Step { .. } => "step".into(),
                Event::Pause(w) => w.into(),
                Event::Note(line) => line,
                Event::Checkpoint { iteration } => format!("ckpt {iteration}"),
            })
        })
        .unwrap();
        assert_eq!(events.first().unwrap(), "start stage2 0/30");
        assert_eq!(events.iter().filter(|e| e.starts_with("ckpt")).count(), 3);
        let stage2 = full.read_info().unwrap().stage2.unwrap();
        assert!(stage2.done && stage2.iterations == 30 && stage2.seconds >= 0.0);
        let log = std::fs::read_to_string(full.log_path()).unwrap();
        assert_eq!(log.lines().count(), 6);
        assert!(log
            .lines()
            .all(|l| l.contains("\"stage\":\"stage2\"") && l.contains("time_s")));

        part.create().unwrap();
        let mut info = RunInfo::default();
        let mut b = Trainer::new(toy(20));
        drive(&part, &mut info, &mut b, OPTIONS, |_| {}).unwrap();
        assert!(!a.stage.x.iter().zip(&b.stage.x).all(|(p, q)| p == q));
        let mut b = Trainer::new(resume(&part.stage2_checkpoint_path(), 30));
        let mut info = part.read_info().unwrap();
        drive(&part, &mut info, &mut b, OPTIONS, |_| {}).unwrap();
        assert_eq!(a.stage.x, b.stage.x);
        assert_eq!(part.read_info().unwrap().stage2.unwrap().iterations, 30);
    }

    /// Non-finite steps are skipped and logged; a streak of them stops the run as diverged (not
    /// the input's fault), and non-finite parameters are never checkpointed.
    /// Snapshots at given wall times are run directories of their own (checkpoint, config, a
    /// run.json of the stage finished there); a resumed session does not write them again.
    #[test]
    fn snapshots_at_wall_times() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        run.create().unwrap();
        run.write_config_toml("[train]\niterations = 20\n").unwrap();
        let mut info = RunInfo::default();
        let times = [1e-9f32, 2e-9, 1e6];
        let options = DriveOptions {
            snapshot_seconds: &times,
            ..OPTIONS
        };
        let mut t = Trainer::new(toy(20));
        let mut notes = Vec::new();
        drive(&run, &mut info, &mut t, options, |e| {
            if let Event::Note(n) = e {
                notes.push(n)
            }
        })
        .unwrap();
        assert_eq!(notes.len(), 2, "{notes:?}");
        for at in [1e-9f32, 2e-9] {
            let snap = run.snapshot("stage2", at);
            let snap_info = snap.read_info().unwrap();
            let p = snap_info.stage("stage2").unwrap();
            assert_eq!((p.iterations, p.done), (1, true), "the first step passes both times");
            assert!(snap.stage2_checkpoint_path().is_file());
            assert_eq!(snap.read_config_toml().unwrap(), run.read_config_toml().unwrap());
        }
        assert!(!run.snapshot("stage2", 1e6).root.exists());
        assert!(run.snapshot("stage2", 60.0).root.ends_with("snapshots/stage2-00060s"));
        assert_eq!(std::fs::read_dir(run.root.join("snapshots")).unwrap().count(), 2);
        // Resumed: the times already passed are not written again.
        std::fs::remove_dir_all(run.snapshot("stage2", 1e-9).root).unwrap();
        let mut more = Trainer::new(resume(&run.stage2_checkpoint_path(), 25));
        drive(&run, &mut info, &mut more, options, |_| {}).unwrap();
        assert!(!run.snapshot("stage2", 1e-9).root.exists());
    }

    #[test]
    fn a_diverging_stage_stops_and_keeps_the_last_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        let mut t = Trainer::new(Toy {
            poison_from: 12,
            ..toy(100)
        });
        let e = drive(&run, &mut RunInfo::default(), &mut t, OPTIONS, |_| {}).unwrap_err();
        assert!(e.to_string().contains("diverged") && !e.is_bad_input(), "{e}");
        assert_eq!(t.stage.iteration, 12 + MAX_NONFINITE_STREAK as u64);
        // Skipped steps count as iterations but leave the parameters alone: the checkpoints after
        // iteration 12 hold its parameters (the last at 30; the streak ended the run at 32).
        let saved = resume(&run.stage2_checkpoint_path(), 100);
        assert_eq!((saved.iteration, &saved.x), (30, &t.stage.x));
        let skipped = std::fs::read_to_string(run.log_path()).unwrap();
        assert!(skipped.lines().filter(|l| l.contains("\"loss\":null")).count() >= MAX_NONFINITE_STREAK as usize - 1);
        t.stage.x[0] = f32::NAN;
        let e = t.save(&run.stage2_checkpoint_path()).unwrap_err();
        assert!(e.to_string().contains("non-finite"));
        assert_eq!(resume(&run.stage2_checkpoint_path(), 100).x, saved.x);
    }

    /// A checkpoint write that fails for a full disk stops the run as a failure (exit 1, not bad
    /// input) naming the file and the OS error; the last good checkpoint, `run.json` and the
    /// directory stay as they were (no temporary left), and the run resumes from them.
    #[test]
    fn a_full_disk_stops_the_run_and_keeps_the_last_checkpoint() {
        if !Path::new("/dev/full").exists() {
            eprintln!("SKIPPED a_full_disk_stops_the_run_and_keeps_the_last_checkpoint: no /dev/full");
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        let mut info = RunInfo::default();
        let mut t = Trainer::new(Toy {
            full_disk_from: 25,
            ..toy(40)
        });
        let e = drive(&run, &mut info, &mut t, OPTIONS, |_| {}).unwrap_err();
        let msg = e.to_string();
        assert!(!e.is_bad_input() && msg.contains("stage2.safetensors"), "{msg}");
        assert!(msg.contains("No space left on device"), "{msg}");
        let saved = resume(&run.stage2_checkpoint_path(), 40);
        assert_eq!(saved.iteration, 20);
        let on_record = run.read_info().unwrap().stage2.unwrap();
        assert!(on_record.iterations == 20 && !on_record.done);
        let mut names: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["log.jsonl", "run.json", "stage2.safetensors"]);
        // Space again: the run resumes from the kept checkpoint to the uninterrupted result.
        let mut full = Trainer::new(toy(40));
        let other = tempfile::tempdir().unwrap();
        drive(
            &RunDir::new(other.path()),
            &mut RunInfo::default(),
            &mut full,
            OPTIONS,
            |_| {},
        )
        .unwrap();
        let mut b = Trainer::new(saved);
        drive(&run, &mut run.read_info().unwrap(), &mut b, OPTIONS, |_| {}).unwrap();
        assert_eq!(b.stage.x, full.stage.x);
    }

    /// A session killed after its final checkpoint but before `run.json` said so: resuming
    /// records the stage as finished without a step.
    #[test]
    fn a_final_checkpoint_not_yet_on_record_finishes_the_stage() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        let mut t = Trainer::new(toy(30));
        drive(&run, &mut RunInfo::default(), &mut t, OPTIONS, |_| {}).unwrap();
        let mut info = run.read_info().unwrap();
        let p = info.stage_mut("stage2").unwrap();
        (p.iterations, p.done) = (20, false);
        run.write_info(&info).unwrap();
        let mut b = Trainer::new(resume(&run.stage2_checkpoint_path(), 30));
        let mut steps = 0;
        drive(&run, &mut info, &mut b, OPTIONS, |e| {
            steps += usize::from(matches!(e, Event::Step { .. }))
        })
        .unwrap();
        let p = run.read_info().unwrap().stage2.unwrap();
        assert!(steps == 0 && p.iterations == 30 && p.done);
    }
}
