//! Depth as sensors write it: millimetre PNGs, depth maps coarser or finer than their images,
//! confidence maps, and the holes and outliers that are dropped and counted instead of refusing
//! the dataset (`i2sdf_data::sensor_depth`). The depth maps are rendered here from the fixture's
//! analytic room at the sensor's own resolution.

use i2sdf_data::fixture::{self, DepthFormat, FixtureOptions};
use i2sdf_data::imageio::{self, ImageF32};
use i2sdf_data::sensor_depth::{self, depth_window};
use i2sdf_data::{load, Camera, DataError, Dataset, DepthDropped};
use serde_json::Value;
use std::path::Path;

/// The room's z-depth seen by `cam` at its own resolution resized to `w`×`h` (a sensor registered
/// to the image: same pose and field of view, another grid).
fn sensor_depth(cam: &Camera, w: usize, h: usize) -> ImageF32 {
    let sensor = cam.resized(w, h);
    let mut img = ImageF32::new(w, h, 1);
    for v in 0..h {
        for u in 0..w {
            let (o, d, cos) = sensor.ray(u as f64 + 0.5, v as f64 + 0.5);
            img.pixel_mut(u, v)[0] = (fixture::room_hit(o, d).0 * cos) as f32;
        }
    }
    img
}

fn edit_json(dir: &Path, f: impl FnOnce(&mut Value)) {
    let p = dir.join("transforms.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&p, serde_json::to_string(&v).unwrap()).unwrap();
}

fn native(opts: &FixtureOptions) -> (tempfile::TempDir, Vec<Camera>) {
    let dir = tempfile::tempdir().unwrap();
    let cams = fixture::write_native(dir.path(), opts);
    (dir, cams)
}

fn depth_path(dir: &Path, k: usize) -> std::path::PathBuf {
    dir.join("depth").join(format!("frame_{k:03}.exr"))
}

fn write_gray8(path: &Path, img: &ImageF32) {
    let raw: Vec<u8> = img.data.iter().map(|v| *v as u8).collect();
    image::GrayImage::from_raw(img.width as u32, img.height as u32, raw)
        .unwrap()
        .save(path)
        .unwrap();
}

/// Asserts a bad-input error naming `file` and containing every needle.
fn assert_refused(result: Result<Dataset, DataError>, file: &str, needles: &[&str]) {
    let e = result.unwrap_err();
    let msg = e.to_string();
    assert!(e.is_bad_input(), "not bad input (exit 2): {msg}");
    assert!(msg.contains(file), "the message does not name {file}: {msg}");
    for n in needles {
        assert!(msg.contains(n), "expected '{n}' in: {msg}");
    }
}

#[test]
fn png16_millimetre_depth_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let cam = &fixture::cameras(&FixtureOptions::default())[0];
    let mm: Vec<u16> = (0..cam.width * cam.height).map(|k| 500 + 7 * k as u16).collect();
    let p = dir.path().join("d.png");
    imageio::write_png16_raw(&p, cam.width, cam.height, 1, &mm).unwrap();
    let (depth, dropped, _) = sensor_depth::load_depth(&p, cam, 0.001, None).unwrap();
    for (d, m) in depth.data.iter().zip(&mm) {
        assert_eq!(*d, (*m as f64 * 0.001) as f32);
    }
    assert_eq!(
        (dropped.samples_total, dropped.kept),
        (mm.len() as u64, mm.len() as u64)
    );
    // An 8-bit PNG holds its integers too (not rescaled to 16 bits).
    let p8 = dir.path().join("d8.png");
    write_gray8(
        &p8,
        &ImageF32::from_data(cam.width, cam.height, 1, vec![200.0; cam.width * cam.height]),
    );
    let (depth, _, _) = sensor_depth::load_depth(&p8, cam, 0.01, None).unwrap();
    assert!(depth.data.iter().all(|d| *d == 2.0), "{:?}", &depth.data[..3]);

    // Through a dataset, with another unit: 0.1 mm.
    let (dir, cams) = native(&FixtureOptions {
        depth: DepthFormat::Png16,
        ..Default::default()
    });
    for (k, cam) in cams.iter().enumerate() {
        let d = sensor_depth(cam, cam.width, cam.height);
        let raw: Vec<u16> = d.data.iter().map(|v| (v * 10_000.0).round() as u16).collect();
        let p = dir.path().join("depth").join(format!("frame_{k:03}.png"));
        imageio::write_png16_raw(&p, cam.width, cam.height, 1, &raw).unwrap();
    }
    edit_json(dir.path(), |v| v["depth_unit_scale_factor"] = Value::from(1e-4));
    let ds = load(dir.path()).unwrap();
    for (f, cam) in ds.frames.iter().zip(&cams) {
        let truth = sensor_depth(cam, cam.width, cam.height);
        for (a, b) in f.depth.as_ref().unwrap().data.iter().zip(&truth.data) {
            assert!((a - b).abs() <= 0.5e-4 + 1e-6, "{a} vs {b}");
        }
    }
}

