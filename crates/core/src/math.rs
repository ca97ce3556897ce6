//! Elementary functions for the hot loops (renderer, CLIP activations).

/// e^x to within ~2e-7 relative for x in [−87, 88] (clamped outside, so never inf or NaN
/// for finite x; NaN stays NaN). Straight-line code that inlines and vectorises: libm's `expf`
/// is a call, and in the renderer's sample loop that call spilled every live float register
/// (all of them are caller-saved); in CLIP's activations the call shows in the profile.
/// e^x = 2^n · e^g with n = round(x log2 e) and g = x − n ln 2 ∈ [−0.347, 0.347], e^g by its
/// Taylor series to g⁶ (remainder g⁷/7! < 1.3e-7).
#[inline(always)]
pub fn fast_exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // ln 2 = HI + LO with HI = 355/512 (9 significant bits, so n·HI is exact in f32), the
    // Cody–Waite reduction.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding then subtracting 1.5·2²³ rounds to the nearest integer for |t| < 2²².
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    let g = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.0
        + g * (1.0
            + g * (0.5
                + g * (1.0 / 6.0 + g * (1.0 / 24.0 + g * (1.0 / 120.0 + g * (1.0 / 720.0))))));
    // 2^n by building the exponent field; n ∈ [−126, 127] after the clamp. t lies in
    // [2²³, 2²⁴), where floats are the integers, so its bits minus those of 1.5·2²³ are n:
    // unlike `n as i32` (a saturating cast LLVM does not vectorise: eight scalar `cvttss2si`
    // per AVX2 vector in CLIP's activation loop), this vectorises. A NaN x gives a NaN p.
    let n_int = t.to_bits().wrapping_sub(ROUND.to_bits());
    let scale = f32::from_bits(n_int.wrapping_add(127) << 23);
    p * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The power of two from the float's bits equals the plain `n as i32` construction bit for
    /// bit, across the range, at the clamps and at the infinities.
    #[test]
    fn exponent_from_bits_equals_the_integer_cast() {
        fn with_cast(x: f32) -> f32 {
            let x = x.clamp(-87.0, 88.0);
            let n = (x * std::f32::consts::LOG2_E + 12_582_912.0) - 12_582_912.0;
            let g = (x - n * 0.693_359_4) - n * -2.121_944_4e-4;
            let p = 1.0
                + g * (1.0
                    + g * (0.5
                        + g * (1.0 / 6.0
                            + g * (1.0 / 24.0 + g * (1.0 / 120.0 + g * (1.0 / 720.0))))));
            p * f32::from_bits(((n as i32 + 127) as u32) << 23)
        }
        let mut xs: Vec<f32> = (-200_000..=200_000).map(|i| i as f32 * 5e-4).collect();
        xs.extend([
            f32::MAX,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -87.0,
            88.0,
            -0.0,
        ]);
        for x in xs {
            assert_eq!(fast_exp(x).to_bits(), with_cast(x).to_bits(), "{x}");
        }
        assert!(fast_exp(f32::NAN).is_nan());
    }

    #[test]
    fn fast_exp_is_accurate_and_finite() {
        let mut worst = 0.0f64;
        for i in -86_990..=87_990 {
            let x = i as f32 * 1e-3;
            let want = (x as f64).exp();
            worst = worst.max((fast_exp(x) as f64 - want).abs() / want);
        }
        assert!(worst < 3e-7, "worst relative error {worst:e}");
        for x in [
            f32::MAX,
            1e4,
            -1e4,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ] {
            assert!(fast_exp(x).is_finite() && fast_exp(x) >= 0.0, "{x}");
        }
        assert!(fast_exp(f32::NAN).is_nan());
        // Monotone where the renderer uses it (transmittance must not grow with density).
        let mut prev = fast_exp(0.0);
        for i in 1..100_000 {
            let e = fast_exp(-(i as f32) * 1e-3);
            assert!(e <= prev, "{i}");
            prev = e;
        }
    }
}
