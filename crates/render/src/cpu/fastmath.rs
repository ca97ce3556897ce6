//! Inlined f32 `ceil` for the march's inner loop.
//!
//! Why hand-written: on the default x86-64 target (SSE2 only) `f32::ceil` is a call into libm
//! (no `roundss` without SSE4.1); the march rounds once per block it crosses, and a call there
//! makes the compiler spill the loop's live floats. (`exp` is `t2tf_core::math::fast_exp`, shared
//! with CLIP.)

/// ⌈v⌉ for finite or infinite v (f32 values of magnitude ≥ 2²³ are already integers).
#[inline(always)]
pub(crate) fn ceil(v: f32) -> f32 {
    if v.abs() < 8_388_608.0 {
        let t = v as i32 as f32;
        if t < v {
            t + 1.0
        } else {
            t
        }
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ceil_matches_std() {
        for v in [
            -1.0,
            -0.999,
            -0.5,
            -0.0,
            0.0,
            0.2,
            1.0,
            1.0001,
            7.5,
            8_388_607.5,
            1e9,
            -1e9,
        ] {
            assert_eq!(ceil(v), v.ceil(), "{v}");
        }
        assert_eq!(ceil(f32::INFINITY), f32::INFINITY);
    }
}
