//! Fully connected networks of any depth and width with skip connections, evaluated tile by tile.
//!
//! Layer `l` computes `Z_l = I_l W_lᵀ + b_l`, `A_l = φ_l(Z_l)` for a tile of points at once (rows),
//! with `I_0 = X` and `I_l = A_{l−1}`, or for a skip layer `I_l = [A_{l−1}, X]/√2` (IDR/VolSDF's
//! convention, so the skip does not double the activation variance). `W_l` is `[out×in]` row-major,
//! followed by `b_l`, all layers in one flat parameter vector.
//!
//! Besides forward/backward, the tile kernels implement what the SDF spatial gradient needs:
//! * [`Mlp::input_gradient_tile`] — a reverse pass seeded with one output (`∂y_s/∂X`), keeping the
//!   per-layer cotangents `G_{A_l}`;
//! * [`Mlp::double_backward_tile`] — the reverse of both passes at once ("reverse over reverse"),
//!   given the output cotangent `Ȳ` and the cotangent `Ḡ_X` of the input gradient. The reverse of
//!   `G_{I_l} = (φ'_l ⊙ G_{A_l}) W_l` runs upward: `Ḡ_{Z_l} = Ḡ_{I_l} W_lᵀ`,
//!   `W̄_l += G_{Z_l}ᵀ Ḡ_{I_l}`, `Ḡ_{A_l} = φ'_l ⊙ Ḡ_{Z_l}`, and the dependence of `φ'_l` on `Z_l`
//!   adds `Z̄_l += φ''_l ⊙ G_{A_l} ⊙ Ḡ_{Z_l}` to the ordinary downward reverse pass. That is 6 matrix
//!   products per layer, against 12 for forward-mode tangents in 3 directions.

use crate::activation::Activation;
use crate::linalg::{gemm_a_b, gemm_a_bt, gemm_at_b_acc, MatmulPrecision};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// Points per tile: a 256×64 activation block is 64 KiB, so a layer's input, output and cotangents
/// stay in the 1 MiB L2 while its products run.
pub const TILE: usize = 256;

const SKIP_SCALE: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// Shape of an MLP: `hidden_layers` hidden layers of `hidden_dim` (so `hidden_layers + 1` linear
/// layers). `skip_layers` lists linear-layer indices (1..=hidden_layers) whose input is
/// `[previous activation, network input]/√2`; the paper's SDF MLP is 8×256 with `skip_layers = [4]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MlpConfig {
    pub input_dim: usize,
    pub hidden_dim: usize,
    pub hidden_layers: usize,
    pub output_dim: usize,
    #[serde(default)]
    pub skip_layers: Vec<usize>,
    pub hidden_activation: Activation,
    pub output_activation: Activation,
}

/// One linear layer's place in the parameter vector and in a tile's activation block.
#[derive(Clone, Debug)]
pub struct Layer {
    pub in_dim: usize,
    pub out_dim: usize,
    /// Offset of `W` (`[out×in]`) in the parameter vector; `b` follows it.
    pub weight_offset: usize,
    pub bias_offset: usize,
    pub skip: bool,
    pub activation: Activation,
    /// Offset of this layer's outputs inside a tile's activation block, in units of rows
    /// (the block holds layer `l` at `rows · act_offset`, `rows × out_dim`).
    pub act_offset: usize,
}

/// Initialization of the SDF network as a sphere (Atzmon & Lipman 2020, SAL; IDR's code): the
/// network then starts as `sdf ≈ ‖x‖ − r`, or `r − ‖x‖` when `inside_out` (indoor scenes: the cameras
/// are inside, so the room starts as free space). The first `position_dims` input columns are the raw
/// position; all other input columns (positional encoding, hash features) start with zero weight.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeometricInit {
    pub radius: f32,
    pub inside_out: bool,
}

/// A multilayer perceptron: configuration, layer table and its flat parameter vector.
#[derive(Clone, Debug)]
pub struct Mlp {
    pub config: MlpConfig,
    pub layers: Vec<Layer>,
    pub params: Vec<f32>,
    /// Operand precision of this network's products (f32 unless a caller sets it: stage 1 does,
    /// from `train.matmul_precision`); not part of the network's state, never saved.
    pub precision: MatmulPrecision,
    act_width: usize,
    max_in: usize,
    max_out: usize,
}

