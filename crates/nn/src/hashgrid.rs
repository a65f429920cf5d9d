//! Multi-resolution hash encoding (Müller et al. 2022, Instant-NGP, Sec. 3), with its Jacobian
//! w.r.t. the position and the sparse gradients of its tables.
//!
//! Level `l` has resolution `N_l = ⌊N_min · b^l⌋`, `b = exp((ln N_max − ln N_min)/(L − 1))`
//! (their eq. 2–3). A position `x ∈ [−bound, bound]³` maps to `p = N_l (x + bound)/(2 bound)`; the
//! feature is the trilinear interpolation `Σ_c w_c(p) T_l[idx(c)]` of the cell's 8 corners.
//! Coarse levels whose `(N_l + 1)³` vertices fit the table are stored densely (one entry per vertex,
//! no collisions); finer levels hash the vertex with their `π`-xor hash (`π = 1, 2654435761,
//! 805459861`) modulo the table size `T`.
//!
//! Since the encoding is linear in the table, its Jacobian is `∂e/∂x_k = Σ_c (∂w_c/∂x_k) T[idx(c)]`,
//! and the gradient of `⟨ā, e⟩ + ⟨g, J v⟩` (`v` a cotangent of the spatial gradient) w.r.t. the
//! table entry of corner `c` is `w_c ā + (v·∇w_c) g`: the eikonal term's double backward costs no
//! more scatter traffic than the plain backward.
//!
//! Everything here runs *level-major* (one level over all points, levels in parallel): a level's
//! table (≤ 4 MiB at `T = 2^19`, 2 features) stays cache-resident while all points visit it, the
//! buffers are `[level][point][feature]`, and the backward's scatter-add needs neither atomics nor
//! per-thread copies of the tables, because each thread owns whole levels.

use crate::linalg::split_lengths_mut;

#[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
#[path = "hashgrid_simd.rs"]
mod simd;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Hash-grid hyper-parameters (the defaults are the representative configuration of the issue).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HashGridConfig {
    pub levels: usize,
    pub features_per_level: usize,
    pub log2_table_size: u32,
    pub base_resolution: u32,
    pub finest_resolution: u32,
    /// Positions are expected in `[−bound, bound]³` (clamped outside, with zero spatial derivative).
    pub bound: f32,
}

impl Default for HashGridConfig {
    fn default() -> Self {
        HashGridConfig {
            levels: 16,
            features_per_level: 2,
            log2_table_size: 19,
            base_resolution: 16,
            finest_resolution: 2048,
            bound: 1.0,
        }
    }
}

/// One level's resolution and table slice.
#[derive(Clone, Debug)]
pub struct HashLevel {
    pub resolution: u32,
    /// First entry of this level in the table (a multiple of 64, so touched-bitmap words never span
    /// two levels).
    pub offset: usize,
    /// Entries of this level.
    pub size: usize,
    pub dense: bool,
}

/// The hash-grid encoding and its parameters (`entries × features_per_level`, level after level).
#[derive(Clone, Debug)]
pub struct HashGrid {
    pub config: HashGridConfig,
    pub levels: Vec<HashLevel>,
    pub params: Vec<f32>,
}

/// Gradient of a hash grid's tables, with a bitmap of the entries that received any (for the lazy
/// Adam update of [`crate::adam`]). Entries not marked are exactly zero. [`crate::Adam::update_sparse`]
/// clears both; after a dense [`crate::Adam::update`] clear the bitmap yourself (`touched.fill(0)`).
#[derive(Clone, Debug)]
pub struct HashGridGrad {
    pub values: Vec<f32>,
    pub touched: Vec<u64>,
}

impl HashGridGrad {
    pub fn new(grid: &HashGrid) -> Self {
        HashGridGrad {
            values: vec![0.0; grid.params.len()],
            touched: vec![0; grid.entries().div_ceil(64)],
        }
    }
}

const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// How many points ahead the table lines are prefetched.
const PREFETCH: usize = 8;

