//! What identifies the data a run trains on, whatever its path: kept in the stage-1 checkpoint
//! (so `--resume` refuses other data) and in `run.json` (so `render`, `edit`, `eval` and
//! `report` say when `--data` names a dataset other than the run's).

use crate::dataset::{Dataset, Frame, Split};
use serde::{Deserialize, Serialize};

/// What identifies the data a run trains on: the training views' count, resolution, cameras and
/// every training map's values (hashed), so a resume against other data is refused whatever its
/// path, and the same data under another path is accepted.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DatasetFingerprint {
    pub train_views: usize,
    /// Width × height of the first training view.
    pub size: [usize; 2],
    /// FNV-1a over the cameras' intrinsics and poses (f64 bits), hex.
    pub cameras: String,
    /// FNV-1a over the training images, HDR images, depth, normal, emitter and material masks
    /// (f32 bits), hex.
    pub images: String,
}

/// How many of the training maps ([`Frame::maps`]) add their presence to the fingerprint whether
/// present or not: those a fingerprint has always covered.
const FINGERPRINT_MAPS_ALWAYS: usize = 5;

/// FNV-1a, one 64-bit word at a time (the fingerprint needs stability across builds and Rust
/// versions, which std's hasher does not promise, not cryptographic strength).
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn word(&mut self, w: u64) {
        self.0 = (self.0 ^ w).wrapping_mul(0x0000_0100_0000_01b3);
    }
    fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

impl DatasetFingerprint {
    pub fn of(dataset: &Dataset) -> Self {
        let (mut cams, mut imgs) = (Fnv::new(), Fnv::new());
        let frames: Vec<_> = dataset.split(Split::Train).collect();
        for f in &frames {
            let c = &f.camera;
            cams.word(c.width as u64);
            cams.word(c.height as u64);
            for v in [c.fx, c.fy, c.cx, c.cy].into_iter().chain(c.c2w.to_cols_array()) {
                cams.word(v.to_bits());
            }
            // Only a real lens adds words, so a pinhole dataset keeps the fingerprint it had.
            for (_, v) in c.lens.params() {
                cams.word(v.to_bits());
            }
            for (k, m) in f.maps().into_iter().take(Frame::TRAINING_MAPS).enumerate() {
                // The maps after the first five came later (the material mask): they add words
                // only where present, so a dataset without them keeps the fingerprint it had.
                if k >= FINGERPRINT_MAPS_ALWAYS && m.is_none() {
                    continue;
                }
                // Which maps are present is part of the data (a mask added changes training).
                imgs.word(k as u64 + 1);
                if let Some(m) = m {
                    imgs.word(m.data.len() as u64);
                    for pair in m.data.chunks(2) {
                        let lo = pair[0].to_bits() as u64;
                        let hi = pair.get(1).map_or(0, |v| v.to_bits() as u64);
                        imgs.word(lo | hi << 32);
                    }
                }
            }
        }
        let size = frames.first().map_or([0, 0], |f| [f.camera.width, f.camera.height]);
        DatasetFingerprint {
            train_views: frames.len(),
            size,
            cameras: cams.hex(),
            images: imgs.hex(),
        }
    }

    /// What differs from `other` (the run's), in words; empty when nothing does.
    pub fn differences(&self, run: &Self) -> Vec<String> {
        let mut out = Vec::new();
        if self.train_views != run.train_views || self.size != run.size {
            out.push(format!(
                "training views: the run's {} of {}×{}, this dataset's {} of {}×{}",
                run.train_views, run.size[0], run.size[1], self.train_views, self.size[0], self.size[1]
            ));
        }
        if self.cameras != run.cameras {
            out.push(format!("cameras: fingerprint {} → {}", run.cameras, self.cameras));
        }
        if self.images != run.images {
            out.push(format!("images: fingerprint {} → {}", run.images, self.images));
        }
        out
    }
}
