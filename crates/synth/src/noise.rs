//! The paper's depth noise model (Sec. 6.3, after Nguyen et al. 2012 and Keselman et al. 2017):
//! ε ~ N(μ(z), σ(z)) with μ(z) = 0.0001125 z² + 0.0048875 and σ(z) = 0.002925 z² + 0.003325, z in
//! metres. `3sigma` triples σ (μ unchanged) for the stronger ablation.

use rand::Rng;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DepthNoise {
    None,
    Sigma,
    #[serde(rename = "3sigma")]
    ThreeSigma,
}

impl DepthNoise {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "none" => Some(DepthNoise::None),
            "sigma" => Some(DepthNoise::Sigma),
            "3sigma" => Some(DepthNoise::ThreeSigma),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            DepthNoise::None => "none",
            DepthNoise::Sigma => "sigma",
            DepthNoise::ThreeSigma => "3sigma",
        }
    }

    /// (μ(z), σ(z)) of the noise added at depth z (metres).
    pub fn params(self, z: f32) -> (f32, f32) {
        let z2 = z * z;
        let (mu, sigma) = (0.0001125 * z2 + 0.0048875, 0.002925 * z2 + 0.003325);
        match self {
            DepthNoise::None => (0.0, 0.0),
            DepthNoise::Sigma => (mu, sigma),
            DepthNoise::ThreeSigma => (mu, 3.0 * sigma),
        }
    }

    /// Adds the noise to every depth value in place.
    pub fn apply(self, depth: &mut [f32], rng: &mut impl Rng) {
        if self == DepthNoise::None {
            return;
        }
        for z in depth.iter_mut() {
            let (mu, sigma) = self.params(*z);
            *z += mu + sigma * standard_normal(rng);
        }
    }
}

/// Box–Muller standard normal.
pub(crate) fn standard_normal(rng: &mut impl Rng) -> f32 {
    let u1: f32 = 1.0 - rng.gen::<f32>();
    let u2: f32 = rng.gen();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn noise_has_the_papers_mean_and_spread() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(1);
        for (mode, k) in [(DepthNoise::Sigma, 1.0f64), (DepthNoise::ThreeSigma, 3.0)] {
            let z = 3.0f32;
            let mut d = vec![z; 200_000];
            mode.apply(&mut d, &mut rng);
            let n = d.len() as f64;
            let mean = d.iter().map(|&x| x as f64 - z as f64).sum::<f64>() / n;
            let var = d.iter().map(|&x| (x as f64 - z as f64 - mean).powi(2)).sum::<f64>() / n;
            let (mu, sigma) = (0.0001125 * 9.0 + 0.0048875, k * (0.002925 * 9.0 + 0.003325));
            assert!((mean - mu).abs() < 4.0 * sigma / n.sqrt(), "mean {mean} vs {mu}");
            assert!((var.sqrt() / sigma - 1.0).abs() < 0.01, "sd {} vs {sigma}", var.sqrt());
        }
    }
}
