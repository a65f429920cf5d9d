//! `i2sdf demo [--out DIR] [--quick]`: the whole pipeline on the built-in synthetic room —
//! synthesize it, validate it, train stage 1 and stage 2, extract the mesh, evaluate (writing
//! the test views as scored into `render/`: the maps, the material maps and the Monte Carlo
//! re-render, as `render` lays them out), render three edits of a test view (`edits/`: an
//! emitter recoloured, a wall mirror, an inserted sphere), and write the HTML report
//! (`report/index.html`). `--quick` trains on a phone capture of the room
//! (`capture/`: JPEG, lens distortion, coarse noisy depth with confidence, no normals, masks or
//! HDR, perturbed training poses) and scores it against the exact room (`scene/`).
//! Each step reuses the subcommand of its name; finished steps are skipped on a re-run.

use super::{check, edit, eval, export, mesh, report, synth, train};
use clap::Args as ClapArgs;
use std::path::{Path, PathBuf};

#[derive(ClapArgs)]
pub struct Args {
    /// Output directory: scene/, run/, mesh.ply, room.glb, render/, metrics.json, edits/, report/.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// A small room (80×60, 24 views) and a short training on its phone capture (`capture/`,
    /// scored against the exact room): about 1½ minutes where the bench iteration takes ~75 ms
    /// (the demo says what to expect on this machine before it starts).
    #[arg(long)]
    pub quick: bool,
    /// LPIPS (AlexNet, v0.1) weights as safetensors (scripts/lpips_weights.py), for the metrics'
    /// and the report's LPIPS; without them it is null, with a note.
    #[arg(long, value_name = "FILE.safetensors")]
    pub lpips_weights: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    check_demo_folder(&args.out)?;
    if let Some(path) = &args.lpips_weights {
        // Checked before the minutes of training, not at the evaluation.
        i2sdf_eval::Lpips::load(path)?;
    }
    // This machine's pace against the plan's, from a second of the bench's representative
    // iteration; the steps done then correct it.
    let bench_ms = i2sdf_nn::bench::representative_iteration_ms(4);
    let pace = (bench_ms / PLAN_BENCH_MS).clamp(0.2, 20.0);
    let mut plan = StagePlan::new(if args.quick { &QUICK_SECONDS } else { &FULL_SECONDS }, pace);
    crate::progress::line(&format!(
        "i2sdf demo{}: about {} on 2 cores where `i2sdf bench`'s iteration takes ~{PLAN_BENCH_MS:.0} ms; it takes {bench_ms:.0} ms here: expect about {}; finished steps are skipped on a re-run",
        if args.quick { " --quick" } else { "" },
        minutes(plan.total()),
        minutes(plan.total() * pace)
    ));
    let scene = args.out.join("scene");
    let run_dir = args.out.join("run");
    // The quick demo trains on the phone capture and scores against the exact room.
    let train_data = if args.quick {
        args.out.join("capture")
    } else {
        scene.clone()
    };
    synthesize(&args, &mut plan, &scene, &train_data)?;
    train_both(&args, &mut plan, &train_data, &run_dir)?;
    outputs(&args, &mut plan, &scene, &run_dir)?;
    plan.finish();
    crate::progress::line(&format!(
        "open {} in a browser",
        args.out.join("report").join("index.html").display()
    ));
    Ok(())
}

/// Step 1: the room (and, for `--quick`, its phone capture) synthesized unless already there,
/// and the training data checked.
fn synthesize(args: &Args, plan: &mut StagePlan, scene: &Path, train_data: &Path) -> anyhow::Result<()> {
    let rooms: Vec<(&Path, bool)> = if args.quick {
        vec![(scene, false), (train_data, true)]
    } else {
        vec![(scene, false)]
    };
    for (k, &(dir, capture)) in rooms.iter().enumerate() {
        if dir.join("transforms.json").is_file() {
            crate::progress::line(&format!("== 1/{STEPS} reuse the room in {}", dir.display()));
            continue;
        }
        if k == 0 {
            plan.stage(1, &format!("synthesize the room into {}", dir.display()));
        } else {
            crate::progress::line(&format!("== 1/{STEPS} its phone capture into {}", dir.display()));
        }
        let (width, height, views, spp) = if args.quick {
            (80, 60, 24, 32)
        } else {
            (160, 120, 48, 128)
        };
        synth::run(synth::Args {
            out: dir.to_path_buf(),
            force: false,
            preset: "livingroom".into(),
            scene: None,
            seed: 0,
            width,
            height,
            views,
            spp,
            depth_noise: None,
            max_depth: 64,
            unbiased: false,
            capture,
            jpeg_quality: None,
            lens: None,
            depth_grid: None,
            confidence: false,
            no_normals: false,
            no_masks: false,
            no_hdr: false,
            pose_noise: None,
            format: synth::OutputFormat::Native,
        })?;
    }
    check::run(check::Args {
        data: train_data.to_path_buf(),
        json: false,
        config: None,
        set: Vec::new(),
    })?;
    Ok(())
}

