//! PNG images (8/16 bit, 1–4 channels) and depth PNGs read as raw integers.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("image.png");
    let _ = i2sdf_data::imageio::read_image_bytes(path, data);
    let _ = i2sdf_data::imageio::read_png_raw_gray_bytes(path, data);
});
