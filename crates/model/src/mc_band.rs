//! Narrow-band sampling for [`marching_cubes`](crate::marching_cubes::marching_cubes) over a field
//! with a known Lipschitz bound, such as a trained SDF (the eikonal term keeps |∇f| near 1).
//!
//! Why: the zero set of an indoor room fills a tiny part of its box, and a dense grid fine enough
//! for a 1.2 cm chandelier arm (1024 samples over a 6 m room) is a billion SDF evaluations, most of
//! them in empty space. Here the field is first sampled on a coarse grid (every `step`-th fine
//! sample per axis). A block of `step`³ fine cells whose eight coarse corners share a sign and all
//! satisfy |f − iso| > L·(half the block diagonal) cannot hold a crossing if f is L-Lipschitz
//! (every point of the block lies within half its diagonal of a corner); its fine
//! samples are filled by trilinear interpolation of the corners (same sign, so no triangle) and
//! only the samples of the other blocks are evaluated. Each fine sample still gets exactly one
//! value, so the mesh stays watertight whatever the field does; where the field obeys the bound
//! the mesh equals the dense one.

use crate::marching_cubes::McGrid;
use i2sdf_data::DataError;

/// Which fine samples to evaluate: see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NarrowBand {
    /// Fine cells per coarse cell along each axis (≥ 1; 1 evaluates everything).
    pub step: usize,
    /// Lipschitz bound assumed of the field (> 0): larger is safer and evaluates more.
    pub lipschitz: f32,
    /// Inside the active blocks, a second level ([`SubBand`]): blocks of `step / 2` fine cells
    /// (an even `step` ≥ 4 only), tested as the first level's blocks are, from the samples at
    /// their corners, so that only the fine samples of the active sub-blocks are evaluated.
    pub refine: bool,
}

impl NarrowBand {
    /// The band [`extract_mesh`](crate::sdf_mesh::extract_mesh) uses for an SDF at
    /// `resolution`: a coarse grid of about 256 samples along the longest side, and twice the
    /// eikonal slope as the bound, since a trained SDF is only near 1-Lipschitz. At 1024 a step of
    /// 4 beat 8 and 2 on the default room's trained run (49.8 s against 66.9 and 54.4 s, meshes
    /// byte-identical) and on a 30-iteration one (32.7 against 40.6 s): finer blocks hug the
    /// surface closer, until the coarse grid itself costs more than it saves. The test against
    /// half the block diagonal (the full diagonal before) gave the default room's stage-2 run the
    /// same mesh, byte for byte, in 29.4 s instead of 37.7 s (bench ~105 ms); with it, a step
    /// of 8 took 40.4 s against 29.3 s for 4 (bench ~120 ms).
    ///
    /// Refined ([`SubBand`]): at 1024 on the default room's stage-2 run, 77 M SDF samples → 49 M.
    pub fn for_sdf(resolution: usize) -> NarrowBand {
        NarrowBand {
            step: (resolution / 256).clamp(1, 8),
            lipschitz: 2.0,
            refine: true,
        }
    }

    /// Fine cells per side of the second level's blocks (None: no second level).
    pub(crate) fn sub_step(&self) -> Option<usize> {
        (self.refine && self.step >= 4 && self.step % 2 == 0).then_some(self.step / 2)
    }
}

/// The coarse samples, which blocks are active, and which fine samples therefore get evaluated.
pub(crate) struct BandMask {
    /// Fine index of each coarse sample, per axis (multiples of `step`, then the last sample).
    coarse: [Vec<usize>; 3],
    /// Coarse values, x fastest.
    values: Vec<f32>,
    /// Per block (x fastest): does it need its fine samples evaluated?
    active: Vec<bool>,
    /// Per fine index per axis: the first and last block containing it (two on a block face).
    blocks_of: [Vec<(u32, u32)>; 3],
}

impl BandMask {
    /// Bytes held for a grid (coarse values, block flags and the per-axis tables).
    pub(crate) fn memory_estimate(grid: &McGrid, band: &NarrowBand) -> f64 {
        let coarse = grid.samples.map(|n| ((n - 1) / band.step.max(1) + 2) as f64);
        let samples = coarse[0] * coarse[1] * coarse[2];
        samples * 4.0 + samples + grid.samples.iter().map(|&n| n as f64 * 24.0).sum::<f64>()
    }

