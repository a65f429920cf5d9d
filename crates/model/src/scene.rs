//! The neural scene of stage 1: F_d, F_c, F_e and β, in the normalized frame (unit sphere).

use crate::config::{Backbone, ModelConfig};
use i2sdf_data::{DataError, Normalization};
use i2sdf_nn::{
    load_safetensors, save_safetensors, FrequencyEncoding, Mlp, MlpWorkspace, Parameters, SdfNetwork, SdfWorkspace,
    SphericalHarmonics,
};
use std::collections::HashMap;
use std::path::Path;

/// The learnable β of the VolSDF density (paper eq. 2), kept as β = β_min + exp(raw): positive
/// whatever the optimizer does, and learned in log space so that a short CPU schedule can move it
/// over orders of magnitude (0.1 → 0.001) at a constant relative rate.
#[derive(Clone, Debug, PartialEq)]
pub struct Beta {
    pub raw: [f32; 1],
    pub min: f32,
}

impl Beta {
    pub fn new(init: f32, min: f32) -> Self {
        Beta {
            raw: [(init - min).ln()],
            min,
        }
    }
    pub fn value(&self) -> f32 {
        self.min + self.raw[0].exp()
    }
    /// dβ/d raw.
    pub fn dvalue(&self) -> f32 {
        self.raw[0].exp()
    }
}

impl Parameters for Beta {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        f(format!("{prefix}.beta_raw"), vec![1], &self.raw);
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        f(format!("{prefix}.beta_raw"), vec![1], &mut self.raw);
    }
}

/// The view-direction encoding of F_c: spherical harmonics (hash-grid backbone) or the paper's
/// positional encoding with 4 bands.
#[derive(Clone, Debug)]
pub enum DirectionEncoding {
    Sh(SphericalHarmonics),
    Frequency(FrequencyEncoding),
}

impl DirectionEncoding {
    pub fn output_dim(&self) -> usize {
        match self {
            DirectionEncoding::Sh(s) => s.output_dim(),
            DirectionEncoding::Frequency(f) => f.output_dim(),
        }
    }
    pub fn encode(&self, dirs: &[f32], out: &mut [f32]) {
        match self {
            DirectionEncoding::Sh(s) => s.encode(dirs, out),
            DirectionEncoding::Frequency(f) => f.encode(dirs, out, None),
        }
    }
}

#[derive(Clone, Debug)]
pub struct NeuralScene {
    pub config: ModelConfig,
    pub normalization: Normalization,
    pub sdf: SdfNetwork,
    pub radiance: Mlp,
    pub emitter: Mlp,
    pub direction: DirectionEncoding,
    pub beta: Beta,
}

impl NeuralScene {
    pub fn new(config: &ModelConfig, normalization: Normalization, seed: u64) -> Self {
        let direction = match config.backbone {
            Backbone::HashGrid => DirectionEncoding::Sh(SphericalHarmonics::new(config.sh_degree)),
            Backbone::Mlp => DirectionEncoding::Frequency(FrequencyEncoding::new(3, 4)),
        };
        NeuralScene {
            config: config.clone(),
            normalization,
            sdf: SdfNetwork::new(config.sdf_network(), seed),
            radiance: Mlp::new(config.radiance_mlp(), seed.wrapping_add(1)),
            emitter: Mlp::new(config.emitter_mlp(), seed.wrapping_add(2)),
            direction,
            beta: Beta::new(config.beta_init, config.beta_min),
        }
    }

    pub fn feature_dim(&self) -> usize {
        self.sdf.feature_dim()
    }

    /// Assembles F_c's input rows [z, enc(v), ∇d] for `n` points (`dirs`: unit view directions
    /// from the camera, `[n×3]`; `gradients`: ∇d, `[n×3]`, the raw SDF gradient as VolSDF feeds it).
    pub fn radiance_input(&self, features: &[f32], dirs: &[f32], gradients: &[f32], out: &mut Vec<f32>) {
        let f = self.feature_dim();
        let e = self.direction.output_dim();
        let n = dirs.len() / 3;
        let w = f + e + 3;
        out.clear();
        out.resize(n * w, 0.0);
        let mut enc = vec![0.0f32; n * e];
        self.direction.encode(dirs, &mut enc);
        for i in 0..n {
            let row = &mut out[i * w..(i + 1) * w];
            row[..f].copy_from_slice(&features[i * f..(i + 1) * f]);
            row[f..f + e].copy_from_slice(&enc[i * e..(i + 1) * e]);
            row[f + e..].copy_from_slice(&gradients[i * 3..i * 3 + 3]);
        }
    }

