//! Inference on the SDF network without the training workspace ([`SdfNetwork::infer`]): the same
//! tile-fused pipeline as the training forward (hash encoding of a block, then each tile through
//! the MLP and the gradient contraction), but nothing is kept for a backward and the buffers are
//! sized by the network and the thread count, never by the number of points — the path of
//! marching cubes, sphere tracing and stage 2's secondary rays.

use crate::linalg::{even_ranges, split_lengths_mut};
use crate::mlp::{TileScratch, TILE};
use crate::sdf::{SdfEncoding, SdfNetwork};
use rayon::prelude::*;

/// Points per block of [`SdfNetwork::infer`] (a multiple of [`TILE`]).
pub const INFER_BLOCK: usize = 16 * TILE;

/// One parallel task's buffers of [`SdfNetwork::infer`]: one block's encoding and Jacobian, one
/// tile's MLP input and activations.
struct InferBlock {
    /// (parameter address, parameter count, MLP input width) of the network the buffers were
    /// sized (and, with fixed weights, transposed) for.
    key: (usize, usize, usize),
    scratch: TileScratch,
    enc: Vec<f32>,
    jac: Vec<f32>,
    input: Vec<f32>,
    input_jac: Vec<f32>,
    acts: Vec<f32>,
    gacts: Vec<f32>,
    gx: Vec<f32>,
}

/// Buffers of [`SdfNetwork::infer`], kept by the caller: sized by the network and the thread
/// count, never by the number of points.
#[derive(Default)]
pub struct SdfInferWorkspace {
    blocks: Vec<InferBlock>,
    /// See [`SdfInferWorkspace::for_fixed_weights`].
    fixed_weights: bool,
}

impl SdfInferWorkspace {
    /// A workspace whose holder promises that the network's weights do not change while it is
    /// used (one kept beside a shared borrow of the network, as a frozen scene's or a ray
    /// caster's): the transposed weights are made once per task instead of once per call. Why:
    /// stage 2's renders call the network many times on small sets (a sphere tracer's last
    /// steps), and transposing on every call was 2–4 % of a re-render's CPU samples.
    pub fn for_fixed_weights() -> Self {
        SdfInferWorkspace {
            blocks: Vec::new(),
            fixed_weights: true,
        }
    }

    fn prepare(&mut self, net: &SdfNetwork, tasks: usize) {
        let key = (net.mlp.params.as_ptr() as usize, net.mlp.params.len(), net.in_dim());
        if self.blocks.first().is_some_and(|b| b.key != key) {
            self.blocks.clear();
        }
        let (d, aw) = (net.in_dim(), net.mlp.activation_width());
        let enc = match &net.encoding {
            SdfEncoding::HashGrid(g) => g.output_dim() * INFER_BLOCK,
            SdfEncoding::Frequency(_) => 0,
        };
        while self.blocks.len() < tasks {
            self.blocks.push(InferBlock {
                key,
                scratch: net.mlp.new_scratch(),
                enc: vec![0.0; enc],
                jac: vec![0.0; enc * 3],
                input: vec![0.0; TILE * d],
                input_jac: vec![0.0; TILE * d * 3],
                acts: vec![0.0; TILE * aw],
                gacts: vec![0.0; TILE * aw],
                gx: vec![0.0; TILE * d],
            });
        }
    }
}

