//! A mixture of direction densities: the proposal of stage 2's Monte Carlo estimator of the
//! rendering equation (paper eq:render). Stage 2 importance-samples the supplementary's GGX BRDF
//! ("BRDF Model": cosine lobe for f_d, VNDF lobe for f_s) together with its emitter clusters
//! (cones towards their bounding spheres) and combines them by one-sample MIS with the balance
//! heuristic, which is the same as drawing from the mixture and dividing by the mixture pdf
//! (Veach 1997, §9.2.4): every sample is weighted f·cos/p_mix, whichever lobe produced it.
//!
//! The mixture is a fixed-capacity value (no heap) built per shading point. A lobe that cannot
//! be drawn at that point (a specular or BRDF lobe seen from below, N·v ≤ 0; a cone whose sphere
//! contains x) drops out, and the remaining weights are renormalized, so that [`sample`] and
//! [`pdf`] always describe the same normalized density.
//!
//! [`sample`]: DirectionMixture::sample
//! [`pdf`]: DirectionMixture::pdf

use crate::brdf::{ggx_d, reflect, sample_ggx_vndf, smith_g1, GgxBrdf, ALPHA_MIN};
use crate::cone_light::{cone_density, cone_sample};
use crate::light::cone_one_minus_cos;
use crate::sampling::{cosine_hemisphere, Frame};
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// One component density of a [`DirectionMixture`] (solid-angle measure, over the whole sphere).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lobe {
    /// Cosine-weighted hemisphere about n: p = max(N·d, 0)/π.
    Cosine,
    /// GGX specular lobe for the view v: h drawn from the visible normals (Heitz 2018), d = v
    /// reflected about h, p = D G1(v)/(4 N·v) as [`GgxBrdf::pdf_specular`]. α is clamped below at
    /// [`ALPHA_MIN`] as in the BRDF. Directions may fall below the horizon.
    Specular { alpha: f32 },
    /// Uniform in the cone that the sphere (`centre`, `radius`) subtends from x
    /// ([`crate::cone_light::cone_sample`]): an emitter cluster.
    Cone { centre: Vec3, radius: f32 },
    /// The supplementary's luminance-weighted diffuse/specular mixture, exactly
    /// [`GgxBrdf::sample_direction`] and [`GgxBrdf::pdf`].
    Brdf(GgxBrdf),
}

/// Capacity of a [`DirectionMixture`] (BRDF lobes plus a few emitter cones).
pub const MAX_LOBES: usize = 8;

/// Up to [`MAX_LOBES`] weighted lobes; weights are relative (normalized over the lobes that can
/// be drawn at the query point).
#[derive(Clone, Copy, Debug)]
pub struct DirectionMixture {
    weights: [f32; MAX_LOBES],
    lobes: [Lobe; MAX_LOBES],
    len: usize,
}

impl Default for DirectionMixture {
    fn default() -> Self {
        Self::new()
    }
}

/// Specular density D G1(v)/(4 N·v) at d (the reflection Jacobian 1/(4 v·h) times the VNDF
/// density G1 (v·h) D/(N·v)); zero when v + d vanishes or h lies below the surface.
#[inline]
fn specular_pdf(alpha: f32, n: Vec3, v: Vec3, d: Vec3, n_dot_v: f32) -> f32 {
    let hv = v + d;
    let len = hv.length();
    if len <= 1e-7 {
        return 0.0;
    }
    ggx_d(alpha, n.dot(hv) / len) * smith_g1(alpha, n_dot_v) / (4.0 * n_dot_v)
}

impl DirectionMixture {
    pub fn new() -> Self {
        DirectionMixture {
            weights: [0.0; MAX_LOBES],
            lobes: [Lobe::Cosine; MAX_LOBES],
            len: 0,
        }
    }

    /// Adds a lobe with relative weight `weight`; non-positive (or non-finite) weights are
    /// ignored. Panics past [`MAX_LOBES`] lobes.
    pub fn push(&mut self, weight: f32, lobe: Lobe) {
        if !(weight > 0.0 && weight.is_finite()) {
            return;
        }
        assert!(self.len < MAX_LOBES, "DirectionMixture holds at most {MAX_LOBES} lobes");
        self.weights[self.len] = weight;
        self.lobes[self.len] = lobe;
        self.len += 1;
    }

