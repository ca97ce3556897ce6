//! Products with the model's constant weight matrices, packed once at load time into a
//! micro-kernel's panel layout, with hand-written micro-kernels chosen by the CPU at run time:
//! AVX2 + FMA 6 × 16 (`avx2.rs`), AVX-512F 6 × 64 f32 and AVX512_BF16 6 × 64 bf16
//! (`avx512.rs`), and scalar references (`portable.rs`).
//!
//! Why hand-written: the `gemm` crate was the bottleneck of the image pass. A profile of
//! `bench_clip --image-only` (ViT-B/32, 3 views, forward + input backward) on an AVX2 machine put
//! 68 % of the cycles in `gemm`'s micro-kernel and 12.5 % in its packing: `gemm` repacks the weight
//! operand on every call, and with m = 150 tokens each weight element packed is used for only 150
//! multiply-adds. The weights never change, so here each one is packed at load — `Wᵀ` for the
//! forward `Y = X · Wᵀ` and `W` for the backward `dX = dY · W`, or with `Compute::one_copy`
//! only `Wᵀ`, whose panels the backward reads transposed (`gemm_t`) — and a call only packs
//! its activation operand (m × k, m = 150 rows, small). The same holds on AVX-512 CPUs with the 6 × 64
//! zmm kernel (`avx512.rs` for its shape); the timings of every engine are in BENCHMARKS.md
//! ("CLIP", "Image pass").
//!
//! Blocking (BLIS-style, one level since m is small): the micro-kernel computes a 6 × NR tile
//! of C (NR = 16 or 64 columns) from 6 rows of A and an NR-column panel of packed B, kc rows at
//! a time: the B micro-panel (16–64 KiB) stays in L1 (or L2) while the row panels of A stream
//! past it, and the A block (≤ MC = 168 rows × kc) stays in L2 while the B panels stream past.
//! Threads (rayon) own disjoint ranges of B's column panels, so every element of C is computed
//! by one thread in the same order whatever the thread count: results are deterministic.
//!
//! Layouts, one per kernel and chosen when a matrix is packed (`PackedB::from_rows_for`):
//! - `Avx2Fma`, `Portable`: f32, 16-column panels `[k][16]`; A packed per call as `[k][6]`.
//! - `Avx512F`: f32, 64-column panels `[k][64]`; A read in place (six row streams), only a last
//!   partial row panel is copied.
//! - `Avx512Bf16`, `PortableBf16`: bf16, 64-column panels of k pairs `[⌈k/2⌉][64]` u32 (k = 2q
//!   in the low half, 2q + 1 in the high half: `vdpbf16ps`'s operand order); A converted per
//!   call to bf16 pairs (round to nearest even), rows of ⌈k/2⌉ u32. Accumulation is f32.
//!
//! Dispatch: `Kernel::best` picks by `is_x86_feature_detected!` — for f32 `Avx512F` with
//! AVX-512F, else `Avx2Fma` with AVX2 + FMA, else `Portable`; for bf16 `Avx512Bf16` with
//! AVX512_BF16 and nothing otherwise (bf16 is never emulated in a model: `Precision::Bf16`
//! falls back to f32 where the CPU lacks it). `Engine::detect()` picks this engine wherever a
//! SIMD f32 kernel exists and the `gemm` crate (`super::matmul`) elsewhere; it is faster on
//! every machine measured (BENCHMARKS.md, "Image pass"). A packed matrix records its kernel,
//! and packing refuses a kernel the CPU lacks, so a kernel never runs on a CPU without its
//! instructions. The choice is a value, [`Compute`], given when a model is loaded; tests and
//! benchmarks force any kernel the CPU has with [`Compute::with_kernel`].

use std::mem::MaybeUninit;
use std::ops::Range;

use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
#[clippy::msrv = "1.89"]
mod avx512;
mod portable;

/// Rows of C per micro-tile (every kernel).
pub(crate) const MR: usize = 6;
/// Widest tile (bias scratch size).
const NR_MAX: usize = 64;
/// At most this many rows of A are kept in L2 per pass: 168 × 256 × 4 B = 168 KiB. A multiple
/// of MR, and above 150 so that three 50-token views are one block (a second block of one
/// panel would re-read every B micro-panel from L3 for a single tile).
const MC: usize = 168;
/// Products below this many multiply-adds run on the calling thread.
const PARALLEL_MIN_MACS: usize = 1 << 20;

/// How `Linear` layers store their weights and multiply with them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Engine {
    /// Weights packed at load (`PackedB`), products in this module.
    Packed,
    /// Weights stored plainly, products by the `gemm` crate (`super::matmul`).
    Crate,
}

/// Number format of the weight products (`Linear` layers); everything else (layer norms,
/// attention, activations, residuals) stays f32.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// Single precision throughout (the default).
    F32,
    /// Weights and activations rounded to bf16 (round to nearest even), products accumulated
    /// in f32 by `vdpbf16ps` (`Kernel::Avx512Bf16`).
    Bf16,
}