#[test]
fn a_4x_coarser_depth_map_is_mapped_onto_its_image() {
    let opts = FixtureOptions {
        width: 32,
        height: 24,
        ..Default::default()
    };
    let (dir, cams) = native(&opts);
    let (ws, hs) = (8, 6);
    for (k, cam) in cams.iter().enumerate() {
        imageio::write_exr(&depth_path(dir.path(), k), &sensor_depth(cam, ws, hs)).unwrap();
    }
    let ds = load(dir.path()).unwrap();
    let (mut carried, mut kept_as_is, mut on_one_wall) = (0, 0, 0);
    for (f, cam) in ds.frames.iter().zip(&cams) {
        let depth = f.depth.as_ref().unwrap();
        assert_eq!((depth.width, depth.height), (32, 24), "kept at the image's size");
        let sensor = sensor_depth(cam, ws, hs);
        let sensor_cam = cam.resized(ws, hs);
        // The room's depth at each image pixel's own centre: where a sample is carried there.
        let exact = sensor_depth(cam, 32, 24);
        for j in 0..24 {
            for i in 0..32 {
                let d = depth.pixel(i, j)[0];
                // Sample (u, v)'s centre, ((u+½)·4, (v+½)·4), lies in pixel (4u+2, 4v+2).
                if i % 4 != 2 || j % 4 != 2 {
                    assert_eq!(d, 0.0, "{}: pixel ({i}, {j}) has no sample", f.name);
                    continue;
                }
                let (u, v) = (i / 4, j / 4);
                let sample = sensor.pixel(u, v)[0];
                if d == sample {
                    // Not carried (no neighbour continues its surface): back-projected through
                    // the image pixel, it still lands within half a sensor pixel's footprint of
                    // the surface point the sensor measured.
                    kept_as_is += 1;
                    let p = f.camera.backproject(i, j, d as f64);
                    let truth = sensor_cam.backproject(u, v, d as f64);
                    let half_footprint = d as f64 * 0.5 / sensor_cam.fx;
                    assert!(
                        (p - truth).length() < half_footprint,
                        "{}: pixel ({i}, {j}) is {:.4} from the surface point (footprint {half_footprint:.4})",
                        f.name,
                        (p - truth).length()
                    );
                } else {
                    // Carried half a sensor pixel along the room's planes: where the sample, its
                    // neighbours and the pixel's centre all lie on one wall, to the depth the
                    // pixel's own ray meets (inverse depth is affine on a plane: exact).
                    // Elsewhere a crease may pass between the sample's centre and the pixel's
                    // (no sample can tell): off by the change of slope over that half pixel.
                    carried += 1;
                    let e = exact.pixel(i, j)[0];
                    let wall = |x: f64, y: f64| {
                        let (o, dir, _) = cam.ray(x, y);
                        fixture::room_hit(o, dir).1
                    };
                    let here = wall(i as f64 + 0.5, j as f64 + 0.5);
                    // The samples the slopes are taken from: two on each side along each axis.
                    let cross = [
                        (0, 0),
                        (-2, 0),
                        (-1, 0),
                        (1, 0),
                        (2, 0),
                        (0, -2),
                        (0, -1),
                        (0, 1),
                        (0, 2),
                    ];
                    let one_wall = cross.iter().all(|&(du, dv): &(isize, isize)| {
                        let (uu, vv) = (u as isize + du, v as isize + dv);
                        let inside = uu >= 0 && vv >= 0 && uu < ws as isize && vv < hs as isize;
                        !inside || wall((uu as f64 + 0.5) * 4.0, (vv as f64 + 0.5) * 4.0) == here
                    });
                    if one_wall {
                        on_one_wall += 1;
                        assert!(
                            (d - e).abs() <= 1e-4 * e,
                            "{}: pixel ({i}, {j}) carried to {d}, the wall there is at {e} (sample {sample})",
                            f.name
                        );
                    } else {
                        assert!(
                            (d - e).abs() <= 0.05 * e,
                            "{}: pixel ({i}, {j}) carried to {d}, the surface there is at {e} (sample {sample})",
                            f.name
                        );
                    }
                }
            }
        }
    }
    // Most samples lie inside a wall, away from the room's edges, and are carried.
    assert!(carried > 20 * kept_as_is, "carried {carried}, kept as is {kept_as_is}");
    assert!(
        on_one_wall * 2 > carried,
        "{on_one_wall} of {carried} carried samples inside one wall"
    );
    let n = (ws * hs * cams.len()) as u64;
    assert_eq!(
        ds.depth_dropped,
        DepthDropped {
            samples_total: n,
            kept: n,
            ..Default::default()
        }
    );
}

