//! i2sdf training, laid out as the pipeline runs it:
//! - [`run`] opens a run directory (fresh or resumed, its dataset and configuration checked) and
//!   starts a stage in it; [`driver`] is the generic loop every stage runs under (seeding, skipped
//!   steps, atomic checkpoints, log, progress); [`resume`] holds the checks that make a run safe to
//!   continue;
//! - [`stage1`]: geometry, radiance and emitter fields by volume rendering (its rays, losses,
//!   three-step schedule, error-guided sampling and pose correction in its folder);
//! - [`stage2`]: emitters and materials by Monte Carlo re-rendering (its targets, clustering,
//!   shading estimator, cache and losses in its folder);
//! - shared by both: the [`config`], the [`maps`] in force, the [`memory`] estimate.
//!
//! The run directory's layout is `i2sdf_model::run_dir`.

pub mod auto;
pub mod config;
pub mod driver;
pub mod maps;
pub mod memory;
pub mod resume;
pub mod run;
pub mod stage1;
pub mod stage2;
