//! i2sdf training: the stage-1 loop (geometry, radiance and emitter fields), its losses, the
//! three-step schedule, error-guided adaptive sampling, checkpoints and the run directory.

pub mod config;
pub mod driver;
pub mod losses;
pub mod pdf_map;
pub mod rays;
pub mod run_dir;
pub mod schedule;
pub mod stage1;
