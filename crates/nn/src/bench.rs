//! The engine's benchmark (`i2sdf bench`): a representative stage-1 iteration timed phase by phase,
//! the paper's MLP backbone, the analytic vs finite-difference spatial gradient, and this machine's
//! f32 sgemm peak measured in the same run, so the MLP phase can be read as a fraction of it.
//!
//! The iteration is what stage 1 does per batch minus volume compositing: `rays × samples` points
//! along random rays; SDF network forward with `∇d`; radiance MLP on `[z, dir encoding, ∇d]`;
//! L2 colour loss per point, eikonal loss, a distance cotangent; radiance backward (into `z` and
//! `∇d`), SDF double backward into MLP and hash tables; Adam (dense MLPs, lazy tables).

use crate::{
    Activation, Adam, AdamConfig, FrequencyEncoding, LrSchedule, Mlp, MlpConfig, MlpWorkspace, SdfEncoding, SdfGrad,
    SdfNetwork, SdfNetworkConfig, SdfWorkspace, SphericalHarmonics,
};
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::time::Instant;

/// What to run.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    pub rays: usize,
    pub samples: usize,
    /// Timed iterations of the representative configuration (after one warm-up).
    pub iterations: usize,
    /// Points per iteration of the paper-backbone run (0: skip it).
    pub paper_points: usize,
    pub paper_iterations: usize,
    /// Also time the 6-point finite-difference spatial gradient against the analytic one.
    pub compare_finite_differences: bool,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            rays: 1024,
            samples: 64,
            iterations: 10,
            paper_points: 8192,
            paper_iterations: 3,
            compare_finite_differences: true,
        }
    }
}

/// Milliseconds per phase of one iteration.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct PhaseMs {
    pub hash_encode: f64,
    pub sdf_mlp_forward: f64,
    pub radiance_forward: f64,
    pub radiance_backward: f64,
    pub sdf_mlp_backward: f64,
    pub hash_scatter: f64,
    pub adam: f64,
    pub other: f64,
}

/// Timing of one configuration.
#[derive(Clone, Debug, Serialize)]
pub struct ConfigReport {
    pub points: usize,
    /// Best iteration.
    pub iteration_ms: f64,
    pub iteration_ms_median: f64,
    /// MLP phase (SDF and radiance MLP tile passes, forward and backward) of the best iteration.
    pub mlp_ms: f64,
    pub mlp_gflop_per_iteration: f64,
    pub mlp_gflops: f64,
    pub phases_ms: PhaseMs,
    /// CPU time of all threads per iteration (mean), where `/proc` tells it: with the cores shared,
    /// `cpu_ms / threads` is what the iteration would take on idle cores.
    pub cpu_ms_per_iteration: Option<f64>,
}

/// The representative iteration at one half precision.
#[derive(Clone, Debug, Serialize)]
pub struct HalfPrecisionReport {
    pub precision: &'static str,
    pub iteration: ConfigReport,
}

/// Analytic vs numerical (central differences, 6 extra points) `∇d` with its backward.
#[derive(Clone, Debug, Serialize)]
pub struct SpatialGradientReport {
    pub analytic_ms: f64,
    pub finite_difference_ms: f64,
}

/// The processor a bench ran on, and which kernels this build uses on it. Machines of the same
/// kind have differed in vector width from one day to the next (AVX-512 on one, AVX2 only on
/// another), which moves every figure; a time is only comparable with a bench of the same CPU.
#[derive(Clone, Debug, Serialize)]
pub struct CpuReport {
    /// `model name` from `/proc/cpuinfo`, where there is one.
    pub model: Option<String>,
    /// The vector extensions the processor reports (runtime detection), of those the engine's
    /// kernels could use.
    pub features: Vec<&'static str>,
    /// The MLP products' kernel of this build: `smallgemm-avx512` (compiled for AVX-512F) or
    /// `matrixmultiply`.
    pub gemm_kernel: &'static str,
}

