//! The configuration's tests: defaults, TOML round trips, and every bad value naming its key.

use super::*;

#[test]
fn defaults_round_trip_through_toml() {
    let c = TrainConfig::default();
    let back: TrainConfig = toml::from_str(&c.to_toml()).unwrap();
    assert_eq!(back, c);
}

#[test]
fn file_and_overrides() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.toml");
    std::fs::write(&p, "[train]\niterations = 77\n[model]\nbackbone = \"mlp\"\n").unwrap();
    let c = TrainConfig::load(
        Some(&p),
        &[
            "train.rays=256".into(),
            "adaptive.enabled=false".into(),
            "loss.bubble = 0.25".into(),
        ],
    )
    .unwrap();
    assert_eq!(c.train.iterations, Auto::Value(77));
    assert_eq!(c.train.rays, 256);
    assert_eq!(c.model.backbone, Backbone::Mlp);
    assert!(!c.adaptive.enabled);
    assert_eq!(c.loss.bubble, 0.25);
    assert_eq!(c.loss.depth, 0.1);
}

/// Values that used to panic deep in the engine (or were silently accepted) are refused with
/// the key named; one step inside the range is accepted.
#[test]
fn out_of_range_values_name_their_key() {
    for (set, key) in [
        ("model.hash_features=3", "model.hash_features"),
        ("model.hash_levels=0", "model.hash_levels"),
        ("model.sdf_hidden=0", "model.sdf_hidden"),
        ("sampling.epsilon=0", "sampling.epsilon"),
        ("sampling.epsilon=-1", "sampling.epsilon"),
        ("loss.rgb=nan", "loss.rgb"),
        ("loss.depth=-0.1", "loss.depth"),
        ("loss.bubble=inf", "loss.bubble"),
        ("train.rays=0", "train.rays"),
        ("train.lr_mlp=0", "train.lr_mlp"),
        ("train.lr_warmup=-1", "train.lr_warmup"),
        ("train.checkpoint_every=0", "train.checkpoint_every"),
        ("train.snapshot_seconds=[60, 30]", "train.snapshot_seconds"),
        ("train.snapshot_seconds=[0]", "train.snapshot_seconds"),
        ("sampling.samples=1", "sampling.samples"),
        ("sampling.upsample=0", "sampling.upsample"),
        ("sampling.occupancy_resolution=4", "sampling.occupancy_resolution"),
        ("sampling.occupancy_every=0", "sampling.occupancy_every"),
        ("sampling.occupancy_margin=-1", "sampling.occupancy_margin"),
        ("maps.photo_depth=1", "maps.photo_depth"),
        ("maps.photo_depth=-0.5", "maps.photo_depth"),
        ("stage2.emitter_min_views=0", "stage2.emitter_min_views"),
        ("stage2.emitter_mask_agreement=1.5", "stage2.emitter_mask_agreement"),
        ("schedule.smooth_bubble=2", "smooth_bubble"),
        ("schedule.bubble_eikonal=-0.5", "bubble_eikonal"),
        ("adaptive.p_min=nan", "adaptive.p_min"),
        ("schedule.warmup_fraction=nan", "warmup_fraction"),
        ("stage2.pixels=0", "stage2.pixels"),
        ("stage2.smooth=-1", "stage2.smooth"),
        ("stage2.rho_prior=-0.1", "stage2.rho_prior"),
        ("stage2.rho_prior_target=1.5", "stage2.rho_prior_target"),
        ("stage2.rho_prior_from=2", "stage2.rho_prior_from"),
        ("stage2.emitter_threshold=2", "stage2.emitter_threshold"),
        ("stage2.cache_samples=0", "stage2.cache_samples"),
    ] {
        let overrides = vec![set.to_string(), "train.iterations=5".to_string()];
        let e = TrainConfig::load(None, &overrides).expect_err(set).to_string();
        assert!(e.contains(key) && e.contains("--set"), "{set}: {e}");
    }
    for ok in [
        "model.hash_features=4",
        "sampling.epsilon=0.01",
        "loss.rgb=0",
        "train.lr_warmup=0",
    ] {
        let overrides = vec![ok.to_string(), "train.iterations=5".to_string()];
        assert!(TrainConfig::load(None, &overrides).is_ok(), "{ok}");
    }
    // Refreshed samples need kept samples: the bake holds none.
    let sets = ["stage2.refresh_pixels=5", "stage2.irradiance_radius=0"].map(String::from);
    let e = TrainConfig::load(None, &sets)
        .expect_err("refresh with the bake")
        .to_string();
    assert!(
        e.contains("stage2.refresh_pixels") && e.contains("stage2.specular_bake"),
        "{e}"
    );
    let mut kept = sets.to_vec();
    kept.push("stage2.specular_bake=false".into());
    assert!(TrainConfig::load(None, &kept).is_ok());
}

