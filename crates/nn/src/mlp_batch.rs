//! Batched MLP evaluation for standalone networks (radiance, emitter, material fields): tiles of
//! [`TILE`] points grouped in chunks, one rayon task per chunk, per-chunk gradient accumulators
//! reduced at the end. Buffers live in a caller-kept [`MlpWorkspace`].

use crate::linalg::{even_ranges, reduce_into, split_lengths_mut};
use crate::mlp::{Mlp, TileScratch, TILE};
use rayon::prelude::*;

struct MlpChunk {
    scratch: TileScratch,
    grad: Vec<f32>,
}

/// What [`Mlp::backward`] needs from the last [`Mlp::forward`] (its input and activations), and
/// per-chunk scratch; reallocated only when the batch grows.
#[derive(Default)]
pub struct MlpWorkspace {
    n: usize,
    input: Vec<f32>,
    acts: Vec<f32>,
    chunks: Vec<MlpChunk>,
}

impl Mlp {
    fn prepare_batch(&self, ws: &mut MlpWorkspace, input: &[f32]) {
        let d = self.input_dim();
        assert_eq!(input.len() % d, 0, "input must be [n × {d}]");
        ws.n = input.len() / d;
        // the copy kept for the backward is made by the chunk tasks, in parallel (see `forward`)
        if ws.input.len() < input.len() {
            ws.input.resize(input.len(), 0.0);
        }
        let need = ws.n.div_ceil(TILE) * TILE * self.activation_width();
        if ws.acts.len() < need {
            ws.acts.resize(need, 0.0);
        }
        if ws.chunks.first().is_some_and(|c| c.grad.len() != self.params.len()) {
            ws.chunks.clear();
        }
        while ws.chunks.len() < 2 * rayon::current_num_threads() {
            ws.chunks.push(MlpChunk {
                scratch: self.new_scratch(),
                grad: vec![0.0; self.params.len()],
            });
        }
    }

    /// Evaluate `n` points (`input`: `[n × input_dim]`) into `output` (`[n × output_dim]`), keeping
    /// the activations in `ws` for [`Mlp::backward`].
    pub fn forward(&self, input: &[f32], ws: &mut MlpWorkspace, output: &mut [f32]) {
        self.prepare_batch(ws, input);
        let (n, d, od, aw) = (ws.n, self.input_dim(), self.output_dim(), self.activation_width());
        let ranges = even_ranges(n.div_ceil(TILE), ws.chunks.len());
        let rows: Vec<usize> = ranges
            .iter()
            .map(|r| ((r.end * TILE).min(n) - r.start * TILE) * od)
            .collect();
        let blocks: Vec<usize> = ranges.iter().map(|r| r.len() * TILE * aw).collect();
        let outs = split_lengths_mut(&mut output[..n * od], &rows);
        let acts = split_lengths_mut(&mut ws.acts, &blocks);
        let in_rows: Vec<usize> = rows.iter().map(|r| r / od * d).collect();
        let kept = split_lengths_mut(&mut ws.input[..n * d], &in_rows);
        let work: Vec<_> = ranges
            .into_iter()
            .zip(ws.chunks.iter_mut())
            .zip(outs.into_iter().zip(acts).zip(kept))
            .collect();
        work.into_par_iter()
            .for_each(|((range, st), ((out_c, acts_c), kept_c))| {
                let start = range.start * TILE * d;
                kept_c.copy_from_slice(&input[start..start + kept_c.len()]);
                self.prepare_transposed(&mut st.scratch);
                for t in range.clone() {
                    let (r0, m) = (t * TILE, TILE.min(n - t * TILE));
                    let local = r0 - range.start * TILE;
                    let a = &mut acts_c[(t - range.start) * TILE * aw..][..m * aw];
                    self.forward_tile(&input[r0 * d..(r0 + m) * d], m, a, &mut st.scratch);
                    out_c[local * od..(local + m) * od].copy_from_slice(self.tile_output(a, m));
                }
            });
    }

