//! The emission of a light the images only saw saturated, from the light it throws on the room.
//!
//! An LDR capture clips every emitter pixel, so its L\[k\] is bounded from below by the images and
//! by nothing else: a diffuse pixel's re-render Kd/π ⊙ (E_field + Σ_k w_k L\[k\]) fits its target
//! for any L\[k\] above that bound, Kd taking up the difference (the scale ambiguity of intrinsic
//! decomposition). Measured on the default room's phone capture: the joint fit left both lights at
//! their lower bound (8× and 25× too dark) and made Kd bright to make up for it (11.3 dB raw);
//! started from the true L it drifted down to the bound within 500 iterations; held at the
//! truth it gave Kd 17.7 dB.
//!
//! What does fix L is the structure of the room, as in Retinex: albedo is piecewise constant
//! while the light of one emitter changes across a surface (falloff, shadow edges) in a way the
//! light of the rest of the room (F_c's radiance, fixed in stage 2) does not. With the wrong L the
//! albedo implied by each pixel, A = π·B / E(L), carries the emitter's pattern; with the right one
//! it is flat across each surface. So each saturated L\[k\] is the minimizer of the variation of
//! ln A between neighbouring pixels of one surface (image neighbours whose points lie on one
//! plane), under a robust penalty so that true material edges count little. One channel at a
//! time, coordinate descent over the emitters, each a coarse scan of ln L then a golden-section
//! refinement.

use crate::stage2::shading::DiffuseSums;
use crate::stage2::{CachedPixel, PixelKind};
use glam::Vec3;
use i2sdf_model::emitters::EmitterTable;
use rayon::prelude::*;
use std::collections::HashMap;

/// One surface pixel as the estimator sees it.
#[derive(Clone, Copy, Debug)]
pub struct ShadedPixel {
    pub position: Vec3,
    pub normal: Vec3,
    /// Training view and pixel (row-major) of the pixel.
    pub view: u32,
    pub pixel: u32,
    /// Linear target and which channels are saturated (bit c).
    pub target: Vec3,
    pub saturated: u8,
}

impl ShadedPixel {
    /// What the estimator needs of a cached pixel.
    pub fn of(p: &CachedPixel) -> Self {
        ShadedPixel {
            position: p.point.position,
            normal: p.point.normal,
            view: p.view,
            pixel: p.pixel,
            target: p.target,
            saturated: p.saturated,
        }
    }
}

/// Settings of [`estimate_emission`].
#[derive(Clone, Copy, Debug)]
pub struct ShadingEstimate {
    /// Image offsets of the neighbour pairs: s = 1, 2, 4, … px, from `min_step` up to `max_step`
    /// (fractions of the view's width), along x, y and both diagonals for each. The long pairs
    /// see the falloff of a light across a surface. The short ones mostly see the errors of the
    /// emitter weights: a reconstructed surface's normals, positions and poses are off by
    /// amounts correlated over a few pixels, an error in the regressor that pulls the estimate
    /// towards zero (attenuation). Measured on dumped inputs (160-px views; L / truth for the
    /// ceiling panel and the bulb), with pairs of 1–32 px against 16–64 px: the phone captures
    /// 0.81 / 0.72 → 0.94 / 0.81 (seed 1) and 0.89 / 0.78 → 1.00 / 0.97 (seed 0), a capture at
    /// its exact poses 0.94 / 0.94 → 1.01 / 1.03, the exact room's geometry under the capture's
    /// images 1.03 / 0.89 → 1.07 / 0.96.
    pub min_step: f32,
    pub max_step: f32,
    /// Largest ratio of an estimate to its lower bound searched.
    pub max_ratio: f32,
    /// Scale δ of the Charbonnier penalty √(x² + δ²) on ln-albedo differences.
    pub delta: f32,
    /// Targets darker than this (linear) are left out: quantization and noise dominate them.
    pub min_target: f32,
    /// Neighbours lie on one surface: normals within this cosine...
    pub min_cos: f32,
    /// ...and the second point within this distance (world) of the first's tangent plane, per unit
    /// of their separation.
    pub max_slope: f32,
}

