//! The GGX microfacet BRDF of the supplementary ("BRDF Model", after Unreal Engine / Karis 2013),
//! with its importance sampling and the exact mixture pdf the supplementary gives:
//!
//! ```text
//! f_r(v,d) = f_d(Kd) + f_s(v,d; N,Ks,ρ)        f_d = Kd/π,  α = ρ²
//! f_s      = D(α,N,h) · G2(α,N,v,d) · F(Ks,d,h)
//! D        = α² / (π ((α²−1)(N·h)² + 1)²)
//! S(v,d)   = (N·d) sqrt(α² + (N·v)²(1−α²))
//! G2       = 1 / (2 (S(v,d) + S(d,v)))          (height-correlated Smith, 1/(4 N·v N·d) folded in)
//! F90      = min(lum(Ks)/0.04, 1)
//! F        = Ks + (F90 − Ks)(1 − d·h)⁵
//! w_d      = lum(Kd) / (lum(Kd) + lum(Ks))
//! p        = w_d p_d + (1 − w_d) p_s,   p_d = N·d/π,   p_s = D · G1(α,N,v) / (4 N·v)
//! G1       = 2 / (sqrt(1 + α²(1 − (N·v)²)/(N·v)²) + 1)
//! ```
//!
//! `p_s` is the density of reflecting `v` about a normal drawn from GGX's distribution of
//! *visible* normals D_v(h) = G1(v) max(0, v·h) D(h) / (N·v) (Heitz 2018), since the reflection
//! Jacobian is 1/(4 v·h); so the specular lobe is sampled with Heitz's VNDF routine and the
//! pdf below is exact. Reflected directions may fall below the horizon: they carry zero BRDF, and
//! `p_s` integrates to one over the whole sphere, not the hemisphere.
//!
//! The Fresnel term: the supplementary declares `F(Ks, d, h)` in f_s and then writes its last line
//! with `(1 − N·d)`; we follow the declared arguments and Unreal's implementation (Schlick with
//! the microfacet normal, `d·h = v·h`).
//!
//! Every term is a pure function of plain `f32` values (cosines, α, colours) so that stage 2 can
//! differentiate it with respect to Kd, Ks and ρ by hand.

use crate::color::luminance;
use crate::sampling::{cosine_hemisphere, Frame};
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI};

/// Smallest α used in evaluation: below it D becomes a delta that f32 cannot hold. ρ = 0.032.
pub const ALPHA_MIN: f32 = 1e-3;

/// GGX normal distribution D(α, N, h) of the supplementary, as a function of N·h.
#[inline]
pub fn ggx_d(alpha: f32, n_dot_h: f32) -> f32 {
    if n_dot_h <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let t = (a2 - 1.0) * n_dot_h * n_dot_h + 1.0;
    a2 / (PI * t * t)
}

/// The supplementary's "G2" (height-correlated Smith visibility, including 1/(4 N·v N·d)):
/// `1 / (2 (S(v,d) + S(d,v)))` with `S(v,d) = (N·d) sqrt(α² + (N·v)²(1−α²))`.
#[inline]
pub fn smith_g2_visibility(alpha: f32, n_dot_v: f32, n_dot_d: f32) -> f32 {
    if n_dot_v <= 0.0 || n_dot_d <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let s_vd = n_dot_d * (a2 + n_dot_v * n_dot_v * (1.0 - a2)).sqrt();
    let s_dv = n_dot_v * (a2 + n_dot_d * n_dot_d * (1.0 - a2)).sqrt();
    0.5 / (s_vd + s_dv)
}

/// Smith masking G1(α, N, v) of the supplementary.
#[inline]
pub fn smith_g1(alpha: f32, n_dot_v: f32) -> f32 {
    if n_dot_v <= 0.0 {
        return 0.0;
    }
    let c2 = n_dot_v * n_dot_v;
    2.0 / ((1.0 + alpha * alpha * (1.0 - c2) / c2).sqrt() + 1.0)
}

/// F90(Ks) = min(lum(Ks)/0.04, 1): surfaces darker than 4 % reflectance lose their grazing boost.
#[inline]
pub fn fresnel_f90(ks: Vec3) -> f32 {
    (luminance(ks) / 0.04).min(1.0)
}