/// Per-thread scratch for the tile kernels (allocated once, reused for every tile).
pub struct TileScratch {
    concat: Vec<f32>,
    ibar: Vec<f32>,
    zbar: Vec<f32>,
    gbar_z: [Vec<f32>; 2],
    gbar_in: Vec<f32>,
    gz: Vec<f32>,
    /// `W̄ᵀ` of one layer, for layers whose weight gradient is formed transposed.
    wt: Vec<f32>,
    zextra: Vec<f32>,
    /// `φ'` of every layer output (layer-blocked), computed once per double backward.
    deriv: Vec<f32>,
    /// `W_lᵀ` of every layer (`[in×out]`, at `Σ_{j<l} in_j·out_j`), valid while
    /// `transposed_ready`: the batch entry points fill it once per chunk of tiles, so the `A·Wᵀ`
    /// products (forward, `Ḡ_Z`) need not transpose `W` on every tile.
    transposed: Vec<f32>,
    transposed_ready: bool,
}

impl TileScratch {
    /// Does it hold the transposed weights of the last [`Mlp::prepare_transposed`]?
    pub(crate) fn transposed_ready(&self) -> bool {
        self.transposed_ready
    }
}

impl Mlp {
    /// A network with default initialization (weights `N(0, 2/in)`, zero biases), seeded.
    pub fn new(config: MlpConfig, seed: u64) -> Self {
        assert!(config.input_dim > 0 && config.output_dim > 0);
        assert!(config.hidden_layers == 0 || config.hidden_dim > 0);
        let n_layers = config.hidden_layers + 1;
        for &s in &config.skip_layers {
            assert!(s >= 1 && s < n_layers, "skip layer {s} must be in 1..{n_layers}");
        }
        let mut layers = Vec::with_capacity(n_layers);
        let (mut offset, mut act_offset) = (0, 0);
        for l in 0..n_layers {
            let skip = config.skip_layers.contains(&l);
            let prev = if l == 0 { config.input_dim } else { config.hidden_dim };
            let in_dim = prev + if skip { config.input_dim } else { 0 };
            let last = l + 1 == n_layers;
            let out_dim = if last { config.output_dim } else { config.hidden_dim };
            let activation = if last {
                config.output_activation
            } else {
                config.hidden_activation
            };
            layers.push(Layer {
                in_dim,
                out_dim,
                weight_offset: offset,
                bias_offset: offset + in_dim * out_dim,
                skip,
                activation,
                act_offset,
            });
            offset += in_dim * out_dim + out_dim;
            act_offset += out_dim;
        }
        let max_in = layers.iter().map(|l| l.in_dim).max().unwrap();
        let max_out = layers.iter().map(|l| l.out_dim).max().unwrap();
        let mut mlp = Mlp {
            config,
            layers,
            params: vec![0.0; offset],
            precision: MatmulPrecision::F32,
            act_width: act_offset,
            max_in,
            max_out,
        };
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        for layer in mlp.layers.clone() {
            let std = (2.0 / layer.in_dim as f32).sqrt();
            for w in &mut mlp.params[layer.weight_offset..layer.bias_offset] {
                *w = std * normal(&mut rng);
            }
        }
        mlp
    }

