//! The material fields of stage 2 (paper Sec. "Material Field"): F_a gives the diffuse and
//! specular albedos Kd, Ks and F_ρ the roughness ρ at a surface point, the parameters of the
//! supplementary's GGX BRDF that the Monte Carlo re-rendering (eq:render) shades with and that
//! the regularizers of eq:material act on.
//!
//! One module, one MLP with 7 outputs ([`MATERIAL_CHANNELS`]: Kd rgb, Ks rgb, ρ) on one of two
//! backbones ([`MaterialBackbone`]):
//! * [`MaterialBackbone::HashGrid`] (default): the field has its own multiresolution hash grid on
//!   the normalized position, followed by a small MLP. Materials are textures: a hash grid fits
//!   sharp albedo edges in a few thousand iterations, where an MLP on z(x) — a feature trained for
//!   geometry and radiance, frozen in stage 2 — is smooth where the geometry is (a poster on a flat
//!   wall has no geometric feature to key on).
//! * [`MaterialBackbone::FeatureMlp`]: the paper's, MLPs on the frozen SDF feature z(x)
//!   (paper: 3 layers, 64 wide; see [`MaterialConfig::paper`]).
//!
//! The paper has two MLPs, F_a and F_ρ; here one MLP has all 7 outputs (the same inputs, half
//! the matrix products). Output mapping: Kd, Ks = σ(·) ∈ [0, 1]; ρ = ρ_min + (1 − ρ_min)·σ(·) ∈
//! [ρ_min, 1] (the MLP's output activation is the sigmoid; the affine part for ρ and its
//! derivative are applied here). ρ_min keeps α = ρ² away from the delta-like lobes whose
//! importance sampling and pdf are ill-conditioned in single precision.

use crate::config::check;
use i2sdf_nn::mlp_batch::MlpInferWorkspace;
use i2sdf_nn::{Activation, HashGrid, HashGridConfig, HashGridGrad, Mlp, MlpConfig, MlpWorkspace, Parameters};
use serde::{Deserialize, Serialize};

/// Kd (rgb), Ks (rgb), ρ: the outputs per point of [`MaterialField::forward`].
pub const MATERIAL_CHANNELS: usize = 7;

/// The BRDF of one point's [`MATERIAL_CHANNELS`] outputs (Kd rgb, Ks rgb, ρ).
pub fn brdf_of_channels(c: &[f32]) -> i2sdf_render::GgxBrdf {
    use glam::Vec3;
    i2sdf_render::GgxBrdf::new(Vec3::new(c[0], c[1], c[2]), Vec3::new(c[3], c[4], c[5]), c[6])
}

/// Points per block of [`MaterialField::infer`] (bounds its buffers whatever the batch).
pub const MATERIAL_INFER_BLOCK: usize = 1 << 14;

/// What the material MLP reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MaterialBackbone {
    /// Its own multiresolution hash grid on the normalized position + a small MLP: sharp
    /// textures in few iterations.
    #[default]
    HashGrid,
    /// The paper's: MLPs on the frozen SDF feature z(x).
    FeatureMlp,
}

/// Hyper-parameters of the material field (`material.*` keys of the configuration).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaterialConfig {
    pub backbone: MaterialBackbone,
    pub hash_levels: usize,
    pub hash_log2_table: u32,
    pub hash_base_resolution: u32,
    pub hash_finest_resolution: u32,
    pub hidden_dim: usize,
    pub hidden_layers: usize,
    /// Smallest roughness the field can output.
    pub rho_min: f32,
    /// Roughness a fresh field starts at. Moderate by default (0.5): from a rough start a
    /// glossy surface's Ks drains away before its ρ can fall (a wide lobe is only more diffuse
    /// light), and the fit paints the reflections into Kd. Where Ks ends near zero no pixel
    /// depends on ρ; stage 2's roughness prior (`stage2.rho_prior`) then takes it rough.
    pub rho_init: f32,
    /// Specular albedo a fresh field starts at (all three channels): 0.3 by default, so that
    /// every surface starts with a visible lobe and the fit decides where to keep it (matte ones
    /// fall to Ks ≈ 0.01 within the run; from 0.04 glossy ones never rise).
    pub ks_init: f32,
    /// Smallest specular albedo the field can output (all three channels): 0 by default, or a
    /// dielectric's F0 (≈ 0.04) so that no surface is fitted without a lobe. Measured on the
    /// default room: at 0.04 the floor gets its true Ks (0.042 of 0.044) but not its ρ (0.90
    /// with the roughness prior, 1.0 without it, truth 0.5), matte Kd loses 0.3 dB
    /// (docs/results.md, twenty-first session).
    pub ks_min: f32,
}

