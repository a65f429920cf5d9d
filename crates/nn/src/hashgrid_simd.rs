//! AVX-512 hash-grid encoding of one level with 2 features per entry, 16 points per step.
//!
//! The scalar loop spends most of its ~60 cycles per point and level on index and weight
//! arithmetic and register spills, not on the 4 cache lines it loads. Here the cell, the 8 corner
//! indices, the trilinear weights and their derivatives are computed for 16 points in vector
//! registers; each corner's 16 entries (2 floats = 8 bytes each) come in by two 8-lane gathers, so
//! 256 loads per step are in flight together (no software prefetch needed). Results match the
//! scalar path up to the order of floating-point additions.

use super::LevelGeometry;
use std::arch::x86_64::*;

const PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// Encode the first `16·⌊n/16⌋` points of `x` (`[n×3]`) on one level into `enc` (`[n×2]`) and,
/// when given, `jac` (`[n×2×3]`). Returns how many points were done; the caller finishes the tail.
///
/// # Safety
/// Requires AVX-512F; `table` must hold every index the level can produce (as for the scalar
/// path), and `enc`/`jac` at least `n·2` / `n·6` floats.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn encode_level_f2(
    geom: &LevelGeometry,
    table: &[f32],
    x: &[f32],
    enc: &mut [f32],
    mut jac: Option<&mut [f32]>,
) -> usize {
    let n = x.len() / 3;
    let blocks = n / 16;
    let idx3 = _mm512_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 30, 33, 36, 39, 42, 45);
    let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
    let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
    let inter_lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
    let inter_hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
    let zero = _mm512_setzero_ps();
    let one = _mm512_set1_ps(1.0);
    let bound = _mm512_set1_ps(geom.bound);
    let scale = _mm512_set1_ps(geom.scale);
    let res = _mm512_set1_ps(geom.res);
    let max_cell = _mm512_set1_epi32(geom.max_cell as i32);
    let mask = _mm512_set1_epi32(geom.mask as i32);
    let offset = _mm512_set1_epi32(geom.offset as i32);
    let mul: [u32; 3] = if geom.dense {
        [1, geom.stride, geom.stride * geom.stride]
    } else {
        PRIMES
    };
    let tbase = table.as_ptr() as *const f64;
    let mut jbuf = [[0f32; 16]; 6];
    for b in 0..blocks {
        let xp = x.as_ptr().add(b * 48);
        let mut w = [[zero; 2]; 3];
        let mut dw = [[zero; 2]; 3];
        let mut term = [[_mm512_setzero_si512(); 2]; 3];
        for k in 0..3 {
            let xk = _mm512_i32gather_ps::<4>(idx3, xp.add(k));
            let p = _mm512_mul_ps(_mm512_add_ps(xk, bound), scale);
            let inside = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(p, zero) & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(p, res);
            // max first: a NaN coordinate becomes 0, so every index stays in the table
            let p = _mm512_min_ps(_mm512_max_ps(p, zero), res);
            let c = _mm512_min_epi32(_mm512_cvttps_epi32(p), max_cell);
            let f = _mm512_sub_ps(p, _mm512_cvtepi32_ps(c));
            w[k] = [_mm512_sub_ps(one, f), f];
            let d = _mm512_maskz_mov_ps(inside, scale);
            dw[k] = [_mm512_sub_ps(zero, d), d];
            let m = _mm512_set1_epi32(mul[k] as i32);
            let t0 = _mm512_mullo_epi32(c, m);
            term[k] = [t0, _mm512_add_epi32(t0, m)];
        }
        let mut e = [zero; 2];
        let mut jv = [zero; 6];
        for kz in 0..2 {
            for jy in 0..2 {
                let wyz = _mm512_mul_ps(w[1][jy], w[2][kz]);
                let dy = _mm512_mul_ps(dw[1][jy], w[2][kz]);
                let dz = _mm512_mul_ps(w[1][jy], dw[2][kz]);
                for ix in 0..2 {
                    let local = if geom.dense {
                        _mm512_add_epi32(_mm512_add_epi32(term[0][ix], term[1][jy]), term[2][kz])
                    } else {
                        _mm512_and_si512(
                            _mm512_xor_si512(_mm512_xor_si512(term[0][ix], term[1][jy]), term[2][kz]),
                            mask,
                        )
                    };
                    let idx = _mm512_add_epi32(local, offset);
                    let lo = _mm512_i32gather_pd::<8>(_mm512_castsi512_si256(idx), tbase);
                    let hi = _mm512_i32gather_pd::<8>(_mm512_extracti64x4_epi64::<1>(idx), tbase);
                    let (lo, hi) = (_mm512_castpd_ps(lo), _mm512_castpd_ps(hi));
                    let t = [
                        _mm512_permutex2var_ps(lo, even, hi),
                        _mm512_permutex2var_ps(lo, odd, hi),
                    ];
                    let wc = _mm512_mul_ps(w[0][ix], wyz);
                    let d = [
                        _mm512_mul_ps(dw[0][ix], wyz),
                        _mm512_mul_ps(w[0][ix], dy),
                        _mm512_mul_ps(w[0][ix], dz),
                    ];
                    for f in 0..2 {
                        e[f] = _mm512_fmadd_ps(wc, t[f], e[f]);
                        if jac.is_some() {
                            for a in 0..3 {
                                jv[f * 3 + a] = _mm512_fmadd_ps(d[a], t[f], jv[f * 3 + a]);
                            }
                        }
                    }
                }
            }
        }
        let ep = enc.as_mut_ptr().add(b * 32);
        _mm512_storeu_ps(ep, _mm512_permutex2var_ps(e[0], inter_lo, e[1]));
        _mm512_storeu_ps(ep.add(16), _mm512_permutex2var_ps(e[0], inter_hi, e[1]));
        if let Some(jac) = jac.as_deref_mut() {
            for (row, v) in jbuf.iter_mut().zip(jv) {
                _mm512_storeu_ps(row.as_mut_ptr(), v);
            }
            let jp = &mut jac[b * 96..(b + 1) * 96];
            for p in 0..16 {
                for c in 0..6 {
                    jp[p * 6 + c] = jbuf[c][p];
                }
            }
        }
    }
    blocks * 16
}

