//! Starting from a given TF and locking ranges of it: the parameterization a refine runs on.
//!
//! A run may start from any TF (`--init`) instead of the paper's initialization, and may
//! lock value ranges (`--lock MIN,MAX`) whose TF must not change. Both reduce to one
//! parameterization, [`StartTf`]: the paper's (softplus spacings, tanh densities and
//! colours), with
//! - **anchors**: points whose positions are fixed. The bounds of every locked range are
//!   control points and anchors, so the spacings of the free parts move points only inside
//!   their own part (`TfParams::anchored_points`); a locked range never slides.
//! - **a gradient mask**: the densities and colours of the points in a locked range, and the
//!   spacings between them, get a zero gradient. The loss still sees the locked part (it is
//!   rendered with the rest); only its parameters do not move. With momentum SGD a parameter
//!   whose gradient is always zero keeps its value exactly.
//! - **a density scale**: a start denser than the paper's σ ≤ 255 (a preset opaque at a short
//!   unit distance) scales every density by `sigma_max / 255`, so the start is represented as
//!   it is and the optimizer keeps the headroom.

use super::{BoxError, Parameterization, PointGrad};
use crate::tf::{ControlPoints, LutGrad, TfParams};

/// A locked range in normalized values, `lo < hi`, inside [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lock {
    /// Lower bound.
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
}

/// The paper's parameterization with fixed anchors and frozen points (see the module docs).
#[derive(Clone, Debug)]
pub struct StartTf {
    k: usize,
    lut_size: usize,
    /// σ = scale · the paper's σ ∈ [0, 255].
    scale: f64,
    anchors: Vec<(usize, f64)>,
    /// Per point: σ and colour frozen.
    frozen_point: Vec<bool>,
    /// Per segment (K − 1): spacing frozen.
    frozen_segment: Vec<bool>,
}

impl StartTf {
    /// Control points this parameterization describes.
    pub fn len(&self) -> usize {
        self.k
    }

    /// Never: at least two points.
    pub fn is_empty(&self) -> bool {
        self.k == 0
    }

    /// Whether point `i`'s density and colour are locked.
    pub fn is_frozen(&self, i: usize) -> bool {
        self.frozen_point[i]
    }

    fn params(&self, flat: &[f64]) -> Result<TfParams, BoxError> {
        super::adapters::tf_params(self.k, flat)
    }
}

impl Parameterization for StartTf {
    fn control_points(&self, flat: &[f64]) -> Result<ControlPoints, BoxError> {
        let mut cp = self.params(flat)?.anchored_points(&self.anchors);
        cp.sigma.iter_mut().for_each(|s| *s *= self.scale);
        Ok(cp)
    }

    fn lut_size(&self) -> usize {
        self.lut_size
    }

    fn params_for(&self, cp: &ControlPoints) -> Result<Vec<f64>, BoxError> {
        if cp.len() != self.k {
            return Err(format!("{} control points given for a TF of {}", cp.len(), self.k).into());
        }
        let mut paper = cp.clone();
        paper.sigma.iter_mut().for_each(|s| *s /= self.scale);
        Ok(TfParams::from_anchored_points(&paper, &self.anchors).to_flat())
    }

    fn backward(
        &self,
        flat: &[f64],
        lut: &LutGrad,
        direct: &PointGrad,
    ) -> Result<Vec<f64>, BoxError> {
        let p = self.params(flat)?;
        let mut cp = p.anchored_points(&self.anchors);
        cp.sigma.iter_mut().for_each(|s| *s *= self.scale);
        let mut g = super::adapters::point_gradient(&cp, self.lut_size, lut, direct);
        // d/dσ_paper = scale · d/dσ.
        g.sigma.iter_mut().for_each(|s| *s *= self.scale);
        let mut grad = p.anchored_backward(&self.anchors, &g);
        for (i, s) in grad.spacing.iter_mut().enumerate() {
            if self.frozen_segment[i] {
                *s = 0.0;
            }
        }
        for i in 0..self.k {
            if self.frozen_point[i] {
                grad.density[i] = 0.0;
                grad.colour[i] = [0.0; 3];
            }
        }
        Ok(grad.to_flat())
    }
}

/// Why a start or a lock cannot be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum StartError {
    /// A lock outside [0, 1], reversed, empty or not finite (normalized bounds given).
    #[error("locked range {lo}..{hi} is not an increasing range inside the data range")]
    BadLock {
        /// Lower bound.
        lo: f64,
        /// Upper bound.
        hi: f64,
    },
    /// Two locks overlap (sorted; normalized bounds).
    #[error("locked ranges overlap")]
    Overlap,
}

