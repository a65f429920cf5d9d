//! Times `KdTree::nearest_distance` against the search it replaced (pruning by the splitting plane
//! only, kept here for the comparison), on what `eval`'s mesh metrics ask of it: a tree over ~1M
//! points on a room's surface (a 4.8 × 2.7 × 3.6 box) queried by ~1M points
//!
//! - `near`: on the walls moved 1 cm in, with 5 mm of noise (a trained run's mesh);
//! - `scattered`: uniform in a box three times the room's size, most of them metres outside it;
//! - `blob`: on a 0.5 m sphere in the middle of the room (an untrained SDF's mesh), and the
//!   reverse, `walls→blob`: the room's points queried against a tree over the sphere's.
//!
//! With two PLY files, the cases are instead `eval`'s two searches on those meshes (no culling):
//! `pred→gt` (the predicted mesh's points against a tree over the GT's) and `gt→pred`, with
//! POINTS samples on each (`mesh_metrics::sample_surface`, seed 0 as `eval`).
//!
//! Queries run in parallel (rayon), as in `eval`. The old search visits nearly the whole tree per
//! far query, so it is timed on the first queries only, doubling their number until it has run
//! for `OLD_SECONDS` (default 5) or all are done, and its total is extrapolated from that; both
//! searches are exact, and their answers are checked to be identical on those queries.
//!
//! `cargo run --release -p i2sdf-eval --example kdtree_bench [-- POINTS [PRED.ply GT.ply]]`

use i2sdf_data::KdTree;
use i2sdf_eval::mesh_metrics::sample_surface;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use std::time::Instant;

/// The previous tree: the same layout and build, searched with the splitting-plane test alone.
struct OldTree {
    points: Vec<[f32; 3]>,
    axes: Vec<u8>,
}

const LEAF_SIZE: usize = 8;

fn dist_sq(p: [f32; 3], q: [f32; 3]) -> f32 {
    (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)
}

impl OldTree {
    fn new(points: &[[f32; 3]]) -> OldTree {
        let mut tree = OldTree {
            points: points.to_vec(),
            axes: vec![0; points.len()],
        };
        let n = tree.points.len();
        tree.build(0, n);
        tree
    }

    fn build(&mut self, lo: usize, hi: usize) {
        if hi - lo <= LEAF_SIZE {
            return;
        }
        let mut min = [f32::INFINITY; 3];
        let mut max = [f32::NEG_INFINITY; 3];
        for p in &self.points[lo..hi] {
            for a in 0..3 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        let axis = (0..3)
            .max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b])))
            .unwrap();
        let mid = (lo + hi) / 2;
        self.points[lo..hi].select_nth_unstable_by(mid - lo, |p, q| p[axis].total_cmp(&q[axis]));
        self.axes[mid] = axis as u8;
        self.build(lo, mid);
        self.build(mid + 1, hi);
    }

    fn nearest_distance_counted(&self, q: [f32; 3]) -> (f32, usize) {
        let (mut best, mut visited) = (f32::INFINITY, 0);
        self.search(q, 0, self.points.len(), &mut best, &mut visited);
        (best.sqrt(), visited)
    }

    fn search(&self, q: [f32; 3], lo: usize, hi: usize, best: &mut f32, visited: &mut usize) {
        *visited += 1;
        if hi - lo <= LEAF_SIZE {
            for p in &self.points[lo..hi] {
                *best = best.min(dist_sq(*p, q));
            }
            return;
        }
        let mid = (lo + hi) / 2;
        let p = self.points[mid];
        *best = best.min(dist_sq(p, q));
        let axis = self.axes[mid] as usize;
        let diff = q[axis] - p[axis];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search(q, near.0, near.1, best, visited);
        if diff * diff < *best {
            self.search(q, far.0, far.1, best, visited);
        }
    }
}

const ROOM: [f32; 3] = [4.8, 2.7, 3.6];

/// `n` points uniform by area on the faces of the box `[lo, hi]`, each moved by up to `noise`
/// along each axis.
fn box_surface(n: usize, lo: [f32; 3], hi: [f32; 3], noise: f32, rng: &mut impl Rng) -> Vec<[f32; 3]> {
    let e: [f32; 3] = std::array::from_fn(|a| hi[a] - lo[a]);
    // Face pairs normal to x, y, z, weighted by area.
    let areas = [e[1] * e[2], e[0] * e[2], e[0] * e[1]];
    let total: f32 = areas.iter().sum();
    (0..n)
        .map(|_| {
            let t = rng.gen::<f32>() * total;
            let axis = if t < areas[0] {
                0
            } else if t < areas[0] + areas[1] {
                1
            } else {
                2
            };
            let mut p: [f32; 3] = std::array::from_fn(|a| lo[a] + rng.gen::<f32>() * e[a]);
            p[axis] = if rng.gen::<bool>() { lo[axis] } else { hi[axis] };
            if noise > 0.0 {
                p.iter_mut().for_each(|x| *x += rng.gen_range(-noise..noise));
            }
            p
        })
        .collect()
}

