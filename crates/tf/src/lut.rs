//! The dense lookup table the renderer samples, and its backward pass to the control points.

use super::{ControlPoints, Lut, LutGrad};

/// Gradient of a loss with respect to every control point: position, density and colour.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlPointsGrad {
    /// ∂L/∂x per point.
    pub x: Vec<f64>,
    /// ∂L/∂σ per point.
    pub sigma: Vec<f64>,
    /// ∂L/∂rgb per point.
    pub rgb: Vec<[f64; 3]>,
}

impl ControlPointsGrad {
    /// A zero gradient for `k` points.
    pub(crate) fn zeros(k: usize) -> ControlPointsGrad {
        ControlPointsGrad {
            x: vec![0.0; k],
            sigma: vec![0.0; k],
            rgb: vec![[0.0; 3]; k],
        }
    }
}

impl Lut {
    /// The piecewise-linear TF the renderer actually samples: one control point per entry.
    /// Exporting this (then simplifying) reproduces what was rendered even when control
    /// points collapse within one LUT cell, where `ControlPoints` and their LUT differ.
    pub fn to_control_points(&self) -> ControlPoints {
        let n = self.entries.len().max(2);
        let at = |j: usize| self.entries[j.min(self.entries.len() - 1)];
        ControlPoints {
            x: (0..n).map(|j| j as f64 / (n - 1) as f64).collect(),
            sigma: (0..n).map(|j| at(j)[0] as f64).collect(),
            rgb: (0..n)
                .map(|j| {
                    let e = at(j);
                    [e[1] as f64, e[2] as f64, e[3] as f64]
                })
                .collect(),
        }
    }
}

/// Where LUT entry `t` falls among the control points: `Left`/`Right` of all of them
/// (constant extension), or inside the segment from point `k - 1` to `k` at weight `w`.
enum Span {
    Clamped(usize),
    Inside { k: usize, w: f64 },
}

/// Walk the LUT entries and control points together: O(n + K) instead of a binary search per
/// entry. The segment rule is exactly `ControlPoints::eval`'s (`partition_point(x <= t)`), so
/// `to_lut` equals sampling `eval` bit for bit (a test checks it).
fn for_each_span(cp: &ControlPoints, n: usize, mut f: impl FnMut(usize, f64, Span)) {
    let kk = cp.len();
    let mut k = 0;
    for j in 0..n {
        let t = j as f64 / (n - 1) as f64;
        while k < kk && cp.x[k] <= t {
            k += 1;
        }
        let span = if k == 0 {
            Span::Clamped(0)
        } else if k >= kk {
            Span::Clamped(kk - 1)
        } else {
            let (x0, x1) = (cp.x[k - 1], cp.x[k]);
            let w = if x1 > x0 { (t - x0) / (x1 - x0) } else { 1.0 };
            Span::Inside { k, w }
        };
        f(j, t, span);
    }
}

impl ControlPoints {
    /// Sample the TF into an `n`-entry lookup table (`n` is raised to 2 at least).
    pub fn to_lut(&self, n: usize) -> Lut {
        let n = n.max(2);
        let mut entries = Vec::with_capacity(n);
        for_each_span(self, n, |_, _, span| {
            let v = match span {
                Span::Clamped(i) => self.at(i),
                Span::Inside { k, w } => {
                    let (a, b) = (self.at(k - 1), self.at(k));
                    std::array::from_fn(|c| a[c] + w * (b[c] - a[c]))
                }
            };
            entries.push(v.map(|v| v as f32));
        });
        Lut { entries }
    }

    /// Backward of [`ControlPoints::to_lut`]: from ∂loss/∂(LUT entry) to ∂loss/∂(control point).
    ///
    /// Entry j inside segment (x0, x1) is v = a + w (b − a) with w = (t_j − x0)/(x1 − x0), so
    /// ∂v/∂a = 1 − w, ∂v/∂b = w, ∂w/∂x0 = −(1 − w)/(x1 − x0), ∂w/∂x1 = −w/(x1 − x0).
    /// Entries on the constant extensions and exactly on a point move with the point's value
    /// only (the position derivative there is one-sided; we take the side the forward used).
    /// A collapsed segment (x1 = x0) holds no entry strictly inside, so no division by zero.
    ///
    /// `grad.entries.len()` must be `n` (the same `n` given to `to_lut`).
    pub fn lut_backward(&self, n: usize, grad: &LutGrad) -> ControlPointsGrad {
        let n = n.max(2);
        assert_eq!(
            grad.entries.len(),
            n,
            "LutGrad has the wrong number of entries"
        );
        let mut out = ControlPointsGrad::zeros(self.len());
        for_each_span(self, n, |j, _, span| {
            let g = grad.entries[j];
            match span {
                Span::Clamped(i) => out.add_value(i, g, 1.0),
                Span::Inside { k, w } => {
                    out.add_value(k - 1, g, 1.0 - w);
                    out.add_value(k, g, w);
                    let (x0, x1) = (self.x[k - 1], self.x[k]);
                    if x1 > x0 {
                        let (a, b) = (self.at(k - 1), self.at(k));
                        let dv_dw: f64 = (0..4).map(|c| g[c] * (b[c] - a[c])).sum();
                        let inv = 1.0 / (x1 - x0);
                        out.x[k - 1] -= dv_dw * (1.0 - w) * inv;
                        out.x[k] -= dv_dw * w * inv;
                    }
                }
            }
        });
        out
    }
}

