//! Scalar micro-kernels for the two packed layouts: the reference every SIMD kernel is tested
//! against (`tests/clip/clip_kernels.rs`), and the f32 engine of CPUs without AVX2. They compute
//! the same sums as the SIMD kernels (one multiply-add per k step, in k order), so f32 results
//! agree with `Avx2Fma` to rounding of fused vs separate multiply-add.

use super::{Tile, MR};

/// f32, A interleaved `[kc][MR]`, B `[kc][nr]`.
///
/// # Safety
/// As `Tile::store_scalar`; `a` and `b` hold at least `kc·MR` and `kc·t.nr` floats.
pub(super) unsafe fn tile_f32(
    kc: usize,
    a: &[f32],
    b: &[f32],
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    let nr = t.nr;
    let mut acc = vec![0.0f32; MR * nr];
    for (ap, bp) in a[..kc * MR]
        .chunks_exact(MR)
        .zip(b[..kc * nr].chunks_exact(nr))
    {
        for (r, &av) in ap.iter().enumerate() {
            for (x, &bv) in acc[r * nr..][..nr].iter_mut().zip(bp) {
                *x = av.mul_add(bv, *x);
            }
        }
    }
    // SAFETY: forwarded from the caller.
    unsafe { t.store_scalar(&acc, crow, ldc) }
}

/// bf16 pairs (see `super::avx512::tile_bf16`): A as MR row streams of `kq` u32 with stride
/// `lda`, B `[kq][nr]` u32. Each bf16 widens exactly to f32 and the product of two bf16 values
/// is exact in f32, so only the additions round.
///
/// # Safety
/// As `Tile::store_scalar`; `a` holds `(MR − 1)·lda + kq` u32s, `b` at least `kq·t.nr`.
pub(super) unsafe fn tile_bf16(
    kq: usize,
    a: &[u32],
    lda: usize,
    b: &[u32],
    crow: *mut f32,
    ldc: usize,
    t: &Tile,
) {
    let nr = t.nr;
    let lo = |v: u32| f32::from_bits(v << 16);
    let hi = |v: u32| f32::from_bits(v & 0xffff_0000);
    let mut acc = vec![0.0f32; MR * nr];
    for (r, row) in acc.chunks_exact_mut(nr).enumerate() {
        let ar = &a[r * lda..][..kq];
        for (&av, bp) in ar.iter().zip(b[..kq * nr].chunks_exact(nr)) {
            let (a0, a1) = (lo(av), hi(av));
            for (x, &bv) in row.iter_mut().zip(bp) {
                *x += a0 * lo(bv) + a1 * hi(bv);
            }
        }
    }
    // SAFETY: forwarded from the caller.
    unsafe { t.store_scalar(&acc, crow, ldc) }
}
