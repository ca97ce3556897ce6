//! The AVX2 + FMA 6 × 16 micro-kernel (`Kernel::Avx2Fma`): the kernel of AVX2-only CPUs (Zen 3
//! and older).

use std::arch::x86_64::*;

use super::{Tile, MR};

/// Columns of this kernel's B panels.
pub(super) const NR: usize = 16;

/// The 6 × 16 micro-kernel: 12 ymm accumulators (row r in `c[2r]`, `c[2r + 1]`), per k step
/// two aligned loads of B, six broadcasts of A and twelve FMAs, which keeps both of Zen 3's
/// FMA pipes busy (the 4 other ymm registers hold B and a broadcast).
///
/// # Safety
/// AVX2 and FMA present; `a` readable for `kc·MR` floats (`[kc][MR]`), `b` for `kc·NR` floats
/// and 32-byte aligned; `t.nr == NR`; C as in `Tile::store_scalar`.
#[target_feature(enable = "avx2,fma")]
// Shaped as avx512.rs's `tile_f32` (signature, prefetch, MR × NR accumulators), with AVX2's
// registers, widths and target features.
pub(super) unsafe fn tile(
    kc: usize,
    a: *const f32,
    b: *const f32,
    prefetch: &[f32],
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    debug_assert_eq!(t.nr, NR);
    // Prefetches are hints: they never fault, whatever the address.
    for line in prefetch.chunks(16) {
        _mm_prefetch::<_MM_HINT_T1>(line.as_ptr().cast());
    }
    if t.full() {
        // C's tile is read (or written) after the loop; start fetching it now.
        for r in 0..MR {
            let row = crow.wrapping_offset((r * ldc) as isize + t.col0);
            _mm_prefetch::<_MM_HINT_T0>(row.cast());
            _mm_prefetch::<_MM_HINT_T0>(row.wrapping_add(NR - 1).cast());
        }
    }
    let mut c = [_mm256_setzero_ps(); 2 * MR];
    for p in 0..kc {
        // SAFETY: p < kc, so these reads stay within the panels the caller guarantees;
        // B lines are 64-byte aligned.
        unsafe {
            let b0 = _mm256_load_ps(b.add(p * NR));
            let b1 = _mm256_load_ps(b.add(p * NR + 8));
            for r in 0..MR {
                let av = _mm256_broadcast_ss(&*a.add(p * MR + r));
                c[2 * r] = _mm256_fmadd_ps(av, b0, c[2 * r]);
                c[2 * r + 1] = _mm256_fmadd_ps(av, b1, c[2 * r + 1]);
            }
        }
    }
    if let Some(bias) = t.bias {
        // SAFETY: the tile's bias has NR floats.
        let (b0, b1) = unsafe {
            (
                _mm256_loadu_ps(bias.as_ptr()),
                _mm256_loadu_ps(bias.as_ptr().add(8)),
            )
        };
        for r in 0..MR {
            c[2 * r] = _mm256_add_ps(c[2 * r], b0);
            c[2 * r + 1] = _mm256_add_ps(c[2 * r + 1], b1);
        }
    }
    if t.full() {
        for r in 0..MR {
            // SAFETY: a full tile: rows 0..MR and columns col0 .. col0 + NR (col0 ≥ 0
            // since lo = 0) are inside C by the caller's guarantee.
            unsafe {
                let dst = crow.offset((r * ldc) as isize + t.col0);
                let (mut v0, mut v1) = (c[2 * r], c[2 * r + 1]);
                if t.add {
                    v0 = _mm256_add_ps(v0, _mm256_loadu_ps(dst));
                    v1 = _mm256_add_ps(v1, _mm256_loadu_ps(dst.add(8)));
                }
                _mm256_storeu_ps(dst, v0);
                _mm256_storeu_ps(dst.add(8), v1);
            }
        }
    } else {
        let mut acc = [0.0f32; MR * NR];
        for (r, v) in c.iter().enumerate() {
            // SAFETY: 2·MR vectors of 8 fill the MR·NR array exactly.
            unsafe { _mm256_storeu_ps(acc.as_mut_ptr().add(r * 8), *v) };
        }
        // The bias is already in the accumulators.
        let t = Tile { bias: None, ..*t };
        // SAFETY: forwarded from the caller.
        unsafe { t.store_scalar(&acc, crow, ldc) }
    }
}

