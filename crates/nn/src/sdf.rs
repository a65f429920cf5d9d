//! The SDF network `F_d(x) = MLP(encoding(x)) → (d, z)` with its analytic spatial gradient `∇d`
//! and a backward that takes cotangents of `d`, `z` *and* `∇d` (the eikonal, smoothness and normal
//! losses) into every parameter.
//!
//! The MLP input is `[x, hash features]` (hash-grid backbone) or `γ(x)`, which starts with `x`
//! (the paper's backbone); both put the raw position first, as the geometric init expects.
//!
//! Pipeline of one batch (`n` points, tiles of [`TILE`] points, chunks of tiles per rayon task):
//! 1. hash encoding and its Jacobian `J`, level-major, levels in parallel;
//! 2. per tile: MLP forward, the reverse pass seeded with `d` (`G_X = ∂d/∂X`), `∇d = Jᵀ G_X`;
//! 3. backward, per tile: `Ḡ_X = J ∇̄d`, the MLP double backward (parameter gradients into a
//!    per-chunk accumulator, `X̄` for the encoding);
//! 4. hash-table scatter of `w_c X̄ + (∇̄d·∇w_c) G_X`, level-major, one thread per level.

use crate::encoding::FrequencyEncoding;
use crate::hashgrid::{HashGrid, HashGridConfig, HashGridGrad};
use crate::linalg::{even_ranges, reduce_into, split_lengths_mut};
use crate::mlp::{GeometricInit, Mlp, MlpConfig, TileScratch, TILE};
use crate::Activation;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::ops::Range;

// The inference path lives in its own file; its workspace is named here too, beside the training one.
pub use crate::sdf_infer::{SdfInferWorkspace, INFER_BLOCK};

/// Which encoding feeds the SDF MLP.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SdfEncodingConfig {
    HashGrid(HashGridConfig),
    /// Sinusoidal positional encoding with this many frequency bands (the paper: 6).
    Frequency {
        frequencies: usize,
    },
}

/// The SDF network: encoding, MLP shape, feature size and initialization.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SdfNetworkConfig {
    pub encoding: SdfEncodingConfig,
    pub hidden_dim: usize,
    pub hidden_layers: usize,
    #[serde(default)]
    pub skip_layers: Vec<usize>,
    pub activation: Activation,
    /// Size of the feature vector `z` output next to the distance.
    pub feature_dim: usize,
    pub geometric_init: Option<GeometricInit>,
}

impl SdfNetworkConfig {
    /// The default backbone: 16-level hash grid (2 features, 2^19 entries, 16 → 2048), MLP
    /// 35 → 64 → 64 → 1 + 15, Softplus(100), inverted-sphere init of radius `radius`.
    pub fn hash_grid(radius: f32) -> Self {
        SdfNetworkConfig {
            encoding: SdfEncodingConfig::HashGrid(HashGridConfig::default()),
            hidden_dim: 64,
            hidden_layers: 2,
            skip_layers: vec![],
            activation: Activation::Softplus { beta: 100.0 },
            feature_dim: 15,
            geometric_init: Some(GeometricInit {
                radius,
                inside_out: true,
            }),
        }
    }

    /// The paper's backbone (VolSDF's): γ(x) with 6 bands, 8×256 Softplus(100) MLP with a skip at
    /// layer 4, a 256-dim feature, inverted-sphere init. (IDR narrows layer 3 to 256 − 39 outputs
    /// so that the skip concatenation is 256 wide; here layer 4 takes all 256 + 39, which keeps
    /// every hidden layer 256 wide.)
    pub fn paper(radius: f32) -> Self {
        SdfNetworkConfig {
            encoding: SdfEncodingConfig::Frequency { frequencies: 6 },
            hidden_dim: 256,
            hidden_layers: 8,
            skip_layers: vec![4],
            activation: Activation::Softplus { beta: 100.0 },
            feature_dim: 256,
            geometric_init: Some(GeometricInit {
                radius,
                inside_out: true,
            }),
        }
    }
}

/// The encoding of an [`SdfNetwork`].
#[derive(Clone, Debug)]
pub enum SdfEncoding {
    HashGrid(HashGrid),
    Frequency(FrequencyEncoding),
}

/// `F_d`: encoding + MLP; output 0 is the signed distance, outputs `1..` the feature `z`.
#[derive(Clone, Debug)]
pub struct SdfNetwork {
    pub config: SdfNetworkConfig,
    pub encoding: SdfEncoding,
    pub mlp: Mlp,
}

/// Gradients of an [`SdfNetwork`]'s parameters (accumulated by `backward`; zero them, or let the
/// optimizer do it, between steps).
#[derive(Clone, Debug)]
pub struct SdfGrad {
    pub mlp: Vec<f32>,
    pub hash_grid: Option<HashGridGrad>,
}

