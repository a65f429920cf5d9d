//! `i2sdf train`: stage 1 (geometry, radiance, emitter fields), stage 2 (materials, emitters) or
//! both, with a progress bar; the runs are opened in `i2sdf_train::run`, the loops, checkpoints and logs live in
//! `i2sdf_train::driver`.

use clap::{Args as ClapArgs, ValueEnum};
use i2sdf_model::RunDir;
use i2sdf_train::config::TrainConfig;
use i2sdf_train::driver::{Event, TrainStage};
use i2sdf_train::run::{train_geometry, train_materials};
use i2sdf_train::stage1::StepStats;
use i2sdf_train::stage2::Stage2Stats;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Stage {
    /// Stage 1: SDF, radiance and emitter fields (paper Sec. 3–4.2).
    Geometry,
    /// Stage 2 on a finished stage-1 run: K-means emitters and their emission, GGX material
    /// fields (paper Sec. 4.2–5).
    Material,
    /// Stage 1, then stage 2.
    All,
}

#[derive(ClapArgs)]
pub struct Args {
    /// Dataset folder (for --resume and --stage material: defaults to the run's, as its run.json
    /// records).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Run folder (created; with --resume or --stage material, continued).
    #[arg(long)]
    pub out: PathBuf,
    /// TOML configuration file (defaults are tuned for the default synthetic room).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a configuration value, e.g. --set train.iterations=2000 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Which stage to train.
    #[arg(long, value_enum, default_value = "geometry")]
    pub stage: Stage,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Print one line per log step instead of a progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Train even when the memory estimate (as `i2sdf check` prints it) exceeds the machine's
    /// available memory.
    #[arg(long)]
    pub ignore_memory: bool,
    /// Stage 2: use the dataset's declared `ldr.exposure` even where its LDR and HDR images
    /// measure another (without it, a disagreement over 5 % is refused).
    #[arg(long)]
    pub trust_exposure: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let run = RunDir::new(&args.out);
    let config = load_config(&args, &run)?;
    if let Some(c) = &config {
        if c.train.threads > 0 {
            let _ = rayon::ThreadPoolBuilder::new()
                .num_threads(c.train.threads)
                .build_global();
        }
    }
    let continues = args.resume || args.stage == Stage::Material;
    let data = match (&args.data, continues) {
        (Some(d), _) => d.clone(),
        (None, true) => run.dataset_path(&run.read_info()?, None)?,
        (None, false) => anyhow::bail!(i2sdf_data::DataError::invalid("--data SCENE is needed to start a run")),
    };
    if !continues {
        check_new_run(&args.out, &data)?;
    }
    crate::progress::line(&format!("loading {}", data.display()));
    let dataset = i2sdf_data::load(&data)?;
    let geometry = matches!(args.stage, Stage::Geometry | Stage::All);
    let material = matches!(args.stage, Stage::Material | Stage::All);
    check_memory(&run, &dataset, config.as_ref(), geometry, material, args.ignore_memory)?;
    if material {
        check_exposure(&dataset, &data, args.trust_exposure)?;
    }
    let mut config = config;
    if geometry {
        run_geometry(&args, &run, &dataset, &data, config.clone())?;
        // Stage 2 of the same command continues from the run as written.
        config = None;
    }
    if material {
        run_materials(&args, &run, &dataset, &data, config)?;
    }
    Ok(())
}

/// The configuration a command trains with: a resumed run's own (with `--set` on top; None
/// when nothing is set: the driver reads it), a stage-2 continuation's own, or a new one from
/// `--config` and `--set`.
fn load_config(args: &Args, run: &RunDir) -> anyhow::Result<Option<TrainConfig>> {
    Ok(if args.resume {
        if args.config.is_some() {
            anyhow::bail!(i2sdf_data::DataError::invalid(
                "--config cannot change a resumed run (use --set)"
            ));
        }
        if args.set.is_empty() {
            None
        } else {
            Some(TrainConfig::load(Some(&run.config_path()), &args.set)?)
        }
    } else if args.stage == Stage::Material && args.config.is_none() {
        // Stage 2 continues a run: its own configuration, with --set on top.
        if !run.config_path().is_file() {
            anyhow::bail!(i2sdf_data::DataError::file(
                &run.root,
                "holds no stage-1 run: train --stage geometry (or --stage all) first"
            ));
        }
        Some(TrainConfig::load(Some(&run.config_path()), &args.set)?)
    } else {
        Some(TrainConfig::load(args.config.as_deref(), &args.set)?)
    })
}

