//! The paper's release format read in full: a scene without `val/` holds out every 8th view, the
//! validation views carry the annotations the release has for them, material masks are read into
//! the frames, `radiometry.json` declares what the release does not; every new file that is wrong
//! is refused naming it (and its field), as bad input.

use i2sdf_data::fixture::{self, FixtureOptions, PaperOptions};
use i2sdf_data::imageio::{self, ImageF32};
use i2sdf_data::{load, DataError, Radiometry, Split, Transfer};
use std::path::Path;

/// Every optional file of the format.
fn full() -> PaperOptions {
    PaperOptions {
        val_maps: true,
        material_masks: true,
        materials: true,
        hdr_exposure: Some(2.0),
        point_cloud: true,
        ..Default::default()
    }
}

/// Loading `dir` fails as bad input with a message holding every needle.
#[track_caller]
fn assert_refused(dir: &Path, needles: &[&str]) {
    let e = load(dir).unwrap_err();
    assert!(e.is_bad_input(), "{e}");
    let msg = e.to_string();
    for n in needles {
        assert!(msg.contains(n), "expected '{n}' in: {msg}");
    }
}

#[test]
fn without_val_every_8th_view_is_held_out_with_its_annotations() {
    let dir = tempfile::tempdir().unwrap();
    let opts = FixtureOptions {
        train_views: 10,
        test_views: 0,
        ..Default::default()
    };
    let extra = PaperOptions {
        no_val: true,
        material_masks: true,
        ..Default::default()
    };
    let truth = fixture::write_paper_with(dir.path(), &opts, &extra);
    assert!(!dir.path().join("val").exists());
    let ds = load(dir.path()).unwrap();
    assert_eq!((ds.count(Split::Train), ds.count(Split::Test)), (8, 2));
    let test: Vec<&str> = ds.split(Split::Test).map(|f| f.name.as_str()).collect();
    assert_eq!(test, ["0000", "0008"]);
    for (f, c) in ds.frames.iter().zip(&truth) {
        assert!(f.camera.c2w.abs_diff_eq(c.c2w, 1e-6), "{}", f.name);
        // Held out or not, each view has its annotations.
        assert!(f.depth.is_some() && f.normal.is_some() && f.emitter_mask.is_some() && f.material_mask.is_some());
    }
    // A single image and no val/ leaves nothing to train on.
    let one = tempfile::tempdir().unwrap();
    let opts = FixtureOptions {
        train_views: 1,
        test_views: 0,
        ..Default::default()
    };
    fixture::write_paper_with(one.path(), &opts, &extra);
    assert_refused(one.path(), &["image", "val/", "nothing to train on"]);
}

#[test]
fn val_views_carry_their_annotations_and_masks_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let truth = fixture::write_paper_with(dir.path(), &FixtureOptions::default(), &full());
    let ds = load(dir.path()).unwrap();
    assert_eq!((ds.count(Split::Train), ds.count(Split::Test)), (4, 2));
    for f in &ds.frames {
        let what = [
            f.hdr.is_some(),
            f.depth.is_some(),
            f.normal.is_some(),
            f.emitter_mask.is_some(),
            f.material_mask.is_some(),
            f.albedo.is_some(),
            f.specular.is_some(),
            f.roughness.is_some(),
        ];
        assert_eq!(what, [true; 8], "{}", f.name);
    }
    // The val views' depth and normals are theirs: the room's wall at each val camera's rays.
    for (f, cam) in ds.split(Split::Test).zip(&truth[4..]) {
        let (i, j) = (cam.width / 2, cam.height / 2);
        let (o, d, _) = cam.ray(i as f64 + 0.5, j as f64 + 0.5);
        let (t, n) = fixture::room_hit(o, d);
        let p = f
            .camera
            .backproject(i, j, f.depth.as_ref().unwrap().pixel(i, j)[0] as f64);
        assert!(
            (p - (o + d * t)).length() < 1e-3 * t,
            "{}: {p} vs {}",
            f.name,
            o + d * t
        );
        let got = f.normal.as_ref().unwrap().pixel(i, j);
        assert!((glam::DVec3::new(got[0] as f64, got[1] as f64, got[2] as f64) - n).length() < 1e-3);
    }
    // The material masks mark the +x wall non-GGX (0) and the rest GGX (1): both are seen.
    let values: Vec<f32> = ds
        .frames
        .iter()
        .flat_map(|f| f.material_mask.as_ref().unwrap().data.clone())
        .collect();
    assert!(values.contains(&0.0) && values.contains(&1.0));
    assert!(values.iter().all(|v| *v == 0.0 || *v == 1.0));
}

