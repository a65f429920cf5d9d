//! Depth as sensors write it (docs/DATASETS.md, depth): a float map in world units
//! or a 16-bit PNG of integers times `depth_unit_scale_factor`, possibly at another resolution
//! than its image (a phone's LiDAR grid is 256×192 beside a 1920×1440 image), possibly with a
//! per-sample confidence map (ARKit's 0 low / 1 medium / 2 high), and with holes and outliers:
//! NaN where the sensor saw nothing, 0 likewise, a reflection 1000 m away.
//!
//! Such samples are dropped ("no depth", 0 in `Frame::depth`) and counted ([`DepthDropped`])
//! instead of refusing the dataset; the sensor grid is mapped onto the image's pixels so that
//! `Frame::depth` keeps the image's size and nothing downstream changes. The validity window
//! (the official I²-SDF loader's `1e-3 < depth < 6` in normalized units) is applied once the
//! normalization is known ([`apply_validity_window`]).

use crate::camera::Camera;
use crate::dataset::{Frame, Normalization};
use crate::error::{DataError, Result};
use crate::imageio::{self, ImageF32};
use std::path::Path;

/// How far a depth map's aspect ratio may differ from its image's (relative) and still be mapped
/// onto it: sensors crop a few pixels (ARKit's 256×192 is exactly 4:3, Azure Kinect modes are
/// not quite their colour camera's), a different aspect means a different field of view.
pub const MAX_ASPECT_MISMATCH: f64 = 0.01;

/// The validity window of the official loader, `1e-3 < depth < 6`, in normalized units (times
/// the normalization's scale in world units): nearer is sensor noise at the lens, farther is
/// beyond the unit sphere's room (windows, mirrors, multipath).
pub const DEPTH_WINDOW_NORMALIZED: (f64, f64) = (1e-3, 6.0);

/// What happened to the depth samples of a dataset (every frame's depth map, relight frames
/// included), counted per sensor sample: each sample is counted once, by the first reason that
/// applies, in the order of the fields. `samples_total` = `kept` + the rest.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct DepthDropped {
    /// Samples read from the depth files.
    pub samples_total: u64,
    /// Samples that became an image pixel's depth.
    pub kept: u64,
    /// NaN or ±∞.
    pub non_finite: u64,
    /// ≤ 0: the file's own "no depth".
    pub non_positive: u64,
    /// Below `depth_confidence_min` in the frame's confidence map.
    pub low_confidence: u64,
    /// Valid samples not used because another sample landed nearer to the centre of the same
    /// image pixel (a depth map finer than its image).
    pub superseded: u64,
    /// Outside the validity window ([`depth_window`]), once the normalization was measured.
    pub out_of_window: u64,
}

impl DepthDropped {
    pub fn add(&mut self, o: &DepthDropped) {
        self.samples_total += o.samples_total;
        self.kept += o.kept;
        self.non_finite += o.non_finite;
        self.non_positive += o.non_positive;
        self.low_confidence += o.low_confidence;
        self.superseded += o.superseded;
        self.out_of_window += o.out_of_window;
    }
}

/// The validity window in world units for a normalization: depths `lo < d < hi` are kept.
pub fn depth_window(norm: &Normalization) -> (f64, f64) {
    let (lo, hi) = DEPTH_WINDOW_NORMALIZED;
    (lo * norm.scale, hi * norm.scale)
}

/// A frame's confidence map and the least confidence a depth sample needs.
#[derive(Clone, Copy, Debug)]
pub struct Confidence<'a> {
    pub path: &'a Path,
    pub min: u8,
}