impl Default for MaterialConfig {
    fn default() -> Self {
        MaterialConfig {
            backbone: MaterialBackbone::HashGrid,
            hash_levels: 16,
            hash_log2_table: 19,
            hash_base_resolution: 16,
            hash_finest_resolution: 128,
            hidden_dim: 64,
            hidden_layers: 2,
            rho_min: 0.05,
            rho_init: 0.5,
            ks_init: 0.3,
            ks_min: 0.0,
        }
    }
}

impl MaterialConfig {
    /// The paper's material fields: MLPs on z(x), 3 hidden layers of 64.
    pub fn paper() -> Self {
        MaterialConfig {
            backbone: MaterialBackbone::FeatureMlp,
            hidden_layers: 3,
            ..Default::default()
        }
    }

    /// Range checks; the message names the key and the allowed range.
    pub fn check(&self) -> Result<(), String> {
        if self.backbone == MaterialBackbone::HashGrid {
            check::int("material.hash_levels", self.hash_levels, 1, 32)?;
            check::int("material.hash_log2_table", self.hash_log2_table, 8, 24)?;
            check::int("material.hash_base_resolution", self.hash_base_resolution, 1, 4096)?;
            check::int(
                "material.hash_finest_resolution",
                self.hash_finest_resolution,
                self.hash_base_resolution,
                1 << 16,
            )?;
        }
        check::int("material.hidden_dim", self.hidden_dim, 8, 256)?;
        check::int("material.hidden_layers", self.hidden_layers, 1, 8)?;
        check::real("material.rho_min", self.rho_min, 0.0, 0.5)?;
        check::real("material.rho_init", self.rho_init, self.rho_min as f64 + 0.01, 0.99)?;
        check::real("material.ks_min", self.ks_min, 0.0, 0.2)?;
        check::real("material.ks_init", self.ks_init, self.ks_min as f64 + 0.01, 0.99)?;
        Ok(())
    }

    fn grid_config(&self) -> HashGridConfig {
        HashGridConfig {
            levels: self.hash_levels,
            features_per_level: 2,
            log2_table_size: self.hash_log2_table,
            base_resolution: self.hash_base_resolution,
            finest_resolution: self.hash_finest_resolution,
            bound: 1.0,
        }
    }
}

/// F_a and F_ρ: an optional hash grid (the [`MaterialBackbone::HashGrid`] backbone) and the MLP.
#[derive(Clone, Debug)]
pub struct MaterialField {
    pub config: MaterialConfig,
    pub grid: Option<HashGrid>,
    pub mlp: Mlp,
}

/// Gradients of a [`MaterialField`]'s parameters (layouts of `grid.params` and `mlp.params`).
pub struct MaterialGrad {
    pub grid: Option<HashGridGrad>,
    pub mlp: Vec<f32>,
}

/// What [`MaterialField::backward`] needs from the last [`MaterialField::forward`], and the
/// buffers of both, reused across steps (they only grow).
#[derive(Default)]
pub struct MaterialWorkspace {
    n: usize,
    positions: Vec<f32>,
    /// Hash encoding, level-major (`levels × n × F`), as the grid writes it.
    enc: Vec<f32>,
    /// The MLP's input rows (`n × levels·F`).
    input: Vec<f32>,
    /// Sigmoid outputs of the MLP (`n × 7`) and their cotangent.
    sig: Vec<f32>,
    d_sig: Vec<f32>,
    d_input: Vec<f32>,
    d_enc: Vec<f32>,
    mlp: MlpWorkspace,
}

/// Buffers of [`MaterialField::infer_with`]: one block's worth, whatever the batch.
#[derive(Default)]
pub struct MaterialInferWorkspace {
    enc: Vec<f32>,
    input: Vec<f32>,
    mlp: MlpInferWorkspace,
}

impl MaterialInferWorkspace {
    /// A workspace for a field whose weights do not change while it is used (kept beside a
    /// shared borrow of it): the MLP's transposed weights are made once per task, not per call
    /// ([`MlpInferWorkspace::for_fixed_weights`]).
    pub fn for_fixed_weights() -> Self {
        MaterialInferWorkspace {
            enc: Vec::new(),
            input: Vec::new(),
            mlp: MlpInferWorkspace::for_fixed_weights(),
        }
    }
}

