//! Emitter masks found from the images, for datasets that do not ship them (a real capture never
//! does): a pixel sees an emitter when it is far brighter than the lit scene and stays so from the
//! other views.
//!
//! 1. Brightness. With HDR images a pixel is a candidate when its luminance exceeds
//!    [`HDR_FACTOR`] × the 99th percentile of the luminance of the scene's unsaturated pixels
//!    (one threshold for the whole scene, so a view that sees only the lamp's dim side is judged
//!    like the others); without HDR, when an LDR channel is saturated (≥ [`LDR_SATURATED`]) and
//!    the luma is at least [`LDR_LUMA_SATURATED`].
//! 2. Cleaning. 8-connected pieces smaller than [`min_component`] pixels are dropped (sensor
//!    noise, a glint on an edge).
//! 3. Multi-view consistency, where the views have depth. A lamp is bright from everywhere; a
//!    highlight is a reflection that moves over the surface as the camera moves. Each piece's
//!    pixels (up to [`MAX_VOTERS`] of them) are back-projected with their depth and projected into
//!    every other view; a view whose own depth there agrees (within [`DEPTH_TOLERANCE`], else the
//!    point is hidden from it) is a witness, and says yes when a pixel of its 3×3 neighbourhood
//!    there is bright. A piece is dropped when it has [`MIN_WITNESSES`] or more and fewer than
//!    [`MIN_AGREEMENT`] of them say yes (too few witnesses refute nothing). Without depth the
//!    brightness test stands alone.
//!
//! 4. Holes. Enclosed holes in a kept piece of at most [`HOLE_MAX_PIXELS`] pixels whose mean
//!    LDR luma is at least [`HOLE_MIN_LUMA`] are filled: JPEG's 8×8 blocks and sensor noise pull
//!    scattered pixels of a saturated panel just under the test (the default room's phone
//!    capture: 228 enclosed holes in its 40 masks, none after; IoU against the exact room's masks
//!    0.736 → 0.778, docs/results.md).
//!
//! No dilation follows. A one-pixel dilation "to catch the rim" was measured on the built-in
//! rooms (80×60, 20 views) against their masks, which mark the pixels whose centre sees an
//! emitter: IoU 0.93 → 0.59 with HDR, 0.83 → 0.50 from LDR alone, and growing only into
//! neighbours above a quarter of the threshold still cost 0.07: a pixel a lamp covers in part is
//! bright already (half a lamp is still far above the scene), so the rim is in, and a ring
//! around it is wall.
//!
//! Why 8× the 99th percentile: a lit diffuse surface returns at most albedo × irradiance / π, and
//! the irradiance of a lamp of radiance L filling a solid angle Ω is at most L·Ω, so a wall is
//! dimmer than the lamp that lights it by π / (albedo · Ω): a large factor for any lamp smaller
//! than a fraction of the hemisphere. The 99th percentile of the unsaturated pixels is about the
//! brightest lit wall. Measured on the built-in rooms, their emitter pixels sit 16× (living room,
//! a large ceiling panel) to 60× (bedroom) above it, their dimmest ones at 8–30×: a factor of 8
//! missed none there (10 missed 2 % of the living room's), 4 took 60 % more false ones. Mirror
//! images of a lamp can pass it: step 3 is what removes them.

use crate::dataset::Frame;
use crate::imageio::ImageF32;
use rayon::prelude::*;

