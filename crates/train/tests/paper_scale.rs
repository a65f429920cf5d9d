//! A scene the size of the paper's (640×480, 200 views) loads and trains. Ignored by default (it
//! writes ~1.5 GB of fixture files); run it under `/usr/bin/time -v` to read the peak memory:
//! `cargo test --release -p i2sdf-train --test paper_scale -- --ignored --nocapture`.

use i2sdf_data::fixture::{self, FixtureOptions};
use i2sdf_train::config::TrainConfig;
use i2sdf_train::driver::Trainer;
use i2sdf_train::maps::TrainingMaps;
use i2sdf_train::stage1::Stage1;
use std::time::Instant;

#[test]
#[ignore]
fn paper_sized_scene_loads_and_trains() {
    let dir = tempfile::tempdir().unwrap();
    let t = Instant::now();
    let opts = FixtureOptions {
        width: 640,
        height: 480,
        train_views: 180,
        test_views: 20,
        ..Default::default()
    };
    fixture::write_native(dir.path(), &opts);
    eprintln!("wrote 200 views of 640×480 in {:.1} s", t.elapsed().as_secs_f64());
    let t = Instant::now();
    let ds = i2sdf_data::load(dir.path()).unwrap();
    eprintln!("loaded in {:.1} s", t.elapsed().as_secs_f64());
    // Iterations chosen so the bubble step (and its PDF maps over all 55 M training pixels) runs.
    let config = TrainConfig::load(None, &["train.iterations=40".into()]).unwrap();
    let maps = TrainingMaps::prepare(&ds, &config).unwrap();
    let mut stage = Trainer::new(Stage1::new(&ds, config, &maps));
    let t = Instant::now();
    while !stage.done() {
        let s = stage.step().unwrap().stats;
        assert!(!s.skipped);
        if s.iteration % 10 == 0 {
            eprintln!(
                "{} {:?} loss {:.4} pdf {}",
                s.iteration,
                s.phase.unwrap(),
                s.loss,
                s.pdf_active
            );
        }
    }
    eprintln!(
        "40 iterations (incl. PDF-map initialisation) in {:.1} s",
        t.elapsed().as_secs_f64()
    );
}
