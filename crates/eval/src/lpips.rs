//! LPIPS (Zhang et al. 2018, "The Unreasonable Effectiveness of Deep Features as a Perceptual
//! Metric"): the `lpips` package's v0.1 metric with its AlexNet backbone, on the engine's
//! forward-only convolution ([`i2sdf_nn::conv2d`]). Lower is more similar; 0 for identical images.
//!
//! For images in [0, 1] (the package's `normalize=True`): `x → 2x − 1`, then its ScalingLayer
//! `(x − shift) / scale` per channel; torchvision AlexNet's `features` up to each of its 5 ReLUs
//! (conv 3→64 k11 s4 p2, ReLU | max-pool 3/2, conv 64→192 k5 p2, ReLU | max-pool 3/2,
//! conv 192→384 k3 p1, ReLU | conv 384→256 k3 p1, ReLU | conv 256→256 k3 p1, ReLU); each
//! layer's features normalised per pixel over channels (`f / (‖f‖ + 1e-10)`), the squared
//! difference of the two images' weighted by the layer's linear head (a 1×1 convolution to one
//! channel, no bias, weights ≥ 0), averaged over pixels, and summed over the 5 layers. Images are
//! not clamped (as the package).
//!
//! The weights are not shipped: [`Lpips::load`] reads a safetensors file with the `lpips`
//! package's state-dict names — backbone `net.slice1.0.weight`/`.bias` (conv 1),
//! `net.slice2.3.*`, `net.slice3.6.*`, `net.slice4.8.*`, `net.slice5.10.*` (PyTorch's
//! `[out][in][kh][kw]` f32), heads `lin0.model.1.weight` … `lin4.model.1.weight` (`[1][C][1][1]`)
//! — which the repository's `scripts/lpips_weights.py` writes from the package's real weights.
//! Other tensors in the file (e.g. the ScalingLayer's buffers) are ignored.

use crate::image_metrics::ImageRef;
use i2sdf_data::DataError;
use i2sdf_nn::conv2d::{max_pool2d, Conv2d, FeatureMap};
use rayon::prelude::*;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use std::path::Path;

/// One convolution of the backbone and where its output goes.
#[derive(Clone, Copy, Debug)]
pub struct LayerSpec {
    /// Tensor name prefix (`{name}.weight`, `{name}.bias`).
    pub name: &'static str,
    pub in_channels: usize,
    pub out_channels: usize,
    pub kernel: usize,
    pub stride: usize,
    pub padding: usize,
    /// A 3×3 stride-2 max pool runs before the convolution.
    pub pool_before: bool,
}

const fn layer(
    name: &'static str,
    in_channels: usize,
    out_channels: usize,
    kernel: usize,
    stride: usize,
    padding: usize,
    pool_before: bool,
) -> LayerSpec {
    LayerSpec {
        name,
        in_channels,
        out_channels,
        kernel,
        stride,
        padding,
        pool_before,
    }
}

/// torchvision AlexNet's `features` as the `lpips` package slices them (one ReLU output each).
pub const ALEXNET: [LayerSpec; 5] = [
    layer("net.slice1.0", 3, 64, 11, 4, 2, false),
    layer("net.slice2.3", 64, 192, 5, 1, 2, true),
    layer("net.slice3.6", 192, 384, 3, 1, 1, true),
    layer("net.slice4.8", 384, 256, 3, 1, 1, false),
    layer("net.slice5.10", 256, 256, 3, 1, 1, false),
];

/// The package's ScalingLayer (applied after `2x − 1`): `(x − SHIFT) / SCALE`.
pub const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
pub const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// The normalisation's epsilon (`lpips.normalize_tensor`).
pub const EPS: f64 = 1e-10;
/// The smallest image side AlexNet's five layers accept (11×11 stride-4 convolution and two 3×3
/// stride-2 pools).
pub const MIN_SIDE: usize = 31;

/// The name of layer `l`'s linear head.
pub fn head_name(l: usize) -> String {
    format!("lin{l}.model.1.weight")
}

/// The metric's weights in PyTorch's layout: per layer of [`ALEXNET`] the convolution's weight
/// `[out][in][k][k]` and bias `[out]`, and the linear head `[C]` (stored `[1][C][1][1]`).
#[derive(Clone, Debug, PartialEq)]
pub struct LpipsWeights {
    pub conv_weights: Vec<Vec<f32>>,
    pub conv_biases: Vec<Vec<f32>>,
    pub heads: Vec<Vec<f32>>,
}

