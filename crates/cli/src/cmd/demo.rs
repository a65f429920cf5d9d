//! `i2sdf demo [--out DIR] [--quick]`: the whole pipeline on the built-in synthetic room —
//! synthesize it, validate it, train stage 1 and stage 2, extract the mesh, render the test views
//! (with the material maps and the Monte Carlo re-render), evaluate, and render three edits of
//! a test view (`edits/`: an emitter recoloured, a wall mirror, an inserted sphere), and write
//! the HTML report (`report/index.html`).
//! Each step reuses the subcommand of the same name; finished steps are skipped on a re-run.

use super::{check, edit, eval, mesh, render, report, synth, train};
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// Output directory: scene/, run/, mesh.ply, render/, metrics.json, edits/, report/.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// A small room (80×60, 24 views) and a short training: about a minute and a half.
    #[arg(long)]
    pub quick: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut plan = StagePlan::new(if args.quick { &QUICK_SECONDS } else { &FULL_SECONDS });
    eprintln!(
        "i2sdf demo{}: about {} on 2 cores where `i2sdf bench`'s iteration takes ~75 ms (twice that on a machine twice as slow); finished steps are skipped on a re-run",
        if args.quick { " --quick" } else { "" },
        minutes(plan.total())
    );
    let scene = args.out.join("scene");
    let run_dir = args.out.join("run");
    if !scene.join("transforms.json").is_file() {
        plan.stage(1, &format!("synthesize the room into {}", scene.display()));
        let (width, height, views, spp) = if args.quick {
            (80, 60, 24, 32)
        } else {
            (160, 120, 48, 128)
        };
        synth::run(synth::Args {
            out: scene.clone(),
            preset: "livingroom".into(),
            scene: None,
            seed: 0,
            width,
            height,
            views,
            spp,
            depth_noise: "none".into(),
            max_depth: 64,
            unbiased: false,
        })?;
    } else {
        eprintln!("== 1/8 reuse the room in {}", scene.display());
    }
    check::run(check::Args {
        data: scene.clone(),
        json: false,
        config: None,
        set: Vec::new(),
    })?;

    let info = i2sdf_model::RunDir::new(&run_dir);
    let done = info.read_info().map(|i| i.stage1.done).unwrap_or(false);
    if !done {
        plan.stage(2, &format!("train stage 1 into {}", run_dir.display()));
        let set = if args.quick {
            vec![
                "train.iterations=1500".to_string(),
                "train.rays=512".into(),
                "model.hash_log2_table=16".into(),
            ]
        } else {
            Vec::new()
        };
        train::run(train::Args {
            data: scene.clone(),
            out: run_dir.clone(),
            config: None,
            set,
            stage: train::Stage::Geometry,
            resume: info.checkpoint_path().is_file(),
            quiet: false,
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
                "stage2.bake_resolution=128".into(),
            ]
        } else {
            Vec::new()
        };
        train::run(train::Args {
            data: scene.clone(),
            out: run_dir.clone(),
            config: None,
            set,
            stage: train::Stage::Material,
            resume: info.stage2_checkpoint_path().is_file(),
            quiet: false,
        })?;
    }
    plan.stage(4, "extract the mesh");
    let resolution = if args.quick { 128 } else { 256 };
    mesh::run(mesh::Args {
        run: run_dir.clone(),
        out: args.out.join("mesh.ply"),
        resolution,
    })?;
    plan.stage(5, "render the test views");
    render::run(render::Args {
        run: run_dir.clone(),
        out: args.out.join("render"),
        split: "test".into(),
        what: "rgb,depth,normal,emitter,albedo,specular,roughness,emission,rerender".into(),
        data: Some(scene.clone()),
        spp: if args.quick { 16 } else { 64 },
        path: Default::default(),
    })?;
    plan.stage(6, "evaluate");
    eval::run(eval::Args {
        run: run_dir.clone(),
        data: scene.clone(),
        out: args.out.join("metrics.json"),
        mesh_resolution: resolution,
        threshold: 0.05,
        spp: if args.quick { 16 } else { 64 },
        bounces: if args.quick { 4 } else { 8 },
    })?;
    plan.stage(
        7,
        "edit: the ceiling light recoloured, a wall mirror, an inserted sphere",
    );
    for (name, text) in DEMO_EDITS {
        let dir = args.out.join("edits");
        std::fs::create_dir_all(&dir).map_err(|e| i2sdf_data::DataError::io(&dir, e.to_string()))?;
        let spec = dir.join(format!("{name}.toml"));
        i2sdf_data::imageio::write_bytes_atomic(&spec, text.as_bytes())?;
        edit::run(edit::Args {
            run: run_dir.clone(),
            spec,
            out: dir.join(name),
            split: "test".into(),
            view: Some(0),
            spp: if args.quick { 16 } else { 64 },
            bounces: if args.quick { 4 } else { 8 },
            width: None,
            height: None,
            seed: 0,
            mesh_resolution: resolution,
            data: Some(scene.clone()),
            composite: "path-traced".into(),
            path: Default::default(),
        })?;
    }
    plan.stage(8, "write the HTML report");
    report::run(report::Args {
        run: run_dir.clone(),
        out: args.out.join("report"),
        data: Some(scene.clone()),
        metrics: Some(args.out.join("metrics.json")),
        view: 0,
        spp: if args.quick { 8 } else { 32 },
        bounces: if args.quick { 4 } else { 8 },
        mesh_resolution: resolution.min(128),
    })?;
    eprintln!(
        "open {} in a browser",
        args.out.join("report").join("index.html").display()
    );
    plan.finish();
    Ok(())
}