/// LDR values at or above this are saturated.
pub const LDR_SATURATED: f32 = 0.99;
/// Without HDR a pixel is a candidate when one channel is saturated and its luma (of the stored
/// values) is at least this. Not "every channel saturated": JPEG keeps luma at full resolution
/// but halves chroma, which pulls one channel of a small warm bulb's rim pixels under
/// saturation. On the default room's phone capture the all-channels rule found 0.29 of the
/// bulb's pixels, and stage 2 then put its emission at 2.2× (a part of the bulb labelled, the
/// rest seen through F_c); with this rule 1.26 and 0.71×, the ceiling panel 0.80×. It costs
/// IoU against the PNG rooms' masks of pixel centres (0.82 → 0.78, 0.68 → 0.58 from LDR): it
/// takes partly covered rim pixels, which do see the lamp.
pub const LDR_LUMA_SATURATED: f32 = 0.98;
/// An HDR pixel is a candidate emitter above this many times the 99th percentile of the
/// unsaturated pixels' luminance (see the module comment for why 8).
pub const HDR_FACTOR: f32 = 8.0;
/// Relative depth difference within which another view sees the same point (else it is hidden).
pub const DEPTH_TOLERANCE: f64 = 0.03;
/// Fraction of a piece's witnesses that must see it bright too.
pub const MIN_AGREEMENT: f64 = 0.5;
/// Witnesses (voter pixels seen by another view, counted per view) needed to refute a piece:
/// a lamp panel that one other view glimpses at one pixel, at its edge, stays.
pub const MIN_WITNESSES: usize = 3;
/// Pixels of a piece that vote (evenly spread over it): enough for a robust vote, and the cost
/// of a large lamp stays that of a small one.
pub const MAX_VOTERS: usize = 64;
/// Largest enclosed hole of a kept piece that is filled (pixels).
pub const HOLE_MAX_PIXELS: usize = 16;
/// Least mean LDR luma of a hole that is filled: a darker enclosed region is an occluder (a
/// chandelier's globe before a panel), not speckle.
pub const HOLE_MIN_LUMA: f32 = 0.9;
/// Luminance samples used at most for the scene's percentile.
const MAX_SAMPLES: usize = 1 << 20;

/// Rec. 709 luminance of linear RGB.
fn luminance(c: &[f32]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The smallest piece kept, in pixels: 2, or one in 50 000 pixels of the image (6 px at 640×480).
pub fn min_component(width: usize, height: usize) -> usize {
    (width * height / 50_000).max(2)
}

/// What [`detect_emitters`] found, per view and in all.
#[derive(Clone, Default, PartialEq, serde::Serialize)]
pub struct EmitterDetection {
    /// One mask per frame given (1 = emitter), in their order.
    #[serde(skip)]
    pub masks: Vec<ImageF32>,
    /// The HDR luminance threshold, when the frames have HDR images.
    pub hdr_threshold: Option<f32>,
    /// Whether the multi-view check ran (the frames have depth).
    pub multi_view: bool,
    /// Bright pixels before cleaning.
    pub candidates: usize,
    /// Pieces dropped as too small, as inconsistent between views, and kept.
    pub dropped_small: usize,
    pub dropped_inconsistent: usize,
    pub kept: usize,
    /// Pixels filled as holes of kept pieces (step 4).
    pub holes_filled: usize,
    /// Emitter pixels of the final masks, and the views with any.
    pub pixels: usize,
    pub views_with_emitters: usize,
}

impl std::fmt::Debug for EmitterDetection {
    /// The counts, and the masks' number (not their pixels).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EmitterDetection")
            .field("masks", &self.masks.len())
            .field("hdr_threshold", &self.hdr_threshold)
            .field("multi_view", &self.multi_view)
            .field("candidates", &self.candidates)
            .field("dropped_small", &self.dropped_small)
            .field("dropped_inconsistent", &self.dropped_inconsistent)
            .field("kept", &self.kept)
            .field("holes_filled", &self.holes_filled)
            .field("pixels", &self.pixels)
            .field("views_with_emitters", &self.views_with_emitters)
            .finish()
    }
}

/// The scene's HDR threshold: [`HDR_FACTOR`] × the 99th percentile of the luminance of the
/// pixels whose LDR value saturates no channel, over the frames with HDR images. `None` without
/// HDR (or without an unsaturated pixel).
pub fn hdr_threshold(frames: &[&Frame]) -> Option<f32> {
    let with_hdr: Vec<&&Frame> = frames.iter().filter(|f| f.hdr.is_some()).collect();
    let total: usize = with_hdr.iter().map(|f| f.pixel_count()).sum();
    let stride = total.div_ceil(MAX_SAMPLES).max(1);
    let mut lum = Vec::new();
    for f in with_hdr {
        let hdr = f.hdr.as_ref().expect("filtered");
        for p in (0..f.pixel_count()).step_by(stride) {
            let ldr = &f.rgb.data[p * 3..p * 3 + 3];
            if ldr.iter().all(|v| *v < LDR_SATURATED) {
                let l = luminance(&hdr.data[p * 3..p * 3 + 3]);
                if l.is_finite() {
                    lum.push(l);
                }
            }
        }
    }
    if lum.is_empty() {
        return None;
    }
    let k = ((lum.len() - 1) as f64 * 0.99).round() as usize;
    let p99 = *lum.select_nth_unstable_by(k, f32::total_cmp).1;
    Some(HDR_FACTOR * p99.max(1e-12))
}

