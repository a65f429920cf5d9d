//! 2-D convolution, ReLU and max pooling over image feature maps: **forward only**. They exist
//! for metrics (LPIPS's AlexNet backbone in `i2sdf-eval`), which never train, so there is no
//! backward and no gradient check.
//!
//! Feature maps are interleaved `height × width × channels` f32 ([`FeatureMap`], HWC: the layout
//! of the house's images), not PyTorch's CHW: a pixel's channels are contiguous, so the im2col
//! rows are copies of whole `kernel × channels` runs of the input and the channel reductions
//! (LPIPS's per-pixel normalisation) read contiguous memory.
//!
//! [`Conv2d`] is im2col + GEMM: the output `[pixels × out]` is `cols[pixels × k·k·in] ·
//! W[k·k·in × out]`, one block of output pixels per rayon task (the im2col buffer of a block is
//! the task's own), each product on the engine's GEMM ([`crate::linalg::gemm_a_b`]). Weights come
//! in PyTorch's `[out][in][kh][kw]` order ([`Conv2d::from_oihw`]) and are reordered once.

use crate::linalg::{gemm_a_b, MatmulPrecision};
use rayon::prelude::*;

/// An interleaved `height × width × channels` f32 feature map (HWC, row-major).
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureMap {
    pub height: usize,
    pub width: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl FeatureMap {
    /// Panics when `data` does not hold `height·width·channels` values.
    pub fn new(height: usize, width: usize, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), height * width * channels, "feature map buffer size");
        FeatureMap {
            height,
            width,
            channels,
            data,
        }
    }

    pub fn zeros(height: usize, width: usize, channels: usize) -> Self {
        Self::new(height, width, channels, vec![0.0; height * width * channels])
    }

    pub fn pixels(&self) -> usize {
        self.height * self.width
    }

    /// The value at row `y`, column `x`, channel `c`.
    #[inline]
    pub fn at(&self, y: usize, x: usize, c: usize) -> f32 {
        self.data[(y * self.width + x) * self.channels + c]
    }
}

/// Output size of a window of `kernel` with `stride` and `padding` (both sides) over `size`
/// (floor mode, as PyTorch), or `None` when the padded input is smaller than the window.
pub fn output_len(size: usize, kernel: usize, stride: usize, padding: usize) -> Option<usize> {
    let padded = size + 2 * padding;
    (stride > 0 && padded >= kernel).then(|| (padded - kernel) / stride + 1)
}

/// A square 2-D convolution with bias (forward only; see the module docs).
#[derive(Clone, Debug)]
pub struct Conv2d {
    pub in_channels: usize,
    pub out_channels: usize,
    pub kernel: usize,
    pub stride: usize,
    pub padding: usize,
    /// `[kernel·kernel·in × out]`: row `(ky·kernel + kx)·in + ci`, column `co` (the im2col order).
    weight: Vec<f32>,
    bias: Vec<f32>,
}

/// Output pixels per rayon task: about a quarter of a thread's share (so the tasks balance), at
/// least 32 and at most 256 (the task's im2col block is `pixels × k·k·in` values: 256 × 3456 × 4 B
/// = 3.5 MB at AlexNet's widest layer). Large blocks amortise the GEMM's packing of the weights,
/// which it repeats for every block.
fn pixel_block(pixels: usize) -> usize {
    pixels.div_ceil(4 * rayon::current_num_threads()).clamp(32, 256)
}

impl Conv2d {
    /// From PyTorch's `weight[out][in][kernel][kernel]` and `bias[out]`. Panics on buffers of the
    /// wrong size or a zero stride (callers check shapes against the file they read).
    pub fn from_oihw(
        weight: &[f32],
        bias: &[f32],
        in_channels: usize,
        out_channels: usize,
        kernel: usize,
        stride: usize,
        padding: usize,
    ) -> Self {
        let taps = kernel * kernel;
        assert_eq!(weight.len(), out_channels * in_channels * taps, "conv weight size");
        assert_eq!(bias.len(), out_channels, "conv bias size");
        assert!(stride > 0 && kernel > 0, "conv kernel and stride must be positive");
        let mut w = vec![0.0f32; taps * in_channels * out_channels];
        for co in 0..out_channels {
            for ci in 0..in_channels {
                for t in 0..taps {
                    w[(t * in_channels + ci) * out_channels + co] = weight[(co * in_channels + ci) * taps + t];
                }
            }
        }
        Conv2d {
            in_channels,
            out_channels,
            kernel,
            stride,
            padding,
            weight: w,
            bias: bias.to_vec(),
        }
    }

    /// `(height, width)` of the output for an input of `height × width`, or `None` when the
    /// padded input is smaller than the kernel.
    pub fn output_size(&self, height: usize, width: usize) -> Option<(usize, usize)> {
        Some((
            output_len(height, self.kernel, self.stride, self.padding)?,
            output_len(width, self.kernel, self.stride, self.padding)?,
        ))
    }