impl LpipsWeights {
    /// Every tensor with its file name and shape.
    pub fn tensors(&self) -> Vec<(String, Vec<usize>, &[f32])> {
        let mut out = Vec::with_capacity(15);
        for (l, s) in ALEXNET.iter().enumerate() {
            let (o, i, k) = (s.out_channels, s.in_channels, s.kernel);
            out.push((
                format!("{}.weight", s.name),
                vec![o, i, k, k],
                &self.conv_weights[l][..],
            ));
            out.push((format!("{}.bias", s.name), vec![o], &self.conv_biases[l][..]));
            out.push((head_name(l), vec![1, o, 1, 1], &self.heads[l][..]));
        }
        out
    }

    /// Reads and checks the weights (see the module docs). Every error names `path`, and the
    /// tensor when one is missing, of the wrong type or shape, or not finite (or a head weight
    /// is negative); all are bad input (exit code 2).
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let bytes =
            std::fs::read(path).map_err(|e| DataError::file(path, format!("cannot read the LPIPS weights: {e}")))?;
        let file = SafeTensors::deserialize(&bytes)
            .map_err(|e| DataError::file(path, format!("not a safetensors file: {e}")))?;
        let tensor = |name: &str, shape: &[usize]| -> Result<Vec<f32>, DataError> {
            let t = file.tensor(name).map_err(|_| {
                DataError::field(
                    path,
                    name,
                    "missing: not LPIPS AlexNet weights (scripts/lpips_weights.py writes them)",
                )
            })?;
            if t.dtype() != Dtype::F32 || t.shape() != shape {
                return Err(DataError::field(
                    path,
                    name,
                    format!("has shape {:?} ({:?}), expected {shape:?} (F32)", t.shape(), t.dtype()),
                ));
            }
            let v: Vec<f32> = t
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(DataError::field(path, name, format!("value {i} is {}", v[i])));
            }
            Ok(v)
        };
        let mut w = LpipsWeights {
            conv_weights: Vec::new(),
            conv_biases: Vec::new(),
            heads: Vec::new(),
        };
        for (l, s) in ALEXNET.iter().enumerate() {
            let (o, i, k) = (s.out_channels, s.in_channels, s.kernel);
            w.conv_weights
                .push(tensor(&format!("{}.weight", s.name), &[o, i, k, k])?);
            w.conv_biases.push(tensor(&format!("{}.bias", s.name), &[o])?);
            let head = tensor(&head_name(l), &[1, o, 1, 1])?;
            if let Some(c) = head.iter().position(|&x| x < 0.0) {
                return Err(DataError::field(
                    path,
                    head_name(l),
                    format!("weight {c} is {}: LPIPS heads are non-negative", head[c]),
                ));
            }
            w.heads.push(head);
        }
        Ok(w)
    }

    /// Writes the weights as [`LpipsWeights::read`] reads them (f32 safetensors).
    pub fn write(&self, path: &Path) -> Result<(), DataError> {
        let tensors = self.tensors();
        let bytes: Vec<Vec<u8>> = tensors
            .iter()
            .map(|(_, _, v)| v.iter().flat_map(|x| x.to_le_bytes()).collect())
            .collect();
        let views = tensors
            .iter()
            .zip(&bytes)
            .map(|((name, shape, _), b)| {
                TensorView::new(Dtype::F32, shape.clone(), b)
                    .map(|v| (name.clone(), v))
                    .map_err(|e| DataError::failed(format!("{name}: {e}")))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let data = safetensors::serialize(views, None).map_err(|e| DataError::failed(e.to_string()))?;
        std::fs::write(path, data).map_err(|e| DataError::io(path, e.to_string()))
    }
}

/// The LPIPS metric, ready to score image pairs (see the module docs).
pub struct Lpips {
    convs: Vec<Conv2d>,
    heads: Vec<Vec<f32>>,
}

impl Lpips {
    /// Panics when the weights do not have [`ALEXNET`]'s shapes ([`LpipsWeights::read`] checks).
    pub fn new(w: &LpipsWeights) -> Self {
        let convs = ALEXNET
            .iter()
            .enumerate()
            .map(|(l, s)| {
                Conv2d::from_oihw(
                    &w.conv_weights[l],
                    &w.conv_biases[l],
                    s.in_channels,
                    s.out_channels,
                    s.kernel,
                    s.stride,
                    s.padding,
                )
            })
            .collect();
        for (l, s) in ALEXNET.iter().enumerate() {
            assert_eq!(w.heads[l].len(), s.out_channels, "LPIPS head {l} size");
        }
        Lpips {
            convs,
            heads: w.heads.clone(),
        }
    }

    /// [`LpipsWeights::read`] then [`Lpips::new`].
    pub fn load(path: &Path) -> Result<Self, DataError> {
        Ok(Self::new(&LpipsWeights::read(path)?))
    }

    /// The backbone's 5 ReLU outputs for an RGB image in [0, 1] (not normalised).
    pub fn features(&self, img: ImageRef) -> Result<Vec<FeatureMap>, DataError> {
        if img.channels != 3 {
            return Err(DataError::invalid(format!(
                "LPIPS: images must be RGB, got {} channels",
                img.channels
            )));
        }
        if img.width < MIN_SIDE || img.height < MIN_SIDE {
            return Err(DataError::invalid(format!(
                "LPIPS: images must be at least {MIN_SIDE}×{MIN_SIDE} pixels (AlexNet's layers), got {}×{}",
                img.width, img.height
            )));
        }
        let scaled = img
            .data
            .chunks_exact(3)
            .flat_map(|p| (0..3).map(move |c| (2.0 * p[c] - 1.0 - SHIFT[c]) / SCALE[c]))
            .collect();
        let mut x = FeatureMap::new(img.height, img.width, 3, scaled);
        let mut out = Vec::with_capacity(ALEXNET.len());
        for (s, conv) in ALEXNET.iter().zip(&self.convs) {
            if s.pool_before {
                x = max_pool2d(&x, 3, 2);
            }
            x = conv.forward_relu(&x);
            out.push(x.clone());
        }
        Ok(out)
    }

    /// Each layer's term (the head-weighted squared difference of the normalised features,
    /// averaged over pixels) for images `a` and `b` of the same size; LPIPS is their sum.
    pub fn layer_distances(&self, a: ImageRef, b: ImageRef) -> Result<[f64; 5], DataError> {
        if (a.width, a.height, a.channels) != (b.width, b.height, b.channels) {
            return Err(DataError::invalid(format!(
                "LPIPS: prediction is {}×{}×{}, ground truth {}×{}×{}",
                a.width, a.height, a.channels, b.width, b.height, b.channels
            )));
        }
        let (fa, fb) = rayon::join(|| self.features(a), || self.features(b));
        let (fa, fb) = (fa?, fb?);
        let mut out = [0.0; 5];
        for (l, (x, y)) in fa.iter().zip(&fb).enumerate() {
            let head = &self.heads[l];
            let c = x.channels;
            // Per-block sums added in order: the same figure whatever the thread count.
            let sum: f64 = x
                .data
                .par_chunks(c * 256)
                .zip(y.data.par_chunks(c * 256))
                .map(|(xs, ys)| {
                    xs.chunks_exact(c)
                        .zip(ys.chunks_exact(c))
                        .map(|(p, q)| {
                            let np = p.iter().map(|&v| v as f64 * v as f64).sum::<f64>().sqrt() + EPS;
                            let nq = q.iter().map(|&v| v as f64 * v as f64).sum::<f64>().sqrt() + EPS;
                            p.iter()
                                .zip(q)
                                .zip(head)
                                .map(|((&u, &v), &w)| {
                                    let d = u as f64 / np - v as f64 / nq;
                                    w as f64 * d * d
                                })
                                .sum::<f64>()
                        })
                        .sum::<f64>()
                })
                .collect::<Vec<f64>>()
                .iter()
                .sum();
            out[l] = sum / x.pixels() as f64;
        }
        Ok(out)
    }

    /// LPIPS between RGB images `a` and `b` in [0, 1] of the same size (at least
    /// [`MIN_SIDE`] pixels each way).
    pub fn distance(&self, a: ImageRef, b: ImageRef) -> Result<f64, DataError> {
        Ok(self.layer_distances(a, b)?.iter().sum())
    }
}