/// Per pixel of `frame`: is it bright enough to be an emitter (the HDR test where it has an HDR
/// image and there is a threshold, else LDR saturation)?
fn bright_pixels(frame: &Frame, threshold: Option<f32>) -> Vec<bool> {
    match (&frame.hdr, threshold) {
        (Some(hdr), Some(t)) => hdr.data.chunks_exact(3).map(|c| luminance(c) > t).collect(),
        _ => frame
            .rgb
            .data
            .chunks_exact(3)
            .map(|c| luminance(c) >= LDR_LUMA_SATURATED && c.iter().any(|v| *v >= LDR_SATURATED))
            .collect(),
    }
}

/// The 8-connected pieces of `set` (pixel indices, row-major), each in scan order.
pub fn components(set: &[bool], width: usize, height: usize) -> Vec<Vec<usize>> {
    let mut seen = vec![false; set.len()];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for start in 0..set.len() {
        if !set[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut piece = Vec::new();
        while let Some(p) = stack.pop() {
            piece.push(p);
            let (x, y) = ((p % width) as isize, (p / width) as isize);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= width as isize || ny >= height as isize {
                        continue;
                    }
                    let q = ny as usize * width + nx as usize;
                    if set[q] && !seen[q] {
                        seen[q] = true;
                        stack.push(q);
                    }
                }
            }
        }
        piece.sort_unstable();
        out.push(piece);
    }
    out
}

/// Is any pixel of the 3×3 neighbourhood of (x, y) bright?
fn bright_near(bright: &[bool], width: usize, height: usize, x: usize, y: usize) -> bool {
    (y.saturating_sub(1)..=(y + 1).min(height - 1))
        .any(|j| (x.saturating_sub(1)..=(x + 1).min(width - 1)).any(|i| bright[j * width + i]))
}

/// (witnesses, witnesses that see it bright) of the point seen at `pixel` of view `a`.
fn votes(frames: &[&Frame], bright: &[Vec<bool>], a: usize, pixel: usize) -> (usize, usize) {
    let fa = frames[a];
    let depth = fa.depth.as_ref().expect("voters have depth");
    let (w, x, y) = (fa.camera.width, pixel % fa.camera.width, pixel / fa.camera.width);
    let d = depth.data[y * w + x] as f64;
    let point = fa.camera.backproject(x, y, d);
    let (mut seen, mut agree) = (0, 0);
    for (b, fb) in frames.iter().enumerate() {
        let Some(db) = fb.depth.as_ref().filter(|_| b != a) else {
            continue;
        };
        let cam = &fb.camera;
        let Some((u, v, z)) = cam.project(point) else {
            continue;
        };
        if !(u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64) {
            continue;
        }
        let (i, j) = (u as usize, v as usize);
        let there = db.data[j * cam.width + i] as f64;
        if there <= 0.0 || (there - z).abs() > DEPTH_TOLERANCE * z {
            continue;
        }
        seen += 1;
        agree += bright_near(&bright[b], cam.width, cam.height, i, j) as usize;
    }
    (seen, agree)
}

