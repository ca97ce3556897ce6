//! Text tower, `transformers` modeling_clip.py `CLIPTextTransformer` + `CLIPModel.text_projection`:
//! token + position embeddings → causal pre-norm transformer → final layer norm at the
//! end-of-text token → projection.
//!
//! Attention is causal, so the state at the end-of-text token depends only on the tokens up to
//! it: each caption runs on that prefix alone (no padding), and the captions of a call share
//! the states of their common beginnings: they run as a prefix tree of tokens (`prefix`), every
//! projection one GEMM over all distinct prefixes.

use std::collections::HashMap;

use super::config::TextConfig;
use super::layers::{LayerNorm, Linear};
use super::prefix;
use super::source::Names;
use super::tower::Tower;
use super::ClipError;

/// The text tower's weights but for its token table (see [`TokenTable`]).
pub struct TextModel {
    pub cfg: TextConfig,
    /// `[max_positions, D]`
    position_embedding: Vec<f32>,
    tower: Tower,
    final_ln: LayerNorm,
    /// `[P, D]`, no bias
    projection: Linear,
}

impl TextModel {
    /// The text tower under `root` (the checkpoint's top level: `text_model.*` and
    /// `text_projection`), projecting to `proj` dimensions.
    pub fn load(root: &Names, cfg: &TextConfig, proj: usize) -> Result<TextModel, ClipError> {
        // The text tower only runs forward: its layers keep no backward copy.
        let root = &root.forward_only();
        let d = cfg.tower.hidden_size;
        let model = root.pp("text_model");
        let emb = model.pp("embeddings");
        Ok(TextModel {
            cfg: cfg.clone(),
            position_embedding: emb
                .pp("position_embedding")
                .tensor("weight", &[cfg.max_positions, d])?,
            tower: Tower::load(&model.pp("encoder"), &cfg.tower)?,
            final_ln: model
                .pp("final_layer_norm")
                .layer_norm(d, cfg.tower.layer_norm_eps)?,
            projection: root.pp("text_projection").linear(proj, d, false)?,
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

    /// Each caption's tokens up to its pooled token, checked against the model.
    fn pooled_prefixes<'a>(&self, captions: &'a [Vec<u32>]) -> Result<Vec<&'a [u32]>, ClipError> {
        captions
            .iter()
            .enumerate()
            .map(|(c, ids)| {
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
                Ok(&ids[..self.pool_index(ids) + 1])
            })
            .collect()
    }

    /// Token + position embedding of the rows `(token, position)`: `[rows, D]`.
    fn embed(
        &self,
        tokens: &TokenTable,
        rows: impl ExactSizeIterator<Item = (u32, usize)>,
    ) -> Vec<f32> {
        let d = self.cfg.tower.hidden_size;
        let mut x = vec![0.0f32; rows.len() * d];
        for (row, (t, i)) in x.chunks_exact_mut(d).zip(rows) {
            let te = tokens.row(t);
            let pe = &self.position_embedding[i * d..(i + 1) * d];
            for ((r, a), b) in row.iter_mut().zip(te).zip(pe) {
                *r = a + b;
            }
        }
        x
    }

    /// Projected (not normalized) embeddings `[captions][P]` of token-id sequences.
    ///
    /// The captions run as prefix trees of at most `prefix::MAX_ROWS` nodes (`prefix`), so
    /// any number of them fits in bounded memory and common beginnings are computed once; a
    /// caption's embedding is the same whichever captions share the call (tested bit for bit
    /// with the packed engine in `tests`).
    /// `tokens` holds at least the rows of the ids in `captions`.
    pub fn forward(
        &self,
        captions: &[Vec<u32>],
        tokens: &TokenTable,
    ) -> Result<Vec<Vec<f32>>, ClipError> {
        let prefixes = self.pooled_prefixes(captions)?;
        let p = self.projection.out_dim;
        let mut out = vec![Vec::new(); captions.len()];
        let mut scratch = prefix::Scratch::default();
        for part in prefix::forest(&prefixes, prefix::MAX_ROWS) {
            let tree = &part.tree;
            let mut x = self.embed(
                tokens,
                tree.tokens
                    .iter()
                    .copied()
                    .zip(tree.positions.iter().copied()),
            );
            let ends: Vec<usize> = part.ends.iter().map(|&(_, n)| n).collect();
            let pooled = match self.tower.layers.split_last() {
                Some((last, body)) => {
                    for l in body {
                        prefix::layer_forward(l, &mut x, tree, &mut scratch);
                    }
                    prefix::layer_forward_ends(last, &x, tree, &ends)
                }
                None => prefix::gather(&x, &ends, self.cfg.tower.hidden_size),
            };
            // The final layer norm is per token, so only the pooled rows need it.
            let (pooled, _) = self.final_ln.forward(&pooled, false);
            let emb = self.projection.forward(&pooled, ends.len());
            for (&(c, _), e) in part.ends.iter().zip(emb.chunks_exact(p)) {
                out[c] = e.to_vec();
            }
        }
        Ok(out)
    }

    /// The path `forward` replaced: captions packed one after another (`Segments`), each on
    /// its own tokens up to the pooled one, or on all of its tokens with `full` (padding
    /// included: what the causal mask makes irrelevant). The reference of the tests.
    #[cfg(test)]
    fn forward_segments(
        &self,
        captions: &[Vec<u32>],
        tokens: &TokenTable,
        full: bool,
    ) -> Vec<Vec<f32>> {
        use super::attention::Segments;
        let prefixes = self.pooled_prefixes(captions).expect("valid captions");
        let mut spans = Vec::new();
        let mut start = 0;
        for (ids, pre) in captions.iter().zip(&prefixes) {
            let len = if full { ids.len() } else { pre.len() };
            spans.push((start, len));
            start += len;
        }
        let seg = Segments {
            spans,
            causal: true,
        };
        let x = self.embed(
            tokens,
            captions
                .iter()
                .zip(&seg.spans)
                .flat_map(|(ids, &(_, len))| ids[..len].iter().copied().zip(0..len))
                .collect::<Vec<_>>()
                .into_iter(),
        );
        let rows: Vec<usize> = prefixes.iter().map(|p| p.len() - 1).collect();
        let (pooled, _) = self.tower.forward_pooled(x, &seg, &rows, false);
        let (pooled, _) = self.final_ln.forward(&pooled, false);
        let out = self.projection.forward(&pooled, captions.len());
        out.chunks_exact(self.projection.out_dim)
            .map(<[f32]>::to_vec)
            .collect()
    }
}

/// Rows of the token embedding `[vocab, D]` (`text_model.embeddings.token_embedding`): the
/// whole table, or the rows of the ids one call uses. The table is the text tower's largest
/// tensor (25 M of ViT-B/32's 63 M text weights) and a call uses a few thousand of its rows
/// at most, so a tower built from a checkpoint reads them from the file for each call.
pub enum TokenTable {
    /// Every row: `[vocab, D]`.
    Whole { d: usize, rows: Vec<f32> },
    /// The rows of some ids: `rows[index[id]]`.
    Some {
        d: usize,
        index: HashMap<u32, usize>,
        rows: Vec<f32>,
    },
}

impl TokenTable {
    /// The whole table of the model under `root` (the checkpoint's top level).
    pub fn whole(root: &Names, cfg: &TextConfig) -> Result<TokenTable, ClipError> {
        let d = cfg.tower.hidden_size;
        let rows = Self::names(root).tensor("weight", &[cfg.vocab_size, d])?;
        Ok(TokenTable::Whole { d, rows })
    }

