//! A phone capture of a room (`crate::capture`): each option changes what it should in the written
//! dataset and nothing else, against the exact room of the same seed, read back from the files.

mod common;

use glam::{DMat3, DMat4, DVec3};
use i2sdf_data::imageio::{read_float_map, read_image, read_png_raw_gray};
use i2sdf_data::Split;
use i2sdf_synth::capture::{PoseNoise, PHONE_OPENCV};
use i2sdf_synth::{generate, CaptureOptions, DepthNoise, RoomPreset, SynthOptions};
use serde_json::Value;
use std::path::Path;

const SEED: u64 = 1;

/// A tiny room: 48×36 (a depth grid of 3 puts its samples' centres on pixel centres), 7 train +
/// 1 test views.
fn render(dir: &Path, capture: CaptureOptions, depth_noise: DepthNoise) -> Value {
    let opts = SynthOptions {
        width: 48,
        height: 36,
        views: 8,
        spp: 2,
        seed: SEED,
        max_depth: 3,
        depth_noise,
        preset: Some("livingroom".into()),
        capture,
        ..Default::default()
    };
    generate(RoomPreset::Livingroom.build(SEED), &opts, dir, &|| {}).expect("renders");
    json(&dir.join("transforms.json"))
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn exact(dir: &Path) -> Value {
    render(dir, CaptureOptions::default(), DepthNoise::None)
}

fn frames(t: &Value) -> &Vec<Value> {
    t["frames"].as_array().unwrap()
}

fn bytes(dir: &Path, frame: &Value, key: &str) -> Vec<u8> {
    std::fs::read(dir.join(frame[key].as_str().unwrap())).unwrap()
}

/// The OpenGL camera-to-world of a written row-major matrix.
fn matrix(v: &Value) -> DMat4 {
    let rows: Vec<Vec<f64>> = serde_json::from_value(v.clone()).unwrap();
    DMat4::from_cols_array_2d(&[0, 1, 2, 3].map(|c| [0, 1, 2, 3].map(|r| rows[r][c])))
}

#[test]
fn the_exact_room_declares_exact_poses_and_depth_and_no_capture() {
    let tmp = tempfile::tempdir().unwrap();
    let t = exact(tmp.path());
    assert_eq!(
        (t["poses_exact"].clone(), t["depth_exact"].clone()),
        (Value::Bool(true), Value::Bool(true))
    );
    assert!(t["generator"].get("capture").is_none());
    assert!(t.get("camera_model").is_none() && t["ldr"]["exposure"].is_f64());
}

#[test]
fn jpeg_frames_decode_near_the_png_ones_and_change_nothing_else() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let (ta, tb) = (
        exact(a.path()),
        render(
            b.path(),
            CaptureOptions {
                jpeg_quality: Some(90),
                ..Default::default()
            },
            DepthNoise::None,
        ),
    );
    for (fa, fb) in frames(&ta).iter().zip(frames(&tb)) {
        assert!(fb["file_path"].as_str().unwrap().ends_with(".jpg"));
        let (png, jpg) = (
            read_image(&a.path().join(fa["file_path"].as_str().unwrap())).unwrap(),
            read_image(&b.path().join(fb["file_path"].as_str().unwrap())).unwrap(),
        );
        assert_eq!((jpg.width, jpg.height, jpg.channels), (48, 36, 3));
        let mean = png.data.iter().zip(&jpg.data).map(|(x, y)| (x - y).abs()).sum::<f32>() / png.data.len() as f32;
        assert!(mean < 0.03 && mean > 0.0, "mean |JPEG − PNG| {mean}");
        for key in [
            "hdr_file_path",
            "depth_file_path",
            "normal_file_path",
            "albedo_file_path",
        ] {
            assert_eq!(bytes(a.path(), fa, key), bytes(b.path(), fb, key), "{key}");
        }
        let mut fb = fb.clone();
        fb["file_path"] = fa["file_path"].clone();
        assert_eq!(fa, &fb);
    }
    assert_eq!(tb["generator"]["capture"]["jpeg_quality"], 90);
}

#[test]
fn the_lens_is_declared_and_the_images_are_rendered_through_it() {
    let tmp = tempfile::tempdir().unwrap();
    let lens_only = CaptureOptions {
        lens: PHONE_OPENCV,
        ..Default::default()
    };
    let t = render(tmp.path(), lens_only, DepthNoise::None);
    assert_eq!(t["camera_model"], "OPENCV");
    for (k, v) in PHONE_OPENCV.params() {
        assert_eq!(t[k].as_f64(), Some(v), "{k}");
    }
    // The loader reads the lens back; every pixel's written depth, back-projected through it,
    // lands on the GT mesh (a known 3D point projects where the image shows it), while
    // back-projected through a pinhole the image's corners miss the mesh by centimetres.
    let ds = i2sdf_data::load(tmp.path()).expect("a lens-only capture loads");
    assert_eq!(ds.frames[0].camera.lens, PHONE_OPENCV);
    let (verts, faces) = common::read_ply(&tmp.path().join("mesh.ply"));
    let dist = |p: DVec3| {
        faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| verts[i as usize].as_dvec3());
                common::point_triangle_distance(p, a, b, c)
            })
            .fold(f64::INFINITY, f64::min)
    };
    let (mut with_lens, mut without) = (0.0f64, 0.0f64);
    for f in ds.frames.iter().take(3) {
        let depth = f.depth.as_ref().unwrap();
        for (i, j) in [(0, 0), (47, 0), (0, 35), (47, 35), (1, 1), (46, 34)] {
            let z = depth.pixel(i, j)[0] as f64;
            with_lens = with_lens.max(dist(f.camera.backproject(i, j, z)));
            without = without.max(dist(f.camera.pinhole().backproject(i, j, z)));
        }
    }
    assert!(
        with_lens < 2e-3,
        "through the declared lens: {with_lens} m off the mesh"
    );
    assert!(without > 2e-2, "through a pinhole: only {without} m off the mesh");
}

