//! i2sdf training: the driver shared by the stages (seeding, skipped steps, checkpoints, resume,
//! log and progress), stage 1 (geometry, radiance and emitter fields), its losses, the three-step
//! schedule and error-guided adaptive sampling. The run directory is `i2sdf_model::run_dir`.

pub mod config;
pub mod driver;
pub mod kmeans;
pub mod losses;
pub mod maps;
pub mod memory;
pub mod neighbour_grid;
pub mod pdf_map;
pub mod pose_correction;
pub mod rays;
pub mod resume;
pub mod schedule;
pub mod shading;
pub mod stage1;
pub mod stage2;
pub mod surface_cache;
pub mod targets;