    /// Samples the coarse grid through `eval` (which checks finiteness) and marks the blocks.
    pub(crate) fn build(
        grid: &McGrid,
        band: &NarrowBand,
        iso: f32,
        batch_points: usize,
        mut eval: impl FnMut(&[[f32; 3]], &mut [f32]) -> Result<(), DataError>,
    ) -> Result<BandMask, DataError> {
        if band.step == 0 || !(band.lipschitz.is_finite() && band.lipschitz > 0.0) {
            return Err(DataError::invalid(format!(
                "marching cubes narrow band: step must be ≥ 1 and the Lipschitz bound > 0, got {} and {}",
                band.step, band.lipschitz
            )));
        }
        let coarse: [Vec<usize>; 3] = std::array::from_fn(|a| {
            let n = grid.samples[a];
            let mut c: Vec<usize> = (0..n).step_by(band.step).collect();
            if *c.last().unwrap() != n - 1 {
                c.push(n - 1);
            }
            c
        });
        let [cx, cy, cz] = [coarse[0].len(), coarse[1].len(), coarse[2].len()];
        let mut values = vec![0.0f32; cx * cy * cz];
        let mut points = Vec::with_capacity(batch_points.min(values.len()));
        let mut start = 0;
        while start < values.len() {
            let end = (start + batch_points).min(values.len());
            points.clear();
            for flat in start..end {
                let (i, j, k) = (flat % cx, (flat / cx) % cy, flat / (cx * cy));
                let p = grid.point(coarse[0][i], coarse[1][j], coarse[2][k]);
                points.push([p[0] as f32, p[1] as f32, p[2] as f32]);
            }
            eval(&points, &mut values[start..end])?;
            start = end;
        }
        let step = grid.step();
        let (bx, by, bz) = (cx - 1, cy - 1, cz - 1);
        let mut active = vec![false; bx * by * bz];
        for k in 0..bz {
            for j in 0..by {
                for i in 0..bx {
                    let ext = [
                        (coarse[0][i + 1] - coarse[0][i]) as f64 * step[0],
                        (coarse[1][j + 1] - coarse[1][j]) as f64 * step[1],
                        (coarse[2][k + 1] - coarse[2][k]) as f64 * step[2],
                    ];
                    // Every point of the block lies within half its diagonal of a corner.
                    let diagonal = (ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2]).sqrt();
                    let threshold = band.lipschitz as f64 * 0.5 * diagonal;
                    let (mut below, mut near) = (0, false);
                    for c in 0..8 {
                        let v = values[(i + (c & 1)) + cx * ((j + ((c >> 1) & 1)) + cy * (k + (c >> 2)))];
                        below += (v < iso) as usize;
                        near |= ((v - iso).abs() as f64) <= threshold;
                    }
                    active[i + bx * (j + by * k)] = near || (below != 0 && below != 8);
                }
            }
        }
        let blocks_of = std::array::from_fn(|a| {
            let blocks = coarse[a].len() - 1;
            (0..grid.samples[a])
                .map(|i| {
                    let hi = (i / band.step).min(blocks - 1);
                    let lo = if i % band.step == 0 && i > 0 {
                        i / band.step - 1
                    } else {
                        hi
                    };
                    (lo as u32, hi as u32)
                })
                .collect()
        });
        Ok(BandMask {
            coarse,
            values,
            active,
            blocks_of,
        })
    }

    fn blocks(&self) -> [usize; 3] {
        std::array::from_fn(|a| self.coarse[a].len() - 1)
    }

    /// Blocks per axis that are `step` fine cells wide (all but a last, narrower one).
    fn regular_blocks(&self) -> [usize; 3] {
        std::array::from_fn(|a| {
            let c = &self.coarse[a];
            let last = c.len() - 2;
            if c.len() >= 2 && c[last + 1] - c[last] == c[1] - c[0] {
                last + 1
            } else {
                last
            }
        })
    }

    fn block_active(&self, a: usize, b: usize, c: usize) -> bool {
        let [bx, by, _] = self.blocks();
        self.active[a + bx * (b + by * c)]
    }

    /// Share of the blocks that are evaluated.
    #[cfg(test)]
    pub(crate) fn active_fraction(&self) -> f64 {
        self.active.iter().filter(|&&a| a).count() as f64 / self.active.len().max(1) as f64
    }

    /// An empty row view, to be moved onto rows with [`BandRow::move_to`] (its buffers are
    /// kept from row to row).
    pub(crate) fn row_view<'m>(&'m self, sub: Option<&'m SubBand>) -> BandRow<'m> {
        BandRow {
            mask: self,
            active_x: Vec::new(),
            columns: Vec::new(),
            sub: sub.map(|band| SubRow {
                band,
                irregular_x: Vec::new(),
                active_x: Vec::new(),
                combos: Vec::new(),
                lattice: None,
            }),
        }
    }
}