#[test]
fn a_3x_finer_depth_map_keeps_the_sample_at_each_pixel_centre() {
    let (dir, cams) = native(&FixtureOptions::default());
    let (ws, hs) = (72, 54);
    for (k, cam) in cams.iter().enumerate() {
        imageio::write_exr(&depth_path(dir.path(), k), &sensor_depth(cam, ws, hs)).unwrap();
    }
    let ds = load(dir.path()).unwrap();
    for (f, cam) in ds.frames.iter().zip(&cams) {
        let depth = f.depth.as_ref().unwrap();
        let sensor = sensor_depth(cam, ws, hs);
        for j in 0..cam.height {
            for i in 0..cam.width {
                // Sample (3i+1, 3j+1)'s centre is pixel (i, j)'s centre: neither a neighbour nor a
                // mean of the nine.
                assert_eq!(depth.pixel(i, j)[0], sensor.pixel(3 * i + 1, 3 * j + 1)[0]);
            }
        }
    }
    let d = ds.depth_dropped;
    assert_eq!(d.samples_total, (ws * hs * cams.len()) as u64);
    assert_eq!(d.kept * 9, d.samples_total);
    assert_eq!(d.superseded, d.samples_total - d.kept);
}

/// Confidence (u + v) mod 3 per sample, as an 8-bit PNG for even frames and a `.npy` for odd ones.
fn with_confidence(dir: &Path, n: usize, w: usize, h: usize) -> u64 {
    let mut zeros = 0;
    let conf = ImageF32::from_data(w, h, 1, (0..w * h).map(|k| ((k % w + k / w) % 3) as f32).collect());
    zeros += conf.data.iter().filter(|c| **c == 0.0).count() as u64 * n as u64;
    for k in 0..n {
        let name = if k % 2 == 0 {
            let name = format!("confidence/frame_{k:03}.png");
            std::fs::create_dir_all(dir.join("confidence")).unwrap();
            write_gray8(&dir.join(&name), &conf);
            name
        } else {
            let name = format!("confidence/frame_{k:03}.npy");
            imageio::write_npy(&dir.join(&name), &conf).unwrap();
            name
        };
        edit_json(dir, |v| v["frames"][k]["confidence_file_path"] = Value::from(name));
    }
    zeros
}