impl Default for ShadingEstimate {
    fn default() -> Self {
        ShadingEstimate {
            min_step: 0.1,
            max_step: 0.4,
            max_ratio: 1000.0,
            delta: 0.05,
            min_target: 0.01,
            min_cos: 0.95,
            max_slope: 0.1,
        }
    }
}

/// Which of the `k` emitters the images saw clipped: at least a quarter of its pixels saturated
/// in some channel (its L\[k\] then starts at a lower bound). Not "most pixels in every channel":
/// JPEG ringing and partly covered rim pixels keep a small bulb's pixels under saturation in
/// places (the default room's phone capture: its mean target was 0.98–0.99).
pub fn saturated_emitters(pixels: &[CachedPixel], k: usize) -> Vec<bool> {
    let mut count = vec![(0usize, 0usize); k];
    for p in pixels {
        if let PixelKind::Emitter(e) = p.kind {
            let c = &mut count[e as usize];
            c.0 += (p.saturated != 0) as usize;
            c.1 += 1;
        }
    }
    count.iter().map(|&(s, n)| n > 0 && 4 * s >= n).collect()
}

/// Stage 2's use: the L\[k\] of the emitters marked `clipped` estimated from the surface pixels
/// (in cache order, `sums[i]` their diffuse sums; `widths` of the training views), the others
/// kept; every L\[k\] at least its current value.
pub fn emission_from_the_room(
    pixels: &[CachedPixel],
    sums: &[DiffuseSums],
    widths: &[usize],
    emitters: &EmitterTable,
    clipped: &[bool],
) -> Vec<[f32; 3]> {
    let shaded: Vec<ShadedPixel> = pixels
        .iter()
        .filter(|p| matches!(p.kind, PixelKind::Surface { .. }))
        .map(ShadedPixel::of)
        .collect();
    let s = ShadingEstimate::default();
    let pairs = neighbour_pairs(&shaded, widths, &s);
    let bound: Vec<Vec3> = (0..emitters.len()).map(|k| emitters.emission(k)).collect();
    estimate_emission(&shaded, sums, &pairs, &bound, clipped, &s)
        .iter()
        .map(|e| e.to_array())
        .collect()
}

/// [`emission_from_the_room`] as stage 2 uses it: the emitters with the estimates of the
/// `clipped` ones, each said to `progress` beside the images' lower bound.
pub fn estimate_clipped_emission(
    pixels: &[CachedPixel],
    sums: &[DiffuseSums],
    widths: &[usize],
    emitters: &EmitterTable,
    clipped: &[bool],
    progress: &dyn Fn(&str),
) -> EmitterTable {
    progress("emission of the clipped emitters from the shading of the room");
    let estimate = emission_from_the_room(pixels, sums, widths, emitters, clipped);
    for (k, l) in estimate.iter().enumerate().filter(|(k, _)| clipped[*k]) {
        let b = emitters.emission(k);
        progress(&format!(
            "emitter {k}: L = {:.3} {:.3} {:.3} (the images' lower bound {:.3} {:.3} {:.3})",
            l[0], l[1], l[2], b.x, b.y, b.z
        ));
    }
    EmitterTable::new(emitters.emitters.clone(), &estimate)
}

/// The pairs of neighbouring pixels on one surface: indices into `pixels`.
pub fn neighbour_pairs(pixels: &[ShadedPixel], widths: &[usize], s: &ShadingEstimate) -> Vec<(u32, u32)> {
    let index: HashMap<(u32, u32), u32> = pixels
        .iter()
        .enumerate()
        .map(|(i, p)| ((p.view, p.pixel), i as u32))
        .collect();
    pixels
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, p)| {
            let w = widths[p.view as usize] as i64;
            let (x, y) = (p.pixel as i64 % w, p.pixel as i64 / w);
            let index = &index;
            let largest = (w as f32 * s.max_step).max(1.0) as i64;
            let smallest = (w as f32 * s.min_step).min(largest as f32);
            (0..)
                .map(|e| 1i64 << e)
                .take_while(move |&st| st <= largest)
                .filter(move |&st| st as f32 >= smallest)
                .flat_map(move |st| {
                    [(st, 0), (0, st), (st, st), (st, -st)]
                        .into_iter()
                        .filter_map(move |(dx, dy)| {
                            let (qx, qy) = (x + dx, y + dy);
                            if qx < 0 || qx >= w || qy < 0 {
                                return None;
                            }
                            let j = *index.get(&(p.view, (qy * w + qx) as u32))?;
                            let q = &pixels[j as usize];
                            let d = q.position - p.position;
                            let on_plane = d.dot(p.normal).abs() <= s.max_slope * d.length();
                            (p.normal.dot(q.normal) >= s.min_cos && on_plane).then_some((i as u32, j))
                        })
                })
        })
        .collect()
}

