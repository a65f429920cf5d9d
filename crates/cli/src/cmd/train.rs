//! `i2sdf train`: stage 1 (geometry, radiance, emitter fields) with a progress bar; the loop,
//! checkpoints and logs live in `i2sdf_train::driver`.

use clap::{Args as ClapArgs, ValueEnum};
use i2sdf_model::RunDir;
use i2sdf_train::config::TrainConfig;
use i2sdf_train::driver::{train_geometry, Event};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Stage {
    /// Stage 1: SDF, radiance and emitter fields (paper Sec. 3–4.2).
    Geometry,
}

#[derive(ClapArgs)]
pub struct Args {
    /// Dataset directory.
    #[arg(long)]
    pub data: PathBuf,
    /// Run directory (created; with --resume, continued).
    #[arg(long)]
    pub out: PathBuf,
    /// TOML configuration file (defaults are tuned for the default synthetic room).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a configuration value, e.g. --set train.iterations=2000 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Which stage to train (stage 2, materials, is not available yet).
    #[arg(long, value_enum, default_value = "geometry")]
    pub stage: Stage,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Print one line per log step instead of a progress bar.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let run = RunDir::new(&args.out);
    let config = if args.resume {
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
    } else {
        Some(TrainConfig::load(args.config.as_deref(), &args.set)?)
    };
    if let Some(c) = &config {
        if c.train.threads > 0 {
            let _ = rayon::ThreadPoolBuilder::new()
                .num_threads(c.train.threads)
                .build_global();
        }
    }
    eprintln!("loading {}", args.data.display());
    let dataset = i2sdf_data::load(&args.data)?;
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{spinner} stage 1 [{bar:30}] {pos}/{len} {msg} ({elapsed} < {eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    if args.quiet {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    let start = Instant::now();
    let mut first = 0;
    let stage = train_geometry(
        &run,
        &dataset,
        &args.data.display().to_string(),
        config,
        args.resume,
        |e| match e {
            Event::Started { iteration, total, .. } => {
                first = iteration;
                bar.set_length(total);
                bar.set_position(iteration);
            }
            Event::Pause(what) => bar.set_message(format!("{what}…")),
            Event::Step {
                iteration, stats: s, ..
            } => {
                bar.set_position(iteration + 1);
                if iteration % 10 == 0 {
                    let its = (iteration + 1 - first) as f64 / start.elapsed().as_secs_f64().max(1e-9);
                    let msg = format!(
                        "{:?} loss {:.4} psnr {:.2} depth {:.4} β {:.4} {:.1} it/s",
                        s.phase.unwrap(),
                        s.loss,
                        s.psnr,
                        s.depth,
                        s.beta,
                        its
                    );
                    if args.quiet {
                        eprintln!("{iteration} {msg}");
                    }
                    bar.set_message(msg);
                }
            }
            Event::Checkpoint { .. } => {}
        },
    )?;
    bar.finish();
    println!(
        "stage 1 done: {} iterations in {:.1} s this session; run in {}",
        stage.iteration,
        start.elapsed().as_secs_f64(),
        args.out.display()
    );
    Ok(())
}
