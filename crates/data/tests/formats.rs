//! Both formats load from fixtures the tests write themselves, with the conventions right: a depth
//! pixel back-projected from two views of a known geometry lands on the same world point.

use glam::DVec3;
use i2sdf_data::fixture::{self, DepthFormat, FixtureOptions};
use i2sdf_data::{load, Dataset, Format, Split};

const ANCHOR: DVec3 = DVec3::new(2.5, 0.3, 0.9); // a point on the +x wall

fn anchored(depth: DepthFormat) -> FixtureOptions {
    FixtureOptions {
        depth,
        anchor: Some(ANCHOR),
        ..Default::default()
    }
}

/// In every view with depth, the anchor projects onto a pixel centre; back-projecting that pixel's
/// depth must give the anchor back (relative to the viewing distance), and the normal there must be
/// the wall's.
fn assert_views_agree_on_anchor(ds: &Dataset, rel_tol: f64) -> usize {
    let mut checked = 0;
    for f in ds.frames.iter().filter(|f| f.depth.is_some()) {
        let (u, v, _) = f.camera.project(ANCHOR).unwrap();
        assert!(
            (u.fract() - 0.5).abs() < 1e-6 && (v.fract() - 0.5).abs() < 1e-6,
            "{}: anchor at ({u}, {v})",
            f.name
        );
        let (i, j) = (u.floor() as usize, v.floor() as usize);
        let d = f.depth.as_ref().unwrap().pixel(i, j)[0] as f64;
        let p = f.camera.backproject(i, j, d);
        let dist = (ANCHOR - f.camera.center()).length();
        let err = (p - ANCHOR).length() / dist;
        assert!(
            err < rel_tol,
            "{}: back-projected {p:?}, expected {ANCHOR:?} (relative error {err:.2e})",
            f.name
        );
        if let Some(n) = &f.normal {
            let n = n.pixel(i, j);
            assert!(
                (n[0] + 1.0).abs() < 1e-5 && n[1].abs() < 1e-5 && n[2].abs() < 1e-5,
                "{}: normal {n:?}",
                f.name
            );
        }
        checked += 1;
    }
    checked
}

#[test]
fn native_format_loads_with_correct_conventions() {
    for depth in [DepthFormat::Exr, DepthFormat::Npy] {
        let dir = tempfile::tempdir().unwrap();
        let truth = fixture::write_native(dir.path(), &anchored(depth));
        let ds = load(dir.path()).unwrap();
        assert_eq!(ds.format, Format::Native);
        assert_eq!((ds.count(Split::Train), ds.count(Split::Test)), (4, 2));
        for (f, c) in ds.frames.iter().zip(&truth) {
            assert!(f.camera.c2w.abs_diff_eq(c.c2w, 1e-9));
            assert!((f.camera.cx - c.cx).abs() < 1e-9);
            assert_eq!(f.rgb.channels, 3);
            assert!(f.emitter_mask.is_some() && f.normal.is_some());
        }
        assert_eq!(assert_views_agree_on_anchor(&ds, 1e-4), 6);
    }
}

#[test]
fn native_png16_depth_is_scaled_by_the_unit_factor() {
    let dir = tempfile::tempdir().unwrap();
    fixture::write_native(dir.path(), &anchored(DepthFormat::Png16));
    let ds = load(dir.path()).unwrap();
    // Millimetre quantization: half a millimetre over a few metres.
    assert_views_agree_on_anchor(&ds, 5e-4);
}

#[test]
fn paper_format_loads_with_its_integer_pixel_and_camera_space_conventions() {
    let dir = tempfile::tempdir().unwrap();
    let truth = fixture::write_paper(dir.path(), &anchored(DepthFormat::Exr));
    let ds = load(dir.path()).unwrap();
    assert_eq!(ds.format, Format::Paper);
    assert_eq!(
        ds.radiometry,
        i2sdf_data::Radiometry::default(),
        "sRGB, no exposure declared"
    );
    assert_eq!((ds.count(Split::Train), ds.count(Split::Test)), (4, 2));
    for (f, c) in ds.frames.iter().zip(&truth) {
        assert!(
            f.camera.c2w.abs_diff_eq(c.c2w, 1e-6),
            "{}: {:?} vs {:?}",
            f.name,
            f.camera.c2w,
            c.c2w
        );
        assert!((f.camera.cx - c.cx).abs() < 1e-6 && (f.camera.fy - c.fy).abs() < 1e-6);
    }
    assert_eq!(assert_views_agree_on_anchor(&ds, 1e-4), 4);
    let f = &ds.frames[0];
    assert!(f.emitter_mask.is_some() && f.normal.is_some() && f.depth.is_some());
    // The release keeps no mesh by default; a `mesh.ply` beside the cameras is the GT mesh.
    assert_eq!(ds.mesh_path, None);
    std::fs::write(dir.path().join("mesh.ply"), b"ply\n").unwrap();
    assert_eq!(load(dir.path()).unwrap().mesh_path, Some(dir.path().join("mesh.ply")));
}

