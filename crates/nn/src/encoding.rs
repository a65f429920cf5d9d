//! Parameter-free encodings: the sinusoidal positional encoding of NeRF/VolSDF (with its Jacobian,
//! for SDF spatial gradients through the paper backbone) and real spherical harmonics for view
//! directions.

use serde::{Deserialize, Serialize};

/// `γ(x) = [x, sin(2⁰x), cos(2⁰x), …, sin(2^{L−1}x), cos(2^{L−1}x)]` (Mildenhall et al. 2020, eq. 4,
/// in VolSDF/IDR's form: log-spaced bands without the factor π, input included). The paper uses
/// `L = 6` for positions and `L = 4` for view directions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrequencyEncoding {
    pub input_dim: usize,
    pub frequencies: usize,
}

impl FrequencyEncoding {
    pub fn new(input_dim: usize, frequencies: usize) -> Self {
        FrequencyEncoding { input_dim, frequencies }
    }

    pub fn output_dim(&self) -> usize {
        self.input_dim * (1 + 2 * self.frequencies)
    }

    /// Encode `n` points (`x`: `[n × input_dim]`) into `out` (`[n × output_dim]`) and, when given,
    /// the dense Jacobian `jac` (`[n × output_dim × input_dim]`, `jac[i][o][k] = ∂out_o/∂x_k`).
    pub fn encode(&self, x: &[f32], out: &mut [f32], mut jac: Option<&mut [f32]>) {
        let (d, od) = (self.input_dim, self.output_dim());
        for (i, xi) in x.chunks_exact(d).enumerate() {
            let o = &mut out[i * od..(i + 1) * od];
            o[..d].copy_from_slice(xi);
            if let Some(jac) = jac.as_deref_mut() {
                let j = &mut jac[i * od * d..(i + 1) * od * d];
                j.fill(0.0);
                for k in 0..d {
                    j[k * d + k] = 1.0;
                }
            }
            for b in 0..self.frequencies {
                let freq = (1u32 << b) as f32;
                for k in 0..d {
                    let (s, c) = (freq * xi[k]).sin_cos();
                    let (is, ic) = (d + 2 * b * d + k, d + (2 * b + 1) * d + k);
                    o[is] = s;
                    o[ic] = c;
                    if let Some(jac) = jac.as_deref_mut() {
                        let j = &mut jac[i * od * d..(i + 1) * od * d];
                        j[is * d + k] = freq * c;
                        j[ic * d + k] = -freq * s;
                    }
                }
            }
        }
    }
}

/// Real spherical harmonics of degree < `degree` (1..=4, so 1, 4, 9 or 16 outputs) of unit
/// directions: the view-direction encoding of Instant-NGP-style radiance fields.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SphericalHarmonics {
    pub degree: usize,
}

impl SphericalHarmonics {
    pub fn new(degree: usize) -> Self {
        assert!((1..=4).contains(&degree), "spherical harmonics degree must be 1..=4");
        SphericalHarmonics { degree }
    }

    pub fn output_dim(&self) -> usize {
        self.degree * self.degree
    }

    /// Encode `n` unit directions (`d`: `[n×3]`) into `out` (`[n × output_dim]`).
    pub fn encode(&self, d: &[f32], out: &mut [f32]) {
        let od = self.output_dim();
        for (dir, o) in d.chunks_exact(3).zip(out.chunks_exact_mut(od)) {
            let (x, y, z) = (dir[0], dir[1], dir[2]);
            let mut all = [0f32; 16];
            let (xy, xz, yz, x2, y2, z2) = (x * y, x * z, y * z, x * x, y * y, z * z);
            all[0] = 0.282_094_8;
            all[1] = -0.488_602_5 * y;
            all[2] = 0.488_602_5 * z;
            all[3] = -0.488_602_5 * x;
            all[4] = 1.092_548_4 * xy;
            all[5] = -1.092_548_4 * yz;
            all[6] = 0.946_174_7 * z2 - 0.315_391_57;
            all[7] = -1.092_548_4 * xz;
            all[8] = 0.546_274_2 * (x2 - y2);
            all[9] = 0.590_043_6 * y * (y2 - 3.0 * x2);
            all[10] = 2.890_611_4 * xy * z;
            all[11] = 0.457_045_8 * y * (1.0 - 5.0 * z2);
            all[12] = 0.373_176_33 * z * (5.0 * z2 - 3.0);
            all[13] = 0.457_045_8 * x * (1.0 - 5.0 * z2);
            all[14] = 1.445_305_7 * z * (x2 - y2);
            all[15] = 0.590_043_6 * x * (3.0 * y2 - x2);
            o.copy_from_slice(&all[..od]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::{assert_grad_close, central_difference, Lcg};

    #[test]
    fn frequency_encoding_layout_and_jacobian() {
        let enc = FrequencyEncoding::new(3, 6);
        assert_eq!(enc.output_dim(), 39);
        let n = 4;
        let mut rng = Lcg(2);
        let x: Vec<f32> = (0..n * 3).map(|_| rng.uniform_pm1()).collect();
        let mut out = vec![0.0; n * 39];
        let mut jac = vec![0.0; n * 39 * 3];
        enc.encode(&x, &mut out, Some(&mut jac));
        // band 2, cos of y for point 1
        assert!((out[39 + 3 + 5 * 3 + 1] - (4.0 * x[4]).cos()).abs() < 1e-6);
        let c: Vec<f32> = (0..n * 39).map(|_| rng.uniform_pm1()).collect();
        let mut analytic = vec![0.0f32; n * 3];
        for i in 0..n {
            for o in 0..39 {
                for k in 0..3 {
                    analytic[i * 3 + k] += c[i * 39 + o] * jac[(i * 39 + o) * 3 + k];
                }
            }
        }
        let fd = central_difference(&x, 1e-3, |xp| {
            let mut e = vec![0.0; n * 39];
            enc.encode(xp, &mut e, None);
            e.iter().zip(&c).map(|(&a, &b)| a as f64 * b as f64).sum()
        });
        assert_grad_close("frequency encoding Jacobian", &analytic, &fd, 1e-2, 1e-2);
    }

    /// The 16 functions are orthonormal on the sphere (quadrature on a Fibonacci lattice).
    #[test]
    fn spherical_harmonics_are_orthonormal() {
        let sh = SphericalHarmonics::new(4);
        let n = 20000;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let dirs: Vec<f32> = (0..n)
            .flat_map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * i as f64;
                [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]
            })
            .collect();
        let mut out = vec![0.0; n * 16];
        sh.encode(&dirs, &mut out);
        for a in 0..16 {
            for b in 0..16 {
                let s: f64 = (0..n)
                    .map(|i| out[i * 16 + a] as f64 * out[i * 16 + b] as f64)
                    .sum::<f64>()
                    * 4.0
                    * std::f64::consts::PI
                    / n as f64;
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((s - want).abs() < 2e-3, "<Y{a}, Y{b}> = {s}");
            }
        }
    }
}
