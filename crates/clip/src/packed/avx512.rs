//! AVX-512 micro-kernels, 6 × 64: f32 FMA (`Kernel::Avx512F`) and bf16 pairs with `vdpbf16ps`
//! (`Kernel::Avx512Bf16`). Both keep C's 6 × 64 tile in 24 zmm accumulators (rows × four
//! 16-lane vectors) and per k step (f32) or k pair (bf16) load four B vectors and broadcast
//! six A values (one `vbroadcastss` each, shared by four multiply-adds): 29–30 of the 32 zmm
//! registers, and the compiled loop has no spills.
//!
//! Why 6 × 64, measured on the 2-core AMD EPYC Zen 4 (AVX-512F/BW/DQ/VL, AVX512_BF16), single
//! thread, CPU time, m = 150 and the ViT-B/32 shapes, in a stand-alone copy of this driver
//! (GFLOPS; FMA peak measured with register-only loops: 113 for ymm and zmm alike, 226 for
//! `vdpbf16ps` zmm): f32 6 × 16 ymm 98–107, 6 × 32 101–108, 12 × 32 97–103 (150 rows pad to
//! 156), 14 × 32 97–106, 8 × 48 101–107, 6 × 64 100–108; bf16 12 × 32 192–210, 8 × 48
//! 200–215, 6 × 64 203–218. Six rows divide 150 (3 views × 50 tokens) and 147 (patches)
//! nearly exactly, and 64 columns divide every width of the CLIP family (512 … 5120). Zen 4
//! executes a zmm FMA on its two 256-bit pipes, so f32 gains little over AVX2 there; on Intel
//! cores with two 512-bit FMA ports the same kernel has twice the AVX2 kernel's peak (24
//! accumulators cover 2 ports × 4 cycles latency three times over).
//!
//! A is read as six row streams (`a + r·lda`) rather than interleaved `[k][6]`: equally fast
//! here, and it lets f32 read full row panels of A in place and bf16 convert rows with
//! contiguous vector loads.
//!
//! Toolchain: AVX-512 intrinsics and `target_feature(enable = "avx512…")` are stable since Rust
//! 1.89, the workspace's `rust-version` (`clippy::msrv` on the module declaration says so for
//! this file too).

use std::arch::x86_64::*;

use super::{Tile, MR};

/// Columns of these kernels' B panels.
pub(super) const NR: usize = 64;
/// 16-lane vectors per tile row.
const NV: usize = NR / 16;

/// Bias, accumulate and store the 6 × 64 accumulators `$c` (`[[__m512; NV]; MR]`) into C as
/// `Tile::store_scalar` describes. A macro so that it expands inside each kernel: as a
/// function it stayed a call (`#[inline(always)]` is refused with `#[target_feature]`, and
/// without the attribute the intrinsics cannot be inlined into it), moving the 24 accumulators
/// through the stack: 3.4 % of the single-thread bf16 image pass in a perf profile.
///
/// Used only inside `unsafe` kernels that enable AVX-512F, whose callers guarantee that rows
/// `< $t.rows` and columns `col0 + lo .. col0 + hi` of C at `$crow` (stride `$ldc`) are
/// writable and `$t.nr == NR`.
macro_rules! store_tile {
    ($c:ident, $crow:expr, $ldc:expr, $t:expr) => {{
        let (crow, ldc, t): (*mut f32, usize, &Tile) = ($crow, $ldc, $t);
        if let Some(bias) = t.bias {
            // SAFETY: the tile's bias has NR floats.
            let bv: [__m512; NV] =
                std::array::from_fn(|v| unsafe { _mm512_loadu_ps(bias.as_ptr().add(16 * v)) });
            for row in $c.iter_mut() {
                for (x, b) in row.iter_mut().zip(&bv) {
                    *x = _mm512_add_ps(*x, *b);
                }
            }
        }
        if t.lo == 0 && t.hi == NR {
            // All columns: vector stores for the valid rows (fewer than MR in a last panel).
            for (r, row) in $c.iter().enumerate().take(t.rows) {
                for (v, x) in row.iter().enumerate() {
                    // SAFETY: rows < t.rows and columns col0 .. col0 + NR (col0 ≥ 0 since
                    // lo = 0) are inside C by the caller's guarantee.
                    unsafe {
                        let dst = crow.offset((r * ldc) as isize + t.col0 + 16 * v as isize);
                        let y = if t.add {
                            _mm512_add_ps(*x, _mm512_loadu_ps(dst))
                        } else {
                            *x
                        };
                        _mm512_storeu_ps(dst, y);
                    }
                }
            }
        } else {
            let mut acc = [0.0f32; MR * NR];
            for (r, row) in $c.iter().enumerate() {
                for (v, x) in row.iter().enumerate() {
                    // SAFETY: MR·NV vectors of 16 fill the MR·NR array exactly.
                    unsafe { _mm512_storeu_ps(acc.as_mut_ptr().add(r * NR + 16 * v), *x) };
                }
            }
            // The bias is already in the accumulators.
            let t = Tile { bias: None, ..*t };
            // SAFETY: forwarded from the caller.
            unsafe { t.store_scalar(&acc, crow, ldc) }
        }
    }};
}

