//! Empty-space skipping (issue 26): an occupancy grid over the scene's cube, built from the SDF,
//! that tells the ray sampler which stretches of a ray can hold no surface, so that it spends its
//! SDF evaluations where one can be (as instant-ngp's and NeuS2's occupancy grids do).
//!
//! A cell is classified by the SDF at its centre c and its half-diagonal h:
//! - *free* when d(c) > h + margin: with a 1-Lipschitz SDF (what the eikonal term trains),
//!   d > margin everywhere in the cell, so the Laplace density there is at most
//!   α·½·e^{−margin/β}: the sampler gives it no density at all;
//! - *solid* when d(c) < −(h + margin): the whole cell is inside the surface, opaque; a ray is cut
//!   where it first enters one (what lies behind is not seen);
//! - *occupied* otherwise: the surface may pass through it.
//!
//! The margin is chosen by the caller in units of β (the density falls by e^{−margin/β} at
//! the border of a free cell) and never below the grid's own cell, so that a slowly moving
//! surface is re-marked before it leaves its occupied band. The grid is a snapshot: the training
//! loop rebuilds it every few iterations.

/// The class of one cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Cell {
    Free = 0,
    Occupied = 1,
    Solid = 2,
}

/// A grid of `resolution`³ cells over the cube [−extent, extent]³ (the normalized scene's).
#[derive(Clone, Debug)]
pub struct OccupancyGrid {
    resolution: usize,
    extent: f32,
    cell: f32,
    margin: f32,
    cells: Vec<Cell>,
}

impl OccupancyGrid {
    /// Classifies every cell by `sdf(points, values)` at the cell centres (called in slabs of
    /// one z-layer, so the caller's evaluator sees batches of `resolution`² points).
    pub fn build<F>(resolution: usize, extent: f32, margin: f32, mut sdf: F) -> OccupancyGrid
    where
        F: FnMut(&[[f32; 3]], &mut [f32]),
    {
        assert!(resolution >= 1 && extent > 0.0 && margin >= 0.0);
        let cell = 2.0 * extent / resolution as f32;
        let half_diagonal = 0.5 * cell * 3f32.sqrt();
        let limit = half_diagonal + margin;
        let centre = |i: usize| -extent + (i as f32 + 0.5) * cell;
        let mut cells = Vec::with_capacity(resolution.pow(3));
        let mut points = Vec::with_capacity(resolution * resolution);
        let mut values = vec![0.0f32; resolution * resolution];
        for z in 0..resolution {
            points.clear();
            for y in 0..resolution {
                for x in 0..resolution {
                    points.push([centre(x), centre(y), centre(z)]);
                }
            }
            sdf(&points, &mut values);
            cells.extend(values.iter().map(|&d| {
                if d > limit {
                    Cell::Free
                } else if d < -limit {
                    Cell::Solid
                } else {
                    // NaN lands here too: unknown is occupied.
                    Cell::Occupied
                }
            }));
        }
        OccupancyGrid {
            resolution,
            extent,
            cell,
            margin,
            cells,
        }
    }

    /// The grid of a scene's SDF over the cube of half-size `extent` (the render bound), its
    /// margin `beta_margin`·β but at least one cell. The SDF is evaluated in parallel, a z-layer
    /// per task, through the inference path.
    pub fn for_scene(scene: &crate::NeuralScene, resolution: usize, extent: f32, beta_margin: f32) -> OccupancyGrid {
        use rayon::prelude::*;
        let cell = 2.0 * extent / resolution as f32;
        let margin = (beta_margin * scene.beta.value()).max(cell);
        let layers: Vec<Vec<f32>> = (0..resolution)
            .into_par_iter()
            .map_init(i2sdf_nn::sdf::SdfInferWorkspace::default, |ws, z| {
                let c = |i: usize| -extent + (i as f32 + 0.5) * cell;
                let mut points = Vec::with_capacity(3 * resolution * resolution);
                for y in 0..resolution {
                    for x in 0..resolution {
                        points.extend_from_slice(&[c(x), c(y), c(z)]);
                    }
                }
                let mut values = vec![0.0f32; resolution * resolution];
                scene.sdf.infer(&points, ws, &mut values, None, None);
                values
            })
            .collect();
        let mut layer = layers.iter();
        OccupancyGrid::build(resolution, extent, margin, |_, out| {
            out.copy_from_slice(layer.next().expect("one layer per call"))
        })
    }