    /// Re-initialize as a sphere SDF (see [`GeometricInit`]); `position_dims` raw position columns
    /// lead the input.
    pub fn geometric_init(&mut self, init: GeometricInit, position_dims: usize, seed: u64) {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed ^ 0x5EED);
        let n = self.layers.len();
        let input_dim = self.config.input_dim;
        for (l, layer) in self.layers.clone().iter().enumerate() {
            let (w0, b0) = (layer.weight_offset, layer.bias_offset);
            let (inn, out) = (layer.in_dim, layer.out_dim);
            if l + 1 == n {
                let sign = if init.inside_out { -1.0 } else { 1.0 };
                let mean = sign * (std::f32::consts::PI / inn as f32).sqrt();
                for w in &mut self.params[w0..b0] {
                    *w = mean + 1e-4 * normal(&mut rng);
                }
                for b in &mut self.params[b0..b0 + out] {
                    *b = -sign * init.radius;
                }
                continue;
            }
            let std = std::f32::consts::SQRT_2 / (out as f32).sqrt();
            // Columns holding non-position inputs (all of them except the raw position).
            let feature_cols = if l == 0 {
                position_dims..inn
            } else if layer.skip {
                (inn - input_dim + position_dims)..inn
            } else {
                0..0
            };
            for r in 0..out {
                for c in 0..inn {
                    self.params[w0 + r * inn + c] = if feature_cols.contains(&c) {
                        0.0
                    } else {
                        std * normal(&mut rng)
                    };
                }
            }
            self.params[b0..b0 + out].fill(0.0);
        }
    }

    pub fn input_dim(&self) -> usize {
        self.config.input_dim
    }
    pub fn output_dim(&self) -> usize {
        self.config.output_dim
    }
    /// Floats per point of the stored activation block (sum of layer widths).
    pub fn activation_width(&self) -> usize {
        self.act_width
    }

    /// Multiply-adds per point of one forward pass.
    pub fn macs_per_point(&self) -> usize {
        self.layers.iter().map(|l| l.in_dim * l.out_dim).sum()
    }

    pub fn new_scratch(&self) -> TileScratch {
        TileScratch {
            concat: vec![0.0; TILE * self.max_in],
            // zbar and ibar trade places in `reverse_down`: same size
            ibar: vec![0.0; TILE * self.max_out.max(self.max_in)],
            zbar: vec![0.0; TILE * self.max_out.max(self.max_in)],
            gbar_z: [vec![0.0; TILE * self.max_out], vec![0.0; TILE * self.max_out]],
            gbar_in: vec![0.0; TILE * self.max_in],
            gz: vec![0.0; TILE * self.max_out],
            wt: vec![0.0; self.layers.iter().map(|l| l.in_dim * l.out_dim).max().unwrap()],
            zextra: vec![0.0; TILE * self.act_width],
            deriv: vec![0.0; TILE * self.act_width],
            transposed: Vec::new(),
            transposed_ready: false,
        }
    }

    /// Fill `scratch` with every `W_lᵀ` for the tiles that follow. The batch entry points
    /// (`SdfNetwork`, `Mlp::forward`) call it at the start of each chunk of tiles, so it always
    /// reflects the current weights; a scratch from [`Mlp::new_scratch`] never has it.
    pub(crate) fn prepare_transposed(&self, scratch: &mut TileScratch) {
        let total: usize = self.layers.iter().map(|l| l.in_dim * l.out_dim).sum();
        scratch.transposed.resize(total, 0.0);
        let mut off = 0;
        for layer in &self.layers {
            let (i, o) = (layer.in_dim, layer.out_dim);
            let w = &self.params[layer.weight_offset..layer.bias_offset];
            let wt = &mut scratch.transposed[off..off + i * o];
            for r in 0..o {
                for c in 0..i {
                    wt[c * o + r] = w[r * i + c];
                }
            }
            off += i * o;
        }
        scratch.transposed_ready = true;
    }

    /// `C[n×out] = beta·C + A[n×in] · W_lᵀ`, from the prepared `W_lᵀ` when there is one.
    #[allow(clippy::too_many_arguments)]
    fn product_a_wt(&self, l: usize, n: usize, a: &[f32], beta: f32, c: &mut [f32], transposed: Option<&[f32]>) {
        let layer = &self.layers[l];
        let (i, o) = (layer.in_dim, layer.out_dim);
        match transposed {
            Some(t) => {
                let off: usize = self.layers[..l].iter().map(|l| l.in_dim * l.out_dim).sum();
                gemm_a_b(n, i, o, a, i, &t[off..off + i * o], o, beta, c, o, self.precision)
            }
            None => gemm_a_bt(
                n,
                i,
                o,
                a,
                i,
                &self.params[layer.weight_offset..layer.bias_offset],
                i,
                beta,
                c,
                o,
                self.precision,
            ),
        }
    }

    /// `W̄_l += Z̄ᵀ I` over the `n` points of a tile (`zbar` `[n×out]`, `input` `[n×in]`). The
    /// product's output rows are vectorized 16 lanes at a time, so a `[out×in]` result with
    /// `in = 35` wastes 27 % of the lanes; when `W̄ᵀ` (`[in×out]`) needs fewer vector operations
    /// (`in·⌈out/16⌉ < out·⌈in/16⌉`, e.g. the first layer 35 → 64), it is formed transposed in
    /// scratch and added back (an `in×out` transpose per tile, ~0.4 % of the product).
    fn accumulate_weight_grad(
        &self,
        l: usize,
        n: usize,
        zbar: &[f32],
        input: &[f32],
        grad_w: &mut [f32],
        wt: &mut [f32],
    ) {
        let (o, i) = (self.layers[l].out_dim, self.layers[l].in_dim);
        if i * o.div_ceil(16) < o * i.div_ceil(16) {
            let wt = &mut wt[..i * o];
            wt.fill(0.0);
            gemm_at_b_acc(i, n, o, input, i, zbar, o, wt, o, self.precision);
            for (r, gw_row) in grad_w.chunks_exact_mut(i).enumerate() {
                for (c, g) in gw_row.iter_mut().enumerate() {
                    *g += wt[c * o + r];
                }
            }
        } else {
            gemm_at_b_acc(o, n, i, zbar, o, input, i, grad_w, i, self.precision);
        }
    }

    /// The input of layer `l` for a tile: `x`, the previous activation, or (skip) their scaled
    /// concatenation built in `concat`.
    fn layer_input<'a>(&self, l: usize, x: &'a [f32], acts: &'a [f32], n: usize, concat: &'a mut [f32]) -> &'a [f32] {
        if l == 0 {
            return &x[..n * self.config.input_dim];
        }
        let prev = &self.layers[l - 1];
        let a_prev = &acts[n * prev.act_offset..n * (prev.act_offset + prev.out_dim)];
        if !self.layers[l].skip {
            return a_prev;
        }
        let (h, d, w) = (prev.out_dim, self.config.input_dim, self.layers[l].in_dim);
        for r in 0..n {
            let row = &mut concat[r * w..(r + 1) * w];
            for (o, &a) in row[..h].iter_mut().zip(&a_prev[r * h..(r + 1) * h]) {
                *o = a * SKIP_SCALE;
            }
            for (o, &v) in row[h..].iter_mut().zip(&x[r * d..(r + 1) * d]) {
                *o = v * SKIP_SCALE;
            }
        }
        &concat[..n * w]
    }

    /// Forward pass of one tile: `x` is `[n × input_dim]`, `acts` receives every layer's output
    /// (`n × activation_width`, layer-blocked); the network output is the last block.
    pub fn forward_tile(&self, x: &[f32], n: usize, acts: &mut [f32], scratch: &mut TileScratch) {
        debug_assert!(n <= TILE);
        for (l, layer) in self.layers.iter().enumerate() {
            let (done, rest) = acts.split_at_mut(n * layer.act_offset);
            let out = &mut rest[..n * layer.out_dim];
            let bias = &self.params[layer.bias_offset..layer.bias_offset + layer.out_dim];
            let input = self.layer_input(l, x, done, n, &mut scratch.concat);
            let transposed = scratch.transposed_ready.then_some(&scratch.transposed[..]);
            // The product overwrites (no read of C) and the bias is added after it: filling every
            // row with the bias first cost a `memmove` call per row (5–8 % of a training step).
            self.product_a_wt(l, n, input, 0.0, out, transposed);
            for row in out.chunks_exact_mut(layer.out_dim) {
                for (o, &b) in row.iter_mut().zip(bias) {
                    *o += b;
                }
            }
            layer.activation.forward_inplace(out);
        }
    }

    /// The output block of a tile's activations.
    pub fn tile_output<'a>(&self, acts: &'a [f32], n: usize) -> &'a [f32] {
        let last = self.layers.last().unwrap();
        &acts[n * last.act_offset..n * (last.act_offset + last.out_dim)]
    }

    /// Distribute the cotangent `ibar` (`n × in_dim` of layer `l`) to the previous layer's output
    /// (written to `prev_out`) and, for layer 0 and skip layers, accumulated into `d_x`.
    fn split_input_cotangent(&self, l: usize, n: usize, ibar: &[f32], prev_out: &mut [f32], d_x: Option<&mut [f32]>) {
        let layer = &self.layers[l];
        let d = self.config.input_dim;
        if l == 0 {
            if let Some(d_x) = d_x {
                for (o, &v) in d_x[..n * d].iter_mut().zip(ibar) {
                    *o += v;
                }
            }
            return;
        }
        let h = self.layers[l - 1].out_dim;
        if !layer.skip {
            prev_out[..n * h].copy_from_slice(&ibar[..n * h]);
            return;
        }
        let w = layer.in_dim;
        for r in 0..n {
            let row = &ibar[r * w..(r + 1) * w];
            for (o, &v) in prev_out[r * h..(r + 1) * h].iter_mut().zip(&row[..h]) {
                *o = v * SKIP_SCALE;
            }
        }
        if let Some(d_x) = d_x {
            for r in 0..n {
                let row = &ibar[r * w + h..(r + 1) * w];
                for (o, &v) in d_x[r * d..(r + 1) * d].iter_mut().zip(row) {
                    *o += v * SKIP_SCALE;
                }
            }
        }
    }

    /// The downward reverse pass: `scratch.zbar` holds `Ā` of the output (`n × output_dim`);
    /// `second_order`, when given, holds `φ'` of every layer and additional `Z̄_l` terms
    /// (both layer-blocked). Accumulates parameter
    /// gradients into `grad` and, when given, overwrites `d_x` with the input cotangent.
    #[allow(clippy::too_many_arguments)]
    fn reverse_down(
        &self,
        x: &[f32],
        n: usize,
        acts: &[f32],
        second_order: Option<(&[f32], &[f32])>,
        grad: &mut [f32],
        mut d_x: Option<&mut [f32]>,
        scratch: &mut TileScratch,
    ) {
        if let Some(d_x) = d_x.as_deref_mut() {
            d_x[..n * self.config.input_dim].fill(0.0);
        }
        for l in (0..self.layers.len()).rev() {
            let layer = &self.layers[l];
            let (o, i) = (layer.out_dim, layer.in_dim);
            let a = &acts[n * layer.act_offset..n * (layer.act_offset + o)];
            let zbar = &mut scratch.zbar[..n * o];
            match second_order {
                Some((deriv, extra)) => {
                    let range = n * layer.act_offset..n * (layer.act_offset + o);
                    for ((z, &s), &e) in zbar.iter_mut().zip(&deriv[range.clone()]).zip(&extra[range]) {
                        *z = *z * s + e;
                    }
                }
                None => layer.activation.backward_inplace(a, zbar),
            }
            let input = self.layer_input(l, x, acts, n, &mut scratch.concat);
            let (gw, gb) = grad[layer.weight_offset..layer.bias_offset + o].split_at_mut(i * o);
            self.accumulate_weight_grad(l, n, zbar, input, gw, &mut scratch.wt);
            for row in zbar.chunks_exact(o) {
                for (g, &z) in gb.iter_mut().zip(row) {
                    *g += z;
                }
            }
            if l > 0 || d_x.is_some() {
                let w = &self.params[layer.weight_offset..layer.bias_offset];
                gemm_a_b(n, o, i, zbar, o, w, i, 0.0, &mut scratch.ibar, i, self.precision);
                if l > 0 && !layer.skip {
                    // Ī_l is Ā_{l−1} as it is: swap the buffers instead of copying
                    std::mem::swap(&mut scratch.zbar, &mut scratch.ibar);
                } else {
                    self.split_input_cotangent(l, n, &scratch.ibar[..n * i], &mut scratch.zbar, d_x.as_deref_mut());
                }
            }
        }
    }

    /// Backward pass of one tile: `d_out` (`n × output_dim`) is the cotangent of the output.
    /// Accumulates parameter gradients into `grad` (same layout as `params`) and, when given,
    /// overwrites `d_x` (`n × input_dim`) with the input cotangent.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_tile(
        &self,
        x: &[f32],
        n: usize,
        acts: &[f32],
        d_out: &[f32],
        grad: &mut [f32],
        d_x: Option<&mut [f32]>,
        scratch: &mut TileScratch,
    ) {
        let od = self.config.output_dim;
        scratch.zbar[..n * od].copy_from_slice(&d_out[..n * od]);
        self.reverse_down(x, n, acts, None, grad, d_x, scratch);
    }

    /// `G_X = ∂y_seed/∂X` for every point of a tile (`n × input_dim`, overwritten), keeping the
    /// cotangents `G_{A_l}` of every layer output in `gacts` (layer-blocked like `acts`) for
    /// [`Mlp::double_backward_tile`].
    pub fn input_gradient_tile(
        &self,
        n: usize,
        acts: &[f32],
        seed: usize,
        gacts: &mut [f32],
        g_x: &mut [f32],
        scratch: &mut TileScratch,
    ) {
        let d = self.config.input_dim;
        g_x[..n * d].fill(0.0);
        let last = self.layers.last().unwrap();
        let top = &mut gacts[n * last.act_offset..n * (last.act_offset + last.out_dim)];
        top.fill(0.0);
        for row in top.chunks_exact_mut(last.out_dim) {
            row[seed] = 1.0;
        }
        for l in (0..self.layers.len()).rev() {
            let layer = &self.layers[l];
            let (o, i) = (layer.out_dim, layer.in_dim);
            let a = &acts[n * layer.act_offset..n * (layer.act_offset + o)];
            let (lower, upper) = gacts.split_at_mut(n * layer.act_offset);
            let w = &self.params[layer.weight_offset..layer.bias_offset];
            if l + 1 == self.layers.len() {
                // The seed is one-hot, so G_{I} = φ'(z_seed) · W[seed, :]: a scaled row, no product.
                let w_row = &w[seed * i..(seed + 1) * i];
                for r in 0..n {
                    let s = layer.activation.derivative_from_output(a[r * o + seed]);
                    for (dst, &wv) in scratch.ibar[r * i..(r + 1) * i].iter_mut().zip(w_row) {
                        *dst = s * wv;
                    }
                }
            } else {
                let gz = &mut scratch.gz[..n * o];
                gz.copy_from_slice(&upper[..n * o]);
                layer.activation.backward_inplace(a, gz);
                if l > 0 && !layer.skip {
                    // G_{A_{l−1}} = G_{I_l}: write the product where it is kept
                    let prev = &mut lower[n * self.layers[l - 1].act_offset..];
                    gemm_a_b(n, o, i, gz, o, w, i, 0.0, prev, i, self.precision);
                    continue;
                }
                gemm_a_b(n, o, i, gz, o, w, i, 0.0, &mut scratch.ibar, i, self.precision);
            }
            let prev_out = if l > 0 {
                &mut lower[n * self.layers[l - 1].act_offset..]
            } else {
                &mut [][..]
            };
            self.split_input_cotangent(l, n, &scratch.ibar[..n * i], prev_out, Some(&mut *g_x));
        }
    }

    /// The reverse of forward *and* of [`Mlp::input_gradient_tile`] (run with the same `seed`) for
    /// one tile: given `d_out = Ȳ` and `gbar_x = Ḡ_X` (the cotangent of `G_X`, `n × input_dim`),
    /// accumulates the gradient of
    /// `⟨Ȳ, Y⟩ + ⟨Ḡ_X, G_X⟩` w.r.t. the parameters into `grad` and, when given, overwrites `d_x`
    /// with its gradient w.r.t. the input `X`.
    #[allow(clippy::too_many_arguments)]
    pub fn double_backward_tile(
        &self,
        x: &[f32],
        n: usize,
        acts: &[f32],
        gacts: &[f32],
        seed: usize,
        d_out: &[f32],
        gbar_x: &[f32],
        grad: &mut [f32],
        d_x: Option<&mut [f32]>,
        scratch: &mut TileScratch,
    ) {
        let d = self.config.input_dim;
        let n_layers = self.layers.len();
        let mut cur = 0; // which gbar_z buffer holds Ḡ_{A_{l−1}}
        for l in 0..n_layers {
            let layer = &self.layers[l];
            let (o, i) = (layer.out_dim, layer.in_dim);
            let last = l + 1 == n_layers;
            // Ḡ_{I_l}
            let [gz0, gz1] = &mut scratch.gbar_z;
            let (gbar_prev, gbar_next) = if cur == 0 { (&*gz0, gz1) } else { (&*gz1, gz0) };
            let gbar_in: &[f32] = if l == 0 {
                &gbar_x[..n * d]
            } else if layer.skip {
                let h = self.layers[l - 1].out_dim;
                for r in 0..n {
                    let row = &mut scratch.gbar_in[r * i..(r + 1) * i];
                    for (o, &v) in row[..h].iter_mut().zip(&gbar_prev[r * h..(r + 1) * h]) {
                        *o = v * SKIP_SCALE;
                    }
                    for (o, &v) in row[h..].iter_mut().zip(&gbar_x[r * d..(r + 1) * d]) {
                        *o = v * SKIP_SCALE;
                    }
                }
                &scratch.gbar_in[..n * i]
            } else {
                &gbar_prev[..n * self.layers[l - 1].out_dim]
            };
            let range = n * layer.act_offset..n * (layer.act_offset + o);
            let a = &acts[range.clone()];
            let ga = &gacts[range.clone()];
            let deriv = &mut scratch.deriv[range.clone()];
            layer.activation.derivative_into(a, deriv);
            // W̄_l += G_{Z_l}ᵀ Ḡ_{I_l}
            let gw = &mut grad[layer.weight_offset..layer.bias_offset];
            if last {
                // G_{Z_L} is zero but for the seed column: a rank-1 update of one row of W̄.
                let gw_row = &mut gw[seed * i..(seed + 1) * i];
                for r in 0..n {
                    let g = ga[r * o + seed] * deriv[r * o + seed];
                    for (dst, &v) in gw_row.iter_mut().zip(&gbar_in[r * i..(r + 1) * i]) {
                        *dst += g * v;
                    }
                }
            } else {
                let gz = &mut scratch.gz[..n * o];
                for ((z, &g), &s) in gz.iter_mut().zip(ga).zip(deriv.iter()) {
                    *z = g * s;
                }
                self.accumulate_weight_grad(l, n, gz, gbar_in, gw, &mut scratch.wt);
            }
            let extra = &mut scratch.zextra[range];
            if last && layer.activation.is_piecewise_linear() {
                extra.fill(0.0);
                break;
            }
            // Ḡ_{Z_l} = Ḡ_{I_l} W_lᵀ; Z̄_l += φ''_l ⊙ G_{A_l} ⊙ Ḡ_{Z_l}; Ḡ_{A_l} = φ'_l ⊙ Ḡ_{Z_l}
            let gbar_z = &mut gbar_next[..n * o];
            let transposed = scratch.transposed_ready.then_some(&scratch.transposed[..]);
            self.product_a_wt(l, n, gbar_in, 0.0, gbar_z, transposed);
            layer.activation.second_order_step(a, deriv, ga, gbar_z, extra);
            cur = 1 - cur;
        }
        let od = self.config.output_dim;
        scratch.zbar[..n * od].copy_from_slice(&d_out[..n * od]);
        let extra = std::mem::take(&mut scratch.zextra);
        let deriv = std::mem::take(&mut scratch.deriv);
        let aw = n * self.act_width;
        self.reverse_down(x, n, acts, Some((&deriv[..aw], &extra[..aw])), grad, d_x, scratch);
        scratch.zextra = extra;
        scratch.deriv = deriv;
    }
}

/// A standard normal sample (Box–Muller; the init path only).
pub(crate) fn normal(rng: &mut impl Rng) -> f32 {
    let u1: f64 = rng.gen::<f64>().max(1e-300);
    let u2: f64 = rng.gen();
    ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
}

#[cfg(test)]
#[path = "mlp_tests.rs"]
mod tests;