/// Reads a depth map (EXR or `.npy` float in world units, the first channel; or a PNG of integers
/// times `png_scale`), drops the samples without valid depth (non-finite, ≤ 0, below the
/// confidence minimum) and maps the sensor grid onto `cam`'s pixels ([`map_to_image`]). The
/// result has the image's size, 0 where there is no depth. With a confidence map, also the
/// footprints of the samples dropped as low confidence ([`low_footprints`]). A depth map whose
/// aspect ratio is not the image's, or a confidence map not of the depth map's size, is an error
/// naming the file.
pub fn load_depth(
    path: &Path,
    cam: &Camera,
    png_scale: f64,
    confidence: Option<Confidence>,
) -> Result<(ImageF32, DepthDropped, Option<ImageF32>)> {
    let is_png = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let samples = if is_png {
        let mut raw = imageio::read_png_raw_gray(path)?;
        raw.data.iter_mut().for_each(|v| *v = (*v as f64 * png_scale) as f32);
        raw
    } else {
        imageio::read_float_map(path)?.channel(0)
    };
    check_aspect(path, &samples, cam)?;
    let conf = confidence
        .map(|c| read_confidence(c.path, &samples).map(|values| (values, c.min)))
        .transpose()?;
    let mut dropped = DepthDropped {
        samples_total: samples.data.len() as u64,
        ..Default::default()
    };
    let valid: Vec<f32> = samples
        .data
        .iter()
        .enumerate()
        .map(|(k, &d)| {
            if !d.is_finite() {
                dropped.non_finite += 1;
            } else if d <= 0.0 {
                dropped.non_positive += 1;
            } else if conf.as_ref().is_some_and(|(c, min)| c[k] < *min) {
                dropped.low_confidence += 1;
            } else {
                return d;
            }
            0.0
        })
        .collect();
    let valid = ImageF32::from_data(samples.width, samples.height, 1, valid);
    let before = valid.data.iter().filter(|d| **d > 0.0).count() as u64;
    let depth = map_to_image(&valid, cam.width, cam.height);
    dropped.kept = depth.data.iter().filter(|d| **d > 0.0).count() as u64;
    dropped.superseded = before - dropped.kept;
    let low = conf.map(|(c, min)| {
        let low: Vec<bool> = c.iter().map(|v| *v < min).collect();
        low_footprints(&low, samples.width, samples.height, cam.width, cam.height)
    });
    Ok((depth, dropped, low))
}

/// The image pixels (`width`×`height`) inside the footprint of a sensor sample marked `low` (a
/// `grid_w`×`grid_h` grid over the image): 1 there, else 0. Where a sensor straddles a depth edge
/// it marks its sample low, so these footprints outline what it saw only in part: a thin object
/// narrower than a sample leaves a trail of them in every view (used by the photometric depth's
/// edge support, `photo_depth::EDGE_MIN_SUPPORT`).
pub fn low_footprints(low: &[bool], grid_w: usize, grid_h: usize, width: usize, height: usize) -> ImageF32 {
    let mut out = ImageF32::new(width, height, 1);
    for y in 0..height {
        let v = (y * grid_h / height).min(grid_h - 1);
        for x in 0..width {
            let u = (x * grid_w / width).min(grid_w - 1);
            if low[v * grid_w + u] {
                out.data[y * width + x] = 1.0;
            }
        }
    }
    out
}

fn check_aspect(path: &Path, depth: &ImageF32, cam: &Camera) -> Result<()> {
    let depth_aspect = depth.width as f64 / depth.height as f64;
    let image_aspect = cam.width as f64 / cam.height as f64;
    if (depth_aspect / image_aspect - 1.0).abs() > MAX_ASPECT_MISMATCH {
        return Err(DataError::file(
            path,
            format!(
                "a depth map of the wrong aspect: {}×{} against the image's {}×{} (aspect ratios \
                 {depth_aspect:.4} and {image_aspect:.4} differ by over {} %)",
                depth.width,
                depth.height,
                cam.width,
                cam.height,
                MAX_ASPECT_MISMATCH * 100.0
            ),
        ));
    }
    Ok(())
}

/// A confidence map: an 8-bit (or 16-bit) grey PNG or a `.npy` of integers 0, 1, 2 at the depth
/// map's size.
fn read_confidence(path: &Path, depth: &ImageF32) -> Result<Vec<u8>> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let img = match ext.as_str() {
        "png" => imageio::read_png_raw_gray(path)?,
        "npy" => imageio::read_float_map(path)?,
        other => {
            return Err(DataError::file(
                path,
                format!("unsupported confidence map format '.{other}' (expected .png or .npy)"),
            ))
        }
    };
    if img.channels != 1 {
        return Err(DataError::file(
            path,
            format!("a confidence map needs 1 channel, found {}", img.channels),
        ));
    }
    if (img.width, img.height) != (depth.width, depth.height) {
        return Err(DataError::file(
            path,
            format!(
                "size {}×{} does not match its depth map's {}×{}",
                img.width, img.height, depth.width, depth.height
            ),
        ));
    }
    img.data
        .iter()
        .enumerate()
        .map(|(k, &v)| match v {
            0.0 => Ok(0),
            1.0 => Ok(1),
            2.0 => Ok(2),
            _ => Err(DataError::file(
                path,
                format!(
                    "confidence {v} at pixel ({}, {}): expected 0, 1 or 2 (ARKit's low, medium, high)",
                    k % img.width,
                    k / img.width
                ),
            )),
        })
        .collect()
}