/// Estimates L\[k\] for the emitters marked `free` (the others keep `emission[k]`), each at least
/// `emission[k]` (the lower bound the saturated images give), from the pixels' diffuse sums
/// (`sums[i]` belongs to `pixels[i]`). Returns the new emissions.
pub fn estimate_emission(
    pixels: &[ShadedPixel],
    sums: &[DiffuseSums],
    pairs: &[(u32, u32)],
    emission: &[Vec3],
    free: &[bool],
    s: &ShadingEstimate,
) -> Vec<Vec3> {
    let mut out = emission.to_vec();
    for c in 0..3 {
        // Pixels usable in this channel: lit, not clipped, not too dark.
        let ln_b: Vec<f32> = pixels
            .iter()
            .map(|p| {
                let b = p.target[c];
                if p.saturated >> c & 1 == 1 || b < s.min_target {
                    f32::NAN
                } else {
                    b.ln()
                }
            })
            .collect();
        let mut l: Vec<f32> = out.iter().map(|e| e[c]).collect();
        // Each evaluation's implied ln-albedo, reused across the searches' many evaluations.
        let mut ln_a = vec![0.0f32; pixels.len()];
        for _sweep in 0..3 {
            for k in (0..l.len()).filter(|&k| free[k]) {
                let lo = emission[k][c].max(1e-4).ln();
                let hi = lo + s.max_ratio.ln();
                let mut trial = l.clone();
                let cost = |t: f32| {
                    trial[k] = t.exp();
                    variation(&ln_b, sums, pairs, &trial, c, s.delta, &mut ln_a)
                };
                l[k] = minimize(cost, lo, hi).exp();
            }
        }
        for (o, v) in out.iter_mut().zip(l) {
            o[c] = v;
        }
    }
    out
}

