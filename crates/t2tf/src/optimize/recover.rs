//! Recovering a known TF from reference renders: one target image per view and a loss on the
//! images (a pixel loss needs no CLIP at all). It drives the same renderer backward, TF
//! backward and SGD as Algorithm 1, so it checks them together (tests/optimize/optimize_recovery.rs)
//! and shows, offline, that the optimizer finds a TF from pictures (examples/demo_recover.rs).
//!
//! Not Algorithm 1's loop (`super::optimize`): there the positive is one embedding for every
//! view (a prompt), here every view has its own target.

use super::sgd::{linear_lr, Sgd};
use super::{EmbeddingError, OptimizeError, Parameterization, PointGrad, Renderer, View};
use crate::image::Image;
use crate::tf::LutGrad;

/// The loss (mean over views) and d loss / d image of each view.
pub type LossAndGrad = (f64, Vec<Vec<f32>>);

/// A loss on a batch of renders.
pub type ImageLoss<'a> = dyn FnMut(&[Image]) -> Result<LossAndGrad, OptimizeError> + 'a;

/// Momentum for recovery: the paper's 0.75.
const MOMENTUM: f64 = 0.75;

/// `steps` of momentum SGD with linear annealing from `lr0`, every view in every step. Returns
/// the parameters and the loss of each step; a non-finite loss or gradient is an error.
pub fn descend<R: Renderer, P: Parameterization + ?Sized>(
    renderer: &R,
    tf: &P,
    views: &[View],
    mut params: Vec<f64>,
    steps: usize,
    lr0: f64,
    loss: &mut ImageLoss,
) -> Result<(Vec<f64>, Vec<f64>), OptimizeError> {
    let mut sgd = Sgd::new(params.len(), MOMENTUM)?;
    let mut losses = Vec::new();
    for step in 0..steps {
        let cp = tf
            .control_points(&params)
            .map_err(OptimizeError::Parameters)?;
        let lut = cp.to_lut(tf.lut_size());
        let mut images = Vec::with_capacity(views.len());
        let mut tapes = Vec::with_capacity(views.len());
        for v in views {
            let (im, _, tape) = renderer.render(&lut, v).map_err(OptimizeError::Renderer)?;
            images.push(im);
            tapes.push(tape);
        }
        let (l, d_images) = loss(&images)?;
        if !l.is_finite() {
            return Err(OptimizeError::NonFinite {
                what: "loss",
                index: 0,
                step,
            });
        }
        losses.push(l);
        let mut lut_grad = LutGrad::zeros(lut.entries.len());
        for (((v, tape), d), im) in views.iter().zip(&tapes).zip(&d_images).zip(&images) {
            // The pixel loss does not look at transmittance.
            let zero_t = vec![0.0f32; im.width * im.height];
            let g = renderer
                .backward(&lut, v, tape, d, &zero_t)
                .map_err(OptimizeError::Renderer)?;
            lut_grad.add(&g);
        }
        let direct = PointGrad {
            sigma: vec![0.0; cp.len()],
            rgb: vec![[0.0; 3]; cp.len()],
        };
        let grad = tf
            .backward(&params, &lut_grad, &direct)
            .map_err(OptimizeError::Parameters)?;
        sgd.update(&mut params, &grad, linear_lr(lr0, step, steps))?;
    }
    Ok((params, losses))
}

/// Mean squared pixel error over views against `targets`; d/d image = 2 (x − t) / (pixels ·
/// views).
pub fn pixel_loss(
    targets: &[Image],
) -> impl FnMut(&[Image]) -> Result<LossAndGrad, OptimizeError> + '_ {
    move |images| {
        if images.len() != targets.len() {
            return Err(EmbeddingError::TargetCount {
                renders: images.len(),
                targets: targets.len(),
            }
            .into());
        }
        let n = images.iter().map(|im| im.data.len()).sum::<usize>() as f64;
        let mut loss = 0.0;
        let mut grads = Vec::with_capacity(images.len());
        for (x, t) in images.iter().zip(targets) {
            if x.data.len() != t.data.len() {
                return Err(EmbeddingError::TargetSize {
                    render: (x.width, x.height),
                    target: (t.width, t.height),
                }
                .into());
            }
            grads.push(
                x.data
                    .iter()
                    .zip(&t.data)
                    .map(|(p, q)| {
                        let d = (p - q) as f64;
                        loss += d * d / n;
                        (2.0 * d / n) as f32
                    })
                    .collect(),
            );
        }
        Ok((loss, grads))
    }
}

/// Mean over views of [`crate::image::psnr`] of the images `a` against `b` (dB, peak 1; 200 dB
/// for equal views). Only a view reproduced exactly reaches that cap; the recovery test's
/// thresholds (tests/optimize) are set on views that are not.
pub fn psnr(a: &[Image], b: &[Image]) -> f64 {
    let total: f64 = a.iter().zip(b).map(|(x, y)| crate::image::psnr(x, y)).sum();
    total / a.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_loss_gradient_matches_central_differences() {
        // The mean squared error is quadratic, so central differences are exact up to
        // rounding; with h = 1e-2 the f32 inputs and the f64 sum give errors ≈ 1e-7 / h.
        let target = vec![Image {
            width: 2,
            height: 1,
            data: vec![0.1, 0.5, 0.9, 0.3, 0.2, 0.7],
        }];
        let x = Image {
            width: 2,
            height: 1,
            data: vec![0.4, 0.5, 0.1, 0.8, 0.25, 0.0],
        };
        let mut f = pixel_loss(&target);
        let (_, g) = f(std::slice::from_ref(&x)).unwrap();
        for (i, &gi) in g[0].iter().enumerate() {
            let (mut a, mut b) = (x.clone(), x.clone());
            a.data[i] += 1e-2;
            b.data[i] -= 1e-2;
            let fd = (f(&[a]).unwrap().0 - f(&[b]).unwrap().0) / 2e-2;
            assert!((fd - gi as f64).abs() < 1e-4, "pixel {i}: {fd} vs {gi}");
        }
        assert!(f(&[]).is_err());
        assert!((psnr(std::slice::from_ref(&x), std::slice::from_ref(&x)) - 200.0).abs() < 1e-9);
    }
}