/// Schlick Fresnel `Ks + (F90 − Ks)(1 − d·h)⁵`.
#[inline]
pub fn schlick_fresnel(ks: Vec3, d_dot_h: f32) -> Vec3 {
    let f90 = fresnel_f90(ks);
    let m = (1.0 - d_dot_h.clamp(0.0, 1.0)).powi(5);
    ks + (Vec3::splat(f90) - ks) * m
}

/// Diffuse-lobe selection weight w_d = lum(Kd) / (lum(Kd) + lum(Ks)); 1 for a black material.
#[inline]
pub fn diffuse_weight(kd: Vec3, ks: Vec3) -> f32 {
    let ld = luminance(kd).max(0.0);
    let ls = luminance(ks).max(0.0);
    if ld + ls > 0.0 {
        ld / (ld + ls)
    } else {
        1.0
    }
}

/// Which lobe a sample came from (for callers that want to treat specular paths differently).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BrdfLobe {
    Diffuse,
    Specular,
}

/// A sampled lighting direction `d` with its BRDF value, mixture pdf and the estimator weight
/// `f_r · (N·d) / p`.
#[derive(Clone, Copy, Debug)]
pub struct BrdfSample {
    pub d: Vec3,
    pub f: Vec3,
    pub pdf: f32,
    pub weight: Vec3,
    pub lobe: BrdfLobe,
}

/// Material parameters at a surface point: diffuse albedo Kd, specular albedo Ks (RGB, linear)
/// and roughness ρ (α = ρ²).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GgxBrdf {
    pub kd: Vec3,
    pub ks: Vec3,
    pub rho: f32,
}

impl GgxBrdf {
    pub fn new(kd: Vec3, ks: Vec3, rho: f32) -> Self {
        GgxBrdf { kd, ks, rho }
    }

    /// α = ρ², clamped below at [`ALPHA_MIN`].
    #[inline]
    pub fn alpha(&self) -> f32 {
        (self.rho * self.rho).max(ALPHA_MIN)
    }

    /// f_r(v, d) for unit vectors `v` (towards the viewer), `d` (towards the light) and normal `n`.
    /// Zero unless both directions lie above the surface.
    pub fn eval(&self, n: Vec3, v: Vec3, d: Vec3) -> Vec3 {
        let n_dot_v = n.dot(v);
        let n_dot_d = n.dot(d);
        if n_dot_v <= 0.0 || n_dot_d <= 0.0 {
            return Vec3::ZERO;
        }
        let h = (v + d).normalize();
        self.eval_cosines(n_dot_v, n_dot_d, n.dot(h), d.dot(h))
    }

    /// f_r from the four cosines it depends on (the form stage 2 differentiates).
    #[inline]
    pub fn eval_cosines(&self, n_dot_v: f32, n_dot_d: f32, n_dot_h: f32, d_dot_h: f32) -> Vec3 {
        let alpha = self.alpha();
        let diffuse = self.kd * FRAC_1_PI;
        let spec = ggx_d(alpha, n_dot_h) * smith_g2_visibility(alpha, n_dot_v, n_dot_d);
        diffuse + schlick_fresnel(self.ks, d_dot_h) * spec
    }

    /// Specular density p_s(v, d) = D G1(v) / (4 N·v), defined for every `d` on the sphere
    /// (zero when the half vector lies below the surface).
    pub fn pdf_specular(&self, n: Vec3, v: Vec3, d: Vec3) -> f32 {
        let n_dot_v = n.dot(v);
        if n_dot_v <= 0.0 {
            return 0.0;
        }
        let hv = v + d;
        let len = hv.length();
        if len <= 1e-7 {
            return 0.0;
        }
        let h = hv / len;
        let alpha = self.alpha();
        ggx_d(alpha, n.dot(h)) * smith_g1(alpha, n_dot_v) / (4.0 * n_dot_v)
    }

    /// Mixture pdf p(v, d) = w_d p_d + (1 − w_d) p_s (solid-angle measure).
    pub fn pdf(&self, n: Vec3, v: Vec3, d: Vec3) -> f32 {
        let w_d = diffuse_weight(self.kd, self.ks);
        let p_d = n.dot(d).max(0.0) * FRAC_1_PI;
        let p_s = if w_d < 1.0 { self.pdf_specular(n, v, d) } else { 0.0 };
        w_d * p_d + (1.0 - w_d) * p_s
    }

