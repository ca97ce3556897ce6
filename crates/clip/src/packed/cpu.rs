//! What the CPU offers the kernels, as the dispatch and report.json see it.

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

/// Whether the CPU reports AMX-BF16 (CPUID leaf 7 EDX bit 22), whether or not the system lets
/// this process use it (`super::amx::status` decides that). `is_x86_feature_detected!` has no
/// stable name for AMX.
#[cfg(target_arch = "x86_64")]
pub(super) fn amx_bf16() -> bool {
    // CPUID exists on every x86-64 CPU (a safe intrinsic); leaf 7 is only read when reported.
    use std::arch::x86_64::__cpuid_count;
    __cpuid_count(0, 0).eax >= 7 && __cpuid_count(7, 0).edx & (1 << 22) != 0
}
