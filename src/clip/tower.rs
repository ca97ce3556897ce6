//! A stack of encoder layers read from `{prefix}.encoder.layers.{i}` (`transformers`
//! modeling_clip.py `CLIPEncoder`), with q/k/v projections stacked into one matrix so a layer's
//! input projection is a single GEMM.

use super::attention::{Attention, Segments};
use super::config::TowerConfig;
use super::encoder::{EncoderLayer, LayerSaved};
use super::layers::Linear;
use super::source::TensorSource;
use super::ClipError;

/// A projection's checkpoint tensors before stacking.
struct Raw {
    weight: Vec<f32>,
    bias: Vec<f32>,
}

pub struct Tower {
    pub layers: Vec<EncoderLayer>,
}

impl Tower {
    pub fn load(src: &dyn TensorSource, prefix: &str, c: &TowerConfig) -> Result<Tower, ClipError> {
        let d = c.hidden_size;
        let mut layers = Vec::with_capacity(c.num_layers);
        for i in 0..c.num_layers {
            let p = format!("{prefix}.encoder.layers.{i}");
            let raw = |name: &str| -> Result<Raw, ClipError> {
                let pre = format!("{p}.self_attn.{name}");
                Ok(Raw {
                    weight: src.tensor(&format!("{pre}.weight"), &[d, d])?,
                    bias: src.tensor(&format!("{pre}.bias"), &[d])?,
                })
            };
            let (q, k, v) = (raw("q_proj")?, raw("k_proj")?, raw("v_proj")?);
            let qkv = Linear::new(
                [q.weight, k.weight, v.weight].concat(),
                Some([q.bias, k.bias, v.bias].concat()),
                d,
                3 * d,
            );
            layers.push(EncoderLayer {
                ln1: src.layer_norm(&format!("{p}.layer_norm1"), d, c.layer_norm_eps)?,
                attn: Attention {
                    qkv,
                    out: src.linear(&format!("{p}.self_attn.out_proj"), d, d, true)?,
                    num_heads: c.num_heads,
                },
                ln2: src.layer_norm(&format!("{p}.layer_norm2"), d, c.layer_norm_eps)?,
                fc1: src.linear(&format!("{p}.mlp.fc1"), c.intermediate_size, d, true)?,
                fc2: src.linear(&format!("{p}.mlp.fc2"), d, c.intermediate_size, true)?,
                act: c.act,
            });
        }
        Ok(Tower { layers })
    }

    /// `x: [T, D]` in place; returns per-layer saved activations when `save`.
    pub fn forward(&self, x: &mut [f32], seg: &Segments, save: bool) -> Vec<LayerSaved> {
        let mut saved = Vec::new();
        for l in &self.layers {
            if let Some(s) = l.forward(x, seg, save) {
                saved.push(s);
            }
        }
        saved
    }

    /// `dy: [T, D]` at the output becomes the gradient at the input, in place.
    pub fn backward(&self, dy: &mut [f32], seg: &Segments, saved: &[LayerSaved]) {
        for (l, s) in self.layers.iter().zip(saved).rev() {
            l.backward(dy, seg, s);
        }
    }
}