    /// Draws `d` from the mixture with three uniforms: `u[0]` picks the lobe by w_d, `u[1..3]`
    /// drive cosine sampling (diffuse) or VNDF sampling of h (specular). `None` when the sample
    /// carries no energy (view or sampled direction below the surface).
    pub fn sample(&self, n: Vec3, v: Vec3, u: [f32; 3]) -> Option<BrdfSample> {
        let frame = Frame::from_normal(n);
        let v_local = frame.to_local(v);
        if v_local.z <= 0.0 {
            return None;
        }
        let (d, lobe) = self.sample_direction_in(&frame, v, v_local, u);
        let n_dot_d = n.dot(d);
        if n_dot_d <= 0.0 {
            return None;
        }
        let pdf = self.pdf(n, v, d);
        if !(pdf > 0.0) || !pdf.is_finite() {
            return None;
        }
        let f = self.eval(n, v, d);
        Some(BrdfSample {
            d,
            f,
            pdf,
            weight: f * (n_dot_d / pdf),
            lobe,
        })
    }
}

impl GgxBrdf {
    /// The raw mixture sampler: a direction whose density is exactly [`GgxBrdf::pdf`] over the
    /// whole sphere (specular samples may fall below the horizon). Requires N·v > 0.
    pub fn sample_direction(&self, n: Vec3, v: Vec3, u: [f32; 3]) -> Vec3 {
        let frame = Frame::from_normal(n);
        self.sample_direction_in(&frame, v, frame.to_local(v), u).0
    }

    #[inline]
    fn sample_direction_in(&self, frame: &Frame, v: Vec3, v_local: Vec3, u: [f32; 3]) -> (Vec3, BrdfLobe) {
        let w_d = diffuse_weight(self.kd, self.ks);
        if u[0] < w_d {
            (frame.to_world(cosine_hemisphere(u[1], u[2])), BrdfLobe::Diffuse)
        } else {
            let h = frame.to_world(sample_ggx_vndf(v_local, self.alpha(), u[1], u[2]));
            (reflect(v, h), BrdfLobe::Specular)
        }
    }
}

/// Gradient of ⟨g, f_r⟩ with respect to the material parameters (Kd, Ks, ρ) for an upstream
/// gradient `g` on the RGB value of f_r: what stage 2 back-propagates into its material fields.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GgxGrad {
    pub kd: Vec3,
    pub ks: Vec3,
    pub rho: f32,
}

impl GgxBrdf {
    /// f_r(v, d) (the value of [`GgxBrdf::eval`], zero below the horizon) and the gradient of
    /// ⟨g, f_r⟩ with respect to Kd, Ks and ρ.
    pub fn eval_backward(&self, n: Vec3, v: Vec3, d: Vec3, g: Vec3) -> (Vec3, GgxGrad) {
        let n_dot_v = n.dot(v);
        let n_dot_d = n.dot(d);
        if n_dot_v <= 0.0 || n_dot_d <= 0.0 {
            return (Vec3::ZERO, GgxGrad::default());
        }
        let h = (v + d).normalize();
        self.eval_cosines_backward(n_dot_v, n_dot_d, n.dot(h), d.dot(h), g)
    }

