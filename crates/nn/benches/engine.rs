//! `cargo bench -p i2sdf-nn`: the engine benchmark of `i2sdf_nn::bench` (same as `i2sdf bench`).
//! `-- --json` prints the report as one JSON object; `-- --quick` times the representative
//! iteration only.

fn main() {
    let json = std::env::args().any(|a| a == "--json");
    let mut opts = i2sdf_nn::bench::BenchOptions::default();
    if std::env::args().any(|a| a == "--quick") {
        opts.paper_points = 0;
        opts.compare_finite_differences = false;
    }
    let report = i2sdf_nn::bench::run(&opts);
    if json {
        println!("{}", serde_json::to_string(&report).expect("report serializes"));
    } else {
        print!("{}", report.to_text());
    }
}
