//! Times stage 2's two fixed-radius neighbour searches on realistic sizes, and keeps their
//! results for a comparison between versions:
//!
//! - `pool_diffuse` over pixels on a room's walls (4.8 × 2.7 × 3.6 m, world units, normals
//!   pointing in, 1 mm of noise), radius 0.08 m (the default `irradiance_radius` 0.024 times a
//!   normalization scale of about 3.3), two emitters: 100k and 393,216 pixels (the default
//!   `cache_pixels`);
//! - `components` of emitter points in normalized units (a 0.38 × 0.24 ceiling panel and a bulb
//!   of radius 0.03, 90 % / 10 % of the points), link 0.05 (the default `emitter_link`): 20k and
//!   100k points.
//!
//! Each case runs `REPS` times (default 3) and the fastest is printed, in wall and CPU seconds. `--dump FILE` writes the
//! pooled sums and the component labels; `--compare FILE` reads such a file and prints, per
//! case, how many pooled values are bit-identical and the largest relative difference, and
//! whether the labels agree.
//!
//! `cargo run --release -p i2sdf-train --example neighbour_bench [-- [--dump FILE | --compare FILE] [REPS]]`

use glam::Vec3;
use i2sdf_train::stage2::emitter_clusters::components;
use i2sdf_train::stage2::shading::{pool_diffuse, DiffuseSums, ShadingPoint};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::time::Instant;

const ROOM: [f32; 3] = [4.8, 2.7, 3.6];

/// `n` pixels uniform by area on the room's walls, normals pointing in, with their diffuse sums.
fn walls(n: usize, rng: &mut Pcg64) -> (Vec<ShadingPoint>, Vec<DiffuseSums>) {
    let e = ROOM;
    let areas = [e[1] * e[2], e[0] * e[2], e[0] * e[1]];
    let total: f32 = areas.iter().sum();
    let points = (0..n)
        .map(|_| {
            let t = rng.gen::<f32>() * total;
            let axis = if t < areas[0] {
                0
            } else if t < areas[0] + areas[1] {
                1
            } else {
                2
            };
            let mut p: [f32; 3] = std::array::from_fn(|a| rng.gen::<f32>() * e[a]);
            let high = rng.gen::<bool>();
            p[axis] = if high { e[axis] } else { 0.0 };
            p.iter_mut().for_each(|x| *x += rng.gen_range(-0.001..0.001));
            let mut normal = Vec3::ZERO;
            normal[axis] = if high { -1.0 } else { 1.0 };
            ShadingPoint {
                position: Vec3::from_array(p),
                normal,
                view: normal,
            }
        })
        .collect();
    let sums = (0..n)
        .map(|_| DiffuseSums {
            field: Vec3::new(rng.gen(), rng.gen(), rng.gen()),
            emit: vec![rng.gen(), rng.gen()],
        })
        .collect();
    (points, sums)
}

/// `n` emitter points in normalized units: a ceiling panel and a bulb.
fn emitter_points(n: usize, rng: &mut Pcg64) -> Vec<[f64; 3]> {
    (0..n)
        .map(|i| {
            if i % 10 != 0 {
                [-0.18 + rng.gen_range(-0.19..0.19), 0.8, rng.gen_range(-0.12..0.12)]
            } else {
                let v: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
                [-0.55 + 0.03 * v[0] / l, 0.55 + 0.03 * v[1] / l, -0.45 + 0.03 * v[2] / l]
            }
        })
        .collect()
}

/// CPU seconds this process has run (user + system, all threads; Linux's `/proc/self/stat`
/// in ticks of 1/100 s), or NaN elsewhere: on a machine shared with other work the wall time
/// says little.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // The fields after the command's closing parenthesis; utime and stime are the 12th and 13th.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |k: usize| f.get(k).and_then(|x| x.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (tick(11) + tick(12)) / 100.0
}

/// Fastest of `reps` runs of `f` in wall seconds, and in CPU seconds, and its last result.
fn time<T>(reps: usize, f: impl Fn() -> T) -> (f64, f64, T) {
    let (mut best, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
    let mut out = None;
    for _ in 0..reps {
        let (t, c) = (Instant::now(), cpu_seconds());
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        best_cpu = best_cpu.min(cpu_seconds() - c);
        out = Some(r);
    }
    (best, best_cpu, out.expect("one run"))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut dump, mut compare, mut reps) = (None, None, 3usize);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--dump" => dump = it.next().cloned(),
            "--compare" => compare = it.next().cloned(),
            r => reps = r.parse().expect("REPS: a number"),
        }
    }
    rayon::broadcast(|_| ());
    println!("{} threads, fastest of {reps}", rayon::current_num_threads());
    let mut values: Vec<f32> = Vec::new();
    let mut labels: Vec<u64> = Vec::new();
    for n in [100_000, 393_216] {
        let mut rng = Pcg64::seed_from_u64(n as u64);
        let (points, sums) = walls(n, &mut rng);
        let (s, cpu, pooled) = time(reps, || pool_diffuse(&points, &sums, 0.08));
        println!("pool_diffuse {n:>7} pixels: {s:.3} s ({cpu:.2} s CPU)");
        for p in &pooled {
            values.extend(p.field.to_array());
            values.extend(&p.emit);
        }
    }
    for n in [20_000, 100_000] {
        let mut rng = Pcg64::seed_from_u64(n as u64 + 1);
        let points = emitter_points(n, &mut rng);
        let (s, cpu, (label, count)) = time(reps, || components(&points, 0.05));
        println!("components   {n:>7} points: {s:.3} s ({cpu:.2} s CPU, {count} pieces)");
        labels.extend(label.iter().map(|&l| l as u64));
    }
    if let Some(path) = dump {
        let mut bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        bytes.extend(labels.iter().flat_map(|v| v.to_le_bytes()));
        std::fs::write(&path, bytes).expect("writing the dump");
    }
    if let Some(path) = compare {
        let bytes = std::fs::read(&path).expect("reading the dump");
        let (v, l) = bytes.split_at(4 * values.len());
        let old: Vec<f32> = v
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let old_labels: Vec<u64> = l
            .chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let same = old
            .iter()
            .zip(&values)
            .filter(|(a, b)| a.to_bits() == b.to_bits())
            .count();
        let worst = old
            .iter()
            .zip(&values)
            .map(|(&a, &b)| {
                if a == b {
                    0.0
                } else {
                    ((a - b).abs() / a.abs().max(b.abs())) as f64
                }
            })
            .fold(0.0, f64::max);
        println!(
            "pooled values: {same} of {} bit-identical, largest relative difference {worst:.3e}",
            values.len()
        );
        println!("component labels identical: {}", old_labels == labels);
    }
}