impl SdfGrad {
    pub fn new(net: &SdfNetwork) -> Self {
        SdfGrad {
            mlp: vec![0.0; net.mlp.params.len()],
            hash_grid: match &net.encoding {
                SdfEncoding::HashGrid(g) => Some(HashGridGrad::new(g)),
                SdfEncoding::Frequency(_) => None,
            },
        }
    }
    pub fn zero(&mut self) {
        self.mlp.fill(0.0);
        if let Some(h) = &mut self.hash_grid {
            h.values.fill(0.0);
            h.touched.fill(0);
        }
    }
}

struct ChunkState {
    scratch: TileScratch,
    input: Vec<f32>,
    jac: Vec<f32>,
    gx: Vec<f32>,
    gbar_x: Vec<f32>,
    dx: Vec<f32>,
    dout: Vec<f32>,
    mlp_grad: Vec<f32>,
}

/// Wall-clock time of the phases of the last forward/backward (for the benchmark).
#[derive(Clone, Copy, Debug, Default)]
pub struct SdfTimings {
    /// Hash encoding and its Jacobian (level-major).
    pub encode: std::time::Duration,
    /// Forward tile pass: MLP forward, input-gradient pass, `∇d` contraction.
    pub mlp_forward: std::time::Duration,
    /// Backward tile pass: MLP (double) backward and the reduction of its gradients.
    pub mlp_backward: std::time::Duration,
    /// Hash-table scatter-add (level-major).
    pub scatter: std::time::Duration,
}

/// Buffers of one batch, kept by the caller between iterations (reallocated only when the batch
/// grows). Holds what `backward` needs from the last `forward`/`forward_with_gradient`.
#[derive(Default)]
pub struct SdfWorkspace {
    n: usize,
    with_gradient: bool,
    x: Vec<f32>,
    enc_levels: Vec<f32>,
    jac_levels: Vec<f32>,
    gx_levels: Vec<f32>,
    abar_levels: Vec<f32>,
    /// The last backward's cotangent of the raw position input (the MLP's first 3 inputs), `[n×3]`.
    xbar: Vec<f32>,
    acts: Vec<f32>,
    gacts: Vec<f32>,
    chunks: Vec<ChunkState>,
    timings: SdfTimings,
}

impl SdfWorkspace {
    /// Phase times of the last forward and backward.
    pub fn timings(&self) -> SdfTimings {
        self.timings
    }
}

/// A raw pointer shared by the chunk tasks, which write disjoint point rows of the level-major
/// buffers (rows `[l][i]` for the `i` of their own tiles only).
#[derive(Clone, Copy)]
struct SharedMut(*mut f32);
unsafe impl Send for SharedMut {}
unsafe impl Sync for SharedMut {}

impl SharedMut {
    /// (A method, so closures capture the `Send` wrapper rather than its raw-pointer field.)
    fn ptr(self) -> *mut f32 {
        self.0
    }
}

fn resize(v: &mut Vec<f32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0.0);
    }
}

/// What every chunk task of a forward or backward reads: the batch's positions `[n×3]` and, for
/// the hash grid, its level-major encoding and Jacobian.
#[derive(Clone, Copy)]
struct BatchInputs<'a> {
    n: usize,
    x: &'a [f32],
    enc_levels: &'a [f32],
    jac_levels: &'a [f32],
}

/// The buffers a forward writes: its outputs (`∇d` when asked) and the activations kept for the
/// backward (`gacts`, of the reverse pass seeded with `d`, when `∇d` is asked).
struct ForwardOutputs<'a> {
    sdf: &'a mut [f32],
    feature: &'a mut [f32],
    gradient: Option<&'a mut [f32]>,
    acts: &'a mut [f32],
    gacts: Option<&'a mut [f32]>,
}

/// One chunk task of the forward: its range of tiles, its scratch, and its own rows of the
/// [`ForwardOutputs`] (the chunk's first row is the first row of each slice).
struct ForwardChunk<'a> {
    tiles: Range<usize>,
    st: &'a mut ChunkState,
    sdf: &'a mut [f32],
    feature: &'a mut [f32],
    gradient: Option<&'a mut [f32]>,
    acts: &'a mut [f32],
    gacts: Option<&'a mut [f32]>,
}

/// What the chunk tasks of a backward share: the last forward's batch and activations, the
/// cotangents, and the level-major cotangent buffers each task writes its own rows of.
struct BackwardShared<'a> {
    batch: BatchInputs<'a>,
    acts: &'a [f32],
    gacts: &'a [f32],
    d_sdf: &'a [f32],
    d_feature: Option<&'a [f32]>,
    d_gradient: Option<&'a [f32]>,
    xbar: SharedMut,
    abar_levels: SharedMut,
}