/// Σ over pairs of the Charbonnier penalty of the ln-albedo difference, divided by the pairs
/// counted (pairs with an unusable pixel are skipped). `ln_a` (one per pixel) is scratch.
fn variation(
    ln_b: &[f32],
    sums: &[DiffuseSums],
    pairs: &[(u32, u32)],
    l: &[f32],
    c: usize,
    delta: f32,
    ln_a: &mut [f32],
) -> f64 {
    ln_a.par_iter_mut().zip(ln_b).zip(sums).for_each(|((a, b), d)| {
        let e = d.field[c] + d.emit.iter().zip(l).map(|(w, l)| w * l).sum::<f32>();
        *a = if e > 0.0 { b - e.ln() } else { f32::NAN };
    });
    let ln_a = &*ln_a;
    let (sum, n) = pairs
        .par_iter()
        .map(|&(i, j)| {
            let d = ln_a[i as usize] - ln_a[j as usize];
            if d.is_finite() {
                (((d * d + delta * delta).sqrt() - delta) as f64, 1usize)
            } else {
                (0.0, 0)
            }
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    sum / n.max(1) as f64
}

/// The minimizer of `f` over [lo, hi]: the best of a scan of 49 points, refined by golden-section
/// search in the interval around it.
fn minimize(mut f: impl FnMut(f32) -> f64, lo: f32, hi: f32) -> f32 {
    const SCAN: usize = 48;
    let at = |i: usize| lo + (hi - lo) * i as f32 / SCAN as f32;
    let best = (0..=SCAN)
        .map(|i| (i, f(at(i))))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0, |b| b.0);
    let (mut a, mut b) = (at(best.saturating_sub(1)), at((best + 1).min(SCAN)));
    let g = 0.618_034f32;
    let (mut x1, mut x2) = (b - g * (b - a), a + g * (b - a));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..20 {
        if f1 <= f2 {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - g * (b - a);
            f1 = f(x1);
        } else {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + g * (b - a);
            f2 = f(x2);
        }
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A random field on a 4-px lattice (`lattice`: 17 × 17 values), interpolated bilinearly.
    fn smooth(lattice: &[f32], x: u32, y: u32) -> f32 {
        let (fx, fy) = (x as f32 / 4.0, y as f32 / 4.0);
        let (i, j) = (fx.floor() as usize, fy.floor() as usize);
        let (u, v) = (fx - i as f32, fy - j as f32);
        let at = |i: usize, j: usize| lattice[j * 17 + i];
        (1.0 - v) * ((1.0 - u) * at(i, j) + u * at(i + 1, j)) + v * ((1.0 - u) * at(i, j + 1) + u * at(i + 1, j + 1))
    }

    /// A floor seen in one 64×64 view, two albedo patches (a material edge down the middle),
    /// lit by a light above one corner (falloff and a shadow edge) and by the room's light
    /// (smooth, from another direction): the saturated light's L comes back from its lower bound.
    ///
    /// `weight_error`: the emitter weights the estimator is given are off by a factor
    /// exp(weight_error · g), g a smooth random field (uniform in [−√3, √3] on a 4-px lattice,
    /// interpolated): errors correlated over a few pixels.
    fn floor(l_true: Vec3, noise: f32, weight_error: f32) -> (Vec<ShadedPixel>, Vec<DiffuseSums>) {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(3);
        let lattice: Vec<f32> = (0..17 * 17)
            .map(|_| (rng.gen::<f32>() * 2.0 - 1.0) * 3f32.sqrt())
            .collect();
        let (mut px, mut sums) = (Vec::new(), Vec::new());
        for y in 0..64u32 {
            for x in 0..64u32 {
                if rng.gen::<f32>() < 0.3 {
                    continue; // not every pixel is cached
                }
                let p = Vec3::new(x as f32 * 0.05, 0.0, y as f32 * 0.05);
                let kd = if x < 32 {
                    Vec3::new(0.7, 0.6, 0.5)
                } else {
                    Vec3::new(0.3, 0.35, 0.4)
                };
                let light = Vec3::new(0.5, 2.0, 0.5);
                let r2 = (light - p).length_squared();
                let shadowed = x > 20 && x < 28 && y > 10 && y < 40;
                let w = if shadowed {
                    0.0
                } else {
                    0.3 * 2.0 / r2 * (2.0 / r2.sqrt())
                };
                let field = Vec3::new(0.6, 0.5, 0.4) * (1.0 + 0.3 * p.z) * (1.0 + noise * rng.gen::<f32>());
                let b = kd / std::f32::consts::PI * (field + l_true * w);
                let given = w * (weight_error * smooth(&lattice, x, y)).exp();
                sums.push(DiffuseSums {
                    field,
                    emit: vec![given],
                });
                px.push(ShadedPixel {
                    position: p,
                    normal: Vec3::Y,
                    view: 0,
                    pixel: y * 64 + x,
                    target: b,
                    saturated: 0,
                });
            }
        }
        (px, sums)
    }

    #[test]
    fn a_saturated_light_comes_back_from_its_lower_bound() {
        let l_true = Vec3::new(9.0, 8.0, 6.0);
        for noise in [0.0, 0.1] {
            let (px, sums) = floor(l_true, noise, 0.0);
            let s = ShadingEstimate::default();
            let pairs = neighbour_pairs(&px, &[64], &s);
            assert!(pairs.len() > 3 * px.len(), "{} pairs", pairs.len());
            let est = estimate_emission(&px, &sums, &pairs, &[Vec3::ONE], &[true], &s);
            for c in 0..3 {
                let r = est[0][c] / l_true[c];
                assert!(
                    (r - 1.0).abs() < 0.1 + noise,
                    "noise {noise}: channel {c}: {} vs {}",
                    est[0][c],
                    l_true[c]
                );
            }
        }
    }

    #[test]
    fn the_long_pairs_resist_errors_of_the_weights() {
        // Weights off by errors correlated over a few pixels (as a reconstructed surface's
        // normals make them) pull the estimate towards the bound: errors-in-variables
        // attenuation. The short pairs see mostly the errors, the long ones the light's falloff,
        // so pairs from a tenth of the width up are pulled less than pairs of every step.
        let l_true = Vec3::new(9.0, 8.0, 6.0);
        let (px, sums) = floor(l_true, 0.0, 0.3);
        let ratio = |s: &ShadingEstimate| {
            let pairs = neighbour_pairs(&px, &[64], s);
            estimate_emission(&px, &sums, &pairs, &[Vec3::ONE], &[true], s)[0].x / l_true.x
        };
        let long = ratio(&ShadingEstimate::default());
        let all = ratio(&ShadingEstimate {
            min_step: 0.0,
            ..Default::default()
        });
        // Measured: 0.76 against 0.67.
        assert!(
            long > 0.7 && long > all + 0.05,
            "from a tenth of the width {long}, every step {all}"
        );
    }

    #[test]
    fn a_held_light_and_the_lower_bound_are_kept() {
        let (px, sums) = floor(Vec3::splat(3.0), 0.0, 0.0);
        let s = ShadingEstimate::default();
        let pairs = neighbour_pairs(&px, &[64], &s);
        let held = estimate_emission(&px, &sums, &pairs, &[Vec3::splat(2.0)], &[false], &s);
        assert_eq!(held[0], Vec3::splat(2.0));
        // A bound above the truth is never undercut.
        let bounded = estimate_emission(&px, &sums, &pairs, &[Vec3::splat(5.0)], &[true], &s);
        assert!(bounded[0].min_element() >= 5.0 - 1e-3, "{:?}", bounded[0]);
    }

    #[test]
    fn an_emitter_is_clipped_when_most_of_its_pixels_are() {
        use crate::stage2::shading::ShadingPoint;
        let px = |kind, saturated| CachedPixel {
            point: ShadingPoint {
                position: Vec3::ZERO,
                normal: Vec3::Y,
                view: Vec3::Y,
            },
            target: Vec3::ONE,
            saturated,
            kind,
            view: 0,
            pixel: 0,
        };
        let pixels = [
            px(PixelKind::Emitter(0), 0b100),
            px(PixelKind::Emitter(0), 0),
            px(PixelKind::Emitter(0), 0),
            px(PixelKind::Emitter(0), 0),
            px(PixelKind::Emitter(1), 0b111),
            px(PixelKind::Emitter(1), 0),
            px(PixelKind::Emitter(1), 0),
            px(PixelKind::Emitter(1), 0),
            px(PixelKind::Emitter(1), 0),
            px(PixelKind::Surface { index: 0 }, 0b111),
        ];
        // 1 of 4 clipped (in one channel); 1 of 5 is under a quarter; no pixel at all.
        assert_eq!(saturated_emitters(&pixels, 3), vec![true, false, false]);
    }

    #[test]
    fn pairs_stay_on_one_plane() {
        let mk = |pixel: u32, position: Vec3, normal: Vec3| ShadedPixel {
            position,
            normal,
            view: 0,
            pixel,
            target: Vec3::ONE,
            saturated: 0,
        };
        // 0 and 1 neighbours on the floor; 2 is a wall's pixel beside them; 3 a step up.
        let px = [
            mk(0, Vec3::ZERO, Vec3::Y),
            mk(1, Vec3::X * 0.05, Vec3::Y),
            mk(2, Vec3::X * 0.1, Vec3::X),
            mk(10, Vec3::new(0.0, 0.3, 0.05), Vec3::Y),
        ];
        let pairs = neighbour_pairs(&px, &[10], &ShadingEstimate::default());
        assert_eq!(pairs, vec![(0, 1)]);
    }
}
