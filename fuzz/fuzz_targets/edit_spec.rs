//! Edit specs (TOML `[[op]]` tables), resolved against a folder holding one texture.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let dir = common::edit_dir();
    let _ = i2sdf_data::EditSpec::from_toml_str(text, &dir.join("edit.toml"));
});