impl SdfNetwork {
    pub fn new(config: SdfNetworkConfig, seed: u64) -> Self {
        let (encoding, input_dim) = match &config.encoding {
            SdfEncodingConfig::HashGrid(h) => {
                let grid = HashGrid::new(h.clone(), seed ^ 0x4a54);
                let dim = 3 + grid.output_dim();
                (SdfEncoding::HashGrid(grid), dim)
            }
            SdfEncodingConfig::Frequency { frequencies } => {
                let enc = FrequencyEncoding::new(3, *frequencies);
                (SdfEncoding::Frequency(enc), enc.output_dim())
            }
        };
        let mlp_config = MlpConfig {
            input_dim,
            hidden_dim: config.hidden_dim,
            hidden_layers: config.hidden_layers,
            output_dim: 1 + config.feature_dim,
            skip_layers: config.skip_layers.clone(),
            hidden_activation: config.activation,
            output_activation: Activation::Identity,
        };
        let mut mlp = Mlp::new(mlp_config, seed);
        if let Some(init) = config.geometric_init {
            mlp.geometric_init(init, 3, seed);
        }
        SdfNetwork { config, encoding, mlp }
    }

    pub fn feature_dim(&self) -> usize {
        self.config.feature_dim
    }

    pub(crate) fn in_dim(&self) -> usize {
        self.mlp.input_dim()
    }

    fn prepare(&self, ws: &mut SdfWorkspace, x: &[f32], with_gradient: bool) {
        assert_eq!(x.len() % 3, 0, "positions must be [n×3]");
        let n = x.len() / 3;
        let (d, aw) = (self.in_dim(), self.mlp.activation_width());
        ws.n = n;
        ws.with_gradient = with_gradient;
        ws.x.clear();
        ws.x.extend_from_slice(x);
        if let SdfEncoding::HashGrid(g) = &self.encoding {
            let m = g.output_dim() * n;
            resize(&mut ws.enc_levels, m);
            resize(&mut ws.abar_levels, m);
            if with_gradient {
                resize(&mut ws.jac_levels, m * 3);
                resize(&mut ws.gx_levels, m);
            }
        }
        let padded = n.div_ceil(TILE) * TILE;
        resize(&mut ws.acts, padded * aw);
        if with_gradient {
            resize(&mut ws.gacts, padded * aw);
        }
        let want_chunks = 2 * rayon::current_num_threads();
        let stale = ws
            .chunks
            .first()
            .is_some_and(|c| c.mlp_grad.len() != self.mlp.params.len() || c.input.len() != TILE * d);
        if stale {
            ws.chunks.clear();
        }
        while ws.chunks.len() < want_chunks {
            ws.chunks.push(ChunkState {
                scratch: self.mlp.new_scratch(),
                input: vec![0.0; TILE * d],
                jac: vec![0.0; TILE * d * 3],
                gx: vec![0.0; TILE * d],
                gbar_x: vec![0.0; TILE * d],
                dx: vec![0.0; TILE * d],
                dout: vec![0.0; TILE * self.mlp.output_dim()],
                mlp_grad: vec![0.0; self.mlp.params.len()],
            });
        }
    }

