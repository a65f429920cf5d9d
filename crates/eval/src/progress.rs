//! Progress of the long parts of an evaluation. [`crate::neural::evaluate_with_progress`] names
//! each step as it starts and counts its work as it goes, so that a caller can show what `eval` is
//! doing: on a poorly trained run a step may take minutes (a mesh of millions of faces floating
//! far from the ground truth), and a silent or unlabelled wait reads as a hang.

/// Receives the steps of an evaluation and their progress. `inc` is called from worker threads,
/// hence `Sync`. A step ends when the next one starts or the evaluation returns.
///
/// The steps of [`crate::neural::evaluate_with_progress`], in order, with the unit of their count:
/// `"test views"` and/or `"training views"` (views rendered), `"mesh extraction"` (no count), and with a ground-truth mesh
/// `"sampling surfaces"` (points sampled on both meshes), `"visibility culling"` (points tested
/// against the training views; skipped without views) and `"nearest neighbours"` (points whose
/// nearest neighbour on the other mesh is found).
pub trait EvalProgress: Sync {
    /// A step named `name` starts, with `total` units of work (0: the step has no count).
    fn step(&self, name: &str, total: u64);
    /// `n` more units of the current step are done.
    fn inc(&self, n: u64);
}

/// Reports nothing: what [`crate::neural::evaluate`] passes.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoProgress;

impl EvalProgress for NoProgress {
    fn step(&self, _name: &str, _total: u64) {}
    fn inc(&self, _n: u64) {}
}

/// Step names, as [`EvalProgress::step`] receives them.
pub const TEST_VIEWS: &str = "test views";
pub const TRAIN_VIEWS: &str = "training views";
pub const MESH_EXTRACTION: &str = "mesh extraction";
pub const SAMPLING: &str = "sampling surfaces";
pub const CULLING: &str = "visibility culling";
pub const NEAREST_NEIGHBOURS: &str = "nearest neighbours";