    /// The convolution of `x`. Panics when `x` has the wrong channel count or is smaller than the
    /// kernel ([`Conv2d::output_size`] is `None`).
    pub fn forward(&self, x: &FeatureMap) -> FeatureMap {
        self.run(x, false)
    }

    /// `max(0, conv(x))`: [`Conv2d::forward`] with the ReLU applied while the block is in cache.
    pub fn forward_relu(&self, x: &FeatureMap) -> FeatureMap {
        self.run(x, true)
    }

    fn run(&self, x: &FeatureMap, relu: bool) -> FeatureMap {
        assert_eq!(x.channels, self.in_channels, "conv input channels");
        let (ho, wo) = self
            .output_size(x.height, x.width)
            .expect("conv input smaller than its kernel");
        let (cin, cout, k) = (self.in_channels, self.out_channels, self.kernel);
        let row = k * k * cin;
        let mut out = FeatureMap::zeros(ho, wo, cout);
        if out.data.is_empty() {
            return out;
        }
        let block = pixel_block(ho * wo);
        out.data
            .par_chunks_mut(block * cout)
            .enumerate()
            .for_each_init(Vec::new, |cols: &mut Vec<f32>, (b, o)| {
                let first = b * block;
                let n = o.len() / cout;
                cols.clear();
                cols.resize(n * row, 0.0);
                for (i, col) in cols.chunks_exact_mut(row).enumerate() {
                    let p = first + i;
                    self.im2col_row(x, p / wo, p % wo, col);
                }
                gemm_a_b(
                    n,
                    row,
                    cout,
                    cols,
                    row,
                    &self.weight,
                    cout,
                    0.0,
                    o,
                    cout,
                    MatmulPrecision::F32,
                );
                for px in o.chunks_exact_mut(cout) {
                    for (v, b) in px.iter_mut().zip(&self.bias) {
                        *v += b;
                        if relu {
                            *v = v.max(0.0);
                        }
                    }
                }
            });
        out
    }

    /// The receptive field of output pixel `(oy, ox)` as one row `[ky][kx][ci]`, zeros outside
    /// the input (`col` must be zeroed by the caller).
    fn im2col_row(&self, x: &FeatureMap, oy: usize, ox: usize, col: &mut [f32]) {
        let (k, cin) = (self.kernel, self.in_channels);
        let y0 = (oy * self.stride) as isize - self.padding as isize;
        let x0 = (ox * self.stride) as isize - self.padding as isize;
        // The kernel columns inside the input: kx in [kx_lo, kx_hi).
        let kx_lo = (-x0).max(0) as usize;
        let kx_hi = ((x.width as isize - x0).max(0) as usize).min(k);
        if kx_lo >= kx_hi {
            return;
        }
        let run = (kx_hi - kx_lo) * cin;
        for ky in 0..k {
            let iy = y0 + ky as isize;
            if iy < 0 || iy >= x.height as isize {
                continue;
            }
            let src = (iy as usize * x.width + (x0 + kx_lo as isize) as usize) * cin;
            let dst = (ky * k + kx_lo) * cin;
            col[dst..dst + run].copy_from_slice(&x.data[src..src + run]);
        }
    }
}

/// `x = max(0, x)` in place.
pub fn relu_in_place(x: &mut FeatureMap) {
    x.data.par_chunks_mut(1 << 14).for_each(|c| {
        for v in c {
            *v = v.max(0.0);
        }
    });
}

