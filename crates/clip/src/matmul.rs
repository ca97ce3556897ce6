//! Matrix products on the `gemm` crate (f32, AVX-512 kernels with the `x86-v4` feature): the
//! engine of `Linear` layers where no packed SIMD kernel applies (`Engine::Crate`, see
//! `super::packed`). `gemm` rather than matrixmultiply because it runs the m = 150 shapes of
//! three batched ViT-B/32 views on every core, where matrixmultiply stays single-threaded.
//! Operands are row-major slices; a transposed operand is expressed through strides, so no
//! copy is ever made.

use gemm::Parallelism;

/// Whether an operand is used as stored or transposed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    /// As stored.
    N,
    /// Transposed.
    T,
}

/// A row-major matrix view: element (i, j) of the *stored* matrix is `data[i * ld + j]`.
#[derive(Clone, Copy)]
pub struct Mat<'a> {
    /// The elements, row-major.
    pub data: &'a [f32],
    /// Leading dimension: the distance between rows.
    pub ld: usize,
}

impl<'a> Mat<'a> {
    /// A view of `data` with rows `ld` apart.
    pub fn new(data: &'a [f32], ld: usize) -> Mat<'a> {
        Mat { data, ld }
    }
}

/// Work below this many multiply-adds runs on the calling thread: splitting it costs more than
/// it saves (attention heads of 50 tokens, for instance, are parallelised one level up).
const PARALLEL_MIN_MACS: usize = 1 << 20;

/// Row and column strides of `op(x)`, an `rows`×`cols` operand, after checking that the last
/// element it reaches lies inside `x` (nothing is read when `k` = 0). Panics as
/// "matmul: NAME too small".
fn strides(x: Mat, op: Op, (rows, cols): (usize, usize), k: usize, name: &str) -> (isize, isize) {
    // The stored matrix is op(x) itself or its transpose.
    let (stored_rows, stored_cols) = match op {
        Op::N => (rows, cols),
        Op::T => (cols, rows),
    };
    assert!(
        k == 0 || (x.ld >= stored_cols && x.data.len() >= (stored_rows - 1) * x.ld + stored_cols),
        "matmul: {name} too small"
    );
    match op {
        Op::N => (x.ld as isize, 1),
        Op::T => (1, x.ld as isize),
    }
}

/// `C = op(A) · op(B)` (or `C += ...` with `accumulate`), `C` being m×n with leading dimension
/// `ldc`. `op(A)` is m×k, `op(B)` is k×n.
// BLAS's sgemm signature (C, ldc, A, op, B, op, m, n, k, β ∈ {0, 1}), which the `gemm` crate
// call below takes apart again; kept flat so it reads like the reference it wraps.
#[allow(clippy::too_many_arguments)]
pub fn matmul(
    c: &mut [f32],
    ldc: usize,
    a: Mat,
    ta: Op,
    b: Mat,
    tb: Op,
    m: usize,
    n: usize,
    k: usize,
    accumulate: bool,
) {
    if m == 0 || n == 0 {
        return;
    }
    // Bounds: the last element each operand touches must lie inside its slice. This is what
    // makes the unsafe call below sound.
    let last = |rows: usize, cols: usize, ld: usize| (rows - 1) * ld + cols;
    assert!(
        ldc >= n && c.len() >= last(m, n, ldc),
        "matmul: C too small"
    );
    let (a_rs, a_cs) = strides(a, ta, (m, k), k, "A");
    let (b_rs, b_cs) = strides(b, tb, (k, n), k, "B");
    if k == 0 {
        if !accumulate {
            for i in 0..m {
                c[i * ldc..i * ldc + n].fill(0.0);
            }
        }
        return;
    }
    let threads = rayon::current_num_threads();
    let par = if m * n * k >= PARALLEL_MIN_MACS && threads > 1 {
        Parallelism::Rayon(threads)
    } else {
        Parallelism::None
    };
    // SAFETY: the asserts above keep every index gemm computes from (rows, cols, strides)
    // inside the three slices; C is borrowed mutably and cannot alias A or B.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            ldc as isize,
            accumulate,
            a.data.as_ptr(),
            a_cs,
            a_rs,
            b.data.as_ptr(),
            b_cs,
            b_rs,
            1.0,
            1.0,
            false,
            false,
            false,
            par,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(a: &[f32], b: &[f32], m: usize, n: usize, k: usize) -> Vec<f32> {
        let mut c = vec![0.0; m * n];
        for i in 0..m {
            for j in 0..n {
                c[i * n + j] = (0..k).map(|p| a[i * k + p] * b[p * n + j]).sum();
            }
        }
        c
    }

    fn transpose(x: &[f32], rows: usize, cols: usize) -> Vec<f32> {
        let mut t = vec![0.0; x.len()];
        for i in 0..rows {
            for j in 0..cols {
                t[j * rows + i] = x[i * cols + j];
            }
        }
        t
    }

    #[test]
    fn all_transpose_combinations_match_naive() {
        // Deterministic operands as in attention.rs's tests: a table of shapes against a
        // naive product, for this module's transposes.
        // Large enough to take the threaded path too.
        for &(m, n, k) in &[(3, 5, 7), (150, 130, 70)] {
            let a: Vec<f32> = (0..m * k)
                .map(|i| ((i * 37 % 101) as f32 - 50.0) / 50.0)
                .collect();
            let b: Vec<f32> = (0..k * n)
                .map(|i| ((i * 53 % 97) as f32 - 48.0) / 48.0)
                .collect();
            let want = naive(&a, &b, m, n, k);
            let at = transpose(&a, m, k);
            let bt = transpose(&b, k, n);
            for (ta, tb) in [
                (Op::N, Op::N),
                (Op::T, Op::N),
                (Op::N, Op::T),
                (Op::T, Op::T),
            ] {
                let (am, bm) = (
                    if ta == Op::N {
                        Mat::new(&a, k)
                    } else {
                        Mat::new(&at, m)
                    },
                    if tb == Op::N {
                        Mat::new(&b, n)
                    } else {
                        Mat::new(&bt, k)
                    },
                );
                let mut c = vec![1.0; m * n];
                matmul(&mut c, n, am, ta, bm, tb, m, n, k, true);
                for (x, y) in c.iter().zip(&want) {
                    assert!((x - 1.0 - y).abs() < 1e-4 * (1.0 + y.abs()), "{ta:?}{tb:?}");
                }
                matmul(&mut c, n, am, ta, bm, tb, m, n, k, false);
                for (x, y) in c.iter().zip(&want) {
                    assert!((x - y).abs() < 1e-4 * (1.0 + y.abs()));
                }
            }
        }
    }
}