impl CpuReport {
    pub fn detect() -> Self {
        let model = std::fs::read_to_string("/proc/cpuinfo").ok().and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        });
        CpuReport {
            model,
            features: detected_features(),
            gemm_kernel: if crate::smallgemm::AVAILABLE {
                "smallgemm-avx512"
            } else {
                "matrixmultiply"
            },
        }
    }
}

#[cfg(target_arch = "x86_64")]
fn detected_features() -> Vec<&'static str> {
    let mut f = Vec::new();
    macro_rules! probe {
        ($($name:tt),*) => {
            $(if std::arch::is_x86_feature_detected!($name) {
                f.push($name);
            })*
        };
    }
    probe!(
        "fma",
        "avx2",
        "avx512f",
        "avx512bw",
        "avx512vl",
        "avx512bf16",
        "avx512fp16",
        "f16c"
    );
    f
}

#[cfg(not(target_arch = "x86_64"))]
fn detected_features() -> Vec<&'static str> {
    Vec::new()
}

#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub cpu: CpuReport,
    pub threads: usize,
    pub load_average: Option<[f64; 3]>,
    pub sgemm_peak_gflops: f64,
    pub iteration_ms: f64,
    pub iteration_ms_median: f64,
    pub mlp_gflops: f64,
    pub mlp_fraction_of_peak: f64,
    pub representative: ConfigReport,
    /// The same iteration with the products in half precision on AMX tiles (`bf16`, `bf16x3`),
    /// where the CPU has them; the f32 fields above stay the figure comparable across versions.
    pub half_precision: Vec<HalfPrecisionReport>,
    /// Best bf16 rate of the AMX kernel on a 1024³ product over all threads (GFLOP/s), where the
    /// CPU has AMX: the peak the half-precision MLP phases are a share of.
    pub amx_bf16_peak_gflops: Option<f64>,
    pub paper: Option<ConfigReport>,
    pub spatial_gradient: Option<SpatialGradientReport>,
}

/// The load average from `/proc/loadavg`, where there is one.
pub fn load_average() -> Option<[f64; 3]> {
    let s = std::fs::read_to_string("/proc/loadavg").ok()?;
    let v: Vec<f64> = s.split_whitespace().take(3).filter_map(|t| t.parse().ok()).collect();
    (v.len() == 3).then(|| [v[0], v[1], v[2]])
}