/// logit(p) = ln(p / (1 − p)).
fn logit(p: f32) -> f32 {
    (p / (1.0 - p)).ln()
}

/// Level-major `[L][n][F]` → row-major `[n][L·F]`.
fn level_to_rows(enc: &[f32], n: usize, levels: usize, f: usize, rows: &mut [f32]) {
    let w = levels * f;
    for l in 0..levels {
        let src = &enc[l * n * f..(l + 1) * n * f];
        for i in 0..n {
            rows[i * w + l * f..i * w + l * f + f].copy_from_slice(&src[i * f..i * f + f]);
        }
    }
}

/// Row-major `[n][L·F]` → level-major `[L][n][F]`.
fn rows_to_level(rows: &[f32], n: usize, levels: usize, f: usize, enc: &mut [f32]) {
    let w = levels * f;
    for l in 0..levels {
        let dst = &mut enc[l * n * f..(l + 1) * n * f];
        for i in 0..n {
            dst[i * f..i * f + f].copy_from_slice(&rows[i * w + l * f..i * w + l * f + f]);
        }
    }
}

impl MaterialField {
    /// A fresh field. `feature_dim` is the SDF feature width (read only by the FeatureMlp
    /// backbone). Initialisation, seeded: the last layer's weights are scaled by 0.1 and its
    /// biases set so that the field starts nearly uniform at Kd ≈ 0.5, Ks ≈ `ks_init`, ρ ≈
    /// `rho_init` (0.3 and 0.5 by default: see those keys). The sigmoid's slope is largest at 0.5,
    /// so Kd can move either way quickly.
    pub fn new(config: &MaterialConfig, feature_dim: usize, seed: u64) -> Self {
        let grid = (config.backbone == MaterialBackbone::HashGrid).then(|| HashGrid::new(config.grid_config(), seed));
        let input_dim = match &grid {
            Some(g) => g.output_dim(),
            None => feature_dim,
        };
        let mut mlp = Mlp::new(
            MlpConfig {
                input_dim,
                hidden_dim: config.hidden_dim,
                hidden_layers: config.hidden_layers,
                output_dim: MATERIAL_CHANNELS,
                skip_layers: Vec::new(),
                hidden_activation: Activation::Relu,
                output_activation: Activation::Sigmoid,
            },
            seed.wrapping_add(17),
        );
        let last = mlp.layers.last().unwrap().clone();
        for w in &mut mlp.params[last.weight_offset..last.bias_offset] {
            *w *= 0.1;
        }
        let rho_s = ((config.rho_init - config.rho_min) / (1.0 - config.rho_min)).clamp(0.01, 0.99);
        let ks = logit(((config.ks_init - config.ks_min) / (1.0 - config.ks_min)).clamp(0.01, 0.99));
        let bias = [0.0, 0.0, 0.0, ks, ks, ks, logit(rho_s)];
        mlp.params[last.bias_offset..last.bias_offset + MATERIAL_CHANNELS].copy_from_slice(&bias);
        MaterialField {
            config: config.clone(),
            grid,
            mlp,
        }
    }

    pub fn new_grad(&self) -> MaterialGrad {
        MaterialGrad {
            grid: self.grid.as_ref().map(HashGridGrad::new),
            mlp: vec![0.0; self.mlp.params.len()],
        }
    }

    fn feature_dim_in(&self) -> usize {
        self.mlp.input_dim()
    }

    /// Sigmoid outputs → Kd, Ks, ρ (in place).
    fn map_outputs(&self, out: &mut [f32]) {
        let (r, k) = (self.config.rho_min, self.config.ks_min);
        for px in out.chunks_exact_mut(MATERIAL_CHANNELS) {
            for ks in &mut px[3..6] {
                *ks = k + (1.0 - k) * *ks;
            }
            px[6] = r + (1.0 - r) * px[6];
        }
    }