/// Steps 2 and 3: both stages trained into `run_dir`, each skipped when done and resumed when
/// interrupted.
fn train_both(args: &Args, plan: &mut StagePlan, train_data: &Path, run_dir: &Path) -> anyhow::Result<()> {
    let info = i2sdf_model::RunDir::new(run_dir);
    let done = info.read_info().map(|i| i.stage1.done).unwrap_or(false);
    if !done {
        plan.stage(2, &format!("train stage 1 into {}", run_dir.display()));
        let set = if args.quick {
            vec![
                "train.iterations=1500".to_string(),
                "train.rays=512".into(),
                "model.hash_log2_table=16".into(),
                // The first pass of before 2026-12-05: the default's 64 costs 7 % more stage 1,
                // and the quick demo's time budget (90 s at a ~75 ms bench) has no room for it.
                "sampling.coarse=32".into(),
            ]
        } else {
            Vec::new()
        };
        train::run(train::Args {
            data: Some(train_data.to_path_buf()),
            out: run_dir.to_path_buf(),
            config: None,
            set,
            stage: train::Stage::Geometry,
            resume: info.checkpoint_path().is_file(),
            quiet: false,
            ignore_memory: false,
            trust_exposure: false,
        })?;
    }
    let stage2_done = info
        .read_info()
        .ok()
        .and_then(|i| i.stage2.map(|s| s.done))
        .unwrap_or(false);
    if !stage2_done {
        plan.stage(
            3,
            &format!("train stage 2 (emitters, materials) into {}", run_dir.display()),
        );
        let set = if args.quick {
            vec![
                "stage2.iterations=400".to_string(),
                "stage2.cache_pixels=32768".into(),
                "stage2.cache_samples=64".into(),
                "stage2.bake_resolution=128".into(),
                // One fit: the quick demo has no time for the choice of a lobe per material.
                "lobes.rhos=[]".into(),
            ]
        } else {
            Vec::new()
        };
        train::run(train::Args {
            data: Some(train_data.to_path_buf()),
            out: run_dir.to_path_buf(),
            config: None,
            set,
            stage: train::Stage::Material,
            resume: info.stage2_checkpoint_path().is_file(),
            quiet: false,
            ignore_memory: false,
            trust_exposure: false,
        })?;
    }
    Ok(())
}

