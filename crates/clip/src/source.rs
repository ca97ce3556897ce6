//! Where the towers get their tensors: a checkpoint (safetensors or PyTorch, one file or
//! shards), or random values of the right scale for benchmarks (timings do not depend on values),
//! and `Names`, the tensor-naming helper every model part reads them through.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::cell::RefCell;
use std::fmt::Display;

use super::layers::{LayerNorm, Linear};
use super::packed::Compute;
use super::weights::Checkpoint;
use super::ClipError;

/// Something that hands out named tensors of a given shape.
pub trait TensorSource {
    /// The tensor called `name` (a full checkpoint name such as
    /// `text_model.final_layer_norm.weight`) as f32, checked to have `shape`.
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError>;

    /// Rows `rows` of the tensor `name` (of `shape`, rows along its first dimension), in the
    /// order asked: `[rows.len(), shape[1..]]`. A source that can read a row alone (a
    /// memory-mapped safetensors file) reads only those; this default reads the whole tensor.
    fn rows(&self, name: &str, shape: &[usize], rows: &[u32]) -> Result<Vec<f32>, ClipError> {
        let all = self.tensor(name, shape)?;
        gather_rows(name, &all, shape, rows)
    }
}

/// Rows `rows` of `all`, a tensor `name` of `shape` (rows along the first dimension).
pub(crate) fn gather_rows(
    name: &str,
    all: &[f32],
    shape: &[usize],
    rows: &[u32],
) -> Result<Vec<f32>, ClipError> {
    let len: usize = shape.iter().skip(1).product();
    let mut out = Vec::with_capacity(rows.len() * len);
    for &r in rows {
        let r = row_index(name, shape, r)?;
        out.extend_from_slice(&all[r * len..(r + 1) * len]);
    }
    Ok(out)
}

/// Row `r` of a tensor `name` of `shape`, or the error naming the rows it has.
pub(crate) fn row_index(name: &str, shape: &[usize], r: u32) -> Result<usize, ClipError> {
    let n = shape.first().copied().unwrap_or(1);
    match r as usize {
        r if r < n => Ok(r),
        r => Err(ClipError::Input(format!(
            "{name}: row {r} asked for, the tensor has {n}"
        ))),
    }
}

/// A tensor source seen from inside a module: names are built by pushing path segments, as
/// candle's `VarBuilder::pp` does, so that each model part names its own tensors relative to
/// where it sits (`vb.pp("encoder").pp("layers").pp(3).pp("mlp").pp("fc1").linear(..)` reads
/// `….encoder.layers.3.mlp.fc1.weight` and `.bias`). A model family with other names (SigLIP,
/// EVA-CLIP) changes the segments where its parts are loaded, nothing else.
#[derive(Clone)]
pub(crate) struct Names<'a> {
    src: &'a dyn TensorSource,
    prefix: String,
    /// How the `Linear` layers read here run.
    compute: Compute,
    /// Whether those layers keep what their input backward needs.
    backward: bool,
}

impl<'a> Names<'a> {
    /// The root: names are used as given; `Linear` layers run as `compute` says.
    pub fn root(src: &'a dyn TensorSource, compute: Compute) -> Names<'a> {
        Names {
            src,
            prefix: String::new(),
            compute,
            backward: true,
        }
    }

    /// The same names, with every layer built under them for the forward pass only.
    pub fn forward_only(&self) -> Names<'a> {
        Names {
            backward: false,
            ..self.clone()
        }
    }

    /// One level down: `segment` appended to the prefix (with a dot).
    pub fn pp(&self, segment: impl Display) -> Names<'a> {
        let prefix = if self.prefix.is_empty() {
            segment.to_string()
        } else {
            format!("{}.{segment}", self.prefix)
        };
        Names {
            src: self.src,
            prefix,
            compute: self.compute,
            backward: self.backward,
        }
    }

    /// The full name of `leaf` here.
    pub fn name(&self, leaf: &str) -> String {
        if self.prefix.is_empty() {
            leaf.to_string()
        } else {
            format!("{}.{leaf}", self.prefix)
        }
    }

    /// The tensor `leaf` here, of `shape`.
    pub fn tensor(&self, leaf: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        self.src.tensor(&self.name(leaf), shape)
    }

    /// Rows `rows` of the tensor `leaf` here, of `shape` ([`TensorSource::rows`]).
    pub fn rows(&self, leaf: &str, shape: &[usize], rows: &[u32]) -> Result<Vec<f32>, ClipError> {
        self.src.rows(&self.name(leaf), shape, rows)
    }

    /// `torch.nn.Linear(inp, out, bias)` stored here (`weight` `[out, inp]`, `bias` `[out]`).
    pub fn linear(&self, out: usize, inp: usize, bias: bool) -> Result<Linear, ClipError> {
        let w = self.tensor("weight", &[out, inp])?;
        let b = if bias {
            Some(self.tensor("bias", &[out])?)
        } else {
            None
        };
        Ok(self.linear_from(w, b, inp, out))
    }

    /// A linear layer from weights at hand (`[out, in]`), built with this tree's compute
    /// settings and, unless [`Names::forward_only`], its input backward.
    pub fn linear_from(&self, w: Vec<f32>, b: Option<Vec<f32>>, inp: usize, out: usize) -> Linear {
        Linear::build(w, b, inp, out, &self.compute, self.backward)
    }

    /// `torch.nn.LayerNorm(dim, eps)` stored here (`weight` and `bias`, `[dim]` each).
    pub fn layer_norm(&self, dim: usize, eps: f32) -> Result<LayerNorm, ClipError> {
        Ok(LayerNorm {
            gamma: self.tensor("weight", &[dim])?,
            beta: self.tensor("bias", &[dim])?,
            eps,
        })
    }
}

impl TensorSource for Checkpoint {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        self.get(name, shape)
    }

    fn rows(&self, name: &str, shape: &[usize], rows: &[u32]) -> Result<Vec<f32>, ClipError> {
        Checkpoint::rows(self, name, shape, rows)
    }
}

/// Deterministic random tensors: layer-norm gains 1, biases small, matrices uniform with the
/// variance of a unit-gain initialisation (1 / fan-in), embeddings 0.02-ish.
pub struct RandomSource {
    rng: RefCell<ChaCha8Rng>,
}

impl RandomSource {
    /// Tensors drawn from a ChaCha8 generator seeded with `seed`, in the order they are asked
    /// for (the same model for the same seed).
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Records the names asked for.
    struct Log(RefCell<Vec<String>>);
    impl TensorSource for Log {
        fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
            self.0.borrow_mut().push(name.to_string());
            Ok(vec![0.0; shape.iter().product::<usize>().max(1)])
        }
    }

    #[test]
    fn names_nest_like_checkpoint_keys() {
        let log = Log(RefCell::new(Vec::new()));
        let root = Names::root(&log, Compute::default());
        root.tensor("logit_scale", &[]).unwrap();
        let layer = root.pp("text_model").pp("encoder").pp("layers").pp(3);
        layer.pp("mlp").pp("fc1").linear(4, 2, true).unwrap();
        layer.pp("layer_norm1").layer_norm(2, 1e-5).unwrap();
        root.pp("text_projection").linear(2, 2, false).unwrap();
        assert_eq!(
            *log.0.borrow(),
            [
                "logit_scale",
                "text_model.encoder.layers.3.mlp.fc1.weight",
                "text_model.encoder.layers.3.mlp.fc1.bias",
                "text_model.encoder.layers.3.layer_norm1.weight",
                "text_model.encoder.layers.3.layer_norm1.bias",
                "text_projection.weight",
            ]
        );
    }
}