impl SdfNetwork {
    /// Inference without the training workspace: distances (and, when asked, the feature `z` and
    /// `∇d`) at any number of points, tile-fused in blocks of [`INFER_BLOCK`] points — the hash
    /// encoding of one block, then each tile through the MLP and the gradient contraction — so
    /// memory is bounded by a few blocks per thread whatever `n` is, nothing is kept for a
    /// backward, and a kept workspace makes repeated calls allocation-free. Equal to
    /// [`SdfNetwork::forward`] / [`SdfNetwork::forward_with_gradient`] on the same points (blocks
    /// and tiles fall on the same boundaries as the batch forward's tiles).
    pub fn infer(
        &self,
        x: &[f32],
        ws: &mut SdfInferWorkspace,
        sdf: &mut [f32],
        feature: Option<&mut [f32]>,
        gradient: Option<&mut [f32]>,
    ) {
        assert_eq!(x.len() % 3, 0, "positions must be [n×3]");
        let n = x.len() / 3;
        let fd = self.feature_dim();
        assert!(sdf.len() >= n);
        let with_gradient = gradient.is_some();
        let blocks = n.div_ceil(INFER_BLOCK);
        let tasks = (2 * rayon::current_num_threads()).min(blocks).max(1);
        ws.prepare(self, tasks);
        let fixed = ws.fixed_weights;
        let ranges = even_ranges(blocks, tasks);
        let rows: Vec<usize> = ranges
            .iter()
            .map(|r| (r.end * INFER_BLOCK).min(n) - (r.start * INFER_BLOCK).min(n))
            .collect();
        let sdf_parts = split_lengths_mut(&mut sdf[..n], &rows);
        let mut feat_parts: Vec<Option<&mut [f32]>> = match feature {
            Some(f) => {
                assert!(f.len() >= n * fd);
                let lens: Vec<usize> = rows.iter().map(|r| r * fd).collect();
                split_lengths_mut(&mut f[..n * fd], &lens)
                    .into_iter()
                    .map(Some)
                    .collect()
            }
            None => rows.iter().map(|_| None).collect(),
        };
        let mut grad_parts: Vec<Option<&mut [f32]>> = match gradient {
            Some(g) => {
                assert!(g.len() >= n * 3);
                let lens: Vec<usize> = rows.iter().map(|r| r * 3).collect();
                split_lengths_mut(&mut g[..n * 3], &lens)
                    .into_iter()
                    .map(Some)
                    .collect()
            }
            None => rows.iter().map(|_| None).collect(),
        };
        let work: Vec<_> = ranges
            .into_iter()
            .zip(ws.blocks.iter_mut())
            .zip(
                sdf_parts
                    .into_iter()
                    .zip(feat_parts.drain(..).zip(grad_parts.drain(..))),
            )
            .collect();
        work.into_par_iter()
            .for_each(|((range, st), (sdf_c, (mut feat_c, mut grad_c)))| {
                if !(fixed && st.scratch.transposed_ready()) {
                    self.mlp.prepare_transposed(&mut st.scratch);
                }
                let base = range.start * INFER_BLOCK;
                for b in range {
                    let b0 = b * INFER_BLOCK;
                    let mb = INFER_BLOCK.min(n - b0);
                    let xb = &x[b0 * 3..(b0 + mb) * 3];
                    self.infer_block(xb, st, with_gradient, |r, d, z, g| {
                        let i = b0 - base + r;
                        sdf_c[i] = d;
                        if let Some(f) = feat_c.as_deref_mut() {
                            f[i * fd..(i + 1) * fd].copy_from_slice(z);
                        }
                        if let (Some(gc), Some(g)) = (grad_c.as_deref_mut(), g) {
                            gc[i * 3..i * 3 + 3].copy_from_slice(&g);
                        }
                    });
                }
            });
    }

