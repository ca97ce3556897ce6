//! Elementary functions for the hot loops (renderer, CLIP activations).

/// e^x to within ~2e-7 relative for x in [−87, 88] (clamped outside, so never inf or NaN
/// for finite x; NaN stays NaN). Straight-line code that inlines and vectorises: libm's `expf`
/// is a call, and in the renderer's sample loop that call spilled every live float register
/// (all of them are caller-saved); in CLIP it was 5 % of the profile.
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
    let n = (x * LOG2E + ROUND) - ROUND;
    let g = (x - n * LN2_HI) - n * LN2_LO;
    let p = 1.0
        + g * (1.0
            + g * (0.5
                + g * (1.0 / 6.0 + g * (1.0 / 24.0 + g * (1.0 / 120.0 + g * (1.0 / 720.0))))));
    // 2^n by building the exponent field; n ∈ [−126, 127] after the clamp.
    let scale = f32::from_bits(((n as i32 + 127) as u32) << 23);
    p * scale
}

#[cfg(test)]
mod tests {
    use super::*;

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
