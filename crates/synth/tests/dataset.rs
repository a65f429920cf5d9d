//! A generated dataset is accepted by the project's loader (what `i2sdf check` runs), has the
//! promised splits, annotations and relit views, and its noisy depth follows the paper's model.

mod common;

use glam::Vec3;
use i2sdf_data::Split;
use i2sdf_synth::tracer::Estimator;
use i2sdf_synth::{generate, DepthNoise, RoomPreset, SynthOptions};

#[test]
fn generated_scene_loads_with_every_annotation() {
    let tmp = tempfile::tempdir().unwrap();
    let opts = SynthOptions {
        width: 40,
        height: 30,
        views: 12,
        spp: 2,
        seed: 1,
        max_depth: 3,
        depth_noise: DepthNoise::Sigma,
        preset: Some("bedroom".into()),
        ..Default::default()
    };
    generate(RoomPreset::Bedroom.build(1), &opts, tmp.path(), &|| {}).unwrap();
    let ds = i2sdf_data::load(tmp.path()).expect("the loader accepts a generated scene");
    assert_eq!((ds.count(Split::Train), ds.count(Split::Test)), (10, 2));
    assert!(ds.mesh_path.as_ref().is_some_and(|p| p.is_file()));
    for f in &ds.frames {
        assert!(f.hdr.is_some() && f.depth.is_some() && f.normal.is_some() && f.emitter_mask.is_some());
        assert!(f.albedo.is_some() && f.specular.is_some() && f.roughness.is_some());
        let n = f.normal.as_ref().unwrap();
        for px in n.data.chunks(3) {
            assert!((Vec3::from_slice(px).length() - 1.0).abs() < 1e-4);
        }
    }
    // Four relit conditions (the room has two emitters), each covering every test view.
    let names: Vec<String> = ds
        .relight
        .iter()
        .map(|r| r.spec.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        ["brighter_warmer", "light_off", "small_light_alone", "small_light_cool"]
    );
    for set in &ds.relight {
        assert_eq!(set.frames.len(), 2);
    }
    // Relighting is linear in the emitters: "light off" + 2×warm first light differ from the
    // original on the test views.
    let test: Vec<_> = ds.split(Split::Test).collect();
    let orig = test[0].hdr.as_ref().unwrap();
    let off = ds.relight[1].frames[0].hdr.as_ref().unwrap();
    let sum = |img: &i2sdf_data::ImageF32| img.data.iter().map(|v| *v as f64).sum::<f64>();
    assert!(sum(off) < sum(orig), "turning a light off darkens the view");
    // the small light alone (the large one off) lights the room less than both did; the cool
    // small light makes the view bluer
    let alone = ds.relight[2].frames[0].hdr.as_ref().unwrap();
    assert!(sum(alone) < sum(orig));
    let cool = ds.relight[3].frames[0].hdr.as_ref().unwrap();
    let blue_over_red = |img: &i2sdf_data::ImageF32| {
        let (r, b) = img
            .data
            .chunks(3)
            .fold((0.0f64, 0.0f64), |(r, b), p| (r + p[0] as f64, b + p[2] as f64));
        b / r
    };
    assert!(blue_over_red(cool) > blue_over_red(orig));

    // Depth noise: written depth = clean depth + N(μ(z), σ(z)).
    let w = common::read_written(tmp.path());
    let (mut sum_r, mut n) = (0.0f64, 0usize);
    for (k, f) in w.json["frames"].as_array().unwrap().iter().enumerate() {
        let gt =
            i2sdf_data::imageio::read_float_map(&tmp.path().join(f["depth_gt_file_path"].as_str().unwrap())).unwrap();
        for (noisy, clean) in w.views[k].depth.iter().zip(&gt.data) {
            let (mu, sigma) = DepthNoise::Sigma.params(*clean);
            sum_r += ((noisy - clean - mu) / sigma) as f64;
            n += 1;
        }
    }
    let mean_r = sum_r / n as f64;
    assert!(
        mean_r.abs() < 4.0 / (n as f64).sqrt(),
        "standardized noise mean {mean_r}"
    );
    assert_eq!(w.json["depth"]["noise"], "sigma");
}

#[test]
fn bad_options_are_rejected_as_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let opts = SynthOptions {
        spp: 0,
        ..Default::default()
    };
    let err = generate(RoomPreset::Bedroom.build(0), &opts, tmp.path(), &|| {}).unwrap_err();
    assert!(err.to_string().contains("spp"));
}

#[test]
fn transforms_json_records_the_estimator() {
    let tmp = tempfile::tempdir().unwrap();
    let default = common::render_tiny(tmp.path(), RoomPreset::Livingroom, 0, 2);
    let est = &default.json["generator"]["estimator"];
    assert_eq!(est["unbiased"], false, "{est}");
    let rho = est["regularization"]["min_roughness_after_diffuse"].as_f64().unwrap();
    assert_eq!(Some(rho as f32), Estimator::DATASET.regularize_roughness);

    let tmp = tempfile::tempdir().unwrap();
    let opts = SynthOptions {
        width: 32,
        height: 24,
        views: 2,
        spp: 1,
        max_depth: 2,
        estimator: Estimator::UNBIASED,
        ..Default::default()
    };
    generate(RoomPreset::Livingroom.build(0), &opts, tmp.path(), &|| {}).unwrap();
    let json = common::read_written(tmp.path()).json;
    let est = &json["generator"]["estimator"];
    assert_eq!(est["unbiased"], true, "{est}");
    assert!(est["regularization"].is_null(), "{est}");
}
