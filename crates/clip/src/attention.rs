//! Multi-head self-attention, `transformers` modeling_clip.py `CLIPAttention`, forward and
//! input backward.
//!
//! Many sequences are packed into one `[tokens, D]` matrix (three 50-token views, or captions
//! of different lengths one after another), so the projections run as single large GEMMs and no
//! padding is ever computed; only the score/softmax/value step works per (sequence, head).

use rayon::prelude::*;

use super::layers::{fast_exp, Linear};

mod mm;

/// Probability rows are stored with this many columns, zero past the sequence length: the
/// per-head products then run on whole 16-lane chunks (`mm`).
fn padded(len: usize) -> usize {
    len.next_multiple_of(16)
}

/// Rows `0 .. len` of `x` (stride `ld`, `dh` wide) transposed into `[dh][lp]`, zero past len.
fn transpose_padded(x: &[f32], ld: usize, len: usize, dh: usize, lp: usize) -> Vec<f32> {
    let mut t = vec![0.0f32; dh * lp];
    for j in 0..len {
        for (c, &v) in x[j * ld..][..dh].iter().enumerate() {
            t[c * lp + j] = v;
        }
    }
    t
}

/// Where each packed sequence lives: rows `start .. start + len`.
#[derive(Clone, Debug)]
pub struct Segments {
    pub spans: Vec<(usize, usize)>,
    /// Causal mask (text tower): token i attends to tokens 0..=i only.
    pub causal: bool,
}

impl Segments {
    /// `count` sequences of `len` tokens each.
    pub fn uniform(count: usize, len: usize, causal: bool) -> Segments {
        Segments {
            spans: (0..count).map(|s| (s * len, len)).collect(),
            causal,
        }
    }
    pub fn total(&self) -> usize {
        self.spans.last().map_or(0, |&(s, l)| s + l)
    }

    /// For each token row: its sequence and position in it (`None` in a gap between spans).
    fn owners(&self) -> Vec<Option<(usize, usize)>> {
        let mut o = vec![None; self.total()];
        for (sq, &(start, len)) in self.spans.iter().enumerate() {
            for i in 0..len {
                o[start + i] = Some((sq, i));
            }
        }
        o
    }
}

/// Rows per parallel task in the scatter loops below (each row is D..3D floats).
const ROWS_PER_TASK: usize = 8;

pub struct Attention {
    /// q, k and v projections stacked: weight `[3D, D]`, bias `[3D]`, rows q then k then v.
    pub qkv: Linear,
    pub out: Linear,
    pub num_heads: usize,
}

/// Activations attention backward needs.
pub struct AttnSaved {
    /// `[T, 3D]`: scaled q, k, v for every token.
    qkv: Vec<f32>,
    /// Softmax probabilities, one `[len, padded(len)]` block per (sequence, head),
    /// sequence-major, zero past column len.
    probs: Vec<Vec<f32>>,
}

impl Attention {
    fn dims(&self) -> (usize, usize, f32) {
        let d = self.out.out_dim;
        let dh = d / self.num_heads;
        (d, dh, (dh as f32).powf(-0.5))
    }

    /// `x: [T, D]` → `[T, D]`.
    pub fn forward(&self, x: &[f32], seg: &Segments, save: bool) -> (Vec<f32>, Option<AttnSaved>) {
        let (d, dh, scale) = self.dims();
        let t = seg.total();
        // qkv: [T, 3D]; q is scaled by dh^-1/2 right after its projection, as in CLIPAttention.
        let mut qkv = self.qkv.forward(x, t);
        qkv.par_chunks_mut(3 * d)
            .with_min_len(ROWS_PER_TASK)
            .for_each(|row| row[..d].iter_mut().for_each(|v| *v *= scale));
        let h = self.num_heads;
        // One task per (sequence, head): P = softmax(Q Kᵀ + mask), O = P V.
        let results: Vec<(Vec<f32>, Vec<f32>)> = (0..seg.spans.len() * h)
            .into_par_iter()
            .map(|task| {
                let (start, len) = seg.spans[task / h];
                let head = task % h;
                let base = &qkv[start * 3 * d..(start + len) * 3 * d];
                let (q, k, v) = (
                    &base[head * dh..],
                    &base[d + head * dh..],
                    &base[2 * d + head * dh..],
                );
                let lp = padded(len);
                let kt = transpose_padded(k, 3 * d, len, dh, lp);
                let mut p = vec![0.0f32; len * lp];
                mm::mm(
                    &mut p,
                    lp,
                    mm::Lhs {
                        data: q,
                        row: 3 * d,
                        col: 1,
                    },
                    mm::Rhs { data: &kt, ld: lp },
                    len,
                    lp,
                    dh,
                );
                softmax_rows(&mut p, lp, len, seg.causal);
                let mut o = vec![0.0f32; len * dh];
                mm::mm(
                    &mut o,
                    dh,
                    mm::Lhs {
                        data: &p,
                        row: lp,
                        col: 1,
                    },
                    mm::Rhs { data: v, ld: 3 * d },
                    len,
                    dh,
                    len,
                );
                (p, o)
            })
            .collect();
        // ctx: [T, D], heads side by side, gathered row by row in parallel.
        let mut ctx = vec![0.0f32; t * d];
        let owners = seg.owners();
        ctx.par_chunks_mut(d)
            .zip(&owners)
            .with_min_len(ROWS_PER_TASK)
            .for_each(|(dst, owner)| {
                if let Some((sq, i)) = *owner {
                    for (head, dst) in dst.chunks_exact_mut(dh).enumerate() {
                        dst.copy_from_slice(&results[sq * h + head].1[i * dh..][..dh]);
                    }
                }
            });
        let y = self.out.forward(&ctx, t);
        let saved = save.then(|| AttnSaved {
            qkv,
            probs: results.into_iter().map(|(p, _)| p).collect(),
        });
        (y, saved)
    }