#[test]
fn radiometry_json_declares_transfer_and_exposure() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("radiometry.json");
    fixture::write_paper(dir.path(), &FixtureOptions::default());
    assert_eq!(load(dir.path()).unwrap().radiometry, Radiometry::default());
    std::fs::write(&path, r#"{"ldr": {"transfer": "linear", "exposure": 0.5}}"#).unwrap();
    assert_eq!(
        load(dir.path()).unwrap().radiometry,
        Radiometry {
            transfer: Transfer::Linear,
            exposure: Some(0.5)
        }
    );
    for (text, field) in [
        (r#"{"ldr": {"transfer": "gamma"}}"#, Some("ldr.transfer")),
        (r#"{"ldr": {"exposure": 0}}"#, Some("ldr.exposure")),
        (r#"{"ldr": "linear"}"#, Some("ldr")),
        (r#"{"transfer": "linear"}"#, Some("ldr")),
        (r#"{"ldr": {"transfer": "linear""#, None),
        ("[1, 2]", None),
    ] {
        std::fs::write(&path, text).unwrap();
        let e = load(dir.path()).unwrap_err();
        assert!(e.is_bad_input(), "{text}: {e}");
        match (&e, field) {
            (DataError::Field { path: p, field: f, .. }, Some(want)) => assert_eq!((p, f.as_str()), (&path, want)),
            (DataError::File { path: p, .. }, None) => assert_eq!(p, &path),
            _ => panic!("{text}: {e:?}"),
        }
    }
    // An empty declaration is the default one.
    std::fs::write(&path, r#"{"ldr": {}}"#).unwrap();
    assert_eq!(load(dir.path()).unwrap().radiometry, Radiometry::default());
}

#[test]
fn new_files_that_are_wrong_are_refused_naming_them() {
    let fresh = || {
        let dir = tempfile::tempdir().unwrap();
        fixture::write_paper_with(dir.path(), &FixtureOptions::default(), &full());
        dir
    };
    let small = |channels| ImageF32::new(10, 7, channels);
    // A material mask of the wrong size.
    let dir = fresh();
    imageio::write_png(&dir.path().join("mask/0001.png"), &small(1)).unwrap();
    assert_refused(dir.path(), &["mask/0001.png", "10×7", "24×18"]);
    // A material mask missing: the directory no longer matches the images.
    let dir = fresh();
    std::fs::remove_file(dir.path().join("mask/0002.png")).unwrap();
    assert_refused(dir.path(), &["mask", "3 files but image/ has 4"]);
    // Val maps of the wrong size, or not one per val image.
    let dir = fresh();
    imageio::write_exr(&dir.path().join("val/depth/0001.exr"), &small(3)).unwrap();
    assert_refused(dir.path(), &["val/depth/0001.exr", "10×7"]);
    let dir = fresh();
    imageio::write_exr(&dir.path().join("val/material/0000_rough.exr"), &small(1)).unwrap();
    assert_refused(dir.path(), &["val/material/0000_rough.exr", "10×7"]);
    let dir = fresh();
    imageio::write_png(&dir.path().join("val/mask/0000.png"), &small(1)).unwrap();
    assert_refused(dir.path(), &["val/mask/0000.png", "10×7"]);
    let dir = fresh();
    std::fs::remove_file(dir.path().join("val/normal/0000.exr")).unwrap();
    assert_refused(dir.path(), &["val/normal", "1 files but val/ has 2"]);
    // Val annotations without val images are not silently dropped.
    let dir = fresh();
    for f in ["0000.png", "0001.png"] {
        std::fs::remove_file(dir.path().join("val").join(f)).unwrap();
    }
    assert_refused(dir.path(), &["val/depth", "2 files but val/ has 0"]);
}
