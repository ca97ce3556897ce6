//! The sample loop's first half for 8 samples of one ray, in NEON (two registers of 4 f32
//! lanes): the arithmetic of `simd.rs`'s AVX2 path, where the loads are lane by lane, since
//! NEON has no gathers.
//!
//! Every operation mirrors the scalar code in `sample.rs` one for one (no fused multiply-add,
//! the same order, `fmaxnm`/`fminnm` for Rust's NaN-ignoring `max`/`min`), so the result is
//! bit-identical to the scalar path's, as on x86-64; a test checks it under qemu-user. The
//! corner indices are computed per lane in 64 bits (`value_index`), so unlike AVX2 this path
//! has no 32-bit index limit. NEON is part of the aarch64 baseline: nothing is detected at run
//! time.

use super::super::bricked::BRICK_POINTS;
use super::super::sample::{value_index, Chunk, MarchParams, Ray, Slots, Voxel, CHUNK};
use std::arch::aarch64::*;

/// Two NEON registers: lanes 0–3 and 4–7 of a chunk.
#[derive(Clone, Copy)]
struct F8(float32x4_t, float32x4_t);

impl F8 {
    #[inline(always)]
    fn splat(x: f32) -> F8 {
        // SAFETY: NEON is always present on aarch64.
        unsafe { F8(vdupq_n_f32(x), vdupq_n_f32(x)) }
    }

    #[inline(always)]
    fn load(a: &[f32; CHUNK]) -> F8 {
        // SAFETY: 8 f32 in `a`; NEON is always present on aarch64.
        unsafe { F8(vld1q_f32(a.as_ptr()), vld1q_f32(a.as_ptr().add(4))) }
    }

    #[inline(always)]
    fn store(self, a: &mut [f32; CHUNK]) {
        // SAFETY: room for 8 f32 in `a`.
        unsafe {
            vst1q_f32(a.as_mut_ptr(), self.0);
            vst1q_f32(a.as_mut_ptr().add(4), self.1);
        }
    }

    /// Lane-wise `f` on both halves.
    #[inline(always)]
    fn map2(self, o: F8, f: impl Fn(float32x4_t, float32x4_t) -> float32x4_t) -> F8 {
        F8(f(self.0, o.0), f(self.1, o.1))
    }

    #[inline(always)]
    fn add(self, o: F8) -> F8 {
        // SAFETY (this and the ones below): NEON is always present on aarch64.
        self.map2(o, |a, b| unsafe { vaddq_f32(a, b) })
    }
    #[inline(always)]
    fn sub(self, o: F8) -> F8 {
        self.map2(o, |a, b| unsafe { vsubq_f32(a, b) })
    }
    #[inline(always)]
    fn mul(self, o: F8) -> F8 {
        self.map2(o, |a, b| unsafe { vmulq_f32(a, b) })
    }
    /// Rust's `f32::max`: the non-NaN operand.
    #[inline(always)]
    fn max(self, o: F8) -> F8 {
        self.map2(o, |a, b| unsafe { vmaxnmq_f32(a, b) })
    }
    /// Rust's `f32::min`: the non-NaN operand.
    #[inline(always)]
    fn min(self, o: F8) -> F8 {
        self.map2(o, |a, b| unsafe { vminnmq_f32(a, b) })
    }

    /// `x.to_int_unchecked::<u32>().min(hi)` per lane (x ∈ [0, 2³²), not NaN): the integer
    /// and its value as f32.
    #[inline(always)]
    fn floor_min(self, hi: u32) -> ([u32; CHUNK], F8) {
        let mut out = [0u32; CHUNK];
        // SAFETY: NEON is always present; `out` holds 8 u32.
        unsafe {
            let h = vdupq_n_u32(hi);
            let (a, b) = (
                vminq_u32(vcvtq_u32_f32(self.0), h),
                vminq_u32(vcvtq_u32_f32(self.1), h),
            );
            vst1q_u32(out.as_mut_ptr(), a);
            vst1q_u32(out.as_mut_ptr().add(4), b);
            (out, F8(vcvtq_f32_u32(a), vcvtq_f32_u32(b)))
        }
    }
}

#[inline(always)]
fn lerp(a: F8, b: F8, w: F8) -> F8 {
    a.add(w.mul(b.sub(a)))
}