/// CPU time consumed so far by all threads of this process (ns), from `/proc/self/task/*/schedstat`.
pub fn process_cpu_ns() -> Option<u64> {
    let mut total = 0u64;
    for entry in std::fs::read_dir("/proc/self/task").ok()? {
        let path = entry.ok()?.path().join("schedstat");
        let s = std::fs::read_to_string(path).ok()?;
        total += s.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(total)
}

/// Best f32 sgemm rate over all rayon threads: a 1024³ product, rows split evenly over the threads,
/// by matrixmultiply and (AVX-512 builds) by the engine's own kernel; the better of the two.
pub fn sgemm_peak_gflops() -> f64 {
    let mm = sgemm_rate(false);
    if crate::smallgemm::AVAILABLE {
        mm.max(sgemm_rate(true))
    } else {
        mm
    }
}

fn sgemm_rate(small_kernel: bool) -> f64 {
    use rayon::prelude::*;
    let n = 1024;
    let a: Vec<f32> = (0..n * n).map(|i| ((i % 97) as f32) * 0.01).collect();
    let b: Vec<f32> = (0..n * n).map(|i| ((i % 89) as f32) * 0.01).collect();
    let mut c = vec![0f32; n * n];
    let parts = rayon::current_num_threads().max(1);
    let rows = n.div_ceil(parts);
    let mut best = f64::MAX;
    for _ in 0..6 {
        let t = Instant::now();
        c.par_chunks_mut(rows * n).enumerate().for_each(|(p, cp)| {
            let m = cp.len() / n;
            let ap = &a[p * rows * n..];
            if small_kernel {
                // SAFETY: A is [m×n] at `ap`, B [n×n], C [m×n]: all in bounds.
                unsafe { crate::smallgemm::gemm(m, n, n, ap.as_ptr(), n, 1, b.as_ptr(), n, false, cp.as_mut_ptr(), n) }
            } else {
                matrixmultiply_gemm(m, n, ap, &b, cp);
            }
        });
        best = best.min(t.elapsed().as_secs_f64());
    }
    2.0 * (n as f64).powi(3) / best / 1e9
}

/// The AMX kernel's bf16 rate on a 1024³ product, rows split over the rayon threads (best of 6).
fn amx_bf16_rate() -> f64 {
    use rayon::prelude::*;
    let n = 1024;
    let a: Vec<f32> = (0..n * n).map(|i| ((i % 97) as f32) * 0.01).collect();
    let b: Vec<f32> = (0..n * n).map(|i| ((i % 89) as f32) * 0.01).collect();
    let mut c = vec![0f32; n * n];
    let rows = n.div_ceil(rayon::current_num_threads().max(1));
    let mut best = f64::MAX;
    for _ in 0..6 {
        let t = Instant::now();
        c.par_chunks_mut(rows * n).enumerate().for_each(|(p, cp)| {
            let m = cp.len() / n;
            // SAFETY: called only where AMX is available; A [m×n], B [n×n], C [m×n] in bounds.
            unsafe {
                crate::amx::gemm(
                    m,
                    n,
                    n,
                    a[p * rows * n..].as_ptr(),
                    n,
                    1,
                    b.as_ptr(),
                    n,
                    false,
                    cp.as_mut_ptr(),
                    n,
                    false,
                )
            }
        });
        best = best.min(t.elapsed().as_secs_f64());
    }
    2.0 * (n as f64).powi(3) / best / 1e9
}

fn matrixmultiply_gemm(m: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    assert!(a.len() >= m * n && b.len() >= n * n && c.len() >= m * n);
    // SAFETY: bounds asserted; row-major strides.
    unsafe {
        matrixmultiply::sgemm(
            m,
            n,
            n,
            1.0,
            a.as_ptr(),
            n as isize,
            1,
            b.as_ptr(),
            n as isize,
            1,
            0.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        )
    }
}

/// Directions encoding of the radiance input.
enum DirEncoding {
    Sh(SphericalHarmonics),
    Frequency(FrequencyEncoding),
}

impl DirEncoding {
    fn dim(&self) -> usize {
        match self {
            DirEncoding::Sh(s) => s.output_dim(),
            DirEncoding::Frequency(f) => f.output_dim(),
        }
    }
    fn encode(&self, d: &[f32], out: &mut [f32]) {
        match self {
            DirEncoding::Sh(s) => s.encode(d, out),
            DirEncoding::Frequency(f) => f.encode(d, out, None),
        }
    }
}

/// A stage-1-shaped training step with every buffer preallocated.
struct Pipeline {
    sdf: SdfNetwork,
    radiance: Mlp,
    dir_encoding: DirEncoding,
    sdf_ws: SdfWorkspace,
    rad_ws: MlpWorkspace,
    sdf_grad: SdfGrad,
    rad_grad: Vec<f32>,
    adam: Adam,
    groups: [usize; 3],
    x: Vec<f32>,
    dirs: Vec<f32>,
    dir_enc: Vec<f32>,
    sdf_out: Vec<f32>,
    feature: Vec<f32>,
    gradient: Vec<f32>,
    rad_in: Vec<f32>,
    rgb: Vec<f32>,
    d_rgb: Vec<f32>,
    d_rad_in: Vec<f32>,
    d_sdf: Vec<f32>,
    d_feature: Vec<f32>,
    d_gradient: Vec<f32>,
}

impl Pipeline {
    fn set_precision(&mut self, p: crate::linalg::MatmulPrecision) {
        self.sdf.mlp.precision = p;
        self.radiance.precision = p;
    }

    fn new(
        sdf_config: SdfNetworkConfig,
        radiance_hidden: (usize, usize),
        dir_encoding: DirEncoding,
        rays: usize,
        samples: usize,
        seed: u64,
    ) -> Self {
        let sdf = SdfNetwork::new(sdf_config, seed);
        let fd = sdf.feature_dim();
        let rad_in_dim = fd + dir_encoding.dim() + 3;
        let radiance = Mlp::new(
            MlpConfig {
                input_dim: rad_in_dim,
                hidden_dim: radiance_hidden.0,
                hidden_layers: radiance_hidden.1,
                output_dim: 3,
                skip_layers: vec![],
                hidden_activation: Activation::Relu,
                output_activation: Activation::Sigmoid,
            },
            seed + 1,
        );
        let mut adam = Adam::new(AdamConfig {
            beta1: 0.9,
            beta2: 0.99,
            eps: 1e-15,
        });
        let sched = LrSchedule::Exponential {
            rate: 0.1,
            steps: 100_000,
        };
        let g0 = adam.add_group("sdf.mlp", sdf.mlp.params.len(), 1e-3, sched);
        let table_len = match &sdf.encoding {
            SdfEncoding::HashGrid(g) => g.params.len(),
            SdfEncoding::Frequency(_) => 0,
        };
        let g1 = adam.add_group("sdf.hash_grid", table_len, 1e-2, sched);
        let g2 = adam.add_group("radiance", radiance.params.len(), 1e-3, sched);
        let n = rays * samples;
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let (mut x, mut dirs) = (Vec::with_capacity(n * 3), Vec::with_capacity(n * 3));
        for _ in 0..rays {
            let o: [f32; 3] = std::array::from_fn(|_| rng.gen_range(-0.5..0.5));
            let d = loop {
                let v: [f32; 3] = std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0));
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if l > 0.1 && l <= 1.0 {
                    break v.map(|c| c / l);
                }
            };
            for s in 0..samples {
                let t = 0.02 + 1.5 * (s as f32 + rng.gen::<f32>()) / samples as f32;
                for k in 0..3 {
                    x.push((o[k] + t * d[k]).clamp(-0.999, 0.999));
                    dirs.push(d[k]);
                }
            }
        }
        let sdf_grad = SdfGrad::new(&sdf);
        let rad_grad = vec![0.0; radiance.params.len()];
        let de = dir_encoding.dim();
        Pipeline {
            sdf_ws: SdfWorkspace::default(),
            rad_ws: MlpWorkspace::default(),
            sdf_grad,
            rad_grad,
            adam,
            groups: [g0, g1, g2],
            dir_enc: vec![0.0; n * de],
            sdf_out: vec![0.0; n],
            feature: vec![0.0; n * fd],
            gradient: vec![0.0; n * 3],
            rad_in: vec![0.0; n * rad_in_dim],
            rgb: vec![0.0; n * 3],
            d_rgb: vec![0.0; n * 3],
            d_rad_in: vec![0.0; n * rad_in_dim],
            d_sdf: vec![0.0; n],
            d_feature: vec![0.0; n * fd],
            d_gradient: vec![0.0; n * 3],
            x,
            dirs,
            sdf,
            radiance,
            dir_encoding,
        }
    }

    fn points(&self) -> usize {
        self.x.len() / 3
    }

    /// Per-point MLP FLOPs actually multiplied in one iteration. SDF MLP (`M` multiply-adds per
    /// forward): forward `M`; input-gradient pass `M − M_last` (the one-hot seed makes the last
    /// layer a scaled row); double backward upward `W̄` `M − M_last` (rank-1 on the last layer) and
    /// `Ḡ_Z` `M − M_last` (identity output: no second-order term), downward `W̄` `M` and `Ī` `M`
    /// (`M − M_0` when the encoding has no parameters, so no input cotangent is formed). Radiance
    /// MLP: forward, `W̄` and `Ī`, `3M`.
    fn mlp_flops_per_point(&self) -> f64 {
        let m_sdf = self.sdf.mlp.macs_per_point() as f64;
        let layers = &self.sdf.mlp.layers;
        let (first, last) = (&layers[0], layers.last().unwrap());
        let m_last = (last.in_dim * last.out_dim) as f64;
        let m_first = (first.in_dim * first.out_dim) as f64;
        let no_input_cotangent = matches!(self.sdf.encoding, SdfEncoding::Frequency(_));
        let sdf = 6.0 * m_sdf - 3.0 * m_last - if no_input_cotangent { m_first } else { 0.0 };
        2.0 * sdf + 2.0 * 3.0 * self.radiance.macs_per_point() as f64
    }

    fn step(&mut self) -> (f64, PhaseMs) {
        let start = Instant::now();
        let n = self.points();
        let fd = self.sdf.feature_dim();
        let de = self.dir_encoding.dim();
        let ri = fd + de + 3;
        self.sdf.forward_with_gradient(
            &self.x,
            &mut self.sdf_ws,
            &mut self.sdf_out,
            &mut self.feature,
            &mut self.gradient,
        );
        let t_rad = Instant::now();
        self.dir_encoding.encode(&self.dirs, &mut self.dir_enc);
        for i in 0..n {
            let row = &mut self.rad_in[i * ri..(i + 1) * ri];
            row[..fd].copy_from_slice(&self.feature[i * fd..(i + 1) * fd]);
            row[fd..fd + de].copy_from_slice(&self.dir_enc[i * de..(i + 1) * de]);
            row[fd + de..].copy_from_slice(&self.gradient[i * 3..i * 3 + 3]);
        }
        let t_rf = Instant::now();
        self.radiance.forward(&self.rad_in, &mut self.rad_ws, &mut self.rgb);
        let rad_forward = t_rf.elapsed();
        // losses: L2 colour against a grey target, eikonal (weight 0.1), a small distance cotangent
        let inv_n = 1.0 / n as f32;
        for i in 0..n {
            for k in 0..3 {
                self.d_rgb[i * 3 + k] = 2.0 * (self.rgb[i * 3 + k] - 0.5) * inv_n;
            }
            self.d_sdf[i] = 1e-3 * self.sdf_out[i].signum() * inv_n;
        }
        let t_rb = Instant::now();
        self.radiance.backward(
            &mut self.rad_ws,
            &self.d_rgb,
            &mut self.rad_grad,
            Some(&mut self.d_rad_in),
        );
        let rad_backward = t_rb.elapsed();
        for i in 0..n {
            let row = &self.d_rad_in[i * ri..(i + 1) * ri];
            self.d_feature[i * fd..(i + 1) * fd].copy_from_slice(&row[..fd]);
            let g = &self.gradient[i * 3..i * 3 + 3];
            let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt().max(1e-8);
            for k in 0..3 {
                self.d_gradient[i * 3 + k] = row[fd + de + k] + 0.1 * 2.0 * (norm - 1.0) * g[k] / norm * inv_n;
            }
        }
        let t_sb = Instant::now();
        self.sdf.backward(
            &mut self.sdf_ws,
            &self.d_sdf,
            Some(&self.d_feature),
            Some(&self.d_gradient),
            &mut self.sdf_grad,
        );
        let t_adam = Instant::now();
        self.adam.begin_step();
        let [g0, g1, g2] = self.groups;
        self.adam.update(g0, &mut self.sdf.mlp.params, &mut self.sdf_grad.mlp);
        if let (SdfEncoding::HashGrid(h), Some(hg)) = (&mut self.sdf.encoding, self.sdf_grad.hash_grid.as_mut()) {
            let f = h.config.features_per_level;
            self.adam.update_sparse(g1, &mut h.params, hg, f);
        }
        self.adam.update(g2, &mut self.radiance.params, &mut self.rad_grad);
        let adam = t_adam.elapsed();
        let total = start.elapsed();
        let tm = self.sdf_ws.timings();
        let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
        let mut p = PhaseMs {
            hash_encode: ms(tm.encode),
            sdf_mlp_forward: ms(tm.mlp_forward),
            radiance_forward: ms(rad_forward),
            radiance_backward: ms(rad_backward),
            sdf_mlp_backward: ms(tm.mlp_backward),
            hash_scatter: ms(tm.scatter),
            adam: ms(adam),
            other: 0.0,
        };
        let _ = (t_rad, t_sb);
        let known = p.hash_encode
            + p.sdf_mlp_forward
            + p.radiance_forward
            + p.radiance_backward
            + p.sdf_mlp_backward
            + p.hash_scatter
            + p.adam;
        p.other = ms(total) - known;
        (ms(total), p)
    }

    fn run(&mut self, iterations: usize) -> ConfigReport {
        self.step(); // warm-up: first-touch of every buffer
        let cpu0 = process_cpu_ns();
        let mut runs: Vec<(f64, PhaseMs)> = (0..iterations.max(1)).map(|_| self.step()).collect();
        let cpu_ms_per_iteration = cpu0
            .zip(process_cpu_ns())
            .map(|(a, b)| (b - a) as f64 / 1e6 / runs.len() as f64);
        runs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (best, phases) = runs[0];
        let median = runs[runs.len() / 2].0;
        let mlp_ms =
            phases.sdf_mlp_forward + phases.sdf_mlp_backward + phases.radiance_forward + phases.radiance_backward;
        let gflop = self.mlp_flops_per_point() * self.points() as f64 / 1e9;
        ConfigReport {
            points: self.points(),
            iteration_ms: best,
            iteration_ms_median: median,
            mlp_ms,
            mlp_gflop_per_iteration: gflop,
            mlp_gflops: gflop / (mlp_ms / 1e3),
            phases_ms: phases,
            cpu_ms_per_iteration,
        }
    }

    /// Best-of-3 time of the SDF network's analytic `∇d` (forward + double backward) against a
    /// 6-point central-difference `∇d` (forward on 7n points + backward), at the same `n`.
    fn compare_spatial_gradients(&mut self) -> SpatialGradientReport {
        let n = self.points();
        let mut best_a = f64::MAX;
        for _ in 0..3 {
            let t = Instant::now();
            self.sdf.forward_with_gradient(
                &self.x,
                &mut self.sdf_ws,
                &mut self.sdf_out,
                &mut self.feature,
                &mut self.gradient,
            );
            self.sdf.backward(
                &mut self.sdf_ws,
                &self.d_sdf,
                Some(&self.d_feature),
                Some(&self.d_gradient),
                &mut self.sdf_grad,
            );
            best_a = best_a.min(t.elapsed().as_secs_f64() * 1e3);
        }
        let eps = 1e-3f32;
        let mut x7 = Vec::with_capacity(n * 21);
        crate::sdf::central_difference_points(&self.x, eps, &mut x7);
        let fd = self.sdf.feature_dim();
        let (mut s7, mut f7) = (vec![0.0; 7 * n], vec![0.0; 7 * n * fd]);
        let mut d7 = vec![0.0; 7 * n];
        let mut ws = SdfWorkspace::default();
        let mut best_f = f64::MAX;
        for _ in 0..3 {
            let t = Instant::now();
            self.sdf.forward(&x7, &mut ws, &mut s7, &mut f7);
            crate::sdf::central_difference_gradient(&s7, eps, &mut self.gradient);
            crate::sdf::central_difference_cotangent(&self.d_sdf, &self.d_gradient, eps, &mut d7);
            self.sdf.backward(&mut ws, &d7, None, None, &mut self.sdf_grad);
            best_f = best_f.min(t.elapsed().as_secs_f64() * 1e3);
        }
        self.sdf_grad.zero();
        SpatialGradientReport {
            analytic_ms: best_a,
            finite_difference_ms: best_f,
        }
    }
}