/// Maps a depth map (1 channel, 0 = no depth) of any size onto a `width`×`height` image of the
/// same camera. Sample (u, v) is taken at its sensor pixel centre and scaled to the image, pixel
/// centres at +0.5: `x = (u + 0.5)·width/Ws`; it lands on the image pixel containing (x, y). Pixels
/// no valid sample lands on have no depth; of several samples landing on one pixel (a map finer
/// than its image), the one nearest to the pixel's centre is kept.
///
/// Nothing is interpolated or averaged across samples: across a depth edge a blend of foreground
/// and background (a mean, or a median of an even count) is a depth no surface has, a "flying
/// pixel" the SDF would be pulled towards. But a sample's centre is rarely its pixel's (a grid of
/// 4 puts every sample at the corner of four pixels, half a pixel off each), and training reads
/// the depth along the pixel's own ray: on a surface seen at a grazing angle, half a pixel of a
/// 160-pixel image (0.3°) is 5 cm of z-depth at 3 m and 75°, and the SDF was fitted to floors
/// and walls tilted by that much. So the sample's value is carried to the pixel's centre along
/// the surface it lies on: inverse depth is affine in the image over a plane, and its slope is
/// taken from the neighbouring samples where they continue the surface ([`transfer_slope`]),
/// none at an edge (the sample is then kept as it is).
pub fn map_to_image(depth: &ImageF32, width: usize, height: usize) -> ImageF32 {
    if (depth.width, depth.height) == (width, height) {
        return depth.clone();
    }
    let mut out = ImageF32::new(width, height, 1);
    let mut best = vec![f64::INFINITY; width * height];
    let sx = width as f64 / depth.width as f64;
    let sy = height as f64 / depth.height as f64;
    for v in 0..depth.height {
        let y = (v as f64 + 0.5) * sy;
        let j = (y.floor() as usize).min(height - 1);
        for u in 0..depth.width {
            let d = depth.pixel(u, v)[0];
            if d <= 0.0 {
                continue;
            }
            let x = (u as f64 + 0.5) * sx;
            let i = (x.floor() as usize).min(width - 1);
            let (dx, dy) = (i as f64 + 0.5 - x, j as f64 + 0.5 - y);
            let dist2 = dx * dx + dy * dy;
            let k = j * width + i;
            if dist2 < best[k] {
                best[k] = dist2;
                // The offset in sensor pixels, along which the inverse depth changes by its slope.
                let w = 1.0 / d as f64;
                let at = |uu: isize, vv: isize| -> Option<f64> {
                    let inside = uu >= 0 && vv >= 0 && (uu as usize) < depth.width && (vv as usize) < depth.height;
                    let z = if inside {
                        depth.pixel(uu as usize, vv as usize)[0]
                    } else {
                        0.0
                    };
                    (z > 0.0).then(|| 1.0 / z as f64)
                };
                let (ui, vi) = (u as isize, v as isize);
                let gu = transfer_slope(w, [at(ui - 2, vi), at(ui - 1, vi)], [at(ui + 1, vi), at(ui + 2, vi)]);
                let gv = transfer_slope(w, [at(ui, vi - 2), at(ui, vi - 1)], [at(ui, vi + 1), at(ui, vi + 2)]);
                let moved = w + gu * dx / sx + gv * dy / sy;
                out.data[k] = if moved > 0.0 { (1.0 / moved) as f32 } else { d };
            }
        }
    }
    out
}

