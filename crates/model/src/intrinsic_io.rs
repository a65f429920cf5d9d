//! Stage 2's checkpoint, `RUN/stage2.safetensors`: the material fields, the emission table and
//! (while training) the optimizer state, with the emitter clusters, the material configuration
//! and the dataset's radiometry as metadata. It is a file of its own so that the frozen stage-1
//! checkpoint is never rewritten by stage 2; [`load_run`] gives a run's scene with whatever
//! stage 2 added.

use crate::emitters::{Emitter, EmitterTable};
use crate::material_field::{MaterialBackbone, MaterialConfig, MaterialField};
use crate::run_dir::RunDir;
use crate::scene::{check_table_fits, checkpoint_header, param_error, NeuralScene, OPTIMIZER_PREFIX};
use i2sdf_data::{DataError, Radiometry};
use i2sdf_nn::params::{load_modules, ModuleSlot};
use i2sdf_nn::{save_safetensors, Parameters};
use std::collections::HashMap;
use std::path::Path;

/// Tensor prefixes of the stage-2 modules.
pub const MATERIAL_PREFIX: &str = "material";
pub const EMISSION_PREFIX: &str = "emission";

/// What stage 2 learns, with what it needs to be read back.
#[derive(Clone, Debug)]
pub struct IntrinsicFields {
    pub material: MaterialField,
    pub emitters: EmitterTable,
    pub radiometry: Radiometry,
}

impl IntrinsicFields {
    /// Writes the fields (and `extra` tensors: optimizer state) atomically, with `meta` entries.
    pub fn save(
        &self,
        path: &Path,
        meta: &[(&str, String)],
        extra: &[(&str, &dyn Parameters)],
    ) -> Result<(), DataError> {
        let mut metadata = HashMap::new();
        metadata.insert(
            "material_config".to_string(),
            serde_json::to_string(&self.material.config).expect("serializes"),
        );
        metadata.insert(
            "emitters".to_string(),
            serde_json::to_string(&self.emitters.emitters).expect("serializes"),
        );
        metadata.insert("transfer".to_string(), self.radiometry.transfer.name().to_string());
        metadata.insert(
            "exposure".to_string(),
            serde_json::to_string(&self.radiometry.exposure).expect("serializes"),
        );
        for (k, v) in meta {
            metadata.insert(k.to_string(), v.clone());
        }
        let mut modules: Vec<(&str, &dyn Parameters)> = vec![
            (MATERIAL_PREFIX, &self.material as &dyn Parameters),
            (EMISSION_PREFIX, &self.emitters as &dyn Parameters),
        ];
        modules.extend_from_slice(extra);
        i2sdf_data::imageio::write_atomic(path, |tmp| {
            save_safetensors(tmp, &modules, Some(metadata)).map_err(|e| e.to_string())
        })
    }

