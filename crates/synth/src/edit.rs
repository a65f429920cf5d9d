//! Synth's side of edit specs. The format itself (parsing, validation, writing, emitter
//! selection) lives in `i2sdf_data::edit_spec`; synth writes `relight` ops through it for its
//! relit test views and selects its emitters by their bounding boxes.

use crate::tracer::Emitter;
use glam::Vec3;
pub use i2sdf_data::edit_spec::{nearest_box, EditOp, EditSpec, RelightOp};

/// The emitters' bounding boxes, in emitter order (what the edit spec selects by).
pub fn emitter_boxes(emitters: &[Emitter]) -> Vec<(Vec3, Vec3)> {
    emitters.iter().map(|e| e.bounds).collect()
}

/// The emitter nearest to `at` (see [`nearest_box`]).
pub fn nearest_emitter(emitters: &[Emitter], at: Vec3) -> Option<usize> {
    nearest_box(&emitter_boxes(emitters), at)
}

/// Per-emitter RGB gains after applying every relight op of `spec` in order.
pub fn emitter_gains(spec: &EditSpec, emitters: &[Emitter]) -> Vec<Vec3> {
    spec.emitter_gains(&emitter_boxes(emitters))
}
