//! What stage 2 keeps of each cached pixel's traced samples, and how it shades a pixel from it.
//!
//! The samples of a pixel (`shading::trace_incident`, the fixed proposal `stage2::cache_mixture`)
//! never change, and for a given material only two sums of them matter:
//!
//! - the diffuse sums Σ w L ([`DiffuseSums`]), pooled over nearby pixels;
//! - the specular sums, which depend on ρ through D·G2. [`SpecularBake`] evaluates them at
//!   [`BAKE_RHO`]'s roughness levels when the cache is built and interpolates linearly in ρ
//!   between levels. With Schlick's F = Ks (1 − m) + F90 m, m = (1 − d·h)⁵, the specular part
//!   at level j is exactly `Ks ⊙ A_j + F90(Ks) B_j` with
//!   A_j = Σ w D_j G2_j (1 − m) L and B_j = Σ w D_j G2_j m L (each split into F_c's radiance and
//!   a weight per emitter, to multiply by the learnable L\[k\]).
//!
//! Baked, a pixel costs a few hundred bytes whatever its sample count, and the loop's cost does
//! not grow with it: the cache can hold every training pixel with many samples (FIPT's baked
//! shading at a few roughness levels, ICCV 2023). The price is the interpolation in ρ between
//! levels; at a level the baked estimate *is* the samples' estimate (test
//! `baked_estimate_equals_the_samples_at_every_level`).

use crate::stage2::shading::{
    shade, shade_backward, shade_pooled, shade_pooled_backward, DiffuseSums, IncidentSample, ShadingPoint,
};
use glam::Vec3;
use i2sdf_data::KdTree;
use i2sdf_render::brdf::{fresnel_f90, ggx_d, smith_g2_visibility, ALPHA_MIN};
use i2sdf_render::{luminance, GgxBrdf, GgxGrad};
use rayon::prelude::*;
use std::f32::consts::FRAC_1_PI;

/// The roughness levels of the bake: dense where a lobe's integral changes fastest with ρ.
pub const BAKE_RHO: [f32; 11] = [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.45, 0.6, 0.8, 1.0];
const LEVELS: usize = BAKE_RHO.len();

/// Per pixel and level: A (RGB), B (RGB), then A's and B's weight of each emitter.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SpecularBake {
    emitters: usize,
    data: Vec<f32>,
}

/// The level segment of ρ: (j, t, 1/(ρ_{j+1} − ρ_j)) with ρ = (1 − t) ρ_j + t ρ_{j+1}; ρ outside
/// the levels is clamped (t = 0 or 1, no slope).
fn segment(rho: f32) -> (usize, f32, f32) {
    if !(rho > BAKE_RHO[0]) {
        return (0, 0.0, 0.0);
    }
    for j in 0..LEVELS - 1 {
        if rho <= BAKE_RHO[j + 1] {
            let inv = 1.0 / (BAKE_RHO[j + 1] - BAKE_RHO[j]);
            return (j, (rho - BAKE_RHO[j]) * inv, inv);
        }
    }
    (LEVELS - 2, 1.0, 0.0)
}

impl SpecularBake {
    fn stride(emitters: usize) -> usize {
        6 + 2 * emitters
    }

    /// Bytes per pixel (for the memory estimate).
    pub fn bytes_per_pixel(emitters: usize) -> usize {
        4 * LEVELS * Self::stride(emitters)
    }

