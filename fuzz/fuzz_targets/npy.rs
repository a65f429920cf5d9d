//! `.npy` float maps (depth, normals, materials) and the matrix reader's f64 path.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("map.npy");
    let _ = i2sdf_data::imageio::read_float_map_bytes(path, data);
    if let Ok(npy) = i2sdf_data::imageio::npy_file(path, data) {
        let _ = i2sdf_data::imageio::read_npy_f64(path, npy);
    }
});
