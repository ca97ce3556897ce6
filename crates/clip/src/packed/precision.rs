//! The number format of the weight products, and `auto`'s measured choice between them.

use super::*;

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