/// One point's cell on one level, factorized per axis: corner `(i, j, k)` has index
/// `offset + combine(ix[i], iy[j], iz[k])`, weight `w[0][i]·w[1][j]·w[2][k]` and
/// `∂w/∂x_0 = dw[0][i]·w[1][j]·w[2][k]` (and likewise for the other axes).
struct Cell {
    ix: [u32; 2],
    iy: [u32; 2],
    iz: [u32; 2],
    w: [[f32; 2]; 3],
    dw: [[f32; 2]; 3],
}

/// Per-level constants of the corner lookup.
#[derive(Clone, Copy)]
struct LevelGeometry {
    res: f32,
    max_cell: u32,
    scale: f32,
    bound: f32,
    dense: bool,
    stride: u32,
    mask: u32,
    offset: u32,
}

impl LevelGeometry {
    #[inline(always)]
    fn locate(&self, x: &[f32]) -> Cell {
        let mut base = [0u32; 3];
        let mut w = [[0f32; 2]; 3];
        let mut dw = [[0f32; 2]; 3];
        for k in 0..3 {
            let p = (x[k] + self.bound) * self.scale;
            let inside = p > 0.0 && p < self.res;
            let p = p.clamp(0.0, self.res);
            let c = (p as u32).min(self.max_cell);
            let f = p - c as f32;
            base[k] = c;
            w[k] = [1.0 - f, f];
            let d = if inside { self.scale } else { 0.0 };
            dw[k] = [-d, d];
        }
        if self.dense {
            let s2 = self.stride * self.stride;
            Cell {
                ix: [base[0], base[0] + 1],
                iy: [base[1] * self.stride, (base[1] + 1) * self.stride],
                iz: [base[2] * s2, (base[2] + 1) * s2],
                w,
                dw,
            }
        } else {
            Cell {
                ix: [base[0].wrapping_mul(PRIMES[0]), (base[0] + 1).wrapping_mul(PRIMES[0])],
                iy: [base[1].wrapping_mul(PRIMES[1]), (base[1] + 1).wrapping_mul(PRIMES[1])],
                iz: [base[2].wrapping_mul(PRIMES[2]), (base[2] + 1).wrapping_mul(PRIMES[2])],
                w,
                dw,
            }
        }
    }