    /// The MLP input of points `r0..r0+m` into `input` (and, for the positional encoding, its
    /// Jacobian into `jac` when asked).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn assemble_input(
        &self,
        ws_x: &[f32],
        enc_levels: &[f32],
        n: usize,
        r0: usize,
        m: usize,
        input: &mut [f32],
        jac: Option<&mut [f32]>,
    ) {
        let d = self.in_dim();
        match &self.encoding {
            SdfEncoding::HashGrid(g) => {
                let f = g.config.features_per_level;
                for r in 0..m {
                    input[r * d..r * d + 3].copy_from_slice(&ws_x[(r0 + r) * 3..(r0 + r) * 3 + 3]);
                }
                for l in 0..g.config.levels {
                    let src = &enc_levels[(l * n + r0) * f..(l * n + r0 + m) * f];
                    let col = 3 + l * f;
                    if f == 2 {
                        // fixed-size copies (a runtime-length `copy_from_slice` is a memcpy call)
                        for (row, s) in input.chunks_exact_mut(d).zip(src.chunks_exact(2)) {
                            row[col] = s[0];
                            row[col + 1] = s[1];
                        }
                    } else {
                        for (row, s) in input.chunks_exact_mut(d).zip(src.chunks_exact(f)) {
                            row[col..col + f].copy_from_slice(s);
                        }
                    }
                }
            }
            SdfEncoding::Frequency(e) => e.encode(&ws_x[r0 * 3..(r0 + m) * 3], input, jac),
        }
    }

    /// Inference and first-order training: writes `sdf` (`[n]`) and `feature` (`[n × feature_dim]`)
    /// for positions `x` (`[n×3]`), keeping activations in `ws` for [`SdfNetwork::backward`] without
    /// a spatial-gradient cotangent.
    pub fn forward(&self, x: &[f32], ws: &mut SdfWorkspace, sdf: &mut [f32], feature: &mut [f32]) {
        self.forward_impl(x, ws, sdf, feature, None);
    }

    /// Like [`SdfNetwork::forward`], also writing the analytic spatial gradient `∇d` (`[n×3]`, the
    /// unnormalized normal) and keeping what the double backward needs.
    pub fn forward_with_gradient(
        &self,
        x: &[f32],
        ws: &mut SdfWorkspace,
        sdf: &mut [f32],
        feature: &mut [f32],
        gradient: &mut [f32],
    ) {
        self.forward_impl(x, ws, sdf, feature, Some(gradient));
    }

    fn forward_impl(
        &self,
        x: &[f32],
        ws: &mut SdfWorkspace,
        sdf: &mut [f32],
        feature: &mut [f32],
        gradient: Option<&mut [f32]>,
    ) {
        let with_gradient = gradient.is_some();
        self.prepare(ws, x, with_gradient);
        let n = ws.n;
        assert!(sdf.len() >= n && feature.len() >= n * self.feature_dim());
        let t0 = std::time::Instant::now();
        if let SdfEncoding::HashGrid(g) = &self.encoding {
            g.encode(
                &ws.x,
                &mut ws.enc_levels,
                with_gradient.then_some(&mut ws.jac_levels[..]),
            );
        }
        let t1 = std::time::Instant::now();
        ws.timings.encode = t1 - t0;
        let gx_levels = SharedMut(ws.gx_levels.as_mut_ptr());
        let batch = BatchInputs {
            n,
            x: &ws.x,
            enc_levels: &ws.enc_levels,
            jac_levels: &ws.jac_levels,
        };
        let outputs = ForwardOutputs {
            sdf,
            feature,
            gradient,
            acts: &mut ws.acts,
            gacts: with_gradient.then_some(&mut ws.gacts[..]),
        };
        let work = self.split_forward_work(n, &mut ws.chunks, outputs);
        work.into_par_iter()
            .for_each(|chunk| self.forward_chunk(batch, gx_levels, chunk));
        ws.timings.mlp_forward = t1.elapsed();
    }

    /// The forward's chunk tasks: even ranges of tiles, each with its own rows of the outputs and
    /// its own block of the kept activations.
    fn split_forward_work<'a>(
        &self,
        n: usize,
        chunks: &'a mut [ChunkState],
        outputs: ForwardOutputs<'a>,
    ) -> Vec<ForwardChunk<'a>> {
        let (aw, fd) = (self.mlp.activation_width(), self.feature_dim());
        let ranges = even_ranges(n.div_ceil(TILE), chunks.len());
        let rows: Vec<usize> = ranges.iter().map(|r| (r.end * TILE).min(n) - r.start * TILE).collect();
        let blocks: Vec<usize> = ranges.iter().map(|r| r.len() * TILE * aw).collect();
        let sdf_parts = split_lengths_mut(&mut outputs.sdf[..n], &rows);
        let feat_rows: Vec<usize> = rows.iter().map(|r| r * fd).collect();
        let feat_parts = split_lengths_mut(&mut outputs.feature[..n * fd], &feat_rows);
        let grad_rows: Vec<usize> = rows.iter().map(|r| r * 3).collect();
        let grad_parts: Vec<Option<&mut [f32]>> = match outputs.gradient {
            Some(gr) => split_lengths_mut(&mut gr[..n * 3], &grad_rows)
                .into_iter()
                .map(Some)
                .collect(),
            None => rows.iter().map(|_| None).collect(),
        };
        let act_parts = split_lengths_mut(outputs.acts, &blocks);
        let gact_parts: Vec<Option<&mut [f32]>> = match outputs.gacts {
            Some(gacts) => split_lengths_mut(gacts, &blocks).into_iter().map(Some).collect(),
            None => rows.iter().map(|_| None).collect(),
        };
        ranges
            .into_iter()
            .zip(chunks.iter_mut())
            .zip(sdf_parts.into_iter().zip(feat_parts))
            .zip(grad_parts.into_iter().zip(act_parts.into_iter().zip(gact_parts)))
            .map(
                |(((tiles, st), (sdf, feature)), (gradient, (acts, gacts)))| ForwardChunk {
                    tiles,
                    st,
                    sdf,
                    feature,
                    gradient,
                    acts,
                    gacts,
                },
            )
            .collect()
    }

    /// One chunk task of the forward: per tile, the MLP input, the MLP forward into the kept
    /// activations, `d` and `z`, and (when asked) the reverse pass seeded with `d` and `∇d`.
    #[inline]
    fn forward_chunk(&self, batch: BatchInputs, gx_levels: SharedMut, chunk: ForwardChunk) {
        let ForwardChunk {
            tiles,
            st,
            sdf,
            feature,
            mut gradient,
            acts: acts_c,
            mut gacts,
        } = chunk;
        let (n, aw) = (batch.n, self.mlp.activation_width());
        let with_gradient = gradient.is_some();
        self.mlp.prepare_transposed(&mut st.scratch);
        for t in tiles.clone() {
            let r0 = t * TILE;
            let m = TILE.min(n - r0);
            let local = r0 - tiles.start * TILE;
            let need_jac = with_gradient && matches!(self.encoding, SdfEncoding::Frequency(_));
            self.assemble_input(
                batch.x,
                batch.enc_levels,
                n,
                r0,
                m,
                &mut st.input,
                need_jac.then_some(&mut st.jac[..]),
            );
            let acts = &mut acts_c[(t - tiles.start) * TILE * aw..][..m * aw];
            self.mlp.forward_tile(&st.input, m, acts, &mut st.scratch);
            self.write_tile_outputs(self.mlp.tile_output(acts, m), m, local, sdf, feature);
            let (Some(grad_c), Some(gacts_c)) = (gradient.as_deref_mut(), gacts.as_deref_mut()) else {
                continue;
            };
            let gacts = &mut gacts_c[(t - tiles.start) * TILE * aw..][..m * aw];
            self.mlp
                .input_gradient_tile(m, acts, 0, gacts, &mut st.gx, &mut st.scratch);
            let grad_tile = &mut grad_c[local * 3..(local + m) * 3];
            match &self.encoding {
                SdfEncoding::HashGrid(g) => self.hash_spatial_gradient(g, batch, r0, m, &st.gx, grad_tile, gx_levels),
                SdfEncoding::Frequency(_) => self.frequency_spatial_gradient(m, &st.gx, &st.jac, grad_tile),
            }
        }
    }

    /// Accumulate into `grad` the parameter gradient of `Σ d̄·d + Σ z̄·z + Σ ∇̄d·∇d` for the batch
    /// of the last forward: `d_sdf` `[n]`, `d_feature` `[n × feature_dim]` (None: zero) and
    /// `d_gradient` `[n×3]` (requires the last forward to be `forward_with_gradient`).
    pub fn backward(
        &self,
        ws: &mut SdfWorkspace,
        d_sdf: &[f32],
        d_feature: Option<&[f32]>,
        d_gradient: Option<&[f32]>,
        grad: &mut SdfGrad,
    ) {
        let t0 = std::time::Instant::now();
        let n = ws.n;
        assert!(
            d_gradient.is_none() || ws.with_gradient,
            "d_gradient needs forward_with_gradient"
        );
        assert!(d_sdf.len() >= n && d_feature.is_none_or(|f| f.len() >= n * self.feature_dim()));
        assert!(d_gradient.is_none_or(|g| g.len() >= n * 3));
        let ranges = even_ranges(n.div_ceil(TILE), ws.chunks.len());
        let abar_levels = SharedMut(ws.abar_levels.as_mut_ptr());
        resize(&mut ws.xbar, n * 3);
        let xbar = SharedMut(ws.xbar.as_mut_ptr());
        let shared = BackwardShared {
            batch: BatchInputs {
                n,
                x: &ws.x,
                enc_levels: &ws.enc_levels,
                jac_levels: &ws.jac_levels,
            },
            acts: &ws.acts,
            gacts: &ws.gacts,
            d_sdf,
            d_feature,
            d_gradient,
            xbar,
            abar_levels,
        };
        let n_ranges = ranges.len();
        let work: Vec<_> = ranges.into_iter().zip(ws.chunks.iter_mut()).collect();
        work.into_par_iter()
            .for_each(|(tiles, st)| self.backward_chunk(&shared, tiles, st));
        reduce_chunk_gradients(&mut ws.chunks, n_ranges, &mut grad.mlp);
        let t1 = std::time::Instant::now();
        ws.timings.mlp_backward = t1 - t0;
        if let SdfEncoding::HashGrid(g) = &self.encoding {
            let hg = grad.hash_grid.as_mut().expect("SdfGrad of another network");
            let m = g.output_dim() * n;
            let gx = d_gradient.map(|_| &ws.gx_levels[..m]);
            g.backward(&ws.x, &ws.abar_levels[..m], gx, d_gradient, hg);
        }
        ws.timings.scatter = t1.elapsed();
    }

    /// One chunk task of the backward: per tile, the MLP input again, the output cotangent, the
    /// MLP backward (double backward with a `∇̄d`) into the chunk's parameter-gradient accumulator,
    /// and the input cotangent handed to the hash-grid scatter.
    #[inline]
    fn backward_chunk(&self, sh: &BackwardShared, tiles: Range<usize>, st: &mut ChunkState) {
        let (n, aw) = (sh.batch.n, self.mlp.activation_width());
        st.mlp_grad.fill(0.0);
        if sh.d_gradient.is_some() {
            self.mlp.prepare_transposed(&mut st.scratch);
        }
        for t in tiles {
            let r0 = t * TILE;
            let m = TILE.min(n - r0);
            let need_jac = sh.d_gradient.is_some() && matches!(self.encoding, SdfEncoding::Frequency(_));
            self.assemble_input(
                sh.batch.x,
                sh.batch.enc_levels,
                n,
                r0,
                m,
                &mut st.input,
                need_jac.then_some(&mut st.jac[..]),
            );
            self.seed_output_cotangent(sh, r0, m, &mut st.dout);
            let acts = &sh.acts[t * TILE * aw..][..m * aw];
            let hash = matches!(self.encoding, SdfEncoding::HashGrid(_));
            let dx = hash.then_some(&mut st.dx[..]);
            match sh.d_gradient {
                Some(v) => {
                    let v = &v[r0 * 3..(r0 + m) * 3];
                    match &self.encoding {
                        SdfEncoding::HashGrid(g) => self.hash_gbar_x(g, sh.batch, r0, m, v, &mut st.gbar_x),
                        SdfEncoding::Frequency(_) => self.frequency_gbar_x(m, v, &st.jac, &mut st.gbar_x),
                    }
                    let gacts = &sh.gacts[t * TILE * aw..][..m * aw];
                    self.mlp.double_backward_tile(
                        &st.input,
                        m,
                        acts,
                        gacts,
                        0,
                        &st.dout,
                        &st.gbar_x,
                        &mut st.mlp_grad,
                        dx,
                        &mut st.scratch,
                    );
                }
                None => self
                    .mlp
                    .backward_tile(&st.input, m, acts, &st.dout, &mut st.mlp_grad, dx, &mut st.scratch),
            }
            if let SdfEncoding::HashGrid(g) = &self.encoding {
                self.store_input_cotangent(g, sh, r0, m, &st.dx);
            }
        }
    }
}

