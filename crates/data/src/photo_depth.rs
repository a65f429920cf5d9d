//! Depth from the images where a depth sensor lost it: a plane sweep along the rays of the pixels
//! that no sensor sample covers, for thin things in front of a sensed background.
//!
//! A phone's depth grid is coarse (ARKit: 256×192 for 1920×1440 colour), and every sample whose
//! footprint straddles a depth edge is a flying pixel that the confidence map marks low and the
//! loader drops. A lamp pole or a table leg narrower than a grid cell therefore has no depth in
//! any view: stage 1 then has nothing to put a surface there, and the colour loss, whose
//! gradient vanishes a few β in front of the surface behind, cannot start one in empty space
//! (docs/results.md, "Why the thin objects stay out").
//!
//! The images see them. For each pixel without a sensor sample whose background (the farthest
//! sample within [`BACKGROUND_RADIUS_CELLS`] grid cells) is known, the pixel's colour is compared
//! with its neighbour views' colours at the points of its ray (multi-view photo-consistency,
//! the plane sweep of MVS restricted to one ray):
//! 1. Background test: the cost at the background's depth (the best within ±[`MIN_GAP`]). A
//!    pixel the background explains (cost under [`BACKGROUND_EXPLAINS`]) is left: most pixels stop
//!    here after one evaluation.
//! 2. Sweep: [`STEPS`] depths uniform in inverse depth, from [`NEAR_FRACTION`] of the background
//!    depth to (1 − [`MIN_GAP`]) of it, refined by a parabola through the best step and its two
//!    neighbours.
//! 3. Acceptance: the best cost under [`MAX_COST`], the background's at least [`MIN_RATIO`] times
//!    it, and no other depth (beyond two steps) within [`UNIQUENESS`] of it (a plain foreground's
//!    colour matches along a stretch of the ray: no depth then).
//! 4. Foreground: the depth lies at least [`MIN_GAP`] in front of every sensor sample within the
//!    background's radius ([`IN_FRONT`]), not only the farthest.
//!    Free space: no neighbour's kept sensor sample within [`SEE_THROUGH_RADIUS`] px of the
//!    point's projection lies more than [`MIN_GAP`] behind it (that sensor saw through the point).
//!    Kept samples are planar footprints, so a thin object's own neighbourhood never votes; a
//!    point floating in front of a sensed wall does.
//! 5. Fusion, once every view is swept: a depth stands where [`MIN_AGREEING`] of its neighbour
//!    views found the same point (within [`CONSISTENCY`] of their depth, a pixel around its
//!    projection). Without 4 and 5, 39 % of the depths found on the default room's phone capture
//!    lay within 2 cm of a true surface and the 90th percentile 31 cm off; with them 58 % and
//!    6 cm (docs/results.md, fifteenth session; thresholds chosen there with the probe
//!    `photo_depth_probe`).
//!
//! The cost of one depth is the colour difference (mean absolute over RGB, display values) to each
//! neighbour view's pixel there, the best of five positions 0.5 px apart (poses off by up to a
//! pixel, as a tracker's are), averaged over the better half of the views that see the point
//! inside their image (a view in which the point is hidden disagrees: the better half keeps the
//! others). Neighbour views are the [`NEIGHBOURS`] whose images hold most of the view's sensed
//! points, weighed by their baseline (a view from the same place sees no parallax).

