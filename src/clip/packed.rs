//! Products with the model's constant weight matrices, packed once at load time into the
//! micro-kernel's panel layout, with a hand-written AVX2 + FMA micro-kernel.
//!
//! Why hand-written (workplace rule: only where the crate was measured to be the bottleneck).
//! On the 2-core AMD EPYC (Zen 3, AVX2 + FMA, no AVX-512) a `perf record` of
//! `bench_clip --image-only` (ViT-B/32, 3 views, forward + input backward) put 68 % of the
//! cycles in `gemm`'s micro-kernel and 12.5 % in its packing (`gemm_common::…::imp_fastcall`):
//! `gemm` repacks the weight operand on every call, and with m = 150 tokens each weight element
//! packed is used for only 150 multiply-adds. The weights never change, so here each one is
//! packed twice at load — `Wᵀ` for the forward `Y = X · Wᵀ` and `W` for the backward
//! `dX = dY · W` — and a call only packs its activation operand (m × k, m = 150 rows, small).
//! Measured with `bench_clip --reps 5`, both engines interleaved in one run on that machine
//! (shared, GEMM peak 165–172 GFLOPS in the run): image forward + backward 0.379 s with the
//! `gemm` crate (76 % of peak, 0.740 CPU s) against 0.327 s here (89 %, 0.652 CPU s); with
//! one thread this micro-kernel runs at 85–94 GFLOPS, level with or above `gemm`'s 2048³.
//!
//! Blocking (BLIS-style, one level since m is small): the micro-kernel computes a 6 × 16 tile
//! of C in 12 ymm accumulators from a 6-row panel of packed A (`[kc][6]`) and a 16-column panel
//! of packed B (`[kc][16]`), kc ≤ KC = 256: the B micro-panel (16 KiB) stays in the 32 KiB L1
//! while the 6-row A panels stream past it, and the A block (≤ MC = 168 rows × KC, 168 KiB;
//! m = 150 tokens is one block)
//! stays in the 512 KiB L2 while the B panels stream past. Threads (rayon) own disjoint ranges
//! of B's column panels, so every element of C is computed by one thread in the same order
//! whatever the thread count: results are deterministic.
//!
//! Dispatch: `Engine::detect()` picks `Packed` only on x86-64 with AVX2 and FMA and without
//! AVX-512F; with AVX-512 the `gemm` crate's 512-bit kernels are faster than this 256-bit one,
//! and without AVX2 there is no fast kernel here, so `Engine::Crate` (`super::matmul`) is used.
//! The packed path itself runs anywhere (a portable kernel stands in for the AVX2 one), so
//! tests can force either engine on any machine (`with_engine`).

use std::cell::Cell;
use std::mem::MaybeUninit;
use std::ops::Range;

use rayon::prelude::*;

/// Rows of C per micro-tile.
pub const MR: usize = 6;
/// Columns of C per micro-tile, and the width of a packed B panel.
pub const NR: usize = 16;
/// Depth of one pass over C: B micro-panel = KC × NR × 4 B = 16 KiB (half of L1).
const KC: usize = 256;
/// At most this many rows of A are kept in L2 per pass: 168 × KC × 4 B = 168 KiB. A multiple
/// of MR, and above 150 so that three 50-token views are one block (a second block of one
/// panel would re-read every B micro-panel from L3 for a single tile).
const MC: usize = 168;
/// Products below this many multiply-adds run on the calling thread.
const PARALLEL_MIN_MACS: usize = 1 << 20;

/// How `Linear` layers store their weights and multiply with them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Engine {
    /// Weights packed at load (`PackedB`), products in this file.
    Packed,
    /// Weights stored plainly, products by the `gemm` crate (`super::matmul`).
    Crate,
}

thread_local! {
    static OVERRIDE: Cell<Option<Engine>> = const { Cell::new(None) };
}

impl Engine {
    /// The faster engine on this machine (see the module comment).
    pub fn detect() -> Engine {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
                && !std::arch::is_x86_feature_detected!("avx512f")
            {
                return Engine::Packed;
            }
        }
        Engine::Crate
    }

    /// What layers built now on this thread use: the `with_engine` override, else `detect()`.
    pub fn current() -> Engine {
        OVERRIDE.with(Cell::get).unwrap_or_else(Engine::detect)
    }
}