/// The stages of a tile in the forward and backward chunk tasks.
impl SdfNetwork {
    /// Splits a tile's MLP output rows `[m × (1 + feature_dim)]` into `d` and `z`, at the chunk's
    /// rows `local..local + m`.
    #[inline]
    fn write_tile_outputs(&self, out: &[f32], m: usize, local: usize, sdf: &mut [f32], feature: &mut [f32]) {
        let fd = self.feature_dim();
        let od = fd + 1;
        for r in 0..m {
            sdf[local + r] = out[r * od];
            feature[(local + r) * fd..(local + r + 1) * fd].copy_from_slice(&out[r * od + 1..(r + 1) * od]);
        }
    }

    /// `∇d = Jᵀ G_X` of a tile (`grad`: its `[m×3]` rows) for the hash grid: the position columns
    /// of `G_X`, plus every level's feature columns through the encoding's Jacobian. The feature
    /// columns are also kept level-major in `gx_levels`, for the curvature term of the scatter.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn hash_spatial_gradient(
        &self,
        g: &HashGrid,
        batch: BatchInputs,
        r0: usize,
        m: usize,
        gx: &[f32],
        grad: &mut [f32],
        gx_levels: SharedMut,
    ) {
        let (d, n, f) = (self.in_dim(), batch.n, g.config.features_per_level);
        for r in 0..m {
            grad[r * 3..r * 3 + 3].copy_from_slice(&gx[r * d..r * d + 3]);
        }
        for l in 0..g.config.levels {
            let jac = &batch.jac_levels[(l * n + r0) * f * 3..(l * n + r0 + m) * f * 3];
            for r in 0..m {
                let gv = &mut grad[r * 3..r * 3 + 3];
                for ff in 0..f {
                    let gxv = gx[r * d + 3 + l * f + ff];
                    let j = &jac[(r * f + ff) * 3..(r * f + ff) * 3 + 3];
                    gv[0] += gxv * j[0];
                    gv[1] += gxv * j[1];
                    gv[2] += gxv * j[2];
                    // SAFETY: row (l, r0 + r) belongs to this chunk's tiles only.
                    unsafe { *gx_levels.ptr().add((l * n + r0 + r) * f + ff) = gxv };
                }
            }
        }
    }

    /// `∇d = Jᵀ G_X` of a tile for the positional encoding, whose Jacobian `jac` (`[m × d × 3]`)
    /// the tile's input assembly wrote.
    #[inline]
    fn frequency_spatial_gradient(&self, m: usize, gx: &[f32], jac: &[f32], grad: &mut [f32]) {
        let d = self.in_dim();
        for r in 0..m {
            let mut gv = [0f32; 3];
            for o in 0..d {
                let j = &jac[(r * d + o) * 3..(r * d + o) * 3 + 3];
                for k in 0..3 {
                    gv[k] += gx[r * d + o] * j[k];
                }
            }
            grad[r * 3..r * 3 + 3].copy_from_slice(&gv);
        }
    }

    /// The cotangent of a tile's MLP outputs, `[d̄, z̄]` per row (`z̄` zero when there is none).
    #[inline]
    fn seed_output_cotangent(&self, sh: &BackwardShared, r0: usize, m: usize, dout: &mut [f32]) {
        let fd = self.feature_dim();
        let od = fd + 1;
        for r in 0..m {
            dout[r * od] = sh.d_sdf[r0 + r];
            let dst = &mut dout[r * od + 1..(r + 1) * od];
            match sh.d_feature {
                Some(df) => dst.copy_from_slice(&df[(r0 + r) * fd..(r0 + r + 1) * fd]),
                None => dst.fill(0.0),
            }
        }
    }

    /// `Ḡ_X = J ∇̄d` of the tile of rows `r0..r0 + m` for the hash grid (`v`: the tile's `[m×3]`
    /// rows of `∇̄d`): the position columns are `∇̄d` itself, each feature column its Jacobian row
    /// dotted with `∇̄d`. (The features of a row are zipped with their Jacobian rows: indexed, the
    /// loop over them got vectorized for long rows, and its set-up, paid per row and level,
    /// measured about twice the time of the whole stage for the usual 2 features.)
    #[inline]
    fn hash_gbar_x(&self, g: &HashGrid, batch: BatchInputs, r0: usize, m: usize, v: &[f32], gbar_x: &mut [f32]) {
        let (d, n, f) = (self.in_dim(), batch.n, g.config.features_per_level);
        for r in 0..m {
            gbar_x[r * d..r * d + 3].copy_from_slice(&v[r * 3..r * 3 + 3]);
        }
        for l in 0..g.config.levels {
            let jac = &batch.jac_levels[(l * n + r0) * f * 3..(l * n + r0 + m) * f * 3];
            let col = 3 + l * f;
            for r in 0..m {
                let vi = &v[r * 3..r * 3 + 3];
                let out = &mut gbar_x[r * d + col..r * d + col + f];
                for (o, j) in out.iter_mut().zip(jac[r * f * 3..(r + 1) * f * 3].chunks_exact(3)) {
                    *o = j[0] * vi[0] + j[1] * vi[1] + j[2] * vi[2];
                }
            }
        }
    }

    /// `Ḡ_X = J ∇̄d` of a tile for the positional encoding (its Jacobian `jac`: `[m × d × 3]`).
    #[inline]
    fn frequency_gbar_x(&self, m: usize, v: &[f32], jac: &[f32], gbar_x: &mut [f32]) {
        let d = self.in_dim();
        for r in 0..m {
            let vi = &v[r * 3..r * 3 + 3];
            for o in 0..d {
                let j = &jac[(r * d + o) * 3..(r * d + o) * 3 + 3];
                gbar_x[r * d + o] = j[0] * vi[0] + j[1] * vi[1] + j[2] * vi[2];
            }
        }
    }

    /// Hands a tile's MLP input cotangent `X̄` (`dx`) on, level-major: its position columns to
    /// `xbar` (for [`SdfNetwork::position_gradient`]), its feature columns to `abar_levels` (what
    /// the hash-table scatter adds up). Row by row, with fixed-size copies for the usual 2
    /// features (as in `assemble_input`): an indexed loop over a row's features got vectorized,
    /// and its set-up, paid per row and level, cost more than the copies.
    #[inline]
    fn store_input_cotangent(&self, g: &HashGrid, sh: &BackwardShared, r0: usize, m: usize, dx: &[f32]) {
        let (d, n, f) = (self.in_dim(), sh.batch.n, g.config.features_per_level);
        // SAFETY (both slices): rows r0..r0 + m (of each level) belong to this chunk's tiles only,
        // and the buffers hold n rows.
        let xbar = unsafe { std::slice::from_raw_parts_mut(sh.xbar.ptr().add(r0 * 3), m * 3) };
        for (o, s) in xbar.chunks_exact_mut(3).zip(dx.chunks_exact(d)) {
            o[0] = s[0];
            o[1] = s[1];
            o[2] = s[2];
        }
        for l in 0..g.config.levels {
            let abar = unsafe { std::slice::from_raw_parts_mut(sh.abar_levels.ptr().add((l * n + r0) * f), m * f) };
            let col = 3 + l * f;
            if f == 2 {
                for (o, s) in abar.chunks_exact_mut(2).zip(dx.chunks_exact(d)) {
                    o[0] = s[col];
                    o[1] = s[col + 1];
                }
            } else {
                for (o, s) in abar.chunks_exact_mut(f).zip(dx.chunks_exact(d)) {
                    o.copy_from_slice(&s[col..col + f]);
                }
            }
        }
    }
}

