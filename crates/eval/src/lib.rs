//! Evaluation for i2sdf (the paper's Sec. 6 and supp. Sec. D, as the README's `eval` row lists): image metrics (with
//! LPIPS when given its weights, [`lpips`]), marching cubes, mesh metrics with
//! visibility culling against the training views, and the `eval` JSON report. Meshes and their PLY
//! I/O are the data layer's (`i2sdf_data::{mesh, ply}`), re-exported here for convenience.

pub mod image_metrics;
pub mod intrinsic;
pub mod lpips;
pub mod mesh;
pub mod mesh_metrics;
pub mod neural;
pub mod poses;
pub mod progress;
pub mod relight;
pub mod report;

pub use i2sdf_data::ply::{read_ply, write_ply};
/// Marching cubes lives in the model crate (training bakes the frozen SDF with it); the old paths
/// `i2sdf_eval::{marching_cubes, mc_tables}` keep naming it.
pub use i2sdf_model::marching_cubes::{self, marching_cubes, McGrid, McOptions};
pub use i2sdf_model::mc_tables;
pub use image_metrics::{depth_l1, normal_angular_l1, psnr, ssim, ImageRef};
pub use intrinsic::{intrinsic_metrics, IntrinsicOptions};
pub use lpips::{Lpips, LpipsWeights};
pub use mesh::TriangleMesh;
pub use mesh_metrics::{
    mesh_metrics, mesh_metrics_with_progress, visible_from_views, CullingView, MeshMetrics, MeshMetricsOptions,
    ObjectRecall,
};
pub use progress::{EvalProgress, NoProgress};
pub use report::{
    EmitterMetrics, EvalReport, GeometryMetrics, MaterialMetrics, MeshReport, RelightSettings, RerenderMetrics,
    ViewSplitMetrics,
};