#[test]
fn typos_and_bad_values_are_errors() {
    let e = TrainConfig::load(None, &["train.iteratons=5".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("iteratons"), "{e}");
    let e = TrainConfig::load(None, &["schedule.warmup_fraction=0.9".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("warmup_fraction"), "{e}");
    assert!(TrainConfig::load(None, &["train.rays".into()]).is_err());
    assert!(TrainConfig::load(None, &["model.backbone=transformer".into()]).is_err());
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.toml");
    std::fs::write(&p, "[train]\nrays = 3\n[stage2]\n\npixels = \"many\"\n").unwrap();
    let e = TrainConfig::load(Some(&p), &[]).unwrap_err().to_string();
    let first = e.lines().next().unwrap();
    assert!(
        first.contains("bad.toml") && first.contains("stage2.pixels (line 5)"),
        "{e}"
    );
    std::fs::write(&p, "[train\n").unwrap();
    assert!(TrainConfig::load(Some(&p), &[])
        .unwrap_err()
        .to_string()
        .contains("bad.toml"));
}

/// `"auto"` resolves against the dataset: a sensor's depth takes 5000 iterations and the eikonal
/// term in the bubble step, and says so; exact depth keeps 2500 and the paper's 0 silently;
/// values given stay, and a bad word or number names its key.
#[test]
fn auto_settings_follow_the_depth() {
    use i2sdf_data::fixture::{self, FixtureOptions};
    let dir = tempfile::tempdir().unwrap();
    fixture::write_native(dir.path(), &FixtureOptions::default());
    let mut ds = i2sdf_data::load(dir.path()).unwrap();
    assert!(ds.depth_exact);
    let mut c = TrainConfig::default();
    assert_eq!(
        (c.train.iterations, c.schedule.bubble_eikonal),
        (Auto::AUTO, Auto::AUTO)
    );
    assert_eq!(c.resolve(&ds), None);
    assert_eq!((c.iterations(), c.schedule.bubble_eikonal), (2500, Auto::Value(0.0)));
    ds.depth_exact = false;
    let mut c = TrainConfig::default();
    let line = c.resolve(&ds).expect("a sensor's depth is said");
    assert!(
        line.contains("train.iterations = 5000") && line.contains("schedule.bubble_eikonal = 1"),
        "{line}"
    );
    assert_eq!((c.iterations(), c.schedule.bubble_eikonal), (5000, Auto::Value(1.0)));
    // A resolved configuration is written with its numbers and reads back equal.
    let text = c.to_toml();
    assert!(
        text.contains("\niterations = 5000") && text.contains("bubble_eikonal = 1.0"),
        "{text}"
    );
    assert_eq!(toml::from_str::<TrainConfig>(&text).unwrap(), c);
    let sets = ["train.iterations=300", "schedule.bubble_eikonal=\"auto\""].map(String::from);
    let mut c = TrainConfig::load(None, &sets).unwrap();
    let line = c.resolve(&ds).unwrap();
    assert!(
        !line.contains("train.iterations") && line.contains("bubble_eikonal = 1"),
        "{line}"
    );
    assert_eq!(c.iterations(), 300);
    for (set, key) in [
        ("train.iterations=often", "train.iterations"),
        ("train.iterations=0", "train.iterations"),
        ("schedule.bubble_eikonal=\"off\"", "schedule.bubble_eikonal"),
    ] {
        let e = TrainConfig::load(None, &[set.to_string()]).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains(key), "{set}: {e}");
    }
}
