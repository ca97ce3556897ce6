//! The paper's initialization: random colours in [0.3, 0.7], densities inversely proportional
//! to the volume histogram, scaled by one factor so that the mean T_N over the rays of the
//! fixed view V0 is ρ (0.05).
//!
//! The scale search runs against a closure `mean_transmittance(&ControlPoints) -> f64`, so the
//! same code drives the real renderer and the tests' analytic model.

use rand::Rng;

use super::{InitError, OptimizeError};
use crate::tf::ControlPoints;

/// Floor added to the histogram density before inverting, in units of the uniform density
/// (a value range holding its fair share of voxels has density 1).
///
/// Why 0.01: value ranges with no voxels at all (gaps between the levels of integer data, the
/// empty top of a skewed range) would get infinite density from 1/p. With the floor their
/// weight is at most 100× that of a range with its fair share, and the ratio between the
/// emptiest and the fullest point is bounded by (p_max + 0.01)/0.01 — about 1e4 for CT air,
/// which fills ~40 % of the voxels in one of 256 bins (p ≈ 100). That keeps every initial σ
/// representable after the one common scale, and empty ranges cost nothing: they render
/// nothing whatever their density.
pub(crate) const DENSITY_FLOOR: f64 = 0.01;

/// Colours uniform in [0.3, 0.7] per channel (away from the flat ends of tanh).
pub(crate) fn random_colours(k: usize, rng: &mut impl Rng) -> Vec<[f64; 3]> {
    (0..k)
        .map(|_| std::array::from_fn(|_| rng.random_range(0.3..=0.7)))
        .collect()
}

/// Relative densities at control points `x` (normalized, ascending), inversely proportional
/// to the histogram, scaled so the largest is 1.
///
/// The histogram is smoothed with each point's own hat function (the piecewise-linear basis
/// function that is 1 at x_k and 0 at its neighbours): that average is exactly the share of
/// voxels whose colour σ_k influences, and it follows the control-point spacing, so 8 or 512
/// points both see a sensible estimate. When no bin centre falls under a hat (points closer
/// than a bin), the bin holding x_k is used.
pub(crate) fn inverse_histogram_weights(
    histogram: &[u64],
    x: &[f64],
) -> Result<Vec<f64>, OptimizeError> {
    let total: u64 = histogram.iter().sum();
    if histogram.is_empty() || total == 0 {
        return Err(InitError::EmptyHistogram.into());
    }
    if x.len() < 2
        || x.iter().any(|v| !(0.0..=1.0).contains(v))
        || x.windows(2).any(|w| w[1] < w[0])
    {
        return Err(InitError::Positions(x.to_vec()).into());
    }
    let bins = histogram.len();
    // Density per unit of normalized value, uniform = 1.
    let density: Vec<f64> = histogram
        .iter()
        .map(|&c| c as f64 / total as f64 * bins as f64)
        .collect();
    let k = x.len();
    let mut w = Vec::with_capacity(k);
    for i in 0..k {
        let left = if i > 0 { x[i - 1] } else { x[i] };
        let right = if i + 1 < k { x[i + 1] } else { x[i] };
        let (mut num, mut den) = (0.0, 0.0);
        for (j, d) in density.iter().enumerate() {
            let c = (j as f64 + 0.5) / bins as f64;
            let hat = if c < x[i] && x[i] > left {
                (c - left) / (x[i] - left)
            } else if c >= x[i] && right > x[i] {
                (right - c) / (right - x[i])
            } else {
                0.0
            };
            if hat > 0.0 {
                num += hat * d;
                den += hat;
            }
        }
        let p = if den > 0.0 {
            num / den
        } else {
            density[((x[i] * bins as f64) as usize).min(bins - 1)]
        };
        w.push(1.0 / (p + DENSITY_FLOOR));
    }
    let max = w.iter().cloned().fold(0.0, f64::max);
    Ok(w.into_iter().map(|v| v / max).collect())
}

/// The result of the initialization.
#[derive(Clone, Debug)]
pub struct Initialization {
    /// The initial TF: evenly spaced points, seeded colours, scaled densities.
    pub control_points: ControlPoints,
    /// The common density scale: σ_k = min(255, scale · w_k).
    pub scale: f64,
    /// Mean T_N of V0 at that scale.
    pub mean_transmittance: f64,
    /// Calls of `mean_transmittance` made.
    pub evaluations: usize,
    /// False when even σ = 255 everywhere leaves the mean T_N above ρ (a thin or small
    /// volume): the most opaque TF allowed is returned then, and the caller should say so.
    pub reached: bool,
}

/// Relative tolerance on ρ at which the search stops (|T − ρ| ≤ 2 % of ρ): the paper asks
/// for "approximately ρ", and each evaluation is a render of V0.
const RHO_TOLERANCE: f64 = 0.02;

