//! A flat emitter as the rectangle it is (`stage2.fit_panels`): a ceiling panel whose cluster of
//! emitter points is a thin axis-aligned box. Stage 1 reconstructs such a light poorly: its
//! pixels are saturated, so nothing photometric holds the surface there, and the recovered
//! surface around the panel is dented and bulged by centimetres (on seed 1's room up to 8 cm
//! above the true panel, F_e below ½ along its edges). A ray that truly reaches the panel then
//! meets a non-emitting surface and carries F_c's dim guess instead of L\[k\]: measured with the
//! true scene, 42 % of the rays from the cached surface points to seed 1's panel (58 % seen as
//! emitter), and stage 2's Kd rose to compensate (docs/results.md, twenty-second session).
//!
//! The panel is the box's mid-plane across its thin axis, bounded by the box on the other two,
//! emitting on the side facing the room (its normalization centre). A ray from that side meets
//! it where it crosses the rectangle before any surface, or where its hit lies in the slab of
//! `depth` about the plane within the rectangle (the recovered panel's own bulges).

use crate::intrinsic::LabelledHit;
use glam::Vec3;
use i2sdf_render::Ray;
use serde::{Deserialize, Serialize};

/// Largest thickness of a panel as a fraction of its smaller other side, both measured as the
/// standard deviation of its points along the axis (for points that fill a box evenly, the
/// ratio of the box's sides). The built-in rooms' ceiling panels are at 0.04–0.08; a bulb is
/// near 1. The spread, not the box, because one stray point sets a box's side: a sensor-depth
/// capture's ceiling panel is 14 cm thick by its points' box over 90 cm, while most of its
/// points lie within a few centimetres of the plane.
pub const PANEL_MAX_THICKNESS: f64 = 0.1;

/// A flat, axis-aligned emitter (world units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Panel {
    /// The axis across the panel (0, 1, 2: x, y, z).
    pub axis: usize,
    /// The plane's coordinate along `axis`.
    pub offset: f64,
    /// The rectangle on the two other axes, in increasing axis order.
    pub lo: [f64; 2],
    pub hi: [f64; 2],
    /// +1 or −1: the side along `axis` that emits (towards the room).
    pub facing: f64,
    /// Half the slab about the plane in which recovered surface is the panel's own.
    pub depth: f64,
}

/// Share of a cluster's points left out at each end of the axis across a panel when its slab is
/// bounded: stray points (a speck of the wall marked as emitter, a bulge of the recovered surface)
/// must not widen the slab over unrelated surfaces. The rectangle keeps the whole box: the
/// recovered panel's points thin out towards its edges (F_e < ½ there), and trimming even this
/// share made the exact rooms' panels 2–11 cm narrower than the true ones (0–1 cm with the box).
pub const PANEL_TRIM: f64 = 0.01;

/// A cluster's points summarized along each axis: their box, the range of all but
/// [`PANEL_TRIM`] of them at either end (nearest ranks: with under 1/[`PANEL_TRIM`] points, the
/// box), their median and their standard deviation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    pub inner_lo: [f64; 3],
    pub inner_hi: [f64; 3],
    pub median: [f64; 3],
    pub sigma: [f64; 3],
}

impl Spread {
    /// The spread of `points`; `None` for none.
    pub fn of(points: &[[f64; 3]]) -> Option<Spread> {
        if points.is_empty() {
            return None;
        }
        let n = points.len();
        let mut s = Spread {
            lo: [0.0; 3],
            hi: [0.0; 3],
            inner_lo: [0.0; 3],
            inner_hi: [0.0; 3],
            median: [0.0; 3],
            sigma: [0.0; 3],
        };
        for a in 0..3 {
            let mut x: Vec<f64> = points.iter().map(|p| p[a]).collect();
            x.sort_by(f64::total_cmp);
            let last = (n - 1) as f64;
            s.lo[a] = x[0];
            s.hi[a] = x[n - 1];
            s.inner_lo[a] = x[(PANEL_TRIM * last).floor() as usize];
            s.inner_hi[a] = x[((1.0 - PANEL_TRIM) * last).ceil() as usize];
            s.median[a] = 0.5 * (x[(n - 1) / 2] + x[n / 2]);
            let mean = x.iter().sum::<f64>() / n as f64;
            s.sigma[a] = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
        }
        Some(s)
    }