#[test]
fn normalization_puts_the_scene_in_the_unit_sphere() {
    let dir = tempfile::tempdir().unwrap();
    fixture::write_native(dir.path(), &FixtureOptions::default());
    let ds = load(dir.path()).unwrap();
    let n = ds.normalization;
    for f in &ds.frames {
        let d = f.depth.as_ref().unwrap();
        for j in 0..f.camera.height {
            for i in 0..f.camera.width {
                let p = f.camera.backproject(i, j, d.pixel(i, j)[0] as f64);
                let q = n.to_normalized(p);
                assert!(q.length() < 1.0, "{q:?}");
                assert!((n.to_world(q) - p).length() < 1e-9);
                assert!((n.world_to_normalized().transform_point3(p) - q).length() < 1e-9);
            }
        }
    }
    // The measured bounds are the room (the fixture sees every wall).
    for a in 0..3 {
        assert!(ds.bounds.min[a] >= fixture::ROOM_MIN[a] - 1e-3);
        assert!(ds.bounds.max[a] <= fixture::ROOM_MAX[a] + 1e-3);
    }
}

/// A capture's JPEG frames (nerfstudio's `ns-process-data` writes `images/frame_00001.jpg`) load
/// like the PNGs they were encoded from, within JPEG's error.
#[test]
fn native_jpeg_frames_load() {
    let dir = tempfile::tempdir().unwrap();
    fixture::write_native(dir.path(), &FixtureOptions::default());
    let png = load(dir.path()).unwrap();
    let json = dir.path().join("transforms.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for f in t["frames"].as_array_mut().unwrap() {
        let rel = f["file_path"].as_str().unwrap().to_string();
        let jpg = rel.replace(".png", ".jpg");
        let img = image::open(dir.path().join(&rel)).unwrap().to_rgb8();
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 95)
            .encode_image(&img)
            .unwrap();
        std::fs::write(dir.path().join(&jpg), bytes).unwrap();
        std::fs::remove_file(dir.path().join(&rel)).unwrap();
        f["file_path"] = serde_json::Value::String(jpg);
    }
    std::fs::write(&json, serde_json::to_string(&t).unwrap()).unwrap();
    let jpeg = load(dir.path()).unwrap();
    for (a, b) in png.frames.iter().zip(&jpeg.frames) {
        assert_eq!(
            (a.rgb.width, a.rgb.height, a.rgb.channels),
            (b.rgb.width, b.rgb.height, b.rgb.channels)
        );
        let mae = a
            .rgb
            .data
            .iter()
            .zip(&b.rgb.data)
            .map(|(x, y)| (x - y).abs())
            .sum::<f32>()
            / a.rgb.data.len() as f32;
        assert!(mae < 0.03, "{}: JPEG mean error {mae}", b.name);
    }
}

/// `transforms.json`'s `ldr: {transfer, exposure}` is parsed into the dataset's radiometry when it
/// is loaded; a bad value is refused there, naming the file and the key (exit code 2).
#[test]
fn native_ldr_radiometry_is_parsed_at_load() {
    use i2sdf_data::{DataError, Radiometry, Transfer};
    let dir = tempfile::tempdir().unwrap();
    fixture::write_native(dir.path(), &FixtureOptions::default());
    let json_path = dir.path().join("transforms.json");
    let original: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    let with = |ldr: Option<serde_json::Value>| {
        let mut v = original.clone();
        if let Some(ldr) = ldr {
            v["ldr"] = ldr;
        }
        std::fs::write(&json_path, serde_json::to_string(&v).unwrap()).unwrap();
        load(dir.path())
    };
    assert_eq!(with(None).unwrap().radiometry, Radiometry::default());
    let ds = with(Some(serde_json::json!({"transfer": "linear", "exposure": 2.5}))).unwrap();
    assert_eq!(
        ds.radiometry,
        Radiometry {
            transfer: Transfer::Linear,
            exposure: Some(2.5)
        }
    );
    for (ldr, key) in [
        (serde_json::json!({"transfer": "gamma"}), "ldr.transfer"),
        (serde_json::json!({"transfer": 2.2}), "ldr.transfer"),
        (serde_json::json!({"exposure": -1.0}), "ldr.exposure"),
        (serde_json::json!("linear"), "ldr"),
    ] {
        let e = with(Some(ldr.clone())).unwrap_err();
        assert!(e.is_bad_input(), "{ldr}: {e}");
        match e {
            DataError::Field { path, field, .. } => assert_eq!((path, field.as_str()), (json_path.clone(), key)),
            e => panic!("{ldr}: {e}"),
        }
    }
}
