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
    .map(String::from)
    .to_vec();
    TrainConfig::load(None, &sets).unwrap()
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
    let params = |s: &Stage1| -> Vec<Vec<f32>> { s.scene.modules().iter().map(|(_, m)| m.values().to_vec()).collect() };
    let want = params(&full.stage);
    // In warm-up, at the bubble step's first iteration (no maps yet), inside it, in the smooth step.
    for at in [5u64, 10, 11, 20, 29, 35] {
        let ckpt = runs.path().join(format!("at{at}.safetensors"));
        let mut part = Trainer::new(Stage1::new(&ds, config(), &maps));
        while part.stage.iteration < at {
            part.step().unwrap();
        }
        part.save(&ckpt).unwrap();
        let meta = checkpoint_metadata(&ckpt).unwrap();
        let fp: DatasetFingerprint = serde_json::from_str(&meta[DATASET_META]).unwrap();
        assert_eq!(fp, DatasetFingerprint::of(&ds));
        // The maps exist from the bubble step's second iteration on, and into the smooth step
        // where bubbles persist there (`schedule.smooth_bubble`).
        let persist = config().schedule.smooth_bubble > 0.0;
        let has_pdf = (11..=30).contains(&at) || (persist && at > 30);
        assert_eq!(meta.contains_key("pdf_maps"), has_pdf, "at {at}");
        assert!(meta.contains_key("rgb_error_maps"), "at {at}");
        drop(part);
        let mut b = Trainer::new(Stage1::resume(&ds, config(), &maps, &ckpt).unwrap());
        while !b.done() {
            b.step().unwrap();
        }
        assert!(params(&b.stage) == want, "resumed at {at}: the parameters differ");
    }
}