    /// `dy: [T, D]` → `dx: [T, D]`.
    pub fn backward(&self, dy: &[f32], seg: &Segments, s: &AttnSaved) -> Vec<f32> {
        let (d, dh, scale) = self.dims();
        let t = seg.total();
        let h = self.num_heads;
        let dctx = self.out.backward(dy, t);
        // Per (sequence, head), with S = Q Kᵀ, P = softmax(S), O = P V:
        //   dP = dO Vᵀ, dV = Pᵀ dO, dS = P ⊙ (dP − rowsum(dP ⊙ P)), dQ = dS K, dK = dSᵀ Q.
        let results: Vec<Vec<f32>> = (0..seg.spans.len() * h)
            .into_par_iter()
            .map(|task| {
                let (start, len) = seg.spans[task / h];
                let head = task % h;
                let base = &s.qkv[start * 3 * d..(start + len) * 3 * d];
                let (q, k, v) = (
                    &base[head * dh..],
                    &base[d + head * dh..],
                    &base[2 * d + head * dh..],
                );
                let dout = &dctx[start * d + head * dh..];
                let p = &s.probs[task];
                let lp = padded(len);
                let vt = transpose_padded(v, 3 * d, len, dh, lp);
                let mut dp = vec![0.0f32; len * lp];
                mm::mm(
                    &mut dp,
                    lp,
                    mm::Lhs {
                        data: dout,
                        row: d,
                        col: 1,
                    },
                    mm::Rhs { data: &vt, ld: lp },
                    len,
                    lp,
                    dh,
                );
                // Padding columns: p = 0 there, so dS = 0 too.
                for (dr, pr) in dp.chunks_exact_mut(lp).zip(p.chunks_exact(lp)) {
                    let dot: f32 = dr[..len].iter().zip(&pr[..len]).map(|(a, b)| a * b).sum();
                    dr.iter_mut()
                        .zip(pr)
                        .for_each(|(a, &b)| *a = b * (*a - dot));
                }
                // dqkv block for this head: [len, 3 dh] = (dQ | dK | dV); dK and dV read dS
                // and P transposed through their strides.
                let mut g = vec![0.0f32; len * 3 * dh];
                mm::mm(
                    &mut g,
                    3 * dh,
                    mm::Lhs {
                        data: &dp,
                        row: lp,
                        col: 1,
                    },
                    mm::Rhs { data: k, ld: 3 * d },
                    len,
                    dh,
                    len,
                );
                mm::mm(
                    &mut g[dh..],
                    3 * dh,
                    mm::Lhs {
                        data: &dp,
                        row: 1,
                        col: lp,
                    },
                    mm::Rhs { data: q, ld: 3 * d },
                    len,
                    dh,
                    len,
                );
                mm::mm(
                    &mut g[2 * dh..],
                    3 * dh,
                    mm::Lhs {
                        data: p,
                        row: 1,
                        col: lp,
                    },
                    mm::Rhs { data: dout, ld: d },
                    len,
                    dh,
                    len,
                );
                g
            })
            .collect();
        let mut dqkv = vec![0.0f32; t * 3 * d];
        let owners = seg.owners();
        dqkv.par_chunks_mut(3 * d)
            .zip(&owners)
            .with_min_len(ROWS_PER_TASK)
            .for_each(|(row, owner)| {
                let Some((sq, i)) = *owner else { return };
                for head in 0..h {
                    let src = &results[sq * h + head][i * 3 * dh..][..3 * dh];
                    // q was scaled after its projection, so its gradient picks up the scale.
                    for (dst, s) in row[head * dh..][..dh].iter_mut().zip(&src[..dh]) {
                        *dst = s * scale;
                    }
                    row[d + head * dh..][..dh].copy_from_slice(&src[dh..2 * dh]);
                    row[2 * d + head * dh..][..dh].copy_from_slice(&src[2 * dh..]);
                }
            });
        self.qkv.backward(&dqkv, t)
    }
}