/// Stage 2 works in the images' linear units: what the images say of their exposure. A
/// declared exposure they contradict is refused unless trusted: fitted at the wrong one, every
/// material comes out off by the factor.
fn check_exposure(dataset: &i2sdf_data::Dataset, data: &Path, trust: bool) -> anyhow::Result<()> {
    let Some(e) = i2sdf_data::exposure::estimate_exposure(dataset) else {
        return Ok(());
    };
    if let Some(declared) = dataset.radiometry.exposure.filter(|_| !trust) {
        if e.disagrees_with(declared) {
            anyhow::bail!(i2sdf_data::DataError::field(
                data.join("transforms.json"),
                "ldr.exposure",
                format!(
                    "{declared} is declared, but the LDR and HDR images measure {:.4} ({} channels, spread {:.1} %): fix the key, or pass --trust-exposure to train with the declared value",
                    e.exposure,
                    e.samples,
                    100.0 * e.spread
                ),
            ));
        }
    }
    for w in e.warnings(dataset) {
        crate::progress::line(&format!("warning: {w}"));
    }
    Ok(())
}

/// A stage's progress bar (hidden with `--quiet`).
fn stage_bar(label: &str, quiet: bool) -> ProgressBar {
    let bar = crate::progress::bar(0);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{spinner}} {label} [{{bar:30}}] {{pos}}/{{len}} {{msg}} ({{elapsed}} < {{eta}})"
        ))
        .expect("valid template")
        .progress_chars("=> "),
    );
    if quiet {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar
}

/// Stage 1. A finished stage 1 resumed (--stage all --resume continuing into stage 2, or a
/// finished run resumed) is not trained again: the driver checks it and writes nothing.
fn run_geometry(
    args: &Args,
    run: &RunDir,
    dataset: &i2sdf_data::Dataset,
    data: &Path,
    config: Option<TrainConfig>,
) -> anyhow::Result<()> {
    let bar = stage_bar("stage 1", args.quiet);
    let start = Instant::now();
    let first = std::cell::Cell::new(None);
    let mut show = progress_events(&bar, start, args.quiet, |s: &StepStats| {
        format!(
            "{:?} loss {:.4} psnr {:.2} depth {:.4} β {:.4}",
            s.phase.unwrap(),
            s.loss,
            s.psnr,
            s.depth,
            s.beta
        )
    });
    let stage = train_geometry(run, dataset, &data.display().to_string(), config, args.resume, |e| {
        if let Event::Started { iteration, .. } = &e {
            first.set(Some(*iteration));
        }
        show(e)
    })?;
    bar.finish();
    if first.get() == Some(stage.iteration) {
        println!(
            "stage 1 had finished: {} iterations; run in {}",
            stage.iteration,
            args.out.display()
        );
    } else {
        println!(
            "stage 1 done: {} iterations in {:.1} s this session; run in {}",
            stage.iteration,
            start.elapsed().as_secs_f64(),
            args.out.display()
        );
    }
    Ok(())
}

/// Stage 2, continued from a checkpoint where the run has one and the command resumes.
fn run_materials(
    args: &Args,
    run: &RunDir,
    dataset: &i2sdf_data::Dataset,
    data: &Path,
    config: Option<TrainConfig>,
) -> anyhow::Result<()> {
    let start = Instant::now();
    let stage2_resume = args.resume || args.stage == Stage::All;
    let bar = stage_bar("stage 2", args.quiet);
    let quiet = args.quiet;
    // Stage 2's setup says what it does and finds (the emitters, the pieces that are not, the
    // clipped lights' L) once each: kept as lines above the bar. Only the tracing counter, a
    // line per 8192 pixels, is the bar's passing message.
    let progress = |what: &str| {
        if quiet {
            eprintln!("stage 2: {what}");
        } else if !what.starts_with("tracing ") {
            crate::progress::line(&format!("stage 2: {what}"));
        }
        bar.set_message(what.to_string());
        bar.tick();
    };
    let stage = train_materials(
        run,
        dataset,
        &data.display().to_string(),
        config,
        stage2_resume && run.stage2_checkpoint_path().is_file(),
        &progress,
        progress_events(&bar, start, quiet, |s: &Stage2Stats| {
            let em: Vec<String> = s
                .emission
                .iter()
                .map(|e| format!("{:.2}", (e[0] + e[1] + e[2]) / 3.0))
                .collect();
            format!(
                "loss {:.4} render {:.4} emitter {:.4} L [{}]",
                s.loss,
                s.render,
                s.emitter,
                em.join(" ")
            )
        }),
    )?;
    bar.finish();
    let Some(stage) = stage else {
        println!("stage 2 had finished; run in {}", args.out.display());
        return Ok(());
    };
    let (surface, emitter) = stage.counts();
    if stage.fields.emitters.is_empty() {
        crate::progress::line(&format!(
            "warning: stage 2 found no emitters: no training pixel's emitter probability passed stage2.emitter_threshold = {} (F_e learns from the emitter masks said above: are there any?), or every piece of marked points was left out (the `not an emitter` lines above say why). The re-render has no direct light, relight ops have nothing to change, and relit renders in edit, eval and the report are black",
            run_threshold(run)
        ));
    }
    println!(
        "stage 2 done: {} iterations in {:.1} s this session ({} emitters, {} surface and {} emitter pixels cached); run in {}",
        stage.iteration(),
        start.elapsed().as_secs_f64(),
        stage.fields.emitters.len(),
        surface,
        emitter,
        args.out.display()
    );
    Ok(())
}