impl Engine {
    /// The faster engine on this machine: this module wherever a SIMD f32 kernel exists (AVX2 +
    /// FMA, or AVX-512F), the `gemm` crate elsewhere.
    pub fn detect() -> Engine {
        if Kernel::best(Precision::F32) == Some(Kernel::Portable) {
            Engine::Crate
        } else {
            Engine::Packed
        }
    }
}

impl Precision {
    /// Whether this CPU computes in this precision natively (bf16: AVX512_BF16).
    pub fn native(self) -> bool {
        Kernel::best(self).is_some()
    }

    /// bf16 where the CPU has `vdpbf16ps` *and* it is measured faster than f32 here
    /// ([`bf16_speedup`] ≥ [`AUTO_BF16_MIN_SPEEDUP`]), f32 elsewhere: never an emulated bf16,
    /// and never a bf16 slower than f32 (Zen 4 measures 1.8–2× faster; one Intel Xeon with
    /// AVX512_BF16 was reported to run the image pass 1.34× slower in bf16).
    pub fn auto() -> Precision {
        if bf16_speedup().is_some_and(|s| s >= AUTO_BF16_MIN_SPEEDUP) {
            Precision::Bf16
        } else {
            Precision::F32
        }
    }

    /// `f32`, `bf16` (an error where the CPU lacks AVX512_BF16: emulating it would be slower
    /// than f32) or `auto`.
    pub fn resolve(name: &str) -> Result<Precision, PrecisionError> {
        match name {
            "f32" => Ok(Precision::F32),
            "auto" => Ok(Precision::auto()),
            "bf16" if Precision::Bf16.native() => Ok(Precision::Bf16),
            "bf16" => Err(PrecisionError::NotNative {
                features: cpu_features(),
            }),
            other => Err(PrecisionError::Unknown(other.to_string())),
        }
    }

    /// `f32` or `bf16`, as `--precision` spells it.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::Bf16 => "bf16",
        }
    }
}

/// How much faster bf16 must measure than f32 for `auto` to pick it: a margin over the
/// calibration's noise, since bf16 also costs accuracy (BENCHMARKS.md, "Precision").
pub const AUTO_BF16_MIN_SPEEDUP: f64 = 1.15;

/// f32 time / bf16 time of the weight products on this CPU, measured once per process (a few
/// milliseconds); `None` where the CPU has no bf16 kernel.
///
/// Why a measurement and not the flag or a table: CPUs with the same AVX512_BF16 flag differ
/// by 2.6× in this ratio (Zen 4 against one Intel Xeon), and a table would miss every CPU the
/// benchmarks never met. The product is one of ViT-B/32's MLP shapes (3 views × 50 tokens,
/// 768 → 3072) on one thread (the kernels' speed ratio, without the scheduling noise of a
/// shared machine), each kernel's best of 7 runs, the two taking turns so a load on the
/// machine meets both alike: about 40 ms. Cheap enough not to cache: a disk cache keyed by the
/// CPU model would also outlive a change of the machine's load or microcode.
pub fn bf16_speedup() -> Option<f64> {
    static SPEEDUP: std::sync::OnceLock<Option<f64>> = std::sync::OnceLock::new();
    *SPEEDUP.get_or_init(|| {
        let f32_kernel = Kernel::best(Precision::F32)?;
        let bf16_kernel = Kernel::best(Precision::Bf16)?;
        let (m, k, n) = (150, 768, 3072);
        let b: Vec<f32> = (0..k * n)
            .map(|i| ((i * 7919) % 997) as f32 / 997.0 - 0.5)
            .collect();
        let a: Vec<f32> = (0..m * k)
            .map(|i| ((i * 104729) % 991) as f32 / 991.0 - 0.5)
            .collect();
        let packed = [
            PackedB::from_rows_for(f32_kernel, &b, k, n),
            PackedB::from_rows_for(bf16_kernel, &b, k, n),
        ];
        let mut c = vec![0.0f32; m * n];
        let mut best = [f64::INFINITY; 2];
        let mut time = || {
            for _ in 0..7 {
                for (i, p) in packed.iter().enumerate() {
                    let t = std::time::Instant::now();
                    gemm(&mut c, n, &a, k, m, p, 0..k, 0..n, None, false);
                    best[i] = best[i].min(t.elapsed().as_secs_f64());
                }
            }
        };
        match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
            Ok(one) => one.install(time),
            Err(_) => time(),
        }
        Some(best[0] / best[1].max(1e-9))
    })
}

/// Why a precision name cannot be had.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PrecisionError {
    /// bf16 on a CPU without AVX512_BF16 (emulating it would be slower than f32).
    #[error("bf16 needs AVX512_BF16, which this CPU lacks ({features}); use f32 or auto")]
    NotNative {
        /// What the CPU has and lacks.
        features: String,
    },
    /// Not f32, bf16 or auto.
    #[error("precision {0:?}: expected f32, bf16 or auto")]
    Unknown(String),
}