/// Activations `backward_pooled` needs.
pub struct PooledAttnSaved {
    /// `[T, 2D]`: k and v for every token.
    kv: Vec<f32>,
    /// `[S, D]`: scaled q of each sequence's query token.
    q: Vec<f32>,
    /// Softmax probabilities `[len]` per (sequence, head).
    probs: Vec<Vec<f32>>,
}

impl Attention {
    /// Attention output for one query token per sequence (`rows[s]`, counted from the start of
    /// sequence s), keys and values from all tokens: `x: [T, D]` → `[S, D]`. The last layer of a
    /// tower only needs the pooled token (class token, end-of-text token), so this skips the
    /// query projection, scores, output projection (and, in `EncoderLayer`, the MLP) of every
    /// other token.
    pub fn forward_pooled(
        &self,
        x: &[f32],
        seg: &Segments,
        rows: &[usize],
        save: bool,
    ) -> (Vec<f32>, Option<PooledAttnSaved>) {
        let (d, dh, scale) = self.dims();
        let (t, ns, h) = (seg.total(), seg.spans.len(), self.num_heads);
        let kv = self.qkv.forward_part(x, t, d..3 * d);
        let xq: Vec<f32> = seg
            .spans
            .iter()
            .zip(rows)
            .flat_map(|(&(start, _), &r)| x[(start + r) * d..][..d].iter().copied())
            .collect();
        let mut q = self.qkv.forward_part(&xq, ns, 0..d);
        q.iter_mut().for_each(|v| *v *= scale);
        let results: Vec<(Vec<f32>, Vec<f32>)> = (0..ns * h)
            .into_par_iter()
            .map(|task| {
                let (sq, head) = (task / h, task % h);
                let (start, len) = seg.spans[sq];
                let qh = &q[sq * d + head * dh..][..dh];
                let keep = if seg.causal { rows[sq] + 1 } else { len };
                let mut p = vec![0.0f32; len];
                for (j, pj) in p[..keep].iter_mut().enumerate() {
                    let k = &kv[(start + j) * 2 * d + head * dh..][..dh];
                    *pj = qh.iter().zip(k).map(|(a, b)| a * b).sum();
                }
                softmax_rows(&mut p[..keep], keep, keep, false);
                let mut o = vec![0.0f32; dh];
                for (j, &pj) in p[..keep].iter().enumerate() {
                    let v = &kv[(start + j) * 2 * d + d + head * dh..][..dh];
                    o.iter_mut().zip(v).for_each(|(o, v)| *o += pj * v);
                }
                (p, o)
            })
            .collect();
        let mut ctx = vec![0.0f32; ns * d];
        for (task, (_, o)) in results.iter().enumerate() {
            ctx[(task / h) * d + (task % h) * dh..][..dh].copy_from_slice(o);
        }
        let y = self.out.forward(&ctx, ns);
        let saved = save.then(|| PooledAttnSaved {
            kv,
            q,
            probs: results.into_iter().map(|(p, _)| p).collect(),
        });
        (y, saved)
    }

