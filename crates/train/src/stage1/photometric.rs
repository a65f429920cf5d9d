//! Photometric rows of the pose alignment: a view is aligned to the fields as a camera is tracked
//! against a textured model (direct image alignment, as DTAM and DSO track): its pixel p sees the
//! surface point X where its corrected ray first crosses the SDF's zero set, the radiance field
//! gives X's colour c, and the pose should move so that the image, sampled where X then
//! projects, shows c. Depth points alone ([`super::pose_correction::PoseCorrection::align_view`])
//! hold a view only along the normals of the surfaces it sees: a view of one wall and the floor
//! can slide along both. The image's edges and texture hold it in the image plane.
//!
//! Linearized at the current pose, with v = X − c' (from the corrected camera centre) and u = v/|v|:
//! moving the camera by (δω, δτ) moves X, seen from the camera, by δv = −δτ − δω × v; the unit
//! direction by P δv / |v| (P = I − u uᵀ); the pixel by M P δv / |v| with M the pseudo-inverse of
//! the 3×2 derivative A of the ray direction over the pixel (taken from the neighbouring pixels'
//! rays, so the lens model is in it); and the image by g M P δv / |v|, g its gradient. With
//! q = g M P / |v|: ∂r/∂δτ = −q, ∂r/∂δω = q × v.

use super::pose_correction::cross;
use super::rays::TrainImage;

/// A view's image smoothed (a Gaussian of σ = 1 px) and its gradient per channel, in pixel units:
/// the linearization holds over about a pixel, so the gradient is taken on the smoothed image to
/// widen the basin past the poses' typical error (a pixel at the rooms' sizes).
pub struct ImageGradient {
    pub dx: Vec<[f32; 3]>,
    pub dy: Vec<[f32; 3]>,
}

/// The Gaussian's weights for σ = 1 px (radius 2).
const BLUR: [f32; 5] = [0.054_489, 0.244_201, 0.402_620, 0.244_201, 0.054_489];

impl ImageGradient {
    pub fn of(im: &TrainImage) -> Self {
        let (w, h) = (im.width, im.height);
        let blur = |src: &[[f32; 3]], along_x: bool| -> Vec<[f32; 3]> {
            let mut out = vec![[0.0f32; 3]; w * h];
            for y in 0..h {
                for x in 0..w {
                    let mut acc = [0.0f32; 3];
                    for (k, wk) in BLUR.iter().enumerate() {
                        let o = k as isize - 2;
                        let (sx, sy) = if along_x {
                            ((x as isize + o).clamp(0, w as isize - 1) as usize, y)
                        } else {
                            (x, (y as isize + o).clamp(0, h as isize - 1) as usize)
                        };
                        let s = src[sy * w + sx];
                        for c in 0..3 {
                            acc[c] += wk * s[c];
                        }
                    }
                    out[y * w + x] = acc;
                }
            }
            out
        };
        let smooth = blur(&blur(&im.rgb, true), false);
        let mut dx = vec![[0.0f32; 3]; w * h];
        let mut dy = vec![[0.0f32; 3]; w * h];
        for y in 0..h {
            for x in 0..w {
                let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
                let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
                for c in 0..3 {
                    dx[y * w + x][c] = (smooth[y * w + x1][c] - smooth[y * w + x0][c]) / (x1 - x0).max(1) as f32;
                    dy[y * w + x][c] = (smooth[y1 * w + x][c] - smooth[y0 * w + x][c]) / (y1 - y0).max(1) as f32;
                }
            }
        }
        ImageGradient { dx, dy }
    }

    /// The largest channel's gradient magnitude at a pixel (per pixel).
    pub fn strength(&self, pixel: usize) -> f32 {
        (0..3)
            .map(|c| self.dx[pixel][c].hypot(self.dy[pixel][c]))
            .fold(0.0, f32::max)
    }
}

/// One residual of the alignment: r + j·(δω, δτ) should be 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotoRow {
    pub j: [f32; 6],
    pub r: f32,
}

