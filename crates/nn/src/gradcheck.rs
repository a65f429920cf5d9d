//! Finite-difference utilities for the gradient tests (compiled in tests, and for other crates'
//! tests behind the `test-support` feature).

/// A tiny deterministic generator for test data (no dependence on `rand`'s stream stability).
pub struct Lcg(pub u64);

impl Lcg {
    pub fn next_u32(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 33) as u32
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 / (1u32 << 24) as f32
    }
    /// Uniform in [−1, 1).
    pub fn uniform_pm1(&mut self) -> f32 {
        2.0 * self.uniform() - 1.0
    }
}

/// `∂f/∂p_i ≈ (f(p + h e_i) − f(p − h e_i)) / 2h` for every coordinate of `p`, with `f` evaluated
/// in f64 on the perturbed f32 vector (the actual step `h` is re-measured after rounding to f32).
pub fn central_difference(p: &[f32], h: f32, mut f: impl FnMut(&[f32]) -> f64) -> Vec<f32> {
    let mut q = p.to_vec();
    (0..p.len())
        .map(|i| {
            let (plus, minus) = (p[i] + h, p[i] - h);
            q[i] = plus;
            let fp = f(&q);
            q[i] = minus;
            let fm = f(&q);
            q[i] = p[i];
            ((fp - fm) / (plus as f64 - minus as f64)) as f32
        })
        .collect()
}

/// Central differences (step 1e-3) of a scalar f32 function of a flat parameter vector.
pub fn numeric_gradient(f: &dyn Fn(&[f32]) -> f32, x: &[f32]) -> Vec<f32> {
    central_difference(x, 1e-3, |y| f(y) as f64)
}

/// [`assert_grad_close`] with one tolerance, absolute and relative.
pub fn assert_close(analytic: &[f32], fd: &[f32], tol: f32) {
    assert_grad_close("gradient", analytic, fd, tol, tol);
}

/// Assert `|analytic − fd| ≤ abs + rel·|fd|` elementwise, and that the overall relative error is
/// small; a wrong sign or a missing term fails one or the other.
pub fn assert_grad_close(what: &str, analytic: &[f32], fd: &[f32], abs: f32, rel: f32) {
    assert_eq!(analytic.len(), fd.len(), "{what}: length");
    let mut num = 0.0f64;
    let mut den = 0.0f64;
    for (i, (&a, &f)) in analytic.iter().zip(fd).enumerate() {
        assert!(
            (a - f).abs() <= abs + rel * f.abs(),
            "{what}[{i}]: analytic {a} vs finite difference {f}"
        );
        num += ((a - f) as f64).powi(2);
        den += (f as f64).powi(2);
    }
    assert!(den > 0.0, "{what}: all-zero reference gradient tests nothing");
    let rel_norm = (num / den).sqrt();
    assert!(rel_norm < 2.0 * rel as f64, "{what}: relative error norm {rel_norm}");
}
