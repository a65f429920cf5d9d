//! Image metrics of the paper's Sec. 6 and supp. Sec. D, as the README's `eval` row lists: PSNR and SSIM on [0, 1] images, depth L1 and normal
//! angular L1 (mean of 1 − n̂·n). Images are interleaved row-major `f32` (`height × width ×
//! channels`); masks are one flag per pixel. Sums run in f64.

use i2sdf_data::DataError;

/// A borrowed interleaved image.
#[derive(Clone, Copy, Debug)]
pub struct ImageRef<'a> {
    pub data: &'a [f32],
    pub width: usize,
    pub height: usize,
    pub channels: usize,
}

impl<'a> ImageRef<'a> {
    pub fn new(data: &'a [f32], width: usize, height: usize, channels: usize) -> Result<Self, DataError> {
        if data.len() != width * height * channels || channels == 0 {
            return Err(DataError::invalid(format!(
                "image buffer has {} values, expected {width}×{height}×{channels}",
                data.len()
            )));
        }
        Ok(ImageRef {
            data,
            width,
            height,
            channels,
        })
    }

    fn pixels(&self) -> usize {
        self.width * self.height
    }
}

fn check_pair(what: &str, a: &ImageRef, b: &ImageRef, mask: Option<&[bool]>) -> Result<(), DataError> {
    if (a.width, a.height, a.channels) != (b.width, b.height, b.channels) {
        return Err(DataError::invalid(format!(
            "{what}: prediction is {}×{}×{}, ground truth {}×{}×{}",
            a.width, a.height, a.channels, b.width, b.height, b.channels
        )));
    }
    for img in [a, b] {
        if img.data.len() != img.pixels() * img.channels {
            return Err(DataError::invalid(format!(
                "{what}: image buffer size does not match its shape"
            )));
        }
    }
    if let Some(mask) = mask {
        if mask.len() != a.pixels() {
            return Err(DataError::invalid(format!(
                "{what}: mask has {} pixels, image {}",
                mask.len(),
                a.pixels()
            )));
        }
    }
    Ok(())
}

fn in_mask(mask: Option<&[bool]>, pixel: usize) -> bool {
    mask.is_none_or(|m| m[pixel])
}

/// Mean squared error over the masked pixels (all channels), or `None` when the mask is empty.
pub fn mse(pred: ImageRef, gt: ImageRef, mask: Option<&[bool]>) -> Result<Option<f64>, DataError> {
    check_pair("MSE", &pred, &gt, mask)?;
    let c = pred.channels;
    let (mut sum, mut count) = (0.0f64, 0usize);
    for p in (0..pred.pixels()).filter(|&p| in_mask(mask, p)) {
        for k in 0..c {
            let d = pred.data[p * c + k] as f64 - gt.data[p * c + k] as f64;
            sum += d * d;
        }
        count += c;
    }
    Ok((count > 0).then(|| sum / count as f64))
}

/// PSNR in dB for images in [0, 1] (peak 1): `10 log10(1 / MSE)`; `+inf` for identical images,
/// `None` for an empty mask.
pub fn psnr(pred: ImageRef, gt: ImageRef, mask: Option<&[bool]>) -> Result<Option<f64>, DataError> {
    Ok(mse(pred, gt, mask)?.map(psnr_from_mse))
}

pub fn psnr_from_mse(mse: f64) -> f64 {
    -10.0 * mse.log10()
}

/// The SSIM window of Wang et al. 2004: an 11-tap Gaussian with σ = 1.5, normalized (the same as
/// skimage's `gaussian_weights=True` and pytorch-msssim).
pub fn ssim_window() -> [f64; 11] {
    let mut w: [f64; 11] = std::array::from_fn(|i| {
        let x = i as f64 - 5.0;
        (-x * x / (2.0 * 1.5 * 1.5)).exp()
    });
    let sum: f64 = w.iter().sum();
    w.iter_mut().for_each(|x| *x /= sum);
    w
}

/// Valid-mode separable filtering of one channel: out is (h − 10) × (w − 10).
fn filter_valid(src: &[f64], width: usize, height: usize, window: &[f64; 11], tmp: &mut [f64], out: &mut [f64]) {
    let ow = width - 10;
    let oh = height - 10;
    for y in 0..height {
        for x in 0..ow {
            tmp[y * ow + x] = (0..11).map(|k| window[k] * src[y * width + x + k]).sum();
        }
    }
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..11).map(|k| window[k] * tmp[(y + k) * ow + x]).sum();
        }
    }
}

