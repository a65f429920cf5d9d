//! `i2sdf`: the command-line contract of the README's "Commands". Each subcommand lives in `cmd/<name>.rs` with
//! its own clap `Args` and a `run` function; this file only dispatches and maps errors to exit codes.

mod cmd;
mod progress;

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
    /// Render a synthetic indoor room with full ground truth (images, depth, normals, emitter masks, materials, mesh, relit test views).
    Synth(cmd::synth::Args),
    /// Time the neural engine: a representative stage-1 iteration, the paper's MLP backbone, and this machine's sgemm peak.
    Bench(cmd::bench::Args),
    /// Train a run: stage 1 (SDF, radiance and emitter fields) from a dataset.
    Train(cmd::train::Args),
    /// Extract the trained SDF's surface as a mesh (marching cubes, world units, PLY).
    Mesh(cmd::mesh::Args),
    /// Export the recovered room as a glTF 2.0 scene (.glb/.gltf): surface, GGX materials, emitters, cameras.
    Export(cmd::export::Args),
    /// Render views with the trained fields: colour, depth, normals, emitter probability.
    Render(cmd::render::Args),
    /// Render edited views of a stage-2 run by path tracing: relight emitters, override materials in regions, insert objects.
    Edit(cmd::edit::Args),
    /// Evaluate a run against its dataset: image, depth, normal and mesh metrics as JSON.
    Eval(cmd::eval::Args),
    /// Write a static HTML report of a run: metrics against the paper's, training curves, GT | ours | error grids, emitters, the surface, relit and edited views.
    Report(cmd::report::Args),
    /// Run the whole pipeline on the built-in synthetic room (synth → check → train → mesh → render → eval).
    Demo(cmd::demo::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check(a) => cmd::check::run(a),
        Command::Synth(a) => cmd::synth::run(a),
        Command::Bench(a) => cmd::bench::run(a),
        Command::Train(a) => cmd::train::run(a),
        Command::Mesh(a) => cmd::mesh::run(a),
        Command::Export(a) => cmd::export::run(a),
        Command::Render(a) => cmd::render::run(a),
        Command::Edit(a) => cmd::edit::run(a),
        Command::Eval(a) => cmd::eval::run(a),
        Command::Report(a) => cmd::report::run(a),
        Command::Demo(a) => cmd::demo::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(cmd::exit_code(&e))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Cli;
    use clap::CommandFactory;

    /// Every flag of every command says what it is for in `--help`.
    #[test]
    fn every_flag_has_a_help_line() {
        let cli = Cli::command();
        let mut missing = Vec::new();
        for sub in cli.get_subcommands() {
            for arg in sub.get_arguments() {
                let Some(long) = arg.get_long() else { continue };
                if matches!(long, "help" | "version") {
                    continue;
                }
                if arg.get_help().is_none_or(|h| h.to_string().trim().is_empty()) {
                    missing.push(format!("{} --{long}", sub.get_name()));
                }
            }
        }
        assert!(missing.is_empty(), "flags without a --help line: {missing:?}");
    }

    /// The README's command table names every flag of each command in that command's row.
    #[test]
    fn the_readme_command_table_matches_the_flags() {
        let readme = include_str!("../../../README.md");
        let cli = Cli::command();
        let mut missing = Vec::new();
        for sub in cli.get_subcommands() {
            let name = sub.get_name();
            let Some(row) = readme.lines().find(|l| l.starts_with(&format!("| `i2sdf {name}"))) else {
                missing.push(format!("no row for `i2sdf {name}`"));
                continue;
            };
            for arg in sub.get_arguments() {
                let Some(long) = arg.get_long() else { continue };
                if matches!(long, "help" | "version") {
                    continue;
                }
                let flag = format!("--{long}");
                let named = row
                    .match_indices(&flag)
                    .any(|(i, _)| !row[i + flag.len()..].starts_with(|c: char| c.is_ascii_alphanumeric() || c == '-'));
                if !named {
                    missing.push(format!("`i2sdf {name}` row lacks {flag}"));
                }
            }
        }
        assert!(missing.is_empty(), "README command table: {missing:?}");
    }

    #[test]
    fn the_readme_configuration_reference_is_the_config_types() {
        let readme = include_str!("../../../README.md");
        let want = i2sdf_train::config::TrainConfig::reference();
        let block = readme
            .split_once("<!-- configuration reference: TrainConfig::reference() -->\n```toml\n")
            .and_then(|(_, rest)| rest.split_once("```"))
            .map(|(b, _)| b);
        assert_eq!(
            block,
            Some(want.as_str()),
            "the README's configuration reference should read:\n{want}"
        );
    }
}
