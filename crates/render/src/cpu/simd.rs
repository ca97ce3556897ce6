//! The sample loop's first half for 8 samples of one ray at once, in AVX2: trilinear
//! interpolation (8 gathers of the bricked data) and LUT classification (8 gathers of the LUT),
//! then e^(−τ). The second half, compositing, is a serial chain and stays scalar. On aarch64
//! the same arithmetic runs in NEON (`simd/neon.rs`).
//!
//! Why hand-written: LLVM does not vectorise the scalar loop on the default x86-64 target
//! (SSE2, no gathers), and runtime dispatch needs the vector code in a `target_feature`
//! function anyway. Every operation mirrors the scalar code in `sample.rs` one for one (no
//! fused multiply-add, the same order), so both paths give bit-identical results — a test
//! checks it — and the result does not depend on which one the CPU takes.

#[cfg(any(target_arch = "x86_64", test))]
use super::sample::CHUNK;
use super::sample::{interpolate_classify_scalar, Chunk, MarchParams, Ray, Slots, Voxel};

/// Whether this CPU can run [`interpolate_classify`].
pub(crate) fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    // NEON is part of the aarch64 baseline.
    #[cfg(target_arch = "aarch64")]
    {
        true
    }
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    {
        false
    }
}

#[cfg(target_arch = "aarch64")]
mod neon;

