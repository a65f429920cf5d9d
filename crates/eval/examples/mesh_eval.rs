//! Scores a mesh file against a dataset's ground-truth mesh with `eval`'s mesh metrics (visibility
//! culling, F-score, per-object and thin-object recall), without the view renders: for comparing
//! extraction settings (e.g. `i2sdf mesh --resolution`) on one trained SDF.
//!
//! `cargo run --release -p i2sdf-eval --example mesh_eval -- MESH.ply DATA`

use i2sdf_eval::mesh_metrics::MeshMetricsOptions;
use i2sdf_eval::neural::{culling_views, mesh_report};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, mesh, data] = args.as_slice() else {
        return Err("usage: mesh_eval MESH.ply DATA".into());
    };
    let dataset = i2sdf_data::load(std::path::Path::new(data))?;
    let gt_path = dataset
        .mesh_path
        .clone()
        .ok_or(format!("{data}: no ground-truth mesh"))?;
    let pred = i2sdf_data::ply::read_ply(std::path::Path::new(mesh))?;
    let gt = i2sdf_data::ply::read_ply(&gt_path)?;
    let (report, groups) = mesh_report(
        &pred,
        &gt,
        &culling_views(&dataset),
        &dataset.objects,
        &MeshMetricsOptions::default(),
    )?;
    println!(
        "{}",
        serde_json::to_string_pretty(
            &serde_json::json!({"mesh": report, "thin_objects": groups.thin, "small_objects": groups.small})
        )?
    );
    Ok(())
}
