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

mod amx;
#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
#[clippy::msrv = "1.89"]
mod avx512;
mod cpu;
mod kernel;
mod pack;
mod portable;
mod precision;
mod product;
#[cfg(test)]
mod tests;
mod transposed;

pub use amx::status as amx_status;
pub use cpu::cpu_features;
pub use kernel::Kernel;
pub use pack::{round_bf16, PackedB};
pub use precision::{
    bf16_speedup, calibration, Calibration, Precision, PrecisionError, AUTO_BF16_MIN_SPEEDUP,
    CALIBRATION_FILE,
};
pub use product::gemm;
pub use transposed::gemm_t;

use pack::*;
use product::*;
pub(crate) use product::{gemm_into_post, gemm_new, gemm_new_post, Post};
pub(crate) use transposed::gemm_t_post;

/// Rows of C per micro-tile (every kernel).
pub(crate) const MR: usize = 6;
/// Widest tile (bias scratch size).
pub(super) const NR_MAX: usize = 64;
/// At most this many rows of A are kept in L2 per pass: 168 × 256 × 4 B = 168 KiB. A multiple
/// of MR, and above 150 so that three 50-token views are one block (a second block of one
/// panel would re-read every B micro-panel from L3 for a single tile).
pub(super) const MC: usize = 168;
/// Products below this many multiply-adds run on the calling thread.
pub(super) const PARALLEL_MIN_MACS: usize = 1 << 20;

/// How `Linear` layers store their weights and multiply with them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Engine {
    /// Weights packed at load (`PackedB`), products in this module.
    Packed,
    /// Weights stored plainly, products by the `gemm` crate (`super::matmul`).
    Crate,
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
    /// Whether `precision` is `auto`'s choice ([`Precision::auto_cached`]): report.json then
    /// says so, with the calibration behind it.
    pub auto: bool,
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
            auto: false,
        }
    }

    /// `--precision auto`: the precision [`Precision::auto_cached`] picks on this CPU (its
    /// calibration kept in `dir`), on the faster engine, marked as `auto`'s choice.
    pub fn auto(dir: Option<&std::path::Path>) -> Compute {
        Compute {
            auto: true,
            ..Compute::new(Precision::auto_cached(dir))
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

    /// One line for report.json: which GEMM the layers use (engine, kernel, precision), how
    /// `auto` chose, whether AMX runs, and the CPU features behind the choice, e.g. `packed
    /// engine, avx512bf16 6x64 bf16 (vdpbf16ps) micro-kernel, bf16; chosen by auto: … measured
    /// 1.83× as fast as avx512f 6x64 f32 (cached; …) (CPU has avx2 fma …; lacks amx_bf16)`.
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
        let auto = if self.auto {
            match calibration(None) {
                Some(c) => format!(
                    "; chosen by auto: {} measured {:.2}× as fast as {} ({}; bf16 needs {AUTO_BF16_MIN_SPEEDUP}×)",
                    c.bf16_kernel, c.speedup, c.f32_kernel, c.source
                ),
                None => "; chosen by auto: this CPU has no bf16 kernel".into(),
            }
        } else {
            String::new()
        };
        #[cfg(target_arch = "x86_64")]
        let amx = match (cpu::amx_bf16(), amx::status()) {
            (false, _) => String::new(),
            (true, Ok(())) => "; AMX ready (self-check passed)".into(),
            (true, Err(why)) => format!("; AMX not used: {why}"),
        };
        #[cfg(not(target_arch = "x86_64"))]
        let amx = "";
        format!("{what}{fallback}{auto}{amx} (CPU {})", cpu_features())
    }
}

/// A `*mut f32` that may cross threads, each of which writes a disjoint set of its elements.
#[derive(Clone, Copy)]
pub(crate) struct SendPtr(pub(crate) *mut f32);
// SAFETY: used only where the threads write disjoint elements: C's column panels in
// `gemm_raw`, `transposed_product` and `transposed_avx2`, each element by one thread in
// `layers::Linear::forward_act`.
unsafe impl Send for SendPtr {}
unsafe impl Sync for SendPtr {}

impl SendPtr {
    /// A method, so that closures capture the whole `SendPtr` (a field access would capture
    /// the bare pointer, which is not `Send`).
    pub(crate) fn get(self) -> *mut f32 {
        self.0
    }
}