/// The driver's events on a progress bar (and, with `quiet`, one line per 10 iterations):
/// `describe` says what a stage's statistics are; the rate is added here.
fn progress_events<'a, T>(
    bar: &'a ProgressBar,
    start: Instant,
    quiet: bool,
    describe: impl Fn(&T) -> String + 'a,
) -> impl FnMut(Event<T>) + 'a {
    let mut first = 0;
    move |e| match e {
        Event::Started { iteration, total, .. } => {
            first = iteration;
            bar.set_length(total);
            bar.set_position(iteration);
        }
        Event::Pause(what) => bar.set_message(format!("{what}…")),
        Event::Note(line) => crate::progress::line(&line),
        Event::Step { iteration, stats, .. } => {
            bar.set_position(iteration + 1);
            if iteration % 10 == 0 {
                let its = (iteration + 1 - first) as f64 / start.elapsed().as_secs_f64().max(1e-9);
                let msg = format!("{} {its:.1} it/s", describe(stats));
                if quiet {
                    eprintln!("{iteration} {msg}");
                }
                bar.set_message(msg);
            }
        }
        Event::Checkpoint { .. } => {}
    }
}

/// A new run's folder: not in a dataset or overlapping `data`, and either absent, empty or a run
/// already (which `open_run` refuses with its own message).
fn check_new_run(out: &std::path::Path, data: &std::path::Path) -> Result<(), i2sdf_data::DataError> {
    use i2sdf_data::output::{absolute, check_inputs, check_outside_datasets, is_run};
    let abs = absolute(out);
    check_outside_datasets("--out", out, &abs)?;
    check_inputs("--out", &abs, &[data])?;
    if out.is_file() {
        return Err(i2sdf_data::DataError::invalid(format!(
            "--out {}: is a file; give a folder for the run",
            out.display()
        )));
    }
    if !is_run(&abs) && !i2sdf_data::output::entries(&abs).is_empty() {
        return Err(i2sdf_data::DataError::invalid(format!(
            "--out {}: exists and holds files that are not a run: choose a new or empty folder",
            out.display()
        )));
    }
    Ok(())
}

/// Refuses (bad input, naming the estimate and the keys) a training that `i2sdf check` would
/// warn does not fit in the machine's available memory, unless `ignore`: better said now than by
/// the OOM killer an hour in. `config` is what this command trains with (`None`: the run's own).
fn check_memory(
    run: &RunDir,
    dataset: &i2sdf_data::Dataset,
    config: Option<&TrainConfig>,
    stage1: bool,
    stage2: bool,
    ignore: bool,
) -> anyhow::Result<()> {
    let own;
    let config = match config {
        Some(c) => c,
        None => {
            own = i2sdf_train::run::read_run_config(run)?;
            &own
        }
    };
    let Some(machine) = i2sdf_train::memory::MachineMemory::read() else {
        return Ok(());
    };
    let estimate = i2sdf_train::memory::estimate(&i2sdf_train::memory::DatasetShape::of(dataset), config);
    let Some(why) = estimate.over(config, stage1, stage2, machine.available) else {
        return Ok(());
    };
    if ignore {
        crate::progress::line(&format!("warning: {why} (--ignore-memory: training anyway)"));
        return Ok(());
    }
    Err(i2sdf_data::DataError::invalid(format!("{why}: lower them, or pass --ignore-memory to train anyway")).into())
}

/// The run's `stage2.emitter_threshold`, for the message; `?` when unreadable.
fn run_threshold(run: &RunDir) -> String {
    i2sdf_train::run::read_run_config(run)
        .map(|c| c.stage2.emitter_threshold.to_string())
        .unwrap_or_else(|_| "?".into())
}