/// The representative iteration alone, best of `iterations` (after one warm-up), in ms: a second's
/// measure of this machine's speed for a caller that scales a time estimate by it (`demo`).
pub fn representative_iteration_ms(iterations: usize) -> f64 {
    let o = BenchOptions::default();
    Pipeline::new(
        SdfNetworkConfig::hash_grid(0.9),
        (64, 2),
        DirEncoding::Sh(SphericalHarmonics::new(4)),
        o.rays,
        o.samples,
        1,
    )
    .run(iterations.max(1))
    .iteration_ms
}

/// Run the benchmark.
pub fn run(opts: &BenchOptions) -> BenchReport {
    let load_average = load_average();
    let peak_before = sgemm_peak_gflops();
    let mut rep = Pipeline::new(
        SdfNetworkConfig::hash_grid(0.9),
        (64, 2),
        DirEncoding::Sh(SphericalHarmonics::new(4)),
        opts.rays,
        opts.samples,
        1,
    );
    let representative = rep.run(opts.iterations);
    let mut half_precision = Vec::new();
    let amx_bf16_peak_gflops = crate::amx::available().then(|| {
        use crate::linalg::MatmulPrecision;
        for p in [MatmulPrecision::Bf16, MatmulPrecision::Bf16x3] {
            rep.set_precision(p);
            half_precision.push(HalfPrecisionReport {
                precision: p.name(),
                iteration: rep.run(opts.iterations),
            });
        }
        rep.set_precision(MatmulPrecision::F32);
        amx_bf16_rate()
    });
    let spatial_gradient = opts.compare_finite_differences.then(|| rep.compare_spatial_gradients());
    drop(rep);
    let paper = (opts.paper_points > 0).then(|| {
        let samples = 64.min(opts.paper_points);
        let rays = opts.paper_points.div_ceil(samples);
        let mut p = Pipeline::new(
            SdfNetworkConfig::paper(0.9),
            (256, 4),
            DirEncoding::Frequency(FrequencyEncoding::new(3, 4)),
            rays,
            samples,
            2,
        );
        p.run(opts.paper_iterations)
    });
    // the best of a measurement before and one after: the cores are shared, and a peak taken while
    // another job ran would flatter the ratio
    let sgemm_peak = peak_before.max(sgemm_peak_gflops());
    BenchReport {
        cpu: CpuReport::detect(),
        threads: rayon::current_num_threads(),
        load_average,
        sgemm_peak_gflops: sgemm_peak,
        iteration_ms: representative.iteration_ms,
        iteration_ms_median: representative.iteration_ms_median,
        mlp_gflops: representative.mlp_gflops,
        mlp_fraction_of_peak: representative.mlp_gflops / sgemm_peak,
        representative,
        half_precision,
        amx_bf16_peak_gflops,
        paper,
        spatial_gradient,
    }
}

