//! The micro-kernels, what each needs of the CPU, and the layout each reads.

use super::*;

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
    /// Intel AMX `tdpbf16ps` computed in software, bit for bit as the SDM defines it
    /// (`amx.rs`): the same panels, tiles and steps as `Amx`, so every CPU tests the AMX
    /// path's layout code, and the reference of the AMX self-check (tests only; a model never
    /// emulates bf16).
    AmxEmulated,
    /// Intel AMX-BF16 `tdpbf16ps`, 16 × 64 (four 16 × 16 tiles of C), bf16 pairs, f32
    /// accumulation; available only after the system granted the tile state and a self-check
    /// against `AmxEmulated` passed (`amx::status`).
    Amx,
}

impl Kernel {
    /// Every kernel, whether this CPU has it or not.
    pub const ALL: [Kernel; 7] = [
        Kernel::Portable,
        Kernel::Avx2Fma,
        Kernel::Avx512F,
        Kernel::PortableBf16,
        Kernel::Avx512Bf16,
        Kernel::AmxEmulated,
        Kernel::Amx,
    ];

    /// A short description ("avx512f 6x64 f32"), as benchmarks and report.json print it.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Portable => "portable 6x16 f32",
            Kernel::Avx2Fma => "avx2+fma 6x16 f32",
            Kernel::Avx512F => "avx512f 6x64 f32",
            Kernel::PortableBf16 => "portable 6x64 bf16",
            Kernel::Avx512Bf16 => "avx512bf16 6x64 bf16 (vdpbf16ps)",
            Kernel::AmxEmulated => "emulated amx 16x64 bf16 (tdpbf16ps in software)",
            Kernel::Amx => "amx-bf16 16x64 bf16 (tdpbf16ps)",
        }
    }

    /// The number format of its products.
    pub fn precision(self) -> Precision {
        match self {
            Kernel::Portable | Kernel::Avx2Fma | Kernel::Avx512F => Precision::F32,
            Kernel::PortableBf16 | Kernel::Avx512Bf16 | Kernel::AmxEmulated | Kernel::Amx => {
                Precision::Bf16
            }
        }
    }

    /// Whether the input backward that reads the forward's panels transposed ([`gemm_t`],
    /// one copy of each weight) runs close to the product with a second packed copy on this
    /// kernel, by `bench_memory --backward` (BENCHMARKS.md, "Memory of a default run"): the
    /// AVX2 kernel reads the panels in place, 1.15–1.17× the two-copy time on Zen 3 (ViT-B/32's
    /// backward shapes); with the AVX-512 one a default run on Zen 4 takes 1.11× the time of
    /// two copies (BENCHMARKS.md, "Default run"); the scalar one copies the panels per call. A table from the benchmarks rather than a calibration at load: the
    /// two differ by ~15 %, less than a few milliseconds' timing on a shared machine tells
    /// apart reliably. Where it is fast, pipelines keep one copy by default.
    pub fn fast_one_copy(self) -> bool {
        matches!(self, Kernel::Avx2Fma)
    }

    /// `None` where this CPU can run the kernel, else what it lacks (for AMX, why in full:
    /// [`amx_status`](super::amx_status)).
    pub fn missing(self) -> Option<&'static str> {
        if self == Kernel::Amx {
            return super::amx::status()
                .is_err()
                .then_some("AMX-BF16 granted by the system and a passing self-check");
        }
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            match self {
                Kernel::Portable | Kernel::PortableBf16 | Kernel::AmxEmulated | Kernel::Amx => None,
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
            Kernel::Portable | Kernel::PortableBf16 | Kernel::AmxEmulated => None,
            _ => Some("an x86-64 CPU"),
        }
    }

    /// Whether this CPU runs it.
    pub fn available(self) -> bool {
        self.missing().is_none()
    }

    /// The fastest kernel for `precision` on this CPU (f32: always one, `Portable` at worst;
    /// bf16: only a native one, AMX before `vdpbf16ps`: the same bf16 operands and f32
    /// accumulation, on matrix units that do a tile product per instruction).
    pub fn best(precision: Precision) -> Option<Kernel> {
        let order: &[Kernel] = match precision {
            Precision::F32 => &[Kernel::Avx512F, Kernel::Avx2Fma, Kernel::Portable],
            Precision::Bf16 => &[Kernel::Amx, Kernel::Avx512Bf16],
        };
        order.iter().copied().find(|k| k.available())
    }

    /// Columns per B panel.
    pub(super) fn nr(self) -> usize {
        match self {
            Kernel::Portable | Kernel::Avx2Fma => 16,
            Kernel::Avx512F
            | Kernel::PortableBf16
            | Kernel::Avx512Bf16
            | Kernel::AmxEmulated
            | Kernel::Amx => 64,
        }
    }

    /// Rows of C per micro-tile: a tile register's 16 rows for AMX, else [`MR`].
    pub(super) fn mr(self) -> usize {
        match self {
            Kernel::AmxEmulated | Kernel::Amx => super::amx::ROWS,
            _ => MR,
        }
    }

    /// Packed rows (k steps, or k pairs for bf16) per pass over C: B micro-panels of 16 KiB
    /// (16 columns × 256) and 64 KiB (64 × 256 f32) or 32 KiB (64 × 128 pairs). Measured in
    /// the stand-alone driver on Zen 4 (`avx512.rs`): f32 6 × 64 at 128 rows 95–101 GFLOPS
    /// against 95–109 at 256; bf16 at 256 pairs 178–212 against 194–214 at 128.
    pub(super) fn kc(self) -> usize {
        match self {
            Kernel::Portable | Kernel::Avx2Fma | Kernel::Avx512F => 256,
            // AMX: a multiple of its 16-pair step, so that only a call's last block has a
            // partial step.
            Kernel::PortableBf16 | Kernel::Avx512Bf16 | Kernel::AmxEmulated | Kernel::Amx => 128,
        }
    }

    pub(super) fn bf16(self) -> bool {
        self.precision() == Precision::Bf16
    }
}
