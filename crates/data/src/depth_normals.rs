//! Normal maps derived from depth, for datasets without normal maps: the cross product of the
//! back-projected neighbours' differences. Per axis the tangent is the central difference where
//! both neighbours continue the surface, the one-sided difference towards the neighbour that does
//! where only one does (an edge), and there is none (no normal) where neither does (a depth
//! discontinuity on both sides, a missing depth). World space, oriented towards the camera.
//!
//! A sensor's coarser depth grid mapped onto the image leaves most pixels without depth (1 in 16
//! for a grid of 4): a pixel's neighbour along an axis is then the nearest pixel with depth within
//! `MAX_GAP`, and the thresholds scale with the gap. Without that no normal could be derived
//! from such a depth map at all, and training silently had no normal loss.
//!
//! Sensor depth is noisy (the paper's model: σ = 3 cm at 3 m), and a cross product of two
//! differences a few centimetres long turns that noise into tens of degrees. So the cross
//! product only seeds each normal. Where the depth map is noisy, it is then refined by a
//! least-squares plane through the samples around the pixel (two samples' spacing each way) that
//! lie on the seed's plane within three times the noise (Hoppe et al. 1992's local planes, with
//! the seed keeping other surfaces across an edge or crease out of the fit). The noise is
//! measured on the map itself ([`relative_noise`]); on noise-free depth the seeds are exact on
//! planes and are kept, since a fit would bend them near creases.

use crate::camera::Camera;
use crate::imageio::ImageF32;
use glam::DVec3;
use rayon::prelude::*;

/// Depth steps within this fraction of the depth are "equal" (a fronto-parallel surface, where the
/// ratio of two tiny steps means nothing).
const FLAT: f64 = 0.002;
/// A neighbour continues the surface when its depth step is at most this fraction of the depth
/// (a wall at 82° from the view axis of a 60° field of view over 80 pixels steps by about this
/// much); and when the two sides disagree, the steeper one is an edge if over twice the other.
const MAX_STEP: f64 = 0.1;
/// The farthest (pixels) a neighbour with depth is looked for along an axis: a depth grid of 8.
const MAX_GAP: isize = 8;

/// A sample within this many times the map's noise (relative to the depth) of the current plane
/// is on the same surface for the plane fit.
const INLIER_SIGMAS: f64 = 3.0;
/// Plane-fit rounds (each with the inliers of the previous round's plane).
const REFINE_ROUNDS: usize = 2;

/// The tangent along one image axis at a pixel of depth `d`, from the neighbours' depths, points
/// and distances in pixels (`None` where there is no neighbour with depth in the image).
type Neighbour = Option<(f64, DVec3, f64)>;
fn tangent(d: f64, prev: Neighbour, here: DVec3, next: Neighbour) -> Option<DVec3> {
    // Depth steps per pixel of gap.
    let step = |n: Neighbour| n.map(|(dn, _, gap)| (dn - d).abs() / gap);
    match (step(prev), step(next)) {
        (Some(a), Some(b)) if a.max(b) <= (2.0 * a.min(b)).max(FLAT * d) && a.max(b) <= MAX_STEP * d => {
            Some(next.unwrap().1 - prev.unwrap().1)
        }
        (a, b) => {
            // One side at most: the smoother, if it continues the surface.
            let prev_ok = a.filter(|s| *s <= MAX_STEP * d);
            let next_ok = b.filter(|s| *s <= MAX_STEP * d);
            match (prev_ok, next_ok) {
                (Some(a), Some(b)) if a <= b => Some(here - prev.unwrap().1),
                (Some(_), Some(_)) | (None, Some(_)) => Some(next.unwrap().1 - here),
                (Some(_), None) => Some(here - prev.unwrap().1),
                (None, None) => None,
            }
        }
    }
}

