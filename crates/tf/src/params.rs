//! The paper's TF parameterization (Appendix A) and its hand-written backward pass.
//!
//! Unconstrained parameters φ = (spacings s, densities p, colours q) map to control points:
//!   d_i = softplus(s_i) + FLOOR          (i < K − 1; spacing between points i and i + 1)
//!   c_0 = 0, c_k = Σ_{i<k} d_i, D = c_{K−1},  x_k = c_k / D      (first 0, last 1)
//!   σ_k = 255 · (tanh(p_k) + 1) / 2,  rgb_k = (tanh(q_k) + 1) / 2

use super::{ControlPoints, ControlPointsGrad, SIGMA_MAX};

/// Added to every softplus spacing. Why: softplus(s) → 0 as s → −∞, so without a floor two
/// points can coincide to rounding, making x_{k+1} − x_k exactly 0; the LUT is then a jump and
/// ∂w/∂x = −w/(x1 − x0) is 0/0. The parameters are scaled so that an even spacing has
/// softplus = 1 (see [`TfParams::from_control_points`]), so this floor is 1e-4 of a typical
/// spacing: small enough never to matter for a real TF (a LUT of 256 entries resolves 4e-3),
/// large enough to keep every segment strictly positive in f64.
const SPACING_FLOOR: f64 = 1e-4;

/// Largest |parameter| the inverse maps produce: tanh(±7.25) = ±(1 − 1e-6), so σ = 0 and
/// σ = 255 come back within 2.6e-4 and colour 0/1 within 5e-7, while the tanh derivative at
/// the clamp (≈ 2e-6) still lets the optimizer move the value.
const ATANH_CLAMP: f64 = 1.0 - 1e-6;

// Shaped like `ControlPoints` (a vector per quantity: positions, densities, colours): these
// are their unconstrained counterparts, not the same values.
/// Unconstrained TF parameters (f64). K control points.
#[derive(Clone, Debug, PartialEq)]
pub struct TfParams {
    /// K − 1 unconstrained spacings.
    pub spacing: Vec<f64>,
    /// K unconstrained densities.
    pub density: Vec<f64>,
    /// K unconstrained colours.
    pub colour: Vec<[f64; 3]>,
}

/// Gradient of a loss with respect to [`TfParams`]; same shapes.
#[derive(Clone, Debug, PartialEq)]
pub struct TfParamsGrad {
    /// ∂L/∂spacing (K − 1).
    pub spacing: Vec<f64>,
    /// ∂L/∂density (K).
    pub density: Vec<f64>,
    /// ∂L/∂colour (K).
    pub colour: Vec<[f64; 3]>,
}

/// softplus(s) = ln(1 + eˢ), without overflow for large s or loss of precision for small.
fn softplus(s: f64) -> f64 {
    s.max(0.0) + (-s.abs()).exp().ln_1p()
}

/// d softplus / ds = logistic(s), in the form that never overflows.
fn sigmoid(s: f64) -> f64 {
    if s >= 0.0 {
        1.0 / (1.0 + (-s).exp())
    } else {
        let e = s.exp();
        e / (1.0 + e)
    }
}

/// Inverse of softplus for y > 0: ln(eʸ − 1).
fn softplus_inv(y: f64) -> f64 {
    if y > 30.0 {
        y // e^{-30} ≈ 1e-13: ln(eʸ − 1) = y + ln(1 − e^{−y}) = y to f64 precision
    } else {
        y.exp_m1().ln()
    }
}

fn atanh_clamped(y: f64) -> f64 {
    y.clamp(-ATANH_CLAMP, ATANH_CLAMP).atanh()
}

impl TfParams {
    /// Number of control points K.
    pub fn len(&self) -> usize {
        self.density.len()
    }

    /// No control points.
    pub fn is_empty(&self) -> bool {
        self.density.is_empty()
    }

