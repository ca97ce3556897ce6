//! One pre-norm transformer layer, `transformers` modeling_clip.py `CLIPEncoderLayer` + `CLIPMLP`:
//! `h = x + attn(ln1(x))`, `y = h + fc2(act(fc1(ln2(h))))`. Shared by both towers.

use super::attention::{Attention, AttnSaved, PooledAttnSaved, Segments};
use super::config::Activation;
use super::layers::{add_assign, LayerNorm, Linear, LnSaved};

pub struct EncoderLayer {
    pub ln1: LayerNorm,
    pub attn: Attention,
    pub ln2: LayerNorm,
    pub fc1: Linear,
    pub fc2: Linear,
    pub act: Activation,
}

/// What backward needs from one layer (nothing of the residual stream itself).
pub struct LayerSaved {
    ln1: LnSaved,
    attn: AttnSaved,
    ln2: LnSaved,
    /// fc1 output before the activation, `[T, intermediate]`.
    pre_act: Vec<f32>,
}

impl EncoderLayer {
    /// `x: [T, D]` is updated in place to the layer's output.
    pub fn forward(&self, x: &mut [f32], seg: &Segments, save: bool) -> Option<LayerSaved> {
        let t = seg.total();
        let (n1, s1) = self.ln1.forward(x, save);
        let (a, sa) = self.attn.forward(&n1, seg, save);
        add_assign(x, &a);
        let (n2, s2) = self.ln2.forward(x, save);
        let (m, pre_act) = self.mlp_hidden(&n2, t, save);
        let o = self.fc2.forward(&m, t);
        add_assign(x, &o);
        Some(LayerSaved {
            ln1: s1?,
            attn: sa?,
            ln2: s2?,
            pre_act: pre_act?,
        })
    }

    /// `dy: [T, D]`, the gradient at the layer's output, becomes the gradient at its input.
    pub fn backward(&self, dy: &mut [f32], seg: &Segments, s: &LayerSaved) {
        let t = seg.total();
        let dm = self.fc2.backward_act(dy, t, self.act, &s.pre_act);
        let dn2 = self.fc1.backward(&dm, t);
        let dh = self.ln2.backward(&dn2, &s.ln2);
        add_assign(dy, &dh);
        let dn1 = self.attn.backward(dy, seg, &s.attn);
        let dx = self.ln1.backward(&dn1, &s.ln1);
        add_assign(dy, &dx);
    }

    /// `act(fc1(n2))`, and fc1's output itself when `save` (for the backward pass).
    fn mlp_hidden(&self, n2: &[f32], rows: usize, save: bool) -> (Vec<f32>, Option<Vec<f32>>) {
        self.fc1.forward_act(n2, rows, self.act, save)
    }

    // Same signature as `Attention::forward_pooled` and the tower's: every level of the pooled
    // path takes the segments and the pooled rows; each does its own level's work.
    /// The layer's output at one token per sequence only (`rows[s]` within sequence s):
    /// `x: [T, D]` → `[S, D]`. Exact for a last layer whose other outputs are discarded.
    pub fn forward_pooled(
        &self,
        x: &[f32],
        seg: &Segments,
        rows: &[usize],
        save: bool,
    ) -> (Vec<f32>, Option<PooledLayerSaved>) {
        let d = self.ln1.dim();
        let ns = seg.spans.len();
        let (n1, s1) = self.ln1.forward(x, save);
        let (a, sa) = self.attn.forward_pooled(&n1, seg, rows, save);
        let mut h: Vec<f32> = seg
            .spans
            .iter()
            .zip(rows)
            .flat_map(|(&(start, _), &r)| x[(start + r) * d..][..d].iter().copied())
            .collect();
        h.iter_mut().zip(&a).for_each(|(x, a)| *x += a);
        let (n2, s2) = self.ln2.forward(&h, save);
        let (m, pre_act) = self.mlp_hidden(&n2, ns, save);
        let o = self.fc2.forward(&m, ns);
        h.iter_mut().zip(&o).for_each(|(x, o)| *x += o);
        let saved = (|| {
            Some(PooledLayerSaved {
                ln1: s1?,
                attn: sa?,
                ln2: s2?,
                pre_act: pre_act?,
            })
        })();
        (h, saved)
    }

    /// Backward of `forward_pooled`: `dy: [S, D]` → `dx: [T, D]`.
    pub fn backward_pooled(
        &self,
        dy: &[f32],
        seg: &Segments,
        rows: &[usize],
        s: &PooledLayerSaved,
    ) -> Vec<f32> {
        let d = self.ln1.dim();
        let ns = seg.spans.len();
        let dm = self.fc2.backward_act(dy, ns, self.act, &s.pre_act);
        let dn2 = self.fc1.backward(&dm, ns);
        let mut dh = self.ln2.backward(&dn2, &s.ln2);
        dh.iter_mut().zip(dy).for_each(|(g, d)| *g += d);
        let dn1 = self.attn.backward_pooled(&dh, seg, rows, &s.attn);
        let mut dx = self.ln1.backward(&dn1, &s.ln1);
        // The residual carries dh straight to the pooled rows.
        for ((&(start, _), &r), g) in seg.spans.iter().zip(rows).zip(dh.chunks_exact(d)) {
            dx[(start + r) * d..][..d]
                .iter_mut()
                .zip(g)
                .for_each(|(a, b)| *a += b);
        }
        dx
    }
}

/// What `backward_pooled` needs from a pooled last layer.
pub struct PooledLayerSaved {
    ln1: LnSaved,
    attn: PooledAttnSaved,
    ln2: LnSaved,
    pre_act: Vec<f32>,
}