use crate::camera::Camera;
use crate::imageio::ImageF32;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// Neighbour views compared per view.
pub const NEIGHBOURS: usize = 8;
/// Depth steps of the sweep.
pub const STEPS: usize = 64;
/// The sweep starts at this fraction of the background's depth.
pub const NEAR_FRACTION: f64 = 0.15;
/// A foreground lies at least this fraction of the background's depth in front of it.
pub const MIN_GAP: f64 = 0.08;
/// A pixel's background: the farthest sensor sample within this many grid cells.
pub const BACKGROUND_RADIUS_CELLS: f64 = 1.5;
/// The background explains a pixel whose cost there is under this (display values, 0–1).
pub const BACKGROUND_EXPLAINS: f32 = 0.03;
/// The best depth's cost must be under this.
pub const MAX_COST: f32 = 0.05;
/// … and the background's at least this many times it.
pub const MIN_RATIO: f32 = 2.5;
/// … and every depth more than two steps away from it above this many times it.
pub const UNIQUENESS: f32 = 1.5;
/// A neighbour's sample sees through a point projected within this many pixels of it.
pub const SEE_THROUGH_RADIUS: f64 = 0.5;
/// Another view's depth agrees within this fraction of it.
pub const CONSISTENCY: f64 = 0.03;
/// A depth found stands where this many of its neighbour views found the same point.
pub const MIN_AGREEING: usize = 2;
/// A neighbour view's baseline is at least this fraction of the mean sensed depth …
pub const MIN_BASELINE: f64 = 0.0;
/// … and counts in full from this fraction on (less parallax, less weight in the choice).
pub const FULL_BASELINE: f64 = 0.1;
/// A neighbour's colour is the best of its pixel and four positions this far away (pixels).
pub const SLACK: f64 = 0.5;
/// Views whose images see the point needed for a cost.
pub const MIN_VIEWS: usize = 3;
/// A depth found lies at least [`MIN_GAP`] in front of the nearest sensor sample within the
/// background's radius: the sweep is for a foreground the sensor lost, and a depth behind a
/// sample beside it is an edge of what the sensor saw (three quarters of the depths it found on
/// the phone captures without this, on the sofa's and shelves' edges, 17 % of them over 5 cm off)
/// or a reflection's virtual image. Stage 1 with it against without (one run each): test PSNR
/// +0.2 / +0.4 dB, F 0.956 / 0.952 (0.956 / 0.950), thin @ 2 cm 0.51 / 0.36 (0.48 / 0.37)
/// (docs/results.md, sixteenth session).
pub const IN_FRONT: bool = true;

/// The sweep's settings; [`PhotoDepthParams::default`] holds the constants above.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotoDepthParams {
    pub neighbours: usize,
    pub steps: usize,
    pub near_fraction: f64,
    pub min_gap: f64,
    pub background_radius_cells: f64,
    pub background_explains: f32,
    pub max_cost: f32,
    pub min_ratio: f32,
    pub uniqueness: f32,
    pub min_views: usize,
    pub see_through_radius: f64,
    pub consistency: f64,
    pub min_agreeing: usize,
    pub min_baseline: f64,
    pub full_baseline: f64,
    pub slack: f64,
    /// A depth found must lie in front of every sensor sample within the background's radius,
    /// not only the farthest ([`IN_FRONT`]).
    pub in_front: bool,
}

impl Default for PhotoDepthParams {
    fn default() -> Self {
        PhotoDepthParams {
            neighbours: NEIGHBOURS,
            steps: STEPS,
            near_fraction: NEAR_FRACTION,
            min_gap: MIN_GAP,
            background_radius_cells: BACKGROUND_RADIUS_CELLS,
            background_explains: BACKGROUND_EXPLAINS,
            max_cost: MAX_COST,
            min_ratio: MIN_RATIO,
            uniqueness: UNIQUENESS,
            min_views: MIN_VIEWS,
            see_through_radius: SEE_THROUGH_RADIUS,
            consistency: CONSISTENCY,
            min_agreeing: MIN_AGREEING,
            min_baseline: MIN_BASELINE,
            full_baseline: FULL_BASELINE,
            slack: SLACK,
            in_front: IN_FRONT,
        }
    }
}

/// One view as the sweep sees it: its camera (at the best poses known), LDR colour (3 channels)
/// and sensor z-depth (1 channel, world units, 0: none), all at the image's size.
#[derive(Clone, Copy, Debug)]
pub struct PhotoView<'a> {
    pub camera: &'a Camera,
    pub rgb: &'a ImageF32,
    pub depth: &'a ImageF32,
}

impl<'a> PhotoView<'a> {
    /// A dataset frame's view at its given pose; `None` without depth.
    pub fn of(frame: &'a crate::dataset::Frame) -> Option<Self> {
        Some(PhotoView {
            camera: &frame.camera,
            rgb: &frame.rgb,
            depth: frame.depth.as_ref()?,
        })
    }
}

/// What the sweep found in one view.
#[derive(Clone, Debug)]
pub struct PhotoDepth {
    /// z-depth at the image's pixels (world units), 0 where none was found.
    pub depth: ImageF32,
    /// Pixels swept (past the background test) and pixels given a depth.
    pub swept: usize,
    pub found: usize,
    /// Per pixel, what the sweep made of it ([`Outcome`] as u8).
    pub outcome: Vec<u8>,
}

