//! Error-guided adaptive sampling (paper Sec. 4.1.2, supp. "Details of Bubbling and Adaptive
//! Sampling"): one PDF map per training image over the pixels that have depth. A pixel's value is
//! its reconstruction error E (the depth error |D̂ − D|, in normalized units), clamped to `p_max`
//! and set to 0 below the pruning threshold P_min; bubble points are drawn with probability
//! proportional to it. Maps are initialised from every pixel's error at the end of warm-up and
//! updated with each batch's errors.
//!
//! The maps of a paper-sized scene (200 × 640×480) hold 61 M pixels, and each iteration both
//! updates and samples them, so the structure is a Fenwick tree over blocks of 64 pixels (f64 block
//! sums: O(log n) update and sampling, exact to f64) above the raw per-pixel f32 values (a linear
//! scan within the chosen block).

use rand::Rng;

const BLOCK: usize = 64;

/// A pixel of the training set: image index and pixel index (y · width + x) within it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRef {
    pub image: u32,
    pub pixel: u32,
}

#[derive(Clone, Debug)]
pub struct PdfMaps {
    /// Start of each image's pixels in the flat arrays.
    offsets: Vec<usize>,
    /// Per pixel: the current (pruned, clamped) error; pixels without depth stay at 0 forever.
    value: Vec<f32>,
    /// Per pixel: may it be sampled at all (has a valid depth)?
    valid: Vec<bool>,
    /// Fenwick tree (1-based) over block sums.
    tree: Vec<f64>,
    p_min: f32,
    p_max: f32,
}

impl PdfMaps {
    /// Empty maps (all zero) for images of the given pixel counts; `valid[i]` says which pixels of
    /// image i have depth.
    pub fn new(valid: Vec<Vec<bool>>, p_min: f32, p_max: f32) -> Self {
        let mut offsets = Vec::with_capacity(valid.len() + 1);
        let mut flat = Vec::new();
        for v in &valid {
            offsets.push(flat.len());
            flat.extend_from_slice(v);
        }
        offsets.push(flat.len());
        let n_blocks = flat.len().div_ceil(BLOCK);
        PdfMaps {
            offsets,
            value: vec![0.0; flat.len()],
            valid: flat,
            tree: vec![0.0; n_blocks + 1],
            p_min,
            p_max,
        }
    }

    /// Empty maps over every pixel of images with these pixel counts (the colour error maps).
    pub fn over_all_pixels(pixels: impl IntoIterator<Item = usize>, p_min: f32, p_max: f32) -> Self {
        Self::new(pixels.into_iter().map(|n| vec![true; n]).collect(), p_min, p_max)
    }

    fn flat_index(&self, p: PixelRef) -> usize {
        self.offsets[p.image as usize] + p.pixel as usize
    }

    fn unflatten(&self, i: usize) -> PixelRef {
        // offsets is sorted; the image is the last offset ≤ i.
        let image = self.offsets.partition_point(|&o| o <= i) - 1;
        PixelRef {
            image: image as u32,
            pixel: (i - self.offsets[image]) as u32,
        }
    }

    /// The value the map stores for an error E: clamped to p_max, pruned below P_min.
    pub fn pruned(&self, error: f32) -> f32 {
        let e = if error.is_finite() {
            error.min(self.p_max)
        } else {
            self.p_max
        };
        if e < self.p_min {
            0.0
        } else {
            e
        }
    }

    fn tree_add(&mut self, block: usize, delta: f64) {
        let mut i = block + 1;
        while i < self.tree.len() {
            self.tree[i] += delta;
            i += i & i.wrapping_neg();
        }
    }

    /// Records a pixel's latest error.
    pub fn update(&mut self, p: PixelRef, error: f32) {
        let i = self.flat_index(p);
        if !self.valid[i] {
            return;
        }
        let v = self.pruned(error);
        let delta = v as f64 - self.value[i] as f64;
        if delta != 0.0 {
            self.value[i] = v;
            self.tree_add(i / BLOCK, delta);
        }
    }

    /// Sets every pixel of one image at once (initialisation at the end of warm-up); `errors` has
    /// one entry per pixel of the image.
    pub fn set_image(&mut self, image: usize, errors: &[f32]) {
        let (a, b) = (self.offsets[image], self.offsets[image + 1]);
        assert_eq!(errors.len(), b - a, "set_image: one error per pixel");
        for (k, &e) in errors.iter().enumerate() {
            self.update(
                PixelRef {
                    image: image as u32,
                    pixel: k as u32,
                },
                e,
            );
        }
    }

    pub fn value(&self, p: PixelRef) -> f32 {
        self.value[self.flat_index(p)]
    }

