//! SGD with momentum (PyTorch semantics, dampening 0, no Nesterov) and the linear learning-rate
//! annealing of the paper.
//!
//! PyTorch: `v ← μ v + g` (on the first step `v = g`, which is the same as starting from
//! `v = 0`), then `p ← p − lr · v`.

use super::OptimizeError;

/// Learning rate of step `step` (0-based) out of `steps`: `lr0 · (1 − step / steps)`.
///
/// This is PyTorch's `LinearLR(start_factor = 1, end_factor = 0, total_iters = steps)`
/// stepped once after each update: the first step uses `lr0`, the last `lr0 / steps`, and the
/// rate would reach 0 after the last step.
pub(crate) fn linear_lr(lr0: f64, step: usize, steps: usize) -> f64 {
    if steps == 0 {
        return 0.0;
    }
    lr0 * (1.0 - step.min(steps) as f64 / steps as f64)
}

/// Momentum SGD over a flat parameter vector.
#[derive(Clone, Debug)]
pub(crate) struct Sgd {
    momentum: f64,
    velocity: Vec<f64>,
    step: usize,
}

impl Sgd {
    /// `n` parameters, momentum μ in [0, 1).
    pub fn new(n: usize, momentum: f64) -> Result<Sgd, OptimizeError> {
        if !(0.0..1.0).contains(&momentum) {
            return Err(OptimizeError::Setting {
                name: "momentum",
                message: format!("must be in [0, 1), got {momentum}"),
            });
        }
        Ok(Sgd {
            momentum,
            velocity: vec![0.0; n],
            step: 0,
        })
    }

    /// The momentum buffer (one entry per parameter).
    #[cfg(test)]
    fn velocity(&self) -> &[f64] {
        &self.velocity
    }

    /// Number of updates applied so far.
    #[cfg(test)]
    fn steps_taken(&self) -> usize {
        self.step
    }

    /// Apply one update with learning rate `lr`.
    ///
    /// A non-finite gradient, or an update that would make a parameter non-finite, is an error
    /// and leaves both the parameters and the momentum untouched, so the caller still holds
    /// the last good transfer function.
    pub fn update(
        &mut self,
        params: &mut [f64],
        grad: &[f64],
        lr: f64,
    ) -> Result<(), OptimizeError> {
        assert_eq!(params.len(), self.velocity.len(), "parameter count changed");
        assert_eq!(grad.len(), self.velocity.len(), "gradient length mismatch");
        if let Some(i) = grad.iter().position(|g| !g.is_finite()) {
            return Err(OptimizeError::NonFinite {
                what: "gradient",
                index: i,
                step: self.step,
            });
        }
        let v: Vec<f64> = self
            .velocity
            .iter()
            .zip(grad)
            .map(|(v, g)| self.momentum * v + g)
            .collect();
        let p: Vec<f64> = params.iter().zip(&v).map(|(p, v)| p - lr * v).collect();
        if let Some(i) = p.iter().position(|x| !x.is_finite()) {
            return Err(OptimizeError::NonFinite {
                what: "parameter after the update",
                index: i,
                step: self.step,
            });
        }
        params.copy_from_slice(&p);
        self.velocity = v;
        self.step += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_pytorch_recurrence_by_hand() {
        // Two steps on p = [1, -2] with g = [0.5, 1] then [-1, 2], μ = 0.75, lr 10 then 5:
        // v1 = g1; p1 = p0 - 10 g1 = [-4, -12]; v2 = 0.75 v1 + g2 = [-0.625, 2.75];
        // p2 = p1 - 5 v2 = [-0.875, -25.75].
        let mut p = vec![1.0, -2.0];
        let mut s = Sgd::new(2, 0.75).unwrap();
        s.update(&mut p, &[0.5, 1.0], 10.0).unwrap();
        assert_eq!(p, vec![-4.0, -12.0]);
        s.update(&mut p, &[-1.0, 2.0], 5.0).unwrap();
        assert_eq!(s.velocity(), &[-0.625, 2.75]);
        assert_eq!(p, vec![-0.875, -25.75]);
        assert_eq!(s.steps_taken(), 2);
    }

    #[test]
    fn linear_annealing_reaches_zero_after_the_last_step() {
        assert_eq!(linear_lr(10.0, 0, 300), 10.0);
        assert!((linear_lr(10.0, 150, 300) - 5.0).abs() < 1e-12);
        assert!((linear_lr(10.0, 299, 300) - 10.0 / 300.0).abs() < 1e-12);
        assert_eq!(linear_lr(10.0, 300, 300), 0.0);
        assert_eq!(linear_lr(10.0, 0, 0), 0.0);
        let lrs: Vec<f64> = (0..300).map(|i| linear_lr(10.0, i, 300)).collect();
        assert!(lrs.windows(2).all(|w| w[1] < w[0]));
    }

    #[test]
    fn minimizes_a_quadratic() {
        // f(p) = ½ Σ c_i p_i²: momentum SGD with a small rate converges to 0.
        let c = [1.0, 4.0, 0.25];
        let mut p = vec![3.0, -2.0, 5.0];
        let mut s = Sgd::new(3, 0.75).unwrap();
        for i in 0..400 {
            let g: Vec<f64> = p.iter().zip(&c).map(|(p, c)| c * p).collect();
            s.update(&mut p, &g, linear_lr(0.1, i, 400)).unwrap();
        }
        assert!(p.iter().all(|x| x.abs() < 1e-3), "{p:?}");
    }

    #[test]
    fn non_finite_gradient_or_parameter_is_an_error_and_changes_nothing() {
        let mut p = vec![1.0, 2.0];
        let mut s = Sgd::new(2, 0.5).unwrap();
        s.update(&mut p, &[1.0, 1.0], 0.1).unwrap();
        let (p0, v0) = (p.clone(), s.velocity().to_vec());
        let e = s.update(&mut p, &[f64::NAN, 0.0], 0.1).unwrap_err();
        assert!(
            e.to_string().contains("non-finite gradient at index 0"),
            "{e}"
        );
        let e = s.update(&mut p, &[0.0, 1e308], 1e10).unwrap_err();
        assert!(e.to_string().contains("parameter"), "{e}");
        assert_eq!(p, p0);
        assert_eq!(s.velocity(), &v0[..]);
        assert!(Sgd::new(1, 1.0).is_err());
        assert!(Sgd::new(1, f64::NAN).is_err());
    }
}