/// What the sweep made of one pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Outcome {
    Sensed = 0,
    NoBackground = 1,
    TooFewViews = 2,
    BackgroundExplains = 3,
    CostTooHigh = 4,
    RatioTooLow = 5,
    NotUnique = 6,
    SeenThrough = 7,
    Unconfirmed = 8,
    Found = 9,
}

/// One neighbour view, set up for the reference view `cam`: a point `z · d` along the reference
/// pixel's camera-space direction `d` lies at `m·d·z + b` in the neighbour's camera space.
struct Neighbour<'a> {
    cam: &'a Camera,
    rgb: &'a ImageF32,
    m: DMat3,
    b: DVec3,
    /// Its sensor depth, and how near a sample a point must project to be seen through (pixels).
    depth: &'a ImageF32,
    half_cell: f64,
}

/// The sensor grid's spacing in a depth map's image pixels, from the share of pixels with a
/// sample (the loader maps each kept sample onto one pixel); `None` without samples.
fn grid_cell(depth: &ImageF32) -> Option<f64> {
    let sensed = depth.data.iter().filter(|z| **z > 0.0).count();
    (sensed > 0).then(|| ((depth.width * depth.height) as f64 / sensed as f64).sqrt())
}

impl Neighbour<'_> {
    /// Whether the neighbour's sensor saw through the point at z-depth `z` along `dir`: a kept
    /// sample whose footprint holds the point's projection lies more than `gap` (relative) behind
    /// it. Kept samples are planar footprints (an edge's are dropped as low confidence), so a
    /// thin object's own neighbourhood never votes; a point floating in front of a sensed wall
    /// does.
    fn sees_through(&self, dir: DVec3, z: f64, gap: f64) -> bool {
        let depth = self.depth;
        let pc = self.m * dir * z + self.b;
        if pc.z <= 1e-6 {
            return false;
        }
        let (u, v) = self.cam.project_camera_space(pc);
        let r = self.half_cell;
        let (x0, x1) = (
            (u - r).floor().max(0.0) as usize,
            ((u + r).ceil() as usize).min(depth.width),
        );
        let (y0, y1) = (
            (v - r).floor().max(0.0) as usize,
            ((v + r).ceil() as usize).min(depth.height),
        );
        (y0..y1).any(|y| {
            (x0..x1).any(|x| {
                let d = depth.data[y * depth.width + x] as f64;
                d > 0.0
                    && ((x as f64 + 0.5 - u).abs() <= r && (y as f64 + 0.5 - v).abs() <= r)
                    && d > pc.z * (1.0 + gap)
            })
        })
    }
}

/// Photometric depth for every training view in `views` (indices into `frames`, which all serve as
/// neighbours): per view `None` where it has no sensor depth to take a background from.
pub fn photo_depth(frames: &[PhotoView], views: &[usize], p: &PhotoDepthParams) -> Vec<Option<PhotoDepth>> {
    let mut swept: Vec<Option<(PhotoDepth, Vec<usize>)>> = (0..frames.len())
        .into_par_iter()
        .map(|i| photo_depth_view(frames, i, p))
        .collect();
    // Fusion: a depth stands where other views found the same point (within
    // `consistency` of their own depth, a pixel around its projection).
    let keep: Vec<Option<Vec<bool>>> = (0..frames.len())
        .into_par_iter()
        .map(|i| {
            let (pd, ns) = swept[i].as_ref()?;
            let cam = &frames[i].camera;
            let w = cam.width;
            Some(
                pd.depth
                    .data
                    .iter()
                    .enumerate()
                    .map(|(px, &z)| {
                        if z <= 0.0 {
                            return false;
                        }
                        let x = cam.backproject(px % w, px / w, z as f64);
                        let agree = ns
                            .iter()
                            .filter(|&&j| {
                                let Some((pj, _)) = &swept[j] else { return false };
                                let Some((u, v, zj)) = frames[j].camera.project(x) else {
                                    return false;
                                };
                                let d = &pj.depth;
                                let (cu, cv) = (u.floor() as isize, v.floor() as isize);
                                (cv - 1..=cv + 1).any(|yy| {
                                    (cu - 1..=cu + 1).any(|xx| {
                                        if xx < 0 || yy < 0 || xx as usize >= d.width || yy as usize >= d.height {
                                            return false;
                                        }
                                        let f = d.data[yy as usize * d.width + xx as usize] as f64;
                                        f > 0.0 && (f - zj).abs() <= p.consistency * zj
                                    })
                                })
                            })
                            .count();
                        agree >= p.min_agreeing
                    })
                    .collect(),
            )
        })
        .collect();
    for (s, k) in swept.iter_mut().zip(keep) {
        if let (Some((pd, _)), Some(k)) = (s.as_mut(), k) {
            for (px, keep) in k.into_iter().enumerate() {
                if pd.depth.data[px] > 0.0 && !keep {
                    pd.depth.data[px] = 0.0;
                    pd.outcome[px] = Outcome::Unconfirmed as u8;
                    pd.found -= 1;
                }
            }
        }
    }
    let mut swept: Vec<Option<PhotoDepth>> = swept.into_iter().map(|s| s.map(|(pd, _)| pd)).collect();
    views.iter().map(|&i| swept[i].take()).collect()
}

