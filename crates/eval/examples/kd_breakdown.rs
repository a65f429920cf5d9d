//! Where the Kd error of a stage-2 run comes from: pools the test views' pixels by their GT
//! material (quantized Kd, Ks, ρ) and prints each group's pixel count, mean GT and predicted Kd,
//! and share of the total squared error; the GT emitter mask's pixels are left out as in `eval`.
//!
//! `cargo run --release -p i2sdf-eval --example kd_breakdown -- RENDERED DATA`
//! where RENDERED is the output of `i2sdf render --split test --what albedo,roughness`.

use i2sdf_data::imageio::{read_float_map, read_image};
use std::collections::HashMap;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        eprintln!("usage: kd_breakdown RENDERED DATA");
        std::process::exit(2);
    }
    let (out, data) = (Path::new(&args[1]), Path::new(&args[2]));
    #[derive(Default)]
    struct Group {
        n: usize,
        gt: [f64; 3],
        pred: [f64; 3],
        sse: f64,
        rough_gt: f64,
        rough_pred: f64,
    }
    let mut groups: HashMap<(i32, i32, i32, i32, i32), Group> = HashMap::new();
    let mut total = 0.0;
    let mut count = 0usize;
    let mut names: Vec<_> = std::fs::read_dir(out.join("albedo"))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "exr"))
        .collect();
    names.sort();
    for p in names {
        let stem = p.file_stem().unwrap().to_string_lossy().to_string();
        let pred = read_float_map(&p)?;
        let rough = read_float_map(&out.join("roughness").join(format!("{stem}.exr")))?;
        let m = data.join("material");
        let gt = read_float_map(&m.join(format!("{stem}_kd.exr")))?;
        let ks = read_float_map(&m.join(format!("{stem}_ks.exr")))?;
        let gr = read_float_map(&m.join(format!("{stem}_roughness.exr")))?;
        let mask = read_image(&data.join("mask").join(format!("{stem}.png")))?;
        // DUMP=DIR: GT Kd beside the prediction (sRGB-encoded, 3× enlarged), to look at.
        if let Ok(dir) = std::env::var("DUMP") {
            let (w, h, k) = (gt.width, gt.height, 3usize);
            let mut img = i2sdf_data::ImageF32::new(2 * w * k, h * k, 3);
            let enc = |v: f32| i2sdf_data::imageio::linear_to_srgb(v.max(0.0));
            for y in 0..h * k {
                for x in 0..2 * w * k {
                    let (src, sx) = if x < w * k { (&gt, x / k) } else { (&pred, x / k - w) };
                    let i = (y / k) * w + sx;
                    for c in 0..3 {
                        img.data[(y * 2 * w * k + x) * 3 + c] = enc(src.data[i * src.channels + c]);
                    }
                }
            }
            std::fs::create_dir_all(&dir)?;
            i2sdf_data::imageio::write_png(&Path::new(&dir).join(format!("{stem}.png")), &img)?;
        }
        for i in 0..gt.width * gt.height {
            if mask.data[i * mask.channels] > 0.5 {
                continue;
            }
            let g: [f32; 3] = std::array::from_fn(|c| gt.data[i * gt.channels + c]);
            if !g[0].is_finite() {
                continue;
            }
            let q = |v: f32| (v * 20.0).round() as i32;
            let key = (
                q(g[0]),
                q(g[1]),
                q(g[2]),
                q(ks.data[i * ks.channels]),
                q(gr.data[i * gr.channels]),
            );
            let e = groups.entry(key).or_default();
            e.n += 1;
            for c in 0..3 {
                let pv = pred.data[i * pred.channels + c] as f64;
                e.gt[c] += g[c] as f64;
                e.pred[c] += pv;
                let d = (pv - g[c] as f64).powi(2);
                e.sse += d;
                total += d;
            }
            e.rough_gt += gr.data[i * gr.channels] as f64;
            e.rough_pred += rough.data[i * rough.channels] as f64;
            count += 1;
        }
    }
    let mut v: Vec<_> = groups.into_iter().collect();
    v.sort_by(|a, b| b.1.sse.partial_cmp(&a.1.sse).unwrap());
    println!(
        "pixels {count}, Kd RMSE {:.4}, PSNR {:.2} dB",
        (total / (3 * count) as f64).sqrt(),
        i2sdf_eval::image_metrics::psnr_from_mse(total / (3 * count) as f64)
    );
    println!("  share   pixels  GT Kd               pred Kd             ks    rho gt/pred");
    for (k, g) in v.iter().take(25) {
        let n = g.n as f64;
        println!(
            "  {:5.1}% {:7}  [{:.3} {:.3} {:.3}]  [{:.3} {:.3} {:.3}]  {:.2}  {:.2}/{:.2}",
            100.0 * g.sse / total,
            g.n,
            g.gt[0] / n,
            g.gt[1] / n,
            g.gt[2] / n,
            g.pred[0] / n,
            g.pred[1] / n,
            g.pred[2] / n,
            k.3 as f64 / 20.0,
            g.rough_gt / n,
            g.rough_pred / n
        );
    }
    Ok(())
}
