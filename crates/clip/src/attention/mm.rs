//! The small dense products inside one attention head (scores, probabilities × values and
//! their backward: 50 × 50 × 64 for a ViT-B/32 view), written for those sizes.
//!
//! Why not the `gemm` crate: profiles of the image pass (perf, single thread, Zen 4) put these
//! products at ≈ 3 % (f32 pass) and ≈ 5 % (bf16 pass) of the cycles for 1.5 % of the FLOPs —
//! at 50 × 50 × 64 the crate's dispatch and packing cost more than the arithmetic. Here a
//! register tile of 4 rows × up to 64 columns is accumulated over k with B rows read in place
//! (contiguous), A read element by element through two strides (so a transposed A costs
//! nothing), and no packing at all.
//!
//! Every copy (baseline, AVX2, AVX-512F) does the same multiply then add per element in the
//! same order — no fused multiply-add, which Rust never contracts on its own — so results are
//! bit-identical whatever the CPU.

/// Rows of C per register tile.
const R: usize = 4;
/// Lanes per column chunk.
const W: usize = 16;

/// The left operand: `A(i, p) = data[i·row + p·col]` (so a transposed A is only other
/// strides).
#[derive(Clone, Copy)]
pub struct Lhs<'a> {
    pub data: &'a [f32],
    pub row: usize,
    pub col: usize,
}

/// The right operand: row p of B is `data[p·ld .. p·ld + n]`.
#[derive(Clone, Copy)]
pub struct Rhs<'a> {
    pub data: &'a [f32],
    pub ld: usize,
}

/// `C[m × n] = A[m × k] · B[k × n]`, overwriting C, whose row i is `c[i·ldc .. i·ldc + n]`.
pub fn mm(c: &mut [f32], ldc: usize, a: Lhs, b: Rhs, m: usize, n: usize, k: usize) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        ldc >= n && c.len() >= (m - 1) * ldc + n,
        "attention mm: C too small"
    );
    if k > 0 {
        assert!(
            a.data.len() > (m - 1) * a.row + (k - 1) * a.col,
            "attention mm: A too small"
        );
        assert!(
            b.data.len() >= (k - 1) * b.ld + n,
            "attention mm: B too small"
        );
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked just above).
            return unsafe { mm_avx512(c, ldc, a, b, m, n, k) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            return unsafe { mm_avx2(c, ldc, a, b, m, n, k) };
        }
    }
    mm_body(c, ldc, a, b, m, n, k)
}

/// `mm` compiled for AVX-512F (16-lane chunks are one zmm each).
///
/// # Safety
/// The CPU has AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn mm_avx512(c: &mut [f32], ldc: usize, a: Lhs, b: Rhs, m: usize, n: usize, k: usize) {
    mm_body(c, ldc, a, b, m, n, k)
}

/// `mm` compiled for AVX2.
///
/// # Safety
/// The CPU has AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn mm_avx2(c: &mut [f32], ldc: usize, a: Lhs, b: Rhs, m: usize, n: usize, k: usize) {
    mm_body(c, ldc, a, b, m, n, k)
}

#[inline(always)]
fn mm_body(c: &mut [f32], ldc: usize, a: Lhs, b: Rhs, m: usize, n: usize, k: usize) {
    for i in (0..m).step_by(R) {
        let rows = R.min(m - i);
        let mut j = 0;
        // Full 16-column chunks, four at a time where possible.
        while j + W <= n {
            let chunks = ((n - j) / W).min(4);
            let at = Block { i, rows, j };
            match chunks {
                4 => tile::<4>(c, ldc, a, b, at, k),
                3 => tile::<3>(c, ldc, a, b, at, k),
                2 => tile::<2>(c, ldc, a, b, at, k),
                _ => tile::<1>(c, ldc, a, b, at, k),
            }
            j += chunks * W;
        }
        // Columns past the last full chunk (widths that are not multiples of 16).
        for r in 0..rows {
            for jj in j..n {
                let mut s = 0.0f32;
                for p in 0..k {
                    s += a.data[(i + r) * a.row + p * a.col] * b.data[p * b.ld + jj];
                }
                c[(i + r) * ldc + jj] = s;
            }
        }
    }
}

/// Where a register tile sits in C: rows `i .. i + rows` (≤ R), columns from `j`.
#[derive(Clone, Copy)]
struct Block {
    i: usize,
    rows: usize,
    j: usize,
}