/// The band's second level: inside the active blocks that are `step` cells wide (the regular
/// ones: all but the last along an axis), blocks of `sub = step / 2` cells, each tested from the
/// samples at its corners (the lattice of every `sub`-th fine sample) as the first level tests
/// its blocks, and filled by trilinear interpolation of them where it cannot hold a crossing.
/// The lattice is evaluated a z-plane at a time as the sweep comes to it (a few planes alive),
/// only at the samples of active regular blocks; its values are the fine samples' own there.
///
/// Measured on the default room's stage-2 run at 1024 (grid 1024×568×909, bench ~113 ms): the
/// first level alone evaluated 76.9 M samples in 19.3 s; with this level 48.8 M in 14.9 s. The
/// faces are the same; 9 of the 4.4 M vertices moved, by at most 1.5 µm (a lattice sample's
/// value comes from another batch of the sampler, whose sums round differently).
pub(crate) struct SubBand {
    sub: usize,
    /// Sub-blocks per first-level block along an axis (2).
    ratio: usize,
    /// Lattice samples per axis over the regular blocks.
    lattice: [usize; 3],
    /// L · half a sub-block's diagonal: a corner value further than this from the iso level
    /// keeps the level set out of the sub-block.
    threshold: f32,
    iso: f32,
    /// Lattice planes evaluated (by lattice z index), x fastest; NaN where no active regular
    /// block holds the sample (never read there).
    planes: std::collections::BTreeMap<usize, Vec<f32>>,
    /// Per sub-block z slab: which of its sub-blocks (x fastest) may hold the level set (false
    /// too for those in inactive blocks).
    slabs: std::collections::BTreeMap<usize, Vec<bool>>,
}

impl SubBand {
    /// The second level of `mask` (None where `band` has none or no block is regular).
    pub(crate) fn new(grid: &McGrid, mask: &BandMask, band: &NarrowBand, iso: f32) -> Option<SubBand> {
        let sub = band.sub_step()?;
        let regular = mask.regular_blocks();
        if regular.contains(&0) {
            return None;
        }
        let ratio = band.step / sub;
        let step = grid.step();
        let diagonal = (0..3).map(|a| (sub as f64 * step[a]).powi(2)).sum::<f64>().sqrt();
        Some(SubBand {
            sub,
            ratio,
            lattice: regular.map(|r| r * ratio + 1),
            threshold: (band.lipschitz as f64 * 0.5 * diagonal) as f32,
            iso,
            planes: Default::default(),
            slabs: Default::default(),
        })
    }

    /// Bytes held at most (three lattice planes and two slabs of flags).
    pub(crate) fn memory_estimate(grid: &McGrid, band: &NarrowBand) -> f64 {
        match band.sub_step() {
            Some(sub) => {
                let n = grid.samples.map(|n| (n / sub + 1) as f64);
                n[0] * n[1] * (4.0 * 4.0 + 3.0)
            }
            None => 0.0,
        }
    }

    fn sub_blocks(&self) -> [usize; 3] {
        self.lattice.map(|n| n - 1)
    }