/// A micro-kernel and the packed layout it reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// Scalar f32, 16-column panels: runs anywhere; the reference for `Avx2Fma`'s layout.
    Portable,
    /// AVX2 + FMA, 6 × 16, f32.
    Avx2Fma,
    /// AVX-512F, 6 × 64, f32.
    Avx512F,
    /// Scalar bf16 pairs, 64-column panels: the reference for `Avx512Bf16` (tests only; a
    /// model never emulates bf16).
    PortableBf16,
    /// AVX512_BF16 `vdpbf16ps`, 6 × 64, bf16 pairs, f32 accumulation.
    Avx512Bf16,
}

impl Kernel {
    /// Every kernel, whether this CPU has it or not.
    pub const ALL: [Kernel; 5] = [
        Kernel::Portable,
        Kernel::Avx2Fma,
        Kernel::Avx512F,
        Kernel::PortableBf16,
        Kernel::Avx512Bf16,
    ];

    /// A short description ("avx512f 6x64 f32"), as benchmarks and report.json print it.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Portable => "portable 6x16 f32",
            Kernel::Avx2Fma => "avx2+fma 6x16 f32",
            Kernel::Avx512F => "avx512f 6x64 f32",
            Kernel::PortableBf16 => "portable 6x64 bf16",
            Kernel::Avx512Bf16 => "avx512bf16 6x64 bf16 (vdpbf16ps)",
        }
    }

    /// The number format of its products.
    pub fn precision(self) -> Precision {
        match self {
            Kernel::Portable | Kernel::Avx2Fma | Kernel::Avx512F => Precision::F32,
            Kernel::PortableBf16 | Kernel::Avx512Bf16 => Precision::Bf16,
        }
    }

    /// Whether the input backward that reads the forward's panels transposed ([`gemm_t`],
    /// one copy of each weight) runs close to the product with a second packed copy on this
    /// kernel, by `bench_memory --backward` (BENCHMARKS.md, "Memory of a default run"): the
    /// AVX2 kernel reads the panels in place, 1.15–1.17× the two-copy time on Zen 3 (ViT-B/32's
    /// backward shapes); the AVX-512 one measured 1.35× on Zen 4, the scalar one copies the
    /// panels per call. A table from the benchmarks rather than a calibration at load: the
    /// two differ by ~15 %, less than a few milliseconds' timing on a shared machine tells
    /// apart reliably. Where it is fast, pipelines keep one copy by default.
    pub fn fast_one_copy(self) -> bool {
        matches!(self, Kernel::Avx2Fma)
    }

    /// `None` where this CPU can run the kernel, else what it lacks.
    pub fn missing(self) -> Option<&'static str> {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            match self {
                Kernel::Portable | Kernel::PortableBf16 => None,
                Kernel::Avx2Fma => (!(has!("avx2") && has!("fma"))).then_some("AVX2 and FMA"),
                Kernel::Avx512F => (!has!("avx512f")).then_some("AVX-512F"),
                Kernel::Avx512Bf16 => {
                    (!(has!("avx512f") && has!("avx512bw") && has!("avx512bf16")))
                        .then_some("AVX-512F, AVX-512BW and AVX512_BF16")
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        match self {
            Kernel::Portable | Kernel::PortableBf16 => None,
            _ => Some("an x86-64 CPU"),
        }
    }

    /// Whether this CPU runs it.
    pub fn available(self) -> bool {
        self.missing().is_none()
    }

    /// The fastest kernel for `precision` on this CPU (f32: always one, `Portable` at worst;
    /// bf16: only a native one).
    pub fn best(precision: Precision) -> Option<Kernel> {
        let order: &[Kernel] = match precision {
            Precision::F32 => &[Kernel::Avx512F, Kernel::Avx2Fma, Kernel::Portable],
            Precision::Bf16 => &[Kernel::Avx512Bf16],
        };
        order.iter().copied().find(|k| k.available())
    }

    /// Columns per B panel.
    fn nr(self) -> usize {
        match self {
            Kernel::Portable | Kernel::Avx2Fma => 16,
            Kernel::Avx512F | Kernel::PortableBf16 | Kernel::Avx512Bf16 => 64,
        }
    }

    /// Packed rows (k steps, or k pairs for bf16) per pass over C: B micro-panels of 16 KiB
    /// (16 columns × 256) and 64 KiB (64 × 256 f32) or 32 KiB (64 × 128 pairs). Measured in
    /// the stand-alone driver on Zen 4 (`avx512.rs`): f32 6 × 64 at 128 rows 95–101 GFLOPS
    /// against 95–109 at 256; bf16 at 256 pairs 178–212 against 194–214 at 128.
    fn kc(self) -> usize {
        match self {
            Kernel::Portable | Kernel::Avx2Fma | Kernel::Avx512F => 256,
            Kernel::PortableBf16 | Kernel::Avx512Bf16 => 128,
        }
    }

    fn bf16(self) -> bool {
        self.precision() == Precision::Bf16
    }
}