/// Run `f` with `Engine::current()` returning `engine` on this thread (for tests and
/// benchmarks that compare the two engines; models built inside `f` keep the engine).
pub fn with_engine<R>(engine: Engine, f: impl FnOnce() -> R) -> R {
    struct Restore(Option<Engine>);
    impl Drop for Restore {
        fn drop(&mut self) {
            OVERRIDE.with(|o| o.set(self.0));
        }
    }
    let _restore = Restore(OVERRIDE.with(|o| o.replace(Some(engine))));
    f()
}

/// One k-row of a packed B panel: a 64-byte cache line, so panel rows are aligned loads.
#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct Line([f32; NR]);

/// A k × n matrix B in the micro-kernel's layout: ⌈n / NR⌉ column panels back to back, panel
/// `j` being `[k][NR]` (columns `j·NR .. j·NR + NR`, zero past n). A row range of B is then a
/// contiguous range of every panel, so one packed copy serves any k sub-range too.
pub struct PackedB {
    k: usize,
    n: usize,
    /// `[panels][k]` lines.
    lines: Vec<Line>,
}

impl PackedB {
    /// From B stored row-major `[k, n]`: `B[p][j] = b[p·n + j]`.
    pub fn from_rows(b: &[f32], k: usize, n: usize) -> PackedB {
        assert_eq!(b.len(), k * n, "PackedB::from_rows: size");
        PackedB::build(k, n, |p, j| b[p * n + j])
    }

    /// From Bᵀ stored row-major `[n, k]` (a checkpoint `[out, in]` weight is `(Wᵀ)ᵀ`):
    /// `B[p][j] = bt[j·k + p]`.
    pub fn from_cols(bt: &[f32], k: usize, n: usize) -> PackedB {
        assert_eq!(bt.len(), k * n, "PackedB::from_cols: size");
        PackedB::build(k, n, |p, j| bt[j * k + p])
    }

    fn build(k: usize, n: usize, at: impl Fn(usize, usize) -> f32 + Sync) -> PackedB {
        let panels = n.div_ceil(NR);
        let mut lines = vec![Line([0.0; NR]); panels * k];
        if k > 0 {
            lines.par_chunks_mut(k).enumerate().for_each(|(jp, panel)| {
                let cols = NR.min(n - jp * NR);
                // Column-outer: with `from_cols` each column is a contiguous source row.
                for c in 0..cols {
                    for (p, line) in panel.iter_mut().enumerate() {
                        line.0[c] = at(p, jp * NR + c);
                    }
                }
            });
        }
        PackedB { k, n, lines }
    }

    pub fn k(&self) -> usize {
        self.k
    }
    pub fn n(&self) -> usize {
        self.n
    }

    /// B as a flat slice (panel-major, see the type).
    fn flat(&self) -> &[f32] {
        // SAFETY: `Line` is `repr(C)` around `[f32; NR]` with alignment 64 = its size, so the
        // lines are contiguous f32s without padding.
        unsafe {
            std::slice::from_raw_parts(self.lines.as_ptr().cast::<f32>(), self.lines.len() * NR)
        }
    }
}

/// Which micro-kernel runs the tiles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kernel {
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
    Portable,
}

impl Kernel {
    fn best() -> Kernel {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                return Kernel::Avx2Fma;
            }
        }
        Kernel::Portable
    }
}

/// `C = (accumulate ? C : 0) + A · B[ks, cols] (+ bias[cols])`, with
/// - `C`: m × `cols.len()`, row-major with leading dimension `ldc` (column 0 of C is column
///   `cols.start` of B);
/// - `A`: m × `ks.len()`, row-major with leading dimension `lda` (column 0 of A multiplies row
///   `ks.start` of B);
/// - `bias`: indexed by B's column, length `b.n()`.
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
    gemm_with(
        Kernel::best(),
        c,
        ldc,
        a,
        lda,
        m,
        b,
        ks,
        cols,
        bias,
        accumulate,
    );
}

/// A `*mut f32` that may cross threads: each thread writes a disjoint set of C's columns.
#[derive(Clone, Copy)]
struct SendPtr(*mut f32);
// SAFETY: only used for C in `gemm_with`, where threads own disjoint column panels.
unsafe impl Send for SendPtr {}
unsafe impl Sync for SendPtr {}

