//! Packing: B once at load into a kernel's panels (`PackedB`), A per call (`pack_a`), and
//! the bf16 rounding both use.

use std::mem::MaybeUninit;

use rayon::prelude::*;

use super::*;

/// One k-row (or part of one) of a packed B panel: a 64-byte cache line, so panel rows are
/// aligned loads. bf16 panels hold u32 bit patterns in the same lines.
#[repr(C, align(64))]
#[derive(Clone, Copy)]
pub(super) struct Line(pub(super) [f32; 16]);

/// A k × n matrix B in a kernel's layout: ⌈n / NR⌉ column panels back to back, panel `j` being
/// `[rows][NR]` (columns `j·NR .. j·NR + NR`, zero past n), rows = k for f32 and ⌈k / 2⌉ k
/// pairs for bf16. A row range of B is then a contiguous range of every panel, so one packed
/// copy serves any k sub-range too.
pub struct PackedB {
    pub(super) k: usize,
    pub(super) n: usize,
    pub(super) kernel: Kernel,
    /// `[panels][rows][NR / 16]` lines.
    pub(super) lines: Vec<Line>,
}

impl PackedB {
    /// From B stored row-major `[k, n]` (`B[p][j] = b[p·n + j]`), for `kernel` (panics if
    /// the CPU lacks it).
    pub fn from_rows_for(kernel: Kernel, b: &[f32], k: usize, n: usize) -> PackedB {
        assert_eq!(b.len(), k * n, "PackedB::from_rows_for: size");
        PackedB::build(kernel, k, n, |p, j| b[p * n + j])
    }

    /// From Bᵀ stored row-major `[n, k]` (a checkpoint `[out, in]` weight is `(Wᵀ)ᵀ`:
    /// `B[p][j] = bt[j·k + p]`), for `kernel` (panics if the CPU lacks it).
    pub fn from_cols_for(kernel: Kernel, bt: &[f32], k: usize, n: usize) -> PackedB {
        assert_eq!(bt.len(), k * n, "PackedB::from_cols_for: size");
        PackedB::build(kernel, k, n, |p, j| bt[j * k + p])
    }

    fn build(
        kernel: Kernel,
        k: usize,
        n: usize,
        at: impl Fn(usize, usize) -> f32 + Sync,
    ) -> PackedB {
        if let Some(what) = kernel.missing() {
            panic!("PackedB for {}: this CPU lacks {what}", kernel.name());
        }
        PackedB::build_unchecked(kernel, k, n, at)
    }

    /// `from_rows_for` without asking whether the CPU runs `kernel`: for the AMX self-check,
    /// which runs before `Kernel::Amx` counts as available (and decides whether it does).
    pub(super) fn from_rows_unchecked(kernel: Kernel, b: &[f32], k: usize, n: usize) -> PackedB {
        assert_eq!(b.len(), k * n, "PackedB::from_rows_unchecked: size");
        PackedB::build_unchecked(kernel, k, n, |p, j| b[p * n + j])
    }

    fn build_unchecked(
        kernel: Kernel,
        k: usize,
        n: usize,
        at: impl Fn(usize, usize) -> f32 + Sync,
    ) -> PackedB {
        let nr = kernel.nr();
        let rows = packed_rows(kernel, k);
        let panel_lines = rows * nr / 16;
        let mut lines = vec![Line([0.0; 16]); n.div_ceil(nr) * panel_lines];
        if rows > 0 {
            lines
                .par_chunks_mut(panel_lines)
                .enumerate()
                .for_each(|(jp, panel)| {
                    // SAFETY: `Line` is `repr(C)` around `[f32; 16]` with alignment 64 = its
                    // size, so the lines are contiguous f32s without padding.
                    let panel: &mut [f32] = unsafe {
                        std::slice::from_raw_parts_mut(panel.as_mut_ptr().cast(), panel.len() * 16)
                    };
                    let cols = nr.min(n - jp * nr);
                    // Column-outer: with `from_cols_for` each column is a contiguous source row.
                    for c in 0..cols {
                        let col = jp * nr + c;
                        if kernel.bf16() {
                            for q in 0..rows {
                                let lo = bf16_bits(at(2 * q, col)) as u32;
                                let hi = if 2 * q + 1 < k {
                                    bf16_bits(at(2 * q + 1, col)) as u32
                                } else {
                                    0
                                };
                                panel[q * nr + c] = f32::from_bits(lo | hi << 16);
                            }
                        } else {
                            for p in 0..rows {
                                panel[p * nr + c] = at(p, col);
                            }
                        }
                    }
                });
        }
        PackedB {
            k,
            n,
            kernel,
            lines,
        }
    }

