//! Text tower, `transformers` modeling_clip.py `CLIPTextTransformer` + `CLIPModel.text_projection`:
//! token + position embeddings → causal pre-norm transformer → final layer norm at the
//! end-of-text token → projection.
//!
//! Attention is causal, so the state at the end-of-text token depends only on the tokens up to
//! it: each caption runs on that prefix alone, and captions are packed one after another into one
//! `[Σ len, D]` matrix (no padding at all), so every projection is one GEMM over all captions.

use super::attention::Segments;
use super::config::TextConfig;
use super::layers::{LayerNorm, Linear};
use super::source::TensorSource;
use super::tower::Tower;
use super::ClipError;

pub struct TextModel {
    pub cfg: TextConfig,
    /// `[vocab, D]`
    token_embedding: Vec<f32>,
    /// `[max_positions, D]`
    position_embedding: Vec<f32>,
    tower: Tower,
    final_ln: LayerNorm,
    /// `[P, D]`, no bias
    projection: Linear,
}

impl TextModel {
    pub fn load(
        src: &dyn TensorSource,
        cfg: &TextConfig,
        proj: usize,
    ) -> Result<TextModel, ClipError> {
        let d = cfg.tower.hidden_size;
        Ok(TextModel {
            cfg: cfg.clone(),
            token_embedding: src.tensor(
                "text_model.embeddings.token_embedding.weight",
                &[cfg.vocab_size, d],
            )?,
            position_embedding: src.tensor(
                "text_model.embeddings.position_embedding.weight",
                &[cfg.max_positions, d],
            )?,
            tower: Tower::load(src, "text_model", &cfg.tower)?,
            final_ln: src.layer_norm("text_model.final_layer_norm", d, cfg.tower.layer_norm_eps)?,
            projection: src.linear("text_projection", proj, d, false)?,
        })
    }

    /// Index of the token whose state is pooled, as `CLIPTextTransformer` picks it: the legacy
    /// `eos_token_id == 2` configs take the largest id (the end-of-text token has the largest
    /// id of the vocabulary), newer ones the first `eos_token_id`; 0 if there is none.
    pub fn pool_index(&self, ids: &[u32]) -> usize {
        if self.cfg.eos_token_id == 2 {
            let max = ids.iter().copied().max().unwrap_or(0);
            ids.iter().position(|&t| t == max).unwrap_or(0)
        } else {
            ids.iter()
                .position(|&t| t as i64 == self.cfg.eos_token_id)
                .unwrap_or(0)
        }
    }

    /// Projected (not normalized) embeddings `[captions][P]` of token-id sequences.
    pub fn forward(&self, captions: &[Vec<u32>]) -> Result<Vec<Vec<f32>>, ClipError> {
        let d = self.cfg.tower.hidden_size;
        let mut spans = Vec::with_capacity(captions.len());
        let mut start = 0;
        for (c, ids) in captions.iter().enumerate() {
            if ids.len() > self.cfg.max_positions {
                return Err(ClipError::Input(format!(
                    "caption {c} has {} tokens, the model's context is {}",
                    ids.len(),
                    self.cfg.max_positions
                )));
            }
            if let Some(&bad) = ids.iter().find(|&&t| t as usize >= self.cfg.vocab_size) {
                return Err(ClipError::Input(format!(
                    "caption {c} has token id {bad}, the vocabulary has {}",
                    self.cfg.vocab_size
                )));
            }
            if ids.is_empty() {
                return Err(ClipError::Input(format!("caption {c} has no tokens")));
            }
            let len = self.pool_index(ids) + 1;
            spans.push((start, len));
            start += len;
        }
        let seg = Segments {
            spans,
            causal: true,
        };
        // x: [Σ len, D] = token embedding + position embedding.
        let mut x = vec![0.0f32; seg.total() * d];
        for (ids, &(s, len)) in captions.iter().zip(&seg.spans) {
            for (i, &t) in ids[..len].iter().enumerate() {
                let row = &mut x[(s + i) * d..(s + i + 1) * d];
                let te = &self.token_embedding[t as usize * d..(t as usize + 1) * d];
                let pe = &self.position_embedding[i * d..(i + 1) * d];
                for ((r, a), b) in row.iter_mut().zip(te).zip(pe) {
                    *r = a + b;
                }
            }
        }
        // Pool at each caption's last token (its end-of-text token); the final layer norm is
        // per token, so only those rows need it.
        let rows: Vec<usize> = seg.spans.iter().map(|&(_, len)| len - 1).collect();
        let (pooled, _) = self.tower.forward_pooled(x, &seg, &rows, false);
        let (pooled, _) = self.final_ln.forward(&pooled, false);
        let out = self.projection.forward(&pooled, captions.len());
        Ok(out
            .chunks_exact(self.projection.out_dim)
            .map(<[f32]>::to_vec)
            .collect())
    }
}