    /// Accumulate into `grad` (layout of `params`) the gradient of `Σ d_output·output` for the batch
    /// of the last [`Mlp::forward`], and, when given, overwrite `d_input` (`[n × input_dim]`) with
    /// its gradient w.r.t. the input (e.g. to pass on to the SDF feature and the normal).
    pub fn backward(&self, ws: &mut MlpWorkspace, d_output: &[f32], grad: &mut [f32], d_input: Option<&mut [f32]>) {
        let (n, d, od, aw) = (ws.n, self.input_dim(), self.output_dim(), self.activation_width());
        assert!(d_output.len() >= n * od && grad.len() == self.params.len());
        let ranges = even_ranges(n.div_ceil(TILE), ws.chunks.len());
        let n_ranges = ranges.len();
        let rows: Vec<usize> = ranges
            .iter()
            .map(|r| ((r.end * TILE).min(n) - r.start * TILE) * d)
            .collect();
        let mut dins: Vec<Option<&mut [f32]>> = match d_input {
            Some(di) => split_lengths_mut(&mut di[..n * d], &rows)
                .into_iter()
                .map(Some)
                .collect(),
            None => rows.iter().map(|_| None).collect(),
        };
        let (input, acts) = (&ws.input[..], &ws.acts[..]);
        let work: Vec<_> = ranges
            .into_iter()
            .zip(ws.chunks.iter_mut())
            .zip(dins.drain(..))
            .collect();
        work.into_par_iter().for_each(|((range, st), mut din_c)| {
            st.grad.fill(0.0);
            for t in range.clone() {
                let (r0, m) = (t * TILE, TILE.min(n - t * TILE));
                let local = r0 - range.start * TILE;
                let a = &acts[t * TILE * aw..][..m * aw];
                let dx = din_c.as_deref_mut().map(|di| &mut di[local * d..(local + m) * d]);
                self.backward_tile(
                    &input[r0 * d..(r0 + m) * d],
                    m,
                    a,
                    &d_output[r0 * od..(r0 + m) * od],
                    &mut st.grad,
                    dx,
                    &mut st.scratch,
                );
            }
        });
        let accs: Vec<Vec<f32>> = ws.chunks[..n_ranges]
            .iter_mut()
            .map(|c| std::mem::take(&mut c.grad))
            .collect();
        reduce_into(grad, &accs);
        for (c, acc) in ws.chunks.iter_mut().zip(accs) {
            c.grad = acc;
        }
    }
}

/// Buffers of [`Mlp::infer`]: one tile's activations and scratch per parallel task, sized by the
/// network, never by the number of points.
#[derive(Default)]
pub struct MlpInferWorkspace {
    /// Per task: the (address, length) of the parameters it was made for, its scratch, its
    /// activations.
    chunks: Vec<((usize, usize), TileScratch, Vec<f32>)>,
    /// See [`MlpInferWorkspace::for_fixed_weights`].
    fixed_weights: bool,
}

impl MlpInferWorkspace {
    /// A workspace whose holder promises that the network's weights do not change while it is
    /// used (kept beside a shared borrow of the network): the transposed weights are made once
    /// per task instead of once per call, as [`crate::sdf::SdfInferWorkspace::for_fixed_weights`].
    pub fn for_fixed_weights() -> Self {
        MlpInferWorkspace {
            chunks: Vec::new(),
            fixed_weights: true,
        }
    }
}

