//! `synth --format paper`: a synthetic room written as the paper's release format loads back as
//! the same dataset as the native one of the same seed (splits, cameras, every map, radiometry),
//! passes `check --data`, and leaves no native copy behind; bad flags exit 2 naming them.

mod common;

use common::{expect, i2sdf, s};
use i2sdf_data::{Format, Frame, ImageF32, Split};
use std::path::Path;

const TINY_ROOM: [&str; 8] = ["--width", "24", "--height", "18", "--views", "6", "--spp", "2"];

fn synth(out: &Path, extra: &[&str]) -> common::Outcome {
    let mut args = vec!["synth", "--out", s(out)];
    args.extend(TINY_ROOM);
    args.extend(extra);
    i2sdf(&args)
}

/// The largest absolute difference of two maps of the same shape.
#[track_caller]
fn max_diff(a: &ImageF32, b: &ImageF32, what: &str) -> f32 {
    assert_eq!(
        (a.width, a.height, a.channels),
        (b.width, b.height, b.channels),
        "{what}: shapes differ"
    );
    a.data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[track_caller]
fn close(a: Option<&ImageF32>, b: Option<&ImageF32>, tol: f32, what: &str) {
    match (a, b) {
        (Some(a), Some(b)) => {
            let d = max_diff(a, b, what);
            assert!(d <= tol, "{what}: differs by {d} (tolerance {tol})");
        }
        (None, None) => {}
        _ => panic!("{what}: present in one dataset only"),
    }
}

fn compare_frames(native: &Frame, paper: &Frame) {
    let (a, b) = (&native.camera, &paper.camera);
    let what = &native.name;
    assert_eq!((a.width, a.height), (b.width, b.height), "{what}");
    for (x, y, n) in [
        (a.fx, b.fx, "fx"),
        (a.fy, b.fy, "fy"),
        (a.cx, b.cx, "cx"),
        (a.cy, b.cy, "cy"),
    ] {
        assert!((x - y).abs() <= 1e-6, "{what}: {n} {x} vs {y}");
    }
    let (p, q) = (a.c2w.to_cols_array(), b.c2w.to_cols_array());
    let d = p.iter().zip(&q).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    assert!(d <= 1e-6, "{what}: poses differ by {d}");
    close(Some(&native.rgb), Some(&paper.rgb), 1.0 / 255.0 + 1e-6, "rgb");
    // EXR float32 throughout: the depth is copied, the normals rotated to camera space and back.
    close(native.depth.as_ref(), paper.depth.as_ref(), 1e-6, "depth");
    close(native.normal.as_ref(), paper.normal.as_ref(), 1e-5, "normal");
    close(native.hdr.as_ref(), paper.hdr.as_ref(), 0.0, "hdr");
    close(
        native.emitter_mask.as_ref(),
        paper.emitter_mask.as_ref(),
        0.0,
        "emitter mask",
    );
    close(native.albedo.as_ref(), paper.albedo.as_ref(), 0.0, "albedo");
    close(native.specular.as_ref(), paper.specular.as_ref(), 0.0, "specular");
    close(native.roughness.as_ref(), paper.roughness.as_ref(), 0.0, "roughness");
    // The synthetic room declares no material mask (every material is GGX): the paper's has ones.
    assert!(native.material_mask.is_none());
    let mask = paper.material_mask.as_ref().expect("the paper format's material mask");
    assert!(
        mask.data.iter().all(|v| *v == 1.0),
        "{what}: a material mask not all ones"
    );
}

#[test]
fn a_synth_room_written_in_the_paper_format_loads_as_the_native_one() {
    let dir = tempfile::tempdir().unwrap();
    let (native_dir, paper_dir) = (dir.path().join("native"), dir.path().join("paper"));
    expect(synth(&native_dir, &[]), 0, &[]);
    expect(synth(&paper_dir, &["--format", "paper"]), 0, &["relit"]);

    let native = i2sdf_data::load(&native_dir).unwrap();
    let paper = i2sdf_data::load(&paper_dir).unwrap();
    assert_eq!(paper.format, Format::Paper);
    for split in [Split::Train, Split::Test] {
        assert_eq!(paper.count(split), native.count(split), "{split:?} views");
        for (a, b) in native.split(split).zip(paper.split(split)) {
            compare_frames(a, b);
        }
    }
    assert_eq!(paper.radiometry, native.radiometry);
    assert!(native.radiometry.exposure.is_some());

    // mesh.ply is a point cloud sampled on the GT mesh: every point on it.
    let cloud = i2sdf_data::ply::read_ply(paper_dir.join("mesh.ply")).unwrap();
    let mesh = i2sdf_data::ply::read_ply(native_dir.join("mesh.ply")).unwrap();
    assert!(
        cloud.faces.is_empty() && cloud.positions.len() > 1000,
        "{}",
        cloud.positions.len()
    );
    let (lo, hi) = mesh
        .positions
        .iter()
        .fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
            (
                std::array::from_fn(|c| lo[c].min(p[c])),
                std::array::from_fn(|c| hi[c].max(p[c])),
            )
        });
    assert!(cloud
        .positions
        .iter()
        .all(|p| (0..3).all(|c| p[c] >= lo[c] - 1e-4 && p[c] <= hi[c] + 1e-4)));

    // Nothing of the native format is left behind.
    for gone in [".native", "transforms.json", "images", "relight", "normals"] {
        assert!(!paper_dir.join(gone).exists(), "{gone} left in the paper-format output");
    }
    expect(i2sdf(&["check", "--data", s(&paper_dir)]), 0, &[]);
    // --force recognizes a paper-format room of its own and replaces it.
    expect(
        synth(&paper_dir, &["--format", "paper", "--force", "--seed", "1"]),
        0,
        &[],
    );
}

#[test]
fn bad_formats_exit_2_naming_the_flag_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("room");
    expect(synth(&out, &["--format", "xyz"]), 2, &["--format", "xyz"]);
    expect(
        synth(&out, &["--format", "paper", "--lens", "opencv"]),
        2,
        &["--format paper", "pinhole", "--lens none"],
    );
    expect(
        synth(&out, &["--format", "paper", "--pose-noise", "1,0.5"]),
        2,
        &["--format paper", "--pose-noise"],
    );
    assert!(!out.exists(), "a refused synth wrote {}", out.display());
}