/// Prefetch hints for the next B micro-panel (into L2) and C's tile (into L1).
#[inline(always)]
fn prefetch_all(prefetch: &[f32], crow: *mut f32, ldc: usize, t: &Tile) {
    // SAFETY: SSE is part of x86-64; prefetches are hints that never fault, whatever the
    // address.
    unsafe {
        for line in prefetch.chunks(16) {
            _mm_prefetch::<_MM_HINT_T1>(line.as_ptr().cast());
        }
        if t.lo == 0 && t.hi == NR {
            for r in 0..t.rows {
                let row = crow.wrapping_offset((r * ldc) as isize + t.col0);
                for v in 0..NV {
                    _mm_prefetch::<_MM_HINT_T0>(row.wrapping_add(16 * v).cast());
                }
            }
        }
    }
}

/// f32: `C[6 × 64] (+)= A[6 × kc] · B[kc × 64]`.
///
/// # Safety
/// AVX-512F present; for r < MR, `a + r·lda` readable for `kc` floats; `b` readable for
/// `kc·NR` floats and 64-byte aligned; `t.nr == NR`; C as in `Tile::store_scalar`.
#[target_feature(enable = "avx512f")]
// Flat arguments: a micro-kernel is the innermost call of the product; its pointers, strides
// and counts stay in registers from `run_tile`, and the `# Safety` contract above is stated
// per argument (a struct would be unpacked again on entry).
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn tile_f32(
    kc: usize,
    a: *const f32,
    lda: usize,
    b: *const f32,
    prefetch: &[f32],
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    debug_assert_eq!(t.nr, NR);
    prefetch_all(prefetch, crow, ldc, t);
    let rows: [*const f32; MR] = std::array::from_fn(|r| a.wrapping_add(r * lda));
    let mut c = [[_mm512_setzero_ps(); NV]; MR];
    for p in 0..kc {
        // SAFETY: p < kc: inside the panels the caller guarantees; B rows are 64-byte aligned.
        unsafe {
            let bp = b.add(p * NR);
            let bv: [__m512; NV] = std::array::from_fn(|v| _mm512_load_ps(bp.add(16 * v)));
            for (acc, row) in c.iter_mut().zip(&rows) {
                let av = _mm512_set1_ps(*row.add(p));
                for (x, bv) in acc.iter_mut().zip(&bv) {
                    *x = _mm512_fmadd_ps(av, *bv, *x);
                }
            }
        }
    }
    store_tile!(c, crow, ldc, t);
}

/// Rows of the transposed product's tile (`tile_f32_t`).
pub(super) const MR_T: usize = 4;
/// Columns of the transposed product's tile: five 16-lane vectors.
pub(super) const NR_T: usize = 80;
const NV_T: usize = NR_T / 16;