/// Check `locks` and sort them. Touching locks (one's upper bound the next's lower bound)
/// are allowed; overlapping ones are not.
pub fn sorted_locks(locks: &[Lock]) -> Result<Vec<Lock>, StartError> {
    for l in locks {
        if !(l.lo.is_finite() && l.hi.is_finite() && 0.0 <= l.lo && l.lo < l.hi && l.hi <= 1.0) {
            return Err(StartError::BadLock { lo: l.lo, hi: l.hi });
        }
    }
    let mut sorted = locks.to_vec();
    sorted.sort_by(|a, b| a.lo.total_cmp(&b.lo));
    if sorted.windows(2).any(|w| w[1].lo < w[0].hi) {
        return Err(StartError::Overlap);
    }
    Ok(sorted)
}

/// The point at normalized `t` on `cp`'s piecewise-linear curves, inserted unless a point is
/// there already; returns the index of the first point at `t` (`last`: the last one, for
/// an upper bound, so a jump at a bound stays with the range it belongs to).
fn insert_at(cp: &mut ControlPoints, t: f64, last: bool) -> usize {
    let hits: Vec<usize> = (0..cp.len()).filter(|&i| cp.x[i] == t).collect();
    if let Some(&i) = if last { hits.last() } else { hits.first() } {
        return i;
    }
    let v = cp.eval(t);
    let i = cp.x.partition_point(|&x| x < t);
    cp.x.insert(i, t);
    cp.sigma.insert(i, v[0]);
    cp.rgb.insert(i, [v[1], v[2], v[3]]);
    i
}

fn locked(locks: &[Lock], x: f64) -> bool {
    locks.iter().any(|l| l.lo <= x && x <= l.hi)
}