    pub fn new(emitters: usize) -> Self {
        SpecularBake {
            emitters,
            data: Vec::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.data.len() / (LEVELS * Self::stride(self.emitters))
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Bakes the pixels whose samples are `samples` (`m` per pixel, in order) and N·v.
    pub fn extend(&mut self, n_dot_v: &[f32], samples: &[IncidentSample], m: usize) {
        let (k, stride) = (self.emitters, Self::stride(self.emitters));
        let old = self.data.len();
        self.data.resize(old + n_dot_v.len() * LEVELS * stride, 0.0);
        self.data[old..]
            .par_chunks_mut(LEVELS * stride)
            .zip(samples.par_chunks(m))
            .zip(n_dot_v.par_iter())
            .for_each(|((out, smp), &nv)| {
                for (j, lv) in out.chunks_exact_mut(stride).enumerate() {
                    let alpha = (BAKE_RHO[j] * BAKE_RHO[j]).max(ALPHA_MIN);
                    for s in smp {
                        if s.weight == 0.0 {
                            continue;
                        }
                        let spec = ggx_d(alpha, s.n_dot_h) * smith_g2_visibility(alpha, nv, s.n_dot_d) * s.weight;
                        if spec == 0.0 {
                            continue;
                        }
                        let fm = (1.0 - s.d_dot_h.clamp(0.0, 1.0)).powi(5);
                        let (a, b) = (spec * (1.0 - fm), spec * fm);
                        if s.emitter >= 0 {
                            lv[6 + s.emitter as usize] += a;
                            lv[6 + k + s.emitter as usize] += b;
                        } else {
                            for c in 0..3 {
                                lv[c] += a * s.radiance[c];
                                lv[3 + c] += b * s.radiance[c];
                            }
                        }
                    }
                }
            });
    }

    /// (A, B) of pixel `p` at level `j` under emissions `emission`.
    fn level(&self, p: usize, j: usize, emission: &[Vec3]) -> (Vec3, Vec3) {
        let stride = Self::stride(self.emitters);
        let lv = &self.data[(p * LEVELS + j) * stride..(p * LEVELS + j + 1) * stride];
        let (mut a, mut b) = (Vec3::from_slice(&lv[0..3]), Vec3::from_slice(&lv[3..6]));
        for (k, l) in emission.iter().enumerate().take(self.emitters) {
            a += *l * lv[6 + k];
            b += *l * lv[6 + self.emitters + k];
        }
        (a, b)
    }

    /// Each pixel's sums averaged, level by level, with those of the nearby pixels whose
    /// specular geometry matches its own within a fraction of that level's lobe: the mismatch
    /// of pixels p and q is δ = ∠(r_p, r_q) + ∠(n_p, n_q) + |x_p − x_q| / `parallax` (r the
    /// mirror direction of the view about the normal; the last term the angle the offset makes
    /// at `parallax`, the distance of what the lobe reflects), and q joins p's level j where
    /// δ ≤ `kappa`·α_j (α_j = ρ_j², the lobe's width in radians, about). Candidates are the
    /// pixels within `radius` (world).
    ///
    /// Why (and why `stage2.specular_pool` is off): a pixel's own specular sums rest on the few
    /// of its samples that fall in the lobe, and a noisy regressor drags the coefficient fitted
    /// on it towards zero (regression dilution). With 128 samples stage 2 fits the default
    /// room's glossy surfaces at Ks 0.29 (truth 0.39) and its floor's sheen at 0.011 (0.044).
    /// But that same pull is what takes matte surfaces' Ks to zero: pooled, their rough lobe
    /// shades like Kd and keeps whatever Ks it started with. The bias pooling adds is a blur of
    /// the reflected light by a fraction of the lobe: none at the sharp levels, where few
    /// pixels match.
    /// Deterministic: neighbours are summed in ascending index.
    pub fn pooled(&self, points: &[ShadingPoint], radius: f32, kappa: f32, parallax: f32) -> SpecularBake {
        assert_eq!(points.len(), self.len(), "one point per baked pixel");
        let stride = Self::stride(self.emitters);
        let row = LEVELS * stride;
        let positions: Vec<[f32; 3]> = points.iter().map(|p| p.position.to_array()).collect();
        let mirror: Vec<Vec3> = points
            .iter()
            .map(|p| (2.0 * p.normal.dot(p.view) * p.normal - p.view).normalize_or_zero())
            .collect();
        let tree = KdTree::new(&positions);
        let tolerance: [f32; LEVELS] = std::array::from_fn(|j| kappa * BAKE_RHO[j] * BAKE_RHO[j]);
        let angle = |a: Vec3, b: Vec3| a.dot(b).clamp(-1.0, 1.0).acos();
        let mut data = vec![0.0f32; self.data.len()];
        data.par_chunks_mut(row)
            .enumerate()
            .for_each_init(Vec::new, |near, (i, out)| {
                let p = &points[i];
                tree.within(positions[i], radius, near);
                let mut count = [0u32; LEVELS];
                for &q in near.iter() {
                    let o = &points[q];
                    let delta = angle(mirror[i], mirror[q])
                        + angle(p.normal, o.normal)
                        + (p.position - o.position).length() / parallax;
                    let src = &self.data[q * row..(q + 1) * row];
                    for j in 0..LEVELS {
                        if delta <= tolerance[j] || q == i {
                            count[j] += 1;
                            let (dst, from) = (
                                &mut out[j * stride..(j + 1) * stride],
                                &src[j * stride..(j + 1) * stride],
                            );
                            dst.iter_mut().zip(from).for_each(|(d, v)| *d += v);
                        }
                    }
                }
                for j in 0..LEVELS {
                    let inv = 1.0 / count[j].max(1) as f32;
                    out[j * stride..(j + 1) * stride].iter_mut().for_each(|d| *d *= inv);
                }
            });
        SpecularBake {
            emitters: self.emitters,
            data,
        }
    }

    /// The specular part of pixel `p`'s estimate for `brdf` (its Kd plays no part).
    pub fn shade(&self, p: usize, brdf: &GgxBrdf, emission: &[Vec3]) -> Vec3 {
        let (j, t, _) = segment(brdf.rho);
        let f90 = fresnel_f90(brdf.ks);
        let (a0, b0) = self.level(p, j, emission);
        let (a1, b1) = self.level(p, j + 1, emission);
        let (a, b) = (a0.lerp(a1, t), b0.lerp(b1, t));
        brdf.ks * a + b * f90
    }

    /// [`SpecularBake::shade`] and the gradient of ⟨g, ·⟩ with respect to Ks and ρ (returned;
    /// Kd's is zero) and to each emission (added to `d_emission`).
    pub fn shade_backward(
        &self,
        p: usize,
        brdf: &GgxBrdf,
        emission: &[Vec3],
        g: Vec3,
        d_emission: &mut [Vec3],
    ) -> (Vec3, GgxGrad) {
        let (j, t, inv) = segment(brdf.rho);
        let lum = luminance(brdf.ks);
        let f90 = fresnel_f90(brdf.ks);
        let (a0, b0) = self.level(p, j, emission);
        let (a1, b1) = self.level(p, j + 1, emission);
        let (a, b) = (a0.lerp(a1, t), b0.lerp(b1, t));
        let value = brdf.ks * a + b * f90;
        let mut ks = g * a;
        if lum < 0.04 {
            // F90 = lum(Ks)/0.04 is shared by the channels: each channel of Ks moves all three.
            let s = g.dot(b) / 0.04;
            ks += Vec3::new(luminance(Vec3::X), luminance(Vec3::Y), luminance(Vec3::Z)) * s;
        }
        let d_value = brdf.ks * (a1 - a0) + (b1 - b0) * f90;
        let rho = g.dot(d_value) * inv;
        let stride = Self::stride(self.emitters);
        let (l0, l1) = (
            &self.data[(p * LEVELS + j) * stride..(p * LEVELS + j + 1) * stride],
            &self.data[(p * LEVELS + j + 1) * stride..(p * LEVELS + j + 2) * stride],
        );
        let k = self.emitters;
        for (e, d) in d_emission.iter_mut().enumerate().take(k) {
            let wa = l0[6 + e] + t * (l1[6 + e] - l0[6 + e]);
            let wb = l0[6 + k + e] + t * (l1[6 + k + e] - l0[6 + k + e]);
            *d += g * (brdf.ks * wa + Vec3::splat(f90 * wb));
        }
        (
            value,
            GgxGrad {
                kd: Vec3::ZERO,
                ks,
                rho,
            },
        )
    }
}

/// The cache of stage 2's surface pixels (in cache order): either their samples (`m` each, for
/// `stage2.specular_bake = false`) or their [`SpecularBake`]; the diffuse sums, pooled or each
/// pixel's own (empty when samples are kept and pooling is off).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShadingCache {
    pub samples: Vec<IncidentSample>,
    pub per_pixel: usize,
    pub diffuse: Vec<DiffuseSums>,
    pub bake: Option<SpecularBake>,
}

impl ShadingCache {
    fn samples_of(&self, s: usize) -> &[IncidentSample] {
        &self.samples[s * self.per_pixel..(s + 1) * self.per_pixel]
    }