#[test]
fn the_depth_grid_holds_the_true_depth_at_its_samples_in_millimetres() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let ta = exact(a.path());
    let grid = CaptureOptions {
        depth_grid: Some(3),
        ..Default::default()
    };
    for noise in [DepthNoise::None, DepthNoise::Sigma] {
        let tb = render(b.path(), grid.clone(), noise);
        assert_eq!(tb["depth_unit_scale_factor"], 0.001);
        assert_eq!(tb["depth"]["grid"], serde_json::json!([16, 12]));
        let (mut sum_r, mut n) = (0.0f64, 0usize);
        for (fa, fb) in frames(&ta).iter().zip(frames(&tb)) {
            let path = b.path().join(fb["depth_file_path"].as_str().unwrap());
            assert!(path.extension().unwrap() == "png");
            let mm = read_png_raw_gray(&path).unwrap();
            assert_eq!((mm.width, mm.height), (16, 12));
            // 16 bits: the normalized reading times 65535 gives the raw values back.
            let unit = read_image(&path).unwrap();
            assert!(mm
                .data
                .iter()
                .zip(&unit.data)
                .all(|(r, u)| (u * 65535.0 - r).abs() < 0.01));
            // Sample (i, j)'s centre is the centre of pixel (3i+1, 3j+1) of the image.
            let fine = read_float_map(&a.path().join(fa["depth_file_path"].as_str().unwrap())).unwrap();
            for j in 0..12 {
                for i in 0..16 {
                    let z = fine.pixel(3 * i + 1, 3 * j + 1)[0];
                    let got = mm.pixel(i, j)[0] / 1000.0;
                    let (mu, sigma) = noise.params(z);
                    if noise == DepthNoise::None {
                        assert!((got - z).abs() <= 0.0005 + 1e-5, "({i}, {j}): {got} vs {z}");
                    } else {
                        sum_r += ((got - z - mu) / sigma) as f64;
                        n += 1;
                        assert!((got - z - mu).abs() < 6.0 * sigma, "({i}, {j}): {got} vs {z}");
                    }
                }
            }
            // The clean full-resolution depth stays for scoring.
            let gt = read_float_map(&b.path().join(fb["depth_gt_file_path"].as_str().unwrap())).unwrap();
            assert_eq!(gt, fine);
        }
        if n > 0 {
            let mean = sum_r / n as f64;
            assert!(mean.abs() < 4.0 / (n as f64).sqrt(), "standardized noise mean {mean}");
        }
    }
}

#[test]
fn confidence_levels_are_arkits_and_low_samples_carry_large_errors() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let ta = exact(a.path());
    let tb = render(
        b.path(),
        CaptureOptions {
            depth_grid: Some(3),
            confidence: true,
            ..Default::default()
        },
        DepthNoise::None,
    );
    let mut count = [0usize; 3];
    let mut err = [0.0f64; 3];
    for (fa, fb) in frames(&ta).iter().zip(frames(&tb)) {
        let conf = read_image(&b.path().join(fb["confidence_file_path"].as_str().unwrap())).unwrap();
        assert_eq!((conf.width, conf.height, conf.channels), (16, 12, 1));
        let mm = read_png_raw_gray(&b.path().join(fb["depth_file_path"].as_str().unwrap())).unwrap();
        let fine = read_float_map(&a.path().join(fa["depth_file_path"].as_str().unwrap())).unwrap();
        for j in 0..12 {
            for i in 0..16 {
                let level = conf.pixel(i, j)[0] * 255.0;
                assert!(level == level.round() && level <= 2.0, "confidence {level}");
                let c = level as usize;
                count[c] += 1;
                err[c] += (mm.pixel(i, j)[0] / 1000.0 - fine.pixel(3 * i + 1, 3 * j + 1)[0]).abs() as f64;
            }
        }
    }
    assert!(count.iter().all(|&c| c > 0), "every level occurs: {count:?}");
    assert!(count[2] > count[0], "most samples are good: {count:?}");
    let mean = [0, 1, 2].map(|c| err[c] / count[c] as f64);
    assert!(
        mean[1] < 1e-3 && mean[2] < 1e-3,
        "medium and high are exact here: {mean:?}"
    );
    assert!(mean[0] > 0.03, "low samples are corrupted: {mean:?}");
}