    /// [`GgxBrdf::eval_cosines`] and the gradient of ⟨g, f_r⟩ with respect to Kd, Ks and ρ, from the
    /// four cosines (stage 2's inner loop: no allocation, no normalization, one square root per
    /// direction term). Hand-derived from the supplementary's formulas ("BRDF Model"):
    ///
    /// ```text
    /// f_r = Kd/π + F · D · G2                      with A = α², α = max(ρ², ALPHA_MIN)
    /// ∂/∂Kd   = g/π
    /// F_c     = Ks_c (1 − m) + F90 m,  m = (1 − d·h)⁵
    /// ∂/∂Ks_c = D G2 (g_c (1 − m) + (Σ g) m ∂F90/∂Ks_c),  ∂F90/∂Ks = lum weights / 0.04 (0 where min clamps)
    /// ∂D/∂A   = (t − 2 A (N·h)²) / (π t³),  t = (A − 1)(N·h)² + 1
    /// ∂G2/∂A  = −2 G2² Σ_(a,b) (N·b)(1 − (N·a)²) / (2 sqrt(A + (N·a)²(1 − A)))
    /// ∂/∂ρ    = ⟨g, F⟩ (∂D/∂A G2 + D ∂G2/∂A) · 2α · 2ρ   (0 where ALPHA_MIN clamps)
    /// ```
    #[inline]
    pub fn eval_cosines_backward(
        &self,
        n_dot_v: f32,
        n_dot_d: f32,
        n_dot_h: f32,
        d_dot_h: f32,
        g: Vec3,
    ) -> (Vec3, GgxGrad) {
        let diffuse = self.kd * FRAC_1_PI;
        let grad_kd = g * FRAC_1_PI;
        // Where eval_cosines' D or G2 vanish the specular term is identically zero, and so are
        // its derivatives.
        if n_dot_v <= 0.0 || n_dot_d <= 0.0 || n_dot_h <= 0.0 {
            let grad = GgxGrad {
                kd: grad_kd,
                ..GgxGrad::default()
            };
            return (diffuse, grad);
        }
        let rho2 = self.rho * self.rho;
        let alpha = rho2.max(ALPHA_MIN);
        let a2 = alpha * alpha;
        // D and ∂D/∂A, written as ggx_d is (same rounding of the value).
        let c2 = n_dot_h * n_dot_h;
        let t = (a2 - 1.0) * n_dot_h * n_dot_h + 1.0;
        let dist = a2 / (PI * t * t);
        let d_dist_da2 = (t - 2.0 * a2 * c2) / (PI * t * t * t);
        // G2 and ∂G2/∂A, written as smith_g2_visibility is.
        let nv2 = n_dot_v * n_dot_v;
        let nd2 = n_dot_d * n_dot_d;
        let qv = (a2 + nv2 * (1.0 - a2)).sqrt();
        let qd = (a2 + nd2 * (1.0 - a2)).sqrt();
        let vis = 0.5 / (n_dot_d * qv + n_dot_v * qd);
        let d_sum_da2 = 0.5 * (n_dot_d * (1.0 - nv2) / qv + n_dot_v * (1.0 - nd2) / qd);
        let d_vis_da2 = -2.0 * vis * vis * d_sum_da2;
        let spec = dist * vis;
        // Schlick Fresnel with F90 = min(lum(Ks)/0.04, 1), as schlick_fresnel.
        let f90_raw = luminance(self.ks) / 0.04;
        let f90 = f90_raw.min(1.0);
        let m = (1.0 - d_dot_h.clamp(0.0, 1.0)).powi(5);
        let fresnel = self.ks + (Vec3::splat(f90) - self.ks) * m;
        let value = diffuse + fresnel * spec;

        let mut d_fresnel = g * (1.0 - m);
        if f90_raw < 1.0 {
            // F90 is shared by the three channels: each channel of Ks moves all of them.
            let lum_weights = Vec3::new(luminance(Vec3::X), luminance(Vec3::Y), luminance(Vec3::Z));
            d_fresnel += lum_weights * ((g.x + g.y + g.z) * m / 0.04);
        }
        let grad_rho = if rho2 > ALPHA_MIN {
            g.dot(fresnel) * (d_dist_da2 * vis + dist * d_vis_da2) * (4.0 * alpha * self.rho)
        } else {
            0.0
        };
        let grad = GgxGrad {
            kd: grad_kd,
            ks: d_fresnel * spec,
            rho: grad_rho,
        };
        (value, grad)
    }
}

/// Mirror `v` about the unit normal `h`: `2 (v·h) h − v`.
#[inline]
pub fn reflect(v: Vec3, h: Vec3) -> Vec3 {
    2.0 * v.dot(h) * h - v
}

