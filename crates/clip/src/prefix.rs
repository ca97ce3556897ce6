//! Many captions through the text tower at once, as a prefix tree of their tokens.
//!
//! The text tower's attention is causal, so the state of token i after any layer depends only
//! on tokens 0..=i: two captions that begin with the same tokens ("a photo of a …") have the
//! same states over that common beginning. Captions are sorted by their token ids and each
//! distinct prefix becomes one node of a tree (one row of the `[nodes, D]` matrices every
//! projection runs on); a node attends to the nodes on its path from the root, which are
//! exactly the tokens before it in each caption through it. Counted in words, the 6,000
//! built-in negatives (`data/captions.txt`) have ~50,000 tokens with their start and end
//! tokens and ~23,000 distinct prefixes, so this does less than half the work of running each
//! caption on its own tokens (timings: BENCHMARKS.md, "Caption pool first use";
//! `examples/bench_clip.rs --pool`), and the products are tall (thousands of rows), which the
//! packed engine wants.
//!
//! Per node and head, the scores are summed over the head's channels in order, one multiply
//! then one add each, and the output over the path in order: the operations
//! `attention::Attention` performs for the same token (its `mm` products, then the same
//! `softmax_rows`), so a caption's embedding does not depend on which other captions share its
//! call (`text::tests`).

use rayon::prelude::*;

use super::attention::softmax_rows;
use super::encoder::EncoderLayer;
use super::layers::add_assign;

/// Most rows (tree nodes) in one pass: bounds the memory of a call with many captions while
/// keeping products tall. A pass holds about ten `[rows, D]` f32 matrices at once (the MLP's
/// `[rows, 4D]` among them): ≈ 20 MiB at D = 512 and 1024 rows, on top of the loaded model.
/// More rows made the caption pool's first use the peak of a default run (2048 rows: ≈ 60
/// MiB more at the peak, no faster); the embeddings do not depend on how the captions are
/// split (`text::tests`).
pub(crate) const MAX_ROWS: usize = 1024;

/// Query rows per parallel task in `attend` (each is a few thousand multiply-adds).
const ROWS_PER_TASK: usize = 16;

/// Captions as a prefix tree: one node per distinct prefix.
#[derive(Debug, Default)]
pub(crate) struct PrefixTree {
    /// Per node: its token id.
    pub tokens: Vec<u32>,
    /// Per node: its position in the captions through it (its depth).
    pub positions: Vec<usize>,
    /// Per node: where its path (root first, itself last, `position + 1` nodes) starts in
    /// `paths`.
    path_start: Vec<usize>,
    paths: Vec<u32>,
}

impl PrefixTree {
    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.tokens.len()
    }

    /// The nodes from the root to `node`, itself last.
    pub fn path(&self, node: usize) -> &[u32] {
        &self.paths[self.path_start[node]..][..self.positions[node] + 1]
    }

    /// A new node `token` under the path `parent` (empty for a root).
    fn push(&mut self, parent: &[u32], token: u32) -> usize {
        let node = self.tokens.len();
        self.tokens.push(token);
        self.positions.push(parent.len());
        self.path_start.push(self.paths.len());
        self.paths.extend_from_slice(parent);
        self.paths.push(node as u32);
        node
    }
}

/// One tree of a `Forest`, and which of the caller's captions end at which of its nodes.
pub(crate) struct Part {
    pub tree: PrefixTree,
    /// `(caption index, node of its last token)`.
    pub ends: Vec<(usize, usize)>,
}

/// The prefix trees of `captions` (each already cut after its pooled token), at most
/// `max_rows` nodes each unless a single caption is longer. Captions are taken in the order of
/// their token ids, so each tree holds a run of neighbours, which share the most.
pub(crate) fn forest(captions: &[&[u32]], max_rows: usize) -> Vec<Part> {
    let mut order: Vec<usize> = (0..captions.len()).collect();
    order.sort_by(|&a, &b| captions[a].cmp(captions[b]));
    let mut parts = Vec::new();
    let mut part = Part {
        tree: PrefixTree::default(),
        ends: Vec::new(),
    };
    // Nodes of the previous caption's tokens in the current tree.
    let mut prev_nodes: Vec<usize> = Vec::new();
    let mut prev: &[u32] = &[];
    for c in order {
        let ids = captions[c];
        let mut common = ids.iter().zip(prev).take_while(|(a, b)| a == b).count();
        if !part.ends.is_empty() && part.tree.len() + (ids.len() - common) > max_rows {
            parts.push(std::mem::replace(
                &mut part,
                Part {
                    tree: PrefixTree::default(),
                    ends: Vec::new(),
                },
            ));
            common = 0;
        }
        prev_nodes.truncate(common);
        for &t in &ids[common..] {
            let parent: Vec<u32> = match prev_nodes.last() {
                Some(&p) => part.tree.path(p).to_vec(),
                None => Vec::new(),
            };
            prev_nodes.push(part.tree.push(&parent, t));
        }
        if let Some(&end) = prev_nodes.last() {
            part.ends.push((c, end));
        }
        prev = ids;
    }
    if !part.ends.is_empty() {
        parts.push(part);
    }
    parts
}