/// Max pooling with a square `kernel` and `stride`, no padding, floor mode (PyTorch's
/// `MaxPool2d(kernel, stride)`). Panics when `x` is smaller than the window.
pub fn max_pool2d(x: &FeatureMap, kernel: usize, stride: usize) -> FeatureMap {
    let ho = output_len(x.height, kernel, stride, 0).expect("max pool input smaller than its window");
    let wo = output_len(x.width, kernel, stride, 0).expect("max pool input smaller than its window");
    let c = x.channels;
    let mut out = FeatureMap::zeros(ho, wo, c);
    if out.data.is_empty() {
        return out;
    }
    out.data.par_chunks_mut(wo * c).enumerate().for_each(|(oy, row)| {
        for (ox, px) in row.chunks_exact_mut(c).enumerate() {
            px.fill(f32::NEG_INFINITY);
            for ky in 0..kernel {
                let iy = oy * stride + ky;
                for kx in 0..kernel {
                    let ix = ox * stride + kx;
                    let src = &x.data[(iy * x.width + ix) * c..][..c];
                    for (m, v) in px.iter_mut().zip(src) {
                        *m = m.max(*v);
                    }
                }
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::Lcg;

    fn random_map(rng: &mut Lcg, h: usize, w: usize, c: usize) -> FeatureMap {
        FeatureMap::new(h, w, c, (0..h * w * c).map(|_| rng.uniform_pm1()).collect())
    }

    /// Direct convolution from PyTorch's layout, summed in f64.
    fn direct(x: &FeatureMap, w: &[f32], b: &[f32], cout: usize, k: usize, s: usize, p: usize) -> FeatureMap {
        let cin = x.channels;
        let ho = output_len(x.height, k, s, p).unwrap();
        let wo = output_len(x.width, k, s, p).unwrap();
        let mut out = FeatureMap::zeros(ho, wo, cout);
        for oy in 0..ho {
            for ox in 0..wo {
                for co in 0..cout {
                    let mut acc = b[co] as f64;
                    for ci in 0..cin {
                        for ky in 0..k {
                            for kx in 0..k {
                                let iy = (oy * s + ky) as isize - p as isize;
                                let ix = (ox * s + kx) as isize - p as isize;
                                if iy < 0 || ix < 0 || iy >= x.height as isize || ix >= x.width as isize {
                                    continue;
                                }
                                let wv = w[((co * cin + ci) * k + ky) * k + kx] as f64;
                                acc += wv * x.at(iy as usize, ix as usize, ci) as f64;
                            }
                        }
                    }
                    out.data[(oy * wo + ox) * cout + co] = acc as f32;
                }
            }
        }
        out
    }

    #[test]
    fn im2col_convolution_matches_the_direct_sum() {
        let mut rng = Lcg(7);
        // (in, out, kernel, stride, padding, height, width): AlexNet's first layer's shape on a
        // small input, odd sizes, no padding, stride 2, 1×1, and more pixels than one block.
        let cases = [
            (3, 8, 11, 4, 2, 23, 19),
            (5, 6, 5, 1, 2, 9, 7),
            (4, 3, 3, 1, 1, 13, 11),
            (2, 5, 3, 2, 0, 10, 9),
            (6, 4, 1, 1, 0, 5, 3),
            (3, 7, 3, 1, 1, 21, 17),
            (130, 9, 3, 1, 1, 6, 5),
            (2, 3, 5, 1, 4, 2, 3),
        ];
        for (cin, cout, k, s, p, h, w) in cases {
            let x = random_map(&mut rng, h, w, cin);
            let wt: Vec<f32> = (0..cout * cin * k * k).map(|_| rng.uniform_pm1()).collect();
            let b: Vec<f32> = (0..cout).map(|_| rng.uniform_pm1()).collect();
            let conv = Conv2d::from_oihw(&wt, &b, cin, cout, k, s, p);
            let want = direct(&x, &wt, &b, cout, k, s, p);
            let got = conv.forward(&x);
            assert_eq!((got.height, got.width, got.channels), (want.height, want.width, cout));
            let tol = 1e-5 * (cin * k * k) as f32;
            for (i, (g, e)) in got.data.iter().zip(&want.data).enumerate() {
                assert!(
                    (g - e).abs() <= tol,
                    "case {cin},{cout},{k},{s},{p},{h}x{w} [{i}]: {g} vs {e}"
                );
            }
            let relu = conv.forward_relu(&x);
            let mut clamped = got.clone();
            relu_in_place(&mut clamped);
            assert_eq!(relu, clamped);
            assert!(clamped.data.iter().all(|&v| v >= 0.0));
        }
    }

    #[test]
    fn max_pool_matches_the_direct_maximum() {
        let mut rng = Lcg(11);
        for (h, w, c, k, s) in [(11, 11, 4, 3, 2), (12, 7, 3, 3, 2), (3, 3, 2, 3, 2), (9, 14, 5, 2, 2)] {
            let x = random_map(&mut rng, h, w, c);
            let got = max_pool2d(&x, k, s);
            let (ho, wo) = ((h - k) / s + 1, (w - k) / s + 1);
            assert_eq!((got.height, got.width, got.channels), (ho, wo, c));
            for oy in 0..ho {
                for ox in 0..wo {
                    for ch in 0..c {
                        let mut m = f32::NEG_INFINITY;
                        for ky in 0..k {
                            for kx in 0..k {
                                m = m.max(x.at(oy * s + ky, ox * s + kx, ch));
                            }
                        }
                        assert_eq!(got.at(oy, ox, ch), m);
                    }
                }
            }
        }
    }

    #[test]
    fn output_sizes_follow_pytorch_floor_mode() {
        assert_eq!(output_len(224, 11, 4, 2), Some(55));
        assert_eq!(output_len(55, 3, 2, 0), Some(27));
        assert_eq!(output_len(27, 5, 1, 2), Some(27));
        assert_eq!(output_len(2, 3, 2, 0), None);
        assert_eq!(output_len(6, 11, 4, 2), None);
        assert_eq!(output_len(7, 11, 4, 2), Some(1));
    }
}