    /// Readies the lattice planes and sub-block slabs that fine planes `first..=last` need
    /// (evaluating new lattice samples through `eval`, in batches of `batch_points`), and
    /// drops those no later plane needs.
    pub(crate) fn prepare(
        &mut self,
        grid: &McGrid,
        mask: &BandMask,
        first: usize,
        last: usize,
        batch_points: usize,
        mut eval: impl FnMut(&[[f32; 3]], &mut [f32]) -> Result<(), DataError>,
    ) -> Result<(), DataError> {
        let [nsx, nsy, nsz] = self.sub_blocks();
        // Sub-block slabs touching the planes: those holding them (two where a plane is a slab
        // face), each needing the lattice planes at both its faces.
        let slab_lo = (first / self.sub).saturating_sub(1);
        let slab_hi = (last / self.sub).min(nsz - 1);
        self.planes.retain(|&r, _| r >= slab_lo);
        self.slabs.retain(|&z, _| z >= slab_lo);
        let (lx, ly) = (self.lattice[0], self.lattice[1]);
        for r in slab_lo..=(slab_hi + 1).min(self.lattice[2] - 1) {
            if self.planes.contains_key(&r) {
                continue;
            }
            let mut values = vec![f32::NAN; lx * ly];
            let (mut points, mut targets) = (Vec::new(), Vec::new());
            // Per (x, y) block: is a block holding the plane there active and regular?
            let z = mask.blocks_of[2][r * self.sub];
            let [bx, by, _] = mask.blocks();
            let regular = mask.regular_blocks();
            let mut held = vec![false; bx * by];
            for b in 0..regular[1] {
                for a in 0..regular[0] {
                    held[a + bx * b] =
                        (z.0..=z.1).any(|c| (c as usize) < regular[2] && mask.block_active(a, b, c as usize));
                }
            }
            for q in 0..ly {
                let y = mask.blocks_of[1][q * self.sub];
                for p in 0..lx {
                    let x = mask.blocks_of[0][p * self.sub];
                    let any = (y.0..=y.1).any(|b| (x.0..=x.1).any(|a| held[a as usize + bx * b as usize]));
                    if any {
                        let g = grid.point(p * self.sub, q * self.sub, r * self.sub);
                        points.push([g[0] as f32, g[1] as f32, g[2] as f32]);
                        targets.push(p + lx * q);
                    }
                }
            }
            let mut got = vec![0.0; points.len()];
            for (p, v) in points
                .chunks(batch_points.max(1))
                .zip(got.chunks_mut(batch_points.max(1)))
            {
                eval(p, v)?;
            }
            for (t, v) in targets.into_iter().zip(got) {
                values[t] = v;
            }
            self.planes.insert(r, values);
        }
        for sz in slab_lo..=slab_hi {
            if self.slabs.contains_key(&sz) {
                continue;
            }
            let (lo, hi) = (&self.planes[&sz], &self.planes[&(sz + 1)]);
            let mut flags = vec![false; nsx * nsy];
            for sy in 0..nsy {
                for sx in 0..nsx {
                    let (a, b, c) = (sx / self.ratio, sy / self.ratio, sz / self.ratio);
                    if !mask.block_active(a, b, c) {
                        continue;
                    }
                    let (mut below, mut near) = (0, false);
                    for corner in 0..8 {
                        let plane = if corner >> 2 == 0 { lo } else { hi };
                        let v = plane[(sx + (corner & 1)) + lx * (sy + ((corner >> 1) & 1))];
                        below += (v < self.iso) as usize;
                        near |= (v - self.iso).abs() <= self.threshold;
                    }
                    flags[sx + nsx * sy] = near || (below != 0 && below != 8);
                }
            }
            self.slabs.insert(sz, flags);
        }
        Ok(())
    }

    /// The sub-blocks along an axis holding fine sample `f` (first and last; None past the
    /// lattice).
    fn subs_of(&self, f: usize, axis: usize) -> Option<(usize, usize)> {
        let n = self.lattice[axis] - 1;
        if f > n * self.sub {
            return None;
        }
        let hi = (f / self.sub).min(n - 1);
        let lo = if f % self.sub == 0 && f > 0 {
            f / self.sub - 1
        } else {
            hi
        };
        Some((lo, hi))
    }
}

/// A (y, z) sub-block holding a row: its indices, the row's fractions in it, and the lattice
/// rows at its corners (index dy + 2 dz, x fastest).
struct Combo<'m> {
    sy: usize,
    sz: usize,
    ty: f32,
    tz: f32,
    rows: [&'m [f32]; 4],
}

/// A [`BandRow`]'s view of the second level: per first-level x block, whether an active block
/// holding the row there is irregular (its samples are all evaluated); per x sub-block, whether
/// a sub-block holding the row there may hold the level set; the (y, z) sub-blocks holding the
/// row with the row's fractions in them; the row's lattice values where it is a lattice row.
struct SubRow<'m> {
    band: &'m SubBand,
    irregular_x: Vec<bool>,
    active_x: Vec<bool>,
    /// The (y, z) sub-blocks holding the row.
    combos: Vec<Combo<'m>>,
    lattice: Option<&'m [f32]>,
}