/// The TF a run starts from and its parameterization: `cp` with a point at every lock bound,
/// and (when it has fewer than `min_points`) points added at the middle of the widest free
/// segments, which changes no value (the curves are linear there). `lut_size`: entries the
/// renderer samples; `sigma_max`: the densest σ the run represents (at least 255).
pub fn prepare(
    cp: &ControlPoints,
    locks: &[Lock],
    min_points: usize,
    lut_size: usize,
    sigma_max: f64,
) -> Result<(ControlPoints, StartTf), StartError> {
    let locks = sorted_locks(locks)?;
    let mut cp = cp.clone();
    for l in &locks {
        insert_at(&mut cp, l.lo, false);
        insert_at(&mut cp, l.hi, true);
    }
    while cp.len() < min_points {
        let widest = (0..cp.len() - 1)
            .filter(|&i| !locked(&locks, 0.5 * (cp.x[i] + cp.x[i + 1])))
            .max_by(|&a, &b| (cp.x[a + 1] - cp.x[a]).total_cmp(&(cp.x[b + 1] - cp.x[b])));
        let Some(i) = widest.filter(|&i| cp.x[i + 1] > cp.x[i]) else {
            break;
        };
        let mid = 0.5 * (cp.x[i] + cp.x[i + 1]);
        insert_at(&mut cp, mid, false);
    }
    let k = cp.len();
    let mut anchors = vec![(0, 0.0)];
    for l in &locks {
        for (t, last) in [(l.lo, false), (l.hi, true)] {
            let i = insert_at(&mut cp, t, last);
            if anchors.last().is_some_and(|a| a.0 < i) && i < k - 1 {
                anchors.push((i, t));
            }
        }
    }
    anchors.push((k - 1, 1.0));
    let frozen_point: Vec<bool> = cp.x.iter().map(|&x| locked(&locks, x)).collect();
    let frozen_segment = (0..k - 1)
        .map(|i| locks.iter().any(|l| l.lo <= cp.x[i] && cp.x[i + 1] <= l.hi))
        .collect();
    let tf = StartTf {
        k,
        lut_size,
        scale: sigma_max.max(crate::tf::SIGMA_MAX) / crate::tf::SIGMA_MAX,
        anchors,
        frozen_point,
        frozen_segment,
    };
    Ok((cp, tf))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> ControlPoints {
        ControlPoints {
            x: vec![0.0, 0.5, 1.0],
            sigma: vec![0.0, 100.0, 200.0],
            rgb: vec![[0.1, 0.2, 0.3], [0.5, 0.5, 0.5], [0.9, 0.8, 0.7]],
        }
    }

    #[test]
    fn prepare_adds_bounds_and_points_without_changing_the_curves() {
        let cp = ramp();
        let locks = [Lock { lo: 0.6, hi: 0.8 }];
        let (out, tf) = prepare(&cp, &locks, 16, 1024, 255.0).unwrap();
        assert!(out.len() >= 16);
        out.validate().unwrap();
        assert_eq!(cp.to_lut(1024), out.to_lut(1024));
        for (i, &x) in out.x.iter().enumerate() {
            assert_eq!(
                tf.is_frozen(i),
                (0.6..=0.8).contains(&x),
                "point {i} at {x}"
            );
        }
        // Round trip through the parameters keeps the positions.
        let back = tf.control_points(&tf.params_for(&out).unwrap()).unwrap();
        for i in 0..out.len() {
            assert!((back.x[i] - out.x[i]).abs() < 1e-9);
        }
    }

    #[test]
    fn locked_points_get_no_gradient_and_the_free_ones_do() {
        let (cp, tf) = prepare(&ramp(), &[Lock { lo: 0.0, hi: 0.3 }], 12, 64, 255.0).unwrap();
        let flat = tf.params_for(&cp).unwrap();
        let lut = LutGrad {
            entries: vec![[1.0, 0.5, -0.5, 0.25]; 64],
        };
        let direct = PointGrad {
            sigma: vec![0.1; cp.len()],
            rgb: vec![[0.1; 3]; cp.len()],
        };
        let g = tf.backward(&flat, &lut, &direct).unwrap();
        let k = cp.len();
        let (dens, col) = (&g[k - 1..2 * k - 1], &g[2 * k - 1..]);
        for i in 0..k {
            let moved = dens[i] != 0.0 || col[3 * i..3 * i + 3].iter().any(|v| *v != 0.0);
            assert_eq!(moved, cp.x[i] > 0.3, "point {i} at {}", cp.x[i]);
        }
        for (i, gs) in g[..k - 1].iter().enumerate() {
            if cp.x[i + 1] <= 0.3 {
                assert_eq!(*gs, 0.0, "segment {i}");
            }
        }
    }

    #[test]
    fn a_dense_start_keeps_its_densities_and_its_gradient_is_exact() {
        let mut cp = ramp();
        cp.sigma = vec![0.0, 600.0, 1000.0];
        let (cp, tf) = prepare(&cp, &[], 6, 64, 1000.0).unwrap();
        let flat = tf.params_for(&cp).unwrap();
        let back = tf.control_points(&flat).unwrap();
        for i in 0..cp.len() {
            assert!(
                (back.sigma[i] - cp.sigma[i]).abs() < 1e-3,
                "σ{i}: {}",
                back.sigma[i]
            );
        }
        // A loss linear in the LUT: its gradient through positions, densities (scaled) and
        // colours against central differences.
        let w: Vec<[f64; 4]> = (0..64)
            .map(|j| {
                let t = j as f64 / 63.0;
                [(3.0 * t).sin(), t, 1.0 - t, (5.0 * t).cos()]
            })
            .collect();
        let loss = |flat: &[f64]| -> f64 {
            let lut = tf.control_points(flat).unwrap().to_lut(64);
            lut.entries
                .iter()
                .zip(&w)
                .map(|(e, w)| (0..4).map(|c| e[c] as f64 * w[c]).sum::<f64>())
                .sum()
        };
        let g = tf
            .backward(
                &flat,
                &LutGrad { entries: w.clone() },
                &PointGrad {
                    sigma: vec![0.0; cp.len()],
                    rgb: vec![[0.0; 3]; cp.len()],
                },
            )
            .unwrap();
        let h = 1e-4;
        for i in 0..flat.len() {
            let (mut a, mut b) = (flat.clone(), flat.clone());
            a[i] += h;
            b[i] -= h;
            let fd = (loss(&a) - loss(&b)) / (2.0 * h);
            // The LUT is f32: differences carry its rounding (≈ 1e-7 · 1000 / h).
            assert!(
                (fd - g[i]).abs() < 2e-2 * (1.0 + fd.abs()),
                "param {i}: fd {fd}, analytic {}",
                g[i]
            );
        }
    }

    #[test]
    fn bad_locks_are_refused() {
        let bad = |l: &[Lock]| sorted_locks(l).unwrap_err();
        assert!(matches!(
            bad(&[Lock { lo: 0.5, hi: 0.2 }]),
            StartError::BadLock { .. }
        ));
        assert!(matches!(
            bad(&[Lock { lo: -0.1, hi: 0.2 }]),
            StartError::BadLock { .. }
        ));
        assert!(matches!(
            bad(&[Lock {
                lo: 0.1,
                hi: f64::NAN
            }]),
            StartError::BadLock { .. }
        ));
        assert_eq!(
            bad(&[Lock { lo: 0.1, hi: 0.5 }, Lock { lo: 0.4, hi: 0.6 }]),
            StartError::Overlap
        );
        assert!(sorted_locks(&[Lock { lo: 0.5, hi: 0.6 }, Lock { lo: 0.1, hi: 0.5 }]).is_ok());
    }
}