/// Mean SSIM (Wang et al. 2004) for images in [0, 1]: Gaussian 11×11 window with σ = 1.5,
/// K1 = 0.01, K2 = 0.03, data range 1, population (not sample) covariances, computed per channel
/// over the windows that fit inside the image and averaged over channels — numerically the same
/// as skimage's `structural_similarity(..., gaussian_weights=True, sigma=1.5,
/// use_sample_covariance=False, data_range=1)` and pytorch-msssim's `ssim`. With a mask, the SSIM
/// map is averaged over the windows whose centre pixel is in the mask. `None` when no window counts.
pub fn ssim(pred: ImageRef, gt: ImageRef, mask: Option<&[bool]>) -> Result<Option<f64>, DataError> {
    check_pair("SSIM", &pred, &gt, mask)?;
    let (w, h, c) = (pred.width, pred.height, pred.channels);
    if w < 11 || h < 11 {
        return Err(DataError::invalid(format!(
            "SSIM needs images of at least 11×11 pixels, got {w}×{h}"
        )));
    }
    const C1: f64 = 0.01 * 0.01;
    const C2: f64 = 0.03 * 0.03;
    let window = ssim_window();
    let (ow, oh) = (w - 10, h - 10);
    let n = w * h;
    let mut planes = vec![vec![0.0f64; n]; 5];
    let mut filtered = vec![vec![0.0f64; ow * oh]; 5];
    let mut tmp = vec![0.0f64; h * ow];
    let (mut sum, mut count) = (0.0f64, 0usize);
    for k in 0..c {
        for p in 0..n {
            let (a, b) = (pred.data[p * c + k] as f64, gt.data[p * c + k] as f64);
            planes[0][p] = a;
            planes[1][p] = b;
            planes[2][p] = a * a;
            planes[3][p] = b * b;
            planes[4][p] = a * b;
        }
        for (plane, out) in planes.iter().zip(filtered.iter_mut()) {
            filter_valid(plane, w, h, &window, &mut tmp, out);
        }
        for y in 0..oh {
            for x in 0..ow {
                if !in_mask(mask, (y + 5) * w + x + 5) {
                    continue;
                }
                let i = y * ow + x;
                let (mu_a, mu_b) = (filtered[0][i], filtered[1][i]);
                let var_a = filtered[2][i] - mu_a * mu_a;
                let var_b = filtered[3][i] - mu_b * mu_b;
                let cov = filtered[4][i] - mu_a * mu_b;
                let luminance = (2.0 * mu_a * mu_b + C1) / (mu_a * mu_a + mu_b * mu_b + C1);
                let contrast_structure = (2.0 * cov + C2) / (var_a + var_b + C2);
                sum += luminance * contrast_structure;
                count += 1;
            }
        }
    }
    Ok((count > 0).then(|| sum / count as f64))
}

/// Mean |pred − gt| of z-depth over the pixels in the mask whose ground truth is valid (finite and
/// positive); `None` when there is none.
pub fn depth_l1(pred: &[f32], gt: &[f32], mask: Option<&[bool]>) -> Result<Option<f64>, DataError> {
    if pred.len() != gt.len() || mask.is_some_and(|m| m.len() != gt.len()) {
        return Err(DataError::invalid(format!(
            "depth L1: prediction has {} pixels, ground truth {}, mask {:?}",
            pred.len(),
            gt.len(),
            mask.map(|m| m.len())
        )));
    }
    let (mut sum, mut count) = (0.0f64, 0usize);
    for p in 0..gt.len() {
        if in_mask(mask, p) && gt[p].is_finite() && gt[p] > 0.0 {
            sum += (pred[p] as f64 - gt[p] as f64).abs();
            count += 1;
        }
    }
    Ok((count > 0).then(|| sum / count as f64))
}