    /// Number of lobes pushed (with positive weight).
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether the lobe can be drawn at (x, N·v): its weight counts only then.
    #[inline]
    fn active(lobe: &Lobe, x: Vec3, n_dot_v: f32) -> bool {
        match *lobe {
            Lobe::Cosine => true,
            Lobe::Specular { .. } | Lobe::Brdf(_) => n_dot_v > 0.0,
            Lobe::Cone { centre, radius } => cone_one_minus_cos(x, centre, radius).is_some(),
        }
    }

    /// Draws a direction with `u[0]` choosing the lobe (then rescaled to [0,1) and reused by the
    /// BRDF lobe's own diffuse/specular choice) and `u[1], u[2]` driving the lobe's 2D warp.
    /// Returns the unit direction (possibly below the horizon) and its mixture pdf (> 0); `None`
    /// when no lobe can be drawn at this point.
    pub fn sample(&self, x: Vec3, n: Vec3, v: Vec3, u: [f32; 3]) -> Option<(Vec3, f32)> {
        let n_dot_v = n.dot(v);
        let mut total = 0.0;
        for i in 0..self.len {
            if Self::active(&self.lobes[i], x, n_dot_v) {
                total += self.weights[i];
            }
        }
        // Weights are finite and positive, so total is a number.
        if total <= 0.0 {
            return None;
        }
        // Pick the lobe by inverting the cumulative active weights; the last active lobe takes
        // what rounding leaves over.
        let target = u[0] * total;
        let mut cum = 0.0;
        let mut chosen = None;
        for i in 0..self.len {
            if !Self::active(&self.lobes[i], x, n_dot_v) {
                continue;
            }
            let w = self.weights[i];
            chosen = Some((i, ((target - cum) / w).clamp(0.0, 1.0 - f32::EPSILON)));
            if target < cum + w {
                break;
            }
            cum += w;
        }
        let (i, u0) = chosen?;
        let d = match self.lobes[i] {
            Lobe::Cosine => Frame::from_normal(n).to_world(cosine_hemisphere(u[1], u[2])),
            Lobe::Specular { alpha } => {
                let frame = Frame::from_normal(n);
                let h = sample_ggx_vndf(frame.to_local(v), alpha.max(ALPHA_MIN), u[1], u[2]);
                reflect(v, frame.to_world(h))
            }
            Lobe::Cone { centre, radius } => cone_sample(x, centre, radius, u[1], u[2])?.0,
            Lobe::Brdf(b) => b.sample_direction(n, v, [u0, u[1], u[2]]),
        };
        let pdf = self.pdf(x, n, v, d);
        (pdf > 0.0 && pdf.is_finite()).then_some((d, pdf))
    }