#[test]
fn pose_noise_perturbs_the_training_poses_only_and_keeps_the_true_ones() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let ta = exact(a.path());
    let noise = PoseNoise { cm: 2.0, deg: 1.0 };
    let tb = render(
        b.path(),
        CaptureOptions {
            pose_noise: Some(noise),
            ..Default::default()
        },
        DepthNoise::None,
    );
    assert_eq!(tb["poses_exact"], false);
    // No depth noise: the depth is still exact.
    assert_eq!(tb["depth_exact"], true);
    let truth = json(&b.path().join(tb["poses_true_path"].as_str().unwrap()));
    for (fa, fb) in frames(&ta).iter().zip(frames(&tb)) {
        // Rendered at the true pose: the same image.
        assert_eq!(bytes(a.path(), fa, "file_path"), bytes(b.path(), fb, "file_path"));
        let name = fb["file_path"].as_str().unwrap();
        assert_eq!(truth["transform_matrix"][name], fa["transform_matrix"], "{name}");
        let (exact, written) = (matrix(&fa["transform_matrix"]), matrix(&fb["transform_matrix"]));
        if fb["split"] == "test" {
            assert_eq!(fa["transform_matrix"], fb["transform_matrix"]);
            continue;
        }
        let moved = (written.w_axis - exact.w_axis).truncate().length();
        let rel = DMat3::from_mat4(written) * DMat3::from_mat4(exact).transpose();
        let angle = ((rel.x_axis.x + rel.y_axis.y + rel.z_axis.z - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos();
        assert!((moved - 0.02).abs() < 1e-5, "{name}: moved {moved} m");
        assert!(
            (angle.to_degrees() - 1.0).abs() < 0.01,
            "{name}: turned {}°",
            angle.to_degrees()
        );
    }
    assert_eq!(tb["generator"]["capture"]["pose_noise"]["deg"], 1.0);
}

#[test]
fn no_normals_masks_or_hdr_leave_out_only_those() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let ta = exact(a.path());
    let tb = render(
        b.path(),
        CaptureOptions {
            normals: false,
            masks: false,
            hdr: false,
            ..Default::default()
        },
        DepthNoise::None,
    );
    for dir in ["normal", "mask", "hdr"] {
        assert!(a.path().join(dir).is_dir() && !b.path().join(dir).exists(), "{dir}");
    }
    assert!(tb["ldr"].get("exposure").is_none() && tb["ldr"]["transfer"] == "srgb");
    for (fa, fb) in frames(&ta).iter().zip(frames(&tb)) {
        let mut fa = fa.clone();
        for key in ["normal_file_path", "emitter_mask_path", "hdr_file_path"] {
            fa.as_object_mut().unwrap().remove(key);
        }
        assert_eq!(&fa, fb);
        for key in [
            "file_path",
            "depth_file_path",
            "albedo_file_path",
            "roughness_file_path",
        ] {
            assert_eq!(bytes(a.path(), &fa, key), bytes(b.path(), fb, key), "{key}");
        }
    }
    // What scoring needs stays: the mesh, the emitters, the relit sets.
    for key in ["emitters", "relight", "objects", "mesh_path"] {
        assert_eq!(ta[key], tb[key], "{key}");
    }
    let ds = i2sdf_data::load(b.path()).expect("loads without normals, masks and HDR");
    assert!(ds
        .frames
        .iter()
        .all(|f| f.normal.is_none() && f.emitter_mask.is_none() && f.hdr.is_none()));
    assert_eq!(ds.count(Split::Test), 1);
}

#[test]
fn a_phone_capture_keeps_the_exact_rooms_scene_and_test_views() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let ta = exact(a.path());
    let mut phone = CaptureOptions::phone();
    phone.depth_grid = Some(3);
    let tb = render(b.path(), phone, DepthNoise::Sigma);
    for f in ["mesh.ply", "scene.toml"] {
        assert_eq!(
            std::fs::read(a.path().join(f)).unwrap(),
            std::fs::read(b.path().join(f)).unwrap(),
            "{f}"
        );
    }
    for (fa, fb) in frames(&ta).iter().zip(frames(&tb)) {
        assert_eq!(fa["split"], fb["split"]);
        if fa["split"] == "test" {
            assert_eq!(fa["transform_matrix"], fb["transform_matrix"]);
        }
        for key in ["confidence_file_path", "depth_file_path", "file_path"] {
            assert!(b.path().join(fb[key].as_str().unwrap()).is_file(), "{key}");
        }
    }
    let cap = &tb["generator"]["capture"];
    assert_eq!(cap["jpeg_quality"], 90);
    assert_eq!(cap["lens"], "OPENCV");
    assert_eq!(cap["depth_noise"], "sigma");
    assert_eq!(
        (cap["normals"].clone(), cap["hdr"].clone()),
        (Value::Bool(false), Value::Bool(false))
    );
    assert_eq!(
        (tb["poses_exact"].clone(), tb["depth_exact"].clone()),
        (Value::Bool(false), Value::Bool(false))
    );
    assert_eq!(tb["generator"]["seed"], ta["generator"]["seed"]);
}