/// Find the one scale s with mean T_N(σ = min(255, s·w)) = ρ by bisection on log s.
///
/// Mean transmittance is non-increasing in every σ, hence in s, so the bracket
/// [s_max · 1e-9, s_max] (s_max saturates every point at 255) holds the answer whenever it
/// exists. A non-finite or out-of-[0, 1] transmittance is an error.
pub(crate) fn fit_density(
    x: &[f64],
    colours: &[[f64; 3]],
    weights: &[f64],
    rho: f64,
    mut mean_transmittance: impl FnMut(&ControlPoints) -> f64,
) -> Result<Initialization, OptimizeError> {
    if !(rho > 0.0 && rho < 1.0) {
        return Err(InitError::Rho(rho).into());
    }
    if weights.len() != x.len()
        || colours.len() != x.len()
        || weights.iter().any(|w| !(w.is_finite() && *w > 0.0))
    {
        return Err(InitError::Weights.into());
    }
    let min_w = weights.iter().cloned().fold(f64::INFINITY, f64::min);
    let points = |s: f64| ControlPoints {
        x: x.to_vec(),
        sigma: weights.iter().map(|w| (s * w).min(255.0)).collect(),
        rgb: colours.to_vec(),
    };
    let mut evaluations = 0;
    let mut eval = |s: f64| -> Result<f64, OptimizeError> {
        evaluations += 1;
        let t = mean_transmittance(&points(s));
        if !(t.is_finite() && (-1e-6..=1.0 + 1e-6).contains(&t)) {
            return Err(InitError::Transmittance {
                transmittance: t,
                scale: s,
            }
            .into());
        }
        Ok(t)
    };
    let s_hi = 255.0 / min_w;
    let t_hi = eval(s_hi)?;
    let done = |s: f64, t: f64, reached: bool, evaluations: usize| Initialization {
        control_points: points(s),
        scale: s,
        mean_transmittance: t,
        evaluations,
        reached,
    };
    if t_hi > rho * (1.0 + RHO_TOLERANCE) {
        return Ok(done(s_hi, t_hi, false, evaluations));
    }
    let s_lo = s_hi * 1e-9;
    let t_lo = eval(s_lo)?;
    if t_lo <= rho {
        return Ok(done(s_lo, t_lo, true, evaluations));
    }
    // Invariant: T(lo) > ρ ≥ T(hi) (up to the tolerance). Keep the closer end as the answer.
    let (mut lo, mut hi) = (s_lo.ln(), s_hi.ln());
    let mut best = (s_hi, t_hi);
    for _ in 0..100 {
        if (best.1 - rho).abs() <= RHO_TOLERANCE * rho || hi - lo < 1e-9 {
            break;
        }
        let mid = 0.5 * (lo + hi);
        let t = eval(mid.exp())?;
        if (t - rho).abs() < (best.1 - rho).abs() {
            best = (mid.exp(), t);
        }
        if t > rho {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(done(best.0, best.1, true, evaluations))
}

/// The whole initialization: colours from `rng`, weights from the histogram, then the scale.
pub fn initialize(
    x: &[f64],
    histogram: &[u64],
    rho: f64,
    rng: &mut impl Rng,
    mean_transmittance: impl FnMut(&ControlPoints) -> f64,
) -> Result<Initialization, OptimizeError> {
    let weights = inverse_histogram_weights(histogram, x)?;
    let colours = random_colours(x.len(), rng);
    fit_density(x, &colours, &weights, rho, mean_transmittance)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn even(k: usize) -> Vec<f64> {
        (0..k).map(|i| i as f64 / (k - 1) as f64).collect()
    }

    /// Analytic stand-in for the renderer: ray r crosses "material" k over length a_rk, so
    /// T_r = exp(−Σ_k σ_k a_rk / 255 · 20). Monotone in every σ, like the real one.
    fn model(a: &[Vec<f64>]) -> impl FnMut(&ControlPoints) -> f64 + '_ {
        move |cp: &ControlPoints| {
            a.iter()
                .map(|row| {
                    (-row.iter().zip(&cp.sigma).map(|(a, s)| a * s).sum::<f64>() / 255.0 * 20.0)
                        .exp()
                })
                .sum::<f64>()
                / a.len() as f64
        }
    }

    fn rays(rng: &mut ChaCha8Rng, n: usize, k: usize, scale: f64) -> Vec<Vec<f64>> {
        (0..n)
            .map(|_| (0..k).map(|_| scale * rng.random_range(0.0..1.0)).collect())
            .collect()
    }

    #[test]
    fn colours_are_in_range_and_seeded() {
        let a = random_colours(50, &mut ChaCha8Rng::seed_from_u64(9));
        let b = random_colours(50, &mut ChaCha8Rng::seed_from_u64(9));
        assert_eq!(a, b);
        assert!(a.iter().flatten().all(|c| (0.3..=0.7).contains(c)));
        let mean = a.iter().flatten().sum::<f64>() / 150.0;
        assert!((mean - 0.5).abs() < 0.03, "{mean}");
    }

    #[test]
    fn weights_are_inverse_to_the_histogram() {
        // 256 bins: a huge peak at the bottom (air), a plateau in the middle, nothing on top.
        let mut h = vec![0u64; 256];
        h[0] = 1_000_000;
        for b in h.iter_mut().take(160).skip(100) {
            *b = 1000;
        }
        let x = even(9);
        let w = inverse_histogram_weights(&h, &x).unwrap();
        assert!(w.iter().all(|v| v.is_finite() && *v > 0.0 && *v <= 1.0));
        // Point 0 (air) gets the lowest weight, the empty top range the highest (= 1).
        let argmin = (0..9).min_by(|&a, &b| w[a].total_cmp(&w[b])).unwrap();
        assert_eq!(argmin, 0);
        assert_eq!(w[8], 1.0);
        // Plateau point (x = 0.5, bins 100..160) lies between.
        assert!(w[4] > w[0] && w[4] < w[8]);
        // Bounded ratio (the floor): max/min ≤ (p_max + floor)/floor.
        let p_max = 256.0 * 1e6 / (1e6 + 60.0 * 1000.0);
        assert!(1.0 / w[0] <= (p_max + DENSITY_FLOOR) / DENSITY_FLOOR * 1.0001);
    }

    #[test]
    fn weights_for_constant_volume_dense_points_and_bad_input() {
        // Constant volume: every voxel in the middle bin (Volume maps it to 0.5).
        let mut h = vec![0u64; 256];
        h[128] = 4096;
        let w = inverse_histogram_weights(&h, &even(32)).unwrap();
        assert!(w.iter().all(|v| v.is_finite() && *v > 0.0));
        // More points than bins: every hat is narrower than a bin for most points.
        let w = inverse_histogram_weights(&h, &even(1000)).unwrap();
        assert!(w.iter().all(|v| v.is_finite() && *v > 0.0));
        // Collapsed points.
        let w = inverse_histogram_weights(&h, &[0.0, 0.5, 0.5, 0.5, 1.0]).unwrap();
        assert!(w.iter().all(|v| v.is_finite() && *v > 0.0));
        assert!(inverse_histogram_weights(&[0; 256], &even(4)).is_err());
        assert!(inverse_histogram_weights(&h, &[0.0, 1.5]).is_err());
        assert!(inverse_histogram_weights(&h, &[0.5, 0.2]).is_err());
    }

    #[test]
    fn scale_search_reaches_rho() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let x = even(16);
        let a = rays(&mut rng, 200, 16, 1.0);
        let mut h = vec![10u64; 256];
        h[0] = 100_000;
        let init = initialize(&x, &h, 0.05, &mut rng, model(&a)).unwrap();
        assert!(init.reached);
        assert!(
            (init.mean_transmittance - 0.05).abs() <= 0.02 * 0.05,
            "{}",
            init.mean_transmittance
        );
        // The returned points are what was measured, and σ ∝ weights below the cap.
        let t = model(&a)(&init.control_points);
        assert_eq!(t, init.mean_transmittance);
        let w = inverse_histogram_weights(&h, &x).unwrap();
        for (s, w) in init.control_points.sigma.iter().zip(&w) {
            assert!((s - (init.scale * w).min(255.0)).abs() < 1e-9);
        }
        assert!(init.evaluations < 60, "{}", init.evaluations);
        assert!(init
            .control_points
            .rgb
            .iter()
            .flatten()
            .all(|c| (0.3..=0.7).contains(c)));
    }

    #[test]
    fn unreachable_rho_returns_the_most_opaque_tf() {
        // Rays too short: even σ = 255 leaves T ≈ exp(−20·0.01·…) ≫ ρ.
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let x = even(8);
        let a = rays(&mut rng, 50, 8, 0.001);
        let init = initialize(&x, &[5u64; 256], 0.05, &mut rng, model(&a)).unwrap();
        assert!(!init.reached);
        assert!(init.control_points.sigma.iter().all(|&s| s == 255.0));
        assert_eq!(init.evaluations, 1);
    }

    #[test]
    fn non_finite_transmittance_is_an_error() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let e = initialize(&even(4), &[1u64; 256], 0.05, &mut rng, |_| f64::NAN).unwrap_err();
        assert!(e.to_string().contains("mean transmittance"), "{e}");
        let e = initialize(&even(4), &[1u64; 256], 0.05, &mut rng, |_| 1.5).unwrap_err();
        assert!(e.to_string().contains("1.5"), "{e}");
        assert!(initialize(&even(4), &[1u64; 256], 0.0, &mut rng, |_| 0.5).is_err());
    }
}
