//! The fields' shape: one struct for the TOML config, the CLI's `--set` and checkpoint metadata.

use i2sdf_nn::{Activation, GeometricInit, HashGridConfig, MlpConfig, SdfEncodingConfig, SdfNetworkConfig};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Backbone {
    /// Multi-resolution hash grid + small MLPs (default; trains in minutes on a CPU).
    HashGrid,
    /// The paper's backbone (supp. "Architecture"): 8×256 SDF MLP with a skip at layer 4 on PE(6)
    /// positions, 256-dim feature, 4×256 radiance MLP on PE(4) directions. For fidelity and
    /// comparison; slow on a CPU.
    Mlp,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    pub backbone: Backbone,
    pub hash_levels: usize,
    pub hash_features: usize,
    pub hash_log2_table: u32,
    pub hash_base_resolution: u32,
    pub hash_finest_resolution: u32,
    pub sdf_hidden: usize,
    pub sdf_layers: usize,
    /// Dimension of the geometry feature z (besides the SDF value).
    pub feature_dim: usize,
    pub color_hidden: usize,
    pub color_layers: usize,
    pub emitter_hidden: usize,
    pub emitter_layers: usize,
    /// Spherical-harmonics degree of the view-direction encoding (hash-grid backbone).
    pub sh_degree: usize,
    /// Radius of the initial inverted sphere in normalized units (the scene is in the unit sphere).
    pub init_radius: f32,
    /// Initial and minimum β of the VolSDF density.
    pub beta_init: f32,
    pub beta_min: f32,
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            backbone: Backbone::HashGrid,
            hash_levels: 16,
            hash_features: 2,
            hash_log2_table: 17,
            hash_base_resolution: 16,
            hash_finest_resolution: 2048,
            sdf_hidden: 64,
            sdf_layers: 2,
            feature_dim: 15,
            color_hidden: 64,
            color_layers: 2,
            emitter_hidden: 64,
            emitter_layers: 1,
            sh_degree: 4,
            init_radius: 1.0,
            beta_init: 0.1,
            beta_min: 1e-4,
        }
    }
}

/// Range checks for configuration values: each names its dotted key, the value and the allowed
/// range, so `--set model.hash_levels=0` fails with a message instead of a panic deep in the
/// engine (the house's one set of value checks, [`i2sdf_data::validate`]).
pub use i2sdf_data::validate as check;

impl ModelConfig {
    /// Checks every key (prefix `model.`) against the range the engine supports.
    pub fn validate(&self) -> Result<(), String> {
        use check::{int, positive};
        int("model.hash_levels", self.hash_levels, 1, 32)?;
        if ![1, 2, 4, 8].contains(&self.hash_features) {
            return Err(format!(
                "model.hash_features = {}: must be 1, 2, 4 or 8 (the hash grid's SIMD layouts)",
                self.hash_features
            ));
        }
        int("model.hash_log2_table", self.hash_log2_table, 8, 24)?;
        int("model.hash_base_resolution", self.hash_base_resolution, 1, 1 << 16)?;
        int(
            "model.hash_finest_resolution",
            self.hash_finest_resolution,
            self.hash_base_resolution,
            1 << 20,
        )
        .map_err(|e| format!("{e} (at least model.hash_base_resolution)"))?;
        let table_floats = (self.hash_levels as u64) * (self.hash_features as u64) << self.hash_log2_table;
        if table_floats > 1 << 28 {
            return Err(format!(
                "model.hash_levels × model.hash_features × 2^model.hash_log2_table = {} × {} × 2^{} = {table_floats} \
                 table entries: more than 2^28 (1 GiB)",
                self.hash_levels, self.hash_features, self.hash_log2_table
            ));
        }
        int("model.sdf_hidden", self.sdf_hidden, 1, 1024)?;
        int("model.sdf_layers", self.sdf_layers, 1, 16)?;
        int("model.feature_dim", self.feature_dim, 1, 512)?;
        int("model.color_hidden", self.color_hidden, 1, 1024)?;
        int("model.color_layers", self.color_layers, 1, 16)?;
        int("model.emitter_hidden", self.emitter_hidden, 1, 1024)?;
        int("model.emitter_layers", self.emitter_layers, 1, 16)?;
        int("model.sh_degree", self.sh_degree, 1, 4)?;
        positive("model.init_radius", self.init_radius, 2.0)?;
        positive("model.beta_min", self.beta_min, 1.0)?;
        positive("model.beta_init", self.beta_init, 10.0)?;
        if self.beta_init <= self.beta_min {
            return Err(format!(
                "model.beta_init = {}: must exceed model.beta_min = {}",
                self.beta_init, self.beta_min
            ));
        }
        Ok(())
    }