/// Corner indices, weights and `v·∇w` of 16 points (one block of [`scatter_level_f2`]).
struct BlockCorners {
    idx: [[u32; 16]; 8],
    w: [[f32; 16]; 8],
    dwv: [[f32; 16]; 8],
}

impl BlockCorners {
    fn new() -> Self {
        BlockCorners {
            idx: [[0; 16]; 8],
            w: [[0.0; 16]; 8],
            dwv: [[0.0; 16]; 8],
        }
    }
}

/// What the corners of a level's blocks are computed from, broadcast once per level.
#[derive(Clone, Copy)]
struct LevelVectors {
    /// Offsets of the 16 points' coordinates (stride 3) for the gathers.
    idx3: __m512i,
    bound: __m512,
    scale: __m512,
    res: __m512,
    max_cell: __m512i,
    mask: __m512i,
    /// Per-axis multipliers of the cell coordinates: the strides (dense) or the hash primes.
    mul: [u32; 3],
    dense: bool,
}

impl LevelVectors {
    #[target_feature(enable = "avx512f")]
    #[inline]
    unsafe fn new(geom: &LevelGeometry) -> Self {
        LevelVectors {
            idx3: _mm512_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 30, 33, 36, 39, 42, 45),
            bound: _mm512_set1_ps(geom.bound),
            scale: _mm512_set1_ps(geom.scale),
            res: _mm512_set1_ps(geom.res),
            max_cell: _mm512_set1_epi32(geom.max_cell as i32),
            mask: _mm512_set1_epi32(geom.mask as i32),
            mul: if geom.dense {
                [1, geom.stride, geom.stride * geom.stride]
            } else {
                PRIMES
            },
            dense: geom.dense,
        }
    }
}

/// The scatter-add of [`super::HashGrid::backward`] for one level with 2 features, on the first
/// `16·⌊n/16⌋` points: indices, weights and `v·∇w_c` are computed 16 points at a time in vector
/// registers (and their lines prefetched), then the read-modify-writes of the previous block run
/// as scalar code (lanes of one block may hit the same entry). `geom.offset` must be 0 (`gv` and
/// `bits` are this level's slices). Returns how many points were done.
///
/// # Safety
/// Requires AVX-512F; `gv`/`bits` must cover the level's entries; `abar`, `g` (`[n×2]`) and `v`
/// (`[n×3]`) must hold `n` points.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn scatter_level_f2(
    geom: &LevelGeometry,
    x: &[f32],
    abar: &[f32],
    gv_cot: Option<(&[f32], &[f32])>,
    gv: &mut [f32],
    bits: &mut [u64],
) -> usize {
    let n = x.len() / 3;
    let blocks = n / 16;
    let lv = LevelVectors::new(geom);
    // Two buffers: block b's corners are computed (and their lines prefetched) while block b − 1's
    // read-modify-writes wait for theirs.
    let mut bufs = [BlockCorners::new(), BlockCorners::new()];
    // The read-modify-writes of block b, one point and corner at a time (lanes of one block may
    // hit the same entry): gv[e] += w_c ā + (v·∇w_c) ḡ, and entry e's touched bit. (Kept a
    // closure: as a function of its own the kernel compiled to a fifth more instructions, though
    // the shared machine's timings could not tell the two apart.)
    let rmw = |blk: &BlockCorners, b: usize, gv: &mut [f32], bits: &mut [u64]| {
        for p in 0..16 {
            let i = b * 16 + p;
            let (a0, a1) = (abar[i * 2], abar[i * 2 + 1]);
            let (g0, g1) = match gv_cot {
                Some((g, _)) => (g[i * 2], g[i * 2 + 1]),
                None => (0.0, 0.0),
            };
            for c in 0..8 {
                let e = blk.idx[c][p] as usize;
                let (w, d) = (blk.w[c][p], blk.dwv[c][p]);
                // SAFETY: e < level size (see encode_level_f2); bits cover the level.
                unsafe {
                    *gv.get_unchecked_mut(e * 2) += w * a0 + d * g0;
                    *gv.get_unchecked_mut(e * 2 + 1) += w * a1 + d * g1;
                    *bits.get_unchecked_mut(e / 64) |= 1 << (e % 64);
                }
            }
        }
    };
    for b in 0..=blocks {
        if b < blocks {
            let blk = &mut bufs[b % 2];
            block_corners(&lv, x, gv_cot, b, blk);
            prefetch_corners(blk, gv);
        }
        if b > 0 {
            rmw(&bufs[(b - 1) % 2], b - 1, gv, bits);
        }
    }
    blocks * 16
}

