//! Denoising a rendered view: the edge-avoiding à-trous wavelet filter (Dammertz et al. 2010,
//! "Edge-Avoiding À-Trous Wavelet Transform for fast Global Illumination Filtering") with the
//! variance-steered luminance weight of SVGF (Schied et al. 2017, "Spatiotemporal
//! Variance-Guided Filtering"), on one frame.
//!
//! Each radiance slot of a [`ViewRender`] (one per emitter, so that relighting stays exact after
//! filtering) is divided by its pixel's reflectance (Kd + Ks, the pixel-centre ray's), filtered,
//! and multiplied back: texture is kept, and only the shading is averaged. A neighbour counts
//! by how alike its normal, depth and reflectance are, and by how far its shading lies from the
//! pixel's in units of the pixel's own noise (the paths' variance, [`ViewRender::variance`]):
//! a shadow edge that stands out of the noise stops the filter, a speckle does not. Pixels that
//! see an emitter or nothing keep their values and are nobody's neighbour.
//!
//! A path tracer's images at tens of paths per pixel are dominated by their noise where a small
//! light lights the room (the relit sets' "small light alone": 64 → 256 paths gained 2.5 dB).
//! Like any denoiser it trades that noise for a bias: fine shading detail below the noise is
//! smoothed, on the scale of the filter's footprint.

use crate::color::luminance;
use crate::render_view::ViewRender;
use glam::Vec3;
use rayon::prelude::*;

/// The filter's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Denoiser {
    /// À-trous passes; pass i reaches 2^(i+1) pixels, so the footprint is 2^(iterations+1) − 2
    /// pixels either side (30 for the default 4).
    pub iterations: u32,
    /// Exponent of the normal weight max(0, n·n')^σ (SVGF's 128: 5° apart weighs 0.6, 10° 0.14).
    pub sigma_normal: f32,
    /// Depth weight exp(−|z − z'| / (σ |∇z · offset| + ε)): in units of the depth change a plane
    /// would make over the offset.
    pub sigma_depth: f32,
    /// Reflectance weight exp(−|a − a'|₁ / σ).
    pub sigma_albedo: f32,
    /// Luminance weight exp(−|l − l'| / (σ √var)): in standard deviations of the pixel's noise.
    pub sigma_luminance: f32,
}

impl Default for Denoiser {
    fn default() -> Self {
        Denoiser {
            iterations: 4,
            sigma_normal: 128.0,
            sigma_depth: 1.0,
            sigma_albedo: 0.1,
            sigma_luminance: 4.0,
        }
    }
}

/// The 5-tap B3 spline of the à-trous transform.
const B3: [f32; 5] = [1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0];
/// Reflectance added before dividing by it (black pixels still carry their shading).
const ALBEDO_FLOOR: f32 = 0.02;

impl Denoiser {
    /// Filters `view`'s radiance slots in place (and their variance, propagated as the filter
    /// weights them); the maps are untouched.
    pub fn apply(&self, view: &mut ViewRender) {
        let (w, h, ne) = (view.width, view.height, view.emitters);
        let n = w * h;
        if ne == 0 || n == 0 || self.iterations == 0 {
            return;
        }
        let filtered = |i: usize| view.depth[i].is_finite() && !view.emitter_mask[i];
        let valid: Vec<bool> = (0..n).map(filtered).collect();
        let albedo: Vec<Vec3> = (0..n)
            .map(|i| view.kd[i] + view.ks[i] + Vec3::splat(ALBEDO_FLOOR))
            .collect();
        let gradient = depth_gradient(view, &valid);
        for k in 0..ne {
            let mut shading: Vec<Vec3> = (0..n).map(|i| view.radiance[i * ne + k] / albedo[i]).collect();
            let mut variance: Vec<f32> = (0..n)
                .map(|i| view.variance.get(i * ne + k).copied().unwrap_or(0.0) / luminance(albedo[i]).powi(2))
                .collect();
            for pass in 0..self.iterations {
                let guide = Guide {
                    view,
                    valid: &valid,
                    albedo: &albedo,
                    gradient: &gradient,
                    noise: blurred_variance(&variance, &valid, w, h),
                };
                let (mut next_s, mut next_v) = (shading.clone(), variance.clone());
                next_s
                    .par_chunks_mut(w)
                    .zip(next_v.par_chunks_mut(w))
                    .enumerate()
                    .for_each(|(y, (row_s, row_v))| {
                        self.pass_row(&guide, 1 << pass, y, &shading, &variance, row_s, row_v)
                    });
                shading = next_s;
                variance = next_v;
            }
            for i in (0..n).filter(|&i| valid[i]) {
                view.radiance[i * ne + k] = shading[i] * albedo[i];
                if let Some(v) = view.variance.get_mut(i * ne + k) {
                    *v = variance[i] * luminance(albedo[i]).powi(2);
                }
            }
        }
    }
}

