//! The native dataset's `transforms.json`, read by the full loader over a tiny real dataset.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = i2sdf_data::native::load_from_str(common::native_dir(), text);
    }
});
