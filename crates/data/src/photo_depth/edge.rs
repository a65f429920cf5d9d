//! The edge support ([`super::EDGE_MIN_SUPPORT`], step 6 of the module's doc): where the colours
//! cannot place a pixel inside a low-confidence footprint, the other views' low-confidence
//! footprints along its ray can; and the clearing (step 7) of the edge depths that ring what
//! the colours found.

use super::{cost, Neighbour, Outcome, PhotoDepthParams, Ray};
use crate::camera::Camera;
use crate::imageio::ImageF32;
use glam::{DMat3, DVec3};

/// Another view as the edge support sees it: where the reference view's points land in it
/// (`m·d·z + b` in its camera space, as [`Neighbour`], from `camera_to_camera`), its low-confidence footprints and its kept
/// samples spread over their footprints.
pub(super) struct EdgeView<'a> {
    pub(super) cam: &'a Camera,
    pub(super) low: &'a ImageF32,
    pub(super) footprint: &'a ImageF32,
    pub(super) m: DMat3,
    pub(super) b: DVec3,
}

impl Ray {
    /// The edge support along the ray: at each step, the views in which the point falls on a
    /// low-confidence footprint less those whose kept sample there lies behind it
    /// (`edge_seen_through`). A thin object the sensor lost leaves low-confidence footprints
    /// around its image in every view that sees it, so they meet along the ray at its depth; a
    /// point in free space before a sensed wall falls on the wall's kept samples in the other
    /// views. Views in which the point is outside the image or behind a nearer sample do not vote.
    /// The peak (the middle of the steps at the highest support, at least `edge_min_support`) is
    /// refined by the colour cost within `edge_window` of its depth; `None` without a peak or
    /// when the depth is behind the pixel's nearest sample. `bg_cost`: [`Ray::background_cost`].
    pub(super) fn by_edges(
        &self,
        views: &[EdgeView],
        ns: &[Neighbour],
        bg_cost: f32,
        support: &mut [f32],
        scratch: &mut Vec<f32>,
        p: &PhotoDepthParams,
    ) -> Option<f64> {
        let zb = self.background;
        let (inv_near, inv_far) = (1.0 / (p.near_fraction * zb), 1.0 / ((1.0 - p.min_gap) * zb));
        let inv = |k: f64| inv_near + (inv_far - inv_near) * k / (p.edge_steps - 1) as f64;
        for (k, s) in support.iter_mut().enumerate() {
            let z = 1.0 / inv(k as f64);
            *s = views.iter().map(|v| v.vote(self.dir, z, p)).sum();
        }
        let top = support.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        if !(top >= p.edge_min_support as f32) {
            return None;
        }
        // What the background itself gets: a region of low confidence in every view (a shelf of
        // books, a grazing floor) supports every depth before it alike.
        let at_background: f32 = views.iter().map(|v| v.vote(self.dir, zb, p)).sum();
        if top - at_background < p.edge_contrast as f32 {
            return None;
        }
        let (sum, n) = (0..support.len())
            .filter(|&k| support[k] == top)
            .fold((0, 0), |(sum, n), k| (sum + k, n + 1));
        let k_peak = sum as f64 / n as f64;
        let z_peak = 1.0 / inv(k_peak);
        // The colour cost's best within the window.
        let refine_steps = 21;
        let best = (0..refine_steps)
            .map(|k| z_peak * (1.0 + p.edge_window * (2.0 * k as f64 / (refine_steps - 1) as f64 - 1.0)))
            .filter_map(|z| cost(ns, self.dir, z, self.colour, scratch, p).map(|c| (c, z)))
            // Ties (a plain colour) go to the peak.
            .min_by(|a, b| {
                a.0.total_cmp(&b.0)
                    .then((a.1 - z_peak).abs().total_cmp(&(b.1 - z_peak).abs()))
            });
        let (c, z) = best?;
        let explained = bg_cost < p.edge_min_ratio * c;
        (c < p.max_cost && !explained && !self.behind_own(z, p)).then_some(z)
    }
}

impl EdgeView<'_> {
    /// +1: the point falls on a low-confidence footprint; −`edge_through_weight`: on a kept
    /// sample lying behind it by over `edge_seen_through`; 0 otherwise.
    fn vote(&self, dir: DVec3, z: f64, p: &PhotoDepthParams) -> f32 {
        let pc = self.m * dir * z + self.b;
        if pc.z <= 1e-6 {
            return 0.0;
        }
        let (u, v) = self.cam.project_camera_space(pc);
        if !(u >= 0.0 && v >= 0.0 && u < self.low.width as f64 && v < self.low.height as f64) {
            return 0.0;
        }
        let k = v as usize * self.low.width + u as usize;
        if self.low.data[k] > 0.5 {
            1.0
        } else if self.footprint.data[k] as f64 > pc.z * (1.0 + p.edge_seen_through) {
            -p.edge_through_weight
        } else {
            0.0
        }
    }
}

/// Each kept sample of a sparse depth map (one pixel per sample, `cell` pixels apart) spread over
/// its footprint, the `cell`-wide square around it; 0 elsewhere.
pub(super) fn footprint_depth(depth: &ImageF32, cell: f64) -> ImageF32 {
    let (w, h) = (depth.width, depth.height);
    let mut out = ImageF32::new(w, h, 1);
    let r = cell / 2.0;
    for (k, &d) in depth.data.iter().enumerate() {
        if d <= 0.0 {
            continue;
        }
        let (cx, cy) = ((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
        let (x0, x1) = (((cx - r).round().max(0.0)) as usize, ((cx + r).round() as usize).min(w));
        let (y0, y1) = (((cy - r).round().max(0.0)) as usize, ((cy + r).round() as usize).min(h));
        for y in y0..y1 {
            out.data[y * w + x0..y * w + x1].fill(d);
        }
    }
    out
}

/// Drops the edge depths with at least `edge_clear_count` depths the colours found within
/// `edge_clear_radius` pixels and `edge_clear_depth` of theirs: there the colours already see
/// the object, and the low-confidence footprints, a grid cell wide, ring it with depths whose
/// rays pass it by. Returns how many were dropped ([`Outcome::Cleared`]).
pub(super) fn clear_edges_near_colour(depth: &mut ImageF32, outcome: &mut [u8], p: &PhotoDepthParams) -> usize {
    let r = p.edge_clear_radius as isize;
    if r == 0 {
        return 0;
    }
    let (w, h) = (depth.width as isize, depth.height as isize);
    let drop: Vec<usize> = (0..depth.data.len())
        .filter(|&k| outcome[k] == Outcome::FoundAtEdge as u8)
        .filter(|&k| {
            let (x, y, z) = (k as isize % w, k as isize / w, depth.data[k] as f64);
            let near = (y - r..=y + r)
                .filter(|yy| (0..h).contains(yy))
                .flat_map(|yy| {
                    (x - r..=x + r)
                        .filter(|xx| (0..w).contains(xx))
                        .map(move |xx| (yy * w + xx) as usize)
                })
                .filter(|&j| {
                    outcome[j] == Outcome::Found as u8 && (depth.data[j] as f64 - z).abs() <= p.edge_clear_depth * z
                })
                .count();
            near >= p.edge_clear_count
        })
        .collect();
    for &k in &drop {
        depth.data[k] = 0.0;
        outcome[k] = Outcome::Cleared as u8;
    }
    drop.len()
}
