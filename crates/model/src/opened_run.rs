//! A trained run opened once for inference ([`OpenedRun`]): its stage-1 scene, its stage-2 fields
//! where stage 2 has checkpointed, `run.json`, the part of its configuration that inference
//! reads ([`InferenceConfig`]) and the record of the surface stage 2 baked ([`BakeRecord`]).
//! `render`, `eval`, `report` and `edit` all open a run here and take its frozen scene from
//! [`OpenedRun::frozen`], which builds it as stage 2 did ([`FrozenScene::labelled`] over the same
//! baked surface), so every command casts the same surface.
//!
//! The configuration's type (the trainer's `TrainConfig`) lives above this crate: the trainer
//! maps it onto [`InferenceConfig`] and opens runs with [`OpenedRun::open`].

use crate::intrinsic::{BakedSurface, FrozenScene};
use crate::intrinsic_io::IntrinsicFields;
use crate::renderer::RenderSettings;
use crate::run_dir::{RunDir, RunInfo};
use crate::scene::NeuralScene;
use i2sdf_data::{Bounds, Camera, DataError, Dataset, Split};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

/// What inference reads of a run's configuration (`RUN/config.toml`).
#[derive(Clone, Debug)]
pub struct InferenceConfig {
    /// The volume renderer's settings the run was trained with (its `[sampling]`).
    pub render: RenderSettings,
    /// `stage2.emitter_threshold`: a hit is emitting where F_e exceeds it.
    pub emitter_threshold: f32,
    /// `stage2.label_unobserved`: the surface inside an emitter that no training camera sees is
    /// that emitter ([`FrozenScene::observe`]).
    pub label_unobserved: bool,
    /// `stage2.bake_resolution` (0: no bake): used only for runs whose stage-2 checkpoint
    /// predates the [`BakeRecord`].
    pub bake_resolution: usize,
}

/// The surface stage 2 baked for its rays ([`BakedSurface`]): the box (world units, before
/// [`PAD_FRACTION`](crate::sdf_mesh::PAD_FRACTION)) of the surface its training pixels see
/// and of the cameras, the resolution (`stage2.bake_resolution`) and the radius of its shading
/// normals' smoothing. Kept in the stage-2 checkpoint's metadata under [`BakeRecord::META_KEY`]
/// (`null`: stage 2 did not bake).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BakeRecord {
    pub bounds: Bounds,
    pub resolution: usize,
    /// The radius (world units) over which the surface's shading normals are the SDF's
    /// averaged ([`crate::shading_normals`]; 0: the SDF's own, as in checkpoints without it).
    #[serde(default)]
    pub normal_smoothing: f32,
}

impl BakeRecord {
    /// The metadata key of the stage-2 checkpoint.
    pub const META_KEY: &'static str = "bake";

    /// The metadata entry of `bake` (stage 2's, `None` where it did not bake).
    pub fn meta(bake: Option<&BakeRecord>) -> (&'static str, String) {
        (
            Self::META_KEY,
            serde_json::to_string(&bake).expect("a bake record serializes"),
        )
    }

    /// The record in a stage-2 checkpoint's metadata: `Ok(None)` where the key is missing
    /// (a checkpoint written before it was kept), `Ok(Some(None))` where stage 2 did not bake.
    pub fn from_meta(path: &Path, meta: &HashMap<String, String>) -> Result<Option<Option<BakeRecord>>, DataError> {
        meta.get(Self::META_KEY)
            .map(|text| serde_json::from_str(text).map_err(|e| DataError::field(path, Self::META_KEY, e.to_string())))
            .transpose()
    }

    /// The baked surface of `scene` this record describes.
    pub fn bake(&self, scene: &NeuralScene) -> Result<Arc<BakedSurface>, DataError> {
        Ok(Arc::new(BakedSurface::new(
            scene,
            &self.bounds,
            self.resolution,
            self.normal_smoothing,
        )?))
    }
}

/// A trained run, opened once: everything `render`, `eval`, `report` and `edit` read of it.
pub struct OpenedRun {
    pub dir: RunDir,
    pub info: RunInfo,
    /// The frozen stage-1 fields (`RUN/checkpoint.safetensors`).
    pub scene: NeuralScene,
    /// Stage 2's fields (`RUN/stage2.safetensors`), when it has checkpointed.
    pub fields: Option<IntrinsicFields>,
    pub config: InferenceConfig,
    /// The surface stage 2 baked (`None`: it did not bake, or there is no stage 2).
    pub bake: Option<BakeRecord>,
    /// What the commands should say about how the run was opened (a stage-2 checkpoint older
    /// than the bake record).
    pub notes: Vec<String>,
}

