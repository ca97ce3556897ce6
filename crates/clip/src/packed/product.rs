//! The product `C = A · B` on packed B: the entry points, the blocked driver (`gemm_raw`),
//! and the dispatch of one micro-tile to its kernel (`run_tile`).

use std::ops::Range;

use rayon::prelude::*;

use super::*;

/// `C = (accumulate ? C : 0) + A · B[ks, cols] (+ bias[cols])`, with
/// - `C`: m × `cols.len()`, row-major with leading dimension `ldc` (column 0 of C is column
///   `cols.start` of B);
/// - `A`: m × `ks.len()`, row-major with leading dimension `lda` (column 0 of A multiplies row
///   `ks.start` of B);
/// - `bias`: indexed by B's column, length `b.n()`.
///
/// Runs `b.kernel()`; with a bf16 kernel A is rounded to bf16 first.
// BLAS's sgemm order (C, ldc, A, lda, m, B, its row and column ranges, bias, β ∈ {0, 1}): the
// leading dimensions sit next to the slices whose bounds the assertions check against them;
// an argument struct would separate the two.
#[allow(clippy::too_many_arguments)]
pub fn gemm(
    c: &mut [f32],
    ldc: usize,
    a: &[f32],
    lda: usize,
    m: usize,
    b: &PackedB,
    ks: Range<usize>,
    cols: Range<usize>,
    bias: Option<&[f32]>,
    accumulate: bool,
) {
    let n = cols.len();
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        ldc >= n && c.len() >= (m - 1) * ldc + n,
        "packed::gemm: C too small"
    );
    if ks.is_empty() {
        assert!(ks.end <= b.k && cols.end <= b.n, "packed::gemm: B range");
        for row in c.chunks_mut(ldc).take(m) {
            let row = &mut row[..n];
            if !accumulate {
                row.fill(0.0);
            }
            if let Some(bias) = bias {
                assert_eq!(bias.len(), b.n, "packed::gemm: bias length");
                row.iter_mut()
                    .zip(&bias[cols.clone()])
                    .for_each(|(y, b)| *y += b);
            }
        }
        return;
    }
    // SAFETY: `c` is an initialized slice of at least the length passed.
    unsafe {
        gemm_raw(
            c.as_mut_ptr(),
            c.len(),
            ldc,
            a,
            lda,
            m,
            b,
            ks,
            cols,
            bias,
            accumulate,
            None,
        )
    }
}

/// `gemm` into a new `[m, cols.len()]` matrix (`ldc = cols.len()`), never zero-filled first:
/// every element is written by the first k-block.
pub(crate) fn gemm_new(
    a: &[f32],
    lda: usize,
    m: usize,
    b: &PackedB,
    ks: Range<usize>,
    cols: Range<usize>,
    bias: Option<&[f32]>,
) -> Vec<f32> {
    gemm_new_post(a, lda, m, b, ks, cols, bias, None)
}

/// An elementwise step fused into the product: `post(row, col, values)` gets C's row `row`,
/// columns `col .. col + values.len()`, once the product of that part is final, and may
/// rewrite it; every element of C is passed exactly once, by the thread that computed it,
/// while the tile is still in L1 (a separate pass re-reads C from L2/L3: for the MLP
/// activation that costs ≈ 5 % of the single-thread bf16 image pass).
pub(crate) type Post<'a> = &'a (dyn Fn(usize, usize, &mut [f32]) + Sync);

/// `gemm_new` with `post` applied to every finished block of C.
// `gemm`'s argument list without C (see there), plus `post`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm_new_post(
    a: &[f32],
    lda: usize,
    m: usize,
    b: &PackedB,
    ks: Range<usize>,
    cols: Range<usize>,
    bias: Option<&[f32]>,
    post: Option<Post>,
) -> Vec<f32> {
    let mut c = Vec::new();
    gemm_into_post(&mut c, a, lda, m, b, ks, cols, bias, post);
    c
}

/// `gemm_new_post` into `c`, whose old contents are dropped and whose memory is reused: a
/// caller that runs many products of one size (the caption pool's layers) touches no fresh
/// pages after the first, where a new buffer per product has its pages faulted in and zeroed
/// each time.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm_into_post(
    c: &mut Vec<f32>,
    a: &[f32],
    lda: usize,
    m: usize,
    b: &PackedB,
    ks: Range<usize>,
    cols: Range<usize>,
    bias: Option<&[f32]>,
    post: Option<Post>,
) {
    let n = cols.len();
    c.clear();
    if m == 0 || n == 0 || ks.is_empty() {
        c.resize(m * n, 0.0);
        gemm(c, n, a, lda, m, b, ks, cols, bias, false);
        if let (Some(post), true) = (post, n > 0) {
            for (row, values) in c.chunks_exact_mut(n).enumerate() {
                post(row, 0, values);
            }
        }
        return;
    }
    c.reserve(m * n);
    // SAFETY: the buffer has capacity m·n; with `accumulate` false and k > 0, `gemm_raw`
    // writes every element of the m × n matrix (the first k-block overwrites all tiles) and
    // reads only elements it wrote, so the whole length is initialized afterwards.
    unsafe {
        gemm_raw(
            c.as_mut_ptr(),
            m * n,
            n,
            a,
            lda,
            m,
            b,
            ks,
            cols,
            bias,
            false,
            post,
        );
        c.set_len(m * n);
    }
}