    /// Kd, Ks, ρ at `n` points for training. `positions`: `[n×3]` in the normalized frame (read
    /// by the hash grid); `features`: `[n×feature_dim]` (read only by FeatureMlp; may be empty
    /// for HashGrid). `out`: `[n×7]` = Kd, Ks ∈ [0, 1], ρ ∈ [ρ_min, 1]. Keeps what
    /// [`MaterialField::backward`] needs in `ws`.
    pub fn forward(&self, positions: &[f32], features: &[f32], ws: &mut MaterialWorkspace, out: &mut [f32]) {
        let n = positions.len() / 3;
        ws.n = n;
        assert!(out.len() >= n * MATERIAL_CHANNELS);
        let out = &mut out[..n * MATERIAL_CHANNELS];
        match &self.grid {
            Some(g) => {
                let (levels, f) = (g.config.levels, g.config.features_per_level);
                ws.positions.clear();
                ws.positions.extend_from_slice(&positions[..n * 3]);
                ws.enc.resize(levels * n * f, 0.0);
                g.encode(&ws.positions, &mut ws.enc, None);
                ws.input.resize(n * levels * f, 0.0);
                level_to_rows(&ws.enc, n, levels, f, &mut ws.input);
                self.mlp.forward(&ws.input, &mut ws.mlp, out);
            }
            None => {
                let d = self.feature_dim_in();
                assert!(features.len() >= n * d, "FeatureMlp needs [n × {d}] features");
                self.mlp.forward(&features[..n * d], &mut ws.mlp, out);
            }
        }
        ws.sig.clear();
        ws.sig.extend_from_slice(out);
        self.map_outputs(out);
    }

    /// Accumulates into `grad` dL/dparams for `d_out` = dL/dout (`[n×7]`) of the last
    /// [`MaterialField::forward`] on `ws`. (The features are frozen in stage 2: no cotangent
    /// flows back into z.)
    pub fn backward(&self, ws: &mut MaterialWorkspace, d_out: &[f32], grad: &mut MaterialGrad) {
        let n = ws.n;
        assert!(d_out.len() >= n * MATERIAL_CHANNELS);
        let scale = 1.0 - self.config.rho_min;
        ws.d_sig.clear();
        ws.d_sig.extend_from_slice(&d_out[..n * MATERIAL_CHANNELS]);
        let ks_scale = 1.0 - self.config.ks_min;
        for px in ws.d_sig.chunks_exact_mut(MATERIAL_CHANNELS) {
            px[3..6].iter_mut().for_each(|d| *d *= ks_scale);
            px[6] *= scale;
        }
        match &self.grid {
            Some(g) => {
                let (levels, f) = (g.config.levels, g.config.features_per_level);
                ws.d_input.resize(n * levels * f, 0.0);
                self.mlp
                    .backward(&mut ws.mlp, &ws.d_sig, &mut grad.mlp, Some(&mut ws.d_input));
                ws.d_enc.resize(levels * n * f, 0.0);
                rows_to_level(&ws.d_input, n, levels, f, &mut ws.d_enc);
                let gg = grad.grid.as_mut().expect("MaterialGrad of another field");
                g.backward(&ws.positions, &ws.d_enc, None, None, gg);
            }
            None => self.mlp.backward(&mut ws.mlp, &ws.d_sig, &mut grad.mlp, None),
        }
    }

    /// Inference (equal to [`MaterialField::forward`], no stored activations), in blocks of
    /// [`MATERIAL_INFER_BLOCK`] points so memory is bounded whatever `n`. Takes `&self` and a
    /// fresh workspace per call, so any number of threads may call it at once (the integrator's
    /// rows do); the cost is a few block-sized allocations per call — callers that query often
    /// from one thread keep a [`MaterialInferWorkspace`] and call [`MaterialField::infer_with`].
    pub fn infer(&self, positions: &[f32], features: &[f32], out: &mut [f32]) {
        self.infer_with(positions, features, &mut MaterialInferWorkspace::default(), out)
    }