#[test]
fn low_confidence_samples_are_dropped_before_the_mapping() {
    let opts = FixtureOptions::default();
    let (dir, cams) = native(&opts);
    let n = cams.len();
    let (w, h) = (opts.width, opts.height);
    let zeros = with_confidence(dir.path(), n, w, h);
    let ds = load(dir.path()).unwrap();
    assert_eq!(
        ds.depth_dropped.low_confidence, zeros,
        "the default minimum is 1 (medium)"
    );
    assert_eq!(ds.depth_dropped.kept, (n * w * h) as u64 - zeros);
    let truth = load(&{
        let (clean, _) = native(&opts);
        clean.keep()
    })
    .unwrap();
    for (f, t) in ds.frames.iter().zip(&truth.frames) {
        let (d, t) = (f.depth.as_ref().unwrap(), t.depth.as_ref().unwrap());
        for j in 0..h {
            for i in 0..w {
                let expected = if (i + j) % 3 == 0 { 0.0 } else { t.pixel(i, j)[0] };
                assert_eq!(d.pixel(i, j)[0], expected, "{}: ({i}, {j})", f.name);
            }
        }
    }
    edit_json(dir.path(), |v| v["depth_confidence_min"] = Value::from(2));
    let high = load(dir.path()).unwrap();
    assert_eq!(
        high.depth_dropped.low_confidence,
        2 * zeros,
        "a third of the samples each"
    );
    edit_json(dir.path(), |v| v["depth_confidence_min"] = Value::from(0));
    assert_eq!(load(dir.path()).unwrap().depth_dropped.low_confidence, 0);

    // A coarser depth map's confidence is at the depth map's resolution.
    let (dir, cams) = native(&FixtureOptions {
        width: 32,
        height: 24,
        ..Default::default()
    });
    for (k, cam) in cams.iter().enumerate() {
        imageio::write_exr(&depth_path(dir.path(), k), &sensor_depth(cam, 8, 6)).unwrap();
    }
    let zeros = with_confidence(dir.path(), cams.len(), 8, 6);
    let ds = load(dir.path()).unwrap();
    assert_eq!(ds.depth_dropped.low_confidence, zeros);
    let depth = ds.frames[0].depth.as_ref().unwrap();
    assert_eq!(depth.pixel(2, 2)[0], 0.0, "sample (0, 0) had confidence 0");
    assert!(depth.pixel(6, 2)[0] > 0.0, "sample (1, 0) had confidence 1");
    // The dropped samples' footprints, 4×4 pixels each, are kept for the photometric depth.
    let low = ds.frames[0]
        .depth_low
        .as_ref()
        .expect("a confidence map gives the footprints");
    for j in 0..24 {
        for i in 0..32 {
            let (u, v) = (i / 4, j / 4);
            let expected = ((u + v) % 3 == 0) as u8 as f32;
            assert_eq!(low.pixel(i, j)[0], expected, "pixel ({i}, {j}) in sample ({u}, {v})");
        }
    }
    assert!(truth.frames[0].depth_low.is_none(), "no confidence map, no footprints");
}

#[test]
fn bad_confidence_input_names_the_file_or_key() {
    let (dir, cams) = native(&FixtureOptions::default());
    with_confidence(dir.path(), cams.len(), 24, 18);
    for bad in [Value::from(3), Value::from(1.5), Value::from("high"), Value::from(-1)] {
        edit_json(dir.path(), |v| v["depth_confidence_min"] = bad.clone());
        assert_refused(load(dir.path()), "transforms.json", &["depth_confidence_min"]);
    }
    edit_json(dir.path(), |v| {
        v.as_object_mut().unwrap().remove("depth_confidence_min");
    });
    load(dir.path()).unwrap();
    // A confidence map not at its depth map's size.
    write_gray8(&dir.path().join("confidence/frame_002.png"), &ImageF32::new(12, 9, 1));
    assert_refused(load(dir.path()), "frame_002.png", &["12×9", "24×18"]);
    let (dir, _) = native(&FixtureOptions::default());
    edit_json(dir.path(), |v| {
        v["frames"][1].as_object_mut().unwrap().remove("depth_file_path");
        v["frames"][1]["confidence_file_path"] = Value::from("c.png");
    });
    assert_refused(load(dir.path()), "transforms.json", &["frames[1].confidence_file_path"]);
}

