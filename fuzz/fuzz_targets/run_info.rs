//! A run directory's `run.json`.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let dir = common::scratch_dir();
    std::fs::write(dir.join("run.json"), data).expect("scratch write");
    let _ = i2sdf_model::RunDir::new(dir).read_info();
});
