//! Adam (Kingma & Ba 2015) with per-group learning rates and schedules, and a lazy update for
//! hash tables.
//!
//! The lazy update follows Instant-NGP (Müller et al. 2022, Sec. 4): hash-table entries that
//! received no gradient this step are skipped entirely — their moments do not decay. Here the
//! skipped set comes from the bitmap the scatter-add fills, so the update touches only the entries
//! the batch visited (coarse levels: a few thousand; the finest: about half of the table) and zeroes
//! their gradient for the next step, instead of streaming all tables, moments and gradients.

use crate::hashgrid::HashGridGrad;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Adam's hyper-parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdamConfig {
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// Learning-rate factor as a function of the step `t` (starting at 1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LrSchedule {
    Constant,
    /// `rate^(t/steps)`: VolSDF decays by `rate = 0.1` over the whole run.
    Exponential {
        rate: f32,
        steps: u64,
    },
    /// Linear warm-up over `warmup` steps, then cosine decay to `min_factor` at `total`.
    WarmupCosine {
        warmup: u64,
        total: u64,
        min_factor: f32,
    },
}

impl LrSchedule {
    pub fn factor(&self, t: u64) -> f32 {
        match *self {
            LrSchedule::Constant => 1.0,
            LrSchedule::Exponential { rate, steps } => rate.powf(t as f32 / steps.max(1) as f32),
            LrSchedule::WarmupCosine {
                warmup,
                total,
                min_factor,
            } => {
                if t < warmup {
                    t as f32 / warmup as f32
                } else {
                    let p = ((t - warmup) as f32 / (total.saturating_sub(warmup).max(1)) as f32).min(1.0);
                    min_factor + (1.0 - min_factor) * 0.5 * (1.0 + (std::f32::consts::PI * p).cos())
                }
            }
        }
    }
}

/// Moments and learning rate of one parameter tensor.
#[derive(Clone, Debug)]
pub struct ParamGroup {
    pub name: String,
    pub lr: f32,
    pub schedule: LrSchedule,
    m: Vec<f32>,
    v: Vec<f32>,
}

/// Index of a group in an [`Adam`].
pub type GroupId = usize;

/// The optimizer: call [`Adam::begin_step`] once per iteration, then update each group.
#[derive(Clone, Debug)]
pub struct Adam {
    pub config: AdamConfig,
    pub groups: Vec<ParamGroup>,
    /// Steps begun so far (`t` of the bias correction).
    pub step: u64,
}

const BLOCK: usize = 1 << 14;

impl Adam {
    pub fn new(config: AdamConfig) -> Self {
        Adam {
            config,
            groups: Vec::new(),
            step: 0,
        }
    }

    /// Register a tensor of `len` parameters with base learning rate `lr`.
    pub fn add_group(&mut self, name: &str, len: usize, lr: f32, schedule: LrSchedule) -> GroupId {
        self.groups.push(ParamGroup {
            name: name.to_string(),
            lr,
            schedule,
            m: vec![0.0; len],
            v: vec![0.0; len],
        });
        self.groups.len() - 1
    }

    pub fn begin_step(&mut self) {
        self.step += 1;
    }

    /// The scheduled learning rate of `group` at the current step.
    pub fn current_lr(&self, group: GroupId) -> f32 {
        let g = &self.groups[group];
        g.lr * g.schedule.factor(self.step)
    }

    /// `α_t = lr·√(1−β₂ᵗ)/(1−β₁ᵗ)` and the ε scaled the same way, so the update is
    /// `p −= α_t m/(√v + ε̂)` — Kingma & Ba's "more efficient" form of Algorithm 1.
    fn step_sizes(&self, group: GroupId) -> (f32, f32) {
        let t = self.step.max(1) as i32;
        let c = &self.config;
        let bc1 = 1.0 - c.beta1.powi(t);
        let bc2 = 1.0 - c.beta2.powi(t);
        (self.current_lr(group) * bc2.sqrt() / bc1, c.eps * bc2.sqrt())
    }