/// One row of fine samples of a [`BandMask`]: which of its samples need evaluating, and the fill
/// of the others. Why by row: asked sample by sample, the block lookups and the corner gathers of
/// the 95 % of samples that are filled took a sixth of the mesh's CPU time at 1024.
pub(crate) struct BandRow<'m> {
    mask: &'m BandMask,
    /// Per x block: is any block holding this row's samples of it active?
    active_x: Vec<bool>,
    /// Per coarse x: the bilinear interpolation at the row's (y, z) of the four coarse values
    /// about it in that x plane (the fill is then one lerp in x between two of them).
    columns: Vec<f32>,
    sub: Option<SubRow<'m>>,
}

impl<'m> BandRow<'m> {
    /// Makes this the view of row `j` of fine plane `k`.
    pub(crate) fn move_to(&mut self, j: usize, k: usize) {
        let m = self.mask;
        let [bx, by, _] = m.blocks();
        let (y, z) = (m.blocks_of[1][j], m.blocks_of[2][k]);
        self.active_x.clear();
        self.active_x.extend(
            (0..bx)
                .map(|a| (z.0..=z.1).any(|c| (y.0..=y.1).any(|b| m.active[a + bx * (b as usize + by * c as usize)]))),
        );
        let (cx, cy) = (m.coarse[0].len(), m.coarse[1].len());
        let (b1, b2) = (y.1 as usize, z.1 as usize);
        let frac = |a: usize, b: usize, i: usize| {
            let (lo, hi) = (m.coarse[a][b], m.coarse[a][b + 1]);
            (i - lo) as f32 / (hi - lo) as f32
        };
        let (ty, tz) = (frac(1, b1, j), frac(2, b2, k));
        let w = [(1.0 - ty) * (1.0 - tz), ty * (1.0 - tz), (1.0 - ty) * tz, ty * tz];
        self.columns.clear();
        self.columns.extend((0..cx).map(|x| {
            (0..4).fold(0.0, |v, c| {
                v + w[c] * m.values[x + cx * ((b1 + (c & 1)) + cy * (b2 + (c >> 1)))]
            })
        }));
        if let Some(s) = self.sub.as_mut() {
            let band = s.band;
            let regular = m.regular_blocks();
            s.irregular_x.clear();
            s.irregular_x.extend((0..bx).map(|a| {
                (z.0..=z.1).any(|c| {
                    (y.0..=y.1).any(|b| {
                        let regular = a < regular[0] && (b as usize) < regular[1] && (c as usize) < regular[2];
                        !regular && m.active[a + bx * (b as usize + by * c as usize)]
                    })
                })
            }));
            s.combos.clear();
            if let (Some(sy), Some(sz)) = (band.subs_of(j, 1), band.subs_of(k, 2)) {
                let lx = band.lattice[0];
                for sz in sz.0..=sz.1 {
                    for sy in sy.0..=sy.1 {
                        let t = |f: usize, b: usize| (f - b * band.sub) as f32 / band.sub as f32;
                        let (lo, hi) = (&band.planes[&sz], &band.planes[&(sz + 1)]);
                        let row = |p: &'m [f32], y: usize| &p[lx * y..lx * (y + 1)];
                        s.combos.push(Combo {
                            sy,
                            sz,
                            ty: t(j, sy),
                            tz: t(k, sz),
                            rows: [row(lo, sy), row(lo, sy + 1), row(hi, sy), row(hi, sy + 1)],
                        });
                    }
                }
            }
            let nsx = band.sub_blocks()[0];
            s.active_x.clear();
            s.active_x.resize(nsx, false);
            for c in &s.combos {
                let flags = &band.slabs[&c.sz][nsx * c.sy..nsx * (c.sy + 1)];
                s.active_x.iter_mut().zip(flags).for_each(|(a, &f)| *a |= f);
            }
            let lx = band.lattice[0];
            s.lattice = (j % band.sub == 0 && k % band.sub == 0 && j / band.sub < band.lattice[1])
                .then(|| band.planes.get(&(k / band.sub)))
                .flatten()
                .map(|p| &p[lx * (j / band.sub)..lx * (j / band.sub + 1)]);
        }
    }