#[test]
fn a_depth_map_of_the_wrong_aspect_is_refused() {
    let (dir, _) = native(&FixtureOptions::default());
    imageio::write_exr(&depth_path(dir.path(), 3), &ImageF32::new(24, 12, 1)).unwrap();
    assert_refused(load(dir.path()), "frame_003.exr", &["wrong aspect", "24×12", "24×18"]);
    // Within 1 %: 4:3 against 24×18 is exact, 97×73 is 0.3 % off.
    imageio::write_exr(&depth_path(dir.path(), 3), &ImageF32::new(97, 73, 1)).unwrap();
    load(dir.path()).unwrap();
}

#[test]
fn non_finite_depth_is_dropped_and_counted_not_refused() {
    let (dir, cams) = native(&FixtureOptions::default());
    let p = depth_path(dir.path(), 0);
    let mut d = imageio::read_float_map(&p).unwrap();
    d.pixel_mut(3, 4)[0] = f32::NAN;
    d.pixel_mut(5, 4)[0] = f32::INFINITY;
    d.pixel_mut(6, 4)[0] = -1.0;
    d.pixel_mut(7, 4)[0] = 0.0;
    imageio::write_exr(&p, &d).unwrap();
    let ds = load(dir.path()).unwrap();
    let depth = ds.frames[0].depth.as_ref().unwrap();
    for i in [3, 5, 6, 7] {
        assert_eq!(depth.pixel(i, 4)[0], 0.0);
    }
    assert!(depth.pixel(4, 4)[0] > 0.0);
    let n = (24 * 18 * cams.len()) as u64;
    assert_eq!(
        ds.depth_dropped,
        DepthDropped {
            samples_total: n,
            kept: n - 4,
            non_finite: 2,
            non_positive: 2,
            ..Default::default()
        }
    );
    assert!(ds.bounds.max.iter().chain(&ds.bounds.min).all(|v| v.is_finite()));
}

#[test]
fn the_validity_window_drops_outliers_in_both_formats() {
    let (dir, _) = native(&FixtureOptions::default());
    let clean = load(dir.path()).unwrap();
    let p = depth_path(dir.path(), 1);
    let mut d = imageio::read_float_map(&p).unwrap();
    d.pixel_mut(10, 10)[0] = 1000.0; // a reflection 1000 m away
    d.pixel_mut(11, 10)[0] = 1e-5; // noise at the lens
    imageio::write_exr(&p, &d).unwrap();
    let ds = load(dir.path()).unwrap();
    let depth = ds.frames[1].depth.as_ref().unwrap();
    assert_eq!((depth.pixel(10, 10)[0], depth.pixel(11, 10)[0]), (0.0, 0.0));
    assert_eq!(ds.depth_dropped.out_of_window, 2);
    assert_eq!(ds.depth_dropped.kept, clean.depth_dropped.kept - 2);
    // The outlier does not move the normalization (the bounds ignore the 0.1 % extremes), so
    // the window is the clean scene's: a few metres.
    let scale = ds.normalization.scale;
    assert!((scale / clean.normalization.scale - 1.0).abs() < 0.01, "{scale}");
    let (lo, hi) = depth_window(&ds.normalization);
    assert!(lo < 0.01 && (10.0..30.0).contains(&hi), "{lo} … {hi}");

    let dir = tempfile::tempdir().unwrap();
    fixture::write_paper(dir.path(), &FixtureOptions::default());
    let p = dir.path().join("depth/0002.exr");
    let mut d = imageio::read_float_map(&p).unwrap();
    d.pixel_mut(4, 4).copy_from_slice(&[1000.0; 3]);
    d.pixel_mut(5, 4).copy_from_slice(&[f32::NAN; 3]);
    imageio::write_exr(&p, &d).unwrap();
    let ds = load(dir.path()).unwrap();
    let depth = ds.frames[2].depth.as_ref().unwrap();
    assert_eq!((depth.pixel(4, 4)[0], depth.pixel(5, 4)[0]), (0.0, 0.0));
    assert_eq!((ds.depth_dropped.out_of_window, ds.depth_dropped.non_finite), (1, 1));
}