/// Interpolate and classify samples n … n + 7 of `ray` into `out`, bit for bit as
/// `interpolate_classify_scalar`.
// The scalar twin's parameters: the march calls whichever the CPU allows with the same
// arguments.
#[inline(always)]
pub(super) fn interpolate_classify<T: Voxel, S: Slots>(
    p: &MarchParams,
    (d, slots): (&[T], S),
    ray: &Ray,
    n: u32,
    delta_norm: f32,
    out: &mut Chunk,
) {
    let (g, lut) = (&p.grid, &p.lut.entries[..]);
    // u = (n + i) as f32 + jitter, as the scalar code rounds it.
    let u = F8::load(&std::array::from_fn(|i| (n + i as u32) as f32)).add(F8::splat(ray.jitter));
    let zero = F8::splat(0.0);
    let mut cells = [[0u32; CHUNK]; 3];
    let mut frac = [zero; 3];
    for ax in 0..3 {
        let x = F8::splat(ray.a[ax]).add(u.mul(F8::splat(ray.bd[ax])));
        let x = x.max(zero).min(F8::splat(g.max_coord[ax]));
        let (c, cf) = x.floor_min(g.max_cell[ax]);
        cells[ax] = c;
        frac[ax] = x.sub(cf);
    }
    // The 8 corners of each lane's cell, loaded lane by lane (64-bit indices).
    let (sy, sz) = (BRICK_POINTS, BRICK_POINTS * BRICK_POINTS);
    let mut corner = [[0f32; CHUNK]; 8];
    for i in 0..CHUNK {
        let base = value_index(
            g.brick_stride,
            slots,
            [cells[0][i], cells[1][i], cells[2][i]],
        );
        debug_assert!(base + 1 + sy + sz < d.len(), "cell outside the grid");
        for (k, off) in [0, 1, sy, sy + 1, sz, sz + 1, sz + sy, sz + sy + 1]
            .into_iter()
            .enumerate()
        {
            // SAFETY: as `sample::trilinear`'s loads: the cell is clamped into the grid, so
            // every corner lies inside its brick's values, inside `d`.
            corner[k][i] = unsafe { *d.get_unchecked(base + off) }.into();
        }
    }
    let c = |k: usize| F8::load(&corner[k]);
    let [fx, fy, fz] = frac;
    let c00 = lerp(c(0), c(1), fx);
    let c10 = lerp(c(2), c(3), fx);
    let c01 = lerp(c(4), c(5), fx);
    let c11 = lerp(c(6), c(7), fx);
    let v = lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz).mul(F8::splat(g.scale));
    v.store(&mut out.v);

    // Classification, as `classify` (NaN lanes: x = 0 here, τ = 0 below).
    let x = v
        .max(zero)
        .min(F8::splat(1.0))
        .mul(F8::splat((lut.len() - 1) as f32));
    let (j, jf) = x.floor_min(lut.len() as u32 - 2);
    let w = x.sub(jf);
    let mut entry = [[0f32; CHUNK]; 8];
    for (i, &ji) in j.iter().enumerate() {
        let (e0, e1) = (lut[ji as usize], lut[ji as usize + 1]);
        for k in 0..4 {
            entry[k][i] = e0[k];
            entry[k + 4][i] = e1[k];
        }
    }
    let e = |k: usize| F8::load(&entry[k]);
    let tau = lerp(e(0), e(4), w).mul(F8::splat(delta_norm));
    // τ = 0 where v is NaN.
    // SAFETY: NEON is always present on aarch64.
    let tau = unsafe {
        let keep = |v: float32x4_t, t: float32x4_t| {
            vreinterpretq_f32_u32(vandq_u32(vceqq_f32(v, v), vreinterpretq_u32_f32(t)))
        };
        F8(keep(v.0, tau.0), keep(v.1, tau.1))
    };
    out.j = j;
    w.store(&mut out.w);
    for ch in 0..3 {
        lerp(e(ch + 1), e(ch + 5), w).store(&mut out.rgb[ch]);
    }
    tau.store(&mut out.tau);
    // SAFETY: NEON is always present on aarch64.
    exp(F8(unsafe { vnegq_f32(tau.0) }, unsafe { vnegq_f32(tau.1) })).store(&mut out.ext);
}

/// `t2tf_core::math::fast_exp`, lane by lane, the same operations in the same order.
#[inline(always)]
fn exp(x: F8) -> F8 {
    const ROUND: f32 = 12_582_912.0;
    let s = F8::splat;
    let x = x.max(s(-87.0)).min(s(88.0));
    let t = x.mul(s(std::f32::consts::LOG2_E)).add(s(ROUND));
    let n = t.sub(s(ROUND));
    let g = x.sub(n.mul(s(0.693_359_4))).sub(n.mul(s(-2.121_944_4e-4)));
    let mut p = s(1.0 / 720.0);
    for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
        p = s(c).add(g.mul(p));
    }
    // 2^n from t's bits, as `fast_exp`: (bits(t) − bits(ROUND) + 127) << 23.
    // SAFETY: NEON is always present on aarch64.
    let scale = |t: float32x4_t| unsafe {
        let n = vsubq_u32(vreinterpretq_u32_f32(t), vdupq_n_u32(ROUND.to_bits()));
        vreinterpretq_f32_u32(vshlq_n_u32::<23>(vaddq_u32(n, vdupq_n_u32(127))))
    };
    p.mul(F8(scale(t.0), scale(t.1)))
}
