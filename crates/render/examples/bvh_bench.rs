//! Rays per second of the BVH on a mesh, with rays like a path tracer's in a room: from points on
//! the surface (area-weighted, nudged off it along the face normal) in cosine-distributed
//! directions (closest hit), and shadow segments from such points to a small light near the top
//! of the box and to other surface points (any hit). One thread; prints the build time, Mrays/s
//! of each query and a checksum (hits, summed t) so that a change of layout can be checked to
//! give the same answers.
//!
//! `cargo run --release -p i2sdf-render --example bvh_bench -- MESH.ply [SIMPLIFY_VOXELS]`
//! (SIMPLIFY_VOXELS: simplify as the edit renderer's recovered surface does, by that fraction of
//! a 256-grid voxel; 0 or absent: not simplified).

use glam::Vec3;
use i2sdf_render::Bvh;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;
use std::time::Instant;

const RAYS: usize = 2_000_000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        return Err("usage: bvh_bench MESH.ply [SIMPLIFY_VOXELS]".into());
    };
    let mut mesh = i2sdf_data::ply::read_ply(path)?;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in &mesh.positions {
        lo = lo.min(Vec3::from(*p));
        hi = hi.max(Vec3::from(*p));
    }
    if let Some(v) = args.get(1).map(|s| s.parse::<f32>()).transpose()? {
        if v > 0.0 {
            let voxel = (hi - lo).max_element() / 255.0;
            let labels = vec![0; mesh.faces.len()];
            mesh = i2sdf_render::simplify::simplify_labelled(&mesh, &labels, v * voxel).0;
        }
    }
    let start = Instant::now();
    let bvh = Bvh::build(&mesh);
    println!(
        "{} triangles, build {:.2} s, depth {}",
        mesh.faces.len(),
        start.elapsed().as_secs_f64(),
        bvh.depth()
    );

    // Area-weighted surface points with their face normals.
    let areas: Vec<f32> = (0..mesh.faces.len())
        .map(|f| {
            let (a, b, c) = (mesh.vertex(f, 0), mesh.vertex(f, 1), mesh.vertex(f, 2));
            0.5 * (b - a).cross(c - a).length()
        })
        .collect();
    let mut cdf = Vec::with_capacity(areas.len());
    let mut acc = 0.0f64;
    for a in &areas {
        acc += *a as f64;
        cdf.push(acc);
    }
    let mut rng = Pcg32::seed_from_u64(7);
    let point = |rng: &mut Pcg32| -> (Vec3, Vec3) {
        let x = rng.gen::<f64>() * acc;
        let f = cdf.partition_point(|&c| c < x).min(cdf.len() - 1);
        let (a, b, c) = (mesh.vertex(f, 0), mesh.vertex(f, 1), mesh.vertex(f, 2));
        let n = (b - a).cross(c - a).normalize_or_zero();
        let (mut u, mut v) = (rng.gen::<f32>(), rng.gen::<f32>());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        (a + u * (b - a) + v * (c - a) + 1e-4 * n, n)
    };
    let light = Vec3::new(0.5 * (lo.x + hi.x), hi.y - 0.15 * (hi.y - lo.y), 0.5 * (lo.z + hi.z));
    let mut closest = Vec::with_capacity(RAYS);
    let mut shadow = Vec::with_capacity(RAYS);
    for i in 0..RAYS {
        let (o, n) = point(&mut rng);
        let (u1, u2) = (rng.gen::<f32>(), rng.gen::<f32>());
        let (r, phi) = (u1.sqrt(), std::f32::consts::TAU * u2);
        let t = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
        let b1 = n.cross(t).normalize();
        let b2 = n.cross(b1);
        let d = (r * phi.cos() * b1 + r * phi.sin() * b2 + (1.0 - u1).max(0.0).sqrt() * n).normalize();
        closest.push((o, d));
        let target = if i % 2 == 0 {
            light + 0.1 * Vec3::new(rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5)
        } else {
            point(&mut rng).0
        };
        let seg = target - o;
        let dist = seg.length();
        shadow.push((o, seg / dist.max(1e-12), dist * (1.0 - 1e-4)));
    }

    let mut stack = Vec::new();
    for round in 0..2 {
        let start = Instant::now();
        let (mut hits, mut sum_t) = (0usize, 0f64);
        for &(o, d) in &closest {
            if let Some(h) = bvh.intersect(o, d, 0.0, f32::INFINITY, &mut stack) {
                hits += 1;
                sum_t += h.t as f64;
            }
        }
        let closest_s = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let mut blocked = 0usize;
        for &(o, d, t_max) in &shadow {
            blocked += bvh.occluded(o, d, 0.0, t_max, &mut stack) as usize;
        }
        let shadow_s = start.elapsed().as_secs_f64();
        println!(
            "round {round}: one at a time: closest hit {:.2} Mrays/s ({hits} hits, Σt {sum_t:.3}); shadow {:.2} Mrays/s ({blocked} blocked)",
            RAYS as f64 / closest_s / 1e6,
            RAYS as f64 / shadow_s / 1e6
        );
        let start = Instant::now();
        let (mut hits, mut sum_t) = (0usize, 0f64);
        bvh.intersect_each(
            closest.len(),
            |i| Some((closest[i].0, closest[i].1, 0.0, f32::INFINITY)),
            |_, h| {
                hits += 1;
                sum_t += h.t as f64;
            },
        );
        let closest_s = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let mut blocked = 0usize;
        bvh.occluded_each(
            shadow.len(),
            |i| Some((shadow[i].0, shadow[i].1, 0.0, shadow[i].2)),
            |_| blocked += 1,
        );
        let shadow_s = start.elapsed().as_secs_f64();
        println!(
            "round {round}: interleaved: closest hit {:.2} Mrays/s ({hits} hits, Σt {sum_t:.3}); shadow {:.2} Mrays/s ({blocked} blocked)",
            RAYS as f64 / closest_s / 1e6,
            RAYS as f64 / shadow_s / 1e6
        );
    }
    Ok(())
}