/// Interpolate and classify samples n … n + 7 of `ray` (values `d`, the grid's, bricks at
/// `slots`) into `out` (see `Chunk`); without `p.simd` through the scalar code.
#[inline(always)]
pub(crate) fn interpolate_classify<T: Voxel, S: Slots>(
    p: &MarchParams,
    (d, slots): (&[T], S),
    ray: &Ray,
    n: u32,
    delta_norm: f32,
    out: &mut Chunk,
) {
    #[cfg(target_arch = "x86_64")]
    if p.simd {
        // SAFETY: `simd` is only true where `available()` said the CPU has AVX2 and the
        // grid's indices fit 32-bit lanes (`View` sets it from `available()` and
        // `Grid::gathers_fit`; tests from there too); `p.grid` holds `Grid`'s invariants
        // and a `Lut` has at least two entries (`render::backend::validate`).
        unsafe { avx2::interpolate_classify(p, (d, slots), ray, n, delta_norm, out) };
        return;
    }
    #[cfg(target_arch = "aarch64")]
    if p.simd {
        neon::interpolate_classify(p, (d, slots), ray, n, delta_norm, out);
        return;
    }
    interpolate_classify_scalar(p, (d, slots), ray, n, delta_norm, out);
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::super::bricked::{BRICK_POINTS, BRICK_VALUES};
    use super::super::sample::{Gather, GatherSlots, InPlace, Table};
    use super::*;
    use std::arch::x86_64::*;
    use t2tf_volume::BRICK_CELLS;

    const _: () = assert!(CHUNK == 8, "one AVX2 register of f32 lanes");

    #[inline(always)]
    unsafe fn lerp(a: __m256, b: __m256, w: __m256) -> __m256 {
        _mm256_add_ps(a, _mm256_mul_ps(w, _mm256_sub_ps(b, a)))
    }

    impl GatherSlots for InPlace {
        #[inline(always)]
        unsafe fn first_values(self, brick: __m256i) -> __m256i {
            _mm256_mullo_epi32(brick, _mm256_set1_epi32(BRICK_VALUES as i32))
        }
    }

    impl GatherSlots for Table<'_> {
        /// One gather of the slot table, then the slot's first value.
        #[inline(always)]
        unsafe fn first_values(self, brick: __m256i) -> __m256i {
            let slot = _mm256_i32gather_epi32::<4>(self.0.as_ptr().cast(), brick);
            _mm256_mullo_epi32(slot, _mm256_set1_epi32(BRICK_VALUES as i32))
        }
    }

    impl Gather for f32 {
        #[inline(always)]
        unsafe fn pair(ptr: *const f32, idx: __m256i, off: i32) -> (__m256, __m256) {
            let i = _mm256_add_epi32(idx, _mm256_set1_epi32(off));
            (
                _mm256_i32gather_ps::<4>(ptr, i),
                _mm256_i32gather_ps::<4>(ptr, _mm256_add_epi32(i, _mm256_set1_epi32(1))),
            )
        }
    }

    impl Gather for u16 {
        /// One 32-bit gather per pair: the two neighbours are adjacent 16-bit values.
        #[inline(always)]
        unsafe fn pair(ptr: *const u16, idx: __m256i, off: i32) -> (__m256, __m256) {
            let i = _mm256_add_epi32(idx, _mm256_set1_epi32(off));
            let both = _mm256_i32gather_epi32::<2>(ptr.cast(), i);
            (
                _mm256_cvtepi32_ps(_mm256_and_si256(both, _mm256_set1_epi32(0xFFFF))),
                _mm256_cvtepi32_ps(_mm256_srli_epi32::<16>(both)),
            )
        }
    }

    impl Gather for u8 {
        /// One 32-bit gather per pair: bytes 0 and 1 of the 4 loaded.
        #[inline(always)]
        unsafe fn pair(ptr: *const u8, idx: __m256i, off: i32) -> (__m256, __m256) {
            let i = _mm256_add_epi32(idx, _mm256_set1_epi32(off));
            let four = _mm256_i32gather_epi32::<1>(ptr.cast(), i);
            let byte = _mm256_set1_epi32(0xFF);
            (
                _mm256_cvtepi32_ps(_mm256_and_si256(four, byte)),
                _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<8>(four), byte)),
            )
        }
    }

    /// SAFETY (callers): the CPU has AVX2; `p.grid` satisfies `Grid`'s invariants, `d` is
    /// its value slice and `slots` its layout (every index below is then inside `d`, as in
    /// the scalar `trilinear`, plus `bricked::PAD` for the 4-byte gathers), its values and
    /// slot table fit 32-bit indices (`Grid::gathers_fit`), and the LUT has at least two
    /// entries.
    // The dispatcher's and the scalar twin's parameters: the march calls whichever the CPU
    // allows with the same arguments.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn interpolate_classify<T: Voxel, S: Slots>(
        p: &MarchParams,
        (d, slots): (&[T], S),
        ray: &Ray,
        n: u32,
        delta_norm: f32,
        out: &mut Chunk,
    ) {
        let (g, lut) = (&p.grid, &p.lut.entries[..]);
        let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        // u = (n + i) as f32 + jitter, exactly as the scalar code rounds it.
        let u = _mm256_add_ps(
            _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(n as i32), lanes)),
            _mm256_set1_ps(ray.jitter),
        );
        let zero = _mm256_setzero_ps();
        let axis = |ax: usize| {
            let p = _mm256_add_ps(
                _mm256_set1_ps(ray.a[ax]),
                _mm256_mul_ps(u, _mm256_set1_ps(ray.bd[ax])),
            );
            // max(p, 0) then min(·, dims − 1); positions are never NaN.
            let p = _mm256_min_ps(_mm256_max_ps(p, zero), _mm256_set1_ps(g.max_coord[ax]));
            // Truncation (p ≥ 0), then the cell clamp.
            let c = _mm256_min_epi32(
                _mm256_cvttps_epi32(p),
                _mm256_set1_epi32(g.max_cell[ax] as i32),
            );
            (c, _mm256_sub_ps(p, _mm256_cvtepi32_ps(c)))
        };
        let ((cx, fx), (cy, fy), (cz, fz)) = (axis(0), axis(1), axis(2));
        let shift = BRICK_CELLS.trailing_zeros() as i32;
        let mask = _mm256_set1_epi32(BRICK_CELLS as i32 - 1);
        let brick = _mm256_add_epi32(
            _mm256_add_epi32(
                _mm256_srl_epi32(cx, _mm_cvtsi32_si128(shift)),
                _mm256_mullo_epi32(
                    _mm256_set1_epi32(g.brick_stride[0] as i32),
                    _mm256_srl_epi32(cy, _mm_cvtsi32_si128(shift)),
                ),
            ),
            _mm256_mullo_epi32(
                _mm256_set1_epi32(g.brick_stride[1] as i32),
                _mm256_srl_epi32(cz, _mm_cvtsi32_si128(shift)),
            ),
        );
        let p = _mm256_set1_epi32(BRICK_POINTS as i32);
        let local = _mm256_add_epi32(
            _mm256_and_si256(cx, mask),
            _mm256_mullo_epi32(
                p,
                _mm256_add_epi32(
                    _mm256_and_si256(cy, mask),
                    _mm256_mullo_epi32(p, _mm256_and_si256(cz, mask)),
                ),
            ),
        );
        let base = _mm256_add_epi32(slots.first_values(brick), local);
        let d = d.as_ptr();
        let (sy, sz) = (BRICK_POINTS as i32, (BRICK_POINTS * BRICK_POINTS) as i32);
        let pair = |off: i32| T::pair(d, base, off);
        let lerp_pair = |(a, b): (__m256, __m256), w: __m256| lerp(a, b, w);
        let c00 = lerp_pair(pair(0), fx);
        let c10 = lerp_pair(pair(sy), fx);
        let c01 = lerp_pair(pair(sz), fx);
        let c11 = lerp_pair(pair(sz + sy), fx);
        let v = _mm256_mul_ps(
            lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz),
            _mm256_set1_ps(g.scale),
        );
        _mm256_storeu_ps(out.v.as_mut_ptr(), v);

        // Classification, as `classify` (NaN lanes: x = 0 here, τ = 0 below).
        let x = _mm256_mul_ps(
            _mm256_min_ps(_mm256_max_ps(v, zero), _mm256_set1_ps(1.0)),
            _mm256_set1_ps((lut.len() - 1) as f32),
        );
        let j = _mm256_min_epi32(
            _mm256_cvttps_epi32(x),
            _mm256_set1_epi32(lut.len() as i32 - 2),
        );
        let w = _mm256_sub_ps(x, _mm256_cvtepi32_ps(j));
        let l = lut.as_ptr().cast::<f32>();
        let j4 = _mm256_slli_epi32::<2>(j);
        let entry =
            |off: i32| _mm256_i32gather_ps::<4>(l, _mm256_add_epi32(j4, _mm256_set1_epi32(off)));
        let nan = _mm256_cmp_ps::<_CMP_UNORD_Q>(v, v);
        let tau = _mm256_andnot_ps(
            nan,
            _mm256_mul_ps(lerp(entry(0), entry(4), w), _mm256_set1_ps(delta_norm)),
        );
        _mm256_storeu_si256(out.j.as_mut_ptr().cast(), j);
        _mm256_storeu_ps(out.w.as_mut_ptr(), w);
        for c in 0..3 {
            let rgb = lerp(entry(c as i32 + 1), entry(c as i32 + 5), w);
            _mm256_storeu_ps(out.rgb[c].as_mut_ptr(), rgb);
        }
        _mm256_storeu_ps(out.tau.as_mut_ptr(), tau);
        _mm256_storeu_ps(out.ext.as_mut_ptr(), exp(_mm256_sub_ps(zero, tau)));
    }

    /// `t2tf_core::math::fast_exp`, lane by lane, the same operations in the same order.
    #[inline(always)]
    unsafe fn exp(x: __m256) -> __m256 {
        let s = _mm256_set1_ps;
        let x = _mm256_min_ps(_mm256_max_ps(x, s(-87.0)), s(88.0));
        let n = _mm256_sub_ps(
            _mm256_add_ps(
                _mm256_mul_ps(x, s(std::f32::consts::LOG2_E)),
                s(12_582_912.0),
            ),
            s(12_582_912.0),
        );
        let g = _mm256_sub_ps(
            _mm256_sub_ps(x, _mm256_mul_ps(n, s(0.693_359_4))),
            _mm256_mul_ps(n, s(-2.121_944_4e-4)),
        );
        let horner = |acc: __m256, c: f32| _mm256_add_ps(s(c), _mm256_mul_ps(g, acc));
        let mut p = s(1.0 / 720.0);
        for c in [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0] {
            p = horner(p, c);
        }
        let scale = _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_add_epi32(
            _mm256_cvttps_epi32(n),
            _mm256_set1_epi32(127),
        )));
        _mm256_mul_ps(p, scale)
    }
}

