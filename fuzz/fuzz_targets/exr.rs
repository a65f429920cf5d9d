//! EXR images and float maps through the house's reader.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let _ = i2sdf_data::imageio::read_image_bytes(Path::new("map.exr"), data);
});
