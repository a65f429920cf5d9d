//! Inference on a trained scene at arbitrary points — the queries of `render`, `mesh`, the ray
//! caster and (stage 2) the secondary rays, which make millions of them: no training workspace,
//! no stored activations, and no allocation per call once the buffers have grown.
//!
//! Measured on the default backbone (16-level hash grid, 2^19 entries, 64-wide MLPs; 1 M random
//! points, the 2 cores shared with other builds): distances 1.6 M points/s (the training forward,
//! which stores every activation for a backward, 0.9 M points/s); distances + ∇d 0.8 M points/s;
//! F_c at arbitrary points (z, ∇d, F_c) 0.7 M points/s (`query_speed`, ignored).

use crate::scene::NeuralScene;
use i2sdf_nn::mlp_batch::MlpInferWorkspace;
use i2sdf_nn::sdf::SdfInferWorkspace;

/// Points per internal block of the queries that chain F_d into F_c (bounds their buffers).
pub const QUERY_BLOCK: usize = 1 << 14;

/// Reusable inference buffers over one scene. Not `Sync`: one per thread (each call is already
/// parallel over its points).
pub struct SceneQuery<'a> {
    pub scene: &'a NeuralScene,
    sdf_ws: SdfInferWorkspace,
    mlp_ws: MlpInferWorkspace,
    /// F_e's own buffers: F_c and F_e alternate in a re-render, and one workspace would be
    /// rebuilt at every switch.
    emitter_ws: MlpInferWorkspace,
    feature: Vec<f32>,
    gradient: Vec<f32>,
    dist: Vec<f32>,
    input: Vec<f32>,
    enc: Vec<f32>,
}

impl<'a> SceneQuery<'a> {
    pub fn new(scene: &'a NeuralScene) -> Self {
        SceneQuery {
            scene,
            sdf_ws: SdfInferWorkspace::default(),
            mlp_ws: MlpInferWorkspace::default(),
            emitter_ws: MlpInferWorkspace::default(),
            feature: Vec::new(),
            gradient: Vec::new(),
            dist: Vec::new(),
            input: Vec::new(),
            enc: Vec::new(),
        }
    }

    /// Buffers that keep the networks' transposed weights between calls: for a holder that
    /// keeps the query beside its shared borrow of the scene, whose weights therefore cannot
    /// change while it is used ([`SdfInferWorkspace::for_fixed_weights`]).
    pub fn for_fixed_weights(scene: &'a NeuralScene) -> Self {
        SceneQuery {
            sdf_ws: SdfInferWorkspace::for_fixed_weights(),
            mlp_ws: MlpInferWorkspace::for_fixed_weights(),
            emitter_ws: MlpInferWorkspace::for_fixed_weights(),
            ..SceneQuery::new(scene)
        }
    }

    /// Signed distances at `points` (`[n×3]`, normalized frame) into `sdf` (`[n]`).
    pub fn sdf(&mut self, points: &[f32], sdf: &mut [f32]) {
        self.scene.sdf.infer(points, &mut self.sdf_ws, sdf, None, None);
    }

    /// Distances and ∇d (`[n×3]`, unnormalized normals).
    pub fn sdf_gradient(&mut self, points: &[f32], sdf: &mut [f32], gradient: &mut [f32]) {
        self.scene
            .sdf
            .infer(points, &mut self.sdf_ws, sdf, None, Some(gradient));
    }

    /// Distance and feature z (`[n × feature_dim]`) at `points`, without the gradient's backward
    /// pass (what F_e and the material backbone need).
    pub fn sdf_feature(&mut self, points: &[f32], sdf: &mut [f32], feature: &mut [f32]) {
        self.scene.sdf.infer(points, &mut self.sdf_ws, sdf, Some(feature), None);
    }

    /// Distance, feature z (`[n × feature_dim]`) and gradient at `points`.
    pub fn sdf_full(&mut self, points: &[f32], sdf: &mut [f32], feature: &mut [f32], gradient: &mut [f32]) {
        self.scene
            .sdf
            .infer(points, &mut self.sdf_ws, sdf, Some(feature), Some(gradient));
    }

    /// F_c at points whose features and gradients are already computed: `dirs` are the unit
    /// directions of the rays arriving there (`[n×3]`), `rgb` is `[n×3]`.
    pub fn radiance(&mut self, features: &[f32], dirs: &[f32], gradients: &[f32], rgb: &mut [f32]) {
        self.scene
            .radiance_input_into(features, dirs, gradients, &mut self.enc, &mut self.input);
        self.scene.radiance.infer(&self.input, &mut self.mlp_ws, rgb);
    }