/// World-space unit normals from a z-depth map (1 channel, world units, 0 = none) seen by
/// `camera`: 3 channels, (0,0,0) where no normal can be derived.
pub fn normals_from_depth(depth: &ImageF32, camera: &Camera) -> ImageF32 {
    let (w, h) = (camera.width, camera.height);
    assert_eq!((depth.width, depth.height), (w, h), "depth map and camera sizes");
    // Back-projected points once (the lens model's inversion is the costly part).
    let points: Vec<Option<(f64, DVec3)>> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let d = depth.data[p * depth.channels] as f64;
            (d > 0.0 && d.is_finite()).then(|| (d, camera.backproject(p % w, p / w, d)))
        })
        .collect();
    let centre = camera.center();
    // The grid's spacing: a sensor grid of N leaves one pixel in N² with depth.
    let with_depth = points.iter().filter(|p| p.is_some()).count().max(1);
    let spacing = ((w * h) as f64 / with_depth as f64)
        .sqrt()
        .round()
        .clamp(1.0, MAX_GAP as f64) as isize;
    // The plane fit's inlier band; none (the seeds kept) on depth without measurable noise.
    let noise = relative_noise(&points, (w, h), spacing);
    let inlier = INLIER_SIGMAS * noise;
    // The fit's window, in samples each way: wider the larger the depth noise against the
    // samples' lateral spacing (σ·z against spacing·z / f). Measured on the default room
    // (160×120, the paper's σ noise): its 4× coarser grid (ratio 0.26) is best at 3 samples,
    // the full-resolution map (ratio 1.0) at 6 or more, where wider windows take in more edges.
    let ratio = noise * camera.fx / spacing as f64;
    let window = spacing * (2.0 + 4.0 * ratio).round().clamp(2.0, 8.0) as isize;
    let refine = inlier > FLAT;
    let mut out = ImageF32::new(w, h, 3);
    out.data.par_chunks_mut(3).enumerate().for_each(|(p, n)| {
        let Some((d, here)) = points[p] else { return };
        let (x, y) = (p % w, p / w);
        // The nearest pixel with depth from (x, y) in direction (di, dj).
        let near = |di: isize, dj: isize| -> Neighbour {
            (1..=MAX_GAP).find_map(|k| {
                let (i, j) = (x as isize + k * di, y as isize + k * dj);
                if i < 0 || j < 0 || i >= w as isize || j >= h as isize {
                    return Some(None);
                }
                points[j as usize * w + i as usize].map(|(dn, pn)| Some((dn, pn, k as f64)))
            })?
        };
        let tx = tangent(d, near(-1, 0), here, near(1, 0));
        let ty = tangent(d, near(0, -1), here, near(0, 1));
        let (Some(tx), Some(ty)) = (tx, ty) else { return };
        let normal = tx.cross(ty);
        let len = normal.length();
        if !(len > 0.0 && len.is_finite()) {
            return;
        }
        let normal = if refine {
            fitted_plane_normal(&points, (w, h), (x, y), here, d, normal / len, window, inlier)
        } else {
            normal / len
        };
        let normal = if normal.dot(centre - here) < 0.0 {
            -normal
        } else {
            normal
        };
        n.copy_from_slice(&[normal.x as f32, normal.y as f32, normal.z as f32]);
    });
    out
}

/// The depth map's noise as a fraction of the depth (a robust σ): over every sample whose two
/// neighbours along the image's x axis lie at the grid's `spacing`, the second difference of
/// inverse depth relative to it, which is 0 on any plane (inverse depth is affine in the image);
/// the median of its magnitude, over 0.6745·√1.5 (the median absolute value of that combination
/// of three samples with independent Gaussian noise of σ 1). Edges are a minority and do not move
/// the median. 0 with too few samples to tell.
fn relative_noise(points: &[Option<(f64, DVec3)>], (w, h): (usize, usize), spacing: isize) -> f64 {
    let s = spacing as usize;
    let mut r: Vec<f64> = Vec::new();
    for y in 0..h {
        for x in s..w.saturating_sub(s) {
            let (Some((d, _)), Some((a, _)), Some((b, _))) =
                (points[y * w + x], points[y * w + x - s], points[y * w + x + s])
            else {
                continue;
            };
            r.push(((0.5 * (1.0 / a + 1.0 / b) - 1.0 / d) * d).abs());
        }
    }
    if r.len() < 16 {
        return 0.0;
    }
    let mid = r.len() / 2;
    let median = *r.select_nth_unstable_by(mid, f64::total_cmp).1;
    median / (0.6745 * 1.5f64.sqrt())
}

