//! The paper format's `cameras_normalize.npz` (a zip of `.npy` matrices), read by the full
//! loader over a tiny real dataset.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let root = common::paper_dir();
    let _ = i2sdf_data::paper::load_with_npz_bytes(root, &root.join("cameras_normalize.npz"), data);
});