impl OpenedRun {
    /// Reads the run at `root` (`run.json`, the stage-1 checkpoint, the stage-2 checkpoint where
    /// there is one) with `config`, the run's own configuration as the trainer maps it.
    pub fn open(root: &Path, config: InferenceConfig) -> Result<OpenedRun, DataError> {
        let dir = RunDir::new(root);
        let info = dir.read_info()?;
        let ckpt = dir.checkpoint_path();
        if !ckpt.is_file() {
            return Err(DataError::file(
                &ckpt,
                "no checkpoint: is this a training run (train --out)?",
            ));
        }
        let (scene, _) = NeuralScene::load(&ckpt)?;
        let s2 = dir.stage2_checkpoint_path();
        let (mut fields, mut bake, mut notes) = (None, None, Vec::new());
        if s2.is_file() {
            let (f, meta) = IntrinsicFields::load(&s2, scene.feature_dim(), &mut [])?;
            bake = match BakeRecord::from_meta(&s2, &meta)? {
                Some(recorded) => recorded,
                None => {
                    let fallback = legacy_bake(&info, &config);
                    notes.push(format!(
                        "note: {} does not record the box stage 2 baked its surface over (written by an older version): {}",
                        s2.display(),
                        match fallback {
                            Some(b) => format!("baked over the dataset's bounds at {}", b.resolution),
                            None => "not baked (rays are sphere traced)".to_string(),
                        }
                    ));
                    fallback
                }
            };
            fields = Some(f);
        }
        Ok(OpenedRun {
            dir,
            info,
            scene,
            fields,
            config,
            bake,
            notes,
        })
    }

    /// Stage 2's fields, or the bad-input error that names the missing checkpoint.
    pub fn stage2(&self) -> Result<&IntrinsicFields, DataError> {
        self.fields.as_ref().ok_or_else(|| self.dir.no_stage2())
    }

    /// The training views of `dataset` (the run's, its poses corrected as stage 1 left them),
    /// where stage 2 labelled the unobserved emitter surface by them (`stage2.label_unobserved`).
    pub fn observers(&self, dataset: &Dataset) -> Option<Vec<Camera>> {
        self.config
            .label_unobserved
            .then(|| dataset.split(Split::Train).map(|f| f.camera.clone()).collect())
    }

    /// The frozen scene with stage 2's emitters, exactly as stage 2 built it: its emitter
    /// threshold, its baked surface (the recorded box and resolution), and what the training views
    /// of `dataset` observe where it labelled by them. `None` without stage 2.
    pub fn frozen(&self, dataset: &Dataset) -> Result<Option<FrozenScene<'_>>, DataError> {
        let Some(fields) = &self.fields else {
            return Ok(None);
        };
        let baked = self.bake.map(|b| b.bake(&self.scene)).transpose()?;
        let observers = self.observers(dataset);
        Ok(Some(FrozenScene::labelled(
            &self.scene,
            &fields.emitters,
            fields.radiometry,
            self.config.emitter_threshold,
            baked,
            observers.as_deref(),
        )))
    }

    /// The scene bounds `run.json` records (where `mesh` looks for the surface).
    pub fn bounds(&self) -> Result<Bounds, DataError> {
        self.info.bounds.ok_or_else(|| {
            DataError::field(
                self.dir.info_path(),
                "bounds",
                "missing (run trained by an older version?)",
            )
        })
    }
}

/// The bake of a run whose stage-2 checkpoint does not record its own: the dataset's bounds
/// (`run.json`) at `stage2.bake_resolution`.
fn legacy_bake(info: &RunInfo, config: &InferenceConfig) -> Option<BakeRecord> {
    let bounds = info.bounds?;
    (config.bake_resolution > 0).then_some(BakeRecord {
        bounds,
        resolution: config.bake_resolution,
        normal_smoothing: 0.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bake_record_round_trips_through_the_metadata() {
        let path = Path::new("stage2.safetensors");
        let record = BakeRecord {
            bounds: Bounds {
                min: [-1.0, 0.0, -2.0],
                max: [1.0, 2.5, 2.0],
            },
            resolution: 128,
            normal_smoothing: 0.073,
        };
        for bake in [Some(record), None] {
            let (k, v) = BakeRecord::meta(bake.as_ref());
            let meta = HashMap::from([(k.to_string(), v)]);
            assert_eq!(BakeRecord::from_meta(path, &meta).unwrap(), Some(bake));
        }
        assert_eq!(BakeRecord::from_meta(path, &HashMap::new()).unwrap(), None);
        // A record written before the smoothing was kept reads as the SDF's own normals.
        let older = HashMap::from([(
            "bake".to_string(),
            r#"{"bounds":{"min":[0,0,0],"max":[1,1,1]},"resolution":64}"#.to_string(),
        )]);
        let read = BakeRecord::from_meta(path, &older).unwrap().unwrap().unwrap();
        assert_eq!((read.resolution, read.normal_smoothing), (64, 0.0));
        let bad = HashMap::from([("bake".to_string(), "[1, 2".to_string())]);
        let e = BakeRecord::from_meta(path, &bad).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("bake"), "{e}");
    }
}