/// Rows `at.i .. at.i + at.rows` × columns `at.j .. at.j + NC·W` of C.
#[inline(always)]
fn tile<const NC: usize>(c: &mut [f32], ldc: usize, a: Lhs, b: Rhs, at: Block, k: usize) {
    let Block { i, rows, j } = at;
    let mut acc = [[[0.0f32; W]; NC]; R];
    for p in 0..k {
        let brow: &[f32] = &b.data[p * b.ld + j..][..NC * W];
        let mut bv = [[0.0f32; W]; NC];
        for (v, chunk) in bv.iter_mut().zip(brow.chunks_exact(W)) {
            v.copy_from_slice(chunk);
        }
        for (r, acc_r) in acc.iter_mut().enumerate() {
            // Rows past m multiply by 0 (their results are not stored).
            let av = if r < rows {
                a.data[(i + r) * a.row + p * a.col]
            } else {
                0.0
            };
            for (acc_v, bv_v) in acc_r.iter_mut().zip(&bv) {
                for (x, y) in acc_v.iter_mut().zip(bv_v) {
                    *x += av * y;
                }
            }
        }
    }
    for (r, acc_r) in acc.iter().enumerate().take(rows) {
        let crow = &mut c[(i + r) * ldc + j..][..NC * W];
        for (dst, v) in crow.chunks_exact_mut(W).zip(acc_r) {
            dst.copy_from_slice(v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against f64 on every shape class: m not a multiple of 4, n with 1–4 full chunks and a
    /// remainder, k = 0 and 1, transposed A, strided B and C (padding untouched).
    #[test]
    fn matches_f64_on_odd_shapes_and_strides() {
        // Shaped like packed/mod.rs's and layers.rs's odd-shape tests (a table of m, n, k
        // against f64); each tests its own product and strides.
        let val = |i: usize, s: usize| ((((i + s) * 2654435761usize) % 2001) as f32 / 1000.0) - 1.0;
        for &(m, n, k) in &[
            (1, 1, 1),
            (3, 16, 5),
            (5, 17, 0),
            (7, 50, 64),
            (50, 64, 50),
            (13, 100, 9),
            (9, 130, 33),
        ] {
            for transposed in [false, true] {
                let (a_row, a_col, a_len) = if transposed {
                    (1, m + 2, (k.max(1)) * (m + 2))
                } else {
                    (k + 3, 1, m * (k + 3))
                };
                let a: Vec<f32> = (0..a_len).map(|i| val(i, 1)).collect();
                let ldb = n + 5;
                let b: Vec<f32> = (0..k.max(1) * ldb).map(|i| val(i, 2)).collect();
                let ldc = n + 1;
                let mut c = vec![7.0f32; m * ldc];
                mm(
                    &mut c,
                    ldc,
                    Lhs {
                        data: &a,
                        row: a_row,
                        col: a_col,
                    },
                    Rhs { data: &b, ld: ldb },
                    m,
                    n,
                    k,
                );
                for i in 0..m {
                    for j in 0..ldc {
                        let got = c[i * ldc + j];
                        if j >= n {
                            assert_eq!(got, 7.0, "padding");
                            continue;
                        }
                        let want: f64 = (0..k)
                            .map(|p| a[i * a_row + p * a_col] as f64 * b[p * ldb + j] as f64)
                            .sum();
                        assert!(
                            (got as f64 - want).abs() <= 1e-5 * (1.0 + k as f64),
                            "{m}x{n}x{k} t={transposed} ({i},{j}): {got} vs {want}"
                        );
                    }
                }
            }
        }
    }

    /// The SIMD copies give the same bits as the baseline one.
    #[test]
    fn copies_agree_bit_for_bit() {
        let (m, n, k) = (50, 80, 64);
        let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.11).cos()).collect();
        let mut fast = vec![0.0; m * n];
        let mut base = vec![0.0; m * n];
        let (la, rb) = (
            Lhs {
                data: &a,
                row: k,
                col: 1,
            },
            Rhs { data: &b, ld: n },
        );
        mm(&mut fast, n, la, rb, m, n, k);
        mm_body(&mut base, n, la, rb, m, n, k);
        assert!(fast
            .iter()
            .zip(&base)
            .all(|(x, y)| x.to_bits() == y.to_bits()));
    }
}
