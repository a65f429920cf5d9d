//! The report's image conversions: a perceptual colour map for error heat-maps (turbo), the
//! per-pixel error of each kind of map, and the display forms of depth and normals. Pixels
//! without ground truth (depth 0, a zero normal) show black in the error map and do not count in
//! its range.

use i2sdf_data::ImageF32;

/// Turbo (Mikhailov 2019), its published polynomial fit: a rainbow-like map whose lightness
/// rises and falls smoothly, so error levels read the same everywhere on the scale.
pub fn turbo(x: f32) -> [f32; 3] {
    let x = x.clamp(0.0, 1.0);
    let r = 0.135_721_38 + x * (4.615_392_6 + x * (-42.660_322 + x * (132.131_08 + x * (-152.942_4 + x * 59.286_38))));
    let g =
        0.091_402_61 + x * (2.194_188_4 + x * (4.842_966_6 + x * (-14.185_033 + x * (4.277_298_6 + x * 2.829_566))));
    let b = 0.106_673_3 + x * (12.641_946 + x * (-60.582_05 + x * (110.362_77 + x * (-89.903_11 + x * 27.348_25))));
    [r.clamp(0.0, 1.0), g.clamp(0.0, 1.0), b.clamp(0.0, 1.0)]
}

/// The colour bar of [`turbo`] as a CSS gradient (the page has no scripts or external images).
pub fn turbo_css_gradient() -> String {
    let stops: Vec<String> = (0..=8)
        .map(|i| {
            let [r, g, b] = turbo(i as f32 / 8.0);
            format!(
                "#{:02x}{:02x}{:02x}",
                (r * 255.0) as u8,
                (g * 255.0) as u8,
                (b * 255.0) as u8
            )
        })
        .collect();
    format!("linear-gradient(to right, {})", stops.join(", "))
}

/// A per-pixel error: values (one per pixel) and which pixels have ground truth.
pub struct ErrorMap {
    pub width: usize,
    pub height: usize,
    pub error: Vec<f32>,
    pub valid: Vec<bool>,
}

impl ErrorMap {
    /// The turbo heat-map over [0, `max`]; pixels without ground truth black.
    pub fn heat(&self, max: f32) -> ImageF32 {
        let mut out = ImageF32::new(self.width, self.height, 3);
        let max = max.max(1e-12);
        for (p, (&e, &ok)) in self.error.iter().zip(&self.valid).enumerate() {
            if ok && e.is_finite() {
                out.data[p * 3..p * 3 + 3].copy_from_slice(&turbo(e / max));
            }
        }
        out
    }

    /// The 99th percentile of the valid errors: the heat-map's top, so a few outliers (an
    /// edge, a light's rim) do not wash the rest out.
    pub fn p99(&self) -> f32 {
        let mut v: Vec<f32> = self
            .error
            .iter()
            .zip(&self.valid)
            .filter(|(e, &ok)| ok && e.is_finite())
            .map(|(e, _)| *e)
            .collect();
        if v.is_empty() {
            return 0.0;
        }
        v.sort_by(f32::total_cmp);
        v[(v.len() - 1) * 99 / 100]
    }

    /// Mean of the valid errors (None when no pixel has ground truth).
    pub fn mean(&self) -> Option<f64> {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for (&e, &ok) in self.error.iter().zip(&self.valid) {
            if ok && e.is_finite() {
                sum += e as f64;
                n += 1;
            }
        }
        (n > 0).then(|| sum / n as f64)
    }
}

fn same_size(a: &ImageF32, b: &ImageF32) -> bool {
    a.width == b.width && a.height == b.height
}

/// Mean absolute difference over the channels, every pixel valid unless `mask` says otherwise.
/// None when the images differ in size.
pub fn abs_error(ours: &ImageF32, gt: &ImageF32, mask: Option<&[bool]>) -> Option<ErrorMap> {
    if !same_size(ours, gt) || ours.channels != gt.channels {
        return None;
    }
    let c = gt.channels;
    let error = ours
        .data
        .chunks(c)
        .zip(gt.data.chunks(c))
        .map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>() / c as f32)
        .collect();
    let n = gt.width * gt.height;
    Some(ErrorMap {
        width: gt.width,
        height: gt.height,
        error,
        valid: mask.map_or_else(|| vec![true; n], <[bool]>::to_vec),
    })
}