/// The slope per sensor pixel of inverse depth `w` at a sample along one grid axis, from the
/// inverse depths of its two neighbours on each side (`before` = [second, first], `after` =
/// [first, second]): the central difference where both first neighbours continue the surface and
/// agree; else the one-sided difference towards a side whose second neighbour confirms it (the
/// three samples in a line, as on one plane: a one-sided step alone may cross a crease of the
/// room, where depth is continuous but its slope is not), the smoother if both do; 0 where none
/// does. A neighbour continues the surface when its step is at most [`TRANSFER_MAX_STEP`] of `w`;
/// two sides disagree (an edge or a crease) when the steeper step is over twice the other.
fn transfer_slope(w: f64, before: [Option<f64>; 2], after: [Option<f64>; 2]) -> f64 {
    let ok = |n: Option<f64>| n.filter(|n| (n - w).abs() <= TRANSFER_MAX_STEP * w);
    let (p, n) = (ok(before[1]), ok(after[0]));
    if let (Some(p), Some(n)) = (p, n) {
        let (a, b) = ((w - p).abs(), (n - w).abs());
        if a.max(b) <= (2.0 * a.min(b)).max(1e-3 * w) {
            return 0.5 * (n - p);
        }
    }
    // Whether first and second neighbour continue `w` in a line: steps of one sign that agree.
    let in_line = |first: Option<f64>, second: Option<f64>| -> Option<f64> {
        let (f, s) = (first?, second?);
        let (near, far) = (w - f, f - s);
        let agree = near.abs().max(far.abs()) <= (2.0 * near.abs().min(far.abs())).max(1e-3 * w);
        (agree && near * far >= 0.0).then_some(near)
    };
    // Slopes along +u: w − p behind, n − w ahead (the second step is n₂ − n).
    let back = in_line(p, before[0]);
    let ahead = in_line(n, after[1]).map(|near| -near);
    match (back, ahead) {
        (Some(a), Some(b)) => {
            if a.abs() <= b.abs() {
                a
            } else {
                b
            }
        }
        (Some(a), None) => a,
        (None, Some(b)) => b,
        (None, None) => 0.0,
    }
}

/// The largest step of inverse depth between neighbouring samples (a fraction of it) that still
/// counts as one surface when a sample is carried to its pixel's centre: a floor at 80° from the
/// view axis steps by about this much per sensor pixel of a 40-sample-wide map.
const TRANSFER_MAX_STEP: f64 = 0.25;

