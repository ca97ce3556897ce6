//! Cosine similarity of embeddings and its gradient, and CLIP's softmax over captions.

/// Norms below this are treated as this, so a zero embedding gives similarity 0, not NaN.
const MIN_NORM: f64 = 1e-12;

fn norm(v: &[f32]) -> f64 {
    v.iter()
        .map(|&x| (x as f64).powi(2))
        .sum::<f64>()
        .sqrt()
        .max(MIN_NORM)
}

/// Why two embeddings have no cosine similarity.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Incomparable {
    #[error("embeddings of different lengths ({0} and {1}) cannot be compared")]
    Lengths(usize, usize),
    #[error("has a non-finite value at index {0}")]
    NonFinite(usize),
    #[error("has zero length: its cosine similarity is undefined")]
    Zero,
}

/// `v / |v|` in f64, or why `v` has no direction (empty, zero, or a NaN/infinite value).
pub fn unit(v: &[f32]) -> Result<Vec<f64>, Incomparable> {
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(Incomparable::NonFinite(i));
    }
    let n = v.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
    if n == 0.0 {
        return Err(Incomparable::Zero);
    }
    Ok(v.iter().map(|&x| x as f64 / n).collect())
}

/// cos(a, b) = â·b̂ in f64, or why it is undefined. The one definition: the optimizer's loss
/// refuses what this refuses, and [`cosine`] scores it as 0.
pub fn cosine_checked(a: &[f32], b: &[f32]) -> Result<f64, Incomparable> {
    if a.len() != b.len() {
        return Err(Incomparable::Lengths(a.len(), b.len()));
    }
    let (u, v) = (unit(a)?, unit(b)?);
    Ok(u.iter().zip(&v).map(|(x, y)| x * y).sum())
}

/// cos(a, b) for scoring: [`cosine_checked`], with 0 (no similarity) where it is undefined.
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    cosine_checked(a, b).unwrap_or(0.0) as f32
}

/// ∂cos(a, b)/∂a = b/(|a||b|) − cos · a/|a|².
pub fn cosine_grad(a: &[f32], b: &[f32]) -> Vec<f32> {
    let (na, nb) = (norm(a), norm(b));
    let c = cosine(a, b) as f64;
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (y as f64 / (na * nb) - c * x as f64 / (na * na)) as f32)
        .collect()
}

/// softmax(scale · sims), stable for any scale.
pub fn softmax_scaled(sims: &[f32], scale: f32) -> Vec<f32> {
    let z: Vec<f64> = sims.iter().map(|&s| s as f64 * scale as f64).collect();
    let max = z.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let e: Vec<f64> = z.iter().map(|v| (v - max).exp()).collect();
    let sum: f64 = e.iter().sum();
    e.iter().map(|v| (v / sum) as f32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_finite_differences_and_zero_is_finite() {
        let a = [0.3f32, -1.2, 0.7, 2.0];
        let b = [1.0f32, 0.5, -0.4, 0.9];
        let g = cosine_grad(&a, &b);
        // f64 central differences on an f32 function: step 1e-3, round-off ~1e-7/1e-3 = 1e-4.
        for i in 0..4 {
            let (mut p, mut m) = (a, a);
            p[i] += 1e-3;
            m[i] -= 1e-3;
            let fd = (cosine(&p, &b) as f64 - cosine(&m, &b) as f64) / 2e-3;
            assert!((g[i] as f64 - fd).abs() < 5e-4, "{i}: {} vs {fd}", g[i]);
        }
        assert_eq!(cosine(&[0.0; 4], &b), 0.0);
        assert_eq!(cosine_checked(&[0.0; 4], &b), Err(Incomparable::Zero));
        assert_eq!(
            cosine_checked(&a, &b[..3]),
            Err(Incomparable::Lengths(4, 3))
        );
        assert_eq!(
            cosine_checked(&[1.0, f32::NAN, 0.0, 0.0], &b),
            Err(Incomparable::NonFinite(1))
        );
        assert!(
            (cosine_checked(&[3.0, 4.0, 0.0, 0.0], &[0.0, 5.0, 12.0, 0.0]).unwrap() - 20.0 / 65.0)
                .abs()
                < 1e-15
        );
        assert!(cosine_grad(&[0.0; 4], &b).iter().all(|v| v.is_finite()));
        let p = softmax_scaled(&[1.0, 0.0, -1.0], 100.0);
        assert!(p.iter().all(|v| v.is_finite()) && (p.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }
}
