//! The loss terms of Algorithm 1 and their gradients, all computed in f64.
//!
//! - contrastive cross-entropy between one image embedding and text classes (class 0 = the
//!   prompt), with logits `s · cos(e_I, e_k)` and `s` = CLIP's logit scale;
//! - the Beta(a, b) prior on each pixel's final transmittance T_N, averaged over pixels;
//! - L1 on control-point densities and L2 of colours towards 0.5.
//!
//! Each function returns the loss and the gradient of that loss with respect to its input.

use super::{EmbeddingError, OptimizeError, TransmittanceError};
use crate::clip::{Incomparable, LogitsError};

/// T_N is clamped to [ε, 1 − ε] inside the Beta prior.
///
/// Why 1e-4: the renderer's T_N is f32, whose spacing just below 1 is 6e-8, so 1 − ε is
/// representable with room to spare and `1 − T` (taken in f64) is exact. The per-pixel prior
/// value then stays within ±|a − 1|·ln(1/ε) ≈ ±4.6 for a = 0.5 (its minimum, at the clamp, is
/// negative because the Beta density exceeds 1 near the ends; the range is the same order as
/// the contrastive loss, ln 129 ≈ 4.9), and its gradient by (|a − 1| + |b − 1|)/ε = 1e4 before the
/// mean over 224² pixels and the weight 0.02, i.e. ≤ 4e-3 per pixel: large enough to push
/// semi-transparent rays, far too small to let one saturated ray dominate a step.
///
/// Outside the clamp (T < ε or T > 1 − ε, including T = 0 and 1 exactly: fully opaque rays and
/// rays that miss the volume) the gradient is 0, as for PyTorch's `clamp`. That is the right
/// answer, not only a safe one: for a, b < 1 the prior decreases towards both ends, so a ray
/// already past the clamp is where the prior wants it, and a ray that misses the box has no
/// parameter to move anyway.
pub(crate) const PRIOR_EPS: f64 = 1e-4;

/// Result of `contrastive` (the contrastive loss of one image embedding).
#[derive(Clone, Debug)]
pub struct Contrastive {
    /// Cross-entropy −log softmax(logits)\[0\].
    pub loss: f64,
    /// `s · cos(e_I, e_k)` per class, class 0 first.
    pub logits: Vec<f64>,
    /// Cosine similarity per class.
    pub cosines: Vec<f64>,
    /// d loss / d e_I, length = embedding dimension.
    pub d_image: Vec<f64>,
}

/// Contrastive cross-entropy with the prompt (`classes[0]`) as the positive class.
///
/// `image`: the image embedding e_I, shape [D], as CLIP projects it (not normalized).
/// `classes`: text (or reference-image) embeddings, each shape [D], not necessarily
/// normalized; they are constants (no gradient). `logit_scale`: exp of CLIP's stored
/// logit_scale (100 for the released models).
///
/// The softmax uses log-sum-exp with the maximum logit subtracted, so logits of 100 and more
/// are exact. The gradient goes through the normalization of e_I:
/// d cos_k / d e_I = (t̂_k − cos_k û) / |e_I|.
pub(crate) fn contrastive(
    image: &[f32],
    classes: &[&[f32]],
    logit_scale: f64,
) -> Result<Contrastive, OptimizeError> {
    if classes.len() < 2 {
        return Err(OptimizeError::NoNegatives);
    }
    // The similarity and its gradient belong to the model (`clip::Head`); the loss only adds
    // the softmax cross-entropy on top.
    let head =
        crate::clip::Head::new(logit_scale).map_err(|_| EmbeddingError::LogitScale(logit_scale))?;
    let l = head.logits(image, classes).map_err(|e| match e {
        LogitsError::Image(problem) => EmbeddingError::Unusable {
            what: "image embedding",
            problem,
        },
        LogitsError::Class(problem) => EmbeddingError::Unusable {
            what: "text embedding",
            problem,
        },
        LogitsError::Length { index, len, image } => EmbeddingError::ClassLength {
            class: index,
            len,
            image_len: image,
        },
    })?;
    let m = l.logits.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let lse = m + l.logits.iter().map(|x| (x - m).exp()).sum::<f64>().ln();
    let loss = lse - l.logits[0];
    // d loss / d logit_k = p_k − [k = 0].
    let d_logits: Vec<f64> = l
        .logits
        .iter()
        .enumerate()
        .map(|(k, x)| (x - lse).exp() - if k == 0 { 1.0 } else { 0.0 })
        .collect();
    let d_image = head.backward(&l, &d_logits);
    let (logits, cosines) = (l.logits, l.cosines);
    Ok(Contrastive {
        loss,
        logits,
        cosines,
        d_image,
    })
}

