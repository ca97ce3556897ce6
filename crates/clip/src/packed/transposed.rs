//! The transposed product `C = A · Bᵀ` on B's forward panels: the input backward of a layer
//! that keeps one copy of its weight.

use std::ops::Range;

use rayon::prelude::*;

use super::*;

/// `C = A · B[.., cols]ᵀ` into a new `[m, b.k()]` matrix, with
/// - `A`: m × `cols.len()`, row-major with leading dimension `lda` (column 0 of A multiplies
///   column `cols.start` of B);
/// - `B`: the packed k × n matrix of a forward product, read transposed in place.
///
/// The input backward of a layer that keeps one copy of its weight: the forward packs `Wᵀ`
/// (k = in, n = out) for `Y = X · Wᵀ`, and `dX = dY · W` is this product on the same panels.
/// f32 kernels only (a bf16 panel pairs B's rows, the backward would need its columns paired).
///
/// Computed as `Cᵀ = B · Aᵀ` (see `transposed_product`): B's panels are row panels of the left
/// operand, read in place by the AVX-512 kernel (rows `nr` floats apart, the k steps of one
/// panel contiguous) and copied per call for the interleaved AVX2 and scalar kernels; `Aᵀ`,
/// small (m = 150 rows of activations), is packed per call as B always is. Threads split B's
/// rows (C's columns), so every element of C is computed by one thread in the same order
/// whatever the thread count.
pub fn gemm_t(a: &[f32], lda: usize, m: usize, b: &PackedB, cols: Range<usize>) -> Vec<f32> {
    gemm_t_post(a, lda, m, b, cols, None)
}

/// `gemm_t` with `post(row, 0, values)` applied to every row of C once it is final.
pub(crate) fn gemm_t_post(
    a: &[f32],
    lda: usize,
    m: usize,
    b: &PackedB,
    cols: Range<usize>,
    post: Option<Post>,
) -> Vec<f32> {
    let kernel = b.kernel;
    assert!(
        !kernel.bf16(),
        "packed::gemm_t: {} pairs B's rows; a transposed product needs an f32 kernel",
        kernel.name()
    );
    assert!(cols.end <= b.n, "packed::gemm_t: B range");
    let (n, k) = (b.k, cols.len());
    if m > 0 && k > 0 {
        assert!(
            lda >= k && a.len() >= (m - 1) * lda + k,
            "packed::gemm_t: A too small"
        );
    }
    let mut c = vec![0.0f32; m * n];
    if m > 0 && n > 0 && k > 0 {
        // Cᵀ (n × m) = B[.., cols] (n × k, read from the panels) · Aᵀ (k × m, packed here),
        // each tile written into C transposed.
        transposed_product(&mut c, b, cols.start, a, lda, k, m);
    }
    if let (Some(post), true) = (post, n > 0) {
        for (row, values) in c.chunks_exact_mut(n).enumerate() {
            post(row, 0, values);
        }
    }
    c
}

/// `Aᵀ` packed as the right operand of `transposed_product`: `n` rows of `k` floats at stride
/// `ld` (`AT[p][j] = a[j·ld + p]`) into ⌈n / nr⌉ panels `[k][nr]`, zero past n. Written a block
/// of k rows at a time, so that the panel rows being filled stay in L1 while each source row
/// is read contiguously.
pub(super) fn pack_transposed(a: &[f32], ld: usize, k: usize, n: usize, nr: usize) -> Vec<Line> {
    let panel_lines = k * nr / 16;
    let mut lines = vec![Line([0.0; 16]); n.div_ceil(nr) * panel_lines];
    let pack = |(jp, panel): (usize, &mut [Line])| {
        // SAFETY: as in `PackedB::build`: the lines are contiguous f32s without padding.
        let panel: &mut [f32] =
            unsafe { std::slice::from_raw_parts_mut(panel.as_mut_ptr().cast(), panel.len() * 16) };
        const ROWS: usize = 64;
        for p0 in (0..k).step_by(ROWS) {
            let p1 = (p0 + ROWS).min(k);
            for c in 0..nr.min(n - jp * nr) {
                let src = &a[(jp * nr + c) * ld..][p0..p1];
                for (p, &v) in (p0..p1).zip(src) {
                    panel[p * nr + c] = v;
                }
            }
        }
    };
    if k * n >= 1 << 16 && rayon::current_num_threads() > 1 {
        lines.par_chunks_mut(panel_lines).enumerate().for_each(pack);
    } else {
        lines.chunks_mut(panel_lines).enumerate().for_each(pack);
    }
    lines
}