    pub fn resolution(&self) -> usize {
        self.resolution
    }

    pub fn margin(&self) -> f32 {
        self.margin
    }

    /// The class of the cell at integer coordinates.
    pub fn cell(&self, x: usize, y: usize, z: usize) -> Cell {
        self.cells[(z * self.resolution + y) * self.resolution + x]
    }

    /// The class of the cell holding `p` (outside the cube: free).
    pub fn at(&self, p: [f32; 3]) -> Cell {
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let f = (p[a] + self.extent) / self.cell;
            if !(0.0..self.resolution as f32).contains(&f) {
                return Cell::Free;
            }
            idx[a] = f as usize;
        }
        self.cell(idx[0], idx[1], idx[2])
    }

    /// Fraction of the cells that are occupied.
    pub fn occupied_fraction(&self) -> f64 {
        self.cells.iter().filter(|&&c| c == Cell::Occupied).count() as f64 / self.cells.len() as f64
    }

    /// The parts of the ray o + t·d (d a unit vector), t ∈ [near, far], that cross occupied
    /// cells, as sorted disjoint `[start, end]` intervals appended to `out` (cleared first); the
    /// ray is cut where it first enters a solid cell. Walks the cells the ray crosses in order
    /// (Amanatides & Woo's grid traversal); adjacent occupied cells merge into one interval.
    pub fn intervals(&self, o: [f32; 3], d: [f32; 3], near: f32, far: f32, out: &mut Vec<[f32; 2]>) {
        out.clear();
        // The ray's part inside the cube (slab test).
        let (mut t0, mut t1) = (near, far);
        for a in 0..3 {
            if d[a].abs() < 1e-12 {
                if o[a].abs() > self.extent {
                    return;
                }
                continue;
            }
            let inv = 1.0 / d[a];
            let (ta, tb) = ((-self.extent - o[a]) * inv, (self.extent - o[a]) * inv);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        if t0 >= t1 {
            return;
        }
        let n = self.resolution as i64;
        // The cell of the entry point, and per axis the step, the t of the next boundary and the
        // t between boundaries.
        let mut idx = [0i64; 3];
        let mut step = [0i64; 3];
        let mut next = [f32::INFINITY; 3];
        let mut delta = [f32::INFINITY; 3];
        let tm = t0 + 0.5 * (t1 - t0).min(1e-4 * self.cell);
        for a in 0..3 {
            let p = o[a] + tm * d[a];
            idx[a] = (((p + self.extent) / self.cell).floor() as i64).clamp(0, n - 1);
            if d[a] > 0.0 {
                step[a] = 1;
                let boundary = -self.extent + (idx[a] + 1) as f32 * self.cell;
                next[a] = (boundary - o[a]) / d[a];
                delta[a] = self.cell / d[a];
            } else if d[a] < 0.0 {
                step[a] = -1;
                let boundary = -self.extent + idx[a] as f32 * self.cell;
                next[a] = (boundary - o[a]) / d[a];
                delta[a] = -self.cell / d[a];
            }
        }
        let mut t = t0;
        loop {
            let axis = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            let t_out = next[axis].min(t1);
            match self.cell(idx[0] as usize, idx[1] as usize, idx[2] as usize) {
                Cell::Solid => {
                    // Cut: an occupied interval ending here keeps its end at the solid cell.
                    return;
                }
                Cell::Occupied => match out.last_mut() {
                    Some(last) if last[1] >= t => last[1] = t_out,
                    _ => out.push([t, t_out]),
                },
                Cell::Free => {}
            }
            if t_out >= t1 {
                return;
            }
            t = t_out;
            idx[axis] += step[axis];
            if idx[axis] < 0 || idx[axis] >= n {
                return;
            }
            next[axis] += delta[axis];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// A room: free inside a sphere of radius 0.6 (positive), solid outside; and a small ball
    /// of radius 0.1 at (0.3, 0, 0) inside it.
    fn room(p: [f32; 3]) -> f32 {
        let len = |q: [f32; 3]| (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
        let wall = 0.6 - len(p);
        let ball = len([p[0] - 0.3, p[1], p[2]]) - 0.1;
        wall.min(ball)
    }

    fn grid(resolution: usize, margin: f32) -> OccupancyGrid {
        OccupancyGrid::build(resolution, 1.0, margin, |pts, out| {
            for (p, o) in pts.iter().zip(out.iter_mut()) {
                *o = room(*p);
            }
        })
    }

    fn random_ray(rng: &mut Pcg64) -> ([f32; 3], [f32; 3]) {
        let o = [
            rng.gen_range(-0.3..0.3),
            rng.gen_range(-0.3..0.3),
            rng.gen_range(-0.3..0.0),
        ];
        let mut d = [
            rng.gen_range(-1.0f32..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        ];
        // Some rays along an axis or a face diagonal: the traversal's ties.
        match rng.gen_range(0..6) {
            0 => d = [1.0, 0.0, 0.0],
            1 => d = [0.0, -1.0, 0.0],
            2 => d = [0.0, 1.0, 1.0],
            _ => {}
        }
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        (o, d.map(|x| x / l))
    }

    /// Conservative: every point of a ray before its cut where |d| ≤ margin lies in an interval;
    /// the cut is at or beyond the true surface; the intervals are sorted, disjoint and in
    /// [near, far]; and they are short (the skipping does something).
    #[test]
    fn intervals_hold_every_near_surface_point_of_the_ray() {
        let margin = 0.02;
        let g = grid(48, margin);
        let mut rng = Pcg64::seed_from_u64(26);
        let mut out = Vec::new();
        let (mut covered, mut total) = (0.0f64, 0.0f64);
        for _ in 0..400 {
            let (o, d) = random_ray(&mut rng);
            let (near, far) = (0.01, 2.0);
            g.intervals(o, d, near, far, &mut out);
            assert!(!out.is_empty(), "every ray from inside the room meets its wall");
            for w in out.windows(2) {
                assert!(w[0][1] < w[1][0], "{out:?}");
            }
            assert!(out.iter().all(|iv| near <= iv[0] && iv[0] < iv[1] && iv[1] <= far));
            let at = |t: f32| room([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
            // The first point where the ray goes inside (the surface it sees).
            let steps = 20_000;
            let hit = (0..=steps)
                .map(|i| near + (far - near) * i as f32 / steps as f32)
                .find(|&t| at(t) < 0.0)
                .expect("the wall");
            let end = out.last().unwrap()[1];
            assert!(end >= hit, "cut at {end} before the surface at {hit}");
            for i in 0..=steps {
                let t = near + (end - near) * i as f32 / steps as f32;
                if at(t).abs() <= margin {
                    assert!(
                        out.iter().any(|iv| iv[0] - 1e-4 <= t && t <= iv[1] + 1e-4),
                        "t {t} (d {}) outside {out:?}",
                        at(t)
                    );
                }
            }
            covered += out.iter().map(|iv| (iv[1] - iv[0]) as f64).sum::<f64>();
            total += (hit - near) as f64;
        }
        assert!(covered < 0.5 * total, "occupied {covered} of {total}: nothing skipped");
    }

    #[test]
    fn cells_are_classified_by_their_centre_distance() {
        let g = grid(16, 0.0);
        assert_eq!(g.at([0.0, 0.0, 0.0]), Cell::Free);
        assert_eq!(g.at([0.95, 0.95, 0.95]), Cell::Solid);
        assert_eq!(
            g.at([0.3, 0.0, 0.0]),
            Cell::Occupied,
            "the ball's centre cell holds its surface"
        );
        assert_eq!(g.at([2.0, 0.0, 0.0]), Cell::Free, "outside the cube");
        let f = g.occupied_fraction();
        assert!(f > 0.0 && f < 0.3, "{f}");
        // A NaN distance is unknown: occupied.
        let nan = OccupancyGrid::build(4, 1.0, 0.0, |_, out| out.fill(f32::NAN));
        assert_eq!(nan.occupied_fraction(), 1.0);
    }

    /// A ray that starts outside the cube or misses it gets nothing; one along a cell boundary
    /// still gets its intervals.
    #[test]
    fn rays_outside_or_along_boundaries() {
        let g = grid(8, 0.0);
        let mut out = Vec::new();
        g.intervals([3.0, 0.0, 0.0], [0.0, 1.0, 0.0], 0.0, 5.0, &mut out);
        assert!(out.is_empty());
        // x = 0 is a cell boundary of an 8³ grid over [−1, 1]³.
        g.intervals([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.0, 2.0, &mut out);
        assert!(!out.is_empty() && out.last().unwrap()[1] >= 0.6 - 1e-3, "{out:?}");
    }
}