/// Steps 4–7: the mesh, the metrics (with the test views' renders), the edits and the report,
/// scored against the exact room `scene`.
fn outputs(args: &Args, plan: &mut StagePlan, scene: &Path, run_dir: &Path) -> anyhow::Result<()> {
    plan.stage(4, "extract the mesh and export the room");
    // The mesh that eval scores (thin objects need fine cells, see MESH_RESOLUTION); the edits'
    // recovered surface is only raytraced and stays at 256.
    let resolution = if args.quick {
        128
    } else {
        i2sdf_eval::neural::MESH_RESOLUTION
    };
    let edit_resolution = resolution.min(256);
    mesh::run(mesh::Args {
        run: run_dir.to_path_buf(),
        out: args.out.join("mesh.ply"),
        resolution,
        force: true,
    })?;
    // The room for Blender or a game engine (glTF 2.0), beside the mesh.
    export::run(export::Args {
        run: run_dir.to_path_buf(),
        out: args.out.join("room.glb"),
        force: true,
        resolution: edit_resolution,
        max_faces: i2sdf_export::ExportOptions::default().max_faces,
        max_error: i2sdf_export::ExportOptions::default().max_error,
        materials: i2sdf_export::ExportOptions::default().materials,
        texture_size: if args.quick {
            QUICK_TEXTURE_SIZE
        } else {
            i2sdf_export::ExportOptions::default().texture_size
        },
        lights: false,
        up: "auto".into(),
        data: Some(scene.to_path_buf()),
    })?;
    plan.stage(5, "evaluate, writing the test views as scored into render/");
    eval::run(eval::Args {
        run: run_dir.to_path_buf(),
        data: Some(scene.to_path_buf()),
        out: args.out.join("metrics.json"),
        mesh_out: None,
        // The test views' maps and re-renders as eval rendered them: a separate `render` step
        // rendered them all again (43 s of the full demo at a bench of ~100 ms).
        renders: Some(args.out.join("render")),
        // The full demo trains on `scene` itself, so the mesh step's mesh is the one eval would
        // extract (same run, bounds and resolution): extracting it again took as long as the
        // mesh step. The quick demo's run has the capture's bounds; its mesh is cheap anyway.
        mesh: (!args.quick).then(|| args.out.join("mesh.ply")),
        force: true,
        mesh_resolution: resolution,
        threshold: 0.05,
        spp: if args.quick { 16 } else { 64 },
        bounces: if args.quick { 4 } else { 8 },
        denoise: false,
        // No LPIPS weights ship: without --lpips-weights the metrics note that LPIPS is null.
        lpips_weights: args.lpips_weights.clone(),
        // The test views only: the training views' figures (`--split both`) take another
        // render of every training view.
        split: "test".into(),
    })?;
    plan.stage(
        6,
        "edit: the ceiling light recoloured, a wall mirror, an inserted sphere",
    );
    for (name, text) in DEMO_EDITS {
        let dir = args.out.join("edits");
        std::fs::create_dir_all(&dir).map_err(|e| i2sdf_data::DataError::io(&dir, e.to_string()))?;
        let spec = dir.join(format!("{name}.toml"));
        i2sdf_data::imageio::write_bytes_atomic(&spec, text.as_bytes())?;
        edit::run(edit::Args {
            run: run_dir.to_path_buf(),
            spec,
            out: dir.join(name),
            force: true,
            split: "test".into(),
            view: Some(0),
            spp: if args.quick { 16 } else { 64 },
            bounces: if args.quick { 4 } else { 8 },
            denoise: false,
            width: None,
            height: None,
            seed: 0,
            mesh_resolution: edit_resolution,
            data: Some(scene.to_path_buf()),
            composite: "path-traced".into(),
            path: Default::default(),
        })?;
    }
    plan.stage(7, "write the HTML report");
    report::run(report::Args {
        run: run_dir.to_path_buf(),
        out: args.out.join("report"),
        force: true,
        data: Some(scene.to_path_buf()),
        metrics: Some(args.out.join("metrics.json")),
        view: 0,
        // Eval's relight settings, so the report's relit frames are the ones eval scored.
        spp: if args.quick { 16 } else { 64 },
        bounces: if args.quick { 4 } else { 8 },
        mesh_resolution: edit_resolution,
        scene: Some(args.out.join("room.glb")),
    })?;
    Ok(())
}

/// What the demo writes in its folder; a folder holding anything else is not the demo's, and
/// the demo refuses it rather than write among a user's files.
const DEMO_ENTRIES: [&str; 9] = [
    "scene",
    "capture",
    "run",
    "mesh.ply",
    "room.glb",
    "render",
    "metrics.json",
    "edits",
    "report",
];

fn check_demo_folder(out: &std::path::Path) -> Result<(), i2sdf_data::DataError> {
    if out.is_file() {
        return Err(i2sdf_data::DataError::invalid(format!(
            "--out {}: is a file; give a folder",
            out.display()
        )));
    }
    if out.exists() && !super::only_entries(out, |name, _| DEMO_ENTRIES.contains(&name)) {
        return Err(i2sdf_data::DataError::invalid(format!(
            "--out {}: holds files that are not a demo's (it writes {}): choose a new or empty folder",
            out.display(),
            DEMO_ENTRIES.join(", ")
        )));
    }
    Ok(())
}

/// `demo --quick`'s texture atlas width (the quick room's surface is coarse; its textures need
/// not be 2048 wide).
const QUICK_TEXTURE_SIZE: u32 = 512;

/// The demo's steps: synthesis and check, stage 1, stage 2, mesh and export, eval (which writes
/// the test views' renders), edits, report.
const STEPS: usize = 7;

/// The bench iteration (ms) of the machine the plan's seconds are for.
const PLAN_BENCH_MS: f64 = 75.0;