/// The sensed points of a view (world space), every `stride`-th sample.
fn sensed_points(frame: &PhotoView, stride: usize) -> Vec<DVec3> {
    let depth = frame.depth;
    let w = depth.width;
    depth
        .data
        .iter()
        .enumerate()
        .filter(|(_, z)| **z > 0.0)
        .step_by(stride.max(1))
        .map(|(p, z)| frame.camera.backproject(p % w, p / w, *z as f64))
        .collect()
}

/// The [`NEIGHBOURS`] views of `frames[i]` that see most of its sensed points, weighed by baseline.
fn neighbours(frames: &[PhotoView], i: usize, p: &PhotoDepthParams) -> Vec<usize> {
    let points = sensed_points(&frames[i], 1);
    let step = (points.len() / 256).max(1);
    let probe: Vec<DVec3> = points.iter().step_by(step).copied().collect();
    if probe.is_empty() {
        return Vec::new();
    }
    let centre = frames[i].camera.center();
    let mean_depth = probe.iter().map(|q| (*q - centre).length()).sum::<f64>() / probe.len() as f64;
    let mut scored: Vec<(f64, usize)> = (0..frames.len())
        .filter(|&j| j != i)
        .filter_map(|j| {
            let cam = &frames[j].camera;
            let seen = probe
                .iter()
                .filter(|q| {
                    cam.project(**q)
                        .is_some_and(|(u, v, _)| u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64)
                })
                .count() as f64
                / probe.len() as f64;
            let baseline = (cam.center() - centre).length() / mean_depth;
            (seen >= 0.2 && baseline >= p.min_baseline).then_some((seen * (baseline / p.full_baseline).min(1.0), j))
        })
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored.into_iter().take(p.neighbours).map(|(_, j)| j).collect()
}

/// Bilinear sample of a 3-channel image at continuous position (u, v) (pixel centres at +0.5);
/// `None` outside the image's centres.
fn bilinear(im: &ImageF32, u: f64, v: f64) -> Option<[f32; 3]> {
    let x = u - 0.5;
    let y = v - 0.5;
    if x < 0.0 || y < 0.0 || x > (im.width - 1) as f64 || y > (im.height - 1) as f64 {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(im.width - 1), (y0 + 1).min(im.height - 1));
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let mut out = [0.0f32; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let at = |xx: usize, yy: usize| im.data[(yy * im.width + xx) * im.channels + c];
        *o =
            (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy) + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy;
    }
    Some(out)
}

/// The photo-consistency cost of the point at z-depth `z` along camera-space direction `dir` of a
/// pixel of colour `colour`; `None` where fewer than [`MIN_VIEWS`] views see it.
fn cost(
    neighbours: &[Neighbour],
    dir: DVec3,
    z: f64,
    colour: [f32; 3],
    scratch: &mut Vec<f32>,
    p: &PhotoDepthParams,
) -> Option<f32> {
    scratch.clear();
    for n in neighbours {
        let pc = n.m * dir * z + n.b;
        if pc.z <= 1e-6 {
            continue;
        }
        let (u, v) = n.cam.project_camera_space(pc);
        let mut best = f32::INFINITY;
        let k = p.slack;
        for (du, dv) in [(0.0, 0.0), (k, 0.0), (-k, 0.0), (0.0, k), (0.0, -k)] {
            if let Some(c) = bilinear(n.rgb, u + du, v + dv) {
                let d = ((c[0] - colour[0]).abs() + (c[1] - colour[1]).abs() + (c[2] - colour[2]).abs()) / 3.0;
                best = best.min(d);
            }
        }
        if best.is_finite() {
            scratch.push(best);
        }
    }
    if scratch.len() < p.min_views {
        return None;
    }
    scratch.sort_by(f32::total_cmp);
    let keep = (scratch.len() / 2).max(p.min_views - 1);
    Some(scratch[..keep].iter().sum::<f32>() / keep as f32)
}