/// Where `attend` reads keys and values: row r's key for channel c at `kv[r·ld + k_at + c]`,
/// its value at `kv[r·ld + v_at + c]` (a stacked `[q | k | v]` or `[k | v]` projection).
pub(crate) struct KeyValues<'a> {
    pub kv: &'a [f32],
    pub ld: usize,
    pub k_at: usize,
    pub v_at: usize,
}

/// Multi-head attention of query rows over their paths in `tree`: `q` holds one already
/// scaled query per row of `nodes` (row stride `q_ld`, channels from 0), and the result is
/// `[nodes.len(), D]`, heads side by side.
pub(crate) fn attend(
    q: (&[f32], usize),
    nodes: &[usize],
    kv: &KeyValues<'_>,
    tree: &PrefixTree,
    heads: usize,
    d: usize,
) -> Vec<f32> {
    let mut ctx = Vec::new();
    attend_into(q, nodes, kv, tree, (heads, d), &mut ctx);
    ctx
}

/// `attend` into `ctx`, its memory reused.
fn attend_into(
    q: (&[f32], usize),
    nodes: &[usize],
    kv: &KeyValues<'_>,
    tree: &PrefixTree,
    (heads, d): (usize, usize),
    ctx: &mut Vec<f32>,
) {
    let (q, q_ld) = q;
    let dh = d / heads;
    ctx.clear();
    ctx.resize(nodes.len() * d, 0.0);
    ctx.par_chunks_mut(d)
        .zip(nodes.par_iter().enumerate())
        .with_min_len(ROWS_PER_TASK)
        .for_each(|(out, (i, &node))| {
            let path = tree.path(node);
            let mut p = vec![0.0f32; path.len()];
            for (head, out) in out.chunks_exact_mut(dh).enumerate() {
                let qh = &q[i * q_ld + head * dh..][..dh];
                // Scores, 16 keys at a time: independent sums, each over the channels in order.
                for (keys, scores) in path.chunks(16).zip(p.chunks_mut(16)) {
                    let mut acc = [0.0f32; 16];
                    for (c, &qc) in qh.iter().enumerate() {
                        for (a, &r) in acc.iter_mut().zip(keys) {
                            *a += qc * kv.kv[r as usize * kv.ld + kv.k_at + head * dh + c];
                        }
                    }
                    scores.copy_from_slice(&acc[..scores.len()]);
                }
                let n = p.len();
                softmax_rows(&mut p, n, n, false);
                out.fill(0.0);
                for (&pj, &r) in p.iter().zip(path) {
                    let v = &kv.kv[r as usize * kv.ld + kv.v_at + head * dh..][..dh];
                    out.iter_mut().zip(v).for_each(|(o, v)| *o += pj * v);
                }
            }
        });
}

/// The buffers of one layer on a tree, kept from layer to layer and tree to tree, so that no
/// product, layer norm or attention faults in fresh pages (`packed::gemm_into_post`).
#[derive(Default)]
pub(crate) struct Scratch {
    n1: Vec<f32>,
    qkv: Vec<f32>,
    ctx: Vec<f32>,
    proj: Vec<f32>,
    n2: Vec<f32>,
    m: Vec<f32>,
}

/// One encoder layer on every node of `tree`, `x: [nodes, D]` updated in place (as
/// `EncoderLayer::forward` on packed sequences), with `scratch`'s buffers.
pub(crate) fn layer_forward(
    layer: &EncoderLayer,
    x: &mut [f32],
    tree: &PrefixTree,
    scratch: &mut Scratch,
) {
    let (d, t, heads) = (layer.ln1.dim(), tree.len(), layer.attn.num_heads);
    let scale = ((d / heads) as f32).powf(-0.5);
    let s = scratch;
    layer.ln1.forward_into(x, &mut s.n1);
    layer.attn.qkv.forward_into(&s.n1, t, None, &mut s.qkv);
    s.qkv
        .par_chunks_mut(3 * d)
        .with_min_len(ROWS_PER_TASK)
        .for_each(|row| row[..d].iter_mut().for_each(|v| *v *= scale));
    let all: Vec<usize> = (0..t).collect();
    let kv = KeyValues {
        kv: &s.qkv,
        ld: 3 * d,
        k_at: d,
        v_at: 2 * d,
    };
    attend_into((&s.qkv, 3 * d), &all, &kv, tree, (heads, d), &mut s.ctx);
    layer.attn.out.forward_into(&s.ctx, t, None, &mut s.proj);
    add_assign(x, &s.proj);
    layer.ln2.forward_into(x, &mut s.n2);
    layer.fc1.forward_into(&s.n2, t, Some(layer.act), &mut s.m);
    layer.fc2.forward_into(&s.m, t, None, &mut s.proj);
    add_assign(x, &s.proj);
}