/// The 8 corners of block `b`'s 16 points into `blk`: entry indices, trilinear weights `w_c` and,
/// with the cotangents `(g, v)` of the `∇d` term, `v·∇w_c` (zero without).
///
/// # Safety
/// Requires AVX-512F; `x` (and `v`) must hold the block's points.
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn block_corners(
    lv: &LevelVectors,
    x: &[f32],
    gv_cot: Option<(&[f32], &[f32])>,
    b: usize,
    blk: &mut BlockCorners,
) {
    let zero = _mm512_setzero_ps();
    let one = _mm512_set1_ps(1.0);
    let xp = x.as_ptr().add(b * 48);
    let mut w = [[zero; 2]; 3];
    let mut dw = [[zero; 2]; 3];
    let mut term = [[_mm512_setzero_si512(); 2]; 3];
    let mut vk = [zero; 3];
    for k in 0..3 {
        let xk = _mm512_i32gather_ps::<4>(lv.idx3, xp.add(k));
        let p = _mm512_mul_ps(_mm512_add_ps(xk, lv.bound), lv.scale);
        let inside = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(p, zero) & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(p, lv.res);
        let p = _mm512_min_ps(_mm512_max_ps(p, zero), lv.res);
        let c = _mm512_min_epi32(_mm512_cvttps_epi32(p), lv.max_cell);
        let f = _mm512_sub_ps(p, _mm512_cvtepi32_ps(c));
        w[k] = [_mm512_sub_ps(one, f), f];
        let d = _mm512_maskz_mov_ps(inside, lv.scale);
        dw[k] = [_mm512_sub_ps(zero, d), d];
        let m = _mm512_set1_epi32(lv.mul[k] as i32);
        let t0 = _mm512_mullo_epi32(c, m);
        term[k] = [t0, _mm512_add_epi32(t0, m)];
        if let Some((_, v)) = gv_cot {
            vk[k] = _mm512_i32gather_ps::<4>(lv.idx3, v.as_ptr().add(b * 48 + k));
        }
    }
    let mut c = 0;
    for kz in 0..2 {
        for jy in 0..2 {
            let wyz = _mm512_mul_ps(w[1][jy], w[2][kz]);
            // v·∇w = v_x dw_x w_y w_z + w_x (v_y dw_y w_z + v_z w_y dw_z)
            let dyz = _mm512_fmadd_ps(
                vk[1],
                _mm512_mul_ps(dw[1][jy], w[2][kz]),
                _mm512_mul_ps(vk[2], _mm512_mul_ps(w[1][jy], dw[2][kz])),
            );
            for ix in 0..2 {
                let local = if lv.dense {
                    _mm512_add_epi32(_mm512_add_epi32(term[0][ix], term[1][jy]), term[2][kz])
                } else {
                    _mm512_and_si512(
                        _mm512_xor_si512(_mm512_xor_si512(term[0][ix], term[1][jy]), term[2][kz]),
                        lv.mask,
                    )
                };
                let wc = _mm512_mul_ps(w[0][ix], wyz);
                let dwv = _mm512_fmadd_ps(_mm512_mul_ps(vk[0], dw[0][ix]), wyz, _mm512_mul_ps(w[0][ix], dyz));
                _mm512_storeu_si512(blk.idx[c].as_mut_ptr() as *mut __m512i, local);
                _mm512_storeu_ps(blk.w[c].as_mut_ptr(), wc);
                _mm512_storeu_ps(blk.dwv[c].as_mut_ptr(), dwv);
                c += 1;
            }
        }
    }
}

/// Prefetches the entries of the block's ix = 0 corners: the x-neighbours (ix = 1) share their
/// lines almost always.
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn prefetch_corners(blk: &BlockCorners, gv: &[f32]) {
    for c in (0..8).step_by(2) {
        for p in 0..16 {
            let e = blk.idx[c][p] as usize;
            _mm_prefetch::<_MM_HINT_T0>(gv.as_ptr().wrapping_add(e * 2) as *const i8);
        }
    }
}