impl BenchReport {
    /// A human-readable summary.
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let load = self
            .load_average
            .map_or("n/a".to_string(), |l| format!("{:.2} {:.2} {:.2}", l[0], l[1], l[2]));
        let _ = writeln!(
            s,
            "cpu {} [{}], MLP products by {}",
            self.cpu.model.as_deref().unwrap_or("unknown"),
            self.cpu.features.join(" "),
            self.cpu.gemm_kernel
        );
        let _ = writeln!(s, "threads {}, load average {load}", self.threads);
        let _ = writeln!(
            s,
            "sgemm peak (1024³, f32, all threads): {:.1} GFLOP/s",
            self.sgemm_peak_gflops
        );
        let mut cfg = |name: &str, r: &ConfigReport, peak: (&str, f64)| {
            let _ = writeln!(s, "{name}: {} points", r.points);
            let _ = writeln!(
                s,
                "  iteration: {:.1} ms best, {:.1} ms median",
                r.iteration_ms, r.iteration_ms_median
            );
            if let Some(c) = r.cpu_ms_per_iteration {
                let _ = writeln!(
                    s,
                    "  CPU time: {c:.1} ms per iteration over all threads ({:.1} ms per thread)",
                    c / self.threads as f64
                );
            }
            let _ = writeln!(
                s,
                "  MLP phase: {:.1} ms, {:.2} GFLOP, {:.1} GFLOP/s ({:.0} % of the {} peak)",
                r.mlp_ms,
                r.mlp_gflop_per_iteration,
                r.mlp_gflops,
                100.0 * r.mlp_gflops / peak.1,
                peak.0
            );
            let p = &r.phases_ms;
            let _ = writeln!(
                s,
                "  phases (ms): hash encode {:.1}, SDF MLP fwd {:.1}, radiance fwd {:.1}, radiance bwd {:.1}, SDF MLP bwd {:.1}, hash scatter {:.1}, Adam {:.1}, other {:.1}",
                p.hash_encode, p.sdf_mlp_forward, p.radiance_forward, p.radiance_backward, p.sdf_mlp_backward, p.hash_scatter, p.adam, p.other
            );
        };
        let sgemm = ("f32 sgemm", self.sgemm_peak_gflops);
        cfg(
            "representative iteration (hash grid 16×2×2^19, SDF 35→64→64→16, radiance 34→64→64→3)",
            &self.representative,
            sgemm,
        );
        for h in &self.half_precision {
            // each path against its own kernel's peak
            let peak = ("AMX bf16", self.amx_bf16_peak_gflops.unwrap_or(f64::NAN));
            cfg(
                &format!("the same with {} products (AMX)", h.precision),
                &h.iteration,
                peak,
            );
        }
        if let Some(p) = &self.paper {
            cfg("paper backbone (PE 6, SDF 8×256 skip 4, radiance 4×256)", p, sgemm);
        }
        if let Some(p) = self.amx_bf16_peak_gflops {
            let _ = writeln!(s, "AMX bf16 peak (1024³, all threads): {p:.1} GFLOP/s");
        }
        if let Some(g) = &self.spatial_gradient {
            let _ = writeln!(
                s,
                "spatial gradient + backward, SDF network only: analytic {:.1} ms, central differences {:.1} ms ({:.1}×)",
                g.analytic_ms,
                g.finite_difference_ms,
                g.finite_difference_ms / g.analytic_ms
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    /// The whole benchmark path on a toy size (timings are not checked: the machine is shared).
    #[test]
    fn bench_runs_and_reports() {
        let opts = super::BenchOptions {
            rays: 8,
            samples: 40,
            iterations: 1,
            paper_points: 300,
            paper_iterations: 1,
            compare_finite_differences: true,
        };
        let r = super::run(&opts);
        assert!(r.sgemm_peak_gflops > 0.0 && r.iteration_ms > 0.0 && r.mlp_gflops > 0.0);
        assert_eq!(r.representative.points, 320);
        let json = serde_json::to_value(&r).unwrap();
        for key in ["iteration_ms", "mlp_gflops", "sgemm_peak_gflops"] {
            assert!(json[key].is_number(), "{key} missing");
        }
        assert!(json["cpu"]["features"].is_array() && json["cpu"]["gemm_kernel"].is_string());
        // the kernel named is the one this build compiled in
        assert_eq!(
            json["cpu"]["gemm_kernel"] == "smallgemm-avx512",
            cfg!(all(target_arch = "x86_64", target_feature = "avx512f"))
        );
    }
}
