//! `cargo run --release -p i2sdf-eval --example lpips_pair -- WEIGHTS.safetensors A.png B.png`:
//! i2sdf's LPIPS of two RGB images of the same size, with its time; compare with
//! `scripts/lpips_weights.py WEIGHTS.safetensors --check A.png B.png` (the `lpips` package's).

use i2sdf_eval::image_metrics::ImageRef;
use i2sdf_eval::Lpips;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [weights, a, b] = &args[..] else {
        return Err("usage: lpips_pair WEIGHTS.safetensors A.png B.png".into());
    };
    let lpips = Lpips::load(Path::new(weights))?;
    let (a_img, b_img) = (
        i2sdf_data::imageio::read_image(Path::new(a))?,
        i2sdf_data::imageio::read_image(Path::new(b))?,
    );
    let ra = ImageRef::new(&a_img.data, a_img.width, a_img.height, a_img.channels)?;
    let rb = ImageRef::new(&b_img.data, b_img.width, b_img.height, b_img.channels)?;
    let t = std::time::Instant::now();
    let d = lpips.distance(ra, rb)?;
    println!("LPIPS {a} {b}: {d:.6} ({:.1} ms)", t.elapsed().as_secs_f64() * 1e3);
    Ok(())
}