impl SendPtr {
    /// A method, so that closures capture the whole `SendPtr` (a field access would capture
    /// the bare pointer, which is not `Send`).
    fn get(self) -> *mut f32 {
        self.0
    }
}

#[allow(clippy::too_many_arguments)]
fn gemm_with(
    kernel: Kernel,
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
            kernel,
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
        )
    }
}

/// `gemm` into a new `[m, cols.len()]` matrix (`ldc = cols.len()`), never zero-filled first:
/// every element is written by the first k-block.
pub fn gemm_new(
    a: &[f32],
    lda: usize,
    m: usize,
    b: &PackedB,
    ks: Range<usize>,
    cols: Range<usize>,
    bias: Option<&[f32]>,
) -> Vec<f32> {
    let n = cols.len();
    if m == 0 || n == 0 || ks.is_empty() {
        let mut c = vec![0.0; m * n];
        gemm(&mut c, n, a, lda, m, b, ks, cols, bias, false);
        return c;
    }
    let mut c = Vec::with_capacity(m * n);
    // SAFETY: the buffer has capacity m·n; with `accumulate` false and k > 0, `gemm_raw`
    // writes every element of the m × n matrix (the first k-block overwrites all tiles) and
    // reads only elements it wrote, so the whole length is initialized afterwards.
    unsafe {
        gemm_raw(
            Kernel::best(),
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
        );
        c.set_len(m * n);
    }
    c
}