/// The 6 × 16 kernel of a transposed product (`gemm_t`) with its left operand read in place
/// from a forward's packed panels: the 6 rows of one 16-step chunk are 16 floats apart and
/// the chunk's k steps contiguous (row r, step p at `a + r·16 + p`), the next chunk
/// `kstride` floats on; `a` is the first chunk's start, which the block enters at step `off`.
/// Gathering that operand into the interleaved `[k][6]` layout on every call instead made the
/// product 1.85× the time of one with a second packed copy on Zen 3. The same broadcasts,
/// loads and FMAs as [`tile`], in the same order, so the sums are those of a packed operand
/// bit for bit. The tile `[6][16]` is written to (`add`: added to) `out`'s rows, `ldo` floats
/// apart.
///
/// # Safety
/// AVX2 and FMA present; `off < 16`; for every chunk the block touches, the 6 rows × 16
/// floats readable; `b` readable for `kc·NR` floats and 32-byte aligned; `out` writable (and
/// with `add` readable) for 6 rows of 16 floats at stride `ldo`.
#[target_feature(enable = "avx2,fma")]
// A transposed product's arguments: the in-place operand's address, entry step and chunk
// stride, the packed panel, and where the tile goes.
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn tile_t(
    kc: usize,
    a: *const f32,
    off: usize,
    kstride: usize,
    b: *const f32,
    out: *mut f32,
    ldo: usize,
    add: bool,
) {
    debug_assert!(off < NR);
    let mut c = [_mm256_setzero_ps(); 2 * MR];
    // One k step: two loads of B, six broadcasts from the chunk's rows, twelve FMAs.
    // SAFETY (of every call): step `p` < kc of the panels the caller guarantees: B lines are
    // 32-byte aligned, and the chunk's 6 rows hold 16 floats each.
    let step = |c: &mut [__m256; 2 * MR], chunk: *const f32, s: usize, p: usize| unsafe {
        let b0 = _mm256_load_ps(b.add(p * NR));
        let b1 = _mm256_load_ps(b.add(p * NR + 8));
        for r in 0..MR {
            let av = _mm256_broadcast_ss(&*chunk.add(r * NR + s));
            c[2 * r] = _mm256_fmadd_ps(av, b0, c[2 * r]);
            c[2 * r + 1] = _mm256_fmadd_ps(av, b1, c[2 * r + 1]);
        }
    };
    let (mut p, mut chunk, mut first) = (0, a, off);
    while p < kc {
        // The next chunk's six lines (48 KiB on for a 768-row B): not in a stream the
        // hardware prefetcher follows. Prefetches are hints: they never fault.
        let next = chunk.wrapping_add(kstride);
        for r in 0..MR {
            _mm_prefetch::<_MM_HINT_T0>(next.wrapping_add(r * NR).cast());
        }
        let steps = (NR - first).min(kc - p);
        if steps == NR {
            // A whole chunk: a constant trip count the compiler unrolls.
            for s in 0..NR {
                step(&mut c, chunk, s, p + s);
            }
        } else {
            for s in 0..steps {
                step(&mut c, chunk, first + s, p + s);
            }
        }
        p += steps;
        first = 0;
        chunk = next;
    }
    for r in 0..MR {
        // SAFETY: row r of `out` holds 16 floats (the caller's guarantee).
        unsafe {
            let dst = out.add(r * ldo);
            let (mut v0, mut v1) = (c[2 * r], c[2 * r + 1]);
            if add {
                v0 = _mm256_add_ps(_mm256_loadu_ps(dst), v0);
                v1 = _mm256_add_ps(_mm256_loadu_ps(dst.add(8)), v1);
            }
            _mm256_storeu_ps(dst, v0);
            _mm256_storeu_ps(dst.add(8), v1);
        }
    }
}
