//! PSNR between LDR images as stored (sRGB-encoded values in [0, 1]), and their mean difference
//! per channel (a bias shows there, noise does not): how the renders of one view by two builds of
//! the renderer are compared.
//!
//! `cargo run --release -p i2sdf-synth --example png_psnr -- A.png B.png [C.png D.png ...]`
//! (pairs: A vs B, C vs D, …)

use i2sdf_eval::ImageRef;
use std::path::Path;

fn image(m: &i2sdf_data::ImageF32) -> ImageRef<'_> {
    ImageRef::new(&m.data, m.width, m.height, m.channels).unwrap()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    assert!(
        !args.is_empty() && args.len().is_multiple_of(2),
        "usage: png_psnr A.png B.png [C.png D.png ...]"
    );
    for pair in args.chunks(2) {
        let read = |p: &str| i2sdf_data::imageio::read_image(Path::new(p)).unwrap_or_else(|e| panic!("{e}"));
        let (a, b) = (read(&pair[0]), read(&pair[1]));
        assert_eq!(
            (a.width, a.height, a.channels),
            (b.width, b.height, b.channels),
            "{} and {} differ in size",
            pair[0],
            pair[1]
        );
        let c = a.channels;
        let mut mean = vec![0.0f64; c];
        for (i, (x, y)) in a.data.iter().zip(&b.data).enumerate() {
            mean[i % c] += *x as f64 - *y as f64;
        }
        let n = a.data.len() as f64;
        let psnr = i2sdf_eval::psnr(image(&a), image(&b), None)
            .unwrap()
            .unwrap_or(f64::NAN);
        let mean: Vec<String> = mean.iter().map(|m| format!("{:+.5}", m / (n / c as f64))).collect();
        println!(
            "{} vs {}: PSNR {psnr:.2} dB, mean difference {}",
            pair[0],
            pair[1],
            mean.join(" ")
        );
    }
}
