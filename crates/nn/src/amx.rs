//! Half-precision products on Intel AMX tiles: bf16 operands, f32 sums (issue 26, lever 1).
//!
//! tiny-cuda-nn runs its MLPs in half precision with f32 accumulation; the CPU counterpart is AMX
//! (`tdpbf16ps`: a 16×32 bf16 tile times a 32×16 one into a 16×16 f32 tile). Measured on the
//! Xeon this was written on, one core: f32 FMA 227 GFLOP/s, AVX512-BF16's `vdpbf16ps` 112 (half
//! the FMA rate, so it is not used), AMX 3,330. A tile product of the MLPs (`256 × 64 × 64`)
//! then costs less than converting its operands to bf16, which is what this module mostly does.
//!
//! Two precisions ([`crate::linalg::MatmulPrecision`]):
//! * `bf16`: each operand rounded once (8-bit mantissa; ~0.4 % relative error per product);
//! * `bf16x3`: each operand split into `hi + lo` (both bf16), and `A·B ≈ hi·hi + hi·lo + lo·hi`,
//!   three tile products for ~16 bits of mantissa, within a few f32 ulps of the f32 result at this
//!   size (the "bf16x3" of oneDNN and of the cuBLAS / XLA split-precision modes).
//!
//! Operands are packed per call into thread-local buffers: `A` row-major `[m₁₆ × k₃₂]` bf16 (rows
//! padded to 16, the inner dimension to 32 with zeros), `B` in AMX's pair layout
//! `[k₃₂/2 × n₁₆]` of `u32` (`B(2q, j)` in the low half, `B(2q+1, j)` in the high half). Output
//! blocks that lie inside `C` are read (when accumulating) and written in place by the tiles;
//! blocks over its edge go through a small buffer and vector code.
//! The tile registers are configured at the start of each call and released at its end, so no
//! tile state outlives a call (the compiler knows nothing of them).

#![allow(clippy::too_many_arguments)]

use std::sync::OnceLock;

/// Whether the CPU has AMX-TILE, AMX-BF16, AVX512-BF16 and AVX512-BW and the OS granted this
/// process the tile state (Linux: `arch_prctl(ARCH_REQ_XCOMP_PERM, XTILEDATA)`). Checked once.
pub fn available() -> bool {
    static AVAILABLE: OnceLock<bool> = OnceLock::new();
    *AVAILABLE.get_or_init(imp::detect)
}

/// `C[m×n] = (accumulate ? C : 0) + A·B` in bf16 (`split = false`) or bf16x3 (`split = true`);
/// `A(r, p) = a[r·rsa + p·csa]`, `B(p, j) = b[p·ldb + j]`, `C(r, j) = c[r·ldc + j]`.
///
/// # Safety
/// [`available`] must be true and all three matrices in bounds for those strides.
pub unsafe fn gemm(
    m: usize,
    k: usize,
    n: usize,
    a: *const f32,
    rsa: usize,
    csa: usize,
    b: *const f32,
    ldb: usize,
    accumulate: bool,
    c: *mut f32,
    ldc: usize,
    split: bool,
) {
    debug_assert!(available());
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    unsafe {
        imp::gemm(m, k, n, a, rsa, csa, b, ldb, accumulate, c, ldc, split)
    }
    #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
    {
        let _ = (m, k, n, a, rsa, csa, b, ldb, accumulate, c, ldc, split);
        unreachable!("AMX is only detected on x86-64 Linux")
    }
}

/// bf16 rounding (to nearest, ties to even) of one value, as the packing does it; for tests and
/// for error bounds.
pub fn round_bf16(x: f32) -> f32 {
    let bits = x.to_bits();
    let rounded = bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) & 0xffff_0000;
    f32::from_bits(rounded)
}

#[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
mod imp {
    pub fn detect() -> bool {
        false
    }
}

#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
mod imp {
    use std::arch::asm;
    use std::arch::x86_64::*;
    use std::cell::RefCell;