    /// [`MaterialField::infer`] with caller-kept buffers (no allocation once grown).
    pub fn infer_with(&self, positions: &[f32], features: &[f32], ws: &mut MaterialInferWorkspace, out: &mut [f32]) {
        let n = positions.len() / 3;
        assert!(out.len() >= n * MATERIAL_CHANNELS);
        let c = MATERIAL_CHANNELS;
        for b0 in (0..n).step_by(MATERIAL_INFER_BLOCK) {
            let m = MATERIAL_INFER_BLOCK.min(n - b0);
            let o = &mut out[b0 * c..(b0 + m) * c];
            match &self.grid {
                Some(g) => {
                    let (levels, f) = (g.config.levels, g.config.features_per_level);
                    ws.enc.resize(levels * m * f, 0.0);
                    g.encode(&positions[b0 * 3..(b0 + m) * 3], &mut ws.enc, None);
                    ws.input.resize(m * levels * f, 0.0);
                    level_to_rows(&ws.enc, m, levels, f, &mut ws.input);
                    self.mlp.infer(&ws.input, &mut ws.mlp, o);
                }
                None => {
                    let d = self.feature_dim_in();
                    assert!(features.len() >= n * d, "FeatureMlp needs [n × {d}] features");
                    self.mlp.infer(&features[b0 * d..(b0 + m) * d], &mut ws.mlp, o);
                }
            }
            self.map_outputs(o);
        }
    }
}

/// Tensors `{prefix}.grid.table` (HashGrid backbone) and `{prefix}.mlp.layers.*`.
impl Parameters for MaterialField {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        if let Some(g) = &self.grid {
            g.visit(&format!("{prefix}.grid"), f);
        }
        self.mlp.visit(&format!("{prefix}.mlp"), f);
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        if let Some(g) = &mut self.grid {
            g.visit_mut(&format!("{prefix}.grid"), f);
        }
        self.mlp.visit_mut(&format!("{prefix}.mlp"), f);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_nn::params::{load_modules, ModuleSlot};
    use i2sdf_nn::save_safetensors;
    use rand::{Rng, SeedableRng};

    fn small(backbone: MaterialBackbone) -> MaterialConfig {
        MaterialConfig {
            backbone,
            hash_levels: 3,
            hash_log2_table: 8,
            hash_base_resolution: 2,
            hash_finest_resolution: 8,
            hidden_dim: 16,
            hidden_layers: 2,
            rho_min: 0.05,
            rho_init: 0.9,
            ks_init: 0.04,
            // Non-zero so that the gradient checks cover the floor's scaling.
            ks_min: 0.02,
        }
    }

    const FD: usize = 5;

    fn inputs(n: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let pos = (0..n * 3).map(|_| rng.gen_range(-0.9f32..0.9)).collect();
        let feat = (0..n * FD).map(|_| rng.gen_range(-1.5f32..1.5)).collect();
        (pos, feat)
    }

    /// L = Σ w·out in f64.
    fn loss(field: &MaterialField, pos: &[f32], feat: &[f32], w: &[f32]) -> f64 {
        let mut out = vec![0.0; w.len()];
        field.forward(pos, feat, &mut MaterialWorkspace::default(), &mut out);
        out.iter().zip(w).map(|(a, b)| *a as f64 * *b as f64).sum()
    }

    /// The backward of the whole field (hash table and MLP, both backbones) against central
    /// differences of L = Σ w·out along random directions in each parameter block.
    #[test]
    fn gradient_matches_finite_differences() {
        for backbone in [MaterialBackbone::HashGrid, MaterialBackbone::FeatureMlp] {
            let mut field = MaterialField::new(&small(backbone), FD, 3);
            let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(9);
            // Larger-than-init values, so that every parameter carries signal.
            if let Some(g) = &mut field.grid {
                g.params.iter_mut().for_each(|v| *v = rng.gen_range(-0.5..0.5));
            }
            field.mlp.params.iter_mut().for_each(|v| *v += rng.gen_range(-0.2..0.2));
            let n = 40;
            let (pos, feat) = inputs(n, 4);
            let w: Vec<f32> = (0..n * MATERIAL_CHANNELS).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let mut ws = MaterialWorkspace::default();
            let mut out = vec![0.0; n * MATERIAL_CHANNELS];
            field.forward(&pos, &feat, &mut ws, &mut out);
            let mut grad = field.new_grad();
            field.backward(&mut ws, &w, &mut grad);
            let h = 1e-3f32;
            for block in 0..2 {
                if block == 0 && field.grid.is_none() {
                    assert!(grad.grid.is_none());
                    continue;
                }
                for trial in 0..if block == 0 { 4 } else { 40 } {
                    let len = if block == 0 {
                        field.grid.as_ref().unwrap().params.len()
                    } else {
                        field.mlp.params.len()
                    };
                    // The table enters linearly before the MLP: a random direction over all of
                    // it. MLP parameters one at a time (a direction over all of them moves every
                    // ReLU's pre-activation at once and crosses kinks).
                    let v: Vec<f32> = if block == 0 {
                        (0..len).map(|_| rng.gen_range(-1.0..1.0)).collect()
                    } else {
                        let k = rng.gen_range(0..len);
                        (0..len).map(|i| if i == k { 1.0 } else { 0.0 }).collect()
                    };
                    let g = if block == 0 {
                        &grad.grid.as_ref().unwrap().values
                    } else {
                        &grad.mlp
                    };
                    let analytic: f64 = g.iter().zip(&v).map(|(a, b)| *a as f64 * *b as f64).sum();
                    let at = |s: f32| {
                        let mut f2 = field.clone();
                        let p = if block == 0 {
                            &mut f2.grid.as_mut().unwrap().params
                        } else {
                            &mut f2.mlp.params
                        };
                        p.iter_mut().zip(&v).for_each(|(p, d)| *p += s * d);
                        loss(&f2, &pos, &feat, &w)
                    };
                    let fd = (at(h) - at(-h)) / (2.0 * h as f64);
                    let err = (analytic - fd).abs();
                    assert!(
                        err <= 2e-2 * fd.abs().max(analytic.abs()) + 2e-3,
                        "{backbone:?} block {block} trial {trial}: analytic {analytic} vs fd {fd}"
                    );
                }
            }
        }
    }