/// The product itself, for m, n, k > 0, then `post` on every tile (see `Post`).
///
/// # Safety
/// `c` is valid for reads and writes of `c_len` floats and not aliased during the call;
/// elements are read only where `accumulate` is set (then they must be initialized) or after
/// this call wrote them.
// `gemm`'s arguments (see there) with C as a raw pointer and length, which the safety contract
// above is about, and `post`. `gemm` is the safe entry on a C slice (and the k = 0 case), this
// the one `gemm_new`/`gemm_new_post` share on uninitialized C, so the raw pointer stays out of
// the safe signature.
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn gemm_raw(
    c: *mut f32,
    c_len: usize,
    ldc: usize,
    a: &[f32],
    lda: usize,
    m: usize,
    b: &PackedB,
    ks: Range<usize>,
    cols: Range<usize>,
    bias: Option<&[f32]>,
    accumulate: bool,
    post: Option<Post>,
) {
    let kernel = b.kernel;
    let (k, n) = (ks.len(), cols.len());
    assert!(m > 0 && n > 0 && k > 0);
    // These bounds make every raw access below sound.
    assert!(ks.end <= b.k && cols.end <= b.n, "packed::gemm: B range");
    assert!(
        ldc >= n && c_len >= (m - 1) * ldc + n,
        "packed::gemm: C too small"
    );
    assert!(
        lda >= k && a.len() >= (m - 1) * lda + k,
        "packed::gemm: A too small"
    );
    if let Some(bias) = bias {
        assert_eq!(bias.len(), b.n, "packed::gemm: bias length");
    }
    let nr = kernel.nr();
    let mr = kernel.mr();
    let panels_m = m.div_ceil(mr);
    let parallel = m * n * k >= PARALLEL_MIN_MACS && rayon::current_num_threads() > 1;
    // Packed rows of B this call covers: k rows (f32), or the k pairs q0 .. q0 + kr (bf16).
    let (row0, shift) = if kernel.bf16() {
        (ks.start / 2, ks.start % 2)
    } else {
        (ks.start, 0)
    };
    let ap = pack_a(kernel, a, lda, m, k, shift, parallel);
    let kr = match &ap {
        APacked::Pairs { kq, .. } => *kq,
        _ => k,
    };
    let b_rows = packed_rows(kernel, b.k);

    let (p0, p1) = (cols.start / nr, cols.end.div_ceil(nr));
    let threads = if parallel {
        rayon::current_num_threads().min(p1 - p0)
    } else {
        1
    };
    let cp = SendPtr(c);
    // Row panels per A block: the fewest blocks of at most MC rows, of balanced sizes.
    let per_block = panels_m.div_ceil(panels_m.div_ceil(MC / mr));
    let bflat = b.flat();
    let ap = &ap;
    let cols = &cols;
    let kc_max = kernel.kc();
    let run = |t: usize| {
        let (j0, j1) = (
            p0 + t * (p1 - p0) / threads,
            p0 + (t + 1) * (p1 - p0) / threads,
        );
        let mut tile_bias = [0.0f32; NR_MAX];
        for kb in (0..kr).step_by(kc_max) {
            let kc = kc_max.min(kr - kb);
            let first = kb == 0;
            for ib in (0..panels_m).step_by(per_block) {
                for j in j0..j1 {
                    // Tile columns j·nr .. j·nr + nr of B, clipped to `cols`.
                    let lo = cols.start.max(j * nr) - j * nr;
                    let hi = cols.end.min(j * nr + nr) - j * nr;
                    if let (true, Some(bias)) = (first, bias) {
                        let bn = nr.min(b.n - j * nr);
                        tile_bias[..bn].copy_from_slice(&bias[j * nr..][..bn]);
                        tile_bias[bn..nr].fill(0.0);
                    }
                    let bpanel = &bflat[(j * b_rows + row0 + kb) * nr..][..kc * nr];
                    // The B micro-panel that comes next (the next column panel, or the
                    // first one of the next k-block): the tiles below prefetch it into L2,
                    // a share each, so that its first tile does not wait on memory (weights
                    // are far larger than the caches and are read once per call).
                    let next = if j + 1 < j1 {
                        Some((j + 1, kb, kc))
                    } else if kb + kc_max < kr {
                        Some((j0, kb + kc_max, kc_max.min(kr - kb - kc_max)))
                    } else {
                        None
                    };
                    let next = next.map_or(&[][..], |(jn, kbn, kcn)| {
                        &bflat[(jn * b_rows + row0 + kbn) * nr..][..kcn * nr]
                    });
                    let i_end = (ib + per_block).min(panels_m);
                    let share = (next.len() / 16).div_ceil(i_end - ib) * 16;
                    for i in ib..i_end {
                        let pf_start = ((i - ib) * share).min(next.len());
                        let prefetch = &next[pf_start..(pf_start + share).min(next.len())];
                        let tile = Tile {
                            rows: mr.min(m - i * mr),
                            lo,
                            hi,
                            // Offset of tile column 0 in C's row; < 0 only when lo > 0.
                            col0: (j * nr) as isize - cols.start as isize,
                            bias: (first && bias.is_some()).then_some(&tile_bias[..nr]),
                            add: !first || accumulate,
                            nr,
                        };
                        // SAFETY: row i·mr of C starts inside `c` (i·mr < m); the tile
                        // writes rows < m and C columns col0 + lo .. col0 + hi, which lie in
                        // 0 .. n ≤ ldc by the clipping above, so inside the asserted bounds.
                        // Threads own disjoint panel ranges j0..j1, hence disjoint columns.
                        // `b.kernel` was checked against this CPU when B was packed.
                        unsafe {
                            let crow = cp.get().add(i * mr * ldc);
                            run_tile(kernel, ap, i, kb, kc, bpanel, prefetch, crow, ldc, &tile);
                        }
                        if let (Some(post), true) = (post, kb + kc == kr) {
                            let col = (j * nr + lo) - cols.start;
                            for r in 0..tile.rows {
                                // SAFETY: the tile's part of this row, written just above by
                                // this thread, which alone owns these columns; no other
                                // reference to it exists during the call.
                                let values = unsafe {
                                    std::slice::from_raw_parts_mut(
                                        cp.get().add((i * mr + r) * ldc + col),
                                        hi - lo,
                                    )
                                };
                                post(i * mr + r, col, values);
                            }
                        }
                    }
                }
            }
        }
    };
    if threads > 1 {
        (0..threads).into_par_iter().for_each(run);
    } else {
        run(0);
    }
}

