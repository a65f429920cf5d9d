//! `i2sdf report --run RUN [--data SCENE] [--metrics M.json] --out DIR`: a static HTML report of
//! the run (`DIR/index.html`, `DIR/img/*.png`, `DIR/*.svg`; see `i2sdf_report`). Everything is
//! checked (run, dataset, metrics file, arguments, the output folder) before anything is written;
//! the report is built in a staging folder beside `DIR` and moved into place at the end.

use clap::Args as ClapArgs;
use i2sdf_data::DataError;
use i2sdf_report::{write_report, ReportOptions, RunInputs};
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// The trained run to report on.
    #[arg(long)]
    pub run: PathBuf,
    /// Output folder (created; built aside and moved into place at the end).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if it holds a previous report.
    #[arg(long)]
    pub force: bool,
    /// Dataset (defaults to the one the run was trained on).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// The `i2sdf eval` JSON of this run (without it the metrics table says how to make one).
    #[arg(long)]
    pub metrics: Option<PathBuf>,
    /// Index of the test view shown.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true, value_parser = super::view_index)]
    pub view: usize,
    /// Paths per pixel of the path-traced images.
    #[arg(long, default_value_t = 32)]
    pub spp: u32,
    /// Most scattering events per path of the relit and edited views.
    #[arg(long, default_value_t = ReportOptions::default().bounces)]
    pub bounces: u32,
    /// Marching-cubes resolution of the surface preview and the edit renderer's mesh.
    #[arg(long, default_value_t = ReportOptions::default().mesh_resolution)]
    pub mesh_resolution: usize,
    /// The room exported by `i2sdf export` (.glb or .gltf), linked from the report.
    #[arg(long)]
    pub scene: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(1..=65536).contains(&args.spp) {
        return Err(DataError::invalid(format!("--spp {}: must be in [1, 65536]", args.spp)).into());
    }
    if !(1..=1024).contains(&args.bounces) {
        return Err(DataError::invalid(format!("--bounces {}: must be in [1, 1024]", args.bounces)).into());
    }
    if !(16..=1024).contains(&args.mesh_resolution) {
        return Err(DataError::invalid(format!(
            "--mesh-resolution {}: must be in [16, 1024]",
            args.mesh_resolution
        ))
        .into());
    }
    let metrics = match &args.metrics {
        Some(p) => Some((p.clone(), i2sdf_report::metrics::read_metrics(p)?)),
        None => None,
    };
    if let Some(scene) = &args.scene {
        if !scene.is_file() || i2sdf_export::Container::of_path(scene).is_none() {
            return Err(
                DataError::file(scene, "--scene: not a .glb or .gltf file (write one with i2sdf export)").into(),
            );
        }
    }
    let (data, dataset) = super::run_dataset(&args.run, args.data.as_deref())?;
    let mut inputs = vec![data.as_path()];
    if let Some(m) = &args.metrics {
        inputs.push(m);
    }
    let staged = super::output_dir(
        "--out",
        &args.out,
        args.force,
        "a report",
        &|dir| {
            dir.join("index.html").is_file()
                && super::only_entries(dir, |name, is_dir| {
                    (is_dir && name == "img") || name == "index.html" || name.ends_with(".svg")
                })
        },
        &inputs,
        Some(64 << 20),
    )?;
    let run = super::open_run(&args.run)?;
    let input = RunInputs {
        run: &run,
        data: &data,
        dataset: &dataset,
        metrics: metrics.as_ref().map(|(p, v)| (p.as_path(), v)),
        scene: args.scene.as_deref().map(|p| {
            let href = i2sdf_report::relative_to(p, &args.out)
                .to_string_lossy()
                .replace('\\', "/");
            (p, href)
        }),
    };
    let options = ReportOptions {
        view: args.view,
        spp: args.spp,
        bounces: args.bounces,
        mesh_resolution: args.mesh_resolution,
    };
    let summary = write_report(&input, &options, staged.path(), &|step| {
        crate::progress::line(&format!("report: {step}…"))
    })?;
    staged.commit()?;
    println!(
        "wrote {} ({} files) in {:.1} s",
        args.out.join("index.html").display(),
        summary.files,
        summary.seconds
    );
    Ok(())
}
