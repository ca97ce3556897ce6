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
    /// The two lengths differ.
    #[error("embeddings of different lengths ({0} and {1}) cannot be compared")]
    Lengths(usize, usize),
    /// A NaN or infinite value, at this index.
    #[error("has a non-finite value at index {0}")]
    NonFinite(usize),
    /// All zero: no direction.
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

/// How a model turns an image embedding and class embeddings into logits: for CLIP,
/// `logit_scale · cos(image, class)`, `transformers` modeling_clip.py `CLIPModel.forward`'s
/// `logits_per_image` (`logit_scale` being exp of the checkpoint's parameter). The model owns
/// it (`Clip::head`), so the loss asks the model rather than knowing CLIP's formula, and a
/// family with another rule changes it here.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Head {
    logit_scale: f64,
}

/// Why [`Head::logits`] cannot compare the embeddings it was given.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LogitsError {
    /// The image embedding has no direction.
    #[error("image embedding {0}")]
    Image(Incomparable),
    /// Class `index`'s embedding has no direction.
    #[error("text embedding {0}")]
    Class(Incomparable),
    /// Class `index` has another length than the image embedding.
    #[error("text embedding {index} has {len} values but the image embedding has {image}")]
    Length {
        /// Which class.
        index: usize,
        /// Its length.
        len: usize,
        /// The image embedding's length.
        image: usize,
    },
}

/// The logits of one image against its classes, and what [`Head::backward`] needs.
#[derive(Clone, Debug)]
pub struct Logits {
    /// One per class, in the order given.
    pub logits: Vec<f64>,
    /// The cosine similarity behind each logit.
    pub cosines: Vec<f64>,
    image_unit: Vec<f64>,
    image_norm: f64,
    class_units: Vec<Vec<f64>>,
}

/// A logit scale that is not positive and finite (from a broken checkpoint).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("CLIP logit scale must be positive and finite, got {0}")]
pub struct BadLogitScale(pub f64);

impl Head {
    /// CLIP's head with temperature `logit_scale` (exp of the stored parameter), which must be
    /// positive and finite.
    pub fn new(logit_scale: f64) -> Result<Head, BadLogitScale> {
        if logit_scale.is_finite() && logit_scale > 0.0 {
            Ok(Head { logit_scale })
        } else {
            Err(BadLogitScale(logit_scale))
        }
    }

    /// The temperature the cosines are multiplied by (100 for OpenAI's models).
    pub fn logit_scale(&self) -> f64 {
        self.logit_scale
    }

    /// `logit_scale · cos(image, class)` for every class, in f64.
    pub fn logits(&self, image: &[f32], classes: &[&[f32]]) -> Result<Logits, LogitsError> {
        let u = unit(image).map_err(LogitsError::Image)?;
        let mut out = Logits {
            logits: Vec::with_capacity(classes.len()),
            cosines: Vec::with_capacity(classes.len()),
            image_norm: image
                .iter()
                .map(|&x| (x as f64) * (x as f64))
                .sum::<f64>()
                .sqrt(),
            image_unit: Vec::new(),
            class_units: Vec::with_capacity(classes.len()),
        };
        for (index, c) in classes.iter().enumerate() {
            if c.len() != image.len() {
                return Err(LogitsError::Length {
                    index,
                    len: c.len(),
                    image: image.len(),
                });
            }
            let t = unit(c).map_err(LogitsError::Class)?;
            let cos: f64 = u.iter().zip(&t).map(|(a, b)| a * b).sum();
            out.cosines.push(cos);
            out.logits.push(self.logit_scale * cos);
            out.class_units.push(t);
        }
        out.image_unit = u;
        Ok(out)
    }

    /// The gradient with respect to the image embedding of `Σ_k d_logits[k] · logit_k`:
    /// with s the scale, û and t̂_k the unit embeddings and w = s Σ_k d_k t̂_k, it is
    /// `(w − (w·û) û) / |image|` (∂cos_k/∂image = (t̂_k − cos_k û) / |image|).
    pub fn backward(&self, l: &Logits, d_logits: &[f64]) -> Vec<f64> {
        let mut w = vec![0.0; l.image_unit.len()];
        for (g, t) in d_logits.iter().zip(&l.class_units) {
            for (wi, ti) in w.iter_mut().zip(t) {
                *wi += self.logit_scale * g * ti;
            }
        }
        let wu: f64 = w.iter().zip(&l.image_unit).map(|(a, b)| a * b).sum();
        w.iter()
            .zip(&l.image_unit)
            .map(|(wi, ui)| (wi - wu * ui) / l.image_norm)
            .collect()
    }
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

    /// The head's gradient against central differences of its logits (f64 throughout:
    /// step 1e-4 on O(1) values, truncation ~1e-8), and its errors name what is wrong.
    #[test]
    fn head_gradient_matches_finite_differences() {
        let head = Head::new(100.0).unwrap();
        let image = [0.3f32, -1.2, 0.7, 2.0];
        let classes: [&[f32]; 3] = [
            &[1.0, 0.5, -0.4, 0.9],
            &[-0.2, 0.1, 0.8, 0.3],
            &[0.0, 1.0, 0.0, 0.0],
        ];
        let d = [0.7, -0.2, 0.4];
        let l = head.logits(&image, &classes).unwrap();
        assert!((l.logits[2] - 100.0 * cosine_checked(&image, classes[2]).unwrap()).abs() < 1e-12);
        let g = head.backward(&l, &d);
        let f = |x: &[f64]| -> f64 {
            let n = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            classes
                .iter()
                .zip(d)
                .map(|(c, dk)| {
                    let nc = c.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
                    let dot: f64 = x.iter().zip(c.iter()).map(|(a, &b)| a * b as f64).sum();
                    dk * 100.0 * dot / (n * nc)
                })
                .sum()
        };
        let x: Vec<f64> = image.iter().map(|&v| v as f64).collect();
        for i in 0..4 {
            let (mut p, mut m) = (x.clone(), x.clone());
            p[i] += 1e-4;
            m[i] -= 1e-4;
            let fd = (f(&p) - f(&m)) / 2e-4;
            assert!(
                (g[i] - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                "{i}: {} vs {fd}",
                g[i]
            );
        }
        assert!(Head::new(0.0).is_err() && Head::new(f64::NAN).is_err());
        let e = head.logits(&image, &[&[1.0, 2.0]]).unwrap_err().to_string();
        assert!(
            e.contains("text embedding 0 has 2 values") && e.contains("has 4"),
            "{e}"
        );
        let e = head.logits(&[0.0; 4], &classes).unwrap_err().to_string();
        assert!(
            e.starts_with("image embedding") && e.contains("zero"),
            "{e}"
        );
    }
}