    /// The estimate of eq:render for surface pixel `s` and material `brdf`.
    pub fn shade(&self, s: usize, brdf: &GgxBrdf, n_dot_v: f32, emission: &[Vec3]) -> Vec3 {
        match (&self.bake, self.diffuse.get(s)) {
            (Some(bake), Some(d)) => brdf.kd * FRAC_1_PI * d.irradiance(emission) + bake.shade(s, brdf, emission),
            (_, Some(d)) => shade_pooled(brdf, n_dot_v, self.samples_of(s), emission, d),
            _ => shade(brdf, n_dot_v, self.samples_of(s), emission),
        }
    }

    /// [`ShadingCache::shade`] and the gradient of ⟨g, ·⟩ with respect to the material
    /// (returned) and to each emission (added to `d_emission`).
    pub fn shade_backward(
        &self,
        s: usize,
        brdf: &GgxBrdf,
        n_dot_v: f32,
        emission: &[Vec3],
        g: Vec3,
        d_emission: &mut [Vec3],
    ) -> (Vec3, GgxGrad) {
        match (&self.bake, self.diffuse.get(s)) {
            (Some(bake), Some(d)) => {
                let (spec, mut grad) = bake.shade_backward(s, brdf, emission, g, d_emission);
                let (diffuse, kd) = d.backward(brdf.kd, emission, g, d_emission);
                grad.kd = kd;
                (diffuse + spec, grad)
            }
            (_, Some(d)) => shade_pooled_backward(brdf, n_dot_v, self.samples_of(s), emission, d, g, d_emission),
            _ => shade_backward(brdf, n_dot_v, self.samples_of(s), emission, g, d_emission),
        }
    }