/// What steers the filter's weights, shared by the passes of one slot.
struct Guide<'a> {
    view: &'a ViewRender,
    valid: &'a [bool],
    albedo: &'a [Vec3],
    gradient: &'a [[f32; 2]],
    /// Each pixel's noise: its variance blurred 3×3.
    noise: Vec<f32>,
}

impl Denoiser {
    /// One à-trous pass (taps `step` pixels apart) over row `y`, into `row_s` / `row_v`.
    #[allow(clippy::too_many_arguments)]
    fn pass_row(
        &self,
        g: &Guide,
        step: usize,
        y: usize,
        shading: &[Vec3],
        variance: &[f32],
        row_s: &mut [Vec3],
        row_v: &mut [f32],
    ) {
        let (w, h, view) = (g.view.width, g.view.height, g.view);
        for x in 0..w {
            let p = y * w + x;
            if !g.valid[p] {
                continue;
            }
            let lp = luminance(shading[p]);
            let l_scale = self.sigma_luminance * g.noise[p].max(0.0).sqrt() + 1e-6;
            let (mut sum, mut var, mut wsum) = (Vec3::ZERO, 0.0f32, 0.0f32);
            for (j, by) in B3.iter().enumerate() {
                let dy = (j as isize - 2) * step as isize;
                let qy = y as isize + dy;
                if qy < 0 || qy >= h as isize {
                    continue;
                }
                for (i, bx) in B3.iter().enumerate() {
                    let dx = (i as isize - 2) * step as isize;
                    let qx = x as isize + dx;
                    if qx < 0 || qx >= w as isize {
                        continue;
                    }
                    let q = qy as usize * w + qx as usize;
                    if !g.valid[q] {
                        continue;
                    }
                    let wn = view.normal[p].dot(view.normal[q]).max(0.0).powf(self.sigma_normal);
                    let plane = (g.gradient[p][0] * dx as f32 + g.gradient[p][1] * dy as f32).abs();
                    let z_scale = self.sigma_depth * plane + 1e-3 * view.depth[p] * step as f32;
                    let wz = (-(view.depth[p] - view.depth[q]).abs() / z_scale).exp();
                    let da = (g.albedo[p] - g.albedo[q]).abs();
                    let wa = (-(da.x + da.y + da.z) / self.sigma_albedo).exp();
                    let wl = (-(lp - luminance(shading[q])).abs() / l_scale).exp();
                    let wt = bx * by * wn * wz * wa * wl;
                    sum += wt * shading[q];
                    var += wt * wt * variance[q];
                    wsum += wt;
                }
            }
            // The pixel itself always counts (all its weights are 1), so wsum > 0.
            row_s[x] = sum / wsum;
            row_v[x] = var / (wsum * wsum);
        }
    }
}