/// The last layer at the `ends` nodes only (keys and values from every node): `x: [nodes, D]`
/// → `[ends.len(), D]`, as `EncoderLayer::forward_pooled`.
pub(crate) fn layer_forward_ends(
    layer: &EncoderLayer,
    x: &[f32],
    tree: &PrefixTree,
    ends: &[usize],
) -> Vec<f32> {
    let (d, t, heads) = (layer.ln1.dim(), tree.len(), layer.attn.num_heads);
    let scale = ((d / heads) as f32).powf(-0.5);
    let (n1, _) = layer.ln1.forward(x, false);
    let kv = layer.attn.qkv.forward_part(&n1, t, d..3 * d);
    let n1q = gather(&n1, ends, d);
    let mut q = layer.attn.qkv.forward_part(&n1q, ends.len(), 0..d);
    q.iter_mut().for_each(|v| *v *= scale);
    let kv = KeyValues {
        kv: &kv,
        ld: 2 * d,
        k_at: 0,
        v_at: d,
    };
    let ctx = attend((&q, d), ends, &kv, tree, heads, d);
    let mut h = gather(x, ends, d);
    add_assign(&mut h, &layer.attn.out.forward(&ctx, ends.len()));
    let (n2, _) = layer.ln2.forward(&h, false);
    let (m, _) = layer.fc1.forward_act(&n2, ends.len(), layer.act, false);
    add_assign(&mut h, &layer.fc2.forward(&m, ends.len()));
    h
}

/// Rows `rows` of `x: [_, d]`.
pub(crate) fn gather(x: &[f32], rows: &[usize], d: usize) -> Vec<f32> {
    rows.iter()
        .flat_map(|&r| x[r * d..][..d].iter().copied())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_prefixes_are_one_node_and_paths_are_the_prefixes() {
        let caps: Vec<Vec<u32>> = vec![
            vec![9, 1, 2, 8],
            vec![9, 1, 3, 8],
            vec![9, 1, 2, 8],
            vec![9, 1, 2, 5, 8],
            vec![7],
        ];
        let refs: Vec<&[u32]> = caps.iter().map(Vec::as_slice).collect();
        let parts = forest(&refs, 100);
        assert_eq!(parts.len(), 1);
        let Part { tree, ends } = &parts[0];
        // Nodes: 7 | 9 1 2 8 | 5 8 (under 2) | 3 8 (under 1) = 1 + 4 + 2 + 2.
        assert_eq!(tree.len(), 9);
        let mut by_caption = vec![usize::MAX; caps.len()];
        for &(c, n) in ends {
            by_caption[c] = n;
        }
        assert_eq!(
            by_caption[0], by_caption[2],
            "identical captions share their end"
        );
        for (c, ids) in caps.iter().enumerate() {
            let path = tree.path(by_caption[c]);
            let tokens: Vec<u32> = path.iter().map(|&n| tree.tokens[n as usize]).collect();
            assert_eq!(&tokens, ids, "caption {c}");
            for (i, &n) in path.iter().enumerate() {
                assert_eq!(tree.positions[n as usize], i);
            }
        }
    }

    #[test]
    fn forest_splits_at_max_rows_and_keeps_every_caption() {
        let caps: Vec<Vec<u32>> = (0..50u32).map(|i| vec![1, i % 7, i, 2]).collect();
        let refs: Vec<&[u32]> = caps.iter().map(Vec::as_slice).collect();
        let parts = forest(&refs, 20);
        assert!(parts.len() > 1);
        let mut seen: Vec<usize> = parts
            .iter()
            .flat_map(|p| p.ends.iter().map(|e| e.0))
            .collect();
        seen.sort();
        assert_eq!(seen, (0..50).collect::<Vec<_>>());
        for p in &parts {
            assert!(p.tree.len() <= 20, "{}", p.tree.len());
            for &(c, n) in &p.ends {
                let t: Vec<u32> = p
                    .tree
                    .path(n)
                    .iter()
                    .map(|&k| p.tree.tokens[k as usize])
                    .collect();
                assert_eq!(t, caps[c]);
            }
        }
    }
}