    pub fn detect() -> bool {
        // SAFETY: `cpuid` exists on every x86-64 CPU; leaf 7 is reported as zeros where absent.
        let leaf7 = __cpuid_count(7, 0);
        let amx_bf16 = (leaf7.edx >> 22) & 1 == 1;
        let amx_tile = (leaf7.edx >> 24) & 1 == 1;
        if !(amx_bf16
            && amx_tile
            && is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512bw")
            && is_x86_feature_detected!("avx512bf16"))
        {
            return false;
        }
        // Linux hands out the 8 KiB tile state only on request (since 5.16); a kernel that does
        // not know the request answers an error and the engine stays on f32.
        const ARCH_REQ_XCOMP_PERM: usize = 0x1023;
        const XFEATURE_XTILEDATA: usize = 18;
        const SYS_ARCH_PRCTL: usize = 158;
        let ret: isize;
        // SAFETY: a plain syscall with two integer arguments; it touches no memory of ours.
        unsafe {
            asm!(
                "syscall",
                inlateout("rax") SYS_ARCH_PRCTL => ret,
                in("rdi") ARCH_REQ_XCOMP_PERM,
                in("rsi") XFEATURE_XTILEDATA,
                lateout("rcx") _,
                lateout("r11") _,
                options(nostack),
            );
        }
        ret == 0
    }

    /// Packed operands and the padded `C`, reused by every call on a thread.
    #[derive(Default)]
    struct Packs {
        a_hi: Vec<u16>,
        a_lo: Vec<u16>,
        b_hi: Vec<u32>,
        b_lo: Vec<u32>,
    }

    std::thread_local! {
        static PACKS: RefCell<Packs> = RefCell::new(Packs::default());
    }

    /// One block's sums, in L1.
    #[repr(C, align(64))]
    struct Out([f32; 32 * 32]);

    /// The tile configuration: palette 1, all eight tiles 16 rows × 64 bytes.
    #[repr(C, align(64))]
    struct TileConfig([u8; 64]);

    const TILE_CONFIG: TileConfig = {
        let mut cfg = [0u8; 64];
        cfg[0] = 1;
        let mut t = 0;
        while t < 8 {
            cfg[16 + 2 * t] = 64; // bytes per row (u16, little-endian)
            cfg[48 + t] = 16; // rows
            t += 1;
        }
        TileConfig(cfg)
    };