#[cfg(test)]
mod tests {
    use super::super::bricked::BrickValues;
    use super::super::march::BoxFrame;
    use super::super::sample::{Grid, InPlace};
    use super::super::{skip, tests::whole, CpuBackend};
    use super::*;
    use crate::backend::Backend;
    use glam::DVec3;
    use std::path::Path;
    use t2tf_tf::Lut;
    use t2tf_volume::{Geometry, ScalarType, TypedBuffer, Volume};

    /// The vector path (AVX2 on x86-64, NEON on aarch64) gives exactly the scalar path's
    /// values and classes, for every stored type, on rays through all of a volume (partial
    /// bricks, NaN voxels for f32).
    #[test]
    fn vector_path_matches_scalar_bit_for_bit() {
        if !available() {
            eprintln!("no vector path on this CPU: only the scalar path runs");
            return;
        }
        let dims = [21usize, 13, 10];
        let n: usize = dims.iter().product();
        let raw: Vec<u16> = (0..n).map(|i| ((i * 7919) % 4001) as u16).collect();
        let u8s: Vec<u8> = raw.iter().map(|&v| (v % 256) as u8).collect();
        let mut floats: Vec<f64> = raw.iter().map(|&v| v as f64 * 0.37 - 3.0).collect();
        floats[17] = f64::NAN;
        let g = Geometry {
            dims,
            spacing: [1.0, 0.8, 1.5],
            origin: [0.0; 3],
        };
        let le = t2tf_volume::ByteOrder::Little;
        let volumes = [
            TypedBuffer::new(ScalarType::U8, le, u8s),
            TypedBuffer::new(
                ScalarType::U16,
                le,
                raw.iter().flat_map(|v| v.to_le_bytes()).collect(),
            ),
            TypedBuffer::from_f64(floats),
        ]
        .map(|b| Volume::from_buffer(Path::new("t"), g, &b).unwrap());
        let lut = Lut {
            entries: (0..64)
                .map(|j| {
                    [
                        (j as f32 * 0.61).sin().abs() * 40.0,
                        0.2,
                        j as f32 / 64.0,
                        0.7,
                    ]
                })
                .collect(),
        };
        let mut kinds = Vec::new();
        for v in &volumes {
            let level = &v.levels[0];
            let prepared = CpuBackend::default().prepare(v, 0).unwrap();
            kinds.push(match prepared.values() {
                BrickValues::U8(_) => "u8",
                BrickValues::U16(_) => "u16",
                BrickValues::F32(_) => "f32",
            });
            let blocks = skip::blocks(&level.bricks, &lut, false, 0.0, false);
            let params = |simd: bool| MarchParams {
                grid: Grid::new(dims, whole(&prepared), None, &blocks),
                lut: &lut,
                inv_l: 1.0 / 20.0,
                stop_below: 0.0,
                simd,
            };
            let (vector, scalar) = (params(true), params(false));
            let mut compared = 0;
            for k in 0..40 {
                let a = k as f64 * 0.61;
                let dir = DVec3::new(a.cos(), a.sin(), 0.4 * (1.7 * a).sin()).normalize();
                let eye = DVec3::new(10.0, 5.0, 7.0) - 40.0 * dir;
                let frame =
                    BoxFrame::new(eye, DVec3::ZERO, DVec3::from_array(g.spacing), dims, 0.37);
                let Some(ray) = frame.clip(dir, (k as f32 * 0.13).fract()) else {
                    continue;
                };
                for n in (0..ray.segments()).step_by(CHUNK) {
                    let (mut fast, mut slow) = (Chunk::default(), Chunk::default());
                    let run = |p: &MarchParams, out: &mut Chunk| match p.grid.values {
                        BrickValues::U8(x) => {
                            interpolate_classify(p, (x, InPlace), &ray, n, p.inv_l, out)
                        }
                        BrickValues::U16(x) => {
                            interpolate_classify(p, (x, InPlace), &ray, n, p.inv_l, out)
                        }
                        BrickValues::F32(x) => {
                            interpolate_classify(p, (x, InPlace), &ray, n, p.inv_l, out)
                        }
                    };
                    run(&vector, &mut fast);
                    run(&scalar, &mut slow);
                    for i in 0..CHUNK {
                        // NaN samples: both NaN (payloads may differ), the rest equal bits.
                        assert_eq!(fast.v[i].is_nan(), slow.v[i].is_nan());
                        let bits = |c: &Chunk| {
                            let v = if c.v[i].is_nan() { 0.0 } else { c.v[i] };
                            [
                                v,
                                c.w[i],
                                c.rgb[0][i],
                                c.rgb[1][i],
                                c.rgb[2][i],
                                c.tau[i],
                                c.ext[i],
                            ]
                            .map(f32::to_bits)
                        };
                        assert_eq!(
                            bits(&fast),
                            bits(&slow),
                            "ray {k}, sample {}",
                            n as usize + i
                        );
                        assert_eq!(fast.j[i], slow.j[i]);
                    }
                    compared += CHUNK;
                }
            }
            assert!(compared > 1000, "only {compared} samples compared");
        }
        assert_eq!(kinds, ["u8", "u16", "f32"]);
    }
}