/// `c[j][i] = Σ_p B[i][c0 + p] · A[j][p]` for p < k, j < m: `c` is `m × b.k` row-major, B the
/// packed k × n matrix read with its rows as the left operand's rows (row i of B is row i of
/// every column panel: `nr` floats, one panel's columns), A m × k at stride `lda`. Computed
/// as `cᵀ = B · Aᵀ` in tiles of `cᵀ` written transposed.
///
/// The AVX-512 kernel here is 4 × 80 (`avx512::tile_f32_t`): the right operand has m = 150
/// columns (3 views × 50 tokens), which 6 × 64 tiles would pad to 192 (28 % of the products
/// wasted), 80-column ones to 160. The AVX2 kernel keeps its 6 × 16 tiles with the left
/// operand read in place (`transposed_avx2`); the scalar one packs it per call.
///
/// k-blocks never cross a B panel except at its start: a block starts at a column of B that
/// is a multiple of `NR_MAX` and spans up to `kc` columns (whole panels: the AVX-512 kernel
/// walks them as chunks), or is the part of one 64-column panel before the first such column.
/// The blocks do not depend on the kernel, so the AVX2 and AVX-512 kernels add the same
/// products in the same order (identical bits, as in `gemm`).
pub(super) fn transposed_product(
    c: &mut [f32],
    b: &PackedB,
    c0: usize,
    a: &[f32],
    lda: usize,
    k: usize,
    m: usize,
) {
    let kernel = b.kernel;
    let nr = kernel.nr();
    let rows_c = b.k;
    // The tile: rows of B (of C) × columns of Aᵀ (of C).
    let (tr, tn) = match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512F => (avx512::MR_T, avx512::NR_T),
        _ => (MR, nr),
    };
    let at = pack_transposed(a, lda, k, m, tn);
    let panels_m = rows_c.div_ceil(tr);
    let panels_n = m.div_ceil(tn);
    let mut blocks = Vec::new();
    let mut s = c0;
    while s < c0 + k {
        let e = if !s.is_multiple_of(NR_MAX) {
            (s.div_ceil(NR_MAX) * NR_MAX).min(c0 + k)
        } else {
            (s + kernel.kc()).min(c0 + k)
        };
        blocks.push(s..e);
        s = e;
    }
    let parallel = rows_c * m * k >= PARALLEL_MIN_MACS && rayon::current_num_threads() > 1;
    let threads = if parallel {
        rayon::current_num_threads().min(panels_m)
    } else {
        1
    };
    let bflat = b.flat();
    // SAFETY: as in `PackedB::flat`.
    let atflat: &[f32] =
        unsafe { std::slice::from_raw_parts(at.as_ptr().cast::<f32>(), at.len() * 16) };
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2Fma {
        let shape = Transposed {
            rows_c,
            c0,
            k,
            m,
            panels_m,
            threads,
        };
        return transposed_avx2(c, bflat, atflat, &blocks, shape);
    }
    let cp = SendPtr(c.as_mut_ptr());
    let blocks = &blocks;
    // B[i][col].
    let at_b = |i: usize, col: usize| bflat[panel_index(rows_c, nr, i, col)];
    let run = |t: usize| {
        let (i0, i1) = (t * panels_m / threads, (t + 1) * panels_m / threads);
        // The left operand where it is copied: `[tiles][kc][MR]` for the interleaved kernels;
        // for the AVX-512 kernel a last partial row panel, as `[chunks][MR_T][64]`.
        let mut pack: Vec<f32> = Vec::new();
        let mut scratch = [0.0f32; MR * 16];
        let per_block = (MC / tr).max(1);
        for ib in (i0..i1).step_by(per_block) {
            let i_end = (ib + per_block).min(i1);
            for (bi, block) in blocks.iter().enumerate() {
                let kc = block.len();
                let interleaved = matches!(kernel, Kernel::Portable | Kernel::Avx2Fma);
                if interleaved {
                    pack.clear();
                    pack.resize((i_end - ib) * kc * MR, 0.0);
                    for (ti, tile) in pack.chunks_exact_mut(kc * MR).enumerate() {
                        let i = (ib + ti) * MR;
                        let valid = MR.min(rows_c - i);
                        for (p, group) in tile.chunks_exact_mut(MR).enumerate() {
                            for (r, g) in group[..valid].iter_mut().enumerate() {
                                *g = at_b(i + r, block.start + p);
                            }
                        }
                    }
                }
                for jb in 0..panels_n {
                    let bpanel = &atflat[(jb * k + block.start - c0) * tn..][..kc * tn];
                    for i in ib..i_end {
                        let rows = tr.min(rows_c - i * tr);
                        let tile = Tile {
                            rows,
                            lo: 0,
                            hi: tn.min(m - jb * tn),
                            col0: (jb * tn) as isize,
                            bias: None,
                            add: bi > 0,
                            nr: tn,
                        };
                        // SAFETY: column i·tr of c is inside its first row (i·tr < rows_c);
                        // the tile writes columns i·tr + (0 .. rows) < rows_c of rows
                        // jb·tn + (0 .. hi) < m of the m × rows_c matrix. Threads own disjoint
                        // row panels i0..i1 of cᵀ, hence disjoint elements of c. The kernel
                        // was checked against this CPU when B was packed.
                        unsafe {
                            let ccol = cp.get().add(i * tr);
                            match kernel {
                                Kernel::Portable | Kernel::Avx2Fma => {
                                    // The kernel's tile into `scratch`, then transposed into c.
                                    let apanel = &pack[(i - ib) * kc * MR..][..kc * MR];
                                    let into = Tile {
                                        lo: 0,
                                        hi: nr,
                                        col0: 0,
                                        add: false,
                                        ..tile
                                    };
                                    let sp = scratch.as_mut_ptr();
                                    match kernel {
                                        #[cfg(target_arch = "x86_64")]
                                        Kernel::Avx2Fma => avx2::tile(
                                            kc,
                                            apanel.as_ptr(),
                                            bpanel.as_ptr(),
                                            &[],
                                            sp,
                                            nr,
                                            &into,
                                        ),
                                        _ => portable::tile_f32(kc, apanel, bpanel, sp, nr, &into),
                                    }
                                    tile.store_transposed(&scratch, ccol, rows_c)
                                }
                                #[cfg(target_arch = "x86_64")]
                                Kernel::Avx512F => {
                                    let (first, kstride) = if rows == tr {
                                        // Rows i·tr .. of B in place: 64 floats apart, the
                                        // next panel `rows_c · 64` floats on.
                                        let at = panel_index(rows_c, nr, i * tr, block.start);
                                        (bflat[at..].as_ptr(), rows_c * nr)
                                    } else {
                                        // A last partial row panel: copied as chunks of
                                        // `MR_T` rows of 64, zero rows.
                                        let chunks = kc.div_ceil(nr);
                                        pack.clear();
                                        pack.resize(chunks * tr * nr, 0.0);
                                        for r in 0..rows {
                                            for p in 0..kc {
                                                pack[(p / nr * tr + r) * nr + p % nr] =
                                                    at_b(i * tr + r, block.start + p);
                                            }
                                        }
                                        (pack.as_ptr(), tr * nr)
                                    };
                                    avx512::tile_f32_t(
                                        kc,
                                        first,
                                        kstride,
                                        bpanel.as_ptr(),
                                        ccol,
                                        rows_c,
                                        &tile,
                                    )
                                }
                                _ => unreachable!("gemm_t checked for an f32 kernel"),
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

/// Where B's element (row `i`, column `col`) is in its packed panels (`PackedB`'s layout:
/// `nr`-column panels of `rows` rows each).
pub(super) fn panel_index(rows: usize, nr: usize, i: usize, col: usize) -> usize {
    ((col / nr) * rows + i) * nr + col % nr
}

/// The shape of a transposed product (`transposed_product`): C is `m × rows_c`, B's columns
/// `c0 .. c0 + k` are summed over, and `threads` threads split the `panels_m` row tiles of Cᵀ.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(super) struct Transposed {
    rows_c: usize,
    c0: usize,
    k: usize,
    m: usize,
    panels_m: usize,
    threads: usize,
}

/// `transposed_product` with the AVX2 kernel: the left operand is read in place from B's
/// panels (`avx2::tile_t`; a last row tile past B's rows from a copy with zero rows), and a
/// thread's rows of Cᵀ are summed over the k-blocks in a buffer laid out as Cᵀ (vector adds,
/// as `gemm` sums C), then written into C transposed once (writing each block's tile into C
/// transposed, as the other kernels do, measures ≈ 3 % slower on Zen 3). The blocks and
/// the order of every sum are those of the other kernels.
#[cfg(target_arch = "x86_64")]
pub(super) fn transposed_avx2(
    c: &mut [f32],
    bflat: &[f32],
    atflat: &[f32],
    blocks: &[Range<usize>],
    shape: Transposed,
) {
    const NR: usize = avx2::NR;
    let Transposed {
        rows_c,
        c0,
        k,
        m,
        panels_m,
        threads,
    } = shape;
    let panels_n = m.div_ceil(NR);
    let ldo = panels_n * NR;
    let cp = SendPtr(c.as_mut_ptr());
    let per_block = MC / MR;
    let run = |t: usize| {
        let (i0, i1) = (t * panels_m / threads, (t + 1) * panels_m / threads);
        // Cᵀ's rows of one row block, `[rows][ldo]`: 168 × 160 floats for m = 150.
        let mut buf = vec![0.0f32; per_block.min(i1 - i0) * MR * ldo];
        // A last partial row tile, as chunks `[chunks][MR][NR]` with zero rows.
        let mut tail: Vec<f32> = Vec::new();
        for ib in (i0..i1).step_by(per_block) {
            let i_end = (ib + per_block).min(i1);
            for (bi, block) in blocks.iter().enumerate() {
                let (kc, off) = (block.len(), block.start % NR);
                let partial = i_end * MR > rows_c;
                if partial {
                    let (i, first) = (i_end - 1, block.start - off);
                    tail.clear();
                    tail.resize((off + kc).div_ceil(NR) * MR * NR, 0.0);
                    for r in 0..rows_c - i * MR {
                        for col in block.clone() {
                            let q = (col - first) / NR;
                            tail[(q * MR + r) * NR + (col - first) % NR] =
                                bflat[panel_index(rows_c, NR, i * MR + r, col)];
                        }
                    }
                }
                for jb in 0..panels_n {
                    let bpanel = &atflat[(jb * k + block.start - c0) * NR..][..kc * NR];
                    for i in ib..i_end {
                        let (first, kstride) = if (i + 1) * MR <= rows_c {
                            // Rows i·MR .. of B in place: 16 floats apart, the next panel
                            // `rows_c · 16` floats on.
                            let at = panel_index(rows_c, NR, i * MR, block.start - off);
                            (bflat[at..].as_ptr(), rows_c * NR)
                        } else {
                            (tail.as_ptr(), MR * NR)
                        };
                        let out =
                            &mut buf[((i - ib) * MR) * ldo + jb * NR..][..(MR - 1) * ldo + NR];
                        let (o, b) = (out.as_mut_ptr(), bpanel.as_ptr());
                        // SAFETY: the kernel was checked against this CPU when B was packed;
                        // every chunk the block touches holds MR rows of NR floats (B's panels
                        // for a full tile, `tail` otherwise); the Aᵀ panel holds kc·NR floats,
                        // 64-byte aligned; `out` holds MR rows of NR floats at stride ldo.
                        unsafe { avx2::tile_t(kc, first, off, kstride, b, o, ldo, bi > 0) }
                    }
                }
            }
            let (x0, x1) = (ib * MR, (i_end * MR).min(rows_c));
            for j in 0..m {
                // SAFETY: row j < m of the m × rows_c matrix C, columns x0 .. x1 < rows_c:
                // threads own disjoint row tiles i0..i1 of Cᵀ, hence disjoint columns of C.
                let row = unsafe {
                    std::slice::from_raw_parts_mut(cp.get().add(j * rows_c + x0), x1 - x0)
                };
                for (x, v) in row.iter_mut().enumerate() {
                    *v = buf[x * ldo + j];
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