/// f32 `Cᵀ[4 × 80] (+)= A[4 × kc] · B[kc × 80]` with A read in place from the packed panels
/// of a forward weight (`super::gemm_t`): A's element (r, c·NR + p), p < NR, is at
/// `a + c·kstride + r·NR + p` (a panel's rows are NR floats apart, the next panel starts
/// `kstride` floats on); B is `[kc][80]`. Per k step five B vectors and four broadcast A
/// values feed 20 multiply-adds (20 accumulators), in k order for each element as `tile_f32`
/// (so the AVX2 kernel's bits). The accumulators stay in registers across chunks; the tile is
/// written transposed (`Tile::store_transposed`).
///
/// # Safety
/// AVX-512F present; every A element named above for r < MR_T and k steps < kc readable; `b`
/// readable for `kc·NR_T` floats and 64-byte aligned; `t.nr == NR_T`, `t.rows ≤ MR_T`; C as in
/// `Tile::store_transposed`.
#[target_feature(enable = "avx512f")]
// Flat arguments, as `tile_f32`'s.
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn tile_f32_t(
    kc: usize,
    a: *const f32,
    kstride: usize,
    b: *const f32,
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    debug_assert_eq!(t.nr, NR_T);
    debug_assert!(t.rows <= MR_T);
    let mut c = [[_mm512_setzero_ps(); NV_T]; MR_T];
    let mut chunk = a;
    let mut p0 = 0;
    while p0 < kc {
        let len = NR.min(kc - p0);
        for p in 0..len {
            // SAFETY: p0 + p < kc: inside the chunks and the B panel the caller guarantees;
            // B rows (32 floats) are 64-byte aligned.
            unsafe {
                let bp = b.add((p0 + p) * NR_T);
                let bv: [__m512; NV_T] = std::array::from_fn(|v| _mm512_load_ps(bp.add(16 * v)));
                for (r, acc) in c.iter_mut().enumerate() {
                    let av = _mm512_set1_ps(*chunk.add(r * NR + p));
                    for (x, bv) in acc.iter_mut().zip(&bv) {
                        *x = _mm512_fmadd_ps(av, *bv, *x);
                    }
                }
            }
        }
        p0 += len;
        chunk = chunk.wrapping_add(kstride);
    }
    let mut acc = [0.0f32; MR_T * NR_T];
    for (r, row) in c.iter().enumerate() {
        for (v, x) in row.iter().enumerate() {
            // SAFETY: MR_T·NV_T vectors of 16 fill the MR_T·NR_T array exactly.
            unsafe { _mm512_storeu_ps(acc.as_mut_ptr().add(r * NR_T + 16 * v), *x) };
        }
    }
    // SAFETY: forwarded from the caller.
    unsafe { t.store_transposed(&acc, crow, ldc) }
}

/// bf16 pairs: `C[6 × 64] (+)= Σ_q A[6][q] · B[q][64]` where every A and B element is a u32
/// holding two bf16 values (k = 2q in the low half, 2q + 1 in the high half) and `vdpbf16ps`
/// adds both products into the f32 accumulator.
///
/// # Safety
/// AVX-512F and AVX512_BF16 present; for r < MR, `a + r·lda` readable for `kq` u32s; `b`
/// readable for `kq·NR` u32s and 64-byte aligned; `t.nr == NR`; C as in `Tile::store_scalar`.
#[target_feature(enable = "avx512f,avx512bf16")]
// Flat arguments, as `tile_f32`'s.
#[allow(clippy::too_many_arguments)]
// The same loop as `tile_f32` with bf16 pairs and `vdpbf16ps` in place of the f32 FMA; kept
// apart because the hottest loop of CLIP should not go through a trait over the element type,
// and the two need different target features.
pub(super) unsafe fn tile_bf16(
    kq: usize,
    a: *const u32,
    lda: usize,
    b: *const u32,
    prefetch: &[f32],
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    debug_assert_eq!(t.nr, NR);
    prefetch_all(prefetch, crow, ldc, t);
    let rows: [*const u32; MR] = std::array::from_fn(|r| a.wrapping_add(r * lda));
    let mut c = [[_mm512_setzero_ps(); NV]; MR];
    for q in 0..kq {
        // SAFETY: q < kq: inside the panels the caller guarantees; B rows are 64-byte aligned.
        // `__m512i` and `__m512bh` are both 64-byte vectors, so the transmutes only retype.
        unsafe {
            let bp = b.add(q * NR);
            let bv: [__m512bh; NV] = std::array::from_fn(|v| {
                std::mem::transmute::<__m512i, __m512bh>(_mm512_load_si512(bp.add(16 * v).cast()))
            });
            for (acc, row) in c.iter_mut().zip(&rows) {
                let av =
                    std::mem::transmute::<__m512i, __m512bh>(_mm512_set1_epi32(*row.add(q) as i32));
                for (x, bv) in acc.iter_mut().zip(&bv) {
                    *x = _mm512_dpbf16_ps(*x, av, *bv);
                }
            }
        }
    }
    store_tile!(c, crow, ldc, t);
}

/// f32 → bf16 bits, round to nearest even, eight or sixteen at a time: the body of
/// `super::to_bf16_slice` compiled for AVX-512 (same operations, so same bits).
///
/// # Safety
/// AVX-512F and AVX-512BW present.
#[target_feature(enable = "avx512f,avx512bw")]
pub(super) unsafe fn to_bf16_pairs(src: &[f32], dst: &mut [u32]) {
    super::to_bf16_pairs_body(src, dst)
}