/// Where and how one micro-tile's result goes into C.
#[derive(Clone, Copy)]
pub(super) struct Tile<'a> {
    /// Valid rows (≤ the kernel's rows per tile).
    pub(super) rows: usize,
    /// Valid tile columns `lo .. hi` (⊆ 0 .. nr).
    pub(super) lo: usize,
    pub(super) hi: usize,
    /// C column of tile column 0.
    pub(super) col0: isize,
    /// Added to every row (first k-block only); `nr` floats.
    pub(super) bias: Option<&'a [f32]>,
    /// Add to C rather than overwrite it.
    pub(super) add: bool,
    /// Tile width (the kernel's NR).
    pub(super) nr: usize,
}

impl Tile<'_> {
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(super) fn full(&self) -> bool {
        self.rows == MR && self.lo == 0 && self.hi == self.nr
    }

    /// Write an accumulated tile `acc [rows][nr]` into C transposed: tile element (r, cc)
    /// goes to C's row `col0 + cc`, column r (the transposed product's tiles, `gemm_t`).
    ///
    /// # Safety
    /// `ccol` is C's column of the tile's first row; rows `col0 + lo .. col0 + hi` and columns
    /// `< self.rows` from it (leading dimension `ldc`) must be writable.
    pub(super) unsafe fn store_transposed(&self, acc: &[f32], ccol: *mut f32, ldc: usize) {
        for cc in self.lo..self.hi {
            // SAFETY: inside the region the caller guarantees.
            let row = unsafe { ccol.offset((cc as isize + self.col0) * ldc as isize) };
            for r in 0..self.rows {
                let v = acc[r * self.nr + cc] + self.bias.map_or(0.0, |b| b[cc]);
                // SAFETY: as above.
                unsafe {
                    let dst = row.add(r);
                    *dst = if self.add { *dst + v } else { v };
                }
            }
        }
    }

    /// Write an accumulated tile `acc [rows][nr]` into C through the general (edge) path.
    ///
    /// # Safety
    /// `crow` is C's row of the tile's first row; rows `< self.rows` and columns
    /// `col0 + lo .. col0 + hi` of it (leading dimension `ldc`) must be writable.
    pub(super) unsafe fn store_scalar(&self, acc: &[f32], crow: *mut f32, ldc: usize) {
        for r in 0..self.rows {
            for cc in self.lo..self.hi {
                let v = acc[r * self.nr + cc] + self.bias.map_or(0.0, |b| b[cc]);
                // SAFETY: inside the region the caller guarantees.
                let dst = unsafe { crow.offset((r * ldc) as isize + self.col0 + cc as isize) };
                unsafe {
                    *dst = if self.add { *dst + v } else { v };
                }
            }
        }
    }
}