    /// Backward of `forward_pooled`: `dy: [S, D]` → `dx: [T, D]`.
    pub fn backward_pooled(
        &self,
        dy: &[f32],
        seg: &Segments,
        rows: &[usize],
        s: &PooledAttnSaved,
    ) -> Vec<f32> {
        let (d, dh, scale) = self.dims();
        let (t, ns, h) = (seg.total(), seg.spans.len(), self.num_heads);
        let dctx = self.out.backward(dy, ns);
        // Per (sequence, head), one query row: dp_j = dO·v_j, ds = p ⊙ (dp − p·dp),
        // dq = Σ_j ds_j k_j, dk_j = ds_j q, dv_j = p_j dO.
        let results: Vec<(Vec<f32>, Vec<f32>)> = (0..ns * h)
            .into_par_iter()
            .map(|task| {
                let (sq, head) = (task / h, task % h);
                let (start, len) = seg.spans[sq];
                let p = &s.probs[task];
                let qh = &s.q[sq * d + head * dh..][..dh];
                let dout = &dctx[sq * d + head * dh..][..dh];
                let key = |j: usize| &s.kv[(start + j) * 2 * d + head * dh..][..dh];
                let val = |j: usize| &s.kv[(start + j) * 2 * d + d + head * dh..][..dh];
                let dp: Vec<f32> = (0..len)
                    .map(|j| dout.iter().zip(val(j)).map(|(a, b)| a * b).sum())
                    .collect();
                let dot: f32 = dp.iter().zip(p).map(|(a, b)| a * b).sum();
                let ds: Vec<f32> = dp.iter().zip(p).map(|(a, &b)| b * (a - dot)).collect();
                let mut dq = vec![0.0f32; dh];
                // dkv block for this head: [len, 2 dh] = (dK | dV).
                let mut g = vec![0.0f32; len * 2 * dh];
                for j in 0..len {
                    dq.iter_mut().zip(key(j)).for_each(|(a, k)| *a += ds[j] * k);
                    let row = &mut g[j * 2 * dh..][..2 * dh];
                    row[..dh]
                        .iter_mut()
                        .zip(qh)
                        .for_each(|(a, q)| *a = ds[j] * q);
                    row[dh..]
                        .iter_mut()
                        .zip(dout)
                        .for_each(|(a, o)| *a = p[j] * o);
                }
                (dq, g)
            })
            .collect();
        let mut dq = vec![0.0f32; ns * d];
        for (task, (dqh, _)) in results.iter().enumerate() {
            let (sq, head) = (task / h, task % h);
            // q was scaled after its projection.
            dq[sq * d + head * dh..][..dh]
                .iter_mut()
                .zip(dqh)
                .for_each(|(a, b)| *a = b * scale);
        }
        // Per-head results scattered into token rows, as `backward`'s dqkv, but only k and v
        // have a row per token here (q exists for the pooled rows alone): another row width
        // and source layout.
        let mut dkv = vec![0.0f32; t * 2 * d];
        let owners = seg.owners();
        dkv.par_chunks_mut(2 * d)
            .zip(&owners)
            .with_min_len(ROWS_PER_TASK)
            .for_each(|(row, owner)| {
                let Some((sq, j)) = *owner else { return };
                for head in 0..h {
                    let src = &results[sq * h + head].1[j * 2 * dh..][..2 * dh];
                    row[head * dh..][..dh].copy_from_slice(&src[..dh]);
                    row[d + head * dh..][..dh].copy_from_slice(&src[dh..]);
                }
            });
        let mut dx = self.qkv.backward_part(&dkv, t, d..3 * d);
        let dxq = self.qkv.backward_part(&dq, ns, 0..d);
        for ((&(start, _), &r), g) in seg.spans.iter().zip(rows).zip(dxq.chunks_exact(d)) {
            dx[(start + r) * d..][..d]
                .iter_mut()
                .zip(g)
                .for_each(|(a, b)| *a += b);
        }
        dx
    }
}

