//! `i2sdf mesh --run RUN --out FILE.ply`: marching cubes over the trained SDF, in world units.

use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// The trained run whose SDF is meshed.
    #[arg(long)]
    pub run: PathBuf,
    /// Output mesh (binary PLY, world units; must end in .ply).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if it exists.
    #[arg(long)]
    pub force: bool,
    /// Samples along the longest side of the scene's bounding box.
    #[arg(long, default_value_t = i2sdf_eval::neural::MESH_RESOLUTION)]
    pub resolution: usize,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let info = i2sdf_model::RunDir::new(&args.run).read_info()?;
    let data = std::path::PathBuf::from(&info.data);
    super::output_file("--out", &args.out, &["ply"], args.force, &[&data], None)?;
    let run = super::open_run(&args.run)?;
    let bounds = run.bounds()?;
    let start = std::time::Instant::now();
    let mesh = i2sdf_model::extract_mesh(&run.scene, &bounds, args.resolution)?;
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