/// The normal of the least-squares plane through the samples within `window` pixels of pixel
/// `(x, y)` (point `here`, depth `d`) that lie within `inlier`·d of the current plane, starting
/// from `seed` (unit). The plane is fitted as a height field over the current plane (z' = a x' +
/// b y' + c in a frame whose z' is the current normal), which stays well posed as long as the
/// seed is not far off. Falls back to the current normal with fewer than 3 inliers or a
/// degenerate fit (samples in a line).
fn fitted_plane_normal(
    points: &[Option<(f64, DVec3)>],
    (w, h): (usize, usize),
    (x, y): (usize, usize),
    here: DVec3,
    d: f64,
    seed: DVec3,
    window: isize,
    inlier: f64,
) -> DVec3 {
    let mut n = seed;
    for _ in 0..REFINE_ROUNDS {
        let t1 = n.any_orthonormal_vector();
        let t2 = n.cross(t1);
        // Normal equations of [a, b, c] for rows (x', y', 1) · [a b c] = z'.
        let mut ata = glam::DMat3::ZERO;
        let mut atb = DVec3::ZERO;
        let mut count = 0;
        for j in (y as isize - window).max(0)..=(y as isize + window).min(h as isize - 1) {
            for i in (x as isize - window).max(0)..=(x as isize + window).min(w as isize - 1) {
                let Some((_, q)) = points[j as usize * w + i as usize] else {
                    continue;
                };
                let r = q - here;
                let z = r.dot(n);
                if z.abs() > inlier * d {
                    continue;
                }
                let row = DVec3::new(r.dot(t1), r.dot(t2), 1.0);
                ata += glam::DMat3::from_cols(row * row.x, row * row.y, row * row.z);
                atb += row * z;
                count += 1;
            }
        }
        // Scale-free degeneracy test: the determinant against the in-plane spread cubed.
        let spread = ata.x_axis.x + ata.y_axis.y;
        if count < 3 || ata.determinant().abs() <= 1e-9 * spread * spread * count as f64 {
            break;
        }
        let abc = ata.inverse() * atb;
        let fitted = (n - abc.x * t1 - abc.y * t2).normalize();
        if !fitted.is_finite() {
            break;
        }
        n = fitted;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::look_at;

    fn camera() -> Camera {
        Camera {
            width: 80,
            height: 60,
            fx: 70.0,
            fy: 70.0,
            cx: 40.0,
            cy: 30.0,
            c2w: look_at(DVec3::new(0.3, -0.4, 0.2), DVec3::new(0.0, 0.0, 5.0), DVec3::Y),
            lens: Default::default(),
        }
    }

    /// Renders the z-depth of a surface given by `hit` (ray origin, direction → distance and the
    /// true normal), and compares the derived normals with the true ones: every pixel with a true
    /// normal and a derived one, the angle in degrees.
    fn angles(hit: impl Fn(DVec3, DVec3) -> Option<(f64, DVec3)>) -> (Vec<f64>, usize) {
        angles_on_grid(1, hit)
    }

    /// As `angles`, with depth only at every `grid`-th pixel along each axis (a sensor's coarser
    /// grid mapped onto the image).
    fn angles_on_grid(grid: usize, hit: impl Fn(DVec3, DVec3) -> Option<(f64, DVec3)>) -> (Vec<f64>, usize) {
        angles_with_noise(grid, 0.0, hit)
    }

    /// As `angles_on_grid`, with each depth sample scaled by 1 + `noise`·g, g a fixed
    /// pseudo-random standard normal per pixel (a sensor's noise relative to the depth).
    fn angles_with_noise(
        grid: usize,
        noise: f64,
        hit: impl Fn(DVec3, DVec3) -> Option<(f64, DVec3)>,
    ) -> (Vec<f64>, usize) {
        let cam = camera();
        let (w, h) = (cam.width, cam.height);
        let mut depth = ImageF32::new(w, h, 1);
        let mut truth = vec![None; w * h];
        for j in 0..h {
            for i in 0..w {
                let (o, d, cos) = cam.ray(i as f64 + 0.5, j as f64 + 0.5);
                if i % grid != grid / 2 || j % grid != grid / 2 {
                    continue;
                }
                if let Some((t, n)) = hit(o, d) {
                    depth.data[j * w + i] = (t * cos * (1.0 + noise * gaussian(j * w + i))) as f32;
                    truth[j * w + i] = Some(n);
                }
            }
        }
        let derived = normals_from_depth(&depth, &cam);
        let mut out = Vec::new();
        let mut missing = 0;
        for (p, t) in truth.iter().enumerate() {
            let Some(t) = t else {
                assert_eq!(&derived.data[p * 3..p * 3 + 3], &[0.0; 3], "a normal without depth");
                continue;
            };
            let n = DVec3::new(
                derived.data[p * 3] as f64,
                derived.data[p * 3 + 1] as f64,
                derived.data[p * 3 + 2] as f64,
            );
            if n == DVec3::ZERO {
                missing += 1;
                continue;
            }
            assert!((n.length() - 1.0).abs() < 1e-5);
            out.push(n.dot(*t).clamp(-1.0, 1.0).acos().to_degrees());
        }
        out.sort_by(f64::total_cmp);
        (out, missing)
    }

    /// A standard normal from a pixel index (Box–Muller on two hashed uniforms): fixed noise.
    fn gaussian(k: usize) -> f64 {
        let hash = |x: u64| {
            let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let (u1, u2) = (1.0 - hash(2 * k as u64), hash(2 * k as u64 + 1));
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Sensor noise (1 % of the depth, the paper's σ(z) / z at 3 m) on a coarse grid: the plane
    /// fit brings the normals within a few degrees (measured: median 1.9°, 90th percentile
    /// 4.2°), where the cross product of two noisy differences alone (the seed) is off by a median
    /// 12.5° (90th percentile 23°).
    #[test]
    fn noisy_coarse_depth_gets_fitted_normals() {
        let normal = DVec3::new(0.3, -0.5, -1.0).normalize();
        let point = DVec3::new(0.0, 0.0, 4.0);
        let (a, _) = angles_with_noise(4, 0.01, |o, d| {
            let t = (point - o).dot(normal) / d.dot(normal);
            (t > 0.0).then_some((t, normal))
        });
        let (median, p90) = (a[a.len() / 2], a[a.len() * 90 / 100]);
        assert!(
            a.len() > 20 * 15 * 9 / 10,
            "{} of {} samples have a normal",
            a.len(),
            20 * 15
        );
        assert!(median < 4.0 && p90 < 8.0, "median {median:.2}°, 90th {p90:.2}°");
    }

    #[test]
    fn a_tilted_plane_gets_its_normal_everywhere() {
        let normal = DVec3::new(0.3, -0.5, -1.0).normalize();
        let point = DVec3::new(0.0, 0.0, 4.0);
        let (a, missing) = angles(|o, d| {
            let t = (point - o).dot(normal) / d.dot(normal);
            (t > 0.0).then_some((t, normal))
        });
        assert_eq!((a.len(), missing), (80 * 60, 0));
        assert!(a[a.len() - 1] < 0.05, "worst {:.3}°", a[a.len() - 1]);
    }

    /// Depth at one pixel in 16 (a depth grid of 4): every sample still gets its normal.
    #[test]
    fn a_coarse_depth_grid_gets_its_normals() {
        let normal = DVec3::new(0.3, -0.5, -1.0).normalize();
        let point = DVec3::new(0.0, 0.0, 4.0);
        let (a, missing) = angles_on_grid(4, |o, d| {
            let t = (point - o).dot(normal) / d.dot(normal);
            (t > 0.0).then_some((t, normal))
        });
        assert_eq!((a.len(), missing), (20 * 15, 0));
        assert!(a[a.len() - 1] < 0.05, "worst {:.3}°", a[a.len() - 1]);
    }

    /// A sphere in front of a wall: the normals match inside; at the silhouette the one-sided
    /// differences stay on their own surface (no normal bent across the depth edge).
    #[test]
    fn a_sphere_gets_its_normals_and_its_silhouette_no_bent_ones() {
        let (c, r) = (DVec3::new(0.0, 0.0, 5.0), 1.5);
        let wall = DVec3::new(0.0, 0.0, -1.0);
        let (a, missing) = angles(|o, d| {
            let oc = o - c;
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - r * r);
            let sphere = (disc >= 0.0).then(|| {
                let t = -b - disc.sqrt();
                (t, (o + d * t - c) / r)
            });
            sphere.or(Some(((9.0 - o.z) / d.z, wall)))
        });
        assert!(a.len() > 4500, "{} pixels", a.len());
        // The last ring of pixels before the silhouette turns by several degrees per pixel: its
        // one-sided differences are off by about half that.
        let (median, p90, worst) = (a[a.len() / 2], a[a.len() * 90 / 100], a[a.len() - 1]);
        let what = format!("median {median:.2}°, 90th {p90:.2}°, worst {worst:.2}°, missing {missing}");
        assert!(median < 0.5 && p90 < 3.0 && worst < 12.0, "{what}");
    }
}