/// Row-wise softmax of a `[len, len]` score block stored with row stride `ld` (columns past
/// len untouched), in place; with `causal`, entries above the diagonal get probability 0 (as
/// adding -inf to the scores would).
pub(crate) fn softmax_rows(p: &mut [f32], ld: usize, len: usize, causal: bool) {
    for (i, row) in p.chunks_exact_mut(ld).enumerate() {
        let row = &mut row[..len];
        let keep = if causal { i + 1 } else { len };
        let max = row[..keep].iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
        let mut sum = 0.0f32;
        for v in &mut row[..keep] {
            *v = fast_exp(*v - max);
            sum += *v;
        }
        let inv = 1.0 / sum;
        row[..keep].iter_mut().for_each(|v| *v *= inv);
        row[keep..].fill(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lin(out: usize, inp: usize, seed: usize) -> Linear {
        Linear::new(
            (0..out * inp)
                .map(|i| (((i + seed) * 2654435761usize % 1000) as f32 / 1000.0 - 0.5) * 0.8)
                .collect(),
            Some(
                (0..out)
                    .map(|i| ((i + seed) % 7) as f32 * 0.05 - 0.15)
                    .collect(),
            ),
            inp,
            out,
            &crate::Compute::default(),
        )
    }

    /// Attention of width `d` with `heads` heads (weights from `seed` and `seed + 1`) on three
    /// sequences of 3, 1 and 4 tokens.
    fn setup(d: usize, seed: usize, heads: usize, causal: bool) -> (Attention, Segments) {
        let att = Attention {
            qkv: lin(3 * d, d, seed),
            out: lin(d, d, seed + 1),
            num_heads: heads,
        };
        let seg = Segments {
            spans: vec![(0, 3), (3, 1), (4, 4)],
            causal,
        };
        (att, seg)
    }

    /// `n` deterministic values ((i · mul mod modulus) − offset) / scale.
    fn pattern(n: usize, mul: usize, modulus: usize, offset: f32, scale: f32) -> Vec<f32> {
        (0..n)
            .map(|i| ((i * mul % modulus) as f32 - offset) / scale)
            .collect()
    }

    /// `dx` against central differences of `loss` at `x` (h = 1e-2; the tolerance is argued at
    /// the test below).
    fn assert_matches_differences(
        x: &[f32],
        dx: &[f32],
        loss: impl Fn(&[f32]) -> f64,
        causal: bool,
    ) {
        let h = 1e-2f32;
        for i in 0..x.len() {
            let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
            xp[i] += h;
            xm[i] -= h;
            let fd = (loss(&xp) - loss(&xm)) / (2.0 * h as f64);
            assert!(
                (dx[i] as f64 - fd).abs() <= 2e-3 * (1.0 + fd.abs()),
                "causal={causal} i={i}: {} vs {fd}",
                dx[i]
            );
        }
    }

    /// Finite differences of `sum(w ⊙ attn(x))` for causal packed segments of different
    /// lengths. Central differences with h = 1e-2 in f64 of an f32 forward: f32 round-off
    /// (~1e-7 relative on O(1) outputs) / h ≈ 1e-5 plus O(h²) truncation, so 2e-3 relative.
    #[test]
    fn backward_matches_finite_differences() {
        let d = 6;
        for causal in [false, true] {
            let (att, seg) = setup(d, 1, 2, causal);
            let t = seg.total();
            let x = pattern(t * d, 37, 23, 11.0, 8.0);
            let w = pattern(t * d, 11, 17, 8.0, 8.0);
            let loss = |x: &[f32]| -> f64 {
                let (y, _) = att.forward(x, &seg, false);
                y.iter().zip(&w).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            let (_, s) = att.forward(&x, &seg, true);
            let dx = att.backward(&w, &seg, &s.unwrap());
            assert_matches_differences(&x, &dx, loss, causal);
        }
    }

    /// The pooled path equals the full one at the query rows, and its backward matches
    /// finite differences (same tolerance argument as above).
    #[test]
    fn pooled_matches_full_and_finite_differences() {
        let d = 6;
        for causal in [false, true] {
            let (att, seg) = setup(d, 3, 3, causal);
            let rows = [2usize, 0, if causal { 3 } else { 1 }];
            let t = seg.total();
            let x = pattern(t * d, 29, 19, 9.0, 7.0);
            let (full, _) = att.forward(&x, &seg, false);
            let (pooled, s) = att.forward_pooled(&x, &seg, &rows, true);
            for (k, (&(start, _), &r)) in seg.spans.iter().zip(&rows).enumerate() {
                for c in 0..d {
                    let (a, b) = (pooled[k * d + c], full[(start + r) * d + c]);
                    assert!((a - b).abs() < 1e-5, "causal={causal} seq {k}: {a} vs {b}");
                }
            }
            let w = pattern(3 * d, 7, 11, 5.0, 5.0);
            let loss = |x: &[f32]| -> f64 {
                let (y, _) = att.forward_pooled(x, &seg, &rows, false);
                y.iter().zip(&w).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            let dx = att.backward_pooled(&w, &seg, &rows, &s.unwrap());
            assert_matches_differences(&x, &dx, loss, causal);
        }
    }

    #[test]
    fn causal_first_token_sees_only_itself_and_huge_scores_stay_finite() {
        let mut p = vec![1e30f32, 5.0, -1e30, 2.0, 1.0, 0.0, 3.0, 3.0, 3.0];
        softmax_rows(&mut p, 3, 3, true);
        assert_eq!(&p[..3], &[1.0, 0.0, 0.0]);
        assert!(p.iter().all(|v| v.is_finite()));
        assert!(((p[3] + p[4]) - 1.0).abs() < 1e-6 && p[5] == 0.0);
    }
}
