//! χ² goodness of fit of a direction sampler against its density (after pbrt-v4's chi2test):
//! the test the samplers of this crate (BRDF, lights, mixtures) are checked with.

use crate::sampling::Frame;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

/// Regularized lower incomplete gamma P(a, x) (Numerical Recipes: series / continued fraction).
pub fn gamma_p(a: f64, x: f64) -> f64 {
    fn ln_gamma(x: f64) -> f64 {
        let c = [
            76.18009172947146,
            -86.50532032941677,
            24.01409824083091,
            -1.231739572450155,
            0.1208650973866179e-2,
            -0.5395239384953e-5,
        ];
        let mut y = x;
        let t = x + 5.5 - (x + 0.5) * (x + 5.5).ln();
        let mut s = 1.000000000190015;
        for ci in c {
            y += 1.0;
            s += ci / y;
        }
        -t + (2.5066282746310005 * s / x).ln()
    }
    if x <= 0.0 {
        return 0.0;
    }
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        sum * (-x + a * x.ln() - ln_gamma(a)).exp()
    } else {
        let (mut b, mut c, mut d) = (x + 1.0 - a, 1e300, 1.0 / (x + 1.0 - a));
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            d = 1.0 / if d.abs() < 1e-300 { 1e-300 } else { d };
            c = b + an / c;
            if c.abs() < 1e-300 {
                c = 1e-300;
            }
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        1.0 - (-x + a * x.ln() - ln_gamma(a)).exp() * h
    }
}

/// p-value of the χ² test of `sample` against `pdf` on equal-solid-angle bins in
/// (cos θ, φ) about `axis`, over cos θ ∈ [cos_min, 1] (which must hold the whole support:
/// a sample below it fails the test). Cells expecting fewer than 5 samples are pooled.
pub fn chi2_pvalue(
    axis: Vec3,
    cos_min: f64,
    pdf: impl Fn(Vec3) -> f64,
    mut sample: impl FnMut([f32; 3]) -> Option<Vec3>,
    samples: usize,
    seed: u64,
) -> f64 {
    let (nt, np, sub) = (40usize, 80usize, 16usize);
    let frame = Frame::from_normal(axis);
    let (dc, dp) = ((1.0 - cos_min) / nt as f64, 2.0 * PI / np as f64);
    let dir = |c: f64, phi: f64| {
        let s = (1.0 - c * c).max(0.0).sqrt();
        frame.to_world(Vec3::new((s * phi.cos()) as f32, (s * phi.sin()) as f32, c as f32))
    };
    let mut observed = vec![0f64; nt * np];
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    for _ in 0..samples {
        let Some(d) = sample([rng.gen(), rng.gen(), rng.gen()]) else {
            continue;
        };
        let l = frame.to_local(d);
        let c = (l.z as f64).clamp(-1.0, 1.0);
        assert!(c >= cos_min - 1e-6, "a sample outside the binned range (cos θ = {c})");
        let mut phi = (l.y as f64).atan2(l.x as f64);
        if phi < 0.0 {
            phi += 2.0 * PI;
        }
        let i = (((c - cos_min) / dc) as usize).min(nt - 1);
        let j = ((phi / dp) as usize).min(np - 1);
        observed[i * np + j] += 1.0;
    }
    let mut cells: Vec<(f64, f64)> = Vec::with_capacity(nt * np);
    for i in 0..nt {
        for j in 0..np {
            let mut e = 0.0;
            for a in 0..sub {
                let c = cos_min + (i as f64 + (a as f64 + 0.5) / sub as f64) * dc;
                for b in 0..sub {
                    e += pdf(dir(c, (j as f64 + (b as f64 + 0.5) / sub as f64) * dp));
                }
            }
            cells.push((e * dc * dp / (sub * sub) as f64 * samples as f64, observed[i * np + j]));
        }
    }
    cells.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
    let (mut pool_e, mut pool_o, mut chsq, mut dof) = (0.0, 0.0, 0.0, 0usize);
    for &(e, o) in &cells {
        if e < 5.0 {
            pool_e += e;
            pool_o += o;
        } else {
            chsq += (o - e) * (o - e) / e;
            dof += 1;
        }
    }
    if pool_e > 0.0 {
        chsq += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        dof += 1;
    }
    1.0 - gamma_p((dof - 1) as f64 / 2.0, chsq / 2.0)
}