    /// Sum of all values (the normalizer of the PDF).
    pub fn total(&self) -> f64 {
        // Prefix sum over all blocks.
        let mut i = self.tree.len() - 1;
        let mut s = 0.0;
        while i > 0 {
            s += self.tree[i];
            i -= i & i.wrapping_neg();
        }
        s.max(0.0)
    }

    /// Number of pixels that can currently be drawn (value > 0).
    pub fn active(&self) -> usize {
        self.value.iter().filter(|v| **v > 0.0).count()
    }

    /// Draws `n` pixels with probability proportional to their value (with replacement). Returns
    /// fewer (none) when every pixel is pruned.
    pub fn sample(&self, n: usize, rng: &mut impl Rng, out: &mut Vec<PixelRef>) {
        out.clear();
        let total = self.total();
        if total <= 0.0 {
            return;
        }
        let n_blocks = self.tree.len() - 1;
        let top = n_blocks.next_power_of_two();
        for _ in 0..n {
            let mut target = rng.gen::<f64>() * total;
            // Fenwick descent: the block where the prefix sum first exceeds the target.
            let mut pos = 0;
            let mut step = top;
            while step > 0 {
                let next = pos + step;
                if next <= n_blocks && self.tree[next] <= target {
                    target -= self.tree[next];
                    pos = next;
                }
                step >>= 1;
            }
            let block = pos.min(n_blocks - 1);
            let start = block * BLOCK;
            let end = (start + BLOCK).min(self.value.len());
            // Within the block: linear scan, falling back to the last positive value when rounding
            // leaves the target past the end.
            let mut chosen = None;
            let mut acc = 0.0f64;
            for i in start..end {
                let v = self.value[i] as f64;
                if v > 0.0 {
                    chosen = Some(i);
                    acc += v;
                    if acc > target {
                        break;
                    }
                }
            }
            if let Some(i) = chosen {
                out.push(self.unflatten(i));
            }
        }
    }
}

