//! Shading normals of a surface fitted without normal maps: the SDF's normals averaged over a
//! radius ([`SmoothedNormals`]), the one definition stage 2 fits its materials with and the
//! renderers (`eval`'s re-render through [`crate::intrinsic::FrozenScene`], `edit`'s recovered
//! mesh) shade with.
//!
//! Why: where no normal map is given, the shading normal is the SDF's gradient, and a surface
//! fitted to a phone's sensor depth is bumpy. Measured on the default room's capture, its
//! training pixels' normals were 14.7° from the true ones (median; 4.9° on the exact room's SDF)
//! and averaged over 8 cm 5.3° (1.2°). Every cosine of the shading carries the bumps' pattern,
//! which stage 2's emission estimate took for noise in the light and answered with too little L;
//! a renderer that shades with the raw gradient then re-renders what stage 2 fitted with other
//! normals (measured: 0.4–0.6 dB of the captures' re-render).

use glam::Vec3;
use i2sdf_data::KdTree;
use rayon::prelude::*;

/// Two normals are averaged together only when within 60° (cos > 0.5): the two sides of a
/// corner or of a thin object stay apart.
const SAME_SIDE_COS: f32 = 0.5;

/// Surface samples (positions, their SDF normals) in a k-d tree, and the radius over which a
/// normal is averaged (world units).
pub struct SmoothedNormals {
    tree: KdTree,
    positions: Vec<[f32; 3]>,
    normals: Vec<Vec3>,
    radius: f32,
}

impl SmoothedNormals {
    /// The samples of a surface: `positions` with their unit `normals`; `radius` > 0.
    pub fn new(positions: &[Vec3], normals: Vec<Vec3>, radius: f32) -> Self {
        assert_eq!(positions.len(), normals.len());
        assert!(radius > 0.0, "smoothing radius {radius}");
        let positions: Vec<[f32; 3]> = positions.iter().map(|p| p.to_array()).collect();
        SmoothedNormals {
            tree: KdTree::new(&positions),
            positions,
            normals,
            radius,
        }
    }

    /// The averaging radius (world units).
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// The mean of the samples' normals within the radius of `x` that lie within 60° of
    /// `normal` (`normal` itself where there are none). Neighbours are summed in ascending index
    /// order, so a sum is the same on every run.
    fn mean(&self, x: [f32; 3], normal: Vec3, near: &mut Vec<usize>) -> Vec3 {
        self.tree.within(x, self.radius, near);
        let sum: Vec3 = near
            .iter()
            .map(|&j| self.normals[j])
            .filter(|m| m.dot(normal) > SAME_SIDE_COS)
            .sum();
        let mean = sum.normalize_or_zero();
        if mean == Vec3::ZERO {
            normal
        } else {
            mean
        }
    }

    /// The smoothed normal at each of the samples themselves (a mesh's vertex normals).
    pub fn at_samples(&self) -> Vec<Vec3> {
        self.positions
            .par_iter()
            .zip(&self.normals)
            .map_init(Vec::new, |near, (&x, &n)| self.mean(x, n, near))
            .collect()
    }

    /// The smoothed normals at surface `points` whose own normals are `normals`, each seen
    /// from `views` (unit, towards the viewer) where given: a point keeps its own normal where
    /// the mean faces away from its viewer.
    pub fn at_points(&self, points: &[Vec3], normals: &[Vec3], views: Option<&[Vec3]>) -> Vec<Vec3> {
        assert!(points.len() == normals.len() && views.map_or(true, |v| v.len() == points.len()));
        points
            .par_iter()
            .zip(normals)
            .enumerate()
            .map_init(Vec::new, |near, (i, (x, &n))| {
                let mean = self.mean(x.to_array(), n, near);
                match views {
                    Some(v) if mean.dot(v[i]) <= 0.0 => n,
                    _ => mean,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg32;

    /// A floor and a wall meeting in a corner, their normals jittered by up to ~25°, with the
    /// true normal of each sample.
    fn bumpy_corner() -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec3>) {
        let mut rng = Pcg32::seed_from_u64(9);
        let (mut positions, mut normals, mut truth) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..40 {
            for j in 0..40 {
                let (u, v) = (i as f32 * 0.01, j as f32 * 0.01);
                for (position, n) in [(Vec3::new(u, 0.0, v), Vec3::Y), (Vec3::new(u, v, 0.0), Vec3::Z)] {
                    let jitter = Vec3::new(rng.gen(), rng.gen(), rng.gen()) - 0.5;
                    positions.push(position);
                    normals.push((n + 0.9 * jitter).normalize());
                    truth.push(n);
                }
            }
        }
        (positions, normals, truth)
    }

    fn angle(a: Vec3, b: Vec3) -> f32 {
        a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()
    }

    fn mean_error(normals: &[Vec3], truth: &[Vec3]) -> f32 {
        normals.iter().zip(truth).map(|(&n, &t)| angle(n, t)).sum::<f32>() / normals.len() as f32
    }

    /// Smoothing brings each side's normals back towards its plane's and keeps the two sides
    /// apart next to the corner, at the samples and at points between them; a point whose mean
    /// would face away from its viewer keeps its own normal.
    #[test]
    fn smoothing_straightens_bumpy_normals_and_keeps_corners() {
        let (positions, normals, truth) = bumpy_corner();
        let field = SmoothedNormals::new(&positions, normals.clone(), 0.05);
        let e0 = mean_error(&normals, &truth);
        let at_samples = field.at_samples();
        let e1 = mean_error(&at_samples, &truth);
        assert!(e0 > 10.0 && e1 < 0.4 * e0, "mean error {e0}° → {e1}°");
        for ((p, n), &t) in positions.iter().zip(&at_samples).zip(&truth) {
            if p.y < 0.02 && p.z < 0.02 {
                assert!(angle(*n, t) < 30.0, "{p} {n} against {t}");
            }
        }
        // Points half a step off the samples, seen from their own side (the floor's seen from
        // above); one seen from below keeps its own normal.
        let points: Vec<Vec3> = positions.iter().map(|p| *p + Vec3::new(0.005, 0.0, 0.0)).collect();
        let mut views = truth.clone();
        views[11] = -views[11];
        let at_points = field.at_points(&points, &normals, Some(&views));
        assert!(mean_error(&at_points, &truth) < 0.4 * e0);
        assert_eq!(at_points[11], normals[11]);
        assert_ne!(at_points[12], normals[12]);
    }

    /// A lone sample with no neighbour on its side keeps its normal; the radius is the one given.
    #[test]
    fn a_sample_without_neighbours_keeps_its_normal() {
        let positions = [Vec3::ZERO, Vec3::new(0.01, 0.0, 0.0), Vec3::new(5.0, 0.0, 0.0)];
        let normals = vec![Vec3::Y, -Vec3::Y, Vec3::X];
        let field = SmoothedNormals::new(&positions, normals.clone(), 0.1);
        assert_eq!(field.radius(), 0.1);
        assert_eq!(field.at_samples(), normals);
    }
}