/// Run one micro-tile: row panel `i` of A, packed rows `kb .. kb + kc`, against `bpanel`.
/// `prefetch`: part of the next B micro-panel, to be brought into L2 (a hint only).
///
/// # Safety
/// As `Tile::store_scalar`; `kernel` is available on this CPU; `ap` was packed for `kernel`
/// with at least `kb + kc` packed rows and more than `i` row panels; `bpanel` holds `kc·nr`
/// floats of a 64-byte-aligned packed panel.
// The micro-kernels' arguments (flat, see `avx512::tile_f32`) plus the panel indices they are
// cut from: this is the call in the innermost loop of the product.
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn run_tile(
    kernel: Kernel,
    ap: &APacked,
    i: usize,
    kb: usize,
    kc: usize,
    bpanel: &[f32],
    prefetch: &[f32],
    crow: *mut f32,
    ldc: usize,
    tile: &Tile,
) {
    #[cfg(not(target_arch = "x86_64"))]
    let _ = prefetch;
    match (kernel, ap) {
        (Kernel::Portable, APacked::Interleaved { data, k }) => {
            let apanel = &data[(i * k + kb) * MR..][..kc * MR];
            // SAFETY: forwarded from the caller.
            unsafe { portable::tile_f32(kc, apanel, bpanel, crow, ldc, tile) }
        }
        #[cfg(target_arch = "x86_64")]
        (Kernel::Avx2Fma, APacked::Interleaved { data, k }) => {
            let apanel = &data[(i * k + kb) * MR..][..kc * MR];
            // SAFETY: forwarded from the caller; the panels hold kc rows.
            unsafe {
                avx2::tile(
                    kc,
                    apanel.as_ptr(),
                    bpanel.as_ptr(),
                    prefetch,
                    crow,
                    ldc,
                    tile,
                )
            }
        }
        #[cfg(target_arch = "x86_64")]
        (
            Kernel::Avx512F,
            APacked::Rows {
                a,
                lda,
                full,
                tail,
                k,
            },
        ) => {
            let (ptr, stride) = if i < *full {
                (a[i * MR * lda + kb..].as_ptr(), *lda)
            } else {
                (tail[kb..].as_ptr(), *k)
            };
            // SAFETY: forwarded from the caller; a full panel's MR rows lie inside A (the
            // caller asserted A's size), the tail holds MR rows of k.
            unsafe { avx512::tile_f32(kc, ptr, stride, bpanel.as_ptr(), prefetch, crow, ldc, tile) }
        }
        (Kernel::PortableBf16, APacked::Pairs { data, kq }) => {
            let apanel = &data[i * MR * kq + kb..];
            // SAFETY: forwarded from the caller; bpanel's f32 slots hold u32 pairs.
            unsafe {
                let b = std::slice::from_raw_parts(bpanel.as_ptr().cast::<u32>(), bpanel.len());
                portable::tile_bf16(kc, apanel, *kq, b, crow, ldc, tile)
            }
        }
        #[cfg(target_arch = "x86_64")]
        (Kernel::Avx512Bf16, APacked::Pairs { data, kq }) => {
            let apanel = &data[i * MR * kq + kb..];
            // SAFETY: forwarded from the caller; the panel holds MR rows of kq u32s.
            unsafe {
                avx512::tile_bf16(
                    kc,
                    apanel.as_ptr(),
                    *kq,
                    bpanel.as_ptr().cast(),
                    prefetch,
                    crow,
                    ldc,
                    tile,
                )
            }
        }
        (Kernel::AmxEmulated | Kernel::Amx, APacked::Pairs { data, kq }) => {
            let apanel = &data[i * amx::ROWS * kq + kb..];
            // The AMX units, or their exact software model: the same steps either way.
            let tile_fn = match kernel {
                #[cfg(target_arch = "x86_64")]
                Kernel::Amx => amx::tile,
                #[cfg(not(target_arch = "x86_64"))]
                Kernel::Amx => unreachable!("AMX is never available off x86-64"),
                _ => amx::tile_emulated,
            };
            // SAFETY: forwarded from the caller (for `Amx`, the tile state was granted before
            // it was packed for); the panel holds `amx::ROWS` rows of kq u32s.
            unsafe {
                tile_fn(
                    kc,
                    apanel.as_ptr(),
                    *kq,
                    bpanel.as_ptr().cast(),
                    crow,
                    ldc,
                    tile,
                )
            }
        }
        _ => unreachable!("A packed for another kernel than {kernel:?}"),
    }
}