    /// The kernel this matrix was packed for (and that multiplies with it).
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// B as a flat slice (panel-major, see the type).
    pub(super) fn flat(&self) -> &[f32] {
        // SAFETY: `Line` is `repr(C)` around `[f32; 16]` with alignment 64 = its size, so the
        // lines are contiguous f32s without padding.
        unsafe {
            std::slice::from_raw_parts(self.lines.as_ptr().cast::<f32>(), self.lines.len() * 16)
        }
    }
}

/// Rows of a packed panel holding k rows of B.
pub(super) fn packed_rows(kernel: Kernel, k: usize) -> usize {
    if kernel.bf16() {
        k.div_ceil(2)
    } else {
        k
    }
}

/// `x` rounded to bf16 (nearest, ties to even), as its 16 bits; NaN stays NaN.
pub(crate) fn bf16_bits(x: f32) -> u16 {
    let u = x.to_bits();
    let rounded = (u.wrapping_add(0x7fff + ((u >> 16) & 1)) >> 16) as u16;
    if x.is_nan() {
        ((u >> 16) as u16) | 0x40
    } else {
        rounded
    }
}

/// `x` rounded to bf16 and widened back: what the bf16 kernels multiply.
pub fn round_bf16(x: f32) -> f32 {
    f32::from_bits((bf16_bits(x) as u32) << 16)
}

/// `dst[q] = bf16(src[2q]) | bf16(src[2q + 1]) << 16`, a missing last element as 0. Written
/// with plain integer operations so that it vectorises (the AVX-512 copy converts 16 pairs per
/// step).
#[inline(always)]
pub(super) fn to_bf16_pairs_body(src: &[f32], dst: &mut [u32]) {
    let full = src.len() / 2;
    let n = full.min(dst.len());
    let (pairs, dst_full) = (&src[..2 * n], &mut dst[..n]);
    for (d, s) in dst_full.iter_mut().zip(pairs.chunks_exact(2)) {
        *d = bf16_bits(s[0]) as u32 | (bf16_bits(s[1]) as u32) << 16;
    }
    if src.len() % 2 == 1 && n < dst.len() {
        dst[n] = bf16_bits(src[src.len() - 1]) as u32;
    }
}

/// Convert a row of A to bf16 pairs (the AVX-512BW copy where the CPU has it, same bits).
pub(super) fn to_bf16_pairs(src: &[f32], dst: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512bw")
    {
        // SAFETY: the CPU has AVX-512F and AVX-512BW (checked just above).
        return unsafe { avx512::to_bf16_pairs(src, dst) };
    }
    to_bf16_pairs_body(src, dst)
}

/// The A operand as the kernel reads it.
pub(super) enum APacked<'a> {
    /// `[panels][k][MR]` f32 (`Portable`, `Avx2Fma`).
    Interleaved { data: Vec<f32>, k: usize },
    /// Row panels of f32 read in place from A (`Avx512F`): full panels at `a[i·MR·lda..]`
    /// with stride `lda`, a last partial one copied into `tail` (`[MR][k]`, zero rows).
    /// Read by the AVX-512 kernel only (x86-64).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    Rows {
        a: &'a [f32],
        lda: usize,
        full: usize,
        tail: Vec<f32>,
        k: usize,
    },
    /// bf16 pairs `[panels·mr][kq]` u32, zero rows past m (the bf16 kernels; `mr` is the
    /// kernel's rows per tile: 6, or AMX's 16).
    Pairs { data: Vec<u32>, kq: usize },
}

