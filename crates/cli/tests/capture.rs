//! The phone-capture path end to end (issue 24): `synth --capture` (JPEG, lens, coarse noisy
//! depth with confidence, no normals, masks or HDR, perturbed poses), `check`, both stages with
//! the pose correction on (the default there), and `eval --data` the exact room, which scores the corrected poses.

mod common;
use common::{i2sdf, s, TINY, TINY_STAGE2};

const ROOM: [&str; 10] = [
    "--width", "48", "--height", "32", "--views", "12", "--spp", "2", "--seed", "3",
];

#[test]
fn a_phone_capture_trains_and_is_scored_against_the_exact_room() {
    let dir = tempfile::tempdir().unwrap();
    let (exact, capture, run, metrics) = (
        dir.path().join("exact"),
        dir.path().join("capture"),
        dir.path().join("run"),
        dir.path().join("metrics.json"),
    );
    let mut a = vec!["synth", "--out", s(&exact)];
    a.extend_from_slice(&ROOM);
    let o = i2sdf(&a);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let mut a = vec!["synth", "--out", s(&capture), "--capture"];
    a.extend_from_slice(&ROOM);
    let o = i2sdf(&a);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let tj: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(capture.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(
        (tj["poses_exact"].clone(), tj["depth_exact"].clone()),
        (false.into(), false.into())
    );
    assert_eq!(tj["camera_model"], "OPENCV");
    assert!(tj["frames"][0]["file_path"].as_str().unwrap().ends_with(".jpg"));

    let out = std::process::Command::new(env!("CARGO_BIN_EXE_i2sdf"))
        .args(["check", "--data", s(&capture)])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("emitter masks: absent → found from the images"), "{text}");
    assert!(text.contains("normals: absent → derived from depth"), "{text}");
    assert!(
        text.contains("depth a sensor's (not declared exact): train.iterations = 5000, schedule.bubble_eikonal = 1"),
        "{text}"
    );

    let mut a = vec!["train", "--quiet", "--data", s(&capture), "--out", s(&run)];
    a.extend_from_slice(&TINY);
    // The correction is on by default where poses are not declared exact; from the start here,
    // so that the tiny run corrects at all.
    a.extend_from_slice(&["--set", "pose.start=0"]);
    let o = i2sdf(&a);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(run.join("poses.json").is_file(), "the corrected poses are written");
    assert!(run.join("emitter_masks").is_dir(), "the found masks are written");
    // The run keeps the numbers "auto" became: the iterations TINY gave, the eikonal term's 1.
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(
        config.contains("bubble_eikonal = 1.0") && !config.contains("iterations = \"auto\""),
        "{config}"
    );
    let o = common::train_material(&capture, &run, &TINY_STAGE2);
    assert_eq!(o.code, 0, "{}", o.stderr);

    let o = i2sdf(&common::eval_args(
        &run,
        &exact,
        &metrics,
        &["--mesh-resolution", "32", "--spp", "1", "--bounces", "1"],
    ));
    assert_eq!(o.code, 0, "{}", o.stderr);
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&metrics).unwrap()).unwrap();
    assert!(m["novel_view"]["psnr"].as_f64().is_some());
    let poses = &m["poses"];
    assert_eq!(
        poses["views"].as_u64(),
        Some(tj["frames"].as_array().unwrap().len() as u64 - 2)
    );
    // The capture's default pose noise (1 cm, 0.5°) is what the given poses are off by.
    let given = &poses["given"];
    assert!(
        (given["translation_median"].as_f64().unwrap() - 0.01).abs() < 1e-4,
        "{poses}"
    );
    assert!(
        (given["rotation_deg_median"].as_f64().unwrap() - 0.5).abs() < 1e-3,
        "{poses}"
    );
}