/// One view's mask and its counts: (mask, candidates, small, inconsistent, kept, holes filled).
fn detect_view(frames: &[&Frame], bright: &[Vec<bool>], a: usize, multi_view: bool) -> (ImageF32, [usize; 5]) {
    let f = frames[a];
    let (w, h) = (f.camera.width, f.camera.height);
    let set = &bright[a];
    let candidates = set.iter().filter(|b| **b).count();
    let (mut small, mut inconsistent, mut kept) = (0, 0, 0);
    let mut mask = ImageF32::new(w, h, 1);
    let depth = f.depth.as_ref().filter(|_| multi_view);
    for piece in components(set, w, h) {
        if piece.len() < min_component(w, h) {
            small += 1;
            continue;
        }
        if let Some(depth) = depth {
            let with_depth: Vec<usize> = piece.iter().copied().filter(|&p| depth.data[p] > 0.0).collect();
            let step = with_depth.len().div_ceil(MAX_VOTERS).max(1);
            let (mut seen, mut agree) = (0, 0);
            for &p in with_depth.iter().step_by(step) {
                let (s, y) = votes(frames, bright, a, p);
                seen += s;
                agree += y;
            }
            if seen >= MIN_WITNESSES && (agree as f64) < MIN_AGREEMENT * seen as f64 {
                inconsistent += 1;
                continue;
            }
        }
        kept += 1;
        for &p in &piece {
            mask.data[p] = 1.0;
        }
    }
    let filled = fill_holes(&mut mask, &f.rgb);
    (mask, [candidates, small, inconsistent, kept, filled])
}