/// The sweep for one view.
fn photo_depth_view(frames: &[PhotoView], i: usize, p: &PhotoDepthParams) -> Option<(PhotoDepth, Vec<usize>)> {
    let frame = &frames[i];
    let depth = frame.depth;
    let cam = &frame.camera;
    let (w, h) = (cam.width, cam.height);
    let cell = grid_cell(depth)?;
    let radius = (p.background_radius_cells * cell).ceil() as isize;
    let r_i = cam.rotation();
    let chosen = neighbours(frames, i, p);
    let ns: Vec<Neighbour> = chosen
        .iter()
        .map(|&j| j)
        .map(|j| {
            let cj = &frames[j].camera;
            let r_jt = cj.rotation().transpose();
            Neighbour {
                cam: cj,
                rgb: frames[j].rgb,
                m: r_jt * r_i,
                b: r_jt * (cam.center() - cj.center()),
                depth: frames[j].depth,
                half_cell: p.see_through_radius,
            }
        })
        .collect();
    let mut out = ImageF32::new(w, h, 1);
    if ns.len() < p.min_views {
        return Some((
            PhotoDepth {
                depth: out,
                swept: 0,
                found: 0,
                outcome: vec![Outcome::TooFewViews as u8; w * h],
            },
            chosen,
        ));
    }
    let rows: Vec<(Vec<f32>, Vec<u8>, usize, usize)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut row = vec![0.0f32; w];
            let mut what = vec![Outcome::Sensed as u8; w];
            let (mut swept, mut found) = (0, 0);
            let mut scratch = Vec::with_capacity(p.neighbours);
            let mut costs = vec![f32::INFINITY; p.steps];
            for x in 0..w {
                if depth.data[y * w + x] > 0.0 {
                    continue;
                }
                let (mut background, mut nearest) = (0.0f32, f32::INFINITY);
                for yy in (y as isize - radius).max(0)..=(y as isize + radius).min(h as isize - 1) {
                    for xx in (x as isize - radius).max(0)..=(x as isize + radius).min(w as isize - 1) {
                        let d = depth.data[yy as usize * w + xx as usize];
                        background = background.max(d);
                        if d > 0.0 {
                            nearest = nearest.min(d);
                        }
                    }
                }
                if background <= 0.0 {
                    what[x] = Outcome::NoBackground as u8;
                    continue;
                }
                let zb = background as f64;
                let dir = cam.pixel_center_dir_cam(x, y);
                let px = frame.rgb.pixel(x, y);
                let colour = [px[0], px[1], px[2]];
                let bg_cost = [1.0 - p.min_gap, 1.0, 1.0 + p.min_gap]
                    .iter()
                    .filter_map(|s| cost(&ns, dir, zb * s, colour, &mut scratch, p))
                    .fold(f32::INFINITY, f32::min);
                if !bg_cost.is_finite() {
                    what[x] = Outcome::TooFewViews as u8;
                    continue;
                }
                if bg_cost < p.background_explains {
                    what[x] = Outcome::BackgroundExplains as u8;
                    continue;
                }
                swept += 1;
                let (inv_near, inv_far) = (1.0 / (p.near_fraction * zb), 1.0 / ((1.0 - p.min_gap) * zb));
                let inv = |k: f64| inv_near + (inv_far - inv_near) * k / (p.steps - 1) as f64;
                for (k, c) in costs.iter_mut().enumerate() {
                    *c = cost(&ns, dir, 1.0 / inv(k as f64), colour, &mut scratch, p).unwrap_or(f32::INFINITY);
                }
                let (best, &c_best) = costs.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).unwrap();
                if !(c_best < p.max_cost) {
                    what[x] = Outcome::CostTooHigh as u8;
                    continue;
                }
                if bg_cost < p.min_ratio * c_best {
                    what[x] = Outcome::RatioTooLow as u8;
                    continue;
                }
                let unique = costs
                    .iter()
                    .enumerate()
                    .all(|(k, c)| k.abs_diff(best) <= 2 || *c >= p.uniqueness * c_best);
                if !unique {
                    what[x] = Outcome::NotUnique as u8;
                    continue;
                }
                let z_best = 1.0 / inv(best as f64);
                // Behind a sample of its own view's, or in front of a neighbour's that lies behind
                // it: a sensor saw past the point.
                let behind_own = p.in_front && z_best > (1.0 - p.min_gap) * nearest as f64;
                if behind_own || ns.iter().any(|n| n.sees_through(dir, z_best, p.min_gap)) {
                    what[x] = Outcome::SeenThrough as u8;
                    continue;
                }
                // Parabola through the best step and its neighbours, in steps.
                let mut k = best as f64;
                if best > 0 && best + 1 < p.steps {
                    let (a, b, c) = (costs[best - 1], c_best, costs[best + 1]);
                    let denom = a - 2.0 * b + c;
                    if a.is_finite() && c.is_finite() && denom > 1e-9 {
                        k += (0.5 * (a - c) / denom).clamp(-0.5, 0.5) as f64;
                    }
                }
                row[x] = (1.0 / inv(k)) as f32;
                what[x] = Outcome::Found as u8;
                found += 1;
            }
            (row, what, swept, found)
        })
        .collect();
    let (mut swept, mut found, mut outcome) = (0, 0, Vec::with_capacity(w * h));
    for (y, (row, what, s, f)) in rows.into_iter().enumerate() {
        out.data[y * w..(y + 1) * w].copy_from_slice(&row);
        outcome.extend(what);
        swept += s;
        found += f;
    }
    Some((
        PhotoDepth {
            depth: out,
            swept,
            found,
            outcome,
        },
        chosen,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::look_at;

    /// A textured wall at z = 3 and a thin bar of one colour at z = 2 in front of it (x ∈
    /// [−0.02, 0.02], all y), seen by cameras along x at z = 0 looking down +z.
    fn scene_hit(o: DVec3, d: DVec3) -> (f64, [f32; 3]) {
        let t_bar = (2.0 - o.z) / d.z;
        let xb = o.x + t_bar * d.x;
        if xb.abs() <= 0.02 {
            return (t_bar, [0.9, 0.1, 0.1]);
        }
        let t = (3.0 - o.z) / d.z;
        let p = o + t * d;
        // A smooth but non-repeating texture (no two wall points alike along a ray's sweep).
        let v = |a: f64| (0.5 + 0.4 * (a).sin()) as f32;
        (
            t,
            [
                v(7.0 * p.x + 3.0 * p.y),
                v(5.0 * p.y - 11.0 * p.x),
                v(13.0 * p.x * p.y + 2.0 * p.x),
            ],
        )
    }

    /// Renders a view: colour everywhere, and a sensor depth on every fourth pixel that drops the
    /// samples whose 4×4 footprint touches the bar (a flying pixel, low confidence).
    fn render(cam: &Camera) -> (ImageF32, ImageF32, Vec<bool>) {
        let (w, h) = (cam.width, cam.height);
        let mut rgb = ImageF32::new(w, h, 3);
        let mut depth = ImageF32::new(w, h, 1);
        let mut bar = vec![false; w * h];
        let mut z_of = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (o, d, cos) = cam.ray(x as f64 + 0.5, y as f64 + 0.5);
                let (t, c) = scene_hit(o, d);
                rgb.pixel_mut(x, y).copy_from_slice(&c);
                z_of[y * w + x] = (t * cos) as f32;
                bar[y * w + x] = c == [0.9, 0.1, 0.1];
            }
        }
        for y in (2..h).step_by(4) {
            for x in (2..w).step_by(4) {
                let touches = (y.saturating_sub(2)..(y + 2).min(h))
                    .any(|yy| (x.saturating_sub(2)..(x + 2).min(w)).any(|xx| bar[yy * w + xx]));
                if !touches {
                    depth.data[y * w + x] = z_of[y * w + x];
                }
            }
        }
        (rgb, depth, bar)
    }

    /// The bar the sensor lost is found from the images, within a few centimetres, on most of
    /// its pixels; no wall pixel gets a depth.
    /// Seven cameras along x looking at the wall, each with its rendering.
    fn bar_scene() -> (Vec<Camera>, Vec<(ImageF32, ImageF32, Vec<bool>)>) {
        let cams: Vec<Camera> = (0..7)
            .map(|k| {
                let eye = DVec3::new(-0.6 + 0.2 * k as f64, 0.05 * (k % 3) as f64, 0.0);
                let mut c = Camera::from_opengl_c2w(96, 72, 80.0, 80.0, 48.0, 36.0, glam::DMat4::IDENTITY);
                c.c2w = look_at(eye, DVec3::new(0.0, 0.0, 3.0), DVec3::new(0.0, -1.0, 0.0));
                c
            })
            .collect();
        let rendered = cams.iter().map(render).collect();
        (cams, rendered)
    }

    #[test]
    fn a_thin_bar_the_sensor_lost_is_found_and_the_wall_is_left() {
        let (cams, rendered) = bar_scene();
        let views: Vec<PhotoView> = cams
            .iter()
            .zip(&rendered)
            .map(|(camera, (rgb, depth, _))| PhotoView { camera, rgb, depth })
            .collect();
        let found = photo_depth(&views, &[3], &PhotoDepthParams::default());
        let pd = found[0].as_ref().expect("the view has depth");
        let (_, _, bar) = &rendered[3];
        let cam = &cams[3];
        let (mut bar_pixels, mut bar_found, mut bar_right) = (0, 0, 0);
        for (p, &z) in pd.depth.data.iter().enumerate() {
            if bar[p] {
                bar_pixels += 1;
                if z > 0.0 {
                    bar_found += 1;
                    let (_, _, cos) = cam.ray((p % cam.width) as f64 + 0.5, (p / cam.width) as f64 + 0.5);
                    bar_right += ((z as f64 / cos - 2.0 / cos).abs() < 0.05) as usize;
                }
            } else {
                assert_eq!(z, 0.0, "a wall pixel got depth {z} (pixel {p})");
            }
        }
        assert!(bar_pixels > 100, "{bar_pixels}");
        assert!(
            bar_found * 2 > bar_pixels,
            "found {bar_found} of the bar's {bar_pixels} pixels"
        );
        assert_eq!(bar_right, bar_found, "a bar pixel's depth off by over 5 cm");
        assert_eq!(pd.found, bar_found);
    }

    /// [`IN_FRONT`]: a depth found must lie in front of the *nearest* sensor sample around it.
    /// The swept view's samples just left of the bar are set nearer than the bar (1.5 against
    /// 2, as the edge of something the sensor saw would be), the wall's samples to its right
    /// kept: the background and so the sweep are unchanged, and without the rule the bar is
    /// found as before; with it every bar pixel is rejected as seen through.
    #[test]
    fn a_depth_behind_a_nearer_sample_beside_it_is_rejected() {
        let (cams, mut rendered) = bar_scene();
        let w = cams[3].width;
        let (_, depth, bar) = &mut rendered[3];
        let mut injected = 0;
        for p in 0..depth.data.len() {
            let (x, y) = (p % w, p / w);
            // A bar pixel 1–6 columns to the right of this sample, in its row.
            let left_of_bar = (x + 1..(x + 7).min(w)).any(|xx| bar[y * w + xx]);
            if depth.data[p] > 0.0 && left_of_bar {
                depth.data[p] = 1.5;
                injected += 1;
            }
        }
        assert!(injected > 10, "{injected} samples set nearer");
        let views: Vec<PhotoView> = cams
            .iter()
            .zip(&rendered)
            .map(|(camera, (rgb, depth, _))| PhotoView { camera, rgb, depth })
            .collect();
        let bar = &rendered[3].2;
        let count = |in_front: bool| {
            let params = PhotoDepthParams {
                in_front,
                ..PhotoDepthParams::default()
            };
            let found = photo_depth(&views, &[3], &params);
            let pd = found[0].as_ref().expect("the view has depth");
            let on_bar = |o: Outcome| (0..bar.len()).filter(|&p| bar[p] && pd.outcome[p] == o as u8).count();
            (on_bar(Outcome::Found), on_bar(Outcome::SeenThrough))
        };
        let bar_pixels = bar.iter().filter(|b| **b).count();
        let (found_off, _) = count(false);
        let (found_on, seen_on) = count(true);
        assert!(
            found_off * 2 > bar_pixels,
            "without the rule {found_off} of {bar_pixels} bar pixels found"
        );
        assert_eq!(found_on, 0, "with the rule a bar pixel behind a nearer sample was kept");
        assert!(
            seen_on >= found_off,
            "with the rule {seen_on} bar pixels seen through, {found_off} found without"
        );
    }
}