/// Expected seconds of the [`STEPS`] steps on the machine where the bench iteration takes
/// [`PLAN_BENCH_MS`]: measured runs scaled by their machine's bench iteration.
/// `--quick`: its run of 2026-12-05 (128.7 s in all between benches of 112.1 and 108.0 ms)
/// scaled by 75/110: synthesis and capture 11 s, stage 1 83 s, stage 2 15 s, mesh and export
/// 8 s, eval 8 s, edits 2 s, report 3 s.
const QUICK_SECONDS: [f64; STEPS] = [8.0, 57.0, 10.0, 5.0, 6.0, 2.0, 2.0];
/// The full demo: its run of 2026-12-05 with eval writing the test views' renders (632.0 s in
/// all between benches of 106.1 and 107.4 ms) scaled by 75/106.75: synthesis 145 s, stage 1
/// 236 s, stage 2 96 s, the mesh at 1024 29 s and the export 11 s, eval 82 s (it scores the
/// mesh step's mesh), the edits 13.5 s and the report 17.4 s; stage 1 then 7 % longer for the
/// first pass at 64 samples (paired runs of the same day). About 1.2× that for stage 1 without
/// AMX (no bf16 products). Stage 2 since the choice of a lobe per material (`[lobes]`, six fits
/// on one cache): ×1.97, its ratio on the default room (2026-12-07: 470 s against 238 s).
const FULL_SECONDS: [f64; STEPS] = [102.0, 178.0, 132.0, 30.0, 58.0, 9.5, 12.0];

fn minutes(seconds: f64) -> String {
    if seconds < 90.0 {
        format!("{seconds:.0} s")
    } else {
        format!("{:.0} min", seconds / 60.0)
    }
}

/// The demo's one progress display across its steps: a bar on top of the steps' own bars, its
/// position the plan's seconds done, its message the step, the time so far and what is left —
/// the plan's expected seconds scaled by how fast this machine has gone through the steps done.
/// A ticker thread moves it within a step (up to 95 % of the step's plan) so that it never
/// stands still while a step runs; each step also prints one `== k/7` line, which logs keep.
struct StagePlan {
    state: std::sync::Arc<std::sync::Mutex<PlanState>>,
    bar: indicatif::ProgressBar,
    ticker: Option<std::thread::JoinHandle<()>>,
}

struct PlanState {
    expected: &'static [f64; STEPS],
    /// This machine's seconds per planned second before any step has shown its own.
    initial_pace: f64,
    start: std::time::Instant,
    /// Expected seconds of the steps finished (or skipped: they count as done, at no time).
    done: f64,
    current: Option<usize>,
    /// When the current step began, in seconds since `start`.
    current_since: f64,
    skipped: f64,
    what: String,
    finished: bool,
}

