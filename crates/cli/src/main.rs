//! `i2sdf`: the command-line contract of DESIGN.md. Each subcommand lives in `cmd/<name>.rs` with
//! its own clap `Args` and a `run` function; this file only dispatches and maps errors to exit codes.

mod cmd;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "i2sdf",
    version,
    about = "Intrinsic indoor scene reconstruction and editing (I²-SDF)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Validate a dataset (native transforms.json or the paper's release format) and summarize it.
    Check(cmd::check::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check(a) => cmd::check::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(cmd::exit_code(&e))
        }
    }
}
