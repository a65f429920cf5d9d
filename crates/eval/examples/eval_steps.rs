//! Where `eval`'s time goes on a run: [`evaluate_with_progress`] with a progress that prints each
//! step as it starts, with its count, and the seconds each took. The test views are rendered with
//! the default render settings (`eval` uses the run's `[sampling]`, read by the train crate).
//! With a stage 2 that found no emitters, prints the note `eval` then adds to its JSON.
//!
//! `cargo run --release -p i2sdf-eval --example eval_steps -- RUN DATA [MESH_RESOLUTION]`

use i2sdf_eval::neural::{evaluate_with_progress, EvalOptions, MESH_RESOLUTION};
use i2sdf_eval::EvalProgress;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// Prints each step's name and count as it starts, and the previous step's time and work done.
struct Printer {
    current: Mutex<Option<(String, u64, Instant)>>,
    done: AtomicU64,
}

impl Printer {
    fn finish(&self) {
        if let Some((name, total, start)) = self.current.lock().unwrap().take() {
            let done = self.done.swap(0, Ordering::Relaxed);
            let count = if total > 0 {
                format!(", {done} of {total}")
            } else {
                String::new()
            };
            println!("  {name}: {:.2} s{count}", start.elapsed().as_secs_f64());
        }
    }
}

impl EvalProgress for Printer {
    fn step(&self, name: &str, total: u64) {
        self.finish();
        *self.current.lock().unwrap() = Some((name.to_string(), total, Instant::now()));
    }
    fn inc(&self, n: u64) {
        self.done.fetch_add(n, Ordering::Relaxed);
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (run, data, resolution) = match &args[..] {
        [run, data] => (run, data, MESH_RESOLUTION),
        [run, data, r] => (run, data, r.parse()?),
        _ => return Err("usage: eval_steps RUN DATA [MESH_RESOLUTION]".into()),
    };
    let (scene, fields) = i2sdf_model::intrinsic_io::load_run(&i2sdf_model::RunDir::new(std::path::Path::new(run)))?;
    let dataset = i2sdf_data::load(std::path::Path::new(data))?;
    let options = EvalOptions {
        mesh_resolution: resolution,
        ..Default::default()
    };
    let progress = Printer {
        current: Mutex::new(None),
        done: AtomicU64::new(0),
    };
    let start = Instant::now();
    let (mut report, mesh) = evaluate_with_progress(&scene, &dataset, &dataset.bounds, &options, &progress)?;
    progress.finish();
    println!(
        "evaluate: {:.2} s; mesh {} faces, F-score {:?}",
        start.elapsed().as_secs_f64(),
        mesh.as_ref().map_or(0, |m| m.num_faces()),
        report.geometry.mesh.fscore
    );
    if fields.is_some_and(|f| f.emitters.is_empty()) {
        report.note_no_emitters();
    }
    for note in &report.notes {
        println!("note: {note}");
    }
    Ok(())
}