    /// Mixture density (solid angle) of the unit direction `d` at x, for unit normal `n` and
    /// unit view direction `v`: Σ w_i p_i(d) / Σ w_i over the lobes that can be drawn here.
    pub fn pdf(&self, x: Vec3, n: Vec3, v: Vec3, d: Vec3) -> f32 {
        let n_dot_v = n.dot(v);
        let (mut total, mut acc) = (0.0, 0.0);
        for i in 0..self.len {
            let lobe = &self.lobes[i];
            if !Self::active(lobe, x, n_dot_v) {
                continue;
            }
            let p = match *lobe {
                Lobe::Cosine => n.dot(d).max(0.0) * FRAC_1_PI,
                Lobe::Specular { alpha } => specular_pdf(alpha.max(ALPHA_MIN), n, v, d, n_dot_v),
                Lobe::Cone { centre, radius } => cone_density(x, centre, radius, d),
                Lobe::Brdf(b) => b.pdf(n, v, d),
            };
            total += self.weights[i];
            acc += self.weights[i] * p;
        }
        if total > 0.0 {
            acc / total
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chi2::chi2_pvalue;
    use rand::{Rng, SeedableRng};

    /// A tilted shading frame, a view 40° off the normal, and an emitter sphere 60° off it on the
    /// other side (its cone, of half-angle ≈ 14.5°, straddles nothing but is well off-axis).
    fn setup() -> (Vec3, Vec3, Vec3, Vec3, f32) {
        let n = Vec3::new(0.2, 0.3, 0.9).normalize();
        let f = Frame::from_normal(n);
        let v = f.to_world(Vec3::new(40f32.to_radians().sin(), 0.0, 40f32.to_radians().cos()));
        let x = Vec3::new(0.5, -0.2, 0.1);
        let to_light = f.to_world(
            Vec3::new(
                -0.6 * 60f32.to_radians().sin(),
                0.8 * 60f32.to_radians().sin(),
                60f32.to_radians().cos(),
            )
            .normalize(),
        );
        (n, v, x, x + 2.0 * to_light, 0.5)
    }

    fn mixtures() -> Vec<(&'static str, DirectionMixture)> {
        let (_, _, _, centre, radius) = setup();
        let cone = Lobe::Cone { centre, radius };
        let brdf = Lobe::Brdf(GgxBrdf::new(Vec3::new(0.5, 0.4, 0.3), Vec3::splat(0.2), 0.4));
        let spec = Lobe::Specular { alpha: 0.1 };
        let of = |lobes: &[(f32, Lobe)]| {
            let mut m = DirectionMixture::new();
            lobes.iter().for_each(|&(w, l)| m.push(w, l));
            m
        };
        vec![
            (
                "cosine+specular+cone",
                of(&[(0.5, Lobe::Cosine), (0.3, spec), (0.2, cone)]),
            ),
            ("brdf+cone", of(&[(2.0, brdf), (1.0, cone)])),
            ("cosine", of(&[(1.0, Lobe::Cosine)])),
            ("specular α=0.1", of(&[(1.0, spec)])),
            ("specular α=0.6", of(&[(1.0, Lobe::Specular { alpha: 0.6 })])),
            ("cone", of(&[(1.0, cone)])),
            ("brdf", of(&[(1.0, brdf)])),
        ]
    }

    #[test]
    fn mixture_pdf_integrates_to_one() {
        let (n, v, x, _, _) = setup();
        let frame = Frame::from_normal(n);
        let mut rng = rand_pcg::Pcg32::seed_from_u64(1);
        for (name, m) in mixtures() {
            // Jittered (cos θ, φ) grid about n: equal-solid-angle cells of 4π/(nc·np).
            let (nc, np) = (1000, 400);
            let mut acc = 0.0f64;
            for i in 0..nc {
                for j in 0..np {
                    let c = -1.0 + 2.0 * (i as f32 + rng.gen::<f32>()) / nc as f32;
                    let phi = std::f32::consts::TAU * (j as f32 + rng.gen::<f32>()) / np as f32;
                    let s = (1.0 - c * c).max(0.0).sqrt();
                    let d = frame.to_world(Vec3::new(s * phi.cos(), s * phi.sin(), c));
                    acc += m.pdf(x, n, v, d) as f64;
                }
            }
            let total = acc * 4.0 * std::f64::consts::PI / (nc * np) as f64;
            assert!((total - 1.0).abs() < 0.01, "{name}: ∫ pdf dω = {total}");
        }
    }

    #[test]
    fn sampling_matches_pdf_chi_square() {
        let (n, v, x, _, _) = setup();
        let cases = mixtures();
        // Šidák-corrected 0.1 % significance over the cases.
        let significance = 1.0 - (1.0f64 - 1e-3).powf(1.0 / cases.len() as f64);
        for (k, (name, m)) in cases.iter().enumerate() {
            let p = chi2_pvalue(
                n,
                -1.0,
                |d| m.pdf(x, n, v, d) as f64,
                |u| {
                    let (d, pdf) = m.sample(x, n, v, u).expect("every lobe can be drawn here");
                    assert!((d.length() - 1.0).abs() < 1e-4);
                    assert!(pdf > 0.0);
                    assert_eq!(pdf, m.pdf(x, n, v, d), "{name}: the returned pdf is the mixture pdf");
                    Some(d)
                },
                200_000,
                31 + k as u64,
            );
            eprintln!("{name}: χ² p-value {p:.3}");
            assert!(p > significance, "{name}: χ² p-value {p:.2e} < {significance:.2e}");
        }
    }

    #[test]
    fn mismatched_weights_are_detected() {
        // The χ² test must be able to fail: samples from one weighting, pdf of another.
        let (n, v, x, centre, radius) = setup();
        let (mut a, mut b) = (DirectionMixture::new(), DirectionMixture::new());
        a.push(0.5, Lobe::Cosine);
        a.push(0.5, Lobe::Cone { centre, radius });
        b.push(0.55, Lobe::Cosine);
        b.push(0.45, Lobe::Cone { centre, radius });
        let p = chi2_pvalue(
            n,
            -1.0,
            |d| a.pdf(x, n, v, d) as f64,
            |u| b.sample(x, n, v, u).map(|s| s.0),
            200_000,
            3,
        );
        assert!(p < 1e-6, "p-value {p:.2e}");
    }

    #[test]
    fn lobes_that_cannot_be_drawn_drop_out() {
        let (n, v, x, centre, radius) = setup();
        let cosine = {
            let mut m = DirectionMixture::new();
            m.push(1.0, Lobe::Cosine);
            m
        };
        // Zero weights are ignored.
        let mut m = DirectionMixture::new();
        m.push(1.0, Lobe::Cosine);
        m.push(0.0, Lobe::Cone { centre, radius });
        assert_eq!(m.len(), 1);
        // A cone whose sphere contains x gives its weight to the others.
        let mut inside = DirectionMixture::new();
        inside.push(1.0, Lobe::Cosine);
        inside.push(3.0, Lobe::Cone { centre: x, radius: 0.1 });
        // A view below the surface disables the specular and BRDF lobes.
        let mut below = DirectionMixture::new();
        below.push(1.0, Lobe::Cosine);
        below.push(2.0, Lobe::Specular { alpha: 0.3 });
        below.push(2.0, Lobe::Brdf(GgxBrdf::new(Vec3::ONE, Vec3::ONE, 0.5)));
        let v_below = reflect(v, n) * -1.0;
        assert!(n.dot(v_below) < 0.0);
        let mut rng = rand_pcg::Pcg32::seed_from_u64(8);
        for _ in 0..1000 {
            let u = [rng.gen(), rng.gen(), rng.gen()];
            let (d, p) = inside.sample(x, n, v, u).unwrap();
            assert!(n.dot(d) >= 0.0 && (p - cosine.pdf(x, n, v, d)).abs() <= 1e-6 * p);
            let (d, p) = below.sample(x, n, v_below, u).unwrap();
            assert!(n.dot(d) >= 0.0 && (p - cosine.pdf(x, n, v, d)).abs() <= 1e-6 * p);
        }
        // Nothing to draw.
        let mut none = DirectionMixture::new();
        assert!(none.sample(x, n, v, [0.5; 3]).is_none());
        none.push(1.0, Lobe::Specular { alpha: 0.2 });
        assert!(none.sample(x, n, v_below, [0.5; 3]).is_none());
        assert_eq!(none.pdf(x, n, v_below, n), 0.0);
    }

    #[test]
    fn brdf_lobe_is_the_brdf_sampler() {
        // With u[0] rescaled, the BRDF lobe alone reproduces GgxBrdf::sample_direction exactly.
        let (n, v, x, _, _) = setup();
        let b = GgxBrdf::new(Vec3::new(0.5, 0.4, 0.3), Vec3::splat(0.2), 0.4);
        let mut m = DirectionMixture::new();
        m.push(1.0, Lobe::Brdf(b));
        let mut rng = rand_pcg::Pcg32::seed_from_u64(12);
        for _ in 0..1000 {
            let u = [rng.gen(), rng.gen(), rng.gen()];
            let (d, p) = m.sample(x, n, v, u).unwrap();
            assert_eq!(d, b.sample_direction(n, v, u));
            assert!((p - b.pdf(n, v, d)).abs() <= 1e-6 * p);
        }
    }
}