/// Expected seconds of the 8 steps (synth + check, stage 1, stage 2, mesh, render, eval, edits,
/// report)
/// on the machine where the bench iteration takes ~75 ms, from runs at ~160 ms halved.
const QUICK_SECONDS: [f64; 8] = [8.0, 75.0, 20.0, 3.0, 8.0, 25.0, 10.0, 5.0];
const FULL_SECONDS: [f64; 8] = [60.0, 650.0, 50.0, 5.0, 25.0, 220.0, 30.0, 30.0];

fn minutes(seconds: f64) -> String {
    if seconds < 90.0 {
        format!("{seconds:.0} s")
    } else {
        format!("{:.0} min", seconds / 60.0)
    }
}

/// One progress line across the demo's steps: the step, the time so far and what is left, the
/// plan's expected seconds scaled by how fast this machine has gone through the steps done.
struct StagePlan {
    expected: &'static [f64; 8],
    start: std::time::Instant,
    /// Expected seconds of the steps finished (or skipped: they count as done, at no time).
    done: f64,
    current: Option<usize>,
    skipped: f64,
}

impl StagePlan {
    fn new(expected: &'static [f64; 8]) -> Self {
        StagePlan {
            expected,
            start: std::time::Instant::now(),
            done: 0.0,
            current: None,
            skipped: 0.0,
        }
    }

    fn total(&self) -> f64 {
        self.expected.iter().sum()
    }

    /// Step `k` (1-based) begins; the steps before it that never began were skipped.
    fn stage(&mut self, k: usize, what: &str) {
        let (elapsed, left) = self.begin(k, self.start.elapsed().as_secs_f64());
        eprintln!(
            "== {k}/8 {what}  [{} elapsed, about {} left]",
            minutes(elapsed),
            minutes(left)
        );
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
        let ran = self.done - self.skipped;
        // The plan's pace until this machine has shown its own over a few seconds of it.
        let pace = if ran >= 5.0 && elapsed > 1.0 {
            elapsed / ran
        } else {
            1.0
        };
        (elapsed, (self.total() - self.done) * pace)
    }

    fn finish(&self) {
        eprintln!("== demo done in {}", minutes(self.start.elapsed().as_secs_f64()));
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
        const PLAN: [f64; 8] = [10.0, 100.0, 20.0, 5.0, 5.0, 50.0, 10.0, 0.0];
        let mut plan = StagePlan::new(&PLAN);
        assert_eq!(plan.begin(1, 0.0), (0.0, 200.0));
        // Step 1 took twice its plan: what is left is expected at the same pace.
        assert_eq!(plan.begin(2, 20.0), (20.0, 380.0));
        // A re-run that skips steps 1–3: they are done at no cost, the pace is the plan's.
        let mut rerun = StagePlan::new(&PLAN);
        assert_eq!(rerun.begin(4, 0.0), (0.0, 70.0));
        assert_eq!(rerun.begin(5, 10.0), (10.0, 130.0));
    }
}
