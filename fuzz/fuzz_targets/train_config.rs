//! The training configuration: a TOML file and `--set key=value` overrides. The input is the
//! file's text, then a NUL byte, then one override per line (no NUL: no overrides; an empty
//! file part: no file).
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let (file, sets) = text.split_once('\0').unwrap_or((text, ""));
    let overrides: Vec<String> = sets.lines().map(str::to_string).collect();
    let path = common::scratch_dir().join("config.toml");
    let file = if file.is_empty() {
        None
    } else {
        std::fs::write(&path, file).expect("scratch write");
        Some(path.as_path())
    };
    let _ = i2sdf_train::config::TrainConfig::load(file, &overrides);
});