    fn modules(&self) -> Vec<(&str, &dyn Parameters)> {
        vec![
            ("sdf", &self.sdf),
            ("radiance", &self.radiance),
            ("emitter", &self.emitter),
            ("density", &self.beta),
        ]
    }

    /// Writes the fields' parameters (and the config and normalization as metadata) to a
    /// safetensors file, atomically. `extra` adds metadata entries.
    pub fn save(&self, path: &Path, extra: &[(&str, String)]) -> Result<(), DataError> {
        self.save_with(path, extra, &[])
    }

    /// [`NeuralScene::save`] with more tensors in the same file (optimizer state).
    pub fn save_with(
        &self,
        path: &Path,
        extra: &[(&str, String)],
        extra_modules: &[(&str, &dyn Parameters)],
    ) -> Result<(), DataError> {
        let mut meta = HashMap::new();
        meta.insert(
            "model_config".to_string(),
            serde_json::to_string(&self.config).expect("config serializes"),
        );
        meta.insert(
            "normalization".to_string(),
            serde_json::to_string(&self.normalization).expect("serializes"),
        );
        for (k, v) in extra {
            meta.insert(k.to_string(), v.clone());
        }
        let mut modules = self.modules();
        modules.extend_from_slice(extra_modules);
        i2sdf_data::imageio::write_atomic(path, |tmp| {
            save_safetensors(tmp, &modules, Some(meta)).map_err(|e| e.to_string())
        })
    }

    /// Reads a scene written by [`NeuralScene::save`]; returns it with the file's metadata.
    pub fn load(path: &Path) -> Result<(NeuralScene, HashMap<String, String>), DataError> {
        let (scene, meta) = Self::load_config(path)?;
        let mut scene = scene;
        scene.load_params(path, &mut [])?;
        Ok((scene, meta))
    }

    /// A fresh scene with the configuration and normalization stored in a checkpoint, and the
    /// checkpoint's metadata (parameters not loaded yet: see [`NeuralScene::load_params`]).
    pub fn load_config(path: &Path) -> Result<(NeuralScene, HashMap<String, String>), DataError> {
        let bytes = std::fs::read(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
        let (_, header) = safetensors_header(&bytes).map_err(|m| DataError::file(path, m))?;
        let config: ModelConfig = header
            .get("model_config")
            .ok_or_else(|| DataError::field(path, "model_config", "missing from the metadata"))
            .and_then(|s| serde_json::from_str(s).map_err(|e| DataError::field(path, "model_config", e.to_string())))?;
        let normalization: Normalization = header
            .get("normalization")
            .ok_or_else(|| DataError::field(path, "normalization", "missing from the metadata"))
            .and_then(|s| {
                serde_json::from_str(s).map_err(|e| DataError::field(path, "normalization", e.to_string()))
            })?;
        Ok((NeuralScene::new(&config, normalization, 0), header))
    }

    /// Loads the fields' parameters (and `extra_modules`, e.g. optimizer state) from a checkpoint
    /// written with this scene's configuration.
    pub fn load_params(
        &mut self,
        path: &Path,
        extra_modules: &mut [(&str, &mut dyn Parameters)],
    ) -> Result<(), DataError> {
        let NeuralScene {
            sdf,
            radiance,
            emitter,
            beta,
            ..
        } = self;
        let mut modules: Vec<(&str, &mut dyn Parameters)> = vec![
            ("sdf", sdf),
            ("radiance", radiance),
            ("emitter", emitter),
            ("density", beta),
        ];
        for (name, m) in extra_modules.iter_mut() {
            modules.push((name, &mut **m));
        }
        load_safetensors(path, &mut modules).map_err(|e| DataError::file(path, e.to_string()))?;
        Ok(())
    }

    /// Are all parameters finite? (Checked before a checkpoint is written.)
    pub fn is_finite(&self) -> bool {
        let mut ok = true;
        for (_, m) in self.modules() {
            m.visit("", &mut |_, _, v| ok &= v.iter().all(|x| x.is_finite()));
        }
        ok
    }
}

/// The metadata of a safetensors file without loading its tensors.
fn safetensors_header(bytes: &[u8]) -> Result<((), HashMap<String, String>), String> {
    let (_, meta) =
        safetensors::SafeTensors::read_metadata(bytes).map_err(|e| format!("not a safetensors file: {e}"))?;
    Ok(((), meta.metadata().clone().unwrap_or_default()))
}

/// Inference on a trained scene in batches (no gradients kept beyond what is asked): the queries
/// of `render`, `mesh` and the sphere tracer.
pub struct SceneQuery<'a> {
    pub scene: &'a NeuralScene,
    sdf_ws: SdfWorkspace,
    mlp_ws: MlpWorkspace,
    input: Vec<f32>,
}