    /// Inference equals the training forward (across a block boundary), the outputs are in
    /// range, and a fresh field starts near Kd 0.5, Ks = ks_init, ρ = rho_init.
    #[test]
    fn infer_equals_forward_and_starts_grey() {
        for backbone in [MaterialBackbone::HashGrid, MaterialBackbone::FeatureMlp] {
            let field = MaterialField::new(&small(backbone), FD, 5);
            let n = MATERIAL_INFER_BLOCK + 37;
            let (pos, feat) = inputs(n, 6);
            let mut a = vec![0.0; n * MATERIAL_CHANNELS];
            let mut b = vec![1.0; n * MATERIAL_CHANNELS];
            field.forward(&pos, &feat, &mut MaterialWorkspace::default(), &mut a);
            field.infer(&pos, &feat, &mut b);
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() <= 1e-6, "{x} vs {y}");
            }
            for px in a.chunks_exact(MATERIAL_CHANNELS) {
                assert!(px[..6].iter().all(|v| (0.0..=1.0).contains(v)));
                assert!((0.05..=1.0).contains(&px[6]));
                assert!((px[0] - 0.5).abs() < 0.1 && (px[3] - 0.04).abs() < 0.03, "{px:?}");
                assert!((px[6] - 0.9).abs() < 0.1, "{px:?}");
            }
        }
    }

    /// save_safetensors / load_modules round trip; tensors under `grid.` and `mlp.`.
    #[test]
    fn save_load_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.safetensors");
        let mut a = MaterialField::new(&small(MaterialBackbone::HashGrid), FD, 1);
        a.grid.as_mut().unwrap().params[5] = 0.25;
        let mut names = Vec::new();
        a.visit("material", &mut |n, _, _| names.push(n));
        assert_eq!(names[0], "material.grid.table");
        assert!(names[1..].iter().all(|n| n.starts_with("material.mlp.layers.")));
        save_safetensors(&p, &[("material", &a)], None).unwrap();
        let mut b = MaterialField::new(&small(MaterialBackbone::HashGrid), FD, 2);
        assert_ne!(a.mlp.params, b.mlp.params);
        let mut slots = [ModuleSlot {
            prefix: "material",
            module: &mut b,
            required: true,
        }];
        load_modules(&p, &mut slots, None).unwrap();
        assert_eq!(a.mlp.params, b.mlp.params);
        assert_eq!(a.grid.unwrap().params, b.grid.unwrap().params);
    }

    #[test]
    fn config_checks_name_the_key() {
        assert!(MaterialConfig::default().check().is_ok());
        assert!(MaterialConfig::paper().check().is_ok());
        let e = MaterialConfig {
            hidden_dim: 4,
            ..Default::default()
        }
        .check()
        .unwrap_err();
        assert!(e.contains("material.hidden_dim") && e.contains("8..=256"), "{e}");
        let c: MaterialConfig = serde_json::from_str(r#"{"backbone": "feature_mlp"}"#).unwrap();
        assert_eq!(c.backbone, MaterialBackbone::FeatureMlp);
        assert_eq!(c.hidden_dim, 64);
    }
}