/// Heitz 2018, "Sampling the GGX Distribution of Visible Normals" (JCGT 7(4)), isotropic case:
/// a microfacet normal in the local frame (z = N) with density D_v(h) = G1(v) max(0,v·h) D(h)/v.z.
/// `v_local.z` must be positive.
pub fn sample_ggx_vndf(v_local: Vec3, alpha: f32, u1: f32, u2: f32) -> Vec3 {
    // Stretch the view into the hemisphere configuration (α = 1).
    let vh = Vec3::new(alpha * v_local.x, alpha * v_local.y, v_local.z).normalize();
    let len_sq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if len_sq > 0.0 {
        Vec3::new(-vh.y, vh.x, 0.0) / len_sq.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    // Uniform disk point, warped towards the visible half of the projected hemisphere.
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    let p1 = r * phi.cos();
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    // Unstretch back to the ellipsoid configuration.
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use rand::{Rng, SeedableRng};

    const LUM: [f64; 3] = [0.213, 0.715, 0.072];

    /// The supplementary's f_r in f64 from the cosines, the reference for finite differences.
    fn eval_f64(kd: DVec3, ks: DVec3, rho: f64, c: [f64; 4]) -> DVec3 {
        let [nv, nd, nh, dh] = c;
        let alpha = (rho * rho).max(ALPHA_MIN as f64);
        let a2 = alpha * alpha;
        let t = (a2 - 1.0) * nh * nh + 1.0;
        let dist = a2 / (std::f64::consts::PI * t * t);
        let s_vd = nd * (a2 + nv * nv * (1.0 - a2)).sqrt();
        let s_dv = nv * (a2 + nd * nd * (1.0 - a2)).sqrt();
        let vis = 0.5 / (s_vd + s_dv);
        let lum = LUM[0] * ks.x + LUM[1] * ks.y + LUM[2] * ks.z;
        let f90 = (lum / 0.04).min(1.0);
        let m = (1.0 - dh.clamp(0.0, 1.0)).powi(5);
        kd / std::f64::consts::PI + (ks + (DVec3::splat(f90) - ks) * m) * (dist * vis)
    }

    fn unit_around(rng: &mut impl Rng, n: Vec3, min_cos: f32) -> Vec3 {
        loop {
            let w = crate::sampling::uniform_sphere(rng.gen(), rng.gen());
            if n.dot(w) > min_cos {
                return w;
            }
        }
    }

    #[test]
    fn backward_matches_finite_differences() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let rhos = [0.05f32, 0.06, 0.1, 0.3, 0.6, 0.95, 1.0];
        let (mut worst_kd, mut worst_ks, mut worst_rho) = (0f64, 0f64, 0f64);
        for k in 0..4000 {
            let n = crate::sampling::uniform_sphere(rng.gen(), rng.gen());
            let v = unit_around(&mut rng, n, 0.05);
            let rho = if k % 2 == 0 {
                rhos[(k / 2) % rhos.len()]
            } else {
                rng.gen_range(0.05..1.0)
            };
            // Half the directions near the mirror lobe (where D is steep), half anywhere.
            let d = if k % 4 < 2 {
                let frame = Frame::from_normal(n);
                let alpha = rho * rho;
                let hl = Vec3::new(rng.gen_range(-2.0..2.0) * alpha, rng.gen_range(-2.0..2.0) * alpha, 1.0);
                let h = frame.to_world(hl.normalize());
                let d = reflect(v, h);
                if n.dot(d) < 0.05 {
                    continue;
                }
                d
            } else {
                unit_around(&mut rng, n, 0.05)
            };
            let kd = Vec3::new(rng.gen(), rng.gen(), rng.gen());
            // Ks below the F90 clamp (lum < 0.04) on a third of the cases, above it otherwise;
            // never within 5 % of the kink where central differences straddle it.
            let ks = loop {
                let scale = if k % 3 == 0 { 0.05 } else { 1.0 };
                let ks = Vec3::new(rng.gen(), rng.gen(), rng.gen()) * scale;
                if (luminance(ks) / 0.04 - 1.0).abs() > 0.05 {
                    break ks;
                }
            };
            let g = Vec3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            );
            let b = GgxBrdf::new(kd, ks, rho);
            let h = (v + d).normalize();
            let c32 = [n.dot(v), n.dot(d), n.dot(h), d.dot(h)];
            let (value, grad) = b.eval_backward(n, v, d, g);
            let (value_c, grad_c) = b.eval_cosines_backward(c32[0], c32[1], c32[2], c32[3], g);
            assert_eq!((value, grad), (value_c, grad_c));
            let fwd = b.eval(n, v, d);
            assert!(
                (value - fwd).abs().max_element() <= 1e-6 * fwd.max_element(),
                "{value} vs {fwd}"
            );

            let c = c32.map(|x| x as f64);
            let (kd64, ks64, g64) = (kd.as_dvec3(), ks.as_dvec3(), g.as_dvec3());
            let obj = |kd: DVec3, ks: DVec3, rho: f64| g64.dot(eval_f64(kd, ks, rho, c));
            let rho64 = rho as f64;
            // f32 computes t = (A − 1)(N·h)² + 1 with an absolute rounding error of ~1e-7, which
            // near the peak of a sharp lobe (t ≈ A = 6e-6 at ρ = 0.05) is a relative error of
            // 1e-7/t in t, hence ~2e-7/t in D and ~3e-7/t in ∂D/∂A: the forward pass has the same
            // error, so that is the accuracy the gradient is held to.
            let alpha64 = (rho64 * rho64).max(ALPHA_MIN as f64);
            let a2 = alpha64 * alpha64;
            let t = (a2 - 1.0) * c[2] * c[2] + 1.0;
            let f32_err = 1.2e-7 / t;
            let mut fd_ks = [0f64; 3];
            for i in 0..3 {
                // f_r is linear in Kd and piecewise linear in Ks (the kink kept > 5 % away).
                let mut e = DVec3::ZERO;
                e[i] = 1e-4;
                let fd_kd = (obj(kd64 + e, ks64, rho64) - obj(kd64 - e, ks64, rho64)) / 2e-4;
                worst_kd = worst_kd.max((grad.kd[i] as f64 - fd_kd).abs() / (fd_kd.abs() + 1e-3));
                fd_ks[i] = (obj(kd64, ks64 + e, rho64) - obj(kd64, ks64 - e, rho64)) / 2e-4;
            }
            let ks_scale = fd_ks.iter().fold(1e-6f64, |a, x| a.max(x.abs()));
            for (i, fd) in fd_ks.iter().enumerate() {
                worst_ks = worst_ks.max((grad.ks[i] as f64 - fd).abs() / (ks_scale * (1.0 + 3.0 * f32_err / 1e-4)));
            }
            let step = 1e-6 * rho64;
            let fd_rho = (obj(kd64, ks64, rho64 + step) - obj(kd64, ks64, rho64 - step)) / (2.0 * step);
            // ∂/∂ρ is a difference of terms (D rises then falls with A): measure the error against
            // the terms' magnitude, |⟨g,F⟩| ((t + 2A(N·h)²)/(π t³) G2 + D |∂G2/∂A|) 4αρ.
            let spec_only = eval_f64(DVec3::ZERO, ks64, rho64, c);
            let g_f = g64.abs().dot(spec_only); // |g|·F·D·G2
            let rho_scale = if rho64 * rho64 > ALPHA_MIN as f64 {
                let (nv, nd, nh) = (c[0], c[1], c[2]);
                let qv = (a2 + nv * nv * (1.0 - a2)).sqrt();
                let qd = (a2 + nd * nd * (1.0 - a2)).sqrt();
                let sum = nd * qv + nv * qd;
                let dlog_vis = (nd * (1.0 - nv * nv) / qv + nv * (1.0 - nd * nd) / qd) * 0.5 / sum;
                let dlog_d = (t + 2.0 * a2 * nh * nh) / (t * a2);
                g_f * (dlog_d + dlog_vis) * 4.0 * alpha64 * rho64
            } else {
                1e-6
            };
            worst_rho = worst_rho.max((grad.rho as f64 - fd_rho).abs() / (rho_scale * (1.0 + 4.0 * f32_err / 1e-3)));
        }
        eprintln!("worst errors (relative to each derivative's scale): kd {worst_kd:.2e} ks {worst_ks:.2e} rho {worst_rho:.2e}");
        assert!(worst_kd < 1e-4 && worst_ks < 1e-3 && worst_rho < 1e-3);
    }

    #[test]
    fn backward_clamps() {
        // ρ² below ALPHA_MIN: α does not move, nor does anything with ρ.
        let b = GgxBrdf::new(Vec3::splat(0.3), Vec3::splat(0.5), 0.02);
        let (n, v) = (Vec3::Z, Vec3::new(0.3, 0.0, 1.0).normalize());
        let d = Vec3::new(-0.3, 0.01, 1.0).normalize();
        let (value, grad) = b.eval_backward(n, v, d, Vec3::ONE);
        assert!(value.max_element() > 0.0 && grad.rho == 0.0);
        // Below the horizon: no value, no gradient (also the diffuse part, as eval).
        let (value, grad) = b.eval_backward(n, v, -d, Vec3::ONE);
        assert_eq!((value, grad), (Vec3::ZERO, GgxGrad::default()));
        // F90 clamped at 1: the channels of Ks decouple, ∂/∂Ks_c ∝ g_c.
        let b = GgxBrdf::new(Vec3::ZERO, Vec3::new(0.5, 0.6, 0.7), 0.4);
        let (_, grad) = b.eval_backward(n, v, Vec3::new(-0.2, 0.0, 1.0).normalize(), Vec3::new(1.0, 0.0, 0.0));
        assert!(grad.ks.x > 0.0 && grad.ks.y == 0.0 && grad.ks.z == 0.0);
    }
}