    /// The axis along which the points spread least, and their thickness there as a fraction
    /// of the smaller of the two other spreads (∞ where those are zero).
    pub fn flatness(&self) -> (usize, f64) {
        let s = self.sigma;
        let axis = (0..3).min_by(|&a, &b| s[a].total_cmp(&s[b])).unwrap_or(0);
        let (u, v) = Panel::others(axis);
        let side = s[u].min(s[v]);
        (axis, if side > 0.0 { s[axis] / side } else { f64::INFINITY })
    }
}

impl Panel {
    /// The panel of a cluster of emitter points, where they are flat (their spread across the
    /// thinnest axis at most [`PANEL_MAX_THICKNESS`] of the next): the plane through their median
    /// across that axis, their box on the other two, facing `room` (a point inside the room), with
    /// a slab reaching all but the strays ([`Spread`]'s inner range) plus `margin`.
    pub fn of_points(points: &[[f64; 3]], room: [f64; 3], margin: f64) -> Option<Panel> {
        Panel::of_spread(&Spread::of(points)?, room, margin)
    }

    /// [`Panel::of_points`] from the points' [`Spread`].
    pub fn of_spread(spread: &Spread, room: [f64; 3], margin: f64) -> Option<Panel> {
        let (axis, thickness) = spread.flatness();
        if thickness > PANEL_MAX_THICKNESS {
            return None;
        }
        let (lo, hi) = (spread.lo, spread.hi);
        let (u, v) = Panel::others(axis);
        let offset = spread.median[axis];
        let facing = if room[axis] >= offset { 1.0 } else { -1.0 };
        Some(Panel {
            axis,
            offset,
            lo: [lo[u], lo[v]],
            hi: [hi[u], hi[v]],
            facing,
            depth: (spread.inner_hi[axis] - offset).max(offset - spread.inner_lo[axis]) + margin,
        })
    }

    /// The panel of a box `[lo, hi]` that points fill evenly (its eight corners' spread is its
    /// sides' ratio): see [`Panel::of_points`].
    pub fn of_box(bounds: [[f64; 3]; 2], room: [f64; 3], margin: f64) -> Option<Panel> {
        let [lo, hi] = bounds;
        let corners: Vec<[f64; 3]> = (0..8)
            .map(|i| std::array::from_fn(|a| if i >> a & 1 == 0 { lo[a] } else { hi[a] }))
            .collect();
        Panel::of_points(&corners, room, margin)
    }

    /// Whether the fields describe a panel: an axis 0–2, finite numbers, `lo ≤ hi`, `facing` ±1,
    /// `depth ≥ 0` (what `emitters.json` must hold).
    pub fn is_valid(&self) -> bool {
        let finite = [self.offset, self.depth, self.lo[0], self.lo[1], self.hi[0], self.hi[1]]
            .iter()
            .all(|x| x.is_finite());
        finite
            && self.axis < 3
            && self.facing.abs() == 1.0
            && self.depth >= 0.0
            && self.lo[0] <= self.hi[0]
            && self.lo[1] <= self.hi[1]
    }

