//! PLY meshes: ASCII and binary, any element layout.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let _ = i2sdf_data::ply::parse_ply(Path::new("mesh.ply"), data);
});
