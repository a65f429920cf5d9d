//! How the emitter masks found from a capture's images compare with the exact room's masks.
//!
//! `cargo run --release -p i2sdf-data --example mask_probe -- CAPTURE ROOM [MASKS_DIR]`
//!
//! Detects the masks of CAPTURE's training views as `train` does (`detect_emitters`) and prints,
//! over the views, the IoU against ROOM's masks (the same views without the lens: only comparable
//! between detectors), the enclosed holes left in the found masks, and the found pixels per
//! true pixel. With MASKS_DIR (a run's `emitter_masks/`, written by an earlier version) the same
//! figures for those masks.

use i2sdf_data::emitter_detect::{detect_emitters, enclosed_holes};
use i2sdf_data::{load, Split};

fn report(name: &str, found: &[Vec<bool>], truth: &[Vec<bool>], w: usize, h: usize) {
    let (mut inter, mut union, mut f, mut t, mut hole) = (0, 0, 0, 0, 0);
    for (a, b) in found.iter().zip(truth) {
        for (&x, &y) in a.iter().zip(b) {
            inter += (x && y) as usize;
            union += (x || y) as usize;
            f += x as usize;
            t += y as usize;
        }
        hole += enclosed_holes(a, w, h).len();
    }
    println!(
        "{name}: IoU {:.3}, found / true pixels {:.3} ({f} / {t}), enclosed holes {hole}",
        inter as f64 / union.max(1) as f64,
        f as f64 / t.max(1) as f64
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        eprintln!("usage: mask_probe CAPTURE ROOM [MASKS_DIR]");
        std::process::exit(2);
    }
    let capture = load(std::path::Path::new(&args[0])).expect("capture");
    let room = load(std::path::Path::new(&args[1])).expect("room");
    let frames: Vec<_> = capture.split(Split::Train).collect();
    let truth: Vec<Vec<bool>> = room
        .split(Split::Train)
        .map(|f| {
            f.emitter_mask
                .as_ref()
                .expect("the room's masks")
                .data
                .iter()
                .map(|v| *v > 0.5)
                .collect()
        })
        .collect();
    let (w, h) = (frames[0].camera.width, frames[0].camera.height);
    let found = detect_emitters(&frames);
    println!("{found:?}");
    let now: Vec<Vec<bool>> = found
        .masks
        .iter()
        .map(|m| m.data.iter().map(|v| *v > 0.5).collect())
        .collect();
    report("detected now", &now, &truth, w, h);
    if let Some(dir) = args.get(2) {
        let old: Vec<Vec<bool>> = frames
            .iter()
            .map(|f| {
                let m = i2sdf_data::imageio::read_image(&std::path::Path::new(dir).join(format!("{}.png", f.name)))
                    .expect("mask");
                m.data.chunks_exact(m.channels).map(|c| c[0] > 0.5).collect()
            })
            .collect();
        report(dir, &old, &truth, w, h);
    }
}