/// How a model's weight products run: chosen when the model is loaded (`Clip::load_files_with`,
/// `Clip::from_source_with`) and kept by every `Linear` layer built then, as candle's
/// `VarBuilder` carries a dtype. A value, never a thread's or the process's setting: models
/// built with different `Compute`s side by side each keep their own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Compute {
    /// Packed weights and this module's kernels, or the `gemm` crate.
    pub engine: Engine,
    /// The number format asked for (`Bf16` where the CPU lacks it builds f32 layers).
    pub precision: Precision,
    /// A kernel forced whatever the engine and precision say (tests and benchmarks; see
    /// [`Compute::with_kernel`]); `None`: chosen by them.
    pub kernel: Option<Kernel>,
    /// Whether f32 layers keep one packed copy of each weight: the input backward then reads
    /// the forward's panels transposed ([`gemm_t`]), which saves the memory of a second copy
    /// (350 MB for ViT-B/32's image tower) but makes the backward products slower: 1.16× with
    /// the AVX2 kernel on Zen 3, 1.35× with the AVX-512 one on Zen 4
    /// (`examples/bench_memory.rs --backward`; see [`Kernel::fast_one_copy`]). `false`: a
    /// second copy `W` for the backward, the faster product. Results agree to float rounding
    /// either way (bit for bit with the AVX2 and scalar kernels).
    pub one_copy: bool,
}

impl Default for Compute {
    /// f32 on the faster engine of this CPU.
    fn default() -> Compute {
        Compute::new(Precision::F32)
    }
}

impl Compute {
    /// `precision` on the faster engine of this CPU ([`Engine::detect`]).
    pub fn new(precision: Precision) -> Compute {
        Compute {
            engine: Engine::detect(),
            precision,
            kernel: None,
            one_copy: false,
        }
    }

    /// The same keeping one copy of each weight or not ([`Compute::one_copy`]).
    pub fn with_one_copy(self, one_copy: bool) -> Compute {
        Compute { one_copy, ..self }
    }

    /// Packed copies of each weight a layer with a backward (the image tower's) keeps: one
    /// for the `gemm` crate and for f32 kernels with [`Compute::one_copy`], else two (the
    /// forward's `Wᵀ` and the backward's `W`; bf16 layers always keep both).
    pub fn backward_weight_copies(&self) -> usize {
        match self.layer_kernel() {
            None => 1,
            Some(k) if k.precision() == Precision::F32 && self.one_copy => 1,
            Some(_) => 2,
        }
    }

    /// Whether its layers' kernel reads one copy of each weight about as fast as two
    /// ([`Kernel::fast_one_copy`]): where it does, pipelines keep one copy by default.
    pub fn prefers_one_copy(&self) -> bool {
        self.layer_kernel().is_some_and(Kernel::fast_one_copy)
    }

    /// The same with `engine` (tests and benchmarks compare the two engines).
    pub fn with_engine(self, engine: Engine) -> Compute {
        Compute { engine, ..self }
    }

    /// The same with every layer packed for `kernel`; `None` where this CPU lacks the
    /// kernel's instructions, so a kernel never runs on a CPU without them.
    pub fn with_kernel(self, kernel: Kernel) -> Option<Compute> {
        kernel.available().then_some(Compute {
            kernel: Some(kernel),
            ..self
        })
    }

    /// The kernel `Linear` layers are packed for, or `None` for the `gemm` crate: the forced
    /// kernel; else with `Precision::Bf16` the native bf16 kernel if any; else by the engine,
    /// the best f32 kernel or the crate.
    pub fn layer_kernel(&self) -> Option<Kernel> {
        if let Some(k) = self.kernel {
            return Some(k);
        }
        if let (Precision::Bf16, Some(k)) = (self.precision, Kernel::best(Precision::Bf16)) {
            return Some(k);
        }
        match self.engine {
            Engine::Packed => Kernel::best(Precision::F32),
            Engine::Crate => None,
        }
    }

    /// One line for report.json: which GEMM the layers use (engine, kernel, precision) and
    /// the CPU features behind the choice, e.g. `packed engine, avx512f 6x64 f32
    /// micro-kernel, f32 (CPU has avx2 fma avx512f avx512bw avx512_bf16; lacks amx_bf16)`.
    pub fn describe(&self) -> String {
        let what = match self.layer_kernel() {
            Some(k) => format!(
                "packed engine, {} micro-kernel, {}",
                k.name(),
                k.precision().name()
            ),
            None => "gemm crate engine, f32".to_string(),
        };
        let fallback = if self.precision == Precision::Bf16 && !Precision::Bf16.native() {
            " (bf16 asked, not native here: f32)"
        } else {
            ""
        };
        format!("{what}{fallback} (CPU {})", cpu_features())
    }
}

