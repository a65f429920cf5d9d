//! Per-camera pose correction learned in stage 1 (as nerfstudio's camera optimizer): each training
//! view gets a small rotation ω (axis × angle, radians, about its camera centre) and translation τ
//! (normalized units), applied to its rays as o' = o + τ, d' = R(ω) d. Poses from ARKit or SfM
//! are off by millimetres and tenths of a degree; this absorbs it instead of blurring the fields.
//!
//! The gradient comes from the rendering losses of the batch's rays: with a sample at
//! x = o' + t d' (t fixed, as the samples are placed without gradient), ∂L/∂τ = Σ ∂L/∂x and
//! ∂L/∂ω = Σ t d' × ∂L/∂x, ∂L/∂x being the SDF network's position gradient
//! ([`i2sdf_nn::SdfNetwork::position_gradient`]). The point losses (bubble, smoothness) move with
//! the corrected rays but do not steer the correction. A quadratic penalty pulls ω and τ towards
//! zero, so views the data cannot place stay where the dataset put them.

use crate::config::{PoseConfig, PoseCorrectionMode};
use i2sdf_data::{Dataset, Normalization};
use i2sdf_nn::params::Parameters;
use i2sdf_nn::{Adam, AdamConfig, LrSchedule};

/// The learned corrections of every training view, with their optimizer.
pub struct PoseCorrection {
    /// Per training image: [ω (3), τ (3)].
    pub delta: Vec<[f32; 6]>,
    adam: Adam,
    grad: Vec<f32>,
    config: PoseConfig,
    /// The first iteration that updates the corrections.
    start: u64,
}

impl PoseCorrection {
    /// `None` when the correction is off (by the key, or `auto` on a dataset that declares its
    /// poses exact).
    pub fn new(
        dataset: &Dataset,
        config: &PoseConfig,
        hash_grid: bool,
        images: usize,
        iterations: u64,
    ) -> Option<Self> {
        let on = match config.correction {
            PoseCorrectionMode::Off => false,
            PoseCorrectionMode::On => true,
            // The paper's MLP backbone keeps no encoding Jacobian to take the gradient from.
            PoseCorrectionMode::Auto => !dataset.poses_exact && hash_grid,
        };
        if !on || images == 0 {
            return None;
        }
        let mut adam = Adam::new(AdamConfig::default());
        // One group for rotations and one for translations: their units differ.
        adam.add_group("pose_rotation", images * 3, config.lr_rotation, LrSchedule::Constant);
        adam.add_group(
            "pose_translation",
            images * 3,
            config.lr_translation,
            LrSchedule::Constant,
        );
        Some(PoseCorrection {
            delta: vec![[0.0; 6]; images],
            adam,
            grad: vec![0.0; images * 6],
            config: config.clone(),
            start: (config.start * iterations as f32) as u64,
        })
    }

    pub fn active(&self, iteration: u64) -> bool {
        iteration >= self.start
    }

    /// The rotation and translation of image `i`.
    pub fn transform(&self, i: usize) -> ([[f32; 3]; 3], [f32; 3]) {
        let d = &self.delta[i];
        (rotation_matrix([d[0], d[1], d[2]]), [d[3], d[4], d[5]])
    }

    /// Adds a ray's gradient: `g_origin` = Σ ∂L/∂x over its samples, `g_dir` = Σ t ∂L/∂x, and
    /// `dir` its corrected direction.
    pub fn add_ray_gradient(&mut self, image: usize, dir: [f32; 3], g_origin: [f32; 3], g_dir: [f32; 3]) {
        // d' = R(ω) d; a change δω rotates d' by δω × d', so ∂L/∂ω = d' × ∂L/∂d'.
        let c = cross(dir, g_dir);
        let g = &mut self.grad[image * 6..image * 6 + 6];
        for k in 0..3 {
            g[k] += c[k];
            g[3 + k] += g_origin[k];
        }
    }

    /// One Adam step on the accumulated gradients plus the penalty's; clears them.
    pub fn step(&mut self) {
        let n = self.delta.len();
        let (mut rot, mut trans) = (vec![0.0f32; n * 3], vec![0.0f32; n * 3]);
        let (mut g_rot, mut g_trans) = (vec![0.0f32; n * 3], vec![0.0f32; n * 3]);
        for i in 0..n {
            for k in 0..3 {
                rot[i * 3 + k] = self.delta[i][k];
                trans[i * 3 + k] = self.delta[i][3 + k];
                // d/dω of λ‖ω‖² (and the same for τ).
                g_rot[i * 3 + k] = self.grad[i * 6 + k] + 2.0 * self.config.regularization * self.delta[i][k];
                g_trans[i * 3 + k] = self.grad[i * 6 + 3 + k] + 2.0 * self.config.regularization * self.delta[i][3 + k];
            }
        }
        self.adam.begin_step();
        self.adam.update(0, &mut rot, &mut g_rot);
        self.adam.update(1, &mut trans, &mut g_trans);
        for i in 0..n {
            for k in 0..3 {
                self.delta[i][k] = rot[i * 3 + k];
                self.delta[i][3 + k] = trans[i * 3 + k];
            }
        }
        self.grad.fill(0.0);
    }