    /// Reads a stage-2 checkpoint for a scene whose SDF feature has `feature_dim` channels;
    /// `extra` slots (optimizer state) are filled from the same file, other optimizer tensors
    /// are skipped. Returns the file's metadata too.
    pub fn load(
        path: &Path,
        feature_dim: usize,
        extra: &mut [ModuleSlot],
    ) -> Result<(IntrinsicFields, HashMap<String, String>), DataError> {
        let (meta, tensor_bytes) = checkpoint_header(path)?;
        let get = |k: &str| {
            meta.get(k)
                .ok_or_else(|| DataError::field(path, k, "missing from the metadata"))
        };
        let config: MaterialConfig = serde_json::from_str(get("material_config")?)
            .map_err(|e| DataError::field(path, "material_config", e.to_string()))?;
        config
            .check()
            .map_err(|m| DataError::field(path, "material_config", m))?;
        if config.backbone == MaterialBackbone::HashGrid {
            let grid = (
                config.hash_levels,
                2,
                config.hash_log2_table,
                config.hash_base_resolution,
                config.hash_finest_resolution,
            );
            check_table_fits(path, "material_config", tensor_bytes, grid)?;
        }
        let emitters: Vec<Emitter> =
            serde_json::from_str(get("emitters")?).map_err(|e| DataError::field(path, "emitters", e.to_string()))?;
        let exposure: Option<f64> =
            serde_json::from_str(get("exposure")?).map_err(|e| DataError::field(path, "exposure", e.to_string()))?;
        let radiometry =
            Radiometry::from_name(get("transfer")?, exposure).map_err(|m| DataError::field(path, "transfer", m))?;
        let k = emitters.len();
        let mut fields = IntrinsicFields {
            material: MaterialField::new(&config, feature_dim, 0),
            emitters: EmitterTable::new(emitters, &vec![[1.0; 3]; k]),
            radiometry,
        };
        {
            let IntrinsicFields { material, emitters, .. } = &mut fields;
            let mut slots = vec![
                ModuleSlot {
                    prefix: MATERIAL_PREFIX,
                    module: material,
                    required: true,
                },
                ModuleSlot {
                    prefix: EMISSION_PREFIX,
                    module: emitters,
                    required: true,
                },
            ];
            for e in extra.iter_mut() {
                slots.push(ModuleSlot {
                    prefix: e.prefix,
                    module: &mut *e.module,
                    required: e.required,
                });
            }
            load_modules(path, &mut slots, Some(OPTIMIZER_PREFIX)).map_err(|e| param_error(path, e))?;
        }
        Ok((fields, meta))
    }
}

/// A run's frozen stage-1 scene and, when stage 2 has checkpointed, its intrinsic fields.
pub fn load_run(run: &RunDir) -> Result<(NeuralScene, Option<IntrinsicFields>), DataError> {
    let ckpt = run.checkpoint_path();
    if !ckpt.is_file() {
        return Err(DataError::file(
            &ckpt,
            "no checkpoint: is this a training run (train --out)?",
        ));
    }
    let (scene, _) = NeuralScene::load(&ckpt)?;
    let s2 = run.stage2_checkpoint_path();
    let fields = if s2.is_file() {
        Some(IntrinsicFields::load(&s2, scene.feature_dim(), &mut [])?.0)
    } else {
        None
    };
    Ok((scene, fields))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material_field::MaterialBackbone;
    use i2sdf_data::Transfer;

    #[test]
    fn round_trips_and_names_what_is_missing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("stage2.safetensors");
        let config = MaterialConfig {
            backbone: MaterialBackbone::HashGrid,
            hash_levels: 2,
            hash_log2_table: 10,
            hash_finest_resolution: 32,
            ..Default::default()
        };
        let e = Emitter {
            centre: [1.0, 2.0, 3.0],
            extent: [0.5, 0.0, 0.5],
            radius: 0.4,
            points: 10,
            sphere: None,
            bounds: None,
            panel: None,
        };
        let fields = IntrinsicFields {
            material: MaterialField::new(&config, 8, 3),
            emitters: EmitterTable::new(vec![e], &[[4.0, 5.0, 6.0]]),
            radiometry: Radiometry {
                transfer: Transfer::Srgb,
                exposure: Some(1.5),
            },
        };
        fields.save(&path, &[("iteration", "7".into())], &[]).unwrap();
        let (back, meta) = IntrinsicFields::load(&path, 8, &mut []).unwrap();
        assert_eq!(meta["iteration"], "7");
        assert_eq!(back.material.mlp.params, fields.material.mlp.params);
        assert_eq!(back.emitters.log_emission, fields.emitters.log_emission);
        assert_eq!(back.emitters.emitters, fields.emitters.emitters);
        assert_eq!(back.radiometry, fields.radiometry);
        std::fs::write(&path, b"not a checkpoint").unwrap();
        let err = IntrinsicFields::load(&path, 8, &mut []).unwrap_err();
        assert!(
            err.is_bad_input() && err.to_string().contains("stage2.safetensors"),
            "{err}"
        );
    }
}