/// Pack A (m × k at stride lda, k ≥ 1) for `kernel`; `q0` is the first k pair of the call
/// (bf16: `ks.start / 2`), `shift` = `ks.start % 2` (A's column 0 is the high half of pair q0
/// when the range starts at an odd row of B).
pub(super) fn pack_a<'a>(
    kernel: Kernel,
    a: &'a [f32],
    lda: usize,
    m: usize,
    k: usize,
    shift: usize,
    parallel: bool,
) -> APacked<'a> {
    let mr = kernel.mr();
    let panels_m = m.div_ceil(mr);
    match kernel {
        Kernel::Portable | Kernel::Avx2Fma => {
            // Packed A, panel-major: panel i (rows i·MR ..) is `[k][MR]`, rows past m zero.
            // Every element is written below, so the buffer is not zero-filled first.
            let mut ap: Vec<f32> = Vec::with_capacity(panels_m * k * MR);
            let pack = |(i, dst): (usize, &mut [MaybeUninit<f32>])| {
                let valid = MR.min(m - i * MR);
                // Destination order (one contiguous MR-group per k step, six row streams
                // in): written row by row with strided stores, this packing is a visible
                // share of the image pass.
                let rows: [&[f32]; MR] = std::array::from_fn(|r| {
                    if r < valid {
                        &a[(i * MR + r) * lda..][..k]
                    } else {
                        &[]
                    }
                });
                if valid == MR {
                    for (p, group) in dst.chunks_exact_mut(MR).enumerate() {
                        for (g, row) in group.iter_mut().zip(&rows) {
                            g.write(row[p]);
                        }
                    }
                } else {
                    for (p, group) in dst.chunks_exact_mut(MR).enumerate() {
                        for (r, g) in group.iter_mut().enumerate() {
                            g.write(if r < valid { rows[r][p] } else { 0.0 });
                        }
                    }
                }
            };
            let spare = &mut ap.spare_capacity_mut()[..panels_m * k * MR];
            if parallel {
                spare.par_chunks_mut(k * MR).enumerate().for_each(pack);
            } else {
                spare.chunks_mut(k * MR).enumerate().for_each(pack);
            }
            // SAFETY: `pack` wrote all MR × k elements of every panel.
            unsafe { ap.set_len(panels_m * k * MR) };
            APacked::Interleaved { data: ap, k }
        }
        Kernel::Avx512F => {
            let full = m / MR;
            let mut tail = Vec::new();
            if full < panels_m {
                tail = vec![0.0; MR * k];
                for r in 0..m - full * MR {
                    tail[r * k..][..k].copy_from_slice(&a[(full * MR + r) * lda..][..k]);
                }
            }
            APacked::Rows {
                a,
                lda,
                full,
                tail,
                k,
            }
        }
        Kernel::PortableBf16 | Kernel::Avx512Bf16 | Kernel::AmxEmulated | Kernel::Amx => {
            let kq = (k + shift).div_ceil(2);
            let mut data = vec![0u32; panels_m * mr * kq];
            let convert = |(r, dst): (usize, &mut [u32])| {
                if r < m {
                    let row = &a[r * lda..][..k];
                    if shift == 1 {
                        // A's column 0 is the high half of the first pair.
                        dst[0] = (bf16_bits(row[0]) as u32) << 16;
                        to_bf16_pairs(&row[1..], &mut dst[1..]);
                    } else {
                        to_bf16_pairs(row, dst);
                    }
                }
            };
            if parallel {
                data.par_chunks_mut(kq)
                    .with_min_len(8)
                    .enumerate()
                    .for_each(convert);
            } else {
                data.chunks_mut(kq).enumerate().for_each(convert);
            }
            APacked::Pairs { data, kq }
        }
    }
}
