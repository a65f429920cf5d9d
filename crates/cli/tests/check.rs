//! `i2sdf check` end to end: good datasets pass with a summary; every kind of bad input exits with
//! code 2 and a message naming the file (and field).

use i2sdf_data::fixture::{self, FixtureOptions};
use i2sdf_data::imageio::{self, ImageF32};
use serde_json::Value;
use std::path::Path;
use std::process::Command;

fn check(dir: &Path) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_i2sdf"))
        .args(["check", "--data"])
        .arg(dir)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn native() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    fixture::write_native(dir.path(), &FixtureOptions::default());
    dir
}

fn edit_json(dir: &Path, f: impl FnOnce(&mut Value)) {
    let p = dir.join("transforms.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&p, serde_json::to_string(&v).unwrap()).unwrap();
}

/// Asserts exit code 2 and that stderr mentions every needle.
fn assert_bad(dir: &Path, needles: &[&str]) {
    let (code, _, err) = check(dir);
    assert_eq!(code, 2, "stderr: {err}");
    for n in needles {
        assert!(err.contains(n), "expected '{n}' in: {err}");
    }
}

#[test]
fn good_datasets_pass_with_a_summary() {
    let dir = native();
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    for needle in [
        "native",
        "4 train, 2 test",
        "24×18",
        "depth 6/6",
        "normal 6/6",
        "emitter_mask 6/6",
        "normalized",
    ] {
        assert!(out.contains(needle), "expected '{needle}' in:\n{out}");
    }
    let dir = tempfile::tempdir().unwrap();
    fixture::write_paper(dir.path(), &FixtureOptions::default());
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("paper release") && out.contains("4 train, 2 test") && out.contains("depth 4/6"),
        "{out}"
    );
}

#[test]
fn missing_dataset_and_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    assert_bad(&dir.path().join("nowhere"), &["nowhere", "not found"]);
    assert_bad(dir.path(), &["not a dataset"]);
    let dir = native();
    std::fs::remove_file(dir.path().join("depth/frame_002.exr")).unwrap();
    assert_bad(dir.path(), &["frame_002.exr", "not found"]);
}

#[test]
fn unreadable_files() {
    let dir = native();
    std::fs::write(dir.path().join("images/frame_001.png"), b"garbage").unwrap();
    assert_bad(dir.path(), &["frame_001.png", "decode"]);
    let dir = native();
    std::fs::write(dir.path().join("transforms.json"), b"{ not json").unwrap();
    assert_bad(dir.path(), &["transforms.json", "invalid JSON"]);
}

#[test]
fn wrong_image_size() {
    let dir = native();
    imageio::write_exr(&dir.path().join("depth/frame_003.exr"), &ImageF32::new(10, 18, 1)).unwrap();
    assert_bad(dir.path(), &["frame_003.exr", "10×18", "24×18"]);
}

#[test]
fn non_finite_values() {
    let dir = native();
    let p = dir.path().join("normals/frame_000.npy");
    let mut n = imageio::read_float_map(&p).unwrap();
    n.pixel_mut(5, 7)[1] = f32::NAN;
    imageio::write_npy(&p, &n).unwrap();
    assert_bad(dir.path(), &["frame_000.npy", "non-finite", "(5, 7)"]);
    let dir = native();
    edit_json(dir.path(), |v| v["frames"][1]["fl_x"] = Value::Null);
    assert_bad(dir.path(), &["transforms.json", "frames[1].fl_x"]);
}

/// Depth as sensors write it: a NaN depth pixel is no depth, dropped and counted (text and
/// JSON), not a refused dataset; a 1000 m outlier falls outside the validity window.
#[test]
fn depth_holes_and_outliers_are_dropped_and_counted() {
    let dir = native();
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("depth kept   2592 of 2592 samples, none dropped; validity window"),
        "{out}"
    );
    let p = dir.path().join("depth/frame_001.exr");
    let mut d = imageio::read_float_map(&p).unwrap();
    d.pixel_mut(5, 7)[0] = f32::NAN;
    d.pixel_mut(6, 7)[0] = 1000.0;
    imageio::write_exr(&p, &d).unwrap();
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("2590 of 2592 samples, dropped 1 non-finite, 1 outside the validity window;"),
        "{out}"
    );
    let (code, out, err) = check_with(dir.path(), &["--json"]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    let dropped = &v["depth_dropped"];
    assert_eq!(
        (&dropped["non_finite"], &dropped["out_of_window"], &dropped["kept"]),
        (&Value::from(1), &Value::from(1), &Value::from(2590)),
        "{out}"
    );
    assert!(v["depth_window"][1].as_f64().unwrap() > 5.0, "{out}");
}