    /// The rows of the ids in `captions` that the vocabulary has (others are the forward's
    /// to reject); no ids: only the table's presence and shape are checked.
    pub fn for_ids(
        root: &Names,
        cfg: &TextConfig,
        captions: &[Vec<u32>],
    ) -> Result<TokenTable, ClipError> {
        let d = cfg.tower.hidden_size;
        let mut ids: Vec<u32> = captions
            .iter()
            .flatten()
            .copied()
            .filter(|&t| (t as usize) < cfg.vocab_size)
            .collect();
        ids.sort_unstable();
        ids.dedup();
        let rows = Self::names(root).rows("weight", &[cfg.vocab_size, d], &ids)?;
        let index = ids.iter().enumerate().map(|(i, &t)| (t, i)).collect();
        Ok(TokenTable::Some { d, index, rows })
    }

    fn names<'a>(root: &Names<'a>) -> Names<'a> {
        root.pp("text_model").pp("embeddings").pp("token_embedding")
    }

    /// The embedding of token `t` (which the table must hold: the forward checked the ids
    /// against the vocabulary, and `for_ids` read all of those).
    fn row(&self, t: u32) -> &[f32] {
        let (d, r) = match self {
            TokenTable::Whole { d, .. } => (*d, t as usize),
            TokenTable::Some { d, index, .. } => (*d, index[&t]),
        };
        let (TokenTable::Whole { rows, .. } | TokenTable::Some { rows, .. }) = self;
        &rows[r * d..(r + 1) * d]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Activation, TowerConfig};
    use crate::packed::{Compute, Engine, Kernel};
    use crate::source::{Names, RandomSource};

    /// A small random text tower (3 layers, 4 heads of 8) with CLIP's layout: the end-of-text
    /// token is the largest id (legacy `eos_token_id = 2` pooling).
    fn model(compute: Compute) -> (TextModel, TokenTable) {
        let cfg = TextConfig {
            tower: TowerConfig {
                hidden_size: 32,
                intermediate_size: 64,
                num_layers: 3,
                num_heads: 4,
                act: Activation::QuickGelu,
                layer_norm_eps: 1e-5,
            },
            vocab_size: 60,
            max_positions: 24,
            eos_token_id: 2,
        };
        let src = RandomSource::new(11);
        let root = Names::root(&src, compute);
        let m = TextModel::load(&root, &cfg, 16).unwrap();
        (m, TokenTable::whole(&root, &cfg).unwrap())
    }

    const SOT: u32 = 57;
    const EOT: u32 = 59;

    /// Captions with shared beginnings, a duplicate, one that is a prefix of another up to
    /// its end token, and a lone start-and-end.
    fn captions() -> Vec<Vec<u32>> {
        let words: [&[u32]; 9] = [
            &[5, 6, 7],
            &[5, 6, 8, 9],
            &[5, 6, 7],
            &[5, 6, 7, 1, 2, 3, 4, 10, 11, 12],
            &[20],
            &[],
            &[5, 30, 31],
            &[40, 6, 7],
            &[5, 6],
        ];
        words
            .iter()
            .map(|w| [&[SOT][..], w, &[EOT]].concat())
            .collect()
    }

    fn max_rel(a: &[f32], b: &[f32]) -> f32 {
        let n = b.iter().map(|v| v * v).sum::<f32>().sqrt();
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
            / n
    }

    /// The prefix-tree path against the path it replaced (each caption on its own tokens,
    /// packed), with each engine this CPU has: bit for bit with the packed engine's f32
    /// kernels (the same operations on every row), to f32 round-off with the `gemm` crate
    /// (its blocking may depend on the matrix height).
    #[test]
    fn prefix_tree_equals_per_caption_path() {
        let caps = captions();
        let mut kernels: Vec<Option<Kernel>> = vec![None];
        kernels.extend(
            [Kernel::Portable, Kernel::Avx2Fma, Kernel::Avx512F]
                .into_iter()
                .filter(|k| k.available())
                .map(Some),
        );
        for k in kernels {
            let (m, t) = match k {
                Some(k) => model(Compute::default().with_kernel(k).unwrap()),
                None => model(Compute::default().with_engine(Engine::Crate)),
            };
            let tree = m.forward(&caps, &t).unwrap();
            let alone: Vec<Vec<f32>> = caps
                .iter()
                .map(|c| {
                    m.forward_segments(std::slice::from_ref(c), &t, false)
                        .remove(0)
                })
                .collect();
            let packed = m.forward_segments(&caps, &t, false);
            for (c, ((t, a), p)) in tree.iter().zip(&alone).zip(&packed).enumerate() {
                if k.is_some() {
                    assert_eq!(t, a, "{k:?} caption {c}: tree vs alone");
                    assert_eq!(t, p, "{k:?} caption {c}: tree vs packed");
                } else {
                    assert!(max_rel(t, a) < 1e-5, "crate caption {c}: {}", max_rel(t, a));
                }
            }
            // Splitting into trees of a few rows changes nothing either.
            let prefixes = m.pooled_prefixes(&caps).unwrap();
            assert!(prefix::forest(&prefixes, 8).len() > 2);
            assert_eq!(tree[0], tree[2], "identical captions");
        }
    }

    /// What the causal mask implies: running a caption padded to the full context (tokens
    /// after its end-of-text token included, as a padded batch would) gives the same pooled
    /// embedding as running it only up to that token (to f32 round-off: the padded rows change
    /// the products' heights, not the values of the pooled row's inputs).
    #[test]
    fn tokens_after_the_end_token_do_not_matter() {
        let (m, t) = model(Compute::default());
        let caps: Vec<Vec<u32>> = captions()
            .into_iter()
            .map(|mut c| {
                // Pad with the end token (as CLIP's tokenizer pads) and other ids.
                let mut k = 0;
                while c.len() < 24 {
                    c.push(if k % 2 == 0 { EOT } else { 3 + k as u32 % 9 });
                    k += 1;
                }
                c
            })
            .collect();
        let full = m.forward_segments(&caps, &t, true);
        let cut = m.forward(&caps, &t).unwrap();
        for (c, (f, t)) in full.iter().zip(&cut).enumerate() {
            assert!(max_rel(f, t) < 1e-6, "caption {c}: {}", max_rel(f, t));
        }
        // And the padded tokens are really there: the padded run differs without the cut.
        assert_ne!(m.pool_index(&caps[0]), caps[0].len() - 1);
    }
}