    /// One block of [`SdfNetwork::infer`]: `emit(row, d, z, ∇d)` for each of its points.
    fn infer_block(
        &self,
        xb: &[f32],
        st: &mut InferBlock,
        with_gradient: bool,
        mut emit: impl FnMut(usize, f32, &[f32], Option<[f32; 3]>),
    ) {
        let mb = xb.len() / 3;
        let (d, aw, od) = (self.in_dim(), self.mlp.activation_width(), self.feature_dim() + 1);
        if let SdfEncoding::HashGrid(g) = &self.encoding {
            g.encode(xb, &mut st.enc, with_gradient.then_some(&mut st.jac[..]));
        }
        let need_jac = with_gradient && matches!(self.encoding, SdfEncoding::Frequency(_));
        for r0 in (0..mb).step_by(TILE) {
            let m = TILE.min(mb - r0);
            self.assemble_input(
                xb,
                &st.enc,
                mb,
                r0,
                m,
                &mut st.input,
                need_jac.then_some(&mut st.input_jac[..]),
            );
            let acts = &mut st.acts[..m * aw];
            self.mlp.forward_tile(&st.input, m, acts, &mut st.scratch);
            if with_gradient {
                let gacts = &mut st.gacts[..m * aw];
                self.mlp
                    .input_gradient_tile(m, acts, 0, gacts, &mut st.gx, &mut st.scratch);
            }
            let out = self.mlp.tile_output(acts, m);
            for r in 0..m {
                let row = &out[r * od..(r + 1) * od];
                let grad = with_gradient.then(|| {
                    let gx = &st.gx[r * d..(r + 1) * d];
                    match &self.encoding {
                        SdfEncoding::HashGrid(g) => {
                            let f = g.config.features_per_level;
                            let mut gv = [gx[0], gx[1], gx[2]];
                            for l in 0..g.config.levels {
                                let jac = &st.jac[(l * mb + r0 + r) * f * 3..(l * mb + r0 + r + 1) * f * 3];
                                for ff in 0..f {
                                    let gxv = gx[3 + l * f + ff];
                                    let j = &jac[ff * 3..ff * 3 + 3];
                                    gv[0] += gxv * j[0];
                                    gv[1] += gxv * j[1];
                                    gv[2] += gxv * j[2];
                                }
                            }
                            gv
                        }
                        SdfEncoding::Frequency(_) => {
                            let mut gv = [0f32; 3];
                            for o in 0..d {
                                let j = &st.input_jac[(r * d + o) * 3..(r * d + o) * 3 + 3];
                                for k in 0..3 {
                                    gv[k] += gx[o] * j[k];
                                }
                            }
                            gv
                        }
                    }
                });
                emit(r0 + r, row[0], &row[1..], grad);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf::{SdfEncodingConfig, SdfNetworkConfig, SdfWorkspace};
    use crate::HashGridConfig;

    fn nets() -> Vec<SdfNetwork> {
        let mut hash = SdfNetworkConfig::hash_grid(0.8);
        hash.encoding = SdfEncodingConfig::HashGrid(HashGridConfig {
            levels: 6,
            log2_table_size: 12,
            finest_resolution: 96,
            ..Default::default()
        });
        let mut freq = SdfNetworkConfig::paper(0.8);
        freq.hidden_dim = 32;
        freq.hidden_layers = 4;
        freq.skip_layers = vec![2];
        freq.feature_dim = 8;
        vec![SdfNetwork::new(hash, 7), SdfNetwork::new(freq, 8)]
    }

    /// The inference path equals the training forward bit for bit, over several blocks, a
    /// partial last tile, and with or without the gradient and the feature.
    #[test]
    fn infer_equals_the_training_forward() {
        for net in nets() {
            let n = 2 * INFER_BLOCK + 3 * TILE + 77;
            let mut s = 0x2545_f491_4f6c_dd1du64;
            let x: Vec<f32> = (0..n * 3)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (s >> 40) as f32 / (1u64 << 24) as f32 * 1.8 - 0.9
                })
                .collect();
            let fd = net.feature_dim();
            let (mut d0, mut z0, mut g0) = (vec![0.0; n], vec![0.0; n * fd], vec![0.0; n * 3]);
            net.forward_with_gradient(&x, &mut SdfWorkspace::default(), &mut d0, &mut z0, &mut g0);
            let mut ws = SdfInferWorkspace::default();
            let (mut d1, mut z1, mut g1) = (vec![0.0; n], vec![0.0; n * fd], vec![0.0; n * 3]);
            net.infer(&x, &mut ws, &mut d1, Some(&mut z1), Some(&mut g1));
            assert_eq!(d0, d1);
            assert_eq!(z0, z1);
            for (a, b) in g0.iter().zip(&g1) {
                assert!((a - b).abs() <= 1e-6 * a.abs().max(1.0), "{a} vs {b}");
            }
            // Distances only, reusing the workspace, on a smaller batch.
            let m = TILE + 5;
            let mut d2 = vec![0.0; m];
            net.infer(&x[..m * 3], &mut ws, &mut d2, None, None);
            let (mut d3, mut z3) = (vec![0.0; m], vec![0.0; m * fd]);
            net.forward(&x[..m * 3], &mut SdfWorkspace::default(), &mut d3, &mut z3);
            assert_eq!(d2, d3);
            net.infer(&[], &mut ws, &mut [], None, None);
        }
    }

    /// A fixed-weights workspace keeps the transposed weights between calls and gives what a
    /// fresh workspace gives, call after call; one kept while the weights change would not (which
    /// is why only holders of a shared borrow of the network make one).
    #[test]
    fn a_fixed_weights_workspace_reuses_its_transposed_weights() {
        for mut net in nets() {
            let n = INFER_BLOCK + 2 * TILE + 9;
            let x: Vec<f32> = (0..n * 3)
                .map(|i| ((i * 37 % 101) as f32 / 101.0) * 1.6 - 0.8)
                .collect();
            let fresh = |net: &SdfNetwork| {
                let mut d = vec![0.0; n];
                net.infer(&x, &mut SdfInferWorkspace::default(), &mut d, None, None);
                d
            };
            let mut fixed = SdfInferWorkspace::for_fixed_weights();
            for _ in 0..3 {
                let mut d = vec![0.0; n];
                net.infer(&x, &mut fixed, &mut d, None, None);
                assert_eq!(d, fresh(&net));
            }
            // The promise broken: the kept transposition is stale, the result differs.
            net.mlp.params.iter_mut().for_each(|w| *w *= 1.5);
            let mut d = vec![0.0; n];
            net.infer(&x, &mut fixed, &mut d, None, None);
            assert_ne!(d, fresh(&net));
        }
    }
}