    /// `x` rounded to bf16 (`hi`, 16 values) and, when `lo` is wanted, the bf16 of the remainder.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16,avx512vl")]
    unsafe fn split16<const LO: bool>(x: __m512) -> (__m256i, __m256i) {
        let hi: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(x));
        if !LO {
            return (hi, _mm256_setzero_si256());
        }
        let hi_f = _mm512_castsi512_ps(_mm512_slli_epi32::<16>(_mm512_cvtepu16_epi32(hi)));
        let lo: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(_mm512_sub_ps(x, hi_f)));
        (hi, lo)
    }

    #[inline]
    fn tail_mask(len: usize) -> u16 {
        if len >= 16 {
            0xffff
        } else {
            ((1u32 << len) - 1) as u16
        }
    }

    /// `A` into `[mp × kp]` bf16 rows (zero padded).
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16,avx512vl")]
    unsafe fn pack_a<const LO: bool>(
        m: usize,
        k: usize,
        a: *const f32,
        rsa: usize,
        csa: usize,
        mp: usize,
        kp: usize,
        hi: &mut Vec<u16>,
        lo: Option<&mut Vec<u16>>,
    ) {
        unsafe {
            // Rows past m are left as they are (finite values of an earlier call): they only
            // reach rows of the product that are never read. Columns past k are written as zeros.
            grow(hi, mp * kp);
            let mut lo = lo;
            if let Some(lo) = lo.as_deref_mut() {
                grow(lo, mp * kp);
            }
            if csa == 1 && rsa != 1 {
                for r in 0..m {
                    let row = a.add(r * rsa);
                    let mut p = 0;
                    while p < kp {
                        let x = if p < k {
                            _mm512_maskz_loadu_ps(tail_mask(k - p), row.add(p))
                        } else {
                            _mm512_setzero_ps()
                        };
                        let (h, l) = split16::<LO>(x);
                        _mm256_storeu_si256(hi.as_mut_ptr().add(r * kp + p) as *mut __m256i, h);
                        if let Some(lo) = lo.as_deref_mut() {
                            _mm256_storeu_si256(lo.as_mut_ptr().add(r * kp + p) as *mut __m256i, l);
                        }
                        p += 16;
                    }
                }
            } else if rsa == 1 {
                // A stored transposed ([k × m], row stride csa): pairs of storage rows become
                // pair words (as in `pack_b`), 16 × 16 blocks of them transposed in registers.
                let hi32 = hi.as_mut_ptr() as *mut u32;
                let lo32 = lo.as_deref_mut().map(|l| l.as_mut_ptr() as *mut u32);
                let (kq, mut r0) = (kp / 2, 0);
                let zero = _mm512_setzero_ps();
                while r0 < m {
                    let mask = tail_mask(m - r0);
                    let mut q0 = 0;
                    while q0 < kq {
                        let mut wh = [_mm512_setzero_si512(); 16];
                        let mut wl = [_mm512_setzero_si512(); 16];
                        for q in 0..16 {
                            let (p0, p1) = (2 * (q0 + q), 2 * (q0 + q) + 1);
                            let x0 = if p0 < k {
                                _mm512_maskz_loadu_ps(mask, a.add(p0 * csa + r0))
                            } else {
                                zero
                            };
                            let x1 = if p1 < k {
                                _mm512_maskz_loadu_ps(mask, a.add(p1 * csa + r0))
                            } else {
                                zero
                            };
                            let (h0, l0) = split16::<LO>(x0);
                            let (h1, l1) = split16::<LO>(x1);
                            wh[q] = pair_words(h0, h1);
                            wl[q] = pair_words(l0, l1);
                        }
                        transpose16(&mut wh);
                        for (r, w) in wh.iter().enumerate().take(m - r0) {
                            _mm512_storeu_si512(hi32.add((r0 + r) * kq + q0) as *mut _, *w);
                        }
                        if let Some(lo32) = lo32 {
                            transpose16(&mut wl);
                            for (r, w) in wl.iter().enumerate().take(m - r0) {
                                _mm512_storeu_si512(lo32.add((r0 + r) * kq + q0) as *mut _, *w);
                            }
                        }
                        q0 += 16;
                    }
                    r0 += 16;
                }
            } else {
                for r in 0..m {
                    hi[r * kp + k..(r + 1) * kp].fill(0);
                    if let Some(lo) = lo.as_deref_mut() {
                        lo[r * kp + k..(r + 1) * kp].fill(0);
                    }
                    for p in 0..k {
                        let x = *a.add(r * rsa + p * csa);
                        let h = round_bits(x);
                        hi[r * kp + p] = h;
                        if let Some(lo) = lo.as_deref_mut() {
                            lo[r * kp + p] = round_bits(x - f32::from_bits((h as u32) << 16));
                        }
                    }
                }
            }
        }
    }

    /// 16 words `h0[j] | h1[j] << 16`: AMX's pair layout of two consecutive rows.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512vl")]
    unsafe fn pair_words(h0: __m256i, h1: __m256i) -> __m512i {
        _mm512_or_si512(
            _mm512_cvtepu16_epi32(h0),
            _mm512_slli_epi32::<16>(_mm512_cvtepu16_epi32(h1)),
        )
    }

    /// Index vectors of [`transpose16`]'s rounds: for `d` = 8, 4, 2, 1, the lanes of row `i`
    /// (bit `d` of `i` clear) and of row `i + d` after swapping their off-diagonal blocks.
    const TRANSPOSE_IDX: [([i32; 16], [i32; 16]); 4] = {
        let mut out = [([0i32; 16], [0i32; 16]); 4];
        let mut s = 0;
        while s < 4 {
            let d = 8 >> s;
            let mut c = 0;
            while c < 16 {
                let set = c & d != 0;
                out[s].0[c] = if set { (16 + c - d) as i32 } else { c as i32 };
                out[s].1[c] = if set { (16 + c) as i32 } else { (c + d) as i32 };
                c += 1;
            }
            s += 1;
        }
        out
    };

    /// In-register transpose of a 16 × 16 block of 32-bit words: four rounds that swap the
    /// off-diagonal `d × d` sub-blocks (`d` = 8, 4, 2, 1) of every pair of rows `i`, `i + d`.
    #[inline(always)]
    unsafe fn transpose16(rows: &mut [__m512i; 16]) {
        unsafe {
            for (s, (lo, hi)) in TRANSPOSE_IDX.iter().enumerate() {
                let d = 8 >> s;
                let li = _mm512_loadu_si512(lo.as_ptr() as *const _);
                let hj = _mm512_loadu_si512(hi.as_ptr() as *const _);
                for i in 0..16 {
                    if i & d == 0 {
                        let (ri, rj) = (rows[i], rows[i + d]);
                        rows[i] = _mm512_permutex2var_epi32(ri, li, rj);
                        rows[i + d] = _mm512_permutex2var_epi32(ri, hj, rj);
                    }
                }
            }
        }
    }

    fn round_bits(x: f32) -> u16 {
        (super::round_bf16(x).to_bits() >> 16) as u16
    }

    /// At least `len` initialized elements (new ones zero); old contents kept.
    fn grow<T: Copy + Default>(v: &mut Vec<T>, len: usize) {
        if v.len() < len {
            v.resize(len, T::default());
        }
    }

    /// `B` (row-major `[k × n]`) into the pair layout `[kp/2 × np]` of `u32`.
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16,avx512vl")]
    unsafe fn pack_b<const LO: bool>(
        k: usize,
        n: usize,
        b: *const f32,
        ldb: usize,
        kp: usize,
        np: usize,
        hi: &mut Vec<u32>,
        lo: Option<&mut Vec<u32>>,
    ) {
        unsafe {
            let rows = kp / 2;
            hi.clear();
            hi.reserve(rows * np);
            hi.set_len(rows * np);
            let mut lo = lo;
            if let Some(lo) = lo.as_deref_mut() {
                lo.clear();
                lo.reserve(rows * np);
                lo.set_len(rows * np);
            }
            for q in 0..rows {
                let (p0, p1) = (2 * q, 2 * q + 1);
                let mut j = 0;
                while j < np {
                    let mask = if j < n { tail_mask(n - j) } else { 0 };
                    let x0 = if p0 < k {
                        _mm512_maskz_loadu_ps(mask, b.add(p0 * ldb + j))
                    } else {
                        _mm512_setzero_ps()
                    };
                    let x1 = if p1 < k {
                        _mm512_maskz_loadu_ps(mask, b.add(p1 * ldb + j))
                    } else {
                        _mm512_setzero_ps()
                    };
                    let (h0, l0) = split16::<LO>(x0);
                    let (h1, l1) = split16::<LO>(x1);
                    _mm512_storeu_si512(hi.as_mut_ptr().add(q * np + j) as *mut _, pair_words(h0, h1));
                    if let Some(lo) = lo.as_deref_mut() {
                        _mm512_storeu_si512(lo.as_mut_ptr().add(q * np + j) as *mut _, pair_words(l0, l1));
                    }
                    j += 16;
                }
            }
        }
    }

    /// One block of `R × C` output tiles (16×16 each, `R, C ∈ {1, 2}`) over the whole inner
    /// dimension, for each `(A, B)` pair in `passes`, into `out` (f32, row stride `ldo_bytes`),
    /// which it first reads when `load`. The sums live in tmm0–3 (row-major order); `A` tiles go
    /// through tmm4–5, `B` tiles through tmm6–7.
    #[inline(always)]
    unsafe fn block<const R: usize, const C: usize>(
        passes: &[(*const u16, *const u32)],
        kp: usize,
        np: usize,
        out: *mut f32,
        ldo_bytes: usize,
        load: bool,
    ) {
        unsafe {
            let s = ldo_bytes;
            let o2 = (out as *mut u8).add(16 * s) as *mut f32;
            if load {
                asm!("tileloadd tmm0, [{p} + {s}*1]", p = in(reg) out, s = in(reg) s, options(nostack, readonly));
                if C == 2 {
                    asm!("tileloadd tmm1, [{p} + {s}*1]", p = in(reg) out.add(16), s = in(reg) s, options(nostack, readonly));
                }
                if R == 2 {
                    asm!("tileloadd tmm2, [{p} + {s}*1]", p = in(reg) o2, s = in(reg) s, options(nostack, readonly));
                    if C == 2 {
                        asm!("tileloadd tmm3, [{p} + {s}*1]", p = in(reg) o2.add(16), s = in(reg) s, options(nostack, readonly));
                    }
                }
            } else {
                asm!(
                    "tilezero tmm0",
                    "tilezero tmm1",
                    "tilezero tmm2",
                    "tilezero tmm3",
                    options(nostack, nomem)
                );
                // Ask for the destination's lines now, so the tile stores below do not wait for
                // them (stores into the batch's activation arrays, which are far out of L1, ran at
                // 13 GB/s without this).
                for r in 0..R * 16 {
                    let row = (out as *const u8).add(r * s);
                    _mm_prefetch::<_MM_HINT_ET0>(row as *const i8);
                    if C == 2 {
                        _mm_prefetch::<_MM_HINT_ET0>(row.add(64) as *const i8);
                    }
                }
            }
            let a_stride = kp * 2;
            let b_stride = np * 4;
            for &(a, b) in passes {
                let mut kc = 0;
                while kc < kp {
                    let a0 = a.add(kc);
                    let b0 = b.add((kc / 2) * np);
                    asm!("tileloadd tmm4, [{p} + {s}*1]", p = in(reg) a0, s = in(reg) a_stride, options(nostack, readonly));
                    asm!("tileloadd tmm6, [{p} + {s}*1]", p = in(reg) b0, s = in(reg) b_stride, options(nostack, readonly));
                    if C == 2 {
                        asm!("tileloadd tmm7, [{p} + {s}*1]", p = in(reg) b0.add(16), s = in(reg) b_stride, options(nostack, readonly));
                    }
                    if R == 2 {
                        asm!("tileloadd tmm5, [{p} + {s}*1]", p = in(reg) a0.add(16 * kp), s = in(reg) a_stride, options(nostack, readonly));
                    }
                    asm!("tdpbf16ps tmm0, tmm4, tmm6", options(nostack, nomem));
                    if C == 2 {
                        asm!("tdpbf16ps tmm1, tmm4, tmm7", options(nostack, nomem));
                    }
                    if R == 2 {
                        asm!("tdpbf16ps tmm2, tmm5, tmm6", options(nostack, nomem));
                        if C == 2 {
                            asm!("tdpbf16ps tmm3, tmm5, tmm7", options(nostack, nomem));
                        }
                    }
                    kc += 32;
                }
            }
            asm!("tilestored [{p} + {s}*1], tmm0", p = in(reg) out, s = in(reg) s, options(nostack));
            if C == 2 {
                asm!("tilestored [{p} + {s}*1], tmm1", p = in(reg) out.add(16), s = in(reg) s, options(nostack));
            }
            if R == 2 {
                asm!("tilestored [{p} + {s}*1], tmm2", p = in(reg) o2, s = in(reg) s, options(nostack));
                if C == 2 {
                    asm!("tilestored [{p} + {s}*1], tmm3", p = in(reg) o2.add(16), s = in(reg) s, options(nostack));
                }
            }
        }
    }

    /// `C[rows × cols] (+)= out[rows × cols]` (`out` with row stride 32).
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn add_out(out: *const f32, rows: usize, cols: usize, c: *mut f32, ldc: usize, accumulate: bool) {
        unsafe {
            for r in 0..rows {
                let mut j = 0;
                while j < cols {
                    let mask = tail_mask(cols - j);
                    let x = _mm512_loadu_ps(out.add(r * 32 + j));
                    let cp = c.add(r * ldc + j);
                    let y = if accumulate {
                        _mm512_add_ps(x, _mm512_maskz_loadu_ps(mask, cp))
                    } else {
                        x
                    };
                    _mm512_mask_storeu_ps(cp, mask, y);
                    j += 16;
                }
            }
        }
    }

    pub unsafe fn gemm(
        m: usize,
        k: usize,
        n: usize,
        a: *const f32,
        rsa: usize,
        csa: usize,
        b: *const f32,
        ldb: usize,
        accumulate: bool,
        c: *mut f32,
        ldc: usize,
        split: bool,
    ) {
        if m == 0 || n == 0 {
            return;
        }
        let (mp, kp, np) = (
            m.next_multiple_of(16),
            k.max(1).next_multiple_of(32),
            n.next_multiple_of(16),
        );
        PACKS.with_borrow_mut(|packs| unsafe {
            let Packs { a_hi, a_lo, b_hi, b_lo } = packs;
            // (the bf16 packing is compiled without the low parts' arithmetic)
            if split {
                pack_a::<true>(m, k, a, rsa, csa, mp, kp, a_hi, Some(&mut *a_lo));
                pack_b::<true>(k, n, b, ldb, kp, np, b_hi, Some(&mut *b_lo));
            } else {
                pack_a::<false>(m, k, a, rsa, csa, mp, kp, a_hi, None);
                pack_b::<false>(k, n, b, ldb, kp, np, b_hi, None);
            }
            let passes_full = [
                (a_hi.as_ptr(), b_hi.as_ptr()),
                (a_hi.as_ptr(), b_lo.as_ptr()),
                (a_lo.as_ptr(), b_hi.as_ptr()),
            ];
            let passes = if split { &passes_full[..] } else { &passes_full[..1] };
            let mut out = Out([0.0; 32 * 32]);
            let outp = out.0.as_mut_ptr();
            asm!("ldtilecfg [{}]", in(reg) TILE_CONFIG.0.as_ptr(), options(nostack, readonly));
            let mut r0 = 0;
            while r0 < mp {
                let rows2 = mp - r0 >= 32;
                let mut j0 = 0;
                while j0 < np {
                    let cols2 = np - j0 >= 32;
                    let mut shifted = [(std::ptr::null::<u16>(), std::ptr::null::<u32>()); 3];
                    for (s, &(pa, pb)) in shifted.iter_mut().zip(passes) {
                        *s = (pa.add(r0 * kp), pb.add(j0));
                    }
                    let shifted = &shifted[..passes.len()];
                    let (bh, bw) = (if rows2 { 32 } else { 16 }, if cols2 { 32 } else { 16 });
                    // A block inside C is read (when accumulating) and written in place by the
                    // tiles; one over C's edge goes through `out` and vector code. (Vector loads
                    // of what tile stores have just written stall: copying every block through
                    // `out` cost half the time of the forward products.)
                    let inside = r0 + bh <= m && j0 + bw <= n;
                    let (dst, ld, load) = if inside {
                        (c.add(r0 * ldc + j0), ldc * 4, accumulate)
                    } else {
                        (outp, 32 * 4, false)
                    };
                    match (rows2, cols2) {
                        (true, true) => block::<2, 2>(shifted, kp, np, dst, ld, load),
                        (true, false) => block::<2, 1>(shifted, kp, np, dst, ld, load),
                        (false, true) => block::<1, 2>(shifted, kp, np, dst, ld, load),
                        (false, false) => block::<1, 1>(shifted, kp, np, dst, ld, load),
                    }
                    if !inside {
                        add_out(
                            outp,
                            bh.min(m - r0),
                            bw.min(n - j0),
                            c.add(r0 * ldc + j0),
                            ldc,
                            accumulate,
                        );
                    }
                    j0 += bw;
                }
                r0 += if rows2 { 32 } else { 16 };
            }
            asm!("tilerelease", options(nostack, nomem));
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], round: bool) -> Vec<f64> {
        let q = |x: f32| if round { round_bf16(x) as f64 } else { x as f64 };
        let mut c = vec![0.0f64; m * n];
        for i in 0..m {
            for j in 0..n {
                c[i * n + j] = (0..k).map(|p| q(a[i * k + p]) * q(b[p * n + j])).sum();
            }
        }
        c
    }

    #[test]
    fn round_bf16_is_round_to_nearest_even() {
        assert_eq!(round_bf16(1.0), 1.0);
        // 1 + 2⁻⁸ is halfway between 1 and 1 + 2⁻⁷: ties to the even mantissa (1.0)
        assert_eq!(round_bf16(1.0 + 1.0 / 256.0), 1.0);
        assert_eq!(round_bf16(1.0 + 3.0 / 256.0), 1.0 + 4.0 / 256.0);
        assert_eq!(round_bf16(-2.0), -2.0);
    }

    /// Both precisions on ragged shapes, both layouts of `A`, with and without accumulation:
    /// `bf16` equals the f64 product of the bf16-rounded operands to f32 summation error, and
    /// `bf16x3` equals the exact product to ~2⁻¹⁶ of the magnitudes.
    #[test]
    fn matches_rounded_and_exact_products() {
        if !available() {
            eprintln!("AMX not available: skipped");
            return;
        }
        for &(m, k, n) in &[
            (1, 1, 1),
            (16, 32, 16),
            (7, 5, 3),
            (256, 35, 64),
            (256, 64, 16),
            (64, 256, 35),
            (40, 70, 50),
            (33, 64, 48),
        ] {
            let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.731).sin() * 1.7).collect();
            let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.377).cos() * 0.9).collect();
            let at: Vec<f32> = (0..k * m).map(|i| a[(i % m) * k + i / m]).collect();
            let scale: Vec<f64> = {
                let mut s = vec![0.0f64; m * n];
                for i in 0..m {
                    for j in 0..n {
                        s[i * n + j] = (0..k).map(|p| (a[i * k + p] * b[p * n + j]).abs() as f64).sum::<f64>() + 1e-30;
                    }
                }
                s
            };
            for split in [false, true] {
                let want = naive(m, k, n, &a, &b, !split);
                let tol = if split { 1e-5 } else { 1e-6 };
                for accumulate in [false, true] {
                    for (ap, rsa, csa) in [(&a, k, 1), (&at, 1, m)] {
                        let ldc = n + 3;
                        let mut c = vec![0.25f32; m * ldc];
                        unsafe {
                            gemm(
                                m,
                                k,
                                n,
                                ap.as_ptr(),
                                rsa,
                                csa,
                                b.as_ptr(),
                                n,
                                accumulate,
                                c.as_mut_ptr(),
                                ldc,
                                split,
                            )
                        };
                        for i in 0..m {
                            for j in 0..n {
                                let w = want[i * n + j] + if accumulate { 0.25 } else { 0.0 };
                                let err = (c[i * ldc + j] as f64 - w).abs() / scale[i * n + j];
                                assert!(err < tol, "({m},{k},{n}) split={split} acc={accumulate} csa={csa} [{i},{j}]: {} vs {w} (rel {err:e})", c[i * ldc + j]);
                            }
                            assert!(
                                c[i * ldc + n..(i + 1) * ldc].iter().all(|&x| x == 0.25),
                                "wrote past a row of C"
                            );
                        }
                    }
                }
            }
        }
    }
}
