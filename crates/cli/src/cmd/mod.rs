pub mod bench;
pub mod check;
pub mod demo;
pub mod eval;
pub mod mesh;
pub mod render;
pub mod synth;
pub mod train;

/// DESIGN.md exit codes: 2 for bad input (a `DataError` in the chain that says so: a file, field,
/// key or argument at fault), 1 for anything else (a failed write, a diverged run, an internal
/// error).
pub fn exit_code(e: &anyhow::Error) -> u8 {
    if e.chain().any(|c| {
        c.downcast_ref::<i2sdf_data::DataError>()
            .is_some_and(|d| d.is_bad_input())
    }) {
        2
    } else {
        1
    }
}

/// A trained run's fields (from its checkpoint) and its run info.
pub fn load_run(
    run: &std::path::Path,
) -> Result<(i2sdf_model::NeuralScene, i2sdf_model::RunInfo), i2sdf_data::DataError> {
    let dir = i2sdf_model::RunDir::new(run);
    let info = dir.read_info()?;
    let (scene, _) = i2sdf_model::NeuralScene::load(&dir.checkpoint_path())?;
    Ok((scene, info))
}

/// The volume renderer's settings the run was trained with (its `[sampling]` section), so
/// `render` and `eval` see what training saw.
pub fn run_render_settings(
    run: &std::path::Path,
) -> Result<i2sdf_model::renderer::RenderSettings, i2sdf_data::DataError> {
    let config = i2sdf_train::driver::read_run_config(&i2sdf_model::RunDir::new(run))?;
    Ok(i2sdf_train::driver::render_settings(&config))
}

/// The scene bounds recorded in the run.
pub fn run_bounds(
    run: &std::path::Path,
    info: &i2sdf_model::RunInfo,
) -> Result<i2sdf_data::Bounds, i2sdf_data::DataError> {
    info.bounds.ok_or_else(|| {
        i2sdf_data::DataError::field(
            run.join("run.json"),
            "bounds",
            "missing (run trained by an older version?)",
        )
    })
}