#[test]
fn degenerate_poses() {
    let dir = native();
    edit_json(dir.path(), |v| {
        v["frames"][2]["transform_matrix"][0] = serde_json::json!([0.0, 0.0, 0.0, 0.0])
    });
    assert_bad(
        dir.path(),
        &["transforms.json", "frames[2].transform_matrix", "not invertible"],
    );
    let dir = native();
    edit_json(dir.path(), |v| {
        let row = v["frames"][0]["transform_matrix"][1].as_array_mut().unwrap();
        for x in row.iter_mut().take(3) {
            *x = Value::from(x.as_f64().unwrap() * 1.5);
        }
    });
    assert_bad(
        dir.path(),
        &["transforms.json", "frames[0].transform_matrix", "not rigid"],
    );
}

#[test]
fn empty_split_and_bad_split() {
    let dir = native();
    edit_json(dir.path(), |v| {
        for f in v["frames"].as_array_mut().unwrap() {
            f["split"] = Value::from("train");
        }
    });
    assert_bad(dir.path(), &["transforms.json", "'test' split is empty"]);
    let dir = native();
    edit_json(dir.path(), |v| v["frames"][0]["split"] = Value::from("validation"));
    assert_bad(dir.path(), &["frames[0].split"]);
    let dir = tempfile::tempdir().unwrap();
    fixture::write_paper(dir.path(), &FixtureOptions::default());
    // Without val/, the paper format holds out every 8th training view instead.
    std::fs::remove_dir_all(dir.path().join("val")).unwrap();
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("3 train, 1 test"), "{out}");
}

#[test]
fn nerfstudio_filename_lists_are_honoured() {
    let dir = native();
    edit_json(dir.path(), |v| {
        for f in v["frames"].as_array_mut().unwrap() {
            f.as_object_mut().unwrap().remove("split");
        }
        v["train_filenames"] =
            serde_json::json!(["images/frame_000.png", "images/frame_001.png", "./images/frame_002.png"]);
        v["test_filenames"] =
            serde_json::json!(["images/frame_003.png", "images/frame_004.png", "images/frame_005.png"]);
    });
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("3 train, 3 test"), "{out}");
    edit_json(dir.path(), |v| {
        v["test_filenames"] = serde_json::json!(["images/frame_003.png"])
    });
    assert_bad(dir.path(), &["frames[4].file_path", "neither"]);
}

#[test]
fn paper_format_errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    fixture::write_paper(dir.path(), &FixtureOptions::default());
    std::fs::remove_file(dir.path().join("depth/0001.exr")).unwrap();
    assert_bad(dir.path(), &["depth", "3 files but image/ has 4"]);

    let dir = tempfile::tempdir().unwrap();
    fixture::write_paper(dir.path(), &FixtureOptions::default());
    std::fs::write(dir.path().join("cameras_normalize.npz"), b"PK garbage").unwrap();
    assert_bad(dir.path(), &["cameras_normalize.npz"]);

    let dir = tempfile::tempdir().unwrap();
    fixture::write_paper(dir.path(), &FixtureOptions::default());
    // All-zero normals mean "no normal", which is fine; [0,1]-encoded colours are not normals.
    let mut n = ImageF32::new(24, 18, 3);
    n.data.iter_mut().for_each(|v| *v = 0.5);
    imageio::write_exr(&dir.path().join("normal/0002.exr"), &n).unwrap();
    assert_bad(dir.path(), &["0002.exr", "unit normals"]);
}

