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
//! 6. Edge support, for what the colours cannot place (a leg of its wall's grey, a pole blended
//!    into one pixel): where the sensor has a confidence map, a pixel inside the footprint of a
//!    sample it marked low is placed where the other views' low-confidence footprints meet along
//!    its ray (a sensor marks low every sample whose footprint straddles a depth edge, so a thin
//!    object leaves a trail of them in every view that sees it), less the views whose sensor saw
//!    through the point; the peak must stand [`EDGE_CONTRAST`] above the background's own
//!    support (a region low in every view, a shelf of books, supports every depth before it
//!    alike), and the colour cost refines it within [`EDGE_WINDOW`], at most 1/[`EDGE_MIN_RATIO`]
//!    of the background's there (the wall pixels that share a leg's footprints keep the wall).
//!    These depths go through the fusion of step 5 like the others. On the seed-1 phone capture
//!    at a run's corrected poses it gives the side table's legs 339 pixels (228 within 2 cm of
//!    them) where the colours gave 4, the lamp pole 88 (61) where they gave none
//!    (docs/results.md, eighteenth session).
//! 7. Clearing, after the fusion: an edge depth within [`EDGE_CLEAR_RADIUS`] pixels of at least
//!    [`EDGE_CLEAR_COUNT`] depths the colours found at about its depth ([`EDGE_CLEAR_DEPTH`]) is
//!    dropped. The footprints are a grid cell wide, so around an object the colours see whole
//!    (a chandelier's globe) the edge support rings it with depths whose rays pass it by, a
//!    halo that inflates it; a line of one pixel (a leg, a pole) has few colour finds to clear
//!    it. On the seed-1 capture the globes' halo falls from 172 pixels to 40, the side table's
//!    legs keep 337 of their 349 depths (docs/results.md, nineteenth session).
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

mod edge;
use edge::{clear_edges_near_colour, footprint_depth, EdgeView};

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

/// Edge support: a pixel in the footprint of a sample its sensor marked low confidence, which the
/// colours did not place, is placed where the most other views' low-confidence footprints meet
/// along its ray, less the views whose sensor saw through the point (step 6 of the module's doc);
/// this many at least (0: off).
pub const EDGE_MIN_SUPPORT: i32 = 3;
/// Steps of the edge-support sweep (uniform in inverse depth, over the colour sweep's range).
pub const EDGE_STEPS: usize = 128;
/// The edge support's peak is refined by the colour cost within this fraction of its depth.
pub const EDGE_WINDOW: f64 = 0.04;
/// The peak's support exceeds the background's by at least this much.
pub const EDGE_CONTRAST: i32 = 2;
/// The colour cost at the background is at least this many times the edge depth's.
pub const EDGE_MIN_RATIO: f32 = 1.5;
/// A view whose sensor saw through a point counts this much against it, half a view that marks
/// it: a sensor's point samples miss an object thinner than their spacing (the seed-1 capture's
/// lamp pole: about as many views see through its true position as mark it). Without the
/// clearing of step 7, half weight cost seed 0's F (0.947); with it, stage 1 + 2 of the seed-0
/// and seed-1 captures give thin @ 2 cm 0.571 / 0.427 and F 0.955 / 0.942 at 1, 0.563 / 0.510
/// and F 0.952 / 0.950 at 0.5 (docs/results.md, nineteenth session; single runs, whose F
/// spreads by ±0.005).
pub const EDGE_THROUGH_WEIGHT: f32 = 0.5;
/// A view's kept sample this much (relative) behind a point saw through it.
pub const EDGE_SEEN_THROUGH: f64 = 0.05;
/// Clearing (step 7 of the module's doc): an edge depth with [`EDGE_CLEAR_COUNT`] depths the
/// colours found within this many pixels (0: off) … At 3 rather than 2 the seed-1 capture's
/// globes keep a halo of 23 edge pixels instead of 45 and the lamp pole 109 of its 117 close
/// depths; with stage 1's drop of what the field explains, four runs of stage 1 + 2 on the two
/// captures gave F 0.949–0.955 and thin @ 2 cm 0.50–0.62 (docs/results.md, twentieth session).
pub const EDGE_CLEAR_RADIUS: usize = 3;
/// … at most this fraction nearer or farther than it is dropped.
pub const EDGE_CLEAR_DEPTH: f64 = 0.1;
/// … this many at least.
pub const EDGE_CLEAR_COUNT: usize = 3;

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
    /// [`EDGE_MIN_SUPPORT`], [`EDGE_STEPS`], [`EDGE_WINDOW`], [`EDGE_SEEN_THROUGH`], …,
    /// [`EDGE_CLEAR_RADIUS`], [`EDGE_CLEAR_DEPTH`], [`EDGE_CLEAR_COUNT`].
    pub edge_min_support: i32,
    pub edge_steps: usize,
    pub edge_window: f64,
    pub edge_seen_through: f64,
    pub edge_contrast: i32,
    pub edge_min_ratio: f32,
    pub edge_through_weight: f32,
    pub edge_clear_radius: usize,
    pub edge_clear_depth: f64,
    pub edge_clear_count: usize,
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
            edge_min_support: EDGE_MIN_SUPPORT,
            edge_steps: EDGE_STEPS,
            edge_window: EDGE_WINDOW,
            edge_seen_through: EDGE_SEEN_THROUGH,
            edge_contrast: EDGE_CONTRAST,
            edge_min_ratio: EDGE_MIN_RATIO,
            edge_through_weight: EDGE_THROUGH_WEIGHT,
            edge_clear_radius: EDGE_CLEAR_RADIUS,
            edge_clear_depth: EDGE_CLEAR_DEPTH,
            edge_clear_count: EDGE_CLEAR_COUNT,
        }
    }
}

