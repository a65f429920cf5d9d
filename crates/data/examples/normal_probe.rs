//! Normals derived from a dataset's depth (`depth_normals`, what stage 1 trains on without normal
//! maps) against its true normal maps: the angle's median and 75th / 90th percentiles over the
//! pixels with both. Made for `docs/results.md` (derived normals from noisy sensor depth):
//! `cargo run --release -p i2sdf-data --example normal_probe -- DATA` on a room written by
//! `i2sdf synth --depth-grid 4 --depth-noise sigma` (normal maps kept).
use std::path::Path;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let ds = i2sdf_data::load(Path::new(&a[1])).unwrap();
    let mut angles = Vec::new();
    for f in &ds.frames {
        let (Some(d), Some(n)) = (&f.depth, &f.normal) else {
            continue;
        };
        let derived = i2sdf_data::depth_normals::normals_from_depth(d, &f.camera);
        for p in 0..f.pixel_count() {
            let g = &derived.data[3 * p..3 * p + 3];
            let t = &n.data[3 * p..3 * p + 3];
            if g == [0.0; 3] || t == [0.0; 3] {
                continue;
            }
            let c: f32 = (0..3).map(|k| g[k] * t[k]).sum();
            angles.push(c.clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    angles.sort_by(f32::total_cmp);
    let q = |x: f64| angles[((angles.len() - 1) as f64 * x) as usize];
    println!(
        "{} normals: median {:.2}°, 75th {:.2}°, 90th {:.2}°",
        angles.len(),
        q(0.5),
        q(0.75),
        q(0.9)
    );
}