/// Mean of 1 − n̂·n over the masked pixels with a valid (non-zero, finite) ground-truth normal;
/// both normals are normalized first, a zero predicted normal counts as 1 (orthogonal). Inputs
/// are 3 values per pixel. `None` when no pixel counts.
pub fn normal_angular_l1(pred: &[f32], gt: &[f32], mask: Option<&[bool]>) -> Result<Option<f64>, DataError> {
    if pred.len() != gt.len() || gt.len() % 3 != 0 || mask.is_some_and(|m| m.len() * 3 != gt.len()) {
        return Err(DataError::invalid(format!(
            "normal angular L1: prediction has {} values, ground truth {}, mask {:?} pixels",
            pred.len(),
            gt.len(),
            mask.map(|m| m.len())
        )));
    }
    let unit = |v: &[f32]| -> Option<[f64; 3]> {
        let v = [v[0] as f64, v[1] as f64, v[2] as f64];
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        (len.is_finite() && len > 1e-12).then(|| v.map(|x| x / len))
    };
    let (mut sum, mut count) = (0.0f64, 0usize);
    for p in 0..gt.len() / 3 {
        if !in_mask(mask, p) {
            continue;
        }
        let Some(n) = unit(&gt[3 * p..3 * p + 3]) else {
            continue;
        };
        let cos = unit(&pred[3 * p..3 * p + 3]).map_or(0.0, |m| m[0] * n[0] + m[1] * n[1] + m[2] * n[2]);
        sum += 1.0 - cos;
        count += 1;
    }
    Ok((count > 0).then(|| sum / count as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: usize = 20;
    const W: usize = 24;

    /// The images of the skimage reference computation (see `reference_values_from_skimage`).
    fn reference_images() -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let (mut a, mut b, mut b2) = (vec![], vec![], vec![]);
        for y in 0..H {
            for x in 0..W {
                for c in 0..3 {
                    let (xf, yf, cf) = (x as f64, y as f64, c as f64);
                    let av = (0.5 + 0.4 * (0.37 * xf + 0.21 * yf + cf).sin()) as f32;
                    let bv = 0.5 + 0.3 * (0.33 * xf - 0.17 * yf + 0.5 * cf).sin() + 0.1 * (0.9 * xf * yf / 7.0).cos();
                    let b2v = av as f64 + 0.1 * (1.3 * xf).sin() * (0.7 * yf).cos();
                    a.push(av);
                    b.push(bv.clamp(0.0, 1.0) as f32);
                    b2.push(b2v.clamp(0.0, 1.0) as f32);
                }
            }
        }
        (a, b, b2)
    }

    fn img(data: &[f32], channels: usize) -> ImageRef<'_> {
        ImageRef::new(data, W, H, channels).unwrap()
    }

    #[test]
    fn reference_values_from_skimage() {
        // skimage 0.26: structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
        // use_sample_covariance=False, data_range=1.0, channel_axis=2) on the same images.
        let (a, b, b2) = reference_images();
        let s = ssim(img(&a, 3), img(&b, 3), None).unwrap().unwrap();
        assert!((s - 0.014886494265796782).abs() < 1e-6, "{s}");
        let s = ssim(img(&a, 3), img(&b2, 3), None).unwrap().unwrap();
        assert!((s - 0.9439983784794793).abs() < 1e-6, "{s}");
        let g: Vec<f32> = a.iter().step_by(3).cloned().collect();
        let g2: Vec<f32> = g.iter().map(|&v| 0.8f32 * v + 0.1f32).collect();
        let s = ssim(img(&g, 1), img(&g2, 1), None).unwrap().unwrap();
        assert!((s - 0.9654064798505021).abs() < 1e-6, "{s}");
    }

    #[test]
    fn ssim_identity_symmetry_and_constant_closed_form() {
        let (a, b, _) = reference_images();
        assert!((ssim(img(&a, 3), img(&a, 3), None).unwrap().unwrap() - 1.0).abs() < 1e-12);
        let ab = ssim(img(&a, 3), img(&b, 3), None).unwrap().unwrap();
        let ba = ssim(img(&b, 3), img(&a, 3), None).unwrap().unwrap();
        assert!((ab - ba).abs() < 1e-12);
        // Constant images: no variance, SSIM is the luminance term alone.
        let (x, y) = (0.3f64, 0.6f64);
        let cx = vec![x as f32; W * H];
        let cy = vec![y as f32; W * H];
        let c1 = 1e-4;
        let expected = (2.0 * x * y + c1) / (x * x + y * y + c1);
        let s = ssim(img(&cx, 1), img(&cy, 1), None).unwrap().unwrap();
        assert!((s - expected).abs() < 1e-6, "{s} vs {expected}");
        // An image against its negative around 0.5 with zero mean difference: luminance 1,
        // structure −1 where there is texture.
        let t: Vec<f32> = (0..W * H)
            .map(|p| if (p % W + p / W) % 2 == 0 { 0.6 } else { 0.4 })
            .collect();
        let neg: Vec<f32> = t.iter().map(|v| 1.0 - v).collect();
        let s = ssim(img(&t, 1), img(&neg, 1), None).unwrap().unwrap();
        let var = 0.01f64; // the checkerboard's local variance (±0.1 around 0.5), to within window edge effects
        let expected = (-2.0 * var + 9e-4) / (2.0 * var + 9e-4);
        assert!((s - expected).abs() < 0.01, "{s} vs {expected}");
    }

    #[test]
    fn ssim_mask_and_errors() {
        let (a, b, _) = reference_images();
        let all = vec![true; W * H];
        let with_full_mask = ssim(img(&a, 3), img(&b, 3), Some(&all)).unwrap();
        assert_eq!(with_full_mask, ssim(img(&a, 3), img(&b, 3), None).unwrap());
        // Only border pixels: no window centre inside.
        let border: Vec<bool> = (0..W * H).map(|p| p % W < 5 || p / W < 5).collect();
        assert_eq!(ssim(img(&a, 3), img(&b, 3), Some(&border)).unwrap(), None);
        let small = vec![0.0f32; 10 * 10];
        let s = ImageRef::new(&small, 10, 10, 1).unwrap();
        assert!(ssim(s, s, None).is_err());
        assert!(ImageRef::new(&small, 10, 11, 1).is_err());
        assert!(ssim(img(&a, 3), ImageRef::new(&a, H, W, 3).unwrap(), None).is_err());
    }

    #[test]
    fn psnr_known_values() {
        let zeros = vec![0.0f32; W * H * 3];
        let tenth = vec![0.1f32; W * H * 3];
        let p = psnr(img(&zeros, 3), img(&tenth, 3), None).unwrap().unwrap();
        assert!((p - 20.0).abs() < 1e-5, "{p}");
        assert_eq!(psnr(img(&zeros, 3), img(&zeros, 3), None).unwrap(), Some(f64::INFINITY));
        // The mask selects the half where the error is 0.01 → 40 dB.
        let mut half = tenth.clone();
        let mask: Vec<bool> = (0..W * H).map(|p| p < W * H / 2).collect();
        for p in 0..W * H {
            let v = if mask[p] { 0.01 } else { 0.5 };
            half[3 * p..3 * p + 3].fill(v);
        }
        let p = psnr(img(&zeros, 3), img(&half, 3), Some(&mask)).unwrap().unwrap();
        assert!((p - 40.0).abs() < 1e-4, "{p}");
        assert_eq!(
            psnr(img(&zeros, 3), img(&half, 3), Some(&vec![false; W * H])).unwrap(),
            None
        );
    }

    #[test]
    fn depth_l1_skips_invalid_and_masked() {
        let pred = [1.0, 2.0, 3.0, 4.0];
        let gt = [1.5, 0.0, f32::NAN, 3.0];
        assert_eq!(depth_l1(&pred, &gt, None).unwrap(), Some(0.75));
        assert_eq!(
            depth_l1(&pred, &gt, Some(&[true, true, true, false])).unwrap(),
            Some(0.5)
        );
        assert_eq!(depth_l1(&pred, &gt, Some(&[false; 4])).unwrap(), None);
        assert!(depth_l1(&pred, &gt[..3], None).is_err());
    }

    #[test]
    fn normal_angular_l1_cases() {
        let gt = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0];
        // same direction (unnormalized), orthogonal, opposite, and an invalid ground truth.
        let pred = [0.0, 0.0, 5.0, 0.0, 1.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0, 0.0];
        let v = normal_angular_l1(&pred, &gt, None).unwrap().unwrap();
        assert!((v - (0.0 + 1.0 + 2.0) / 3.0).abs() < 1e-12);
        let v = normal_angular_l1(&pred, &gt, Some(&[true, false, true, true]))
            .unwrap()
            .unwrap();
        assert!((v - 1.0).abs() < 1e-12);
        // A zero prediction counts as orthogonal.
        let v = normal_angular_l1(&[0.0; 3], &gt[..3], None).unwrap().unwrap();
        assert_eq!(v, 1.0);
    }
}