    /// Surface pixels held.
    pub fn len(&self) -> usize {
        match &self.bake {
            Some(b) => b.len(),
            None => self.samples.len() / self.per_pixel.max(1),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg32;

    fn random_pixel(rng: &mut Pcg32, n: usize) -> (f32, Vec<IncidentSample>) {
        let nv = 0.2 + 0.8 * rng.gen::<f32>();
        let v = Vec3::new((1.0 - nv * nv).sqrt(), 0.0, nv);
        let samples = (0..n)
            .map(|i| {
                // Half the directions near the mirror direction, so that narrow lobes see some.
                let d = if i % 2 == 0 {
                    (Vec3::new(-v.x, 0.0, v.z) + 0.2 * Vec3::new(rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5, 0.0))
                        .normalize()
                } else {
                    let (a, b): (f32, f32) = (rng.gen::<f32>() * 6.283, rng.gen::<f32>().max(0.05));
                    let r = (1.0 - b * b).sqrt();
                    Vec3::new(r * a.cos(), r * a.sin(), b)
                };
                let h = (v + d).normalize();
                IncidentSample {
                    n_dot_d: d.z,
                    n_dot_h: h.z,
                    d_dot_h: d.dot(h),
                    weight: if d.z > 0.0 { rng.gen::<f32>() * 0.2 } else { 0.0 },
                    radiance: [rng.gen(), rng.gen(), rng.gen()],
                    emitter: if rng.gen::<f32>() < 0.3 {
                        rng.gen_range(0..2)
                    } else {
                        -1
                    },
                }
            })
            .collect();
        (nv, samples)
    }

    /// At a level the bake is the samples' own specular estimate; between levels it lies
    /// between the two levels' estimates.
    #[test]
    fn baked_estimate_equals_the_samples_at_every_level() {
        let mut rng = Pcg32::seed_from_u64(3);
        let emission = [Vec3::new(4.0, 3.0, 2.0), Vec3::new(1.0, 6.0, 0.5)];
        for _ in 0..20 {
            let (nv, samples) = random_pixel(&mut rng, 48);
            let mut bake = SpecularBake::new(2);
            bake.extend(&[nv], &samples, samples.len());
            for ks in [Vec3::new(0.5, 0.4, 0.3), Vec3::splat(0.02)] {
                for &rho in &BAKE_RHO {
                    let b = GgxBrdf::new(Vec3::ZERO, ks, rho);
                    let exact = shade(&b, nv, &samples, &emission);
                    let baked = bake.shade(0, &b, &emission);
                    assert!(
                        (exact - baked).abs().max_element() <= 1e-4 * (1.0 + exact.abs().max_element()),
                        "ρ {rho}: samples {exact}, baked {baked}"
                    );
                }
                let mid = GgxBrdf::new(Vec3::ZERO, ks, 0.4);
                let (lo, hi) = (
                    shade(&GgxBrdf { rho: 0.35, ..mid }, nv, &samples, &emission),
                    shade(&GgxBrdf { rho: 0.45, ..mid }, nv, &samples, &emission),
                );
                let v = bake.shade(0, &mid, &emission);
                for c in 0..3 {
                    assert!(v[c] >= lo[c].min(hi[c]) - 1e-5 && v[c] <= lo[c].max(hi[c]) + 1e-5);
                }
            }
        }
    }

    /// Pooling averages a level's sums over the pixels that reflect alike within that level's
    /// tolerance: two pixels at one point whose views differ by 10° share the rough levels' sums
    /// and keep their own at the sharp ones; a lone pixel and identical pixels keep theirs.
    #[test]
    fn specular_pooling_shares_rough_levels_only_between_pixels_that_reflect_alike() {
        let stride = SpecularBake::stride(1);
        let row = LEVELS * stride;
        let point = |tilt: f32, x: f32| ShadingPoint {
            position: Vec3::new(x, 0.0, 0.0),
            normal: Vec3::Z,
            view: Vec3::new(tilt.sin(), 0.0, tilt.cos()),
        };
        let ten = 10f32.to_radians();
        // Pixels 0 and 1 at the origin, views 30° and 40° from the normal; pixel 2 far away.
        let points = [point(0.5236, 0.0), point(0.5236 + ten, 0.0), point(0.5236, 5.0)];
        let data: Vec<f32> = (0..3 * row)
            .map(|i| (i / row) as f32 * 10.0 + (i % row) as f32 * 0.01)
            .collect();
        let bake = SpecularBake { emitters: 1, data };
        let pooled = bake.pooled(&points, 1.0, 0.5, 1.0);
        for j in 0..LEVELS {
            let (lo, hi) = (j * stride, (j + 1) * stride);
            let own0 = &bake.data[lo..hi];
            let own1 = &bake.data[row + lo..row + hi];
            let got0 = &pooled.data[lo..hi];
            // The mirror directions differ by 10°: within 0.5·ρ² only for ρ ≥ 0.6.
            let shared = 0.5 * BAKE_RHO[j] * BAKE_RHO[j] >= ten;
            for c in 0..stride {
                let want = if shared { 0.5 * (own0[c] + own1[c]) } else { own0[c] };
                assert!(
                    (got0[c] - want).abs() < 1e-5,
                    "level {j} value {c}: {} vs {want}",
                    got0[c]
                );
            }
            assert_eq!(
                &pooled.data[2 * row + lo..2 * row + hi],
                &bake.data[2 * row + lo..2 * row + hi]
            );
        }
        assert!(
            0.5 * 0.6f32 * 0.6 >= ten && 0.5 * 0.45f32 * 0.45 < ten,
            "both cases occur"
        );
        // Pixels alike in every way share every level; identical sums stay as they are.
        let same = [points[0]; 4];
        let rows: Vec<f32> = (0..4 * row).map(|i| (i % row) as f32).collect();
        let b = SpecularBake {
            emitters: 1,
            data: rows.clone(),
        };
        assert_eq!(b.pooled(&same, 1.0, 0.5, 1.0).data, rows);
    }

    /// The baked estimator's gradient (Kd, Ks on both sides of the F90 clamp, ρ inside a
    /// segment, every L[k]) matches central differences; with pooled diffuse sums through
    /// [`ShadingCache`].
    #[test]
    fn baked_gradient_matches_finite_differences() {
        let mut rng = Pcg32::seed_from_u64(8);
        for trial in 0..30 {
            let (nv, samples) = random_pixel(&mut rng, 32);
            let mut bake = SpecularBake::new(2);
            bake.extend(&[nv], &samples, samples.len());
            let cache = ShadingCache {
                samples: Vec::new(),
                per_pixel: samples.len(),
                diffuse: vec![DiffuseSums::of(&samples, 2)],
                bake: Some(bake),
            };
            let ks_scale = if trial % 3 == 0 { 0.03 } else { 0.6 };
            // ρ away from the levels (the slope jumps there).
            let rho = loop {
                let r = 0.06 + 0.9 * rng.gen::<f32>();
                if BAKE_RHO.iter().all(|l| (l - r).abs() > 0.01) {
                    break r;
                }
            };
            let brdf = GgxBrdf::new(
                Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 0.8,
                Vec3::new(rng.gen(), rng.gen(), rng.gen()) * ks_scale,
                rho,
            );
            let emission = vec![Vec3::new(3.0, 2.0, 1.0), Vec3::new(0.5, 8.0, 2.0)];
            let g = Vec3::new(rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5);
            let mut d_em = vec![Vec3::ZERO; 2];
            let (value, grad) = cache.shade_backward(0, &brdf, nv, &emission, g, &mut d_em);
            assert!((value - cache.shade(0, &brdf, nv, &emission)).abs().max_element() < 1e-5);
            let loss = |b: &GgxBrdf, e: &[Vec3]| g.dot(cache.shade(0, b, nv, e)) as f64;
            crate::stage2::shading::check_gradient_by_differences(
                trial, &brdf, &emission, &grad, &d_em, 2e-3f32, &loss,
            );
        }
    }
}