    /// The parameters whose [`TfParams::control_points`] reproduce `cp` (used to initialize).
    ///
    /// Spacings are scaled so the mean softplus spacing is 1, which keeps `SPACING_FLOOR` a
    /// fixed fraction of a typical spacing. Spacings below the floor come back at the floor;
    /// σ and colours at the ends of their ranges come back within the `ATANH_CLAMP` margin.
    /// `cp` is expected to pass [`ControlPoints::validate`].
    pub fn from_control_points(cp: &ControlPoints) -> TfParams {
        let k = cp.len();
        let segments = k.saturating_sub(1).max(1) as f64;
        let spacing =
            cp.x.windows(2)
                .map(|w| {
                    let target = (w[1] - w[0]) * segments - SPACING_FLOOR;
                    // Keep softplus' argument positive: a floor-sized target maps to a spacing
                    // of e^-27 (≈ 2e-12) above the floor.
                    softplus_inv(target.max(2e-12))
                })
                .collect();
        let density = cp
            .sigma
            .iter()
            .map(|&s| atanh_clamped(2.0 * s / SIGMA_MAX - 1.0))
            .collect();
        let colour = cp
            .rgb
            .iter()
            .map(|c| c.map(|v| atanh_clamped(2.0 * v - 1.0)))
            .collect();
        TfParams {
            spacing,
            density,
            colour,
        }
    }

    /// The control points these parameters describe (always valid: x ascending from 0 to 1,
    /// strictly, σ ∈ [0, 255], colours ∈ [0, 1]).
    pub fn control_points(&self) -> ControlPoints {
        let mut x = Vec::with_capacity(self.len());
        let mut c = 0.0;
        x.push(0.0);
        for &s in &self.spacing {
            c += softplus(s) + SPACING_FLOOR;
            x.push(c);
        }
        let total = c;
        for v in &mut x {
            *v /= total;
        }
        // Division can leave the last at 1 − ε; the convention is exactly 1.
        if let Some(last) = x.last_mut() {
            *last = 1.0;
        }
        ControlPoints {
            x,
            sigma: self
                .density
                .iter()
                .map(|&p| SIGMA_MAX * 0.5 * (p.tanh() + 1.0))
                .collect(),
            rgb: self
                .colour
                .iter()
                .map(|q| q.map(|v| 0.5 * (v.tanh() + 1.0)))
                .collect(),
        }
    }

    /// Backward of [`TfParams::control_points`].
    ///
    /// With x_k = c_k / D: ∂x_k/∂d_i = \[i < k\]/D − x_k/D, so
    /// ∂L/∂d_i = (Σ_{k>i} g_k − Σ_k g_k x_k) / D (a suffix sum: O(K)), then ∂d_i/∂s_i =
    /// logistic(s_i). The ends x_0 = 0 and x_{K−1} = 1 are constants, so their gradients drop
    /// out (x_0 contributes g_0·0; x_{K−1}'s \[i < K−1\] − 1 cancel). ∂σ/∂p = 127.5 (1 − tanh²p),
    /// ∂rgb/∂q = (1 − tanh²q)/2.
    pub fn backward(&self, g: &ControlPointsGrad) -> TfParamsGrad {
        let k = self.len();
        let cp_x = self.control_points().x;
        let mut total = 0.0;
        for &s in &self.spacing {
            total += softplus(s) + SPACING_FLOOR;
        }
        let weighted: f64 = (0..k).map(|i| g.x[i] * cp_x[i]).sum();
        let mut spacing = vec![0.0; self.spacing.len()];
        let mut suffix = 0.0;
        for i in (0..self.spacing.len()).rev() {
            suffix += g.x[i + 1];
            spacing[i] = (suffix - weighted) / total * sigmoid(self.spacing[i]);
        }
        let density = self
            .density
            .iter()
            .zip(&g.sigma)
            .map(|(&p, &gs)| {
                let t = p.tanh();
                gs * 0.5 * SIGMA_MAX * (1.0 - t * t)
            })
            .collect();
        let colour = self
            .colour
            .iter()
            .zip(&g.rgb)
            .map(|(q, gc)| {
                std::array::from_fn(|c| {
                    let t = q[c].tanh();
                    gc[c] * 0.5 * (1.0 - t * t)
                })
            })
            .collect();
        TfParamsGrad {
            spacing,
            density,
            colour,
        }
    }