/// Drops the depth of every pixel outside the validity window ([`depth_window`]) of `norm`, in
/// every frame given, and counts them in `dropped` (as `out_of_window`, no longer `kept`).
pub fn apply_validity_window<'a>(
    frames: impl IntoIterator<Item = &'a mut Frame>,
    norm: &Normalization,
    dropped: &mut DepthDropped,
) {
    let (lo, hi) = depth_window(norm);
    for f in frames {
        let Some(depth) = &mut f.depth else { continue };
        for d in depth.data.iter_mut().filter(|d| **d > 0.0) {
            let v = *d as f64;
            if v <= lo || v >= hi {
                *d = 0.0;
                dropped.out_of_window += 1;
                dropped.kept -= 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> ImageF32 {
        let mut img = ImageF32::new(w, h, 1);
        for v in 0..h {
            for u in 0..w {
                img.pixel_mut(u, v)[0] = f(u, v);
            }
        }
        img
    }

    #[test]
    fn a_coarser_map_lands_each_sample_on_the_pixel_under_its_centre() {
        // 3×2 samples onto 12×8 pixels: sample (u, v) sits at ((u+½)·4, (v+½)·4) = pixel (4u+2, 4v+2).
        // Samples that do not continue one surface (steps over a quarter of the inverse depth)
        // are kept as they are.
        let coarse = grid(3, 2, |u, v| 2f32.powi(u as i32 + 3 * v as i32));
        let out = map_to_image(&coarse, 12, 8);
        for j in 0..8 {
            for i in 0..12 {
                let expected = if i % 4 == 2 && j % 4 == 2 {
                    coarse.pixel(i / 4, j / 4)[0]
                } else {
                    0.0
                };
                assert_eq!(out.pixel(i, j)[0], expected, "pixel ({i}, {j})");
            }
        }
    }

    #[test]
    fn a_finer_map_keeps_the_valid_sample_nearest_each_pixel_centre() {
        // 8×4 samples onto 4×2 pixels: samples 2i and 2i+1 land on pixel i, both ¼ pixel from its
        // centre; the first in scan order wins a tie. With the ties broken by an invalid sample,
        // its neighbour is kept.
        // Neighbours twice as far as each other: edges everywhere, nothing carried.
        let fine = grid(8, 4, |u, v| 2f32.powi(u as i32 + 8 * v as i32));
        let out = map_to_image(&fine, 4, 2);
        assert_eq!(out.pixel(1, 1)[0], fine.pixel(2, 2)[0]);
        let mut holes = fine.clone();
        holes.pixel_mut(2, 2)[0] = 0.0;
        let out = map_to_image(&holes, 4, 2);
        assert_eq!(out.pixel(1, 1)[0], fine.pixel(3, 2)[0]);
        // 3×3 samples onto one pixel: the centre sample is kept, not a mean.
        let mut nine = grid(3, 3, |_, _| 1.0);
        nine.pixel_mut(1, 1)[0] = 5.0;
        assert_eq!(map_to_image(&nine, 1, 1).data, vec![5.0]);
    }

    /// A plane seen by a pinhole camera, sampled on a grid 4× coarser than the image: every sample
    /// sits at the corner of four pixels, half a pixel off the one it lands on, and its z-depth is
    /// carried to that pixel's centre along the plane (inverse depth is affine in the image).
    /// Across an edge (a box in front of the plane), a sample keeps its own value.
    #[test]
    fn a_sample_is_carried_to_its_pixel_centre_along_the_surface() {
        // Inverse depth of a tilted plane in image pixel coordinates (x, y), pixel centres at +½.
        let plane = |x: f64, y: f64| 1.0 / (0.5 + 0.004 * x + 0.011 * y);
        let coarse = grid(10, 8, |u, v| {
            plane((u as f64 + 0.5) * 4.0, (v as f64 + 0.5) * 4.0) as f32
        });
        let out = map_to_image(&coarse, 40, 32);
        for v in 0..8 {
            for u in 0..10 {
                let (i, j) = (4 * u + 2, 4 * v + 2);
                let want = plane(i as f64 + 0.5, j as f64 + 0.5);
                let got = out.pixel(i, j)[0] as f64;
                assert!((got - want).abs() < 1e-5 * want, "pixel ({i}, {j}): {got} vs {want}");
                // The sample's own value is another depth (the correction matters).
                assert!((coarse.pixel(u, v)[0] as f64 - want).abs() > 1e-3 * want);
            }
        }
        // A box twice as near over samples 4..7 × 3..6: its samples and the plane's beside it
        // keep what they measured along the axis of the edge, so no depth leaks across it.
        let mut boxed = coarse.clone();
        for v in 3..6 {
            for u in 4..7 {
                boxed.pixel_mut(u, v)[0] *= 0.5;
            }
        }
        let out = map_to_image(&boxed, 40, 32);
        // The box's corner sample (4, 3): its left and upper neighbours are the plane, so its
        // slopes come from the box alone (its right and lower neighbours, two in a line each):
        // carried along the box.
        let z = out.pixel(18, 14)[0] as f64;
        let want = 0.5 * plane(18.5, 14.5);
        assert!((z - want).abs() < 1e-5 * want, "{z} vs {want}");
        // The plane sample left of the box (3, 3) takes its slope from the plane side only.
        let want = plane(14.5, 14.5);
        let got = out.pixel(14, 14)[0] as f64;
        assert!((got - want).abs() < 2e-3 * want, "{got} vs {want}");
    }

    #[test]
    fn confidence_values_other_than_0_1_2_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let depth = grid(4, 3, |_, _| 1.0);
        let p = dir.path().join("conf.npy");
        imageio::write_npy(&p, &grid(4, 3, |u, _| if u == 3 { 255.0 } else { 2.0 })).unwrap();
        let e = read_confidence(&p, &depth).unwrap_err();
        assert!(
            e.is_bad_input() && e.to_string().contains("conf.npy") && e.to_string().contains("(3, 0)"),
            "{e}"
        );
        imageio::write_npy(&p, &grid(4, 3, |u, _| u.min(2) as f32)).unwrap();
        assert_eq!(read_confidence(&p, &depth).unwrap()[..4], [0, 1, 2, 2]);
    }
}