    /// The two axes other than `axis`, in increasing order.
    fn others(axis: usize) -> (usize, usize) {
        match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        }
    }

    /// Whether `p` lies over the rectangle (on the other two axes).
    fn over(&self, p: Vec3) -> bool {
        let (u, v) = Panel::others(self.axis);
        let (pu, pv) = (p[u] as f64, p[v] as f64);
        pu >= self.lo[0] && pu <= self.hi[0] && pv >= self.lo[1] && pv <= self.hi[1]
    }

    /// Whether `p` is the recovered panel's own surface: over the rectangle, within `depth` of
    /// the plane.
    pub fn holds(&self, p: Vec3) -> bool {
        self.over(p) && (p[self.axis] as f64 - self.offset).abs() <= self.depth
    }

    /// The rectangle's corners, in counter-clockwise order seen from the emitting side (two
    /// triangles 0-1-2 and 0-2-3 face the room).
    pub fn corners(&self) -> [Vec3; 4] {
        let (u, v) = Panel::others(self.axis);
        let at = |a: f64, b: f64| {
            let mut p = Vec3::ZERO;
            p[self.axis] = self.offset as f32;
            p[u] = a as f32;
            p[v] = b as f32;
            p
        };
        let c = [
            at(self.lo[0], self.lo[1]),
            at(self.hi[0], self.lo[1]),
            at(self.hi[0], self.hi[1]),
            at(self.lo[0], self.hi[1]),
        ];
        if (c[1] - c[0]).cross(c[2] - c[0]).dot(self.normal()) >= 0.0 {
            c
        } else {
            [c[0], c[3], c[2], c[1]]
        }
    }

    /// The emitting side's unit normal.
    pub fn normal(&self) -> Vec3 {
        let mut n = Vec3::ZERO;
        n[self.axis] = self.facing as f32;
        n
    }

    /// Where `ray` meets the panel, given what it hit in the recovered surface (`current`): the
    /// panel's hit labelled `emitter` if the ray comes from the emitting side and either crosses
    /// the rectangle before `current` (or `current` is none) or `current` lies in the panel's
    /// slab over the rectangle; else `None` (the current hit stands).
    pub fn hit(&self, ray: &Ray, current: Option<&LabelledHit>, emitter: u32) -> Option<LabelledHit> {
        let a = self.axis;
        let along = ray.dir[a] as f64 * self.facing;
        if along >= 0.0 {
            // Parallel, or leaving from behind: the panel's back does not emit.
            return None;
        }
        let t = ((self.offset - ray.origin[a] as f64) / ray.dir[a] as f64) as f32;
        if !(t > ray.t_min && t < ray.t_max) {
            return None;
        }
        let position = ray.origin + t * ray.dir;
        if !self.over(position) {
            return None;
        }
        let meets = match current {
            None => true,
            Some(h) => t <= h.t || self.holds(h.position),
        };
        meets.then(|| LabelledHit {
            t,
            position,
            normal: self.normal(),
            emitter: Some(emitter),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 m × 0.8 m ceiling panel at y = 2.6 (its points' box 4 cm thick), the room below.
    fn ceiling() -> Panel {
        Panel::of_box([[0.0, 2.58, 0.0], [1.0, 2.62, 0.8]], [0.5, 1.3, 0.4], 0.02).unwrap()
    }

    #[test]
    fn a_thin_box_is_a_panel_facing_the_room() {
        let p = ceiling();
        assert_eq!((p.axis, p.lo, p.hi, p.facing), (1, [0.0, 0.0], [1.0, 0.8], -1.0));
        assert!((p.offset - 2.6).abs() < 1e-12 && (p.depth - 0.04).abs() < 1e-12);
        assert_eq!(p.normal(), Vec3::new(0.0, -1.0, 0.0));
        let c = p.corners();
        assert!((c[1] - c[0])
            .cross(c[2] - c[0])
            .normalize()
            .abs_diff_eq(p.normal(), 1e-6));
        assert!(c.iter().all(|q| (q.y - 2.6).abs() < 1e-6) && p.holds(Vec3::new(0.5, 2.63, 0.4)));
        assert!(!p.holds(Vec3::new(0.5, 2.65, 0.4)) && !p.holds(Vec3::new(1.1, 2.6, 0.4)));
        // A wall panel facing −x (the room on the low side).
        let w = Panel::of_box([[3.0, 0.5, 0.0], [3.05, 1.5, 1.0]], [0.0, 1.0, 0.0], 0.0).unwrap();
        assert_eq!((w.axis, w.facing, w.lo, w.hi), (0, -1.0, [0.5, 0.0], [1.5, 1.0]));
        // A bulb's box, a bar, a point: not panels.
        assert!(Panel::of_box([[0.0, 0.0, 0.0], [0.2, 0.2, 0.2]], [0.0; 3], 0.0).is_none());
        assert!(Panel::of_box([[0.0, 0.0, 0.0], [1.0, 0.05, 0.05]], [0.0; 3], 0.0).is_none());
        assert!(Panel::of_box([[1.0; 3], [1.0; 3]], [0.0; 3], 0.0).is_none());
    }

    /// Points over a 1 m × 0.8 m panel at y = 2.6, within a centimetre of it, and two stray ones
    /// 7 cm off: their box is 14 cm thick (0.175 of its 80 cm side, no panel), their spread is
    /// flat, so they are a panel, and its slab does not reach the strays.
    #[test]
    fn a_few_stray_points_do_not_hide_a_panel() {
        let mut points: Vec<[f64; 3]> = (0..21 * 17)
            .map(|i| {
                let (a, b) = ((i % 21) as f64 / 20.0, (i / 21) as f64 / 16.0);
                [a, 2.6 + 0.01 * ((i * 7919 % 13) as f64 / 6.0 - 1.0), 0.8 * b]
            })
            .collect();
        points.extend([[0.3, 2.53, 0.4], [0.7, 2.67, 0.2]]);
        let room = [0.5, 1.3, 0.4];
        let spread = Spread::of(&points).unwrap();
        assert_eq!(spread.flatness().0, 1);
        assert!(spread.flatness().1 < 0.05, "{spread:?}");
        let (ys, yh) = (points.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min), 2.67);
        assert!(Panel::of_box([[0.0, ys, 0.0], [1.0, yh, 0.8]], room, 0.02).is_none());
        let p = Panel::of_points(&points, room, 0.02).unwrap();
        assert_eq!((p.axis, p.lo, p.hi, p.facing), (1, [0.0, 0.0], [1.0, 0.8], -1.0));
        assert!((p.offset - 2.6).abs() < 2e-3 && (p.depth - 0.03).abs() < 2e-3, "{p:?}");
        assert!(!p.holds(Vec3::new(0.3, 2.53, 0.4)) && p.holds(Vec3::new(0.3, 2.61, 0.4)));
        // The points of a sphere (a bulb) are no panel, however few stray.
        let sphere: Vec<[f64; 3]> = (0..500)
            .map(|i| {
                let (z, phi) = (1.0 - 2.0 * (i as f64 + 0.5) / 500.0, i as f64 * 2.39996);
                let r = (1.0 - z * z).sqrt();
                [0.1 * r * phi.cos(), 1.8 + 0.1 * z, 0.1 * r * phi.sin()]
            })
            .collect();
        assert!(Spread::of(&sphere).unwrap().flatness().1 > 0.9);
        assert!(Panel::of_points(&sphere, room, 0.02).is_none() && Spread::of(&[]).is_none());
    }

    fn surface(ray: &Ray, t: f32) -> LabelledHit {
        LabelledHit {
            t,
            position: ray.origin + t * ray.dir,
            normal: Vec3::Y,
            emitter: None,
        }
    }

    #[test]
    fn rays_from_the_room_meet_the_panel_through_holes_and_bulges() {
        let p = ceiling();
        let up = Ray::new(Vec3::new(0.5, 1.0, 0.4), Vec3::Y, 0.0, f32::INFINITY);
        // Through a hole (the recovered surface 8 cm above the panel), or nothing hit at all.
        for current in [Some(surface(&up, 1.68)), None] {
            let h = p.hit(&up, current.as_ref(), 3).unwrap();
            assert!((h.t - 1.6).abs() < 1e-5 && h.emitter == Some(3) && h.normal == -Vec3::Y);
        }
        // A bulge 3 cm below the plane, over the rectangle: the panel's own surface.
        assert!(p.hit(&up, Some(&surface(&up, 1.57)), 3).is_some());
        // Something 10 cm below the panel (a lamp hanging from it) stands.
        assert!(p.hit(&up, Some(&surface(&up, 1.5)), 3).is_none());
        // Beside the rectangle, from behind (above the ceiling), or parallel: no panel.
        let beside = Ray::new(Vec3::new(1.2, 1.0, 0.4), Vec3::Y, 0.0, f32::INFINITY);
        assert!(p.hit(&beside, None, 3).is_none());
        let behind = Ray::new(Vec3::new(0.5, 3.0, 0.4), -Vec3::Y, 0.0, f32::INFINITY);
        assert!(p.hit(&behind, None, 3).is_none());
        let level = Ray::new(Vec3::new(-1.0, 2.6, 0.4), Vec3::X, 0.0, f32::INFINITY);
        assert!(p.hit(&level, None, 3).is_none());
        // An oblique ray that crosses the plane over the rectangle.
        let d = Vec3::new(0.5, 1.6, 0.0).normalize();
        let oblique = Ray::new(Vec3::new(0.0, 1.0, 0.4), d, 0.0, f32::INFINITY);
        let h = p.hit(&oblique, None, 0).unwrap();
        assert!((h.position.y - 2.6).abs() < 1e-5 && (h.position.x - 0.5).abs() < 1e-5);
    }
}
