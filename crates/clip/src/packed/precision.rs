//! The number format of the weight products, and `auto`'s measured choice between them.

use std::path::Path;

use super::*;

/// Number format of the weight products (`Linear` layers); everything else (layer norms,
/// attention, activations, residuals) stays f32.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// Single precision throughout (the default).
    F32,
    /// Weights and activations rounded to bf16 (round to nearest even), products accumulated
    /// in f32 by AMX's `tdpbf16ps` (`Kernel::Amx`) or AVX512_BF16's `vdpbf16ps`
    /// (`Kernel::Avx512Bf16`).
    Bf16,
}

impl Precision {
    /// Whether this CPU computes in this precision natively (bf16: AMX-BF16 or AVX512_BF16).
    pub fn native(self) -> bool {
        Kernel::best(self).is_some()
    }

    /// bf16 where the CPU has a bf16 kernel (AMX, else `vdpbf16ps`) *and* it is measured
    /// faster than f32 here ([`bf16_speedup`] ≥ [`AUTO_BF16_MIN_SPEEDUP`]), f32 elsewhere:
    /// never an emulated bf16, and never a bf16 slower than f32 (Zen 4 measures 1.8–2× faster;
    /// one Intel Xeon with AVX512_BF16 was reported to run the image pass 1.34× slower in
    /// `vdpbf16ps` bf16). Measured in this process; [`Precision::auto_cached`] keeps the
    /// measurement per CPU on disk, so that every run on a machine picks the same.
    pub fn auto() -> Precision {
        Precision::from_speedup(bf16_speedup())
    }

    /// [`Precision::auto`] with its calibration read from, or written to, `dir` (the caller's
    /// cache folder; `None`: measured in this process only). See [`calibration`].
    pub fn auto_cached(dir: Option<&Path>) -> Precision {
        Precision::from_speedup(calibration(dir).map(|c| c.speedup))
    }

    fn from_speedup(speedup: Option<f64>) -> Precision {
        if speedup.is_some_and(|s| s >= AUTO_BF16_MIN_SPEEDUP) {
            Precision::Bf16
        } else {
            Precision::F32
        }
    }

    /// `f32`, `bf16` (an error where the CPU has no bf16 kernel: emulating it would be slower
    /// than f32) or `auto` (measured in this process).
    pub fn resolve(name: &str) -> Result<Precision, PrecisionError> {
        Precision::resolve_cached(name, None)
    }

    /// [`Precision::resolve`], with `auto`'s calibration kept in `dir`
    /// ([`Precision::auto_cached`]).
    pub fn resolve_cached(name: &str, dir: Option<&Path>) -> Result<Precision, PrecisionError> {
        match name {
            "f32" => Ok(Precision::F32),
            "auto" => Ok(Precision::auto_cached(dir)),
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

/// f32 time / bf16 time of the weight products on this CPU (the process's [`calibration`]);
/// `None` where the CPU has no bf16 kernel.
pub fn bf16_speedup() -> Option<f64> {
    calibration(None).map(|c| c.speedup)
}

/// `auto`'s measurement: how much faster this CPU's best bf16 kernel multiplies than its best
/// f32 kernel.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Calibration {
    /// f32 time / bf16 time.
    pub speedup: f64,
    /// The kernels compared ([`Kernel::name`]).
    pub f32_kernel: String,
    /// The bf16 kernel.
    pub bf16_kernel: String,
    /// Best single-thread seconds of each.
    pub f32_seconds: f64,
    /// The same for bf16.
    pub bf16_seconds: f64,
    /// Where it came from: "measured" in this process, or "cached" from an earlier run.
    #[serde(skip, default = "cached")]
    pub source: &'static str,
}

fn cached() -> &'static str {
    "cached"
}

/// The file in a cache folder that keeps calibrations, one per CPU model and kernel pair.
pub const CALIBRATION_FILE: &str = "clip-calibration.json";

/// This process's calibration, `None` where the CPU has no bf16 kernel. Decided once per
/// process, by the first call: with `dir`, read from `dir/clip-calibration.json` under this
/// machine's key (the CPU's model, the two kernels and this crate's version), or measured and
/// stored there; without, measured.
///
/// Why a measurement and not the flag or a table: CPUs with the same AVX512_BF16 flag differ
/// by 2.6× in this ratio (Zen 4 against one Intel Xeon), and a table would miss every CPU the
/// benchmarks never met. The product is one of ViT-B/32's MLP shapes (3 views × 50 tokens,
/// 768 → 3072) on one thread (the kernels' speed ratio, without the scheduling noise of a
/// shared machine), each kernel's best of 7 runs, the two taking turns so a load on the
/// machine meets both alike: about 40 ms. Why kept on disk: a measurement near the threshold
/// could pick bf16 in one run and f32 in the next, and the two give different TFs; with the
/// file, every run on a machine picks alike until the CPU, the kernels or t2tf change (or the
/// file is removed). A file that cannot be read or written is measured around, never an error.
pub fn calibration(dir: Option<&Path>) -> Option<Calibration> {
    static CALIBRATION: std::sync::OnceLock<Option<Calibration>> = std::sync::OnceLock::new();
    CALIBRATION
        .get_or_init(|| {
            let f32_kernel = Kernel::best(Precision::F32)?;
            let bf16_kernel = Kernel::best(Precision::Bf16)?;
            let key = format!(
                "{} | {} | {} | t2tf-clip {}",
                t2tf_core::platform::cpu()
                    .model
                    .unwrap_or_else(|| "unknown CPU".into()),
                f32_kernel.name(),
                bf16_kernel.name(),
                env!("CARGO_PKG_VERSION")
            );
            let file = dir.map(|d| d.join(CALIBRATION_FILE));
            let mut table: std::collections::BTreeMap<String, Calibration> = file
                .as_deref()
                .and_then(|f| std::fs::read(f).ok())
                .and_then(|bytes| serde_json::from_slice(&bytes).ok())
                .unwrap_or_default();
            if let Some(found) = table.get(&key).filter(|c| c.speedup.is_finite()) {
                return Some(found.clone());
            }
            let measured = measure(f32_kernel, bf16_kernel);
            if let (Some(file), Some(dir)) = (&file, dir) {
                table.insert(key, measured.clone());
                // Best effort: an unwritable cache only means the next run measures again.
                if let Ok(json) = serde_json::to_vec_pretty(&table) {
                    let _ = std::fs::create_dir_all(dir);
                    let _ = t2tf_core::fs::atomic_replace_bytes(file, &json);
                }
            }
            Some(measured)
        })
        .clone()
}

/// Time the two kernels on one of ViT-B/32's MLP products (see [`calibration`]).
fn measure(f32_kernel: Kernel, bf16_kernel: Kernel) -> Calibration {
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
    Calibration {
        speedup: best[0] / best[1].max(1e-9),
        f32_kernel: f32_kernel.name().into(),
        bf16_kernel: bf16_kernel.name().into(),
        f32_seconds: best[0],
        bf16_seconds: best[1],
        source: "measured",
    }
}

/// Why a precision name cannot be had.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PrecisionError {
    /// bf16 on a CPU without a bf16 kernel (emulating it would be slower than f32).
    #[error(
        "bf16 needs AVX512_BF16 or AMX-BF16, which this CPU lacks ({features}); use f32 or auto"
    )]
    NotNative {
        /// What the CPU has and lacks.
        features: String,
    },
    /// Not f32, bf16 or auto.
    #[error("precision {0:?}: expected f32, bf16 or auto")]
    Unknown(String),
}
