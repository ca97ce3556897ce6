//! Where the towers get their tensors: a checkpoint (safetensors or PyTorch, one file or
//! shards), or random values of the right scale for benchmarks (timings do not depend on values).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::cell::RefCell;

use super::layers::{LayerNorm, Linear};
use super::weights::Checkpoint;
use super::ClipError;

/// Something that hands out named tensors of a given shape.
pub trait TensorSource {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError>;

    fn linear(
        &self,
        prefix: &str,
        out: usize,
        inp: usize,
        bias: bool,
    ) -> Result<Linear, ClipError> {
        let w = self.tensor(&format!("{prefix}.weight"), &[out, inp])?;
        let b = if bias {
            Some(self.tensor(&format!("{prefix}.bias"), &[out])?)
        } else {
            None
        };
        Ok(Linear::new(w, b, inp, out))
    }

    fn layer_norm(&self, prefix: &str, dim: usize, eps: f32) -> Result<LayerNorm, ClipError> {
        Ok(LayerNorm {
            gamma: self.tensor(&format!("{prefix}.weight"), &[dim])?,
            beta: self.tensor(&format!("{prefix}.bias"), &[dim])?,
            eps,
        })
    }
}

impl TensorSource for Checkpoint {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        self.get(name, shape)
    }
}

/// Deterministic random tensors: layer-norm gains 1, biases small, matrices uniform with the
/// variance of a unit-gain initialisation (1 / fan-in), embeddings 0.02-ish.
pub struct RandomSource {
    rng: RefCell<ChaCha8Rng>,
}

impl RandomSource {
    pub fn new(seed: u64) -> RandomSource {
        RandomSource {
            rng: RefCell::new(ChaCha8Rng::seed_from_u64(seed)),
        }
    }
}

impl TensorSource for RandomSource {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        let n: usize = shape.iter().product::<usize>().max(1);
        let mut rng = self.rng.borrow_mut();
        let is_norm = name.contains("layer_norm") || name.contains("layrnorm");
        let v = if is_norm && name.ends_with("weight") {
            vec![1.0; n]
        } else if name == "logit_scale" {
            vec![100f32.ln()]
        } else {
            let half_width = if shape.len() >= 2 && !name.contains("embedding") {
                (3.0 / (n / shape[0]) as f32).sqrt()
            } else {
                0.05
            };
            (0..n)
                .map(|_| rng.random_range(-half_width..half_width))
                .collect()
        };
        Ok(v)
    }
}