    /// Prefetch the table lines of the cell of `x` (corners `(0, j, k)`; their `i = 1` neighbours
    /// share the line almost always, since the x prime is 1). The gathers and scatter-adds of the
    /// fine levels are cache misses on a 4 MiB table; issuing them a few points ahead overlaps the
    /// latencies.
    #[inline(always)]
    fn prefetch(&self, x: &[f32], base: *const f32, features: usize) {
        #[cfg(target_arch = "x86_64")]
        {
            let cell = self.locate(x);
            for k in 0..2 {
                for j in 0..2 {
                    let idx = self.index(&cell, 0, j, k);
                    // SAFETY: prefetch never faults; the address is inside the table anyway.
                    unsafe {
                        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                            base.wrapping_add(idx * features) as *const i8,
                        )
                    };
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (x, base, features);
    }

    /// Table entry of corner `(i, j, k)` (global index).
    #[inline(always)]
    fn index(&self, cell: &Cell, i: usize, j: usize, k: usize) -> usize {
        let local = if self.dense {
            cell.ix[i] + cell.iy[j] + cell.iz[k]
        } else {
            (cell.ix[i] ^ cell.iy[j] ^ cell.iz[k]) & self.mask
        };
        (self.offset + local) as usize
    }
}

impl HashGrid {
    /// A grid with its table initialized uniformly in ±1e-4 (Instant-NGP).
    pub fn new(config: HashGridConfig, seed: u64) -> Self {
        assert!(config.levels >= 1 && config.features_per_level >= 1);
        assert!(config.base_resolution >= 1 && config.finest_resolution >= config.base_resolution);
        let table = 1usize << config.log2_table_size;
        let growth = if config.levels > 1 {
            ((config.finest_resolution as f64).ln() - (config.base_resolution as f64).ln()) / (config.levels - 1) as f64
        } else {
            0.0
        };
        let mut offset = 0;
        let levels = (0..config.levels)
            .map(|l| {
                let resolution = (config.base_resolution as f64 * (growth * l as f64).exp() + 1e-6).floor() as u32;
                let vertices = (resolution as usize + 1).pow(3);
                let dense = vertices <= table;
                let size = if dense { vertices } else { table };
                let level = HashLevel {
                    resolution,
                    offset,
                    size,
                    dense,
                };
                offset += size.div_ceil(64) * 64;
                level
            })
            .collect();
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let params = (0..offset * config.features_per_level)
            .map(|_| rng.gen_range(-1e-4..1e-4))
            .collect();
        HashGrid { config, levels, params }
    }

    /// Cell edge length of `level` in world units (Neuralangelo's finite-difference step).
    pub fn cell_size(&self, level: usize) -> f32 {
        2.0 * self.config.bound / self.levels[level].resolution as f32
    }

    /// Output features per point.
    pub fn output_dim(&self) -> usize {
        self.config.levels * self.config.features_per_level
    }
    /// Table entries over all levels (including alignment padding).
    pub fn entries(&self) -> usize {
        self.params.len() / self.config.features_per_level
    }

    fn geometry(&self, level: &HashLevel) -> LevelGeometry {
        LevelGeometry {
            res: level.resolution as f32,
            max_cell: level.resolution - 1,
            scale: level.resolution as f32 / (2.0 * self.config.bound),
            bound: self.config.bound,
            dense: level.dense,
            stride: level.resolution + 1,
            mask: level.size as u32 - 1,
            offset: level.offset as u32,
        }
    }

    /// Encode `n` positions (`x`: `[n×3]`) level-major: `enc[l][i][f]` (`levels × n × F`) and, when
    /// given, the Jacobian `jac[l][i][f][k] = ∂enc/∂x_k` (`levels × n × F × 3`). Levels run in
    /// parallel.
    pub fn encode(&self, x: &[f32], enc: &mut [f32], jac: Option<&mut [f32]>) {
        if x.is_empty() {
            return;
        }
        let n = x.len() / 3;
        let fdim = self.config.features_per_level;
        let enc = &mut enc[..self.config.levels * n * fdim];
        match jac {
            Some(jac) => enc
                .par_chunks_mut(n * fdim)
                .zip(jac[..self.config.levels * n * fdim * 3].par_chunks_mut(n * fdim * 3))
                .zip(&self.levels)
                .for_each(|((e, j), level)| self.dispatch_encode(level, x, e, Some(j))),
            None => enc
                .par_chunks_mut(n * fdim)
                .zip(&self.levels)
                .for_each(|(e, level)| self.dispatch_encode(level, x, e, None)),
        }
    }

    fn dispatch_encode(&self, level: &HashLevel, x: &[f32], enc: &mut [f32], jac: Option<&mut [f32]>) {
        match self.config.features_per_level {
            1 => self.encode_level::<1>(level, x, enc, jac),
            2 => {
                #[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
                {
                    let mut jac = jac;
                    let geom = self.geometry(level);
                    // SAFETY: AVX-512F is enabled for this build; indices stay inside the table
                    // exactly as in the scalar path; the buffers hold n points.
                    let done = unsafe { simd::encode_level_f2(&geom, &self.params, x, enc, jac.as_deref_mut()) };
                    let jac_tail = jac.map(|j| &mut j[done * 6..]);
                    self.encode_level::<2>(level, &x[done * 3..], &mut enc[done * 2..], jac_tail);
                }
                #[cfg(not(all(target_arch = "x86_64", target_feature = "avx512f")))]
                self.encode_level::<2>(level, x, enc, jac)
            }
            4 => self.encode_level::<4>(level, x, enc, jac),
            8 => self.encode_level::<8>(level, x, enc, jac),
            f => panic!("features_per_level {f} not supported (1, 2, 4 or 8)"),
        }
    }

    fn encode_level<const F: usize>(&self, level: &HashLevel, x: &[f32], enc: &mut [f32], jac: Option<&mut [f32]>) {
        let geom = self.geometry(level);
        let table = &self.params[..];
        let gather = |idx: usize| -> [f32; F] {
            debug_assert!((idx + 1) * F <= table.len());
            // SAFETY: `index` is below offset + size of this level by construction (dense: the
            // last vertex; hashed: masked), and the table holds every level.
            unsafe { std::array::from_fn(|f| *table.get_unchecked(idx * F + f)) }
        };
        match jac {
            Some(jac) => {
                for (p, ((xi, e), j)) in x
                    .chunks_exact(3)
                    .zip(enc.chunks_exact_mut(F))
                    .zip(jac.chunks_exact_mut(3 * F))
                    .enumerate()
                {
                    if let Some(ahead) = x.get((p + PREFETCH) * 3..(p + PREFETCH) * 3 + 3) {
                        geom.prefetch(ahead, table.as_ptr(), F);
                    }
                    let cell = geom.locate(xi);
                    let mut acc = [0f32; F];
                    let mut dacc = [[0f32; 3]; F];
                    for k in 0..2 {
                        for jj in 0..2 {
                            let wyz = cell.w[1][jj] * cell.w[2][k];
                            let dy = cell.dw[1][jj] * cell.w[2][k];
                            let dz = cell.w[1][jj] * cell.dw[2][k];
                            for i in 0..2 {
                                let t = gather(geom.index(&cell, i, jj, k));
                                let w = cell.w[0][i] * wyz;
                                let d = [cell.dw[0][i] * wyz, cell.w[0][i] * dy, cell.w[0][i] * dz];
                                for f in 0..F {
                                    acc[f] += w * t[f];
                                    dacc[f][0] += d[0] * t[f];
                                    dacc[f][1] += d[1] * t[f];
                                    dacc[f][2] += d[2] * t[f];
                                }
                            }
                        }
                    }
                    e.copy_from_slice(&acc);
                    for f in 0..F {
                        j[f * 3..f * 3 + 3].copy_from_slice(&dacc[f]);
                    }
                }
            }
            None => {
                for (p, (xi, e)) in x.chunks_exact(3).zip(enc.chunks_exact_mut(F)).enumerate() {
                    if let Some(ahead) = x.get((p + PREFETCH) * 3..(p + PREFETCH) * 3 + 3) {
                        geom.prefetch(ahead, table.as_ptr(), F);
                    }
                    let cell = geom.locate(xi);
                    let mut acc = [0f32; F];
                    for k in 0..2 {
                        for jj in 0..2 {
                            let wyz = cell.w[1][jj] * cell.w[2][k];
                            for i in 0..2 {
                                let t = gather(geom.index(&cell, i, jj, k));
                                let w = cell.w[0][i] * wyz;
                                for f in 0..F {
                                    acc[f] += w * t[f];
                                }
                            }
                        }
                    }
                    e.copy_from_slice(&acc);
                }
            }
        }
    }

    /// Scatter-add the table gradient of `⟨ā, enc⟩ + ⟨g, J v⟩` into `grad`: `abar` and `g` are
    /// level-major like `enc` (`levels × n × F`), `v` (`[n×3]`, optional) is the cotangent of the
    /// spatial gradient. Each level is owned by one thread: no atomics, no table copies.
    pub fn backward(&self, x: &[f32], abar: &[f32], g: Option<&[f32]>, v: Option<&[f32]>, grad: &mut HashGridGrad) {
        if x.is_empty() {
            return;
        }
        let n = x.len() / 3;
        let fdim = self.config.features_per_level;
        let lens: Vec<usize> = self
            .levels
            .iter()
            .enumerate()
            .map(|(l, lv)| {
                let next = self.levels.get(l + 1).map_or(self.entries(), |nx| nx.offset);
                next - lv.offset
            })
            .collect();
        let value_lens: Vec<usize> = lens.iter().map(|l| l * fdim).collect();
        let word_lens: Vec<usize> = lens.iter().map(|l| l / 64).collect();
        let values = split_lengths_mut(&mut grad.values, &value_lens);
        let words = split_lengths_mut(&mut grad.touched, &word_lens);
        values
            .into_par_iter()
            .zip(words)
            .enumerate()
            .for_each(|(l, (gv, bits))| {
                let ab = &abar[l * n * fdim..(l + 1) * n * fdim];
                let gl = g.map(|g| &g[l * n * fdim..(l + 1) * n * fdim]);
                let level = &self.levels[l];
                match fdim {
                    1 => self.scatter_level::<1>(level, x, ab, gl, v, gv, bits),
                    2 => {
                        #[cfg(all(target_arch = "x86_64", target_feature = "avx512f"))]
                        {
                            let mut geom = self.geometry(level);
                            geom.offset = 0;
                            let cot = gl.zip(v);
                            // SAFETY: AVX-512F is enabled for this build; gv/bits are this
                            // level's slices and every local index is below the level's size.
                            let done = unsafe { simd::scatter_level_f2(&geom, x, ab, cot, gv, bits) };
                            self.scatter_level::<2>(
                                level,
                                &x[done * 3..],
                                &ab[done * 2..],
                                gl.map(|g| &g[done * 2..]),
                                v.map(|v| &v[done * 3..]),
                                gv,
                                bits,
                            );
                        }
                        #[cfg(not(all(target_arch = "x86_64", target_feature = "avx512f")))]
                        self.scatter_level::<2>(level, x, ab, gl, v, gv, bits)
                    }
                    4 => self.scatter_level::<4>(level, x, ab, gl, v, gv, bits),
                    8 => self.scatter_level::<8>(level, x, ab, gl, v, gv, bits),
                    f => panic!("features_per_level {f} not supported (1, 2, 4 or 8)"),
                }
            });
    }

    /// One level of [`HashGrid::backward`]: `gv` and `bits` are this level's slices.
    #[allow(clippy::too_many_arguments)]
    fn scatter_level<const F: usize>(
        &self,
        level: &HashLevel,
        x: &[f32],
        abar: &[f32],
        g: Option<&[f32]>,
        v: Option<&[f32]>,
        gv: &mut [f32],
        bits: &mut [u64],
    ) {
        let mut geom = self.geometry(level);
        geom.offset = 0; // local indices into this level's slices
        let n = x.len() / 3;
        let base = gv.as_ptr();
        let mut add = |idx: usize, w: f32, a: &[f32], dwv: f32, gi: &[f32; F]| {
            debug_assert!((idx + 1) * F <= gv.len() && idx / 64 < bits.len());
            // SAFETY: local index below this level's size (see `encode_level`).
            unsafe {
                for f in 0..F {
                    *gv.get_unchecked_mut(idx * F + f) += w * a[f] + dwv * gi[f];
                }
                *bits.get_unchecked_mut(idx / 64) |= 1 << (idx % 64);
            }
        };
        for i in 0..n {
            if let Some(ahead) = x.get((i + PREFETCH) * 3..(i + PREFETCH) * 3 + 3) {
                geom.prefetch(ahead, base, F);
            }
            let cell = geom.locate(&x[i * 3..i * 3 + 3]);
            let a = &abar[i * F..(i + 1) * F];
            let (gi, vi): ([f32; F], [f32; 3]) = match (g, v) {
                (Some(g), Some(v)) => (
                    std::array::from_fn(|f| g[i * F + f]),
                    [v[i * 3], v[i * 3 + 1], v[i * 3 + 2]],
                ),
                _ => ([0.0; F], [0.0; 3]),
            };
            for k in 0..2 {
                for jj in 0..2 {
                    let wyz = cell.w[1][jj] * cell.w[2][k];
                    // v·∇w = v_x dw_x w_y w_z + v_y w_x dw_y w_z + v_z w_x w_y dw_z
                    let dyz = vi[1] * cell.dw[1][jj] * cell.w[2][k] + vi[2] * cell.w[1][jj] * cell.dw[2][k];
                    for ii in 0..2 {
                        let w = cell.w[0][ii] * wyz;
                        let dwv = vi[0] * cell.dw[0][ii] * wyz + cell.w[0][ii] * dyz;
                        add(geom.index(&cell, ii, jj, k), w, a, dwv, &gi);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gradcheck::{assert_grad_close, central_difference, Lcg};

    fn small_grid() -> HashGrid {
        let config = HashGridConfig {
            levels: 3,
            features_per_level: 2,
            log2_table_size: 6,
            base_resolution: 2,
            finest_resolution: 9,
            bound: 1.0,
        };
        let mut grid = HashGrid::new(config, 3);
        let mut rng = Lcg(8);
        grid.params.iter_mut().for_each(|p| *p = rng.uniform_pm1());
        grid
    }

    /// Points whose cell coordinates are ≥ 0.05 from every cell face on every level, so that
    /// finite differences never straddle the piecewise-trilinear kinks.
    fn interior_points(grid: &HashGrid, n: usize) -> Vec<f32> {
        let mut rng = Lcg(21);
        let mut x = Vec::new();
        while x.len() < n * 3 {
            let p = [
                rng.uniform_pm1() * 0.95,
                rng.uniform_pm1() * 0.95,
                rng.uniform_pm1() * 0.95,
            ];
            let ok = grid.levels.iter().all(|lv| {
                p.iter().all(|&v| {
                    let q = (v + 1.0) * lv.resolution as f32 / 2.0;
                    (q - q.floor()).min(q.ceil() - q) > 0.05
                })
            });
            if ok {
                x.extend_from_slice(&p);
            }
        }
        x
    }

    /// The vectorized 2-feature path equals the scalar loop (points inside and outside the box).
    #[test]
    fn vectorized_encode_matches_scalar() {
        let grid = HashGrid::new(
            HashGridConfig {
                log2_table_size: 12,
                finest_resolution: 256,
                ..Default::default()
            },
            4,
        );
        let mut grid = grid;
        let mut rng = Lcg(31);
        grid.params.iter_mut().for_each(|p| *p = rng.uniform_pm1());
        let n = 16 * 9 + 5;
        let x: Vec<f32> = (0..n * 3).map(|_| rng.uniform_pm1() * 1.1).collect();
        for level in &grid.levels {
            let (mut e1, mut j1) = (vec![0.0; n * 2], vec![0.0; n * 6]);
            let (mut e2, mut j2) = (vec![0.0; n * 2], vec![0.0; n * 6]);
            grid.dispatch_encode(level, &x, &mut e1, Some(&mut j1));
            grid.encode_level::<2>(level, &x, &mut e2, Some(&mut j2));
            for (a, b) in e1.iter().zip(&e2).chain(j1.iter().zip(&j2)) {
                assert!(
                    (a - b).abs() <= 1e-5 * (1.0 + b.abs()),
                    "level {}: {a} vs {b}",
                    level.resolution
                );
            }
            let mut e3 = vec![0.0; n * 2];
            grid.dispatch_encode(level, &x, &mut e3, None);
            assert_eq!(e1, e3);
        }
    }

    /// The vectorized 2-feature scatter equals the scalar loop, with and without the `∇d` term.
    #[test]
    fn vectorized_scatter_matches_scalar() {
        let grid = HashGrid::new(
            HashGridConfig {
                log2_table_size: 10,
                finest_resolution: 256,
                ..Default::default()
            },
            5,
        );
        let mut rng = Lcg(41);
        let n = 16 * 20 + 7;
        let (l, f) = (grid.config.levels, 2);
        let x: Vec<f32> = (0..n * 3).map(|_| rng.uniform_pm1() * 1.1).collect();
        let abar: Vec<f32> = (0..l * n * f).map(|_| rng.uniform_pm1()).collect();
        let g: Vec<f32> = (0..l * n * f).map(|_| rng.uniform_pm1()).collect();
        let v: Vec<f32> = (0..n * 3).map(|_| rng.uniform_pm1()).collect();
        for with_v in [true, false] {
            let mut fast = HashGridGrad::new(&grid);
            let (gg, vv) = if with_v {
                (Some(&g[..]), Some(&v[..]))
            } else {
                (None, None)
            };
            grid.backward(&x, &abar, gg, vv, &mut fast);
            let mut slow = HashGridGrad::new(&grid);
            for (li, level) in grid.levels.iter().enumerate() {
                let end = grid.levels.get(li + 1).map_or(grid.entries(), |nx| nx.offset);
                let gv = &mut slow.values[level.offset * f..end * f];
                let bits = &mut slow.touched[level.offset / 64..end / 64];
                let ab = &abar[li * n * f..(li + 1) * n * f];
                let gl = gg.map(|g| &g[li * n * f..(li + 1) * n * f]);
                grid.scatter_level::<2>(level, &x, ab, gl, vv, gv, bits);
            }
            assert_eq!(fast.touched, slow.touched);
            for (a, b) in fast.values.iter().zip(&slow.values) {
                assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
            }
        }
    }

    #[test]
    fn levels_are_dense_then_hashed() {
        let grid = HashGrid::new(HashGridConfig::default(), 0);
        let res: Vec<u32> = grid.levels.iter().map(|l| l.resolution).collect();
        assert_eq!(res[0], 16);
        assert_eq!(*res.last().unwrap(), 2048);
        assert!(grid.levels[0].dense && grid.levels[4].dense && !grid.levels[5].dense);
        assert!(grid.levels.iter().all(|l| l.offset % 64 == 0));
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let grid = small_grid();
        let n = 6;
        let x = interior_points(&grid, n);
        let (l, f) = (grid.config.levels, grid.config.features_per_level);
        let mut enc = vec![0.0; l * n * f];
        let mut jac = vec![0.0; l * n * f * 3];
        grid.encode(&x, &mut enc, Some(&mut jac));
        let mut rng = Lcg(5);
        let c: Vec<f32> = (0..enc.len()).map(|_| rng.uniform_pm1()).collect();
        // d⟨c, enc⟩/dx_{i,k} = Σ_{l,f} c[l,i,f] J[l,i,f,k]
        let mut analytic = vec![0.0f32; n * 3];
        for lv in 0..l {
            for i in 0..n {
                for ff in 0..f {
                    for k in 0..3 {
                        analytic[i * 3 + k] += c[(lv * n + i) * f + ff] * jac[((lv * n + i) * f + ff) * 3 + k];
                    }
                }
            }
        }
        let fd = central_difference(&x, 1e-3, |xp| {
            let mut e = vec![0.0; enc.len()];
            grid.encode(xp, &mut e, None);
            e.iter().zip(&c).map(|(&a, &b)| a as f64 * b as f64).sum()
        });
        assert_grad_close("hash grid Jacobian", &analytic, &fd, 2e-3, 1e-2);
    }

    #[test]
    fn table_gradient_matches_finite_differences() {
        let grid = small_grid();
        let n = 6;
        let x = interior_points(&grid, n);
        let (l, f) = (grid.config.levels, grid.config.features_per_level);
        let mut rng = Lcg(17);
        let abar: Vec<f32> = (0..l * n * f).map(|_| rng.uniform_pm1()).collect();
        let g: Vec<f32> = (0..l * n * f).map(|_| rng.uniform_pm1()).collect();
        let v: Vec<f32> = (0..n * 3).map(|_| rng.uniform_pm1()).collect();
        let mut grad = HashGridGrad::new(&grid);
        grid.backward(&x, &abar, Some(&g), Some(&v), &mut grad);
        let fd = central_difference(&grid.params, 1e-2, |p| {
            let mut gr = grid.clone();
            gr.params.copy_from_slice(p);
            let mut enc = vec![0.0; l * n * f];
            let mut jac = vec![0.0; l * n * f * 3];
            gr.encode(&x, &mut enc, Some(&mut jac));
            let mut s: f64 = enc.iter().zip(&abar).map(|(&a, &b)| a as f64 * b as f64).sum();
            for lv in 0..l {
                for i in 0..n {
                    for ff in 0..f {
                        let row = (lv * n + i) * f + ff;
                        let jv: f32 = (0..3).map(|k| jac[row * 3 + k] * v[i * 3 + k]).sum();
                        s += g[row] as f64 * jv as f64;
                    }
                }
            }
            s
        });
        assert_grad_close("hash table gradient", &grad.values, &fd, 2e-3, 1e-2);
        // the bitmap marks exactly the entries with a gradient
        for e in 0..grid.entries() {
            let marked = grad.touched[e / 64] >> (e % 64) & 1 == 1;
            let nonzero = grad.values[e * f..(e + 1) * f].iter().any(|&v| v != 0.0);
            assert!(marked || !nonzero, "entry {e} has a gradient but is not marked");
        }
    }
}
