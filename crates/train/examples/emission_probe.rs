//! Runs `emission_from_shading` on inputs dumped by `stage2_ablation` (`EST=1 EST_DUMP=FILE`)
//! with settings from the environment, so its parameters can be studied without a cache build:
//! `EST_HOLD=k=r,g,b EST_FLOOR=1 EST_POOL=0.1 EST_MINSTEP=0.1 EST_STEP=0.4 EST_DELTA=0.05 EST_COS=0.95 EST_SLOPE=0.1 EST_MIN=0.01
//! cargo run --release -p i2sdf-train --example emission_probe -- FILE`.

use glam::Vec3;
use i2sdf_train::stage2::emission_from_shading::{estimate_emission, neighbour_pairs, ShadedPixel, ShadingEstimate};
use i2sdf_train::stage2::shading::{pool_diffuse, DiffuseSums, ShadingPoint};

fn env<T: std::str::FromStr>(key: &str, default: T) -> T {
    std::env::var(key).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: emission_probe FILE")?;
    let bytes = std::fs::read(path)?;
    let raw: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let (n, k, width) = (raw[0] as usize, raw[1] as usize, raw[2] as usize);
    // EST_FLOOR=v: the lower bound lowered to v (stage2_ablation dumps the stage's estimate as
    // the bound, which no variant could then go under).
    let floor: f32 = env("EST_FLOOR", f32::INFINITY);
    let bound: Vec<Vec3> = (0..k)
        .map(|e| Vec3::from_slice(&raw[3 + 3 * e..6 + 3 * e]).min(Vec3::splat(floor)))
        .collect();
    let row = 15 + k;
    let (mut px, mut sums) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for r in raw[3 + 3 * k..].chunks_exact(row) {
        px.push(ShadedPixel {
            position: Vec3::from_slice(&r[0..3]),
            normal: Vec3::from_slice(&r[3..6]),
            target: Vec3::from_slice(&r[6..9]),
            view: r[12 + k] as u32,
            pixel: r[13 + k] as u32,
            saturated: r[14 + k] as u8,
        });
        sums.push(DiffuseSums {
            field: Vec3::from_slice(&r[9..12]),
            emit: r[12..12 + k].to_vec(),
        });
    }
    let d = ShadingEstimate::default();
    let s = ShadingEstimate {
        min_step: env("EST_MINSTEP", d.min_step),
        max_step: env("EST_STEP", d.max_step),
        delta: env("EST_DELTA", d.delta),
        min_cos: env("EST_COS", d.min_cos),
        max_slope: env("EST_SLOPE", d.max_slope),
        min_target: env("EST_MIN", d.min_target),
        ..d
    };
    // EST_POOL=r: the (already pooled) sums averaged again over r (world units), as
    // `pool_diffuse` does, to see how the estimate follows the emitter weights' noise.
    let pool: f32 = env("EST_POOL", 0.0);
    if pool > 0.0 {
        let pts: Vec<ShadingPoint> = px
            .iter()
            .map(|p| ShadingPoint {
                position: p.position,
                normal: p.normal,
                view: Vec3::ZERO,
            })
            .collect();
        sums = pool_diffuse(&pts, &sums, pool);
    }
    let views = px.iter().map(|p| p.view as usize + 1).max().unwrap_or(0);
    let pairs = neighbour_pairs(&px, &vec![width; views], &s);
    // EST_HOLD="k=r,g,b": emitter k held there (the others estimated).
    let (mut bound, mut free) = (bound, vec![true; k]);
    if let Ok(h) = std::env::var("EST_HOLD") {
        let (e, v) = h.split_once('=').ok_or("EST_HOLD=k=r,g,b")?;
        let e: usize = e.parse()?;
        let v: Vec<f32> = v.split(',').map(|x| x.parse()).collect::<Result<_, _>>()?;
        bound[e] = Vec3::from_slice(&v);
        free[e] = false;
    }
    let est = estimate_emission(&px, &sums, &pairs, &bound, &free, &s);
    for (e, l) in est.iter().enumerate() {
        println!("L{e} {:.3} {:.3} {:.3}", l.x, l.y, l.z);
    }
    println!("{} pairs", pairs.len());
    Ok(())
}
