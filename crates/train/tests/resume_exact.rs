//! Stage 1 resumed from a checkpoint at any step of its schedule — inside the bubble step too,
//! where the error-guided PDF maps carry state from batch to batch, and with the colour error maps
//! that draw a quarter of the rays — continues bit for bit as the uninterrupted run; a checkpoint
//! names the data it was trained on.

#[allow(dead_code)]
mod common;

use i2sdf_train::config::TrainConfig;
use i2sdf_train::driver::Trainer;
use i2sdf_train::maps::TrainingMaps;
use i2sdf_train::resume::{checkpoint_metadata, DatasetFingerprint, DATASET_META};
use i2sdf_train::stage1::Stage1;

fn config() -> TrainConfig {
    config_with(&[])
}

fn config_with(extra: &[&str]) -> TrainConfig {
    // 40 iterations: warm-up 0–10, bubble 10–30, smooth 30–40.
    let sets: Vec<String> = [
        "train.iterations=40",
        "train.rays=128",
        "train.eikonal_points=128",
        "train.bubble_points=128",
        // the three steps of the paper's schedule, so that each is resumed into
        "schedule.warmup_fraction=0.25",
        "schedule.bubble_fraction=0.5",
        "model.hash_levels=4",
        "model.hash_log2_table=12",
        "sampling.samples=16",
        "sampling.coarse=16",
        "adaptive.rgb_rays=0.25",
    ]
    .iter()
    .chain(extra)
    .map(|s| s.to_string())
    .collect();
    TrainConfig::load(None, &sets).unwrap()
}

/// Every module's parameters.
fn params(s: &Stage1) -> Vec<Vec<f32>> {
    s.scene.modules().iter().map(|(_, m)| m.values().to_vec()).collect()
}

/// A fresh stage 1 trained to iteration `at` and checkpointed to `path`: the checkpoint's metadata.
fn checkpoint_at(
    ds: &i2sdf_data::Dataset,
    config: TrainConfig,
    maps: &TrainingMaps,
    at: u64,
    path: &std::path::Path,
) -> std::collections::HashMap<String, String> {
    let mut part = Trainer::new(Stage1::new(ds, config, maps));
    while part.stage.iteration < at {
        part.step().unwrap();
    }
    part.save(path).unwrap();
    checkpoint_metadata(path).unwrap()
}

/// Stage 1 resumed from `path` and trained to its end: its parameters.
fn finish_resumed(
    ds: &i2sdf_data::Dataset,
    config: TrainConfig,
    maps: &TrainingMaps,
    path: &std::path::Path,
) -> Vec<Vec<f32>> {
    let mut b = Trainer::new(Stage1::resume(ds, config, maps, path).unwrap());
    while !b.done() {
        b.step().unwrap();
    }
    params(&b.stage)
}

#[test]
fn stage1_resumes_bit_for_bit_at_every_step_of_the_schedule() {
    let (_dir, ds) = common::dataset();
    let maps = TrainingMaps::prepare(&ds, &TrainConfig::default()).unwrap();
    let runs = tempfile::tempdir().unwrap();
    let mut full = Trainer::new(Stage1::new(&ds, config(), &maps));
    while !full.done() {
        full.step().unwrap();
    }
    let want = params(&full.stage);
    // In warm-up, at the bubble step's first iteration (no maps yet), inside it, in the smooth step.
    for at in [5u64, 10, 11, 20, 29, 35] {
        let ckpt = runs.path().join(format!("at{at}.safetensors"));
        let meta = checkpoint_at(&ds, config(), &maps, at, &ckpt);
        let fp: DatasetFingerprint = serde_json::from_str(&meta[DATASET_META]).unwrap();
        assert_eq!(fp, DatasetFingerprint::of(&ds));
        // The maps exist from the bubble step's second iteration on, and into the smooth step
        // where bubbles persist there (`schedule.smooth_bubble`).
        let persist = config().schedule.smooth_bubble > 0.0;
        let has_pdf = (11..=30).contains(&at) || (persist && at > 30);
        assert_eq!(meta.contains_key("pdf_maps"), has_pdf, "at {at}");
        assert!(meta.contains_key("rgb_error_maps"), "at {at}");
        assert!(
            finish_resumed(&ds, config(), &maps, &ckpt) == want,
            "resumed at {at}: the parameters differ"
        );
    }
}

/// The sweep for depth from the images (`maps.photo_depth`) on sensor depth with holes: the
/// depths it found are in every later checkpoint, and a run resumed after it continues bit for
/// bit (with them, and with the PDF maps made over them).
#[test]
fn stage1_resumes_bit_for_bit_after_the_sweep_for_depth() {
    let (_dir, mut ds) = common::dataset();
    // A coarse sensor, declared a sensor's: depth on every fourth pixel of every fourth row, and
    // not where the sample's 4×4 footprint straddles a depth edge (a flying pixel).
    ds.depth_exact = false;
    for f in &mut ds.frames {
        let (w, h) = (f.camera.width, f.camera.height);
        if let Some(d) = &mut f.depth {
            let full = d.data.clone();
            for (p, z) in d.data.iter_mut().enumerate() {
                let (x, y) = (p % w, p / w);
                let footprint = (y.saturating_sub(2)..(y + 2).min(h))
                    .flat_map(|yy| (x.saturating_sub(2)..(x + 2).min(w)).map(move |xx| yy * w + xx))
                    .map(|q| full[q]);
                let (lo, hi) = footprint.fold((f32::INFINITY, 0.0f32), |(lo, hi), v| (lo.min(v), hi.max(v)));
                if x % 4 != 2 || y % 4 != 2 || hi > 1.05 * lo {
                    *z = 0.0;
                }
            }
        }
    }
    let cfg = || config_with(&["maps.photo_depth=0.5"]);
    let maps = TrainingMaps::prepare(&ds, &cfg()).unwrap();
    let mut full = Trainer::new(Stage1::new(&ds, cfg(), &maps));
    let mut swept = Vec::new();
    while !full.done() {
        let it = full.stage.iteration;
        if let Some(n) = full.step().unwrap().stats.photo_depth {
            swept.push((it, n));
        }
    }
    // Once, at half of the run. (The fixture's box room has no foreground for it to find, so the
    // depths it keeps are none: what it finds is `i2sdf_data::photo_depth`'s test; here the
    // schedule, the checkpoint's tensor and the PDF maps made again at the sweep.)
    assert!(matches!(swept[..], [(20, _)]), "{swept:?}");
    let want = params(&full.stage);
    let runs = tempfile::tempdir().unwrap();
    for at in [15u64, 20, 21, 25] {
        let ckpt = runs.path().join(format!("at{at}.safetensors"));
        let meta = checkpoint_at(&ds, cfg(), &maps, at, &ckpt);
        assert_eq!(meta.contains_key("photo_depth"), at > 20, "at {at}");
        assert!(
            finish_resumed(&ds, cfg(), &maps, &ckpt) == want,
            "resumed at {at}: the parameters differ"
        );
    }
}