    /// All parameters in one vector (spacings, densities, then r, g, b per point), for
    /// optimizers that work on flat vectors.
    pub fn to_flat(&self) -> Vec<f64> {
        let mut v = self.spacing.clone();
        v.extend(&self.density);
        v.extend(self.colour.iter().flatten());
        v
    }

    /// Inverse of [`TfParams::to_flat`] for the same K; `None` if the length is wrong.
    pub fn from_flat(k: usize, v: &[f64]) -> Option<TfParams> {
        if k < 2 || v.len() != (k - 1) + k + 3 * k {
            return None;
        }
        let (spacing, rest) = v.split_at(k - 1);
        let (density, colour) = rest.split_at(k);
        Some(TfParams {
            spacing: spacing.to_vec(),
            density: density.to_vec(),
            colour: colour.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        })
    }
}

/// Control points whose positions are fixed: (point index, x), ascending in both, the first
/// `(0, 0.0)` and the last `(K − 1, 1.0)`. Between two anchors the spacings place the points
/// inside that interval only, so a change there moves no point outside it (what keeps a
/// locked range of a TF where it is). The ends alone give [`TfParams::control_points`].
pub type Anchors = [(usize, f64)];

/// Is `anchors` well formed for `k` points?
fn anchors_ok(anchors: &Anchors, k: usize) -> bool {
    anchors.len() >= 2
        && anchors[0] == (0, 0.0)
        && anchors[anchors.len() - 1] == (k - 1, 1.0)
        && anchors
            .windows(2)
            .all(|w| w[1].0 > w[0].0 && w[1].1 >= w[0].1)
}

impl TfParams {
    /// [`TfParams::control_points`] with positions fixed at `anchors`: between anchors
    /// (i0, x0) and (i1, x1), x_k = x0 + (x1 − x0) · c_k / D with c_k the sum of the
    /// interval's spacings before k and D all of them. Panics on malformed anchors (the
    /// caller builds them; see [`Anchors`]).
    pub fn anchored_points(&self, anchors: &Anchors) -> ControlPoints {
        let k = self.len();
        assert!(
            anchors_ok(anchors, k),
            "malformed anchors {anchors:?} for {k} points"
        );
        let mut cp = self.control_points();
        for w in anchors.windows(2) {
            let ((i0, x0), (i1, x1)) = (w[0], w[1]);
            let mut c = 0.0;
            for i in i0..i1 {
                c += softplus(self.spacing[i]) + SPACING_FLOOR;
                cp.x[i + 1] = c;
            }
            for v in &mut cp.x[i0 + 1..i1] {
                *v = x0 + (x1 - x0) * (*v / c);
            }
            cp.x[i0] = x0;
            cp.x[i1] = x1;
        }
        cp
    }

    /// Backward of [`TfParams::anchored_points`]. Inside an interval of width W and spacing
    /// sum D, ∂x_k/∂d_i = W (\[i < k\] − (x_k − x0)/W) / D for its inner points k; anchors are
    /// constants. Densities and colours as in [`TfParams::backward`].
    pub fn anchored_backward(&self, anchors: &Anchors, g: &ControlPointsGrad) -> TfParamsGrad {
        let k = self.len();
        assert!(
            anchors_ok(anchors, k),
            "malformed anchors {anchors:?} for {k} points"
        );
        let x = self.anchored_points(anchors).x;
        let mut out = self.backward(g);
        for w in anchors.windows(2) {
            let ((i0, x0), (i1, x1)) = (w[0], w[1]);
            let width = x1 - x0;
            let total: f64 = (i0..i1)
                .map(|i| softplus(self.spacing[i]) + SPACING_FLOOR)
                .sum();
            let local = |j: usize| {
                if width > 0.0 {
                    (x[j] - x0) / width
                } else {
                    0.0
                }
            };
            let weighted: f64 = (i0 + 1..i1).map(|j| g.x[j] * local(j)).sum();
            let mut suffix = 0.0;
            for i in (i0..i1).rev() {
                if i + 1 < i1 {
                    suffix += g.x[i + 1];
                }
                out.spacing[i] = width * (suffix - weighted) / total * sigmoid(self.spacing[i]);
            }
        }
        out
    }