/// The three channels' rows of pixel `pixel` of `im`, which sees the surface point `x` (normalized
/// frame) of colour `colour`; `None` at the image's border or where the direction's derivative
/// over the pixel is degenerate.
pub fn photometric_rows(
    im: &TrainImage,
    gradient: &ImageGradient,
    pixel: usize,
    x: [f32; 3],
    colour: [f32; 3],
) -> Option<[PhotoRow; 3]> {
    let (w, h) = (im.width, im.height);
    let (px, py) = (pixel % w, pixel / w);
    if px == 0 || py == 0 || px + 1 >= w || py + 1 >= h {
        return None;
    }
    let (o, _) = im.ray(pixel);
    let v = [x[0] - o[0], x[1] - o[1], x[2] - o[2]];
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if len < 1e-6 {
        return None;
    }
    let u = v.map(|c| c / len);
    // A: the corrected direction's central differences over the pixel, one column per axis.
    let diff = |a: usize, b: usize| -> [f32; 3] {
        let (da, db) = (im.ray(a).1, im.ray(b).1);
        std::array::from_fn(|k| 0.5 * (db[k] - da[k]))
    };
    let ax = diff(pixel - 1, pixel + 1);
    let ay = diff(pixel - w, pixel + w);
    // M = (AᵀA)⁻¹Aᵀ.
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (a11, a12, a22) = (dot(ax, ax), dot(ax, ay), dot(ay, ay));
    let det = a11 * a22 - a12 * a12;
    if det <= 1e-12 * a11 * a22 || !det.is_finite() {
        return None;
    }
    let m_row = |c1: f32, c2: f32| -> [f32; 3] { std::array::from_fn(|k| (c1 * ax[k] + c2 * ay[k]) / det) };
    let mx = m_row(a22, -a12);
    let my = m_row(-a12, a11);
    // M P: each row minus its component along u.
    let project = |m: [f32; 3]| -> [f32; 3] {
        let s = dot(m, u);
        std::array::from_fn(|k| (m[k] - s * u[k]) / len)
    };
    let (mx, my) = (project(mx), project(my));
    let rgb = im.rgb[pixel];
    Some(std::array::from_fn(|c| {
        let (gx, gy) = (gradient.dx[pixel][c], gradient.dy[pixel][c]);
        let q: [f32; 3] = std::array::from_fn(|k| gx * mx[k] + gy * my[k]);
        let jw = cross(q, v);
        PhotoRow {
            j: [jw[0], jw[1], jw[2], -q[0], -q[1], -q[2]],
            r: rgb[c] - colour[c],
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{PoseConfig, PoseCorrectionMode};
    use crate::stage1::pose_correction::{rotate, rotation_matrix, PoseCorrection};

    /// A textured wall z = 1 seen by a pinhole camera at the origin: its colour at a point.
    fn texture(x: [f32; 3]) -> [f32; 3] {
        let a = (6.0 * x[0]).sin() * (5.0 * x[1]).cos();
        let b = (4.0 * x[0] + 7.0 * x[1]).sin();
        [0.5 + 0.2 * a, 0.5 + 0.15 * b, 0.4 + 0.1 * a + 0.1 * b]
    }

    /// Where a ray meets the wall z = 1.
    fn wall_hit(o: [f32; 3], d: [f32; 3]) -> [f32; 3] {
        let t = (1.0 - o[2]) / d[2];
        std::array::from_fn(|k| o[k] + t * d[k])
    }

    /// A 48×36 view (f = 40 px) whose image was taken at the true pose (the origin, looking
    /// along +z) but whose given pose is the truth turned by `err_w` about its centre and moved
    /// by `err_t`.
    fn view(err_w: [f32; 3], err_t: [f32; 3]) -> TrainImage {
        let (w, h, f) = (48usize, 36usize, 40.0f32);
        let true_dirs: Vec<[f32; 3]> = (0..w * h)
            .map(|p| {
                let (x, y) = (
                    (p % w) as f32 + 0.5 - w as f32 / 2.0,
                    (p / w) as f32 + 0.5 - h as f32 / 2.0,
                );
                let n = (x * x + y * y + f * f).sqrt();
                [x / n, y / n, f / n]
            })
            .collect();
        let rgb = true_dirs.iter().map(|d| texture(wall_hit([0.0; 3], *d))).collect();
        let r_err = rotation_matrix(err_w);
        TrainImage {
            frame_index: 0,
            width: w,
            height: h,
            origin: err_t,
            dirs: true_dirs.iter().map(|d| rotate(&r_err, *d)).collect(),
            cos: true_dirs.iter().map(|d| d[2]).collect(),
            rgb,
            depth: vec![0.0; w * h],
            normal: None,
            emitter: None,
            rotation: rotation_matrix([0.0; 3]),
            translation: [0.0; 3],
        }
    }

    /// The rows' Jacobian against a finite difference: a correction δ moves the pixel where the
    /// view sees the surface point X, and the image changes by its gradient times that move,
    /// which the rows must predict as j·δ (the pixel found by projecting X through the given
    /// camera turned and moved by δ).
    #[test]
    fn rows_match_a_finite_difference_of_the_projection() {
        let (err_w, err_t) = ([0.004f32, -0.003, 0.002], [0.003f32, 0.002, -0.004]);
        let im = view(err_w, err_t);
        let g = ImageGradient::of(&im);
        let transpose =
            |m: [[f32; 3]; 3]| -> [[f32; 3]; 3] { std::array::from_fn(|i| std::array::from_fn(|j| m[j][i])) };
        // The pixel (continuous, centres at +0.5) of X through the given camera corrected by δ.
        let pixel_of = |x: [f32; 3], delta: [f32; 6]| -> (f32, f32) {
            let rel = [
                x[0] - err_t[0] - delta[3],
                x[1] - err_t[1] - delta[4],
                x[2] - err_t[2] - delta[5],
            ];
            let r = rotation_matrix([delta[0], delta[1], delta[2]]);
            let local = rotate(&transpose(rotation_matrix(err_w)), rotate(&transpose(r), rel));
            (40.0 * local[0] / local[2] + 24.0, 40.0 * local[1] / local[2] + 18.0)
        };
        let eps = 1e-3f32;
        for p in [13 * 48 + 20, 20 * 48 + 30, 30 * 48 + 5, 3 * 48 + 44] {
            let (o, d) = im.ray(p);
            let x = wall_hit(o, d);
            let (px0, py0) = pixel_of(x, [0.0; 6]);
            assert!((px0 - ((p % 48) as f32 + 0.5)).abs() < 1e-3 && (py0 - ((p / 48) as f32 + 0.5)).abs() < 1e-3);
            let rows = photometric_rows(&im, &g, p, x, texture(x)).unwrap();
            for axis in 0..6 {
                let mut delta = [0.0f32; 6];
                delta[axis] = eps;
                let (px, py) = pixel_of(x, delta);
                for (c, row) in rows.iter().enumerate() {
                    let predicted: f32 = (0..6).map(|k| row.j[k] * delta[k]).sum();
                    let observed = g.dx[p][c] * (px - px0) + g.dy[p][c] * (py - py0);
                    assert!(
                        (predicted - observed).abs() < 0.02 * observed.abs() + 1e-6,
                        "pixel {p} axis {axis} channel {c}: {predicted} vs {observed}"
                    );
                }
            }
        }
    }

    /// Gauss–Newton on the photometric rows alone brings a view whose given pose is off by
    /// 0.6° and 1 cm back to the pose its image was taken at.
    #[test]
    fn photometric_alignment_recovers_the_pose() {
        let (err_w, err_t) = ([0.006f32, -0.008, 0.005], [0.01f32, -0.006, 0.008]);
        let mut im = view(err_w, err_t);
        let g = ImageGradient::of(&im);
        let config = PoseConfig {
            correction: PoseCorrectionMode::On,
            regularization: 0.0,
            photometric_weight: 1.0,
            ..Default::default()
        };
        let mut pc = PoseCorrection::standalone(config, vec![err_t]);
        for _ in 0..10 {
            (im.rotation, im.translation) = pc.transform(0);
            let mut rows = Vec::new();
            for p in 0..im.pixels() {
                let (o, d) = im.ray(p);
                let x = wall_hit(o, d);
                if let Some(r) = photometric_rows(&im, &g, p, x, texture(x)) {
                    rows.extend_from_slice(&r);
                }
            }
            pc.align_view_with(0, &[], &rows, 0.0, 0.1, 1.0);
        }
        let (r, t) = pc.transform(0);
        // The corrected centre is the true one (the origin), the corrected rotation identity.
        let centre: Vec<f32> = (0..3).map(|k| err_t[k] + t[k]).collect();
        let total = rotate(&r, rotate(&rotation_matrix(err_w), [0.3, 0.5, 0.81]));
        let rot_err: f32 = (0..3).map(|k| (total[k] - [0.3f32, 0.5, 0.81][k]).abs()).sum();
        assert!(centre.iter().all(|c| c.abs() < 1e-3), "centre {centre:?}");
        assert!(rot_err < 1e-3, "rotation error {rot_err}");
    }
}