    /// F_c at arbitrary points seen along `dirs`: F_d (feature and ∇d) then F_c, in blocks of
    /// [`QUERY_BLOCK`] points.
    pub fn radiance_at(&mut self, points: &[f32], dirs: &[f32], rgb: &mut [f32]) {
        let n = points.len() / 3;
        let fd = self.scene.feature_dim();
        for b0 in (0..n).step_by(QUERY_BLOCK) {
            let m = QUERY_BLOCK.min(n - b0);
            let (mut feature, mut gradient, mut dist) = (
                std::mem::take(&mut self.feature),
                std::mem::take(&mut self.gradient),
                std::mem::take(&mut self.dist),
            );
            feature.resize(m * fd, 0.0);
            gradient.resize(m * 3, 0.0);
            dist.resize(m, 0.0);
            self.sdf_full(&points[b0 * 3..(b0 + m) * 3], &mut dist, &mut feature, &mut gradient);
            self.radiance(
                &feature,
                &dirs[b0 * 3..(b0 + m) * 3],
                &gradient,
                &mut rgb[b0 * 3..(b0 + m) * 3],
            );
            (self.feature, self.gradient, self.dist) = (feature, gradient, dist);
        }
    }

    /// F_e at points with features already computed: `prob` is `[n]`.
    pub fn emitter(&mut self, features: &[f32], prob: &mut [f32]) {
        self.scene.emitter.infer(features, &mut self.emitter_ws, prob);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ModelConfig;
    use i2sdf_data::Normalization;
    use i2sdf_nn::{MlpWorkspace, SdfWorkspace};

    /// The queries equal the training forward passes (renderer path) on the same points.
    #[test]
    fn queries_match_the_training_forward() {
        let c = ModelConfig {
            hash_levels: 4,
            hash_log2_table: 12,
            hash_finest_resolution: 64,
            ..Default::default()
        };
        let scene = NeuralScene::new(
            &c,
            Normalization {
                center: [0.0; 3],
                scale: 1.0,
            },
            4,
        );
        let n = QUERY_BLOCK + 300;
        let pts: Vec<f32> = (0..n * 3).map(|i| ((i as f32) * 0.618).sin() * 0.9).collect();
        let dirs: Vec<f32> = (0..n)
            .flat_map(|i| {
                let a = i as f32 * 0.1;
                [a.cos() * 0.6, a.sin() * 0.6, 0.8]
            })
            .collect();
        let fd = scene.feature_dim();
        let (mut d0, mut z0, mut g0) = (vec![0.0; n], vec![0.0; n * fd], vec![0.0; n * 3]);
        scene
            .sdf
            .forward_with_gradient(&pts, &mut SdfWorkspace::default(), &mut d0, &mut z0, &mut g0);
        let mut input = Vec::new();
        scene.radiance_input(&z0, &dirs, &g0, &mut input);
        let mut rgb0 = vec![0.0; n * 3];
        scene.radiance.forward(&input, &mut MlpWorkspace::default(), &mut rgb0);
        let mut q = SceneQuery::new(&scene);
        let mut d1 = vec![0.0; n];
        q.sdf(&pts, &mut d1);
        assert_eq!(d0, d1);
        let mut rgb1 = vec![0.0; n * 3];
        q.radiance_at(&pts, &dirs, &mut rgb1);
        for (a, b) in rgb0.iter().zip(&rgb1) {
            assert!((a - b).abs() <= 1e-6, "{a} vs {b}");
        }
        let (mut e0, mut e1) = (vec![0.0; n], vec![0.0; n]);
        scene.emitter.forward(&z0, &mut MlpWorkspace::default(), &mut e0);
        q.emitter(&z0, &mut e1);
        assert_eq!(e0, e1);
    }

    /// Points per second of the distance-only and the full (z, ∇d, F_c) queries, printed with
    /// `--nocapture` (a figure for the docs, not an assertion).
    #[test]
    #[ignore]
    fn query_speed() {
        let scene = NeuralScene::new(
            &ModelConfig::default(),
            Normalization {
                center: [0.0; 3],
                scale: 1.0,
            },
            4,
        );
        let n = 1 << 20;
        let pts: Vec<f32> = (0..n * 3).map(|i| ((i as f32) * 0.618).sin() * 0.9).collect();
        let dirs: Vec<f32> = (0..n).flat_map(|_| [0.0f32, 0.6, 0.8]).collect();
        let mut q = SceneQuery::new(&scene);
        let mut d = vec![0.0; n];
        let mut g = vec![0.0; n * 3];
        let mut rgb = vec![0.0; n * 3];
        q.sdf(&pts[..QUERY_BLOCK * 3], &mut d[..QUERY_BLOCK]);
        let rate = |t: std::time::Instant| n as f64 / t.elapsed().as_secs_f64() / 1e6;
        let t = std::time::Instant::now();
        q.sdf(&pts, &mut d);
        eprintln!("sdf: {:.2} M points/s", rate(t));
        let t = std::time::Instant::now();
        q.sdf_gradient(&pts, &mut d, &mut g);
        eprintln!("sdf + gradient: {:.2} M points/s", rate(t));
        let t = std::time::Instant::now();
        q.radiance_at(&pts, &dirs, &mut rgb);
        eprintln!("radiance_at (z, gradient, F_c): {:.2} M points/s", rate(t));
        // The training forward for comparison.
        let fd = scene.feature_dim();
        let mut z = vec![0.0; n * fd];
        let mut ws = SdfWorkspace::default();
        let t = std::time::Instant::now();
        scene.sdf.forward(&pts, &mut ws, &mut d, &mut z);
        eprintln!(
            "training forward: {:.2} M points/s",
            n as f64 / t.elapsed().as_secs_f64() / 1e6
        );
    }
}
