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

impl ModelConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.init_radius > 0.0) {
            return Err("model.init_radius must be positive".into());
        }
        if !(self.beta_init > self.beta_min && self.beta_min > 0.0) {
            return Err("model.beta_init must exceed model.beta_min > 0".into());
        }
        if !(1..=4).contains(&self.sh_degree) {
            return Err("model.sh_degree must be 1..=4".into());
        }
        if self.feature_dim == 0 {
            return Err("model.feature_dim must be positive".into());
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