/// The product itself, for m, n, k > 0.
///
/// # Safety
/// `c` is valid for reads and writes of `c_len` floats and not aliased during the call;
/// elements are read only where `accumulate` is set (then they must be initialized) or after
/// this call wrote them.
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_raw(
    kernel: Kernel,
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
) {
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

    // Packed A, panel-major: panel i (rows i·MR ..) is `[k][MR]`, rows past m zero. Every
    // element is written below, so the buffer is not zero-filled first.
    let panels_m = m.div_ceil(MR);
    let mut ap: Vec<f32> = Vec::with_capacity(panels_m * k * MR);
    let pack = |(i, dst): (usize, &mut [MaybeUninit<f32>])| {
        let valid = MR.min(m - i * MR);
        // Destination order (one contiguous MR-group per k step, six row streams in): this
        // was 3 % of the image pass written row by row with strided stores.
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
    let parallel = m * n * k >= PARALLEL_MIN_MACS && rayon::current_num_threads() > 1;
    let spare = &mut ap.spare_capacity_mut()[..panels_m * k * MR];
    if parallel {
        spare.par_chunks_mut(k * MR).enumerate().for_each(pack);
    } else {
        spare.chunks_mut(k * MR).enumerate().for_each(pack);
    }
    // SAFETY: `pack` wrote all MR × k elements of every panel.
    unsafe { ap.set_len(panels_m * k * MR) };

    let (p0, p1) = (cols.start / NR, cols.end.div_ceil(NR));
    let threads = if parallel {
        rayon::current_num_threads().min(p1 - p0)
    } else {
        1
    };
    let cp = SendPtr(c);
    // Row panels per A block: the fewest blocks of at most MC rows, of balanced sizes.
    let per_block = panels_m.div_ceil(panels_m.div_ceil(MC / MR));
    let bflat = b.flat();
    let ap = &ap[..];
    let cols = &cols;
    let run = |t: usize| {
        let (j0, j1) = (
            p0 + t * (p1 - p0) / threads,
            p0 + (t + 1) * (p1 - p0) / threads,
        );
        for kb in (0..k).step_by(KC) {
            let kc = KC.min(k - kb);
            let first = kb == 0;
            for ib in (0..panels_m).step_by(per_block) {
                for j in j0..j1 {
                    // Tile columns j·NR .. j·NR + NR of B, clipped to `cols`.
                    let lo = cols.start.max(j * NR) - j * NR;
                    let hi = cols.end.min(j * NR + NR) - j * NR;
                    let mut tile_bias = [0.0f32; NR];
                    if let (true, Some(bias)) = (first, bias) {
                        let bn = NR.min(b.n - j * NR);
                        tile_bias[..bn].copy_from_slice(&bias[j * NR..][..bn]);
                    }
                    let bpanel = &bflat[(j * b.k + ks.start + kb) * NR..][..kc * NR];
                    // The B micro-panel that comes next (the next column panel, or the
                    // first one of the next k-block): the tiles below prefetch it into L2,
                    // a share each, so that its first tile does not wait on memory (weights
                    // are far larger than the caches and are read once per call).
                    let next = if j + 1 < j1 {
                        Some((j + 1, kb, kc))
                    } else if kb + KC < k {
                        Some((j0, kb + KC, KC.min(k - kb - KC)))
                    } else {
                        None
                    };
                    let next = next.map_or(&[][..], |(jn, kbn, kcn)| {
                        &bflat[(jn * b.k + ks.start + kbn) * NR..][..kcn * NR]
                    });
                    let i_end = (ib + per_block).min(panels_m);
                    let share = (next.len() / NR).div_ceil(i_end - ib) * NR;
                    for i in ib..i_end {
                        let apanel = &ap[(i * k + kb) * MR..][..kc * MR];
                        let pf_start = ((i - ib) * share).min(next.len());
                        let prefetch = &next[pf_start..(pf_start + share).min(next.len())];
                        let tile = Tile {
                            rows: MR.min(m - i * MR),
                            lo,
                            hi,
                            // Offset of tile column 0 in C's row; < 0 only when lo > 0.
                            col0: (j * NR) as isize - cols.start as isize,
                            bias: (first && bias.is_some()).then_some(&tile_bias),
                            add: !first || accumulate,
                        };
                        // SAFETY: row i·MR of C starts inside `c` (i·MR < m); the tile
                        // writes rows < m and C columns col0 + lo .. col0 + hi, which lie in
                        // 0 .. n ≤ ldc by the clipping above, so inside the asserted bounds.
                        // Threads own disjoint panel ranges j0..j1, hence disjoint columns.
                        // The kernel choice was detected on this machine.
                        unsafe {
                            let crow = cp.get().add(i * MR * ldc);
                            run_tile(kernel, kc, apanel, bpanel, prefetch, crow, ldc, &tile);
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
struct Tile<'a> {
    /// Valid rows (≤ MR).
    rows: usize,
    /// Valid tile columns `lo .. hi` (⊆ 0 .. NR).
    lo: usize,
    hi: usize,
    /// C column of tile column 0.
    col0: isize,
    /// Added to every row (first k-block only).
    bias: Option<&'a [f32; NR]>,
    /// Add to C rather than overwrite it.
    add: bool,
}

impl Tile<'_> {
    fn full(&self) -> bool {
        self.rows == MR && self.lo == 0 && self.hi == NR
    }

    /// Write an accumulated tile `acc [MR][NR]` into C through the general (edge) path.
    ///
    /// # Safety
    /// `crow` is C's row of the tile's first row; rows `< self.rows` and columns
    /// `col0 + lo .. col0 + hi` of it (leading dimension `ldc`) must be writable.
    unsafe fn store_scalar(&self, acc: &[f32; MR * NR], crow: *mut f32, ldc: usize) {
        for r in 0..self.rows {
            for cc in self.lo..self.hi {
                let v = acc[r * NR + cc] + self.bias.map_or(0.0, |b| b[cc]);
                // SAFETY: inside the region the caller guarantees.
                let dst = unsafe { crow.offset((r * ldc) as isize + self.col0 + cc as isize) };
                unsafe {
                    *dst = if self.add { *dst + v } else { v };
                }
            }
        }
    }
}

/// `prefetch`: part of the next B micro-panel, to be brought into L2 (a hint only).
///
/// # Safety
/// As `Tile::store_scalar`; for `Kernel::Avx2Fma` the CPU must have AVX2 and FMA.
#[allow(clippy::too_many_arguments)]
unsafe fn run_tile(
    kernel: Kernel,
    kc: usize,
    a: &[f32],
    b: &[f32],
    prefetch: &[f32],
    crow: *mut f32,
    ldc: usize,
    tile: &Tile,
) {
    debug_assert!(a.len() >= kc * MR && b.len() >= kc * NR);
    match kernel {
        // SAFETY: forwarded from the caller.
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2Fma => unsafe {
            avx2::tile(kc, a.as_ptr(), b.as_ptr(), prefetch, crow, ldc, tile)
        },
        Kernel::Portable => {
            let _ = prefetch;
            let mut acc = [0.0f32; MR * NR];
            for (ap, bp) in a[..kc * MR]
                .chunks_exact(MR)
                .zip(b[..kc * NR].chunks_exact(NR))
            {
                for (r, &av) in ap.iter().enumerate() {
                    for (x, &bv) in acc[r * NR..][..NR].iter_mut().zip(bp) {
                        *x = av.mul_add(bv, *x);
                    }
                }
            }
            // SAFETY: forwarded from the caller.
            unsafe { tile.store_scalar(&acc, crow, ldc) }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{Tile, MR, NR};

    /// The 6 × 16 micro-kernel: 12 ymm accumulators (row r in `c[2r]`, `c[2r + 1]`), per k step
    /// two aligned loads of B, six broadcasts of A and twelve FMAs, which keeps both of Zen 3's
    /// FMA pipes busy (the 4 other ymm registers hold B and a broadcast).
    ///
    /// # Safety
    /// AVX2 and FMA present; `a` readable for `kc·MR` floats, `b` for `kc·NR` floats and
    /// 32-byte aligned; C as in `Tile::store_scalar`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn tile(
        kc: usize,
        a: *const f32,
        b: *const f32,
        prefetch: &[f32],
        crow: *mut f32,
        ldc: usize,
        t: &Tile,
    ) {
        // Prefetches are hints: they never fault, whatever the address.
        for line in prefetch.chunks(NR) {
            _mm_prefetch::<_MM_HINT_T1>(line.as_ptr().cast());
        }
        if t.full() {
            // C's tile is read (or written) after the loop; start fetching it now.
            for r in 0..MR {
                let row = crow.wrapping_offset((r * ldc) as isize + t.col0);
                _mm_prefetch::<_MM_HINT_T0>(row.cast());
                _mm_prefetch::<_MM_HINT_T0>(row.wrapping_add(NR - 1).cast());
            }
        }
        let mut c = [_mm256_setzero_ps(); 2 * MR];
        for p in 0..kc {
            // SAFETY: p < kc, so these reads stay within the panels the caller guarantees;
            // B lines are 64-byte aligned.
            unsafe {
                let b0 = _mm256_load_ps(b.add(p * NR));
                let b1 = _mm256_load_ps(b.add(p * NR + 8));
                for r in 0..MR {
                    let av = _mm256_broadcast_ss(&*a.add(p * MR + r));
                    c[2 * r] = _mm256_fmadd_ps(av, b0, c[2 * r]);
                    c[2 * r + 1] = _mm256_fmadd_ps(av, b1, c[2 * r + 1]);
                }
            }
        }
        if let Some(bias) = t.bias {
            // SAFETY: a 16-float array.
            let (b0, b1) = unsafe {
                (
                    _mm256_loadu_ps(bias.as_ptr()),
                    _mm256_loadu_ps(bias.as_ptr().add(8)),
                )
            };
            for r in 0..MR {
                c[2 * r] = _mm256_add_ps(c[2 * r], b0);
                c[2 * r + 1] = _mm256_add_ps(c[2 * r + 1], b1);
            }
        }
        if t.full() {
            for r in 0..MR {
                // SAFETY: a full tile: rows 0..MR and columns col0 .. col0 + NR (col0 ≥ 0
                // since lo = 0) are inside C by the caller's guarantee.
                unsafe {
                    let dst = crow.offset((r * ldc) as isize + t.col0);
                    let (mut v0, mut v1) = (c[2 * r], c[2 * r + 1]);
                    if t.add {
                        v0 = _mm256_add_ps(v0, _mm256_loadu_ps(dst));
                        v1 = _mm256_add_ps(v1, _mm256_loadu_ps(dst.add(8)));
                    }
                    _mm256_storeu_ps(dst, v0);
                    _mm256_storeu_ps(dst.add(8), v1);
                }
            }
        } else {
            let mut acc = [0.0f32; MR * NR];
            for (r, v) in c.iter().enumerate() {
                // SAFETY: 2·MR vectors of 8 fill the MR·NR array exactly.
                unsafe { _mm256_storeu_ps(acc.as_mut_ptr().add(r * 8), *v) };
            }
            // The bias is already in the accumulators.
            let t = Tile { bias: None, ..*t };
            // SAFETY: forwarded from the caller.
            unsafe { t.store_scalar(&acc, crow, ldc) }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// C = base + A·B (+ bias) in f64, B given row-major [k, n].
    #[allow(clippy::too_many_arguments)]
    fn naive(
        base: &[f32],
        a: &[f32],
        b: &[f32],
        m: usize,
        n: usize,
        k: usize,
        bias: Option<&[f32]>,
    ) -> Vec<f64> {
        let mut c: Vec<f64> = base.iter().map(|&v| v as f64).collect();
        for i in 0..m {
            for j in 0..n {
                let s: f64 = (0..k)
                    .map(|p| a[i * k + p] as f64 * b[p * n + j] as f64)
                    .sum();
                c[i * n + j] += s + bias.map_or(0.0, |b| b[j] as f64);
            }
        }
        c
    }

    fn values(len: usize, seed: usize, scale: f32) -> Vec<f32> {
        (0..len)
            .map(|i| ((((i + seed) * 2654435761usize) % 2001) as f32 / 1000.0 - 1.0) * scale)
            .collect()
    }

    fn kernels() -> Vec<Kernel> {
        let mut k = vec![Kernel::Portable];
        if Kernel::best() != Kernel::Portable {
            k.push(Kernel::best());
        }
        k
    }

    /// Error bound of an f32 dot product of length k against the f64 value: ~k·ε·Σ|a||b|,
    /// here bounded with the magnitudes used.
    fn check(got: &[f32], want: &[f64], tol: f64, what: &str) {
        for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
            assert!(
                (g as f64 - w).abs() <= tol * (1.0 + w.abs()),
                "{what}: element {i}: {g} vs {w}"
            );
        }
    }

    #[test]
    fn odd_shapes_overwrite_and_accumulate_match_f64() {
        let shapes = [
            (1, 1, 1),
            (5, 7, 3),
            (7, 17, 1),
            (6, 16, 256),
            (17, 33, 257),
            (150, 151, 770),
            (151, 150, 513),
            (1, 40, 770),
        ];
        for kernel in kernels() {
            for &(m, n, k) in &shapes {
                let a = values(m * k, 1, 1.0);
                let b = values(k * n, 2, 1.0);
                let bias = values(n, 3, 1.0);
                let pb = PackedB::from_rows(&b, k, n);
                // The same B given transposed packs to the same thing.
                let mut bt = vec![0.0; k * n];
                for p in 0..k {
                    for j in 0..n {
                        bt[j * k + p] = b[p * n + j];
                    }
                }
                let pbt = PackedB::from_cols(&bt, k, n);
                assert!(pb.flat() == pbt.flat());
                let tol = 1e-6 * (k as f64).sqrt().max(1.0) * 4.0;
                let base = values(m * n, 4, 2.0);
                let what = format!("{kernel:?} {m}x{n}x{k}");
                for bias in [None, Some(&bias[..])] {
                    let mut c = vec![f32::NAN; m * n];
                    gemm_with(kernel, &mut c, n, &a, k, m, &pb, 0..k, 0..n, bias, false);
                    check(
                        &c,
                        &naive(&vec![0.0; m * n], &a, &b, m, n, k, bias),
                        tol,
                        &what,
                    );
                    let mut c = base.clone();
                    gemm_with(kernel, &mut c, n, &a, k, m, &pb, 0..k, 0..n, bias, true);
                    check(&c, &naive(&base, &a, &b, m, n, k, bias), tol, &what);
                }
            }
        }
    }

    /// Sub-ranges of B's rows and (unaligned) columns, strided A and C, k = 0.
    #[test]
    fn sub_ranges_and_strides() {
        let (m, n, k) = (13, 45, 70);
        let b = values(k * n, 5, 1.0);
        let pb = PackedB::from_rows(&b, k, n);
        let bias = values(n, 6, 1.0);
        for kernel in kernels() {
            for (ks, cols) in [
                (0..k, 0..n),
                (3..70, 5..40),
                (16..33, 16..32),
                (7..8, 44..45),
            ] {
                let (kk, nn) = (ks.len(), cols.len());
                let (lda, ldc) = (kk + 3, nn + 2);
                let a = values(m * lda, 7, 1.0);
                let mut c = values(m * ldc, 8, 1.0);
                let before = c.clone();
                gemm_with(
                    kernel,
                    &mut c,
                    ldc,
                    &a,
                    lda,
                    m,
                    &pb,
                    ks.clone(),
                    cols.clone(),
                    Some(&bias),
                    true,
                );
                for i in 0..m {
                    for j in 0..ldc {
                        let got = c[i * ldc + j];
                        if j >= nn {
                            assert_eq!(got.to_bits(), before[i * ldc + j].to_bits(), "padding");
                            continue;
                        }
                        let bj = cols.start + j;
                        let want: f64 = before[i * ldc + j] as f64
                            + bias[bj] as f64
                            + (0..kk)
                                .map(|p| a[i * lda + p] as f64 * b[(ks.start + p) * n + bj] as f64)
                                .sum::<f64>();
                        assert!(
                            (got as f64 - want).abs() < 1e-5 * (1.0 + want.abs()),
                            "{kernel:?} {ks:?} {cols:?}"
                        );
                    }
                }
            }
            // k = 0: C = bias (overwrite) or C + bias (accumulate).
            let mut c = vec![1.0f32; 2 * n];
            gemm_with(
                kernel,
                &mut c,
                n,
                &[],
                0,
                2,
                &pb,
                4..4,
                0..n,
                Some(&bias),
                true,
            );
            assert!(c
                .iter()
                .zip(bias.iter().cycle())
                .all(|(c, b)| *c == 1.0 + b));
            gemm_with(kernel, &mut c, n, &[], 0, 2, &pb, 4..4, 0..n, None, false);
            assert!(c.iter().all(|&c| c == 0.0));
        }
    }

    #[test]
    fn zeros_and_large_magnitudes() {
        let (m, n, k) = (9, 20, 40);
        for kernel in kernels() {
            let pb = PackedB::from_rows(&vec![0.0; k * n], k, n);
            let a = values(m * k, 1, 1e30);
            let mut c = vec![f32::NAN; m * n];
            gemm_with(kernel, &mut c, n, &a, k, m, &pb, 0..k, 0..n, None, false);
            assert!(c.iter().all(|&v| v == 0.0), "overwrite ignores old C");
            // Large but finite products: 1e18 · 1e18 summed over 40 terms stays below f32::MAX.
            let a = values(m * k, 2, 1e18);
            let b = values(k * n, 3, 1e18);
            let pb = PackedB::from_rows(&b, k, n);
            gemm_with(kernel, &mut c, n, &a, k, m, &pb, 0..k, 0..n, None, false);
            let want = naive(&vec![0.0; m * n], &a, &b, m, n, k, None);
            for (&g, &w) in c.iter().zip(&want) {
                assert!(
                    g.is_finite() && (g as f64 - w).abs() <= 1e-5 * 1e36 * k as f64,
                    "{g} vs {w}"
                );
            }
        }
    }

    #[test]
    fn threaded_equals_single_threaded_bit_for_bit() {
        let (m, n, k) = (150, 200, 300);
        let a = values(m * k, 1, 1.0);
        let pb = PackedB::from_rows(&values(k * n, 2, 1.0), k, n);
        let mut par = vec![0.0; m * n];
        gemm(&mut par, n, &a, k, m, &pb, 0..k, 0..n, None, false);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let mut one = vec![0.0; m * n];
        pool.install(|| gemm(&mut one, n, &a, k, m, &pb, 0..k, 0..n, None, false));
        assert!(par
            .iter()
            .zip(&one)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn engine_override_is_scoped() {
        let outer = Engine::current();
        with_engine(Engine::Crate, || {
            assert_eq!(Engine::current(), Engine::Crate);
            with_engine(Engine::Packed, || {
                assert_eq!(Engine::current(), Engine::Packed)
            });
            assert_eq!(Engine::current(), Engine::Crate);
        });
        assert_eq!(Engine::current(), outer);
    }
}