    pub fn sdf_network(&self) -> SdfNetworkConfig {
        let init = Some(GeometricInit {
            radius: self.init_radius,
            inside_out: true,
        });
        match self.backbone {
            Backbone::HashGrid => SdfNetworkConfig {
                encoding: SdfEncodingConfig::HashGrid(HashGridConfig {
                    levels: self.hash_levels,
                    features_per_level: self.hash_features,
                    log2_table_size: self.hash_log2_table,
                    base_resolution: self.hash_base_resolution,
                    finest_resolution: self.hash_finest_resolution,
                    bound: 1.0,
                }),
                hidden_dim: self.sdf_hidden,
                hidden_layers: self.sdf_layers,
                skip_layers: vec![],
                activation: Activation::Softplus { beta: 100.0 },
                feature_dim: self.feature_dim,
                geometric_init: init,
            },
            Backbone::Mlp => SdfNetworkConfig {
                feature_dim: self.feature_dim.max(256),
                ..SdfNetworkConfig::paper(self.init_radius)
            },
        }
    }

    /// Feature size of the SDF network actually built.
    pub fn feature_size(&self) -> usize {
        self.sdf_network().feature_dim
    }

    /// Width of the view-direction encoding.
    pub fn direction_dim(&self) -> usize {
        match self.backbone {
            Backbone::HashGrid => self.sh_degree * self.sh_degree,
            Backbone::Mlp => 3 + 2 * 3 * 4,
        }
    }

    /// F_c: [z, enc(v), n] → RGB (sigmoid).
    pub fn radiance_mlp(&self) -> MlpConfig {
        let (hidden, layers) = match self.backbone {
            Backbone::HashGrid => (self.color_hidden, self.color_layers),
            Backbone::Mlp => (256, 4),
        };
        MlpConfig {
            input_dim: self.feature_size() + self.direction_dim() + 3,
            hidden_dim: hidden,
            hidden_layers: layers,
            output_dim: 3,
            skip_layers: vec![],
            hidden_activation: Activation::Relu,
            output_activation: Activation::Sigmoid,
        }
    }