    /// The corrected camera-to-world pose of a view in world units: the rotation about its
    /// camera centre, the translation scaled out of the normalized frame.
    pub fn corrected_c2w(&self, i: usize, c2w: glam::DMat4, norm: &Normalization) -> glam::DMat4 {
        let (r, t) = self.transform(i);
        let r = glam::DMat3::from_cols_array_2d(&r.map(|row| row.map(f64::from))).transpose();
        let rot = r * glam::DMat3::from_mat4(c2w);
        let centre = c2w.w_axis.truncate() + glam::DVec3::from(t.map(f64::from)) * norm.scale;
        glam::DMat4::from_cols(
            rot.x_axis.extend(0.0),
            rot.y_axis.extend(0.0),
            rot.z_axis.extend(0.0),
            centre.extend(1.0),
        )
    }
}

/// The checkpoint tensors: `{prefix}.delta`, and Adam's moments and step as `{prefix}.m` /
/// `.v` / `.step` (under the optimizer's prefix, so inference loads skip them).
impl Parameters for PoseCorrection {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        let n = self.delta.len();
        f(format!("{prefix}.delta"), vec![n, 6], self.delta.as_flattened());
        for (k, g) in self.adam.groups.iter().enumerate() {
            let (m, v) = self.adam.moments(k);
            f(format!("{prefix}.{}.m", g.name), vec![m.len()], m);
            f(format!("{prefix}.{}.v", g.name), vec![v.len()], v);
        }
        f(format!("{prefix}.step"), vec![1], &[self.adam.step as f32]);
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        let n = self.delta.len();
        f(format!("{prefix}.delta"), vec![n, 6], self.delta.as_flattened_mut());
        let names: Vec<String> = self.adam.groups.iter().map(|g| g.name.clone()).collect();
        for (k, name) in names.iter().enumerate() {
            let (m, v) = self.adam.moments_mut(k);
            f(format!("{prefix}.{name}.m"), vec![m.len()], m);
            f(format!("{prefix}.{name}.v"), vec![v.len()], v);
        }
        let mut step = [self.adam.step as f32];
        f(format!("{prefix}.step"), vec![1], &mut step);
        self.adam.step = step[0] as u64;
    }
}

/// Rodrigues' formula: the rotation by |ω| about ω/|ω| (row-major).
pub fn rotation_matrix(w: [f32; 3]) -> [[f32; 3]; 3] {
    let theta = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    if theta < 1e-12 {
        return [[1.0, -w[2], w[1]], [w[2], 1.0, -w[0]], [-w[1], w[0], 1.0]];
    }
    let k = [w[0] / theta, w[1] / theta, w[2] / theta];
    let (s, c) = theta.sin_cos();
    let v = 1.0 - c;
    [
        [
            c + k[0] * k[0] * v,
            k[0] * k[1] * v - k[2] * s,
            k[0] * k[2] * v + k[1] * s,
        ],
        [
            k[1] * k[0] * v + k[2] * s,
            c + k[1] * k[1] * v,
            k[1] * k[2] * v - k[0] * s,
        ],
        [
            k[2] * k[0] * v - k[1] * s,
            k[2] * k[1] * v + k[0] * s,
            c + k[2] * k[2] * v,
        ],
    ]
}

pub fn rotate(r: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rodrigues_is_a_rotation_by_the_angle() {
        let w = [0.1f32, -0.2, 0.05];
        let r = rotation_matrix(w);
        // Orthonormal, and the axis is fixed.
        for i in 0..3 {
            for j in 0..3 {
                let d: f32 = (0..3).map(|k| r[i][k] * r[j][k]).sum();
                assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-6);
            }
        }
        let axis = rotate(&r, w);
        assert!((0..3).all(|k| (axis[k] - w[k]).abs() < 1e-7));
        // A small rotation moves v by ω × v.
        let eps = [1e-4f32, 0.0, 0.0];
        let v = [0.0, 1.0, 0.0];
        let moved = rotate(&rotation_matrix(eps), v);
        let expected = cross(eps, v);
        assert!((0..3).all(|k| (moved[k] - v[k] - expected[k]).abs() < 1e-7));
    }

    /// The ray gradient ∂L/∂ω = d' × ∂L/∂d' against a finite difference of a loss of the rotated
    /// direction.
    #[test]
    fn rotation_gradient_matches_finite_differences() {
        let d = [0.3f32, -0.5, 0.81];
        let target = [0.2f32, 0.1, -0.4];
        let loss = |w: [f32; 3]| -> f64 {
            let r = rotate(&rotation_matrix(w), d);
            (0..3).map(|k| target[k] as f64 * r[k] as f64).sum()
        };
        let g_dir = target; // ∂L/∂d' of the linear loss
        let analytic = cross(d, g_dir);
        for k in 0..3 {
            let mut p = [0.0f32; 3];
            let mut m = [0.0f32; 3];
            p[k] = 1e-3;
            m[k] = -1e-3;
            let fd = (loss(p) - loss(m)) / 2e-3;
            assert!((fd - analytic[k] as f64).abs() < 1e-4, "{k}: {fd} vs {}", analytic[k]);
        }
    }
}
