//! Evaluation for i2sdf (DESIGN.md "Evaluation"): image metrics, marching cubes, PLY meshes, mesh
//! metrics with visibility culling against the training views, and the `eval` JSON report.

pub mod image_metrics;
pub mod kdtree;
pub mod marching_cubes;
pub mod mc_tables;
pub mod mesh;
pub mod mesh_metrics;
pub mod neural;
pub mod ply;
pub mod report;

pub use image_metrics::{depth_l1, normal_angular_l1, psnr, ssim, ImageRef};
pub use marching_cubes::{marching_cubes, McGrid, McOptions};
pub use mesh::TriangleMesh;
pub use mesh_metrics::{mesh_metrics, visible_from_views, CullingView, MeshMetrics, MeshMetricsOptions, ObjectRecall};
pub use ply::{read_ply, write_ply};
pub use report::{EvalReport, GeometryMetrics, MeshReport};