/// Adds the parameter-gradient accumulators of the first `n_chunks` chunks into `out`, lending
/// them to [`reduce_into`] and putting them back (no copy, no allocation but the list).
fn reduce_chunk_gradients(chunks: &mut [ChunkState], n_chunks: usize, out: &mut [f32]) {
    let accs: Vec<Vec<f32>> = chunks[..n_chunks]
        .iter_mut()
        .map(|c| std::mem::take(&mut c.mlp_grad))
        .collect();
    reduce_into(out, &accs);
    for (c, acc) in chunks.iter_mut().zip(accs) {
        c.mlp_grad = acc;
    }
}

impl SdfNetwork {
    /// After [`SdfNetwork::backward`] of a [`SdfNetwork::forward_with_gradient`] batch with a
    /// hash-grid encoding: writes into `out` (`[n×3]`) the gradient of the backward's objective
    /// `Σ d̄·d + Σ z̄·z` w.r.t. the input positions (what a camera pose correction needs: how the
    /// loss moves with the points). The curvature term of a `∇̄d` cotangent (through the
    /// encoding's second derivatives) is left out: trilinear cells have none along each axis and
    /// the pose correction only needs a descent direction. `None` for the frequency encoding,
    /// whose Jacobian the forward does not keep.
    pub fn position_gradient(&self, ws: &SdfWorkspace, out: &mut [f32]) -> Option<()> {
        let SdfEncoding::HashGrid(g) = &self.encoding else {
            return None;
        };
        if !ws.with_gradient {
            return None;
        }
        let (n, f) = (ws.n, g.config.features_per_level);
        out[..n * 3].copy_from_slice(&ws.xbar[..n * 3]);
        for l in 0..g.config.levels {
            let abar = &ws.abar_levels[l * n * f..(l + 1) * n * f];
            let jac = &ws.jac_levels[l * n * f * 3..(l + 1) * n * f * 3];
            for i in 0..n {
                for ff in 0..f {
                    let a = abar[i * f + ff];
                    let j = &jac[(i * f + ff) * 3..(i * f + ff) * 3 + 3];
                    for k in 0..3 {
                        out[i * 3 + k] += a * j[k];
                    }
                }
            }
        }
        Some(())
    }
}