impl StagePlan {
    fn new(expected: &'static [f64; STEPS], pace: f64) -> Self {
        let state = PlanState::new(expected, pace);
        let bar = crate::progress::top_bar(state.total().ceil() as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("demo [{bar:30}] {percent:>3}% {msg}")
                .expect("valid template")
                .progress_chars("=> "),
        );
        let state = std::sync::Arc::new(std::sync::Mutex::new(state));
        let ticker = {
            let (state, bar) = (state.clone(), bar.clone());
            std::thread::spawn(move || loop {
                {
                    let s = state.lock().unwrap_or_else(|p| p.into_inner());
                    if s.finished {
                        break;
                    }
                    s.show(&bar);
                }
                std::thread::sleep(std::time::Duration::from_millis(500));
            })
        };
        StagePlan {
            state,
            bar,
            ticker: Some(ticker),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, PlanState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn total(&self) -> f64 {
        self.lock().total()
    }

    /// Step `k` (1-based) begins; the steps before it that never began were skipped.
    fn stage(&mut self, k: usize, what: &str) {
        let mut s = self.lock();
        let now = s.start.elapsed().as_secs_f64();
        let (elapsed, left) = s.begin(k, now);
        s.what = format!("{k}/{STEPS} {what}");
        s.show(&self.bar);
        crate::progress::line(&format!(
            "== {k}/{STEPS} {what}  [{} elapsed, about {} left]",
            minutes(elapsed),
            minutes(left)
        ));
    }

    fn finish(mut self) {
        let took = {
            let mut s = self.lock();
            s.finished = true;
            s.start.elapsed().as_secs_f64()
        };
        if let Some(t) = self.ticker.take() {
            let _ = t.join();
        }
        self.bar.finish_and_clear();
        crate::progress::line(&format!("== demo done in {}", minutes(took)));
    }
}

impl Drop for StagePlan {
    /// A failed step ends the demo: the ticker stops and the bar goes.
    fn drop(&mut self) {
        self.lock().finished = true;
        if let Some(t) = self.ticker.take() {
            let _ = t.join();
            self.bar.abandon();
        }
    }
}

impl PlanState {
    fn new(expected: &'static [f64; STEPS], initial_pace: f64) -> Self {
        PlanState {
            expected,
            initial_pace,
            start: std::time::Instant::now(),
            done: 0.0,
            current: None,
            current_since: 0.0,
            skipped: 0.0,
            what: String::new(),
            finished: false,
        }
    }

    fn total(&self) -> f64 {
        self.expected.iter().sum()
    }

    /// This machine's seconds per planned second, from the steps it ran (not skipped); the
    /// bench's estimate until they amount to a few seconds of work.
    fn pace(&self, elapsed_done: f64) -> f64 {
        let ran = self.done - self.skipped;
        if ran >= 5.0 && elapsed_done > 1.0 {
            elapsed_done / ran
        } else {
            self.initial_pace
        }
    }

    /// Books step `k` as begun `elapsed` seconds in: (elapsed, the seconds expected to be left).
    fn begin(&mut self, k: usize, elapsed: f64) -> (f64, f64) {
        let i = k - 1;
        let first = self.current.map_or(0, |c| c + 1);
        if let Some(c) = self.current {
            self.done += self.expected[c];
        }
        for j in first..i {
            self.done += self.expected[j];
            self.skipped += self.expected[j];
        }
        self.current = Some(i);
        self.current_since = elapsed;
        (elapsed, (self.total() - self.done) * self.pace(elapsed))
    }

    /// At `now` seconds: (the plan's seconds done, the seconds expected to be left). Within a
    /// step its plan is credited at this machine's pace, up to 95 % until the step ends.
    fn progress(&self, now: f64) -> (f64, f64) {
        let Some(c) = self.current else {
            return (0.0, self.total());
        };
        let pace = self.pace(self.current_since);
        let step = ((now - self.current_since) / pace).min(0.95 * self.expected[c]);
        let done = self.done + step;
        (done, (self.total() - done) * pace)
    }

    fn show(&self, bar: &indicatif::ProgressBar) {
        let now = self.start.elapsed().as_secs_f64();
        let (done, left) = self.progress(now);
        bar.set_position(done as u64);
        bar.set_message(format!(
            "{}  [{} elapsed, about {} left]",
            self.what,
            minutes(now),
            minutes(left)
        ));
    }
}

/// The demo's edits of the built-in living room (world units of its `synth` preset): the ceiling
/// panel warmer and brighter, part of the back wall between the lamp and the TV a mirror, a
/// glossy ball on the floor in front of it (its shadow on the floor, its image in the mirror).
const DEMO_EDITS: [(&str, &str); 3] = [
    (
        "recolour",
        "[[op]]\nkind = \"relight\"\nat = [-0.62, 2.65, 0.0]\nscale = 1.5\ncolor = [1.0, 0.6, 0.3]\n",
    ),
    (
        "mirror",
        "[[op]]\nkind = \"material\"\nbox = { lo = [-2.35, 0.5, -2.3], hi = [-0.75, 2.3, -2.05] }\npreset = \"mirror\"\n",
    ),
    (
        "sphere",
        "[[op]]\nkind = \"material\"\nbox = { lo = [-2.35, 0.5, -2.3], hi = [-0.75, 2.3, -2.05] }\npreset = \"mirror\"\n\
         [[op]]\nkind = \"insert\"\nsphere = { centre = [-1.1, 0.3, -1.4], radius = 0.3 }\npreset = \"glossy\"\n",
    ),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_eta_follows_the_plan_then_this_machine() {
        const PLAN: [f64; STEPS] = [10.0, 100.0, 20.0, 5.0, 55.0, 10.0, 0.0];
        let state = || PlanState::new(&PLAN, 1.0);
        let mut plan = state();
        assert_eq!(plan.progress(0.0), (0.0, 200.0));
        assert_eq!(plan.begin(1, 0.0), (0.0, 200.0));
        // Within step 1, at the plan's pace: credited as it goes, never past 95 % of the step.
        assert_eq!(plan.progress(4.0), (4.0, 196.0));
        assert_eq!(plan.progress(30.0), (9.5, 190.5));
        // Step 1 took twice its plan: what is left is expected at the same pace.
        assert_eq!(plan.begin(2, 20.0), (20.0, 380.0));
        assert_eq!(plan.progress(40.0), (20.0, 360.0));
        // A re-run that skips steps 1–3: they are done at no cost, the pace is the plan's.
        let mut rerun = state();
        assert_eq!(rerun.begin(4, 0.0), (0.0, 70.0));
        assert_eq!(rerun.begin(5, 10.0), (10.0, 130.0));
        // A machine the bench found twice as slow: twice the plan until steps have run.
        let mut slow = PlanState::new(&PLAN, 2.0);
        assert_eq!(slow.begin(1, 0.0), (0.0, 400.0));
        assert_eq!(slow.progress(4.0), (2.0, 396.0));
        assert_eq!(slow.begin(2, 20.0), (20.0, 380.0));
    }
}
