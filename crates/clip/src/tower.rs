//! A stack of encoder layers read from `encoder.layers.{i}` under a tower (`transformers`
//! modeling_clip.py `CLIPEncoder`), with q/k/v projections stacked into one matrix so a layer's
//! input projection is a single GEMM.

use super::attention::{Attention, Segments};
use super::config::TowerConfig;
use super::encoder::{EncoderLayer, LayerSaved, PooledLayerSaved};
use super::source::Names;
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
    /// The layers under `encoder` (a tower's `encoder`: `layers.{i}.*`).
    pub fn load(encoder: &Names, c: &TowerConfig) -> Result<Tower, ClipError> {
        let d = c.hidden_size;
        let mut layers = Vec::with_capacity(c.num_layers);
        for i in 0..c.num_layers {
            let p = encoder.pp("layers").pp(i);
            let attn = p.pp("self_attn");
            let raw = |name: &str| -> Result<Raw, ClipError> {
                let proj = attn.pp(name);
                Ok(Raw {
                    weight: proj.tensor("weight", &[d, d])?,
                    bias: proj.tensor("bias", &[d])?,
                })
            };
            let (q, k, v) = (raw("q_proj")?, raw("k_proj")?, raw("v_proj")?);
            let qkv = attn.linear_from(
                [q.weight, k.weight, v.weight].concat(),
                Some([q.bias, k.bias, v.bias].concat()),
                d,
                3 * d,
            );
            let mlp = p.pp("mlp");
            layers.push(EncoderLayer {
                ln1: p.pp("layer_norm1").layer_norm(d, c.layer_norm_eps)?,
                attn: Attention {
                    qkv,
                    out: attn.pp("out_proj").linear(d, d, true)?,
                    num_heads: c.num_heads,
                },
                ln2: p.pp("layer_norm2").layer_norm(d, c.layer_norm_eps)?,
                fc1: mlp.pp("fc1").linear(c.intermediate_size, d, true)?,
                fc2: mlp.pp("fc2").linear(d, c.intermediate_size, true)?,
                act: c.act,
            });
        }
        Ok(Tower { layers })
    }

    /// Run the stack on `x: [T, D]` and return the final states of the pooled tokens only
    /// (`rows[s]` within sequence s), `[S, D]`: every layer but the last runs on all tokens, the
    /// last one only produces the pooled rows (its other outputs would be discarded).
    pub fn forward_pooled(
        &self,
        mut x: Vec<f32>,
        seg: &Segments,
        rows: &[usize],
        save: bool,
    ) -> (Vec<f32>, TowerSaved) {
        let mut saved = TowerSaved {
            layers: Vec::new(),
            last: None,
        };
        let Some((last, body)) = self.layers.split_last() else {
            let d = x.len() / seg.total().max(1);
            return (gather(&x, seg, rows, d), saved);
        };
        for l in body {
            if let Some(s) = l.forward(&mut x, seg, save) {
                saved.layers.push(s);
            }
        }
        let (y, s) = last.forward_pooled(&x, seg, rows, save);
        saved.last = s;
        (y, saved)
    }

    // Same signature as `Attention::backward_pooled` (plus `d`): each level of the pooled
    // backward takes the segments, the pooled rows and its own saved state.
    /// Backward of `forward_pooled` (which must have run with `save`): `dy: [S, D]` →
    /// `dx: [T, D]`. `d` is the width, needed only for a tower without layers.
    pub fn backward_pooled(
        &self,
        dy: &[f32],
        seg: &Segments,
        rows: &[usize],
        saved: &TowerSaved,
        d: usize,
    ) -> Vec<f32> {
        let (Some((last, body)), Some(ls)) = (self.layers.split_last(), saved.last.as_ref()) else {
            let mut dx = vec![0.0; seg.total() * d];
            for ((&(start, _), &r), g) in seg.spans.iter().zip(rows).zip(dy.chunks_exact(d)) {
                dx[(start + r) * d..][..d].copy_from_slice(g);
            }
            return dx;
        };
        let mut dx = last.backward_pooled(dy, seg, rows, ls);
        for (l, s) in body.iter().zip(&saved.layers).rev() {
            l.backward(&mut dx, seg, s);
        }
        dx
    }
}

/// Saved activations of a whole tower.
pub struct TowerSaved {
    layers: Vec<LayerSaved>,
    last: Option<PooledLayerSaved>,
}

fn gather(x: &[f32], seg: &Segments, rows: &[usize], d: usize) -> Vec<f32> {
    seg.spans
        .iter()
        .zip(rows)
        .flat_map(|(&(start, _), &r)| x[(start + r) * d..][..d].iter().copied())
        .collect()
}