    /// F_e: z → emitter probability (sigmoid); the paper's is 2 layers of 128.
    pub fn emitter_mlp(&self) -> MlpConfig {
        let (hidden, layers) = match self.backbone {
            Backbone::HashGrid => (self.emitter_hidden, self.emitter_layers),
            Backbone::Mlp => (128, 2),
        };
        MlpConfig {
            input_dim: self.feature_size(),
            hidden_dim: hidden,
            hidden_layers: layers,
            output_dim: 1,
            skip_layers: vec![],
            hidden_activation: Activation::Relu,
            output_activation: Activation::Sigmoid,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NeuralScene;
    use i2sdf_data::Normalization;
    use i2sdf_nn::{MlpWorkspace, SdfWorkspace};

    /// A small configuration that the edge cases below start from.
    fn small() -> ModelConfig {
        ModelConfig {
            hash_levels: 2,
            hash_log2_table: 10,
            hash_finest_resolution: 32,
            ..Default::default()
        }
    }

    /// Builds the fields and runs the SDF (with gradient), F_c and F_e on a few points.
    fn build_and_query(c: &ModelConfig) {
        let scene = NeuralScene::new(
            c,
            Normalization {
                center: [0.0; 3],
                scale: 1.0,
            },
            1,
        );
        let n = 5;
        let x: Vec<f32> = (0..n * 3).map(|i| (i as f32 * 0.37).sin() * 0.9).collect();
        let (mut d, mut g) = (vec![0.0; n], vec![0.0; n * 3]);
        let mut z = vec![0.0; n * scene.feature_dim()];
        scene
            .sdf
            .forward_with_gradient(&x, &mut SdfWorkspace::default(), &mut d, &mut z, &mut g);
        let dirs: Vec<f32> = (0..n).flat_map(|_| [0.0, 0.0, 1.0]).collect();
        let mut input = Vec::new();
        scene.radiance_input(&z, &dirs, &g, &mut input);
        let mut rgb = vec![0.0; n * 3];
        scene.radiance.forward(&input, &mut MlpWorkspace::default(), &mut rgb);
        let mut e = vec![0.0; n];
        scene.emitter.forward(&z, &mut MlpWorkspace::default(), &mut e);
        assert!(d.iter().chain(&rgb).chain(&e).all(|v| v.is_finite()), "{c:?}");
    }

    /// Every key at the ends of its allowed range builds working fields (no panic in the engine),
    /// and one step past either end is refused with the key named.
    #[test]
    fn every_key_is_checked_at_both_ends_of_its_range() {
        type Edit = fn(&mut ModelConfig);
        let accepted: [(&str, Edit); 16] = [
            ("hash_levels=1", |c| c.hash_levels = 1),
            ("hash_levels=32", |c| {
                c.hash_levels = 32;
                c.hash_finest_resolution = 64
            }),
            ("hash_features=1", |c| c.hash_features = 1),
            ("hash_features=8", |c| c.hash_features = 8),
            ("hash_log2_table=8", |c| c.hash_log2_table = 8),
            ("hash_base_resolution=1", |c| c.hash_base_resolution = 1),
            ("hash_finest_resolution=base", |c| {
                c.hash_finest_resolution = c.hash_base_resolution
            }),
            ("sdf_hidden=1", |c| c.sdf_hidden = 1),
            ("sdf_layers=1", |c| c.sdf_layers = 1),
            ("feature_dim=1", |c| c.feature_dim = 1),
            ("color_layers=1", |c| c.color_layers = 1),
            ("emitter_hidden=1", |c| c.emitter_hidden = 1),
            ("sh_degree=1", |c| c.sh_degree = 1),
            ("sh_degree=4", |c| c.sh_degree = 4),
            ("init_radius=2", |c| c.init_radius = 2.0),
            ("beta_init just above beta_min", |c| c.beta_init = c.beta_min * 1.001),
        ];
        for (what, edit) in accepted {
            let mut c = small();
            edit(&mut c);
            assert!(c.validate().is_ok(), "{what}: {:?}", c.validate());
            build_and_query(&c);
        }
        let rejected: [(&str, Edit); 14] = [
            ("model.hash_levels", |c| c.hash_levels = 0),
            ("model.hash_features", |c| c.hash_features = 3),
            ("model.hash_features", |c| c.hash_features = 0),
            ("model.hash_log2_table", |c| c.hash_log2_table = 25),
            ("model.hash_finest_resolution", |c| {
                c.hash_finest_resolution = c.hash_base_resolution - 1
            }),
            ("2^28", |c| {
                c.hash_levels = 32;
                c.hash_features = 8;
                c.hash_log2_table = 24
            }),
            ("model.sdf_hidden", |c| c.sdf_hidden = 0),
            ("model.sdf_layers", |c| c.sdf_layers = 0),
            ("model.feature_dim", |c| c.feature_dim = 0),
            ("model.color_hidden", |c| c.color_hidden = 0),
            ("model.sh_degree", |c| c.sh_degree = 5),
            ("model.init_radius", |c| c.init_radius = f32::NAN),
            ("model.beta_min", |c| c.beta_min = 0.0),
            ("model.beta_init", |c| c.beta_init = c.beta_min),
        ];
        for (key, edit) in rejected {
            let mut c = small();
            edit(&mut c);
            let e = c.validate().expect_err(key);
            assert!(e.contains(key), "{key}: {e}");
        }
    }
}