impl ControlPointsGrad {
    fn add_value(&mut self, i: usize, g: [f64; 4], weight: f64) {
        self.sigma[i] += weight * g[0];
        for c in 0..3 {
            self.rgb[i][c] += weight * g[c + 1];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_cp(rng: &mut impl Rng, k: usize) -> ControlPoints {
        let mut x: Vec<f64> = (0..k).map(|_| rng.random::<f64>()).collect();
        x.sort_by(f64::total_cmp);
        x[0] = 0.0;
        x[k - 1] = 1.0;
        ControlPoints {
            x,
            sigma: (0..k).map(|_| rng.random_range(0.0..255.0)).collect(),
            rgb: (0..k)
                .map(|_| std::array::from_fn(|_| rng.random()))
                .collect(),
        }
    }

    #[test]
    fn lut_as_control_points_resamples_to_the_same_lut() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut cp = random_cp(&mut rng, 12);
        // Two points inside one cell of a 64-entry LUT: their LUT is not the exact TF.
        cp.x[5] = cp.x[4] + 1e-4;
        let lut = cp.to_lut(64);
        let back = lut.to_control_points().to_lut(64);
        for (a, b) in lut.entries.iter().zip(&back.entries) {
            for c in 0..4 {
                assert!(
                    (a[c] - b[c]).abs() <= 1e-6 * a[c].abs().max(1.0),
                    "{a:?} {b:?}"
                );
            }
        }
    }

    #[test]
    fn sweep_equals_eval_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        for k in [2, 3, 7, 40] {
            let mut cp = random_cp(&mut rng, k);
            if k > 3 {
                // A collapsed pair and a point exactly on a LUT entry: the edge cases.
                cp.x[2] = cp.x[1];
                cp.x[3] = 0.5;
                cp.x.sort_by(f64::total_cmp);
            }
            for n in [2, 3, 256, 1000] {
                let lut = cp.to_lut(n);
                for (j, e) in lut.entries.iter().enumerate() {
                    let want = cp.eval(j as f64 / (n - 1) as f64).map(|v| v as f32);
                    assert_eq!(*e, want, "k={k} n={n} j={j}");
                }
            }
        }
    }

    /// Loss = Σ_j Σ_c w_jc · LUT_jc with fixed random weights; its gradient wrt the LUT is w.
    fn loss(cp: &ControlPoints, n: usize, w: &LutGrad) -> f64 {
        let mut s = 0.0;
        for_each_span(cp, n, |j, t, _| {
            let v = cp.eval(t);
            s += (0..4).map(|c| w.entries[j][c] * v[c]).sum::<f64>();
        });
        s
    }

    #[test]
    fn lut_backward_matches_central_differences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let n = 64;
        for k in [2, 5, 9] {
            let cp = random_cp(&mut rng, k);
            let w = LutGrad {
                entries: (0..n)
                    .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
                    .collect(),
            };
            let g = cp.lut_backward(n, &w);
            // Values: the loss is linear in σ and colours, so central differences are exact
            // up to rounding (≈1e-13 relative for h = 1e-3 and sums of ~64·255).
            // Positions: the loss is piecewise smooth in x_k with kinks where a point crosses
            // a LUT entry (spacing 1/63 ≈ 0.016); h = 1e-7 keeps the stencil inside one piece
            // unless a point sits within 1e-7 of an entry (probability ~1e-5 per point), and
            // the truncation error O(h²·|f'''|) is far below 1e-5. Rounding: ~1e-13·|f|/h ≈ 1e-4
            // absolute for |f| ~ 1e4, so the tolerance is 1e-3 absolute + 1e-6 relative.
            for i in 0..k {
                let fd = |f: &dyn Fn(&mut ControlPoints, f64), h: f64| {
                    let mut p = cp.clone();
                    f(&mut p, h);
                    let mut m = cp.clone();
                    f(&mut m, -h);
                    (loss(&p, n, &w) - loss(&m, n, &w)) / (2.0 * h)
                };
                let ds = fd(&|c, h| c.sigma[i] += h, 1e-3);
                assert!((ds - g.sigma[i]).abs() < 1e-6 * (1.0 + ds.abs()), "σ{i}");
                for ch in 0..3 {
                    let dc = fd(&|c, h| c.rgb[i][ch] += h, 1e-3);
                    assert!(
                        (dc - g.rgb[i][ch]).abs() < 1e-6 * (1.0 + dc.abs()),
                        "rgb{i}"
                    );
                }
                if i > 0 && i < k - 1 {
                    let dx = fd(&|c, h| c.x[i] += h, 1e-7);
                    assert!(
                        (dx - g.x[i]).abs() < 1e-3 + 1e-6 * dx.abs(),
                        "x{i}: fd {dx} analytic {}",
                        g.x[i]
                    );
                }
            }
        }
    }

    #[test]
    fn collapsed_points_give_finite_gradients() {
        let cp = ControlPoints {
            x: vec![0.0, 0.5, 0.5, 0.5, 1.0],
            sigma: vec![0.0, 255.0, 0.0, 255.0, 10.0],
            rgb: vec![[0.5; 3]; 5],
        };
        let n = 256;
        let g = cp.lut_backward(
            n,
            &LutGrad {
                entries: vec![[1.0; 4]; n],
            },
        );
        assert!(g.x.iter().chain(&g.sigma).all(|v| v.is_finite()));
        // Every entry's weight lands somewhere: Σ ∂/∂σ_k = n when ∂loss/∂σ_j = 1.
        assert!((g.sigma.iter().sum::<f64>() - n as f64).abs() < 1e-9);
    }
}