impl Mlp {
    /// Inference without stored activations (the radiance and emitter fields queried at
    /// arbitrary points): `output` (`[n × output_dim]`) for `input` (`[n × input_dim]`), tile by
    /// tile, equal to [`Mlp::forward`]. A kept workspace makes repeated calls allocation-free.
    pub fn infer(&self, input: &[f32], ws: &mut MlpInferWorkspace, output: &mut [f32]) {
        let (d, od, aw) = (self.input_dim(), self.output_dim(), self.activation_width());
        assert_eq!(input.len() % d, 0, "input must be [n × {d}]");
        let n = input.len() / d;
        assert!(output.len() >= n * od);
        let tiles = n.div_ceil(TILE);
        let tasks = (2 * rayon::current_num_threads()).min(tiles).max(1);
        let key = (self.params.as_ptr() as usize, self.params.len());
        if ws.chunks.first().is_some_and(|c| c.0 != key || c.2.len() != TILE * aw) {
            ws.chunks.clear();
        }
        while ws.chunks.len() < tasks {
            ws.chunks.push((key, self.new_scratch(), vec![0.0; TILE * aw]));
        }
        let fixed = ws.fixed_weights;
        let ranges = even_ranges(tiles, tasks);
        let rows: Vec<usize> = ranges
            .iter()
            .map(|r| ((r.end * TILE).min(n) - (r.start * TILE).min(n)) * od)
            .collect();
        let outs = split_lengths_mut(&mut output[..n * od], &rows);
        let work: Vec<_> = ranges.into_iter().zip(ws.chunks.iter_mut()).zip(outs).collect();
        work.into_par_iter().for_each(|((range, (_, scratch, acts)), out_c)| {
            if !(fixed && scratch.transposed_ready()) {
                self.prepare_transposed(scratch);
            }
            for t in range.clone() {
                let (r0, m) = (t * TILE, TILE.min(n - t * TILE));
                let local = r0 - range.start * TILE;
                let a = &mut acts[..m * aw];
                self.forward_tile(&input[r0 * d..(r0 + m) * d], m, a, scratch);
                out_c[local * od..(local + m) * od].copy_from_slice(self.tile_output(a, m));
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use crate::gradcheck::{assert_grad_close, central_difference, Lcg};
    use crate::{Activation, Mlp, MlpConfig, MlpWorkspace};

    /// The batched path over several tiles and chunks equals the finite-difference gradient.
    #[test]
    fn batched_backward_matches_finite_differences() {
        let config = MlpConfig {
            input_dim: 5,
            hidden_dim: 8,
            hidden_layers: 2,
            output_dim: 3,
            skip_layers: vec![],
            // smooth, so finite differences over 700 points never straddle a ReLU kink
            hidden_activation: Activation::Softplus { beta: 10.0 },
            output_activation: Activation::Sigmoid,
        };
        let mlp = Mlp::new(config, 3);
        let n = 700;
        let mut rng = Lcg(1);
        let x: Vec<f32> = (0..n * 5).map(|_| rng.uniform_pm1()).collect();
        let c: Vec<f32> = (0..n * 3).map(|_| rng.uniform_pm1()).collect();
        let mut ws = MlpWorkspace::default();
        let mut y = vec![0.0; n * 3];
        mlp.forward(&x, &mut ws, &mut y);
        let mut grad = vec![0.0; mlp.params.len()];
        let mut dx = vec![0.0; n * 5];
        mlp.backward(&mut ws, &c, &mut grad, Some(&mut dx));
        let loss = |m: &Mlp, xs: &[f32]| {
            let mut y = vec![0.0; n * 3];
            m.forward(xs, &mut MlpWorkspace::default(), &mut y);
            y.iter().zip(&c).map(|(&a, &b)| a as f64 * b as f64).sum::<f64>()
        };
        let fd = central_difference(&mlp.params, 1e-3, |p| {
            let mut m = mlp.clone();
            m.params.copy_from_slice(p);
            loss(&m, &x)
        });
        assert_grad_close("batched MLP parameters", &grad, &fd, 5e-3, 2e-2);
        let fdx = central_difference(&x[..40], 1e-3, |xp| {
            let mut xs = x.clone();
            xs[..40].copy_from_slice(xp);
            loss(&mlp, &xs)
        });
        assert_grad_close("batched MLP input", &dx[..40], &fdx, 2e-3, 2e-2);
        // The inference path gives the same outputs without keeping activations.
        let mut y2 = vec![0.0; n * 3];
        let mut iws = crate::mlp_batch::MlpInferWorkspace::default();
        mlp.infer(&x, &mut iws, &mut y2);
        assert_eq!(y, y2);
        mlp.infer(&x[..5 * 17], &mut iws, &mut y2[..3 * 17]);
        assert_eq!(y[..3 * 17], y2[..3 * 17]);
    }
}