/// The CPU features the dispatch looks at, as `/proc/cpuinfo` spells them.
pub fn cpu_features() -> String {
    #[cfg(target_arch = "x86_64")]
    {
        let asked = ["avx2", "fma", "avx512f", "avx512bw", "avx512_bf16"];
        let flags: Vec<(&str, bool)> = asked
            .iter()
            .map(|&f| (f, t2tf_core::platform::has_flag(f)))
            .chain([("amx_bf16", amx_bf16())])
            .collect();
        let (yes, no): (Vec<_>, Vec<_>) = flags.iter().partition(|(_, h)| *h);
        let names = |v: Vec<&(&str, bool)>| v.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(" ");
        format!("has {}; lacks {}", names(yes), names(no))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        "not x86-64".to_string()
    }
}

/// Whether the CPU reports AMX-BF16 (CPUID leaf 7 EDX bit 22). Only reported: there is no AMX
/// kernel (untestable on the AVX-512 development machine, which lacks AMX), so AMX machines
/// run `Avx512Bf16`. `is_x86_feature_detected!` has no stable name for AMX.
#[cfg(target_arch = "x86_64")]
fn amx_bf16() -> bool {
    // CPUID exists on every x86-64 CPU (a safe intrinsic); leaf 7 is only read when reported.
    use std::arch::x86_64::__cpuid_count;
    __cpuid_count(0, 0).eax >= 7 && __cpuid_count(7, 0).edx & (1 << 22) != 0
}

/// One k-row (or part of one) of a packed B panel: a 64-byte cache line, so panel rows are
/// aligned loads. bf16 panels hold u32 bit patterns in the same lines.
#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct Line([f32; 16]);

/// A k × n matrix B in a kernel's layout: ⌈n / NR⌉ column panels back to back, panel `j` being
/// `[rows][NR]` (columns `j·NR .. j·NR + NR`, zero past n), rows = k for f32 and ⌈k / 2⌉ k
/// pairs for bf16. A row range of B is then a contiguous range of every panel, so one packed
/// copy serves any k sub-range too.
pub struct PackedB {
    k: usize,
    n: usize,
    kernel: Kernel,
    /// `[panels][rows][NR / 16]` lines.
    lines: Vec<Line>,
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
    fn flat(&self) -> &[f32] {
        // SAFETY: `Line` is `repr(C)` around `[f32; 16]` with alignment 64 = its size, so the
        // lines are contiguous f32s without padding.
        unsafe {
            std::slice::from_raw_parts(self.lines.as_ptr().cast::<f32>(), self.lines.len() * 16)
        }
    }
}