/// |Δz| in world units where the ground truth has depth (> 0).
pub fn depth_error(ours: &ImageF32, gt: &ImageF32) -> Option<ErrorMap> {
    let valid: Vec<bool> = gt.data.iter().map(|&d| d > 0.0 && d.is_finite()).collect();
    abs_error(ours, gt, Some(&valid))
}

/// The angle between the normals in degrees where the ground truth has a normal.
pub fn normal_error(ours: &ImageF32, gt: &ImageF32) -> Option<ErrorMap> {
    if !same_size(ours, gt) || ours.channels != 3 || gt.channels != 3 {
        return None;
    }
    let mut valid = Vec::with_capacity(gt.data.len() / 3);
    let error = ours
        .data
        .chunks(3)
        .zip(gt.data.chunks(3))
        .map(|(a, b)| {
            let la = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            let lb = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
            valid.push(lb > 0.5 && la > 1e-6);
            let cos = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (la * lb).max(1e-12);
            cos.clamp(-1.0, 1.0).acos().to_degrees()
        })
        .collect();
    Some(ErrorMap {
        width: gt.width,
        height: gt.height,
        error,
        valid,
    })
}

/// Depth shown near = bright over [0, `far`] (one `far` for ground truth and ours, so the two
/// compare), 0 (no depth) black.
pub fn depth_display(depth: &ImageF32, far: f32) -> ImageF32 {
    let mut out = depth.clone();
    let far = far.max(1e-6);
    out.data.iter_mut().for_each(|d| {
        *d = if *d > 0.0 && d.is_finite() {
            1.0 - (*d / far).clamp(0.0, 1.0) * 0.9
        } else {
            0.0
        }
    });
    out
}

/// The 99th percentile of the positive depths: the display's far end.
pub fn depth_far(depth: &ImageF32) -> f32 {
    let mut v: Vec<f32> = depth
        .data
        .iter()
        .copied()
        .filter(|d| *d > 0.0 && d.is_finite())
        .collect();
    if v.is_empty() {
        return 1.0;
    }
    v.sort_by(f32::total_cmp);
    v[(v.len() - 1) * 99 / 100]
}

/// World-space normals as colours, (n + 1) / 2; a zero normal (none) black.
pub fn normal_display(normal: &ImageF32) -> ImageF32 {
    let mut out = normal.clone();
    for px in out.data.chunks_mut(3) {
        if px.iter().any(|x| *x != 0.0) {
            px.iter_mut().for_each(|x| *x = 0.5 * (*x + 1.0));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_runs_dark_blue_to_dark_red() {
        let [r0, _, b0] = turbo(0.1);
        let [r1, _, b1] = turbo(1.0);
        assert!(b0 > r0 && r1 > b1, "{r0} {b0} {r1} {b1}");
        assert!(turbo(0.5)[1] > 0.8, "bright green-yellow in the middle");
    }

    #[test]
    fn errors_skip_pixels_without_ground_truth() {
        let gt = ImageF32::from_data(2, 1, 1, vec![0.0, 2.0]);
        let ours = ImageF32::from_data(2, 1, 1, vec![5.0, 1.5]);
        let e = depth_error(&ours, &gt).unwrap();
        assert_eq!(e.valid, [false, true]);
        assert_eq!(e.mean(), Some(0.5));
        assert_eq!(e.p99(), 0.5);
        let heat = e.heat(1.0);
        assert_eq!(&heat.data[..3], &[0.0; 3]);
        let n = normal_error(
            &ImageF32::from_data(1, 1, 3, vec![0.0, 0.0, 1.0]),
            &ImageF32::from_data(1, 1, 3, vec![0.0, 1.0, 0.0]),
        )
        .unwrap();
        assert!((n.error[0] - 90.0).abs() < 1e-3);
    }
}