    /// Dense update of every parameter of `group`; zeroes `grads`.
    pub fn update(&mut self, group: GroupId, params: &mut [f32], grads: &mut [f32]) {
        let (alpha, eps) = self.step_sizes(group);
        let (b1, b2) = (self.config.beta1, self.config.beta2);
        let g = &mut self.groups[group];
        assert!(
            params.len() == g.m.len() && grads.len() == g.m.len(),
            "group {} has {} parameters",
            g.name,
            g.m.len()
        );
        params
            .par_chunks_mut(BLOCK)
            .zip(grads.par_chunks_mut(BLOCK))
            .zip(g.m.par_chunks_mut(BLOCK).zip(g.v.par_chunks_mut(BLOCK)))
            .for_each(|((p, gr), (m, v))| {
                for i in 0..p.len() {
                    let gi = gr[i];
                    m[i] = b1 * m[i] + (1.0 - b1) * gi;
                    v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
                    p[i] -= alpha * m[i] / (v[i].sqrt() + eps);
                    gr[i] = 0.0;
                }
            });
    }

    /// Lazy update of a hash table: only entries marked in `grad.touched` (rows of `row_len`
    /// parameters) are updated; their gradients and the bitmap are cleared.
    pub fn update_sparse(&mut self, group: GroupId, params: &mut [f32], grad: &mut HashGridGrad, row_len: usize) {
        let (alpha, eps) = self.step_sizes(group);
        let (b1, b2) = (self.config.beta1, self.config.beta2);
        let g = &mut self.groups[group];
        assert!(params.len() == g.m.len() && grad.values.len() == g.m.len());
        let words = BLOCK / 64;
        let floats = words * 64 * row_len;
        params
            .par_chunks_mut(floats)
            .zip(grad.values.par_chunks_mut(floats))
            .zip(g.m.par_chunks_mut(floats).zip(g.v.par_chunks_mut(floats)))
            .zip(grad.touched.par_chunks_mut(words))
            .for_each(|(((p, gr), (m, v)), bits)| {
                for (w, word) in bits.iter_mut().enumerate() {
                    let mut b = *word;
                    while b != 0 {
                        let e = w * 64 + b.trailing_zeros() as usize;
                        b &= b - 1;
                        for i in e * row_len..(e + 1) * row_len {
                            let gi = gr[i];
                            m[i] = b1 * m[i] + (1.0 - b1) * gi;
                            v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
                            p[i] -= alpha * m[i] / (v[i].sqrt() + eps);
                            gr[i] = 0.0;
                        }
                    }
                    *word = 0;
                }
            });
    }

    /// First and second moments of a group (for checkpoints).
    pub fn moments(&self, group: GroupId) -> (&[f32], &[f32]) {
        (&self.groups[group].m, &self.groups[group].v)
    }

    pub fn moments_mut(&mut self, group: GroupId) -> (&mut [f32], &mut [f32]) {
        let g = &mut self.groups[group];
        (&mut g.m, &mut g.v)
    }

    /// The group of this name.
    pub fn group_id(&self, name: &str) -> Option<GroupId> {
        self.groups.iter().position(|g| g.name == name)
    }
}

impl ParamGroup {
    /// Name, first and second moments, mutably (to load them from a checkpoint).
    pub fn state_mut(&mut self) -> (&str, &mut [f32], &mut [f32]) {
        (&self.name, &mut self.m, &mut self.v)
    }

    /// First and second moments.
    pub fn state(&self) -> (&[f32], &[f32]) {
        (&self.m, &self.v)
    }
}

