//! Checkpoints: a stage-1 scene (`checkpoint.safetensors`) and stage-2 intrinsic fields
//! (`stage2.safetensors`), config and metadata included. The loaders take a path, so the input
//! is written to a scratch file.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

/// The SDF feature size of the seed checkpoints' scene (`make_seeds`).
const FEATURE_DIM: usize = 3;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch_dir().join("checkpoint.safetensors");
    std::fs::write(&path, data).expect("scratch write");
    let _ = i2sdf_model::scene::checkpoint_metadata(&path);
    let _ = i2sdf_model::NeuralScene::load(&path);
    let _ = i2sdf_model::intrinsic_io::IntrinsicFields::load(&path, FEATURE_DIM, &mut []);
});