/// Rows of a packed panel holding k rows of B.
fn packed_rows(kernel: Kernel, k: usize) -> usize {
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
fn to_bf16_pairs_body(src: &[f32], dst: &mut [u32]) {
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
fn to_bf16_pairs(src: &[f32], dst: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512bw")
    {
        // SAFETY: the CPU has AVX-512F and AVX-512BW (checked just above).
        return unsafe { avx512::to_bf16_pairs(src, dst) };
    }
    to_bf16_pairs_body(src, dst)
}

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
/// pages after the first. A new buffer per product has its pages faulted in and zeroed each
/// time: ≈ 15 % of the pool's wall time on Zen 3 (BENCHMARKS.md, "Caption pool first use").
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
fn pack_transposed(a: &[f32], ld: usize, k: usize, n: usize, nr: usize) -> Vec<Line> {
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
fn transposed_product(
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
fn panel_index(rows: usize, nr: usize, i: usize, col: usize) -> usize {
    ((col / nr) * rows + i) * nr + col % nr
}

/// The shape of a transposed product (`transposed_product`): C is `m × rows_c`, B's columns
/// `c0 .. c0 + k` are summed over, and `threads` threads split the `panels_m` row tiles of Cᵀ.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct Transposed {
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
fn transposed_avx2(
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

/// A `*mut f32` that may cross threads: each thread writes a disjoint set of C's columns.
// The same wrapper as layers.rs's `SyncPtr`; kept apart so that each `unsafe impl`'s SAFETY
// argument covers exactly one use (disjoint column panels here, one element per thread there).
#[derive(Clone, Copy)]
struct SendPtr(*mut f32);
// SAFETY: only used for C in `gemm_raw`, where threads own disjoint column panels.
unsafe impl Send for SendPtr {}
unsafe impl Sync for SendPtr {}

impl SendPtr {
    /// A method, so that closures capture the whole `SendPtr` (a field access would capture
    /// the bare pointer, which is not `Send`).
    fn get(self) -> *mut f32 {
        self.0
    }
}

/// The A operand as the kernel reads it.
enum APacked<'a> {
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
    /// bf16 pairs `[panels·MR][kq]` u32, zero rows past m (`Avx512Bf16`, `PortableBf16`).
    Pairs { data: Vec<u32>, kq: usize },
}

/// Pack A (m × k at stride lda, k ≥ 1) for `kernel`; `q0` is the first k pair of the call
/// (bf16: `ks.start / 2`), `shift` = `ks.start % 2` (A's column 0 is the high half of pair q0
/// when the range starts at an odd row of B).
fn pack_a<'a>(
    kernel: Kernel,
    a: &'a [f32],
    lda: usize,
    m: usize,
    k: usize,
    shift: usize,
    parallel: bool,
) -> APacked<'a> {
    let panels_m = m.div_ceil(MR);
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
        Kernel::PortableBf16 | Kernel::Avx512Bf16 => {
            let kq = (k + shift).div_ceil(2);
            let mut data = vec![0u32; panels_m * MR * kq];
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

/// The product itself, for m, n, k > 0, then `post` on every tile (see `Post`).
///
/// # Safety
/// `c` is valid for reads and writes of `c_len` floats and not aliased during the call;
/// elements are read only where `accumulate` is set (then they must be initialized) or after
/// this call wrote them.
// `gemm`'s arguments (see there) with C as a raw pointer and length, which the safety contract
// above is about, and `post`. Its parameter list repeats `gemm`'s on purpose: `gemm` is the safe
// entry on a C slice (and the k = 0 case), this the one `gemm_new`/`gemm_new_post` share on
// uninitialized C; folding them into one would put the raw pointer in the safe signature.
#[allow(clippy::too_many_arguments)]
unsafe fn gemm_raw(
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
    let panels_m = m.div_ceil(MR);
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
    let per_block = panels_m.div_ceil(panels_m.div_ceil(MC / MR));
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
                            rows: MR.min(m - i * MR),
                            lo,
                            hi,
                            // Offset of tile column 0 in C's row; < 0 only when lo > 0.
                            col0: (j * nr) as isize - cols.start as isize,
                            bias: (first && bias.is_some()).then_some(&tile_bias[..nr]),
                            add: !first || accumulate,
                            nr,
                        };
                        // SAFETY: row i·MR of C starts inside `c` (i·MR < m); the tile
                        // writes rows < m and C columns col0 + lo .. col0 + hi, which lie in
                        // 0 .. n ≤ ldc by the clipping above, so inside the asserted bounds.
                        // Threads own disjoint panel ranges j0..j1, hence disjoint columns.
                        // `b.kernel` was checked against this CPU when B was packed.
                        unsafe {
                            let crow = cp.get().add(i * MR * ldc);
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
                                        cp.get().add((i * MR + r) * ldc + col),
                                        hi - lo,
                                    )
                                };
                                post(i * MR + r, col, values);
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
struct Tile<'a> {
    /// Valid rows (≤ MR).
    rows: usize,
    /// Valid tile columns `lo .. hi` (⊆ 0 .. nr).
    lo: usize,
    hi: usize,
    /// C column of tile column 0.
    col0: isize,
    /// Added to every row (first k-block only); `nr` floats.
    bias: Option<&'a [f32]>,
    /// Add to C rather than overwrite it.
    add: bool,
    /// Tile width (the kernel's NR).
    nr: usize,
}

impl Tile<'_> {
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn full(&self) -> bool {
        self.rows == MR && self.lo == 0 && self.hi == self.nr
    }

    /// Write an accumulated tile `acc [rows][nr]` into C transposed: tile element (r, cc)
    /// goes to C's row `col0 + cc`, column r (the transposed product's tiles, `gemm_t`).
    ///
    /// # Safety
    /// `ccol` is C's column of the tile's first row; rows `col0 + lo .. col0 + hi` and columns
    /// `< self.rows` from it (leading dimension `ldc`) must be writable.
    unsafe fn store_transposed(&self, acc: &[f32], ccol: *mut f32, ldc: usize) {
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

    /// Write an accumulated tile `acc [MR][nr]` into C through the general (edge) path.
    ///
    /// # Safety
    /// `crow` is C's row of the tile's first row; rows `< self.rows` and columns
    /// `col0 + lo .. col0 + hi` of it (leading dimension `ldc`) must be writable.
    unsafe fn store_scalar(&self, acc: &[f32], crow: *mut f32, ldc: usize) {
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
unsafe fn run_tile(
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
        _ => unreachable!("A packed for another kernel than {kernel:?}"),
    }
}
#[cfg(test)]
mod tests {
    use super::*;

    /// C = base + A·B (+ bias) in f64, B given row-major [k, n].
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

    /// Every kernel this CPU runs (the scalar ones always).
    fn kernels() -> Vec<Kernel> {
        Kernel::ALL.into_iter().filter(|k| k.available()).collect()
    }

    /// What the kernel multiplies: `v` itself, or rounded to bf16.
    fn seen(kernel: Kernel, v: &[f32]) -> Vec<f32> {
        if kernel.bf16() {
            v.iter().map(|&x| round_bf16(x)).collect()
        } else {
            v.to_vec()
        }
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
                let pb = PackedB::from_rows_for(kernel, &b, k, n);
                let (ar, br) = (seen(kernel, &a), seen(kernel, &b));
                // The same B given transposed packs to the same thing.
                let mut bt = vec![0.0; k * n];
                for p in 0..k {
                    for j in 0..n {
                        bt[j * k + p] = b[p * n + j];
                    }
                }
                let pbt = PackedB::from_cols_for(kernel, &bt, k, n);
                assert!(pb.flat() == pbt.flat());
                let tol = 1e-6 * (k as f64).sqrt().max(1.0) * 4.0;
                let base = values(m * n, 4, 2.0);
                let what = format!("{kernel:?} {m}x{n}x{k}");
                for bias in [None, Some(&bias[..])] {
                    let mut c = vec![f32::NAN; m * n];
                    gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, bias, false);
                    check(
                        &c,
                        &naive(&vec![0.0; m * n], &ar, &br, m, n, k, bias),
                        tol,
                        &what,
                    );
                    let mut c = base.clone();
                    gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, bias, true);
                    check(&c, &naive(&base, &ar, &br, m, n, k, bias), tol, &what);
                }
            }
        }
    }

    /// Sub-ranges of B's rows and (unaligned) columns, strided A and C, k = 0.
    #[test]
    fn sub_ranges_and_strides() {
        let (m, n, k) = (13, 45, 70);
        let b = values(k * n, 5, 1.0);
        let bias = values(n, 6, 1.0);
        for kernel in kernels() {
            let pb = PackedB::from_rows_for(kernel, &b, k, n);
            let br = seen(kernel, &b);
            for (ks, cols) in [
                (0..k, 0..n),
                (3..70, 5..40),
                (16..33, 16..32),
                (7..8, 44..45),
            ] {
                let (kk, nn) = (ks.len(), cols.len());
                let (lda, ldc) = (kk + 3, nn + 2);
                let a = values(m * lda, 7, 1.0);
                let ar = seen(kernel, &a);
                let mut c = values(m * ldc, 8, 1.0);
                let before = c.clone();
                gemm(
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
                                .map(|p| {
                                    ar[i * lda + p] as f64 * br[(ks.start + p) * n + bj] as f64
                                })
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
            gemm(&mut c, n, &[], 0, 2, &pb, 4..4, 0..n, Some(&bias), true);
            assert!(c
                .iter()
                .zip(bias.iter().cycle())
                .all(|(c, b)| *c == 1.0 + b));
            gemm(&mut c, n, &[], 0, 2, &pb, 4..4, 0..n, None, false);
            assert!(c.iter().all(|&c| c == 0.0));
        }
    }

    #[test]
    fn zeros_and_large_magnitudes() {
        let (m, n, k) = (9, 20, 40);
        for kernel in kernels() {
            let pb = PackedB::from_rows_for(kernel, &vec![0.0; k * n], k, n);
            let a = values(m * k, 1, 1e30);
            let mut c = vec![f32::NAN; m * n];
            gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, None, false);
            assert!(c.iter().all(|&v| v == 0.0), "overwrite ignores old C");
            // Large but finite products: 1e18 · 1e18 summed over 40 terms stays below f32::MAX.
            let a = values(m * k, 2, 1e18);
            let b = values(k * n, 3, 1e18);
            let pb = PackedB::from_rows_for(kernel, &b, k, n);
            gemm(&mut c, n, &a, k, m, &pb, 0..k, 0..n, None, false);
            let want = naive(
                &vec![0.0; m * n],
                &seen(kernel, &a),
                &seen(kernel, &b),
                m,
                n,
                k,
                None,
            );
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
        for kernel in kernels() {
            let pb = PackedB::from_rows_for(kernel, &values(k * n, 2, 1.0), k, n);
            let mut one = vec![0.0; m * n];
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap();
            pool.install(|| gemm(&mut one, n, &a, k, m, &pb, 0..k, 0..n, None, false));
            for threads in [2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut par = vec![0.0; m * n];
                pool.install(|| gemm(&mut par, n, &a, k, m, &pb, 0..k, 0..n, None, false));
                assert!(
                    par.iter()
                        .zip(&one)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{kernel:?} with {threads} threads"
                );
            }
        }
    }

    /// `post` sees every element of C once, with its row and column, after the product is
    /// final (it sees the plain result), and what it writes is the result.
    #[test]
    fn post_sees_every_element_once_with_its_final_value() {
        use std::sync::atomic::{AtomicU32, Ordering};
        for kernel in kernels() {
            for (m, n, k, cols) in [
                (1, 1, 1, 0..1),
                (13, 130, 70, 3..129),
                (150, 200, 600, 0..200),
                (7, 64, 0, 0..64),
            ] {
                let a = values(m * k, 1, 1.0);
                let pb = PackedB::from_rows_for(kernel, &values(k * n, 2, 1.0), k, n);
                let bias = values(n, 3, 1.0);
                let nn = cols.len();
                let plain = gemm_new(&a, k, m, &pb, 0..k, cols.clone(), Some(&bias));
                let seen: Vec<AtomicU32> = (0..m * nn).map(|_| AtomicU32::new(0)).collect();
                let post = |row: usize, col: usize, v: &mut [f32]| {
                    for (i, x) in v.iter_mut().enumerate() {
                        let at = row * nn + col + i;
                        seen[at].fetch_add(1, Ordering::Relaxed);
                        assert_eq!(x.to_bits(), plain[at].to_bits(), "{kernel:?} final value");
                        *x = -*x;
                    }
                };
                let got = gemm_new_post(&a, k, m, &pb, 0..k, cols, Some(&bias), Some(&post));
                assert!(
                    seen.iter().all(|c| c.load(Ordering::Relaxed) == 1),
                    "{kernel:?}"
                );
                assert!(got.iter().zip(&plain).all(|(g, p)| *g == -*p));
            }
        }
    }

    #[test]
    fn bf16_rounding_is_nearest_even() {
        assert_eq!(bf16_bits(1.0), 0x3f80);
        // 1 + 2^-8 is halfway between 1 and 1 + 2^-7: ties to even (1.0).
        assert_eq!(bf16_bits(1.0 + 1.0 / 256.0), 0x3f80);
        // 1 + 3·2^-8 is halfway between 1 + 2^-7 and 1 + 2^-6: ties to even (1 + 2^-6).
        assert_eq!(bf16_bits(1.0 + 3.0 / 256.0), 0x3f82);
        assert_eq!(bf16_bits(-2.5), 0xc020);
        assert!(round_bf16(f32::NAN).is_nan());
        assert_eq!(round_bf16(f32::INFINITY), f32::INFINITY);
        assert_eq!(round_bf16(f32::MAX), f32::INFINITY);
        // The vectorised pair conversion gives the same bits, odd length included.
        let src: Vec<f32> = (0..37).map(|i| (i as f32 - 18.3) * 1.37e-3).collect();
        let mut fast = vec![0u32; 19];
        let mut slow = vec![0u32; 19];
        to_bf16_pairs(&src, &mut fast);
        to_bf16_pairs_body(&src, &mut slow);
        assert_eq!(fast, slow);
        assert_eq!(fast[18], bf16_bits(src[36]) as u32);
        assert_eq!(
            fast[3],
            bf16_bits(src[6]) as u32 | (bf16_bits(src[7]) as u32) << 16
        );
    }

    #[test]
    fn precision_resolution() {
        assert_eq!(Precision::resolve("f32"), Ok(Precision::F32));
        assert_eq!(Precision::resolve("bf16").is_ok(), Precision::Bf16.native());
        let auto = Precision::resolve("auto").unwrap();
        // bf16 only where native and measured faster.
        assert_eq!(
            auto == Precision::Bf16,
            Precision::Bf16.native() && bf16_speedup().unwrap() >= AUTO_BF16_MIN_SPEEDUP
        );
        assert_eq!(bf16_speedup().is_some(), Precision::Bf16.native());
        if let Some(s) = bf16_speedup() {
            eprintln!("bf16 measured {s:.2}× the f32 kernel's speed");
            assert!(s.is_finite() && s > 0.0);
        }
        assert!(Precision::resolve("fp8").is_err());
        let f32_layers = Compute::default().layer_kernel();
        // Native bf16, or f32 layers as before: never an emulated bf16.
        let want = if Precision::Bf16.native() {
            Some(Kernel::Avx512Bf16)
        } else {
            f32_layers
        };
        assert_eq!(Compute::new(Precision::Bf16).layer_kernel(), want);
        assert!(!Compute::default().describe().is_empty());
    }

    #[test]
    fn settings_are_values() {
        let c = Compute::default();
        assert_eq!(c.engine, Engine::detect());
        assert_eq!(c.with_engine(Engine::Crate).layer_kernel(), None);
        let forced = c.with_kernel(Kernel::Portable).unwrap();
        assert_eq!(forced.layer_kernel(), Some(Kernel::Portable));
        assert_eq!(
            forced.with_engine(Engine::Crate).layer_kernel(),
            Some(Kernel::Portable)
        );
        // Built on another thread, a model gets what it is given, not that thread's f32.
        let bf = Compute::new(Precision::Bf16);
        let there = std::thread::spawn(move || bf.layer_kernel())
            .join()
            .unwrap();
        assert_eq!(there, bf.layer_kernel());
    }
}