/// Positions of the 6-point central-difference stencil (Neuralangelo's numerical gradient): `out`
/// becomes `7n` points in 7 blocks of `n` — `x`, then `x + εe_k` and `x − εe_k` for `k = 0, 1, 2`.
/// Evaluate them with [`SdfNetwork::forward`], then use [`central_difference_gradient`] and, for
/// the backward, [`central_difference_cotangent`]. Neuralangelo ties `ε` to the cell size of the
/// finest active hash level ([`crate::HashGrid::cell_size`]).
pub fn central_difference_points(x: &[f32], eps: f32, out: &mut Vec<f32>) {
    out.clear();
    out.extend_from_slice(x);
    for k in 0..3 {
        for sign in [1.0f32, -1.0] {
            out.extend(x.chunks_exact(3).flat_map(|p| {
                let mut q = [p[0], p[1], p[2]];
                q[k] += sign * eps;
                q
            }));
        }
    }
}

/// `∇d ≈ (d(x + εe_k) − d(x − εe_k)) / 2ε` from the `7n` distances of the stencil.
pub fn central_difference_gradient(sdf7: &[f32], eps: f32, gradient: &mut [f32]) {
    let n = sdf7.len() / 7;
    for i in 0..n {
        for k in 0..3 {
            gradient[i * 3 + k] = (sdf7[(1 + 2 * k) * n + i] - sdf7[(2 + 2 * k) * n + i]) / (2.0 * eps);
        }
    }
}

/// Cotangent of the `7n` stencil distances given `d̄` (`[n]`) and `∇̄d` (`[n×3]`).
pub fn central_difference_cotangent(d_sdf: &[f32], d_gradient: &[f32], eps: f32, d_sdf7: &mut [f32]) {
    let n = d_sdf.len();
    d_sdf7[..n].copy_from_slice(d_sdf);
    for i in 0..n {
        for k in 0..3 {
            let c = d_gradient[i * 3 + k] / (2.0 * eps);
            d_sdf7[(1 + 2 * k) * n + i] = c;
            d_sdf7[(2 + 2 * k) * n + i] = -c;
        }
    }
}

#[cfg(test)]
#[path = "sdf_tests.rs"]
mod tests;