fn sphere(n: usize, centre: [f32; 3], radius: f32, rng: &mut impl Rng) -> Vec<[f32; 3]> {
    (0..n)
        .map(|_| loop {
            let v: [f32; 3] = std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0));
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 1e-3 && l <= 1.0 {
                break std::array::from_fn(|a| centre[a] + radius * v[a] / l);
            }
        })
        .collect()
}

/// Seconds and mean nodes entered per query, over `queries` in parallel.
fn run(queries: &[[f32; 3]], search: impl Fn([f32; 3]) -> (f32, usize) + Sync) -> (Vec<f32>, f64, f64) {
    let start = Instant::now();
    let (d, n): (Vec<f32>, Vec<usize>) = queries.par_iter().map(|&q| search(q)).unzip();
    let seconds = start.elapsed().as_secs_f64();
    let mean = n.iter().sum::<usize>() as f64 / n.len().max(1) as f64;
    (d, seconds, mean)
}

/// A case: its name, the tree's points and the queries.
type Case = (String, Vec<[f32; 3]>, Vec<[f32; 3]>);

/// The synthetic cases of the module doc.
fn synthetic(n: usize) -> Vec<Case> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let walls = box_surface(n, [0.0; 3], ROOM, 0.0, &mut rng);
    let centre = ROOM.map(|x| 0.5 * x);
    let near = box_surface(n, [0.01; 3], ROOM.map(|x| x - 0.01), 0.005, &mut rng);
    let scattered = (0..n)
        .map(|_| std::array::from_fn(|a| rng.gen_range(-ROOM[a]..2.0 * ROOM[a])))
        .collect();
    let blob = sphere(n, centre, 0.5, &mut rng);
    vec![
        ("near".into(), walls.clone(), near),
        ("scattered".into(), walls.clone(), scattered),
        ("blob".into(), walls.clone(), blob.clone()),
        ("walls→blob".into(), blob, walls),
    ]
}

/// `eval`'s two searches between the meshes' samples.
fn meshes(n: usize, pred: &str, gt: &str) -> Vec<Case> {
    let read = |p: &str| i2sdf_eval::read_ply(std::path::Path::new(p)).unwrap_or_else(|e| panic!("{p}: {e}"));
    let (pred, gt) = (read(pred), read(gt));
    println!("predicted mesh {} faces, GT {} faces", pred.num_faces(), gt.num_faces());
    let t = Instant::now();
    let (p, _) = sample_surface(&pred, n, 0);
    let (g, _) = sample_surface(&gt, n, 0);
    println!("sampling both: {:.2} s", t.elapsed().as_secs_f64());
    vec![("pred→gt".into(), g.clone(), p.clone()), ("gt→pred".into(), p, g)]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n: usize = args.first().map_or(1_000_000, |s| s.parse().expect("POINTS: a number"));
    let old_budget: f64 = std::env::var("OLD_SECONDS").map_or(5.0, |s| s.parse().expect("OLD_SECONDS: seconds"));
    let cases = match &args[..] {
        [_, pred, gt] => meshes(n, pred, gt),
        [] | [_] => synthetic(n),
        _ => panic!("usage: kdtree_bench [POINTS [PRED.ply GT.ply]]"),
    };
    // The thread pool starts before anything is timed.
    rayon::broadcast(|_| ());
    println!(
        "{} threads; old: seconds extrapolated from the queries timed",
        rayon::current_num_threads()
    );
    println!(
        "{:<11} {:>9} {:>9} {:>11} {:>12} {:>11} {:>9} {:>9} {:>9}",
        "case",
        "build new",
        "build old",
        "query new s",
        "(unsorted) s",
        "query old s",
        "nodes new",
        "nodes old",
        "old timed"
    );
    for (name, points, queries) in &cases {
        let t = Instant::now();
        let new = KdTree::new(points);
        let build_new = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let old = OldTree::new(points);
        let build_old = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let d_new = new.nearest_distances(queries, &|_| {});
        let s_new = t.elapsed().as_secs_f64();
        let (d_unsorted, s_unsorted, nodes_new) = run(queries, |q| new.nearest_distance_counted(q));
        assert_eq!(d_unsorted, d_new, "{name}: the batch disagrees with single queries");
        let (mut m, mut spent, mut nodes_old) = (1000.min(queries.len()), 0.0, 0.0);
        let mut timed = 0;
        while spent < old_budget {
            let (d_old, s, nodes) = run(&queries[..m], |q| old.nearest_distance_counted(q));
            assert_eq!(d_old, d_new[..m], "{name}: the searches disagree");
            (spent, nodes_old, timed) = (s, nodes, m);
            if m == queries.len() {
                break;
            }
            m = (2 * m).min(queries.len());
        }
        let s_old = spent * queries.len() as f64 / timed as f64;
        println!(
            "{name:<11} {build_new:>9.2} {build_old:>9.2} {s_new:>11.2} {s_unsorted:>12.2} {s_old:>11.2} {nodes_new:>9.1} {nodes_old:>9.0} {timed:>9}"
        );
    }
}
