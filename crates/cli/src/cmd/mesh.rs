//! `i2sdf mesh --run RUN --out FILE.ply`: marching cubes over the trained SDF, in world units.

use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    #[arg(long)]
    pub run: PathBuf,
    /// Output mesh (binary PLY, world units).
    #[arg(long)]
    pub out: PathBuf,
    /// Samples along the longest side of the scene's bounding box.
    #[arg(long, default_value_t = i2sdf_eval::neural::MESH_RESOLUTION)]
    pub resolution: usize,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (scene, info) = super::load_run(&args.run)?;
    let bounds = super::run_bounds(&args.run, &info)?;
    let start = std::time::Instant::now();
    let mesh = i2sdf_eval::neural::extract_mesh(&scene, &bounds, args.resolution)?;
    i2sdf_eval::write_ply(&args.out, &mesh)?;
    println!(
        "wrote {}: {} vertices, {} triangles ({}³ grid, {:.1} s)",
        args.out.display(),
        mesh.positions.len(),
        mesh.faces.len(),
        args.resolution,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