    /// Parameters whose [`TfParams::anchored_points`] reproduce `cp` (whose points at the
    /// anchors' indices must sit at the anchors' positions). Spacings are scaled per
    /// interval so their mean softplus is 1, as [`TfParams::from_control_points`] does over
    /// the whole range.
    pub fn from_anchored_points(cp: &ControlPoints, anchors: &Anchors) -> TfParams {
        let k = cp.len();
        assert!(
            anchors_ok(anchors, k),
            "malformed anchors {anchors:?} for {k} points"
        );
        let mut p = TfParams::from_control_points(cp);
        for w in anchors.windows(2) {
            let ((i0, x0), (i1, x1)) = (w[0], w[1]);
            let segments = (i1 - i0) as f64;
            let width = x1 - x0;
            for i in i0..i1 {
                let d = if width > 0.0 {
                    (cp.x[i + 1] - cp.x[i]) / width
                } else {
                    0.0
                };
                let target = d * segments - SPACING_FLOOR;
                p.spacing[i] = softplus_inv(target.max(2e-12));
            }
        }
        p
    }
}

impl TfParamsGrad {
    /// Same layout as [`TfParams::to_flat`].
    pub fn to_flat(&self) -> Vec<f64> {
        let mut v = self.spacing.clone();
        v.extend(&self.density);
        v.extend(self.colour.iter().flatten());
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_params(rng: &mut impl Rng, k: usize) -> TfParams {
        TfParams {
            spacing: (0..k - 1).map(|_| rng.random_range(-3.0..3.0)).collect(),
            density: (0..k).map(|_| rng.random_range(-2.0..2.0)).collect(),
            colour: (0..k)
                .map(|_| std::array::from_fn(|_| rng.random_range(-2.0..2.0)))
                .collect(),
        }
    }

    /// A smooth scalar function of the control points with random weights, so that every
    /// component of the backward is exercised.
    fn loss(cp: &ControlPoints, w: &ControlPointsGrad) -> f64 {
        let mut s = 0.0;
        for i in 0..cp.len() {
            s += w.x[i] * cp.x[i] + w.sigma[i] * cp.sigma[i];
            s += (0..3).map(|c| w.rgb[i][c] * cp.rgb[i][c]).sum::<f64>();
        }
        s
    }

    /// Random weights of `loss`, one per position, density and colour channel.
    fn random_weights(rng: &mut impl Rng, k: usize) -> ControlPointsGrad {
        ControlPointsGrad {
            x: (0..k).map(|_| rng.random_range(-1.0..1.0)).collect(),
            sigma: (0..k).map(|_| rng.random_range(-1.0..1.0)).collect(),
            rgb: (0..k)
                .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
                .collect(),
        }
    }

    /// `analytic` against central differences of `f` (the loss of flat parameters) at `flat`.
    ///
    /// The maps are smooth (softplus, tanh, a quotient with D ≥ FLOOR·(K−1) > 0); central
    /// differences with h = 1e-5 have truncation error h²/6·|f'''| ≲ 1e-10·255 and rounding
    /// ≈ 1e-16·|f|/h ≲ 1e-8 for |f| ≲ 255·K: tolerance 1e-6 absolute plus 1e-6 relative covers
    /// both with margin.
    fn assert_central_differences(flat: &[f64], analytic: &[f64], f: impl Fn(&[f64]) -> f64) {
        let h = 1e-5;
        for (i, gi) in analytic.iter().enumerate() {
            let (mut a, mut b) = (flat.to_vec(), flat.to_vec());
            a[i] += h;
            b[i] -= h;
            let fd = (f(&a) - f(&b)) / (2.0 * h);
            assert!(
                (fd - gi).abs() < 1e-6 + 1e-6 * fd.abs(),
                "{} parameters, parameter {i}: fd {fd} analytic {gi}",
                flat.len()
            );
        }
    }

    #[test]
    fn backward_matches_central_differences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for k in [2, 3, 8, 20] {
            let p = random_params(&mut rng, k);
            let w = random_weights(&mut rng, k);
            assert_central_differences(&p.to_flat(), &p.backward(&w).to_flat(), |v| {
                loss(&TfParams::from_flat(k, v).unwrap().control_points(), &w)
            });
        }
    }