    /// The value of fine sample i of the row where it need not be evaluated: filled in an
    /// inactive block ([`BandRow::fill`]) or sub-block, or the lattice's; None where the sampler
    /// must give it.
    #[inline]
    pub(crate) fn value(&self, i: usize) -> Option<f32> {
        let x = self.mask.blocks_of[0][i];
        if !(self.active_x[x.0 as usize] || self.active_x[x.1 as usize]) {
            return Some(self.fill(i));
        }
        let s = self.sub.as_ref()?;
        if s.irregular_x[x.0 as usize] || s.irregular_x[x.1 as usize] {
            return None;
        }
        let band = s.band;
        // In an active regular block (x, and the row's y and z, lie within the lattice).
        let sx = band.subs_of(i, 0)?;
        if let Some(row) = s.lattice.filter(|_| i % band.sub == 0) {
            return Some(row[i / band.sub]);
        }
        if s.active_x[sx.0] || s.active_x[sx.1] {
            return None;
        }
        // Every sub-block holding the sample is inactive or in an inactive block: the first in
        // an active block is one of the former.
        for sxx in sx.0..=sx.1 {
            for c in &s.combos {
                if !self
                    .mask
                    .block_active(sxx / band.ratio, c.sy / band.ratio, c.sz / band.ratio)
                {
                    continue;
                }
                let t = [(i - sxx * band.sub) as f32 / band.sub as f32, c.ty, c.tz];
                let mut v = 0.0;
                for corner in 0..8 {
                    let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
                    let w = (if dx == 1 { t[0] } else { 1.0 - t[0] })
                        * (if dy == 1 { t[1] } else { 1.0 - t[1] })
                        * (if dz == 1 { t[2] } else { 1.0 - t[2] });
                    v += w * c.rows[dy + 2 * dz][sxx + dx];
                }
                return Some(v);
            }
        }
        None
    }

    /// The value of unevaluated fine sample i: trilinear in the corners of its (inactive) block
    /// (bilinear in y and z per corner column, [`BandRow::columns`], then linear in x). Why in
    /// that order: the eight-term sum per sample was a tenth of the mesh's CPU time at 1024,
    /// filled samples being nine in ten.
    #[inline]
    fn fill(&self, i: usize) -> f32 {
        let b = self.mask.blocks_of[0][i].1 as usize;
        let (lo, hi) = (self.mask.coarse[0][b], self.mask.coarse[0][b + 1]);
        let t = (i - lo) as f32 / (hi - lo) as f32;
        (1.0 - t) * self.columns[b] + t * self.columns[b + 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::marching_cubes::{marching_cubes, McOptions};
    use i2sdf_data::mesh::TriangleMesh;
    use std::sync::atomic::{AtomicU64, Ordering};

    /// A sphere and a rod of radius 0.01 (under two cells of the 256 grid, a third of a cell of
    /// the coarse one): exact SDFs, so 1-Lipschitz.
    fn sphere_and_rod(points: &[[f32; 3]], out: &mut [f32]) {
        for (p, o) in points.iter().zip(out.iter_mut()) {
            let sphere = ((p[0] - 0.3).powi(2) + (p[1] + 0.2).powi(2) + p[2].powi(2)).sqrt() - 0.35;
            let rod = ((p[1] - 0.5013).powi(2) + (p[2] + 0.1007).powi(2)).sqrt() - 0.01;
            let rod = rod.max(p[0].abs() - 0.6);
            *o = sphere.min(rod);
        }
    }

    /// The mesh of `field` on the cube [-1, 1]³ and the number of samples it evaluated.
    fn extract(
        resolution: usize,
        band: Option<NarrowBand>,
        field: impl Fn(&[[f32; 3]], &mut [f32]) + Sync,
    ) -> (TriangleMesh, u64) {
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], resolution).unwrap();
        let calls = AtomicU64::new(0);
        let options = McOptions {
            narrow_band: band,
            ..Default::default()
        };
        let mesh = marching_cubes(&grid, &options, |p, v| {
            calls.fetch_add(p.len() as u64, Ordering::Relaxed);
            field(p, v)
        })
        .unwrap();
        (mesh, calls.into_inner())
    }

