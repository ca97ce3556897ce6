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
// The same micro-kernel shape as avx512.rs's `tile_f32` (signature, prefetch, MR × NR
// accumulators): kept apart because registers, widths and target features differ per ISA.
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
