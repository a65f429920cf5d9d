//! `i2sdf bench`: time the neural engine (the benchmark itself lives in `i2sdf_nn::bench`).

use i2sdf_nn::bench::{run as run_bench, BenchOptions};

#[derive(clap::Args)]
pub struct Args {
    /// Print one JSON object (cpu, iteration_ms, mlp_gflops, sgemm_peak_gflops, phases, …) on stdout.
    #[arg(long)]
    pub json: bool,
    /// Rays per iteration of the representative configuration.
    #[arg(long, default_value_t = 1024)]
    pub rays: usize,
    /// Samples per ray.
    #[arg(long, default_value_t = 64)]
    pub samples: usize,
    /// Timed iterations (after one warm-up).
    #[arg(long, default_value_t = 10)]
    pub iterations: usize,
    /// Points per iteration of the paper-backbone run (8×256 SDF MLP, 4×256 radiance); 0 skips it.
    #[arg(long, default_value_t = 8192)]
    pub paper_points: usize,
    /// Timed iterations of the paper-backbone run.
    #[arg(long, default_value_t = 3)]
    pub paper_iterations: usize,
    /// Skip the analytic vs finite-difference spatial-gradient comparison.
    #[arg(long)]
    pub no_fd_comparison: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let bad = |flag: &str, v: usize, lo: usize, hi: usize| {
        (!(lo..=hi).contains(&v)).then(|| i2sdf_data::DataError::invalid(format!("{flag} {v}: must be in {lo}..={hi}")))
    };
    // Limits: what one iteration of the representative configuration can hold in memory here
    // (the product rays × samples, checked below) and what finishes in minutes.
    let checks = [
        bad("--rays", args.rays, 1, 1 << 20),
        bad("--samples", args.samples, 1, 1024),
        bad("--iterations", args.iterations, 1, 10_000),
        bad("--paper-points", args.paper_points, 0, 1 << 20),
        bad("--paper-iterations", args.paper_iterations, 1, 1000),
    ];
    if let Some(e) = checks.into_iter().flatten().next() {
        return Err(e.into());
    }
    if args.rays * args.samples > 1 << 21 {
        return Err(i2sdf_data::DataError::invalid(format!(
            "--rays {} × --samples {}: {} points per iteration, more than the {} the bench holds",
            args.rays,
            args.samples,
            args.rays * args.samples,
            1 << 21
        ))
        .into());
    }
    let opts = BenchOptions {
        rays: args.rays,
        samples: args.samples,
        iterations: args.iterations,
        paper_points: args.paper_points,
        paper_iterations: args.paper_iterations,
        compare_finite_differences: !args.no_fd_comparison,
    };
    let report = run_bench(&opts);
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print!("{}", report.to_text());
    }
    Ok(())
}