/// The moments as checkpoint tensors `{prefix}.{group}.m` / `.v` (a resumed run continues bit for
/// bit). Loading fills the moments of the groups already registered.
impl crate::params::Parameters for Adam {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        for g in &self.groups {
            f(format!("{prefix}.{}.m", g.name), vec![g.m.len()], &g.m);
            f(format!("{prefix}.{}.v", g.name), vec![g.v.len()], &g.v);
        }
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        for g in &mut self.groups {
            f(format!("{prefix}.{}.m", g.name), vec![g.m.len()], &mut g.m);
            f(format!("{prefix}.{}.v", g.name), vec![g.v.len()], &mut g.v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::Lcg;

    #[test]
    fn dense_update_follows_algorithm_1() {
        let cfg = AdamConfig {
            beta1: 0.9,
            beta2: 0.99,
            eps: 1e-8,
        };
        let mut adam = Adam::new(cfg);
        let id = adam.add_group("w", 3, 0.1, LrSchedule::Constant);
        let mut p = vec![1.0f32, -2.0, 0.5];
        let (mut m, mut v, mut q) = ([0f64; 3], [0f64; 3], [1.0f64, -2.0, 0.5]);
        for t in 1..=5 {
            let g: Vec<f32> = q.iter().map(|&x| (2.0 * x) as f32).collect(); // ∇ of x²
            let mut gm = g.clone();
            adam.begin_step();
            adam.update(id, &mut p, &mut gm);
            assert!(gm.iter().all(|&x| x == 0.0));
            for i in 0..3 {
                m[i] = 0.9 * m[i] + 0.1 * g[i] as f64;
                v[i] = 0.99 * v[i] + 0.01 * (g[i] as f64).powi(2);
                let mh = m[i] / (1.0 - 0.9f64.powi(t));
                let vh = v[i] / (1.0 - 0.99f64.powi(t));
                q[i] -= 0.1 * mh / (vh.sqrt() + 1e-8);
                assert!((p[i] as f64 - q[i]).abs() < 1e-5, "step {t}: {} vs {}", p[i], q[i]);
            }
        }
    }

    /// Lazy == dense on touched entries; untouched entries (and their moments) stay as they were.
    #[test]
    fn sparse_update_matches_dense_on_touched_entries() {
        let cfg = AdamConfig::default();
        let (entries, f) = (3 * 64, 2);
        let mut rng = Lcg(3);
        let p0: Vec<f32> = (0..entries * f).map(|_| rng.uniform_pm1()).collect();
        let (mut pd, mut ps) = (p0.clone(), p0.clone());
        let mut dense = Adam::new(cfg);
        let mut sparse = Adam::new(cfg);
        let gd = dense.add_group("t", entries * f, 0.01, LrSchedule::Exponential { rate: 0.1, steps: 10 });
        let gs = sparse.add_group("t", entries * f, 0.01, LrSchedule::Exponential { rate: 0.1, steps: 10 });
        let touched = |e: usize| e % 3 != 1;
        for _ in 0..4 {
            let mut hg = HashGridGrad {
                values: vec![0.0; entries * f],
                touched: vec![0; entries / 64],
            };
            for e in (0..entries).filter(|&e| touched(e)) {
                hg.values[e * f] = rng.uniform_pm1();
                hg.values[e * f + 1] = rng.uniform_pm1();
                hg.touched[e / 64] |= 1 << (e % 64);
            }
            let mut g = hg.values.clone();
            dense.begin_step();
            sparse.begin_step();
            dense.update(gd, &mut pd, &mut g);
            sparse.update_sparse(gs, &mut ps, &mut hg, f);
            assert!(hg.values.iter().all(|&v| v == 0.0) && hg.touched.iter().all(|&w| w == 0));
        }
        for e in 0..entries {
            for i in e * f..(e + 1) * f {
                if touched(e) {
                    assert!((pd[i] - ps[i]).abs() < 1e-7);
                    assert!(ps[i] != p0[i]);
                } else {
                    assert_eq!(ps[i], p0[i]);
                }
            }
        }
    }

    #[test]
    fn schedules() {
        let e = LrSchedule::Exponential { rate: 0.1, steps: 100 };
        assert!((e.factor(100) - 0.1).abs() < 1e-6 && (e.factor(50) - 0.316_227_8).abs() < 1e-5);
        let c = LrSchedule::WarmupCosine {
            warmup: 10,
            total: 110,
            min_factor: 0.0,
        };
        assert!((c.factor(5) - 0.5).abs() < 1e-6 && (c.factor(60) - 0.5).abs() < 1e-6 && c.factor(110).abs() < 1e-6);
    }
}