    #[test]
    fn band_mesh_equals_the_dense_mesh_of_a_lipschitz_field_for_a_fraction_of_the_samples() {
        let (dense, dense_calls) = extract(256, None, sphere_and_rod);
        for step in [2, 4, 8] {
            let band = NarrowBand {
                step,
                lipschitz: 1.0,
                refine: false,
            };
            let (banded, calls) = extract(256, Some(band), sphere_and_rod);
            assert_eq!(banded, dense, "step {step}");
            assert!(calls * 4 < dense_calls, "step {step}: {calls} of {dense_calls} samples");
            if step >= 4 {
                let refined = NarrowBand { refine: true, ..band };
                let (mesh, refined_calls) = extract(256, Some(refined), sphere_and_rod);
                assert_eq!(mesh, dense, "step {step}, refined");
                assert!(
                    refined_calls * 10 < calls * 8,
                    "step {step}: refined {refined_calls} against {calls} samples"
                );
            }
        }
        // The rod is in the mesh: its vertices lie on the cylinder.
        let on_rod = dense
            .positions
            .iter()
            .filter(|p| p[0].abs() < 0.55 && p[1] > 0.4)
            .map(|p| ((p[1] - 0.5013).powi(2) + (p[2] + 0.1007).powi(2)).sqrt())
            .collect::<Vec<_>>();
        assert!(
            on_rod.len() > 500 && on_rod.iter().all(|r| (r - 0.01).abs() < 0.004),
            "{}",
            on_rod.len()
        );
        assert!(dense.is_watertight_and_consistently_oriented());
    }

    #[test]
    fn a_field_that_breaks_the_bound_still_gives_a_watertight_mesh() {
        // Steep noise (slope ~ 40) on a sphere: the band misses some crossings, but every sample
        // has one value, so what comes out is closed.
        let field = |points: &[[f32; 3]], out: &mut [f32]| {
            for (p, o) in points.iter().zip(out.iter_mut()) {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                *o = r - 0.5 + 0.2 * (40.0 * p[0]).sin() * (37.0 * p[1]).cos();
            }
        };
        let (mesh, _) = extract(
            96,
            Some(NarrowBand {
                step: 4,
                lipschitz: 1.0,
                refine: false,
            }),
            field,
        );
        assert!(!mesh.faces.is_empty());
        assert!(mesh.is_watertight_and_consistently_oriented());
    }

    #[test]
    fn bad_band_settings_are_refused() {
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], 16).unwrap();
        for band in [
            NarrowBand {
                step: 0,
                lipschitz: 1.0,
                refine: false,
            },
            NarrowBand {
                step: 2,
                lipschitz: 0.0,
                refine: false,
            },
            NarrowBand {
                step: 2,
                lipschitz: f32::NAN,
                refine: false,
            },
        ] {
            let err = BandMask::build(&grid, &band, 0.0, 64, |_, _| Ok(())).err().unwrap();
            assert!(err.is_bad_input() && err.to_string().contains("narrow band"), "{err}");
        }
    }

    #[test]
    fn blocks_cover_every_sample_once_or_on_a_face_twice() {
        let grid = McGrid::cubic([-1.0; 3], [1.0; 3], 19).unwrap();
        let mask = BandMask::build(
            &grid,
            &NarrowBand {
                step: 4,
                lipschitz: 1.0,
                refine: false,
            },
            0.0,
            1000,
            |p, v| {
                p.iter().zip(v.iter_mut()).for_each(|(p, v)| *v = p[0] + 10.0);
                Ok(())
            },
        )
        .unwrap();
        // 19 samples: coarse at 0, 4, 8, 12, 16, 18 → five blocks, the last two cells wide.
        assert_eq!(mask.coarse[0], vec![0, 4, 8, 12, 16, 18]);
        assert_eq!(mask.blocks_of[0][0], (0, 0));
        assert_eq!(mask.blocks_of[0][4], (0, 1));
        assert_eq!(mask.blocks_of[0][17], (4, 4));
        assert_eq!(mask.blocks_of[0][18], (4, 4));
        // A linear field far from its zero: no block active, and the fill is exact.
        assert_eq!(mask.active_fraction(), 0.0);
        let x = grid.point(17, 3, 5)[0] as f32;
        let mut row = mask.row_view(None);
        row.move_to(3, 5);
        assert!((row.value(17).unwrap() - (x + 10.0)).abs() < 1e-5);
    }
}