/// The enclosed holes of a mask (`inside[p]`: the pixel is in it): the 4-connected pieces of its
/// complement that touch no image border, each as pixel indices.
pub fn enclosed_holes(inside: &[bool], w: usize, h: usize) -> Vec<Vec<usize>> {
    let mut seen = vec![false; inside.len()];
    let mut holes = Vec::new();
    let mut stack = Vec::new();
    for start in 0..inside.len() {
        if inside[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut hole = Vec::new();
        let mut touches_border = false;
        while let Some(p) = stack.pop() {
            hole.push(p);
            let (x, y) = (p % w, p / w);
            touches_border |= x == 0 || y == 0 || x + 1 == w || y + 1 == h;
            let neighbours = [
                (x > 0).then(|| p - 1),
                (x + 1 < w).then(|| p + 1),
                (y > 0).then(|| p - w),
                (y + 1 < h).then(|| p + w),
            ];
            for q in neighbours.into_iter().flatten() {
                if !inside[q] && !seen[q] {
                    seen[q] = true;
                    stack.push(q);
                }
            }
        }
        if !touches_border {
            holes.push(hole);
        }
    }
    holes
}

/// Fills the enclosed holes of `mask` of at most [`HOLE_MAX_PIXELS`] pixels and mean luma of
/// `rgb` ≥ [`HOLE_MIN_LUMA`]; returns the pixels filled.
fn fill_holes(mask: &mut ImageF32, rgb: &ImageF32) -> usize {
    let inside: Vec<bool> = mask.data.iter().map(|v| *v >= 0.5).collect();
    let mut filled = 0;
    for hole in enclosed_holes(&inside, mask.width, mask.height) {
        if hole.len() > HOLE_MAX_PIXELS {
            continue;
        }
        let luma = hole
            .iter()
            .map(|&p| luminance(&rgb.data[3 * p..3 * p + 3]))
            .sum::<f32>()
            / hole.len() as f32;
        if luma >= HOLE_MIN_LUMA {
            for &p in &hole {
                mask.data[p] = 1.0;
            }
            filled += hole.len();
        }
    }
    filled
}

/// Emitter masks of `frames` from their images (and depth, where they have it): see the module
/// comment. Every frame is a witness for the others.
pub fn detect_emitters(frames: &[&Frame]) -> EmitterDetection {
    let threshold = hdr_threshold(frames);
    let bright: Vec<Vec<bool>> = frames.par_iter().map(|f| bright_pixels(f, threshold)).collect();
    let with_depth = frames.iter().filter(|f| f.depth.is_some()).count();
    let multi_view = with_depth >= 2;
    let views: Vec<(ImageF32, [usize; 5])> = (0..frames.len())
        .into_par_iter()
        .map(|a| detect_view(frames, &bright, a, multi_view))
        .collect();
    let mut out = EmitterDetection {
        hdr_threshold: threshold,
        multi_view,
        ..Default::default()
    };
    for (mask, [candidates, small, inconsistent, kept, filled]) in views {
        let pixels = mask.data.iter().filter(|v| **v > 0.5).count();
        out.candidates += candidates;
        out.dropped_small += small;
        out.dropped_inconsistent += inconsistent;
        out.kept += kept;
        out.holes_filled += filled;
        out.pixels += pixels;
        out.views_with_emitters += (pixels > 0) as usize;
        out.masks.push(mask);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{look_at, Camera};
    use crate::dataset::Split;
    use glam::DVec3;
    use std::path::PathBuf;

    /// A camera at `eye` looking at the origin, 64×48.
    fn camera(eye: DVec3) -> Camera {
        Camera {
            width: 64,
            height: 48,
            fx: 60.0,
            fy: 60.0,
            cx: 32.0,
            cy: 24.0,
            c2w: look_at(eye, DVec3::ZERO, DVec3::Z),
            lens: Default::default(),
        }
    }

    /// A view of the floor z = 0 (grey) with a lamp: the disc of radius 0.25 around `lamp` on the
    /// floor glows from every side; and a highlight: the mirror reflection of a point light at
    /// `light` in the floor, where the view's reflected ray points at it (so it moves with the eye).
    fn view(eye: DVec3, lamp: DVec3, light: DVec3, hdr: bool) -> Frame {
        let camera = camera(eye);
        let (w, h) = (camera.width, camera.height);
        let mut rgb = ImageF32::new(w, h, 3);
        let mut radiance = ImageF32::new(w, h, 3);
        let mut depth = ImageF32::new(w, h, 1);
        for j in 0..h {
            for i in 0..w {
                let (o, d, cos) = camera.ray(i as f64 + 0.5, j as f64 + 0.5);
                let t = -o.z / d.z;
                let p = o + d * t;
                depth.data[j * w + i] = (t * cos) as f32;
                let reflected = DVec3::new(d.x, d.y, -d.z);
                let to_light = (light - p).normalize();
                let l = if (p - lamp).length() < 0.25 {
                    50.0
                } else if reflected.dot(to_light) > 0.998 {
                    30.0
                } else {
                    0.3
                };
                radiance.pixel_mut(i, j).copy_from_slice(&[l; 3]);
                rgb.pixel_mut(i, j).copy_from_slice(&[(l * 2.0).min(1.0); 3]);
            }
        }
        Frame {
            name: format!("{eye}"),
            split: Split::Train,
            camera,
            image_path: PathBuf::new(),
            rgb,
            hdr: hdr.then_some(radiance),
            depth: Some(depth),
            depth_low: None,
            normal: None,
            emitter_mask: None,
            material_mask: None,
            albedo: None,
            specular: None,
            roughness: None,
        }
    }

    /// Does pixel `p` of `f` see the floor within 0.6 of the lamp (its radius and a pixel or two)'s centre?
    fn on_lamp(f: &Frame, p: usize, lamp: DVec3) -> bool {
        let w = f.camera.width;
        let d = f.depth.as_ref().unwrap().data[p] as f64;
        (f.camera.backproject(p % w, p / w, d) - lamp).length() < 0.6
    }

    /// The lamp is bright from both views and kept; the highlight sits on another spot of the
    /// floor in each view, so each view's highlight is dark from the other and dropped. Without
    /// depth the highlight can no longer be told from the lamp and is kept.
    #[test]
    fn keeps_the_lamp_and_drops_a_moving_highlight() {
        let lamp = DVec3::new(-0.5, 0.3, 0.0);
        let light = DVec3::new(0.6, -0.2, 1.2);
        for hdr in [true, false] {
            let frames = [
                view(DVec3::new(1.5, -2.5, 2.0), lamp, light, hdr),
                view(DVec3::new(-1.0, -2.8, 1.6), lamp, light, hdr),
            ];
            let refs: Vec<&Frame> = frames.iter().collect();
            let found = detect_emitters(&refs);
            assert!(found.multi_view && found.hdr_threshold.is_some() == hdr);
            assert_eq!((found.kept, found.dropped_inconsistent), (2, 2), "{found:?}");
            for (k, f) in frames.iter().enumerate() {
                let raw = bright_pixels(f, found.hdr_threshold);
                let mask = &found.masks[k];
                let px = |on: bool, set: &dyn Fn(usize) -> bool| {
                    (0..raw.len()).filter(|&p| set(p) && on_lamp(f, p, lamp) == on).count()
                };
                // A highlight was there to drop, and is gone; the lamp is kept whole.
                assert!(px(false, &|p| raw[p]) >= 2, "view {k}: no highlight rendered");
                assert_eq!(px(false, &|p| mask.data[p] > 0.5), 0, "view {k}: highlight kept");
                assert!(px(true, &|p| raw[p]) >= 10, "view {k}: no lamp rendered");
                assert_eq!(
                    px(true, &|p| mask.data[p] > 0.5),
                    px(true, &|p| raw[p]),
                    "view {k}: lamp cut"
                );
            }
            // Without depth the brightness test alone keeps the highlights.
            let blind: Vec<Frame> = frames.iter().cloned().map(|f| Frame { depth: None, ..f }).collect();
            let found = detect_emitters(&blind.iter().collect::<Vec<_>>());
            assert!(
                !found.multi_view && found.dropped_inconsistent == 0 && found.kept == 4,
                "{found:?}"
            );
        }
    }

    /// Pieces below the size floor are noise: a lone saturated pixel is dropped.
    #[test]
    fn drops_single_saturated_pixels() {
        let mut f = view(
            DVec3::new(1.5, -2.5, 2.0),
            DVec3::new(9.0, 9.0, 0.0),
            DVec3::new(0.0, 0.0, -5.0),
            false,
        );
        f.rgb.pixel_mut(10, 10).copy_from_slice(&[1.0; 3]);
        let found = detect_emitters(&[&f]);
        assert_eq!((found.candidates, found.dropped_small, found.pixels), (1, 1, 0));
    }

    /// A 12×12 panel on a 20×20 image with JPEG-like speckle (single pixels at 0.97), a dark 2×2
    /// occluder inside and a bright 5×5 hole: the speckle is filled, the occluder and the large
    /// hole stay out, and nothing outside the panel changes.
    #[test]
    fn fills_the_speckle_of_a_panel_but_not_an_occluder_or_a_large_hole() {
        let (w, h) = (20, 20);
        let mut rgb = ImageF32::new(w, h, 3);
        let mut mask = ImageF32::new(w, h, 1);
        for y in 4..16 {
            for x in 4..16 {
                mask.data[y * w + x] = 1.0;
                rgb.pixel_mut(x, y).copy_from_slice(&[1.0; 3]);
            }
        }
        let speckle = [(6, 6), (9, 5), (13, 13)];
        let occluder = [(6, 12), (7, 12), (6, 13), (7, 13)];
        let mut unset = |x: usize, y: usize, v: f32| {
            mask.data[y * w + x] = 0.0;
            rgb.pixel_mut(x, y).copy_from_slice(&[v; 3]);
        };
        for &(x, y) in &speckle {
            unset(x, y, 0.97);
        }
        for &(x, y) in &occluder {
            unset(x, y, 0.5);
        }
        for y in 9..14 {
            for x in 9..14 {
                if (x, y) != (13, 13) {
                    unset(x, y, 0.99);
                }
            }
        }
        let before = mask.clone();
        let filled = fill_holes(&mut mask, &rgb);
        assert_eq!(filled, 2, "the two lone speckle pixels (the third joins the 5×5 hole)");
        for &(x, y) in &speckle[..2] {
            assert_eq!(mask.data[y * w + x], 1.0);
        }
        for &(x, y) in &occluder {
            assert_eq!(mask.data[y * w + x], 0.0);
        }
        assert_eq!(mask.data[11 * w + 11], 0.0, "a 25-pixel hole is more than speckle");
        let changed = (0..w * h).filter(|&p| mask.data[p] != before.data[p]).count();
        assert_eq!(changed, 2);
    }
}
