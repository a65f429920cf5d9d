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
