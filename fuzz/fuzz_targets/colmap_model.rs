//! COLMAP's sparse model files (`cameras`, `images`, `points3D`, binary and text): the first byte
//! picks the file and format, the rest is its content.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Some((&which, bytes)) = data.split_first() else { return };
    use i2sdf_data::colmap::*;
    let text = || std::str::from_utf8(bytes).ok();
    match which % 6 {
        0 => drop(parse_cameras_bin(Path::new("cameras.bin"), bytes)),
        1 => drop(parse_images_bin(Path::new("images.bin"), bytes)),
        2 => drop(parse_points_bin(Path::new("points3D.bin"), bytes)),
        3 => drop(text().map(|t| parse_cameras_txt(Path::new("cameras.txt"), t))),
        4 => drop(text().map(|t| parse_images_txt(Path::new("images.txt"), t))),
        _ => drop(text().map(|t| parse_points_txt(Path::new("points3D.txt"), t))),
    }
});