/// Per pixel, ∂z/∂x and ∂z/∂y in depth per pixel: of the two one-sided differences the smaller,
/// so that a depth edge beside a pixel does not make its own surface look steep.
fn depth_gradient(view: &ViewRender, valid: &[bool]) -> Vec<[f32; 2]> {
    let (w, h) = (view.width, view.height);
    let z = &view.depth;
    let side = |p: usize, q: Option<usize>| q.filter(|&q| valid[q]).map(|q| (z[q] - z[p]).abs());
    (0..w * h)
        .map(|p| {
            if !valid[p] {
                return [0.0; 2];
            }
            let (x, y) = (p % w, p / w);
            let one = |a: Option<f32>, b: Option<f32>| match (a, b) {
                (Some(a), Some(b)) => a.min(b),
                (Some(v), None) | (None, Some(v)) => v,
                (None, None) => 0.0,
            };
            let gx = one(side(p, (x > 0).then(|| p - 1)), side(p, (x + 1 < w).then(|| p + 1)));
            let gy = one(side(p, (y > 0).then(|| p - w)), side(p, (y + 1 < h).then(|| p + w)));
            [gx, gy]
        })
        .collect()
}

/// The variance blurred 3×3 (binomial) over valid pixels: SVGF's estimate of a pixel's noise,
/// steadier than its own paths' variance.
fn blurred_variance(variance: &[f32], valid: &[bool], w: usize, h: usize) -> Vec<f32> {
    const K: [f32; 3] = [0.25, 0.5, 0.25];
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            if !valid[p] {
                continue;
            }
            let (mut s, mut ws) = (0.0, 0.0);
            for (j, ky) in K.iter().enumerate() {
                for (i, kx) in K.iter().enumerate() {
                    let (qx, qy) = (x as isize + i as isize - 1, y as isize + j as isize - 1);
                    if qx < 0 || qy < 0 || qx >= w as isize || qy >= h as isize {
                        continue;
                    }
                    let q = qy as usize * w + qx as usize;
                    if valid[q] {
                        s += kx * ky * variance[q];
                        ws += kx * ky;
                    }
                }
            }
            out[p] = s / ws;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg32;

    /// A w×h view of one slot: a floor (normal +y, depth 2) whose left half has Kd `kd_left`,
    /// right half `kd_right`; shading `shade(x, y)` times Kd plus Gaussian noise of standard
    /// deviation `sigma` (relative to the shading), with its variance recorded.
    fn noisy_view(
        w: usize,
        h: usize,
        sigma: f32,
        shade: impl Fn(usize, usize) -> f32,
        seed: u64,
    ) -> (ViewRender, Vec<Vec3>) {
        let mut rng = Pcg32::seed_from_u64(seed);
        let (mut radiance, mut clean, mut variance, mut kd) = (vec![], vec![], vec![], vec![]);
        for y in 0..h {
            for x in 0..w {
                let a = if x < w / 2 {
                    Vec3::new(0.6, 0.4, 0.2)
                } else {
                    Vec3::new(0.1, 0.3, 0.5)
                };
                let s = shade(x, y);
                let truth = Vec3::splat(s) * (a + Vec3::splat(ALBEDO_FLOOR));
                // Box–Muller.
                let (u1, u2): (f32, f32) = (rng.gen::<f32>().max(1e-7), rng.gen());
                let g = (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos();
                radiance.push(truth * (1.0 + sigma * g));
                clean.push(truth);
                variance.push((sigma * luminance(truth)).powi(2));
                kd.push(a);
            }
        }
        let n = w * h;
        let view = ViewRender {
            width: w,
            height: h,
            emitters: 1,
            radiance,
            variance,
            depth: vec![2.0; n],
            normal: vec![Vec3::Y; n],
            emitter_mask: vec![false; n],
            kd,
            ks: vec![Vec3::ZERO; n],
            roughness: vec![0.5; n],
        };
        (view, clean)
    }

    fn mse(a: &[Vec3], b: &[Vec3]) -> f32 {
        a.iter().zip(b).map(|(a, b)| (*a - *b).length_squared()).sum::<f32>() / a.len() as f32
    }

    /// On smooth shading the noise falls by an order of magnitude, the mean is kept, and the
    /// reflectance edge in the middle stays where it was (texture is divided out, not blurred).
    #[test]
    fn smooth_shading_loses_its_noise_and_keeps_its_texture() {
        let (w, h) = (48, 32);
        let (mut view, clean) = noisy_view(w, h, 0.3, |x, y| 1.0 + 0.01 * (x + y) as f32, 1);
        let before = mse(&view.radiance, &clean);
        Denoiser::default().apply(&mut view);
        let after = mse(&view.radiance, &clean);
        assert!(after < before / 10.0, "mse {before} → {after}");
        let mean = |v: &[Vec3]| v.iter().copied().sum::<Vec3>() / v.len() as f32;
        let (m, c) = (mean(&view.radiance), mean(&clean));
        assert!(((m - c) / c).abs().max_element() < 0.02, "{m} vs {c}");
        // Either side of the Kd edge, the colours stay those of their own side.
        let row = h / 2 * w;
        for x in [w / 2 - 1, w / 2] {
            let (got, want) = (view.radiance[row + x], clean[row + x]);
            assert!(
                ((got - want) / want).abs().max_element() < 0.15,
                "x {x}: {got} vs {want}"
            );
        }
        // The propagated variance says the noise fell too.
        assert!(view.variance[row + 10] < (0.3f32 * luminance(clean[row + 10])).powi(2) / 10.0);
    }

    /// A shadow edge far above the noise stops the filter: across it the shading is not mixed.
    #[test]
    fn a_shadow_edge_above_the_noise_survives() {
        let (w, h) = (48, 32);
        let shade = |_x: usize, y: usize| if y < 16 { 1.0 } else { 0.2 };
        let (mut view, clean) = noisy_view(w, h, 0.05, shade, 2);
        Denoiser::default().apply(&mut view);
        for x in [5, 20, 40] {
            for y in [15, 16] {
                let p = y * w + x;
                let rel = ((view.radiance[p] - clean[p]) / clean[p]).abs().max_element();
                assert!(rel < 0.1, "({x}, {y}): {} vs {}", view.radiance[p], clean[p]);
            }
        }
    }

    /// Surfaces at another depth or facing another way are not mixed: a wall (normal +z) beside
    /// the floor, and a far floor beside the near one, keep their own shading.
    #[test]
    fn geometry_edges_stop_the_filter() {
        let (w, h) = (32, 16);
        let (mut view, clean) = noisy_view(w, h, 0.0, |x, _| if x < 8 { 3.0 } else { 1.0 }, 3);
        // Columns 0..8: a wall facing the camera; 24..: the floor 1 m further.
        for y in 0..h {
            for x in 0..8 {
                view.normal[y * w + x] = Vec3::Z;
            }
            for x in 24..w {
                view.depth[y * w + x] = 3.0;
                let p = y * w + x;
                view.radiance[p] *= 2.0;
            }
        }
        // Noise-free slots with a large recorded variance: only the geometry can stop mixing.
        view.variance.iter_mut().for_each(|v| *v = 100.0);
        let expected: Vec<Vec3> = view.radiance.clone();
        Denoiser::default().apply(&mut view);
        for y in [0, h / 2, h - 1] {
            for x in [7, 8, 23, 24] {
                let p = y * w + x;
                let rel = ((view.radiance[p] - expected[p]) / expected[p]).abs().max_element();
                assert!(rel < 0.02, "({x}, {y}): {} vs {}", view.radiance[p], expected[p]);
            }
        }
        let _ = clean;
    }

    /// Emitters and the background keep their values, and a view without slots is left alone.
    #[test]
    fn emitters_and_empty_pixels_are_kept() {
        let (mut view, _) = noisy_view(16, 8, 0.3, |_, _| 1.0, 4);
        view.emitter_mask[3] = true;
        view.depth[5] = f32::INFINITY;
        let (e, b) = (view.radiance[3], view.radiance[5]);
        Denoiser::default().apply(&mut view);
        assert_eq!((view.radiance[3], view.radiance[5]), (e, b));
        let mut empty = ViewRender {
            emitters: 0,
            radiance: vec![],
            variance: vec![],
            ..view
        };
        Denoiser::default().apply(&mut empty);
    }
}