impl<'a> SceneQuery<'a> {
    pub fn new(scene: &'a NeuralScene) -> Self {
        SceneQuery {
            scene,
            sdf_ws: SdfWorkspace::default(),
            mlp_ws: MlpWorkspace::default(),
            input: Vec::new(),
        }
    }

    /// Signed distances at `points` (`[n×3]`, normalized frame).
    pub fn sdf(&mut self, points: &[f32], sdf: &mut [f32]) {
        let n = points.len() / 3;
        let mut feature = vec![0.0; n * self.scene.feature_dim()];
        self.scene
            .sdf
            .forward(points, &mut self.sdf_ws, &mut sdf[..n], &mut feature);
    }

    /// Distance, feature and gradient at `points`.
    pub fn sdf_full(&mut self, points: &[f32], sdf: &mut [f32], feature: &mut [f32], gradient: &mut [f32]) {
        self.scene
            .sdf
            .forward_with_gradient(points, &mut self.sdf_ws, sdf, feature, gradient);
    }

    /// F_c at points with features and gradients already computed: `rgb` is `[n×3]`.
    pub fn radiance(&mut self, features: &[f32], dirs: &[f32], gradients: &[f32], rgb: &mut [f32]) {
        let mut input = std::mem::take(&mut self.input);
        self.scene.radiance_input(features, dirs, gradients, &mut input);
        self.scene.radiance.forward(&input, &mut self.mlp_ws, rgb);
        self.input = input;
    }

    /// F_e at points with features already computed: `prob` is `[n]`.
    pub fn emitter(&mut self, features: &[f32], prob: &mut [f32]) {
        self.scene.emitter.forward(features, &mut self.mlp_ws, prob);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> ModelConfig {
        ModelConfig {
            hash_levels: 4,
            hash_log2_table: 12,
            hash_finest_resolution: 64,
            init_radius: 0.8,
            ..Default::default()
        }
    }

    #[test]
    fn starts_as_an_inverted_sphere() {
        let scene = NeuralScene::new(
            &small(),
            Normalization {
                center: [0.0; 3],
                scale: 1.0,
            },
            3,
        );
        let mut q = SceneQuery::new(&scene);
        let pts = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, -0.9, 0.0, 0.0, 0.0, 1.3];
        let mut d = [0.0; 4];
        q.sdf(&pts, &mut d);
        // ≈ r − ‖x‖ (a small softplus MLP only approximates the cone at the centre): free space
        // inside, decreasing outwards, negative outside the sphere.
        assert!(d[0] > 0.5 && d[0] > d[1] && d[1] > d[2] && d[3] < 0.0, "{d:?}");
        assert!((d[1] - 0.3).abs() < 0.1, "{d:?}");
    }

    #[test]
    fn save_load_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let mut scene = NeuralScene::new(
            &small(),
            Normalization {
                center: [1.0, 2.0, 3.0],
                scale: 4.0,
            },
            5,
        );
        scene.beta.raw[0] = -3.14;
        scene.radiance.params[7] = 0.5;
        let p = dir.path().join("fields.safetensors");
        scene.save(&p, &[("iteration", "12".into())]).unwrap();
        let (back, meta) = NeuralScene::load(&p).unwrap();
        assert_eq!(meta["iteration"], "12");
        assert_eq!(back.config, scene.config);
        assert_eq!(back.normalization, scene.normalization);
        assert_eq!(back.beta, scene.beta);
        assert_eq!(back.radiance.params, scene.radiance.params);
        assert_eq!(back.sdf.mlp.params, scene.sdf.mlp.params);
        std::fs::write(&p, b"junk").unwrap();
        assert!(NeuralScene::load(&p)
            .unwrap_err()
            .to_string()
            .contains("fields.safetensors"));
    }
}