/// Cosine similarity of two embeddings in f64 (`clip::cosine_checked`, errors as in
/// [`contrastive`]).
pub(crate) fn cosine(a: &[f32], b: &[f32]) -> Result<f64, OptimizeError> {
    crate::clip::cosine_checked(a, b).map_err(|e| {
        match e {
            Incomparable::Lengths(..) => EmbeddingError::Lengths(e),
            _ => EmbeddingError::Unusable {
                what: "an embedding",
                problem: e,
            },
        }
        .into()
    })
}

/// The Beta(a, b) prior on per-pixel transmittance: mean over pixels of
/// −(a − 1) ln T̃ − (b − 1) ln(1 − T̃) with T̃ = clamp(T, ε, 1 − ε) ([`PRIOR_EPS`]).
///
/// The normalizing constant ln B(a, b) is left out: it moves no gradient (the reported term
/// is the negative log density up to that constant, so it can be negative).
/// Returns (loss, d loss / d T per pixel).
pub(crate) fn beta_prior(t: &[f32], a: f64, b: f64) -> Result<(f64, Vec<f64>), OptimizeError> {
    if t.is_empty() {
        return Err(TransmittanceError::Empty.into());
    }
    if !(a.is_finite() && a > 0.0 && b.is_finite() && b > 0.0) {
        return Err(TransmittanceError::Parameters { a, b }.into());
    }
    let n = t.len() as f64;
    let mut loss = 0.0;
    let mut grad = Vec::with_capacity(t.len());
    for (i, &ti) in t.iter().enumerate() {
        if ti.is_nan() {
            return Err(TransmittanceError::NaN(i).into());
        }
        let ti = ti as f64;
        let tc = ti.clamp(PRIOR_EPS, 1.0 - PRIOR_EPS);
        loss += -(a - 1.0) * tc.ln() - (b - 1.0) * (1.0 - tc).ln();
        let inside = (PRIOR_EPS..=1.0 - PRIOR_EPS).contains(&ti);
        grad.push(if inside {
            (-(a - 1.0) / tc + (b - 1.0) / (1.0 - tc)) / n
        } else {
            0.0
        });
    }
    Ok((loss / n, grad))
}

/// λ1 Σ_k |σ_k| and its gradient λ1 sign(σ_k) (sign(0) = 0, as PyTorch).
pub(crate) fn density_l1(sigma: &[f64], lambda: f64) -> (f64, Vec<f64>) {
    let loss = lambda * sigma.iter().map(|s| s.abs()).sum::<f64>();
    let grad = sigma
        .iter()
        .map(|&s| {
            if s > 0.0 {
                lambda
            } else if s < 0.0 {
                -lambda
            } else {
                0.0
            }
        })
        .collect();
    (loss, grad)
}