/// The paper's release declares no exposure; `check` measures the one its LDR/HDR pairs show and
/// says it, and a `radiometry.json` declares it (and is checked against the images).
#[test]
fn paper_format_exposure_is_measured_and_declared() {
    let dir = tempfile::tempdir().unwrap();
    let extra = fixture::PaperOptions {
        hdr_exposure: Some(2.0),
        material_masks: true,
        ..Default::default()
    };
    fixture::write_paper_with(dir.path(), &FixtureOptions::default(), &extra);
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("exposure     declared –, measured 2.0000"), "{out}");
    assert!(
        err.contains("no exposure is declared") && err.contains("2.0000"),
        "{err}"
    );
    // The material masks are counted and what stage 2 does with them is said.
    assert!(
        out.contains("material_mask 4/6") && out.contains("material masks"),
        "{out}"
    );
    std::fs::write(
        dir.path().join("radiometry.json"),
        r#"{"ldr": {"transfer": "srgb", "exposure": 2.0}}"#,
    )
    .unwrap();
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("exposure     declared 2, measured 2.0000"), "{out}");
    assert!(!err.contains("warning"), "{err}");
    std::fs::write(dir.path().join("radiometry.json"), r#"{"ldr": {"exposure": 6.0}}"#).unwrap();
    let (code, _, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("ldr.exposure = 6 is declared") && err.contains("2.0000"),
        "{err}"
    );
    std::fs::write(dir.path().join("radiometry.json"), r#"{"ldr": {"exposure": "bright"}}"#).unwrap();
    assert_bad(dir.path(), &["radiometry.json", "ldr.exposure"]);
}

fn check_with(dir: &Path, extra: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_i2sdf"))
        .args(["check", "--data"])
        .arg(dir)
        .args(extra)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The training memory estimate is printed (text and JSON) beside the machine's memory; a
/// configuration that cannot fit warns, naming both figures, and still passes (exit 0).
#[test]
fn training_memory_is_estimated_and_warned_about() {
    let dir = native();
    let (code, out, err) = check_with(dir.path(), &[]);
    assert_eq!(code, 0, "{err}");
    for needle in [
        "training memory (estimate): stage 1",
        "training memory (estimate): stage 2",
        "dataset",
        "GiB",
        "machine memory:",
    ] {
        assert!(out.contains(needle), "expected '{needle}' in:\n{out}");
    }
    assert!(!err.contains("warning"), "{err}");
    // 2^20 rays × 1024 samples: terabytes of activations.
    let huge = ["--set", "train.rays=1048576", "--set", "sampling.samples=1024"];
    let (code, _, err) = check_with(dir.path(), &huge);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("warning: stage 1 needs about")
            && err.contains("GiB available")
            && err.contains("train.rays: 1024 → 1048576")
            && err.contains("--ignore-memory"),
        "{err}"
    );
    let (code, out, err) = check_with(dir.path(), &[&huge[..], &["--json"][..]].concat());
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert!(v["memory"]["stage1_bytes"].as_f64().unwrap() > 1e12, "{out}");
    assert!(v["memory"]["stage2_bytes"].as_f64().unwrap() > 0.0);
    assert_eq!(v["memory"]["fits"], Value::Bool(false));
    assert!(
        v.get("format").is_some() && v.get("train_views").is_some(),
        "the summary is still there"
    );
    // The configuration is read as `train` reads it: a bad key is bad input.
    let (code, _, err) = check_with(dir.path(), &["--set", "stage2.pixels=0"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("stage2.pixels"), "{err}");
}

/// A COLMAP dataset: the summary says how its scale was fixed (text and JSON), and bad input in
/// its model exits 2 naming the file.
#[test]
fn colmap_datasets_print_their_scale_fix() {
    let dir = tempfile::tempdir().unwrap();
    fixture::write_colmap(dir.path(), &FixtureOptions::default(), 0.25);
    let (code, out, err) = check(dir.path());
    assert_eq!(code, 0, "{err}");
    for needle in [
        "COLMAP sparse model",
        "4 train, 2 test",
        "scale        COLMAP model ×",
        "depth 6/6",
    ] {
        assert!(out.contains(needle), "expected '{needle}' in:\n{out}");
    }
    let (code, out, err) = check_with(dir.path(), &["--json"]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["format"], "Colmap");
    let ratio = v["colmap_scale"]["ratio"].as_f64().unwrap();
    assert!((ratio * 0.25 - 1.0).abs() < 0.01, "{ratio}");
    assert!(v["colmap_scale"]["samples"].as_u64().unwrap() > 100);

    let cameras = dir.path().join("sparse/0/cameras.txt");
    let text = std::fs::read_to_string(&cameras).unwrap();
    std::fs::write(&cameras, text.replacen("PINHOLE", "FULL_OPENCV", 1)).unwrap();
    assert_bad(dir.path(), &["cameras.txt", "FULL_OPENCV"]);
}

/// Item 5 of issue 24: a synthesized room exported as a COLMAP dataset (text model at another
/// scale, its images, 16-bit millimetre depth, masks, test.txt) loads with the cameras of its
/// transforms.json, the scale recovered from the depth.
#[test]
fn a_synth_room_exported_to_colmap_loads_with_its_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let room = dir.path().join("room");
    let out = Command::new(env!("CARGO_BIN_EXE_i2sdf"))
        .args([
            "synth", "--width", "40", "--height", "30", "--views", "12", "--spp", "4", "--out",
        ])
        .arg(&room)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let native = i2sdf_data::load(&room).unwrap();

    let model_scale = 0.23;
    let colmap = dir.path().join("colmap");
    let (mut views, mut points, mut test_list) = (Vec::new(), Vec::new(), String::new());
    for f in &native.frames {
        let file = f.image_path.file_name().unwrap().to_string_lossy().into_owned();
        std::fs::create_dir_all(colmap.join("images")).unwrap();
        std::fs::copy(&f.image_path, colmap.join("images").join(&file)).unwrap();
        let depth = f.depth.as_ref().expect("synth rooms have depth");
        let mm: Vec<u16> = depth.data.iter().map(|d| (d * 1000.0).round() as u16).collect();
        let stem = file.trim_end_matches(".png");
        imageio::write_png16_raw(
            &colmap.join(format!("depth/{stem}.png")),
            depth.width,
            depth.height,
            1,
            &mm,
        )
        .unwrap();
        if let Some(mask) = &f.emitter_mask {
            imageio::write_png(&colmap.join(format!("masks/{stem}.png")), mask).unwrap();
        }
        if f.split == i2sdf_data::Split::Test {
            test_list.push_str(&format!("{file}\n"));
        }
        for j in (0..f.camera.height).step_by(3) {
            for i in (0..f.camera.width).step_by(3) {
                let d = depth.pixel(i, j)[0] as f64;
                if d > 0.0 {
                    points.push(f.camera.backproject(i, j, d) * model_scale);
                }
            }
        }
        let mut cam = f.camera.clone();
        cam.c2w.w_axis = (f.camera.center() * model_scale).extend(1.0);
        views.push((file, cam));
    }
    fixture::write_colmap_text(&colmap.join("sparse/0"), &views, &points);
    std::fs::write(colmap.join("test.txt"), test_list).unwrap();

    let ds = i2sdf_data::load(&colmap).unwrap();
    let fix = ds.colmap_scale.unwrap();
    let err = (fix.ratio * model_scale - 1.0).abs();
    println!(
        "synth room via COLMAP: ratio {:.6} (true {:.6}), error {err:.2e}, spread {:.2e}, {} samples",
        fix.ratio,
        1.0 / model_scale,
        fix.spread,
        fix.samples
    );
    assert!(err < 0.01, "{fix:?}");
    assert_eq!(ds.frames.len(), native.frames.len());
    let (lo, hi) = (native.bounds.min, native.bounds.max);
    let extent = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
    for (a, b) in ds.frames.iter().zip(&native.frames) {
        assert_eq!((&a.name, a.split), (&b.name, b.split));
        assert_eq!(
            (a.camera.fx, a.camera.fy, a.camera.cx, a.camera.cy),
            (b.camera.fx, b.camera.fy, b.camera.cx, b.camera.cy)
        );
        // transforms.json holds f32 rotations, orthonormal to ~1e-7: the quaternion makes them exact.
        assert!(a.camera.rotation().abs_diff_eq(b.camera.rotation(), 1e-6), "{}", a.name);
        let off = (a.camera.center() - b.camera.center()).length();
        assert!(
            off < 0.01 * extent,
            "{}: centre off by {off} (room extent {extent})",
            a.name
        );
        assert_eq!(a.rgb.data, b.rgb.data);
    }
    let n = (ds.normalization.scale / native.normalization.scale - 1.0).abs();
    assert!(
        n < 0.02,
        "normalization scale {} vs {}",
        ds.normalization.scale,
        native.normalization.scale
    );
}