/// One view as the sweep sees it: its camera (at the best poses known), LDR colour (3 channels)
/// and sensor z-depth (1 channel, world units, 0: none), all at the image's size; where the
/// sensor has a confidence map, `low` is 1 over the footprints of the samples it marked low (see
/// [`crate::dataset::Frame::depth_low`]).
#[derive(Clone, Copy, Debug)]
pub struct PhotoView<'a> {
    pub camera: &'a Camera,
    pub rgb: &'a ImageF32,
    pub depth: &'a ImageF32,
    pub low: Option<&'a ImageF32>,
}

impl<'a> PhotoView<'a> {
    /// A dataset frame's view at its given pose; `None` without depth.
    pub fn of(frame: &'a crate::dataset::Frame) -> Option<Self> {
        Some(PhotoView {
            camera: &frame.camera,
            rgb: &frame.rgb,
            depth: frame.depth.as_ref()?,
            low: frame.depth_low.as_ref(),
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
    /// Placed by the low-confidence footprints ([`EDGE_MIN_SUPPORT`]).
    FoundAtEdge = 10,
    /// Placed by the low-confidence footprints, then dropped as the rim of what the colours
    /// found ([`EDGE_CLEAR_RADIUS`]).
    Cleared = 11,
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

/// The map from `from`'s camera space to `to`'s: a point `z · d` along a camera-space direction
/// `d` of `from` lies at `m·d·z + b` in `to`'s camera space.
fn camera_to_camera(from: &Camera, to: &Camera) -> (DMat3, DVec3) {
    let r_to = to.rotation().transpose();
    (r_to * from.rotation(), r_to * (from.center() - to.center()))
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
    // Each kept sample spread over its footprint, for the edge support's see-through test.
    let footprints: Vec<Option<ImageF32>> = frames
        .par_iter()
        .map(|f| {
            let cell = grid_cell(f.depth)?;
            (p.edge_min_support > 0 && f.low.is_some()).then(|| footprint_depth(f.depth, cell))
        })
        .collect();
    let mut swept: Vec<Option<(PhotoDepth, Vec<usize>)>> = (0..frames.len())
        .into_par_iter()
        .map(|i| photo_depth_view(frames, &footprints, i, p))
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
    // After the fusion, so that the depths it drops still confirm the other views'.
    swept.par_iter_mut().flatten().for_each(|(pd, _)| {
        pd.found -= clear_edges_near_colour(&mut pd.depth, &mut pd.outcome, p);
    });
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

/// One pixel's ray: its camera-space direction, colour, background (the farthest sensor sample
/// around it) and the nearest sample around it (z-depths).
struct Ray {
    dir: DVec3,
    colour: [f32; 3],
    background: f64,
    nearest: f64,
}

impl Ray {
    /// The colour sweep (steps 1–4 of the module's doc): the depth found, or why none; and whether
    /// the pixel got past the background test. `bg_cost`: [`Ray::background_cost`].
    fn by_colour(
        &self,
        ns: &[Neighbour],
        bg_cost: f32,
        costs: &mut [f32],
        scratch: &mut Vec<f32>,
        p: &PhotoDepthParams,
    ) -> (Result<f64, Outcome>, bool) {
        let (dir, colour, zb) = (self.dir, self.colour, self.background);
        if !bg_cost.is_finite() {
            return (Err(Outcome::TooFewViews), false);
        }
        if bg_cost < p.background_explains {
            return (Err(Outcome::BackgroundExplains), false);
        }
        let (inv_near, inv_far) = (1.0 / (p.near_fraction * zb), 1.0 / ((1.0 - p.min_gap) * zb));
        let inv = |k: f64| inv_near + (inv_far - inv_near) * k / (p.steps - 1) as f64;
        for (k, c) in costs.iter_mut().enumerate() {
            *c = cost(ns, dir, 1.0 / inv(k as f64), colour, scratch, p).unwrap_or(f32::INFINITY);
        }
        let (best, &c_best) = costs.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).unwrap();
        if !(c_best < p.max_cost) {
            return (Err(Outcome::CostTooHigh), true);
        }
        if bg_cost < p.min_ratio * c_best {
            return (Err(Outcome::RatioTooLow), true);
        }
        let unique = costs
            .iter()
            .enumerate()
            .all(|(k, c)| k.abs_diff(best) <= 2 || *c >= p.uniqueness * c_best);
        if !unique {
            return (Err(Outcome::NotUnique), true);
        }
        let z_best = 1.0 / inv(best as f64);
        // Behind a sample of its own view's, or in front of a neighbour's that lies behind it: a
        // sensor saw past the point.
        if self.behind_own(z_best, p) || ns.iter().any(|n| n.sees_through(dir, z_best, p.min_gap)) {
            return (Err(Outcome::SeenThrough), true);
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
        (Ok(1.0 / inv(k)), true)
    }

    /// The colour cost at the background: the best within ±`min_gap` of its depth; infinite
    /// where too few views see it.
    fn background_cost(&self, ns: &[Neighbour], scratch: &mut Vec<f32>, p: &PhotoDepthParams) -> f32 {
        [1.0 - p.min_gap, 1.0, 1.0 + p.min_gap]
            .iter()
            .filter_map(|s| cost(ns, self.dir, self.background * s, self.colour, scratch, p))
            .fold(f32::INFINITY, f32::min)
    }

    /// Whether a depth lies behind the nearest sample around the pixel ([`IN_FRONT`]).
    fn behind_own(&self, z: f64, p: &PhotoDepthParams) -> bool {
        p.in_front && z > (1.0 - p.min_gap) * self.nearest
    }
}

/// The sweep for one view.
fn photo_depth_view(
    frames: &[PhotoView],
    footprints: &[Option<ImageF32>],
    i: usize,
    p: &PhotoDepthParams,
) -> Option<(PhotoDepth, Vec<usize>)> {
    let frame = &frames[i];
    let depth = frame.depth;
    let cam = &frame.camera;
    let (w, h) = (cam.width, cam.height);
    let cell = grid_cell(depth)?;
    let radius = (p.background_radius_cells * cell).ceil() as isize;
    let chosen = neighbours(frames, i, p);
    let ns: Vec<Neighbour> = chosen
        .iter()
        .map(|&j| {
            let (m, b) = camera_to_camera(cam, frames[j].camera);
            Neighbour {
                cam: frames[j].camera,
                rgb: frames[j].rgb,
                m,
                b,
                depth: frames[j].depth,
                half_cell: p.see_through_radius,
            }
        })
        .collect();
    // Every other view with a confidence map, for the edge support.
    let own_low = frame.low.filter(|_| p.edge_min_support > 0);
    let edge_views: Vec<EdgeView> = match own_low {
        Some(_) => (0..frames.len())
            .filter(|&j| j != i)
            .filter_map(|j| {
                let (m, b) = camera_to_camera(cam, frames[j].camera);
                Some(EdgeView {
                    cam: frames[j].camera,
                    low: frames[j].low?,
                    footprint: footprints[j].as_ref()?,
                    m,
                    b,
                })
            })
            .collect(),
        None => Vec::new(),
    };
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
            let mut support = vec![0.0f32; p.edge_steps];
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
                let ray = Ray {
                    dir: cam.pixel_center_dir_cam(x, y),
                    colour: {
                        let px = frame.rgb.pixel(x, y);
                        [px[0], px[1], px[2]]
                    },
                    background: background as f64,
                    nearest: nearest as f64,
                };
                // Once per pixel: both the colour sweep and the edge support compare with it.
                let bg_cost = ray.background_cost(&ns, &mut scratch, p);
                let (placed, past_background) = ray.by_colour(&ns, bg_cost, &mut costs, &mut scratch, p);
                swept += past_background as usize;
                let placed = match placed {
                    Err(why) if own_low.is_some_and(|l| l.data[y * w + x] > 0.5) => ray
                        .by_edges(&edge_views, &ns, bg_cost, &mut support, &mut scratch, p)
                        .map(|z| (z, Outcome::FoundAtEdge))
                        .ok_or(why),
                    placed => placed.map(|z| (z, Outcome::Found)),
                };
                match placed {
                    Ok((z, how)) => {
                        row[x] = z as f32;
                        what[x] = how as u8;
                        found += 1;
                    }
                    Err(why) => what[x] = why as u8,
                }
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
mod tests;
