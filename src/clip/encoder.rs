//! One pre-norm transformer layer, `transformers` modeling_clip.py `CLIPEncoderLayer` + `CLIPMLP`:
//! `h = x + attn(ln1(x))`, `y = h + fc2(act(fc1(ln2(h))))`. Shared by both towers.

use super::attention::{Attention, AttnSaved, Segments};
use super::config::Activation;
use super::layers::{activation_backward, activation_forward, LayerNorm, Linear, LnSaved};

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
        x.iter_mut().zip(&a).for_each(|(x, a)| *x += a);
        let (n2, s2) = self.ln2.forward(x, save);
        let mut m = self.fc1.forward(&n2, t);
        let pre_act = save.then(|| m.clone());
        activation_forward(self.act, &mut m);
        let o = self.fc2.forward(&m, t);
        x.iter_mut().zip(&o).for_each(|(x, o)| *x += o);
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
        let mut dm = self.fc2.backward(dy, t);
        activation_backward(self.act, &s.pre_act, &mut dm);
        let dn2 = self.fc1.backward(&dm, t);
        let dh = self.ln2.backward(&dn2, &s.ln2);
        dy.iter_mut().zip(&dh).for_each(|(g, d)| *g += d);
        let dn1 = self.attn.backward(dy, seg, &s.attn);
        let dx = self.ln1.backward(&dn1, &s.ln1);
        dy.iter_mut().zip(&dx).for_each(|(g, d)| *g += d);
    }
}