/// λ2 Σ_k Σ_c (c_kc − 0.5)² and its gradient 2 λ2 (c_kc − 0.5).
pub(crate) fn colour_l2(rgb: &[[f64; 3]], lambda: f64) -> (f64, Vec<[f64; 3]>) {
    let loss = lambda
        * rgb
            .iter()
            .flat_map(|c| c.iter())
            .map(|c| (c - 0.5) * (c - 0.5))
            .sum::<f64>();
    let grad = rgb
        .iter()
        .map(|c| c.map(|v| 2.0 * lambda * (v - 0.5)))
        .collect();
    (loss, grad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_vec(rng: &mut ChaCha8Rng, d: usize) -> Vec<f32> {
        (0..d).map(|_| rng.random_range(-1.0f32..1.0)).collect()
    }

    /// Contrastive loss evaluated in f64 from an f64 image embedding (for finite differences
    /// that are not limited by f32 rounding of the perturbed input).
    fn contrastive_f64(image: &[f64], classes: &[Vec<f32>], s: f64) -> f64 {
        let n = image.iter().map(|x| x * x).sum::<f64>().sqrt();
        let logits: Vec<f64> = classes
            .iter()
            .map(|c| {
                let cn = c.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
                s * image.iter().zip(c).map(|(a, &b)| a * b as f64).sum::<f64>() / (n * cn)
            })
            .collect();
        let m = logits.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        m + logits.iter().map(|l| (l - m).exp()).sum::<f64>().ln() - logits[0]
    }

    #[test]
    fn contrastive_gradient_matches_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let d = 16;
        let image = random_vec(&mut rng, d);
        let classes: Vec<Vec<f32>> = (0..6).map(|_| random_vec(&mut rng, d)).collect();
        let refs: Vec<&[f32]> = classes.iter().map(|c| c.as_slice()).collect();
        let s = 100.0;
        let c = contrastive(&image, &refs, s).unwrap();
        let x: Vec<f64> = image.iter().map(|&v| v as f64).collect();
        assert!((contrastive_f64(&x, &classes, s) - c.loss).abs() < 1e-12);
        // Central differences in f64 with h = 1e-6 on |e_I| ~ 2.3: truncation error ~h² · f''' ·
        // s³ ~ 1e-6, rounding ~ 1e-16 · 5 / 1e-6 ~ 1e-9; gradients are O(10), so 1e-5
        // relative to the largest component leaves a margin of 10 over both.
        let h = 1e-6;
        let gmax = c.d_image.iter().fold(0.0f64, |m, g| m.max(g.abs()));
        assert!(gmax > 1.0, "gradient unexpectedly small: {gmax}");
        for i in 0..d {
            let mut p = x.clone();
            p[i] += h;
            let mut m = x.clone();
            m[i] -= h;
            let fd =
                (contrastive_f64(&p, &classes, s) - contrastive_f64(&m, &classes, s)) / (2.0 * h);
            assert!(
                (fd - c.d_image[i]).abs() < 1e-5 * gmax,
                "component {i}: analytic {} vs fd {fd}",
                c.d_image[i]
            );
        }
    }

    #[test]
    fn contrastive_is_exact_for_huge_logits() {
        // Image equal to the prompt: logit 0 is s; a negative orthogonal to it has logit 0.
        let image = [1.0f32, 0.0, 0.0];
        let prompt = [2.0f32, 0.0, 0.0];
        let neg = [0.0f32, 1.0, 0.0];
        for s in [100.0, 1000.0, 1e5] {
            let c = contrastive(&image, &[&prompt, &neg], s).unwrap();
            // loss = ln(1 + e^{-s}) = e^{-s} to double precision; never NaN or negative.
            assert!(
                c.loss.is_finite() && c.loss >= 0.0 && c.loss < 1e-40,
                "{}",
                c.loss
            );
            assert!(c.d_image.iter().all(|g| g.is_finite()));
            // Reverse: the negative is the image; loss ≈ s exactly, gradient finite.
            let c = contrastive(&image, &[&neg, &prompt], s).unwrap();
            assert!((c.loss - s).abs() < 1e-9 * s, "{} vs {s}", c.loss);
            assert!(c.d_image.iter().all(|g| g.is_finite()));
        }
    }

    #[test]
    fn cosine_matches_contrastive_and_rejects_mismatch() {
        let (a, b, c) = ([3.0f32, 4.0, 0.0], [0.0f32, 5.0, 12.0], [1.0f32, 0.0, 0.0]);
        assert!((cosine(&a, &b).unwrap() - 20.0 / 65.0).abs() < 1e-15);
        let r = contrastive(&a, &[&b, &c], 100.0).unwrap();
        assert_eq!(r.cosines[0], cosine(&a, &b).unwrap());
        assert!(cosine(&a, &[1.0, 2.0]).is_err());
        assert!(cosine(&a, &[0.0; 3]).is_err());
    }

    #[test]
    fn contrastive_rejects_zero_negatives_and_bad_embeddings() {
        let e = [1.0f32, 2.0];
        assert!(matches!(
            contrastive(&e, &[&e], 100.0),
            Err(OptimizeError::NoNegatives)
        ));
        let msg = contrastive(&[0.0, 0.0], &[&e, &e], 100.0)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("zero length"), "{msg}");
        let msg = contrastive(&e, &[&e, &[1.0, 2.0, 3.0]], 100.0)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("text embedding 1"), "{msg}");
        let msg = contrastive(&[f32::NAN, 1.0], &[&e, &e], 100.0)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("non-finite"), "{msg}");
        assert!(contrastive(&e, &[&e, &e], f64::NAN).is_err());
    }

    fn prior_f64(t: &[f64], a: f64, b: f64) -> f64 {
        t.iter()
            .map(|&t| {
                let tc = t.clamp(PRIOR_EPS, 1.0 - PRIOR_EPS);
                -(a - 1.0) * tc.ln() - (b - 1.0) * (1.0 - tc).ln()
            })
            .sum::<f64>()
            / t.len() as f64
    }

    #[test]
    fn beta_prior_gradient_matches_central_differences() {
        // Values exactly representable in f32 so the f64 reference sees the same inputs.
        let t: Vec<f32> = vec![0.03125, 0.25, 0.5, 0.625, 0.96875, 0.001953125];
        for (a, b) in [(0.5, 0.5), (0.3, 0.8), (2.0, 3.0)] {
            let (loss, g) = beta_prior(&t, a, b).unwrap();
            let x: Vec<f64> = t.iter().map(|&v| v as f64).collect();
            assert!((loss - prior_f64(&x, a, b)).abs() < 1e-12);
            // h = 1e-7 keeps every perturbed point inside the clamp (smallest T is 2e-3); the
            // truncation error h² f''' / 6 ≤ 1e-14 · 2/T³ / n ~ 1e-6 at T = 2e-3, rounding
            // 1e-16 / 1e-7 ~ 1e-9: a tolerance of 1e-5 relative + 1e-7 absolute holds both.
            let h = 1e-7;
            for i in 0..t.len() {
                let mut p = x.clone();
                p[i] += h;
                let mut m = x.clone();
                m[i] -= h;
                let fd = (prior_f64(&p, a, b) - prior_f64(&m, a, b)) / (2.0 * h);
                assert!(
                    (fd - g[i]).abs() < 1e-5 * fd.abs() + 1e-7,
                    "a={a} b={b} i={i}: {} vs {fd}",
                    g[i]
                );
            }
        }
    }

    #[test]
    fn beta_prior_is_finite_at_zero_and_one() {
        let t = [0.0f32, 1.0, 0.0, 1.0];
        let (loss, g) = beta_prior(&t, 0.5, 0.5).unwrap();
        // Clamped: each pixel contributes 0.5 ln ε + 0.5 ln(1 − ε) ≈ −4.605, the minimum.
        let expect = 0.5 * (PRIOR_EPS.ln() + (1.0 - PRIOR_EPS).ln());
        assert!((loss - expect).abs() < 1e-12, "{loss} vs {expect}");
        let (mid, _) = beta_prior(&[0.5], 0.5, 0.5).unwrap();
        assert!(mid > loss, "T = 0.5 must cost more than T at the ends");
        assert_eq!(g, vec![0.0; 4]);
        // Just inside the clamp the gradient is the analytic one, bounded by 1/ε per pixel.
        let (_, g) = beta_prior(&[2e-4], 0.5, 0.5).unwrap();
        let t = 2e-4f32 as f64;
        assert!((g[0] - (0.5 / t - 0.5 / (1.0 - t))).abs() < 1e-6);
        assert!(g[0].abs() <= 1.0 / PRIOR_EPS);
        // For a = b < 1 the prior pulls T towards the nearer end.
        let (_, g) = beta_prior(&[0.2, 0.8], 0.5, 0.5).unwrap();
        assert!(g[0] > 0.0 && g[1] < 0.0, "{g:?}");
    }

    #[test]
    fn beta_prior_rejects_nan_and_empty() {
        assert!(beta_prior(&[], 0.5, 0.5).is_err());
        let m = beta_prior(&[0.5, f32::NAN], 0.5, 0.5)
            .unwrap_err()
            .to_string();
        assert!(m.contains("pixel 1"), "{m}");
        assert!(beta_prior(&[0.5], 0.0, 0.5).is_err());
    }

    #[test]
    fn regularizers_match_central_differences() {
        // The central-difference loop of the prior's test above, with this loss's own step
        // and tolerance (argued next to each).
        let sigma = vec![3.0, 0.5, 200.0, 17.0];
        let rgb = vec![[0.1, 0.5, 0.9], [0.7, 0.3, 0.45]];
        let (l1, g1) = density_l1(&sigma, 2e-5);
        assert!((l1 - 2e-5 * 220.5).abs() < 1e-15);
        let (l2, g2) = colour_l2(&rgb, 8e-4);
        let h = 1e-6;
        // Both are smooth away from σ = 0 (L1 is linear there, L2 quadratic): central
        // differences are exact up to rounding, ~1e-16 · |loss| / h ≈ 1e-13.
        for i in 0..sigma.len() {
            let mut p = sigma.clone();
            p[i] += h;
            let mut m = sigma.clone();
            m[i] -= h;
            let fd = (density_l1(&p, 2e-5).0 - density_l1(&m, 2e-5).0) / (2.0 * h);
            assert!((fd - g1[i]).abs() < 1e-10, "{fd} vs {}", g1[i]);
        }
        for k in 0..rgb.len() {
            for c in 0..3 {
                let mut p = rgb.clone();
                p[k][c] += h;
                let mut m = rgb.clone();
                m[k][c] -= h;
                let fd = (colour_l2(&p, 8e-4).0 - colour_l2(&m, 8e-4).0) / (2.0 * h);
                assert!((fd - g2[k][c]).abs() < 1e-10, "{fd} vs {}", g2[k][c]);
            }
        }
        assert!(l2 > 0.0);
        // σ = 0 exactly: subgradient 0, no NaN.
        assert_eq!(density_l1(&[0.0], 1.0).1, vec![0.0]);
    }
}