/// Every pixel's initial error from a depth render on a grid of stride `s` (the grid pixels
/// (a·s, b·s), `rendered` row-major over ⌈w/s⌉ × ⌈h/s⌉) and the pixel's own depth `gt` (≤ 0: none).
///
/// Rendering every pixel of a paper-sized scene (61 M rays) at the end of warm-up would cost more
/// than the whole stage, while copying a grid sample's error over its s×s block (what this
/// replaced) prunes any object thinner than s pixels that the grid misses: exactly what the maps
/// are for. Here the rendered depth, which is smooth wherever the SDF is, is interpolated and
/// each pixel's own depth compared with it: a missing pole keeps its error at every one of its
/// pixels. Where the grid's four corners straddle a rendered depth edge (they differ by more than
/// `edge`), interpolating across it would invent errors along every edge the SDF already has, so
/// the pixel takes the smallest error of the interpolation and of each corner's depth: a pixel on
/// either side of the edge matches its side, one of an object the SDF lacks matches neither.
pub fn grid_errors(width: usize, height: usize, s: usize, rendered: &[f32], gt: &[f32], edge: f32) -> Vec<f32> {
    assert!(s >= 1, "grid_errors: stride ≥ 1");
    let (gw, gh) = (width.div_ceil(s), height.div_ceil(s));
    assert_eq!(
        rendered.len(),
        gw * gh,
        "grid_errors: one rendered depth per grid pixel"
    );
    assert_eq!(gt.len(), width * height, "grid_errors: one depth per pixel");
    let mut out = vec![0.0f32; width * height];
    for j in 0..height {
        let (b0, b1) = (j / s, (j / s + 1).min(gh - 1));
        let fy = if b1 > b0 { (j - b0 * s) as f32 / s as f32 } else { 0.0 };
        for i in 0..width {
            let d = gt[j * width + i];
            if d <= 0.0 || !d.is_finite() {
                continue;
            }
            let (a0, a1) = (i / s, (i / s + 1).min(gw - 1));
            let fx = if a1 > a0 { (i - a0 * s) as f32 / s as f32 } else { 0.0 };
            let c = [
                rendered[b0 * gw + a0],
                rendered[b0 * gw + a1],
                rendered[b1 * gw + a0],
                rendered[b1 * gw + a1],
            ];
            let top = c[0] + fx * (c[1] - c[0]);
            let bottom = c[2] + fx * (c[3] - c[2]);
            let mut e = (top + fy * (bottom - top) - d).abs();
            let (lo, hi) = c.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
            if hi - lo > edge {
                e = c.iter().fold(e, |e, &v| e.min((v - d).abs()));
            }
            out[j * width + i] = e;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn maps(sizes: &[usize]) -> PdfMaps {
        PdfMaps::new(sizes.iter().map(|&n| vec![true; n]).collect(), 0.05, 10.0)
    }

    #[test]
    fn pruning_and_clamping() {
        let m = PdfMaps::new(vec![vec![true; 4]], 0.05, 1.0);
        assert_eq!(m.pruned(0.01), 0.0);
        assert_eq!(m.pruned(0.3), 0.3);
        assert_eq!(m.pruned(7.0), 1.0);
        assert_eq!(m.pruned(f32::NAN), 1.0);
    }

    #[test]
    fn samples_follow_the_errors_chi_square() {
        // 3 images, odd sizes so blocks straddle images; a few pixels with known weights.
        let mut m = maps(&[100, 37, 250]);
        let picks = [
            (0u32, 3u32, 1.0f32),
            (0, 99, 2.0),
            (1, 0, 3.0),
            (2, 64, 0.5),
            (2, 249, 3.5),
        ];
        for &(image, pixel, e) in &picks {
            m.update(PixelRef { image, pixel }, e);
        }
        // A pruned pixel never shows up.
        m.update(PixelRef { image: 2, pixel: 10 }, 0.01);
        assert_eq!(m.active(), 5);
        assert!((m.total() - 10.0).abs() < 1e-9);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let n = 200_000;
        let mut out = Vec::new();
        m.sample(n, &mut rng, &mut out);
        assert_eq!(out.len(), n);
        let mut chi2 = 0.0;
        for &(image, pixel, e) in &picks {
            let count = out.iter().filter(|p| **p == PixelRef { image, pixel }).count() as f64;
            let expected = n as f64 * e as f64 / 10.0;
            chi2 += (count - expected).powi(2) / expected;
        }
        assert_eq!(
            out.iter()
                .filter(|p| picks.iter().all(|q| (q.0, q.1) != (p.image, p.pixel)))
                .count(),
            0
        );
        // 4 degrees of freedom: P(χ² > 18.47) = 0.001.
        assert!(chi2 < 18.47, "chi2 = {chi2}");
    }

    #[test]
    fn updates_move_the_mass() {
        let mut m = maps(&[300]);
        let a = PixelRef { image: 0, pixel: 5 };
        let b = PixelRef { image: 0, pixel: 290 };
        m.update(a, 1.0);
        m.update(b, 1.0);
        m.update(a, 0.0); // fixed: pruned away
        assert_eq!(m.value(a), 0.0);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
        let mut out = Vec::new();
        m.sample(1000, &mut rng, &mut out);
        assert!(out.iter().all(|p| *p == b));
        m.update(b, 0.0);
        m.sample(10, &mut rng, &mut out);
        assert!(out.is_empty());
        assert!(m.total().abs() < 1e-12);
    }

    #[test]
    fn pixels_without_depth_are_never_drawn() {
        let mut valid = vec![true; 10];
        valid[4] = false;
        let mut m = PdfMaps::new(vec![valid], 0.05, 10.0);
        m.set_image(0, &[0.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let mut out = Vec::new();
        m.sample(100, &mut rng, &mut out);
        assert!(out.iter().all(|p| p.pixel == 9));
    }

    #[test]
    fn grid_errors_keep_an_object_thinner_than_the_stride() {
        // A tilted wall the SDF has, a step edge it has too (flat on both sides: a corner's depth
        // is only exact there), and a one-pixel pole it lacks, rendered on a stride-4 grid that
        // never lands on the pole.
        let (w, h, s) = (23, 13, 4);
        let wall = |i: usize, _j: usize| if i < 11 { 2.0 + 0.01 * i.min(8) as f32 } else { 3.5 };
        let mut gt: Vec<f32> = (0..w * h).map(|p| wall(p % w, p / w)).collect();
        for j in 0..h {
            gt[j * w + 6] = 1.2; // the pole, column 6
        }
        gt[0] = 0.0; // no depth: no error
        let (gw, gh) = (w.div_ceil(s), h.div_ceil(s));
        let rendered: Vec<f32> = (0..gw * gh).map(|g| wall((g % gw) * s, (g / gw) * s)).collect();
        let e = grid_errors(w, h, s, &rendered, &gt, 0.05);
        for j in 0..h {
            for i in 0..w {
                let v = e[j * w + i];
                if i == 6 {
                    assert!(v > 0.7, "pole pixel ({i},{j}) error {v}");
                } else {
                    // The wall is linear within each cell; either side of the edge matches a corner.
                    assert!(v < 1e-4, "pixel ({i},{j}) error {v}");
                }
            }
        }
        // Copying the grid sample's error over its block, as before, loses the pole.
        assert!(rendered.iter().all(|&r| r > 1.9));
        // Stride 1 is the exact error.
        let exact = grid_errors(w, h, 1, &gt.iter().map(|d| d + 0.3).collect::<Vec<_>>(), &gt, 0.05);
        assert!(exact.iter().skip(1).all(|&v| (v - 0.3).abs() < 1e-5));
    }
}
