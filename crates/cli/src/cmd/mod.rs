pub mod bench;
pub mod check;
pub mod demo;
pub mod edit;
pub mod eval;
pub mod mesh;
pub mod render;
pub mod report;
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

/// A trained run's stage-1 scene, its stage-2 fields where `RUN/stage2.safetensors` exists, and
/// its run info.
pub fn load_run_intrinsic(
    run: &std::path::Path,
) -> Result<
    (
        i2sdf_model::NeuralScene,
        Option<i2sdf_model::intrinsic_io::IntrinsicFields>,
        i2sdf_model::RunInfo,
    ),
    i2sdf_data::DataError,
> {
    let dir = i2sdf_model::RunDir::new(run);
    let info = dir.read_info()?;
    let (scene, fields) = i2sdf_model::intrinsic_io::load_run(&dir)?;
    Ok((scene, fields, info))
}

/// The bad-input error for a stage-2 output asked of a run without stage 2.
pub fn no_stage2(run: &std::path::Path) -> i2sdf_data::DataError {
    i2sdf_data::DataError::file(
        i2sdf_model::RunDir::new(run).stage2_checkpoint_path(),
        "no stage 2: train --stage material first",
    )
}

/// The F_e threshold stage 2 labelled its emitters with (the run's `stage2.emitter_threshold`).
pub fn run_emitter_threshold(run: &std::path::Path) -> Result<f32, i2sdf_data::DataError> {
    let config = i2sdf_train::driver::read_run_config(&i2sdf_model::RunDir::new(run))?;
    Ok(config.stage2.emitter_threshold)
}

/// Whether stage 2 labelled the unobserved surface inside emitters as emitting (the run's
/// `stage2.label_unobserved`): the re-render, `render` and `edit` label hits the same way.
pub fn run_label_unobserved(run: &std::path::Path) -> Result<bool, i2sdf_data::DataError> {
    let config = i2sdf_train::driver::read_run_config(&i2sdf_model::RunDir::new(run))?;
    Ok(config.stage2.label_unobserved)
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