    #[test]
    fn control_points_round_trip_through_params() {
        let cp = ControlPoints {
            x: vec![0.0, 0.1, 0.35, 0.9, 1.0],
            sigma: vec![0.0, 12.5, 255.0, 100.0, 3.0],
            rgb: vec![
                [0.3, 0.7, 0.5],
                [0.0, 1.0, 0.2],
                [0.5; 3],
                [0.9, 0.1, 0.4],
                [1.0; 3],
            ],
        };
        let back = TfParams::from_control_points(&cp).control_points();
        back.validate().unwrap();
        for i in 0..cp.len() {
            assert!((back.x[i] - cp.x[i]).abs() < 1e-9, "x{i}");
            // σ within the clamp margin 255·1e-6/2 ... (see ATANH_CLAMP)
            assert!((back.sigma[i] - cp.sigma[i]).abs() < 3e-4, "σ{i}");
            for c in 0..3 {
                assert!((back.rgb[i][c] - cp.rgb[i][c]).abs() < 1e-6);
            }
        }
        let even = TfParams::from_control_points(
            &ControlPoints::evenly_spaced(vec![10.0; 5], vec![[0.5; 3]; 5]).unwrap(),
        );
        assert!(even
            .spacing
            .iter()
            .all(|&s| (softplus(s) + SPACING_FLOOR - 1.0).abs() < 1e-12));
    }

    #[test]
    fn extreme_parameters_stay_finite_and_ordered() {
        let k = 6;
        let p = TfParams {
            spacing: vec![-800.0, 800.0, -1e300, 0.0, f64::MAX],
            density: vec![1e308, -1e308, 0.0, 40.0, -40.0, 1.0],
            colour: vec![[1e300, -1e300, 0.0]; k],
        };
        let cp = p.control_points();
        cp.validate().unwrap();
        assert!(cp.x.windows(2).all(|w| w[1] > w[0] || w[1] == 1.0));
        let g = p.backward(&ControlPointsGrad {
            x: vec![1.0; k],
            sigma: vec![1.0; k],
            rgb: vec![[1.0; 3]; k],
        });
        assert!(g.to_flat().iter().all(|v| v.is_finite()), "{g:?}");
    }
    #[test]
    fn anchored_backward_matches_central_differences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let k = 9;
        let anchors = [(0, 0.0), (3, 0.25), (4, 0.25), (6, 0.7), (8, 1.0)];
        let p = random_params(&mut rng, k);
        let w = random_weights(&mut rng, k);
        let cp = p.anchored_points(&anchors);
        cp.validate().unwrap();
        for &(i, x) in &anchors {
            assert_eq!(cp.x[i], x);
        }
        let g = p.anchored_backward(&anchors, &w).to_flat();
        assert_central_differences(&p.to_flat(), &g, |v| {
            let q = TfParams::from_flat(k, v).unwrap();
            loss(&q.anchored_points(&anchors), &w)
        });
        // A spacing between two adjacent anchors moves nothing.
        assert_eq!(g[3], 0.0);
    }

    #[test]
    fn anchored_points_round_trip_and_ends_alone_are_the_plain_map() {
        let cp = ControlPoints {
            x: vec![0.0, 0.1, 0.3, 0.3, 0.65, 1.0],
            sigma: vec![0.0, 12.5, 255.0, 100.0, 3.0, 40.0],
            rgb: vec![[0.3, 0.7, 0.5]; 6],
        };
        let anchors = [(0, 0.0), (2, 0.3), (3, 0.3), (5, 1.0)];
        let back = TfParams::from_anchored_points(&cp, &anchors).anchored_points(&anchors);
        for i in 0..cp.len() {
            assert!(
                (back.x[i] - cp.x[i]).abs() < 1e-9,
                "x{i}: {} {}",
                back.x[i],
                cp.x[i]
            );
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let p = random_params(&mut rng, 7);
        let (a, b) = (p.control_points(), p.anchored_points(&[(0, 0.0), (6, 1.0)]));
        for i in 0..7 {
            assert!((a.x[i] - b.x[i]).abs() < 1e-15);
        }
    }
}
