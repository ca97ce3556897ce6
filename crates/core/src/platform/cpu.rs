//! The CPU's model name and feature flags, for reports: what decides which kernels run and so
//! the last bits of a result.

/// The CPU as the system names it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Cpu {
    /// The model name ("AMD EPYC 9R14", "Apple M2"), where the system says.
    pub model: Option<String>,
    /// Feature flags, spelled as Linux's `/proc/cpuinfo` spells them (`avx2`, `avx512_bf16`,
    /// `asimd`): all of them on Linux, the ones the kernels look at elsewhere.
    pub flags: Vec<String>,
}

/// This machine's CPU.
pub fn cpu() -> Cpu {
    if let Ok(text) = std::fs::read_to_string("/proc/cpuinfo") {
        let parsed = parse_cpuinfo(&text);
        // Under an emulator (qemu-user) /proc/cpuinfo describes the host's CPU, not the one
        // this program runs on: kept only when it holds the flags this CPU reports.
        let detected = detected_flags();
        let ours = detected.iter().all(|f| parsed.flags.contains(f));
        if ours && (parsed.model.is_some() || !parsed.flags.is_empty()) {
            return parsed;
        }
    }
    Cpu {
        model: brand(),
        flags: detected_flags(),
    }
}

/// The CPU's brand string from the kernel (`sysctl`).
#[cfg(target_vendor = "apple")]
fn brand() -> Option<String> {
    super::macos::cpu_brand()
}

/// The CPU's brand string from `sysinfo` (CPUID on x86, the system's name elsewhere).
#[cfg(not(target_vendor = "apple"))]
fn brand() -> Option<String> {
    use sysinfo::{CpuRefreshKind, RefreshKind, System};
    let sys =
        System::new_with_specifics(RefreshKind::nothing().with_cpu(CpuRefreshKind::nothing()));
    sys.cpus()
        .first()
        .map(|c| c.brand().trim().to_string())
        .filter(|b| !b.is_empty())
}

/// The flags asked of the CPU itself where `/proc/cpuinfo` does not say: those t2tf's
/// kernels dispatch on, by their `/proc/cpuinfo` names.
#[cfg(target_arch = "x86_64")]
const ASKED: &[&str] = &[
    "sse2",
    "avx",
    "avx2",
    "fma",
    "f16c",
    "avx512f",
    "avx512bw",
    "avx512_bf16",
];
#[cfg(target_arch = "aarch64")]
const ASKED: &[&str] = &["asimd", "fphp", "bf16", "i8mm", "sve"];
#[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
const ASKED: &[&str] = &[];

/// Whether this CPU has the feature `/proc/cpuinfo` calls `name`, asked of the CPU itself
/// (std's run-time detection); `false` for a name this architecture does not ask about.
pub fn has_flag(name: &str) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        match name {
            "sse2" => has!("sse2"),
            "avx" => has!("avx"),
            "avx2" => has!("avx2"),
            "fma" => has!("fma"),
            "f16c" => has!("f16c"),
            "avx512f" => has!("avx512f"),
            "avx512bw" => has!("avx512bw"),
            "avx512_bf16" => has!("avx512bf16"),
            _ => false,
        }
    }
    #[cfg(target_arch = "aarch64")]
    {
        use std::arch::is_aarch64_feature_detected as has;
        match name {
            "asimd" => has!("neon"),
            "fphp" => has!("fp16"),
            "bf16" => has!("bf16"),
            "i8mm" => has!("i8mm"),
            "sve" => has!("sve"),
            _ => false,
        }
    }
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    {
        let _ = name;
        false
    }
}

/// The flags of [`ASKED`] this CPU has.
fn detected_flags() -> Vec<String> {
    ASKED
        .iter()
        .filter(|f| has_flag(f))
        .map(|f| f.to_string())
        .collect()
}

/// The first processor's model name and flags from `/proc/cpuinfo`'s text (x86 says
/// "model name" and "flags"; ARM "Features", often with no model name).
fn parse_cpuinfo(text: &str) -> Cpu {
    let first = text.split("\n\n").next().unwrap_or("");
    let field = |keys: &[&str]| {
        first.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            keys.contains(&k.trim()).then(|| v.trim().to_string())
        })
    };
    Cpu {
        model: field(&["model name", "Model"]).filter(|m| !m.is_empty()),
        flags: field(&["flags", "Features"])
            .map(|f| f.split_whitespace().map(str::to_string).collect())
            .unwrap_or_default(),
    }
}

/// Whether this CPU's AMX tiles (AMX-TILE and AMX-BF16) may be used by this process, asking
/// the system for them where it must: `Err` says why not.
///
/// Three things must hold: the CPU reports AMX-TILE and AMX-BF16 (CPUID leaf 7, EDX bits 24
/// and 22); the system saves the tile state (XCR0 bits 17 and 18, read with `xgetbv` where
/// CPUID says the system uses XSAVE); and on Linux the process has asked for it: Linux
/// enables the tile data only for processes that request it
/// (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`, Linux 5.16 and later), and an AMX
/// instruction before that raises SIGILL. Windows enables the state for every process where
/// XCR0 has it. The answer is computed once per process.
pub fn amx_tiles() -> Result<(), String> {
    static ANSWER: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    ANSWER.get_or_init(ask_amx_tiles).clone()
}

#[cfg(target_arch = "x86_64")]
fn ask_amx_tiles() -> Result<(), String> {
    use std::arch::x86_64::__cpuid_count;
    // CPUID exists on every x86-64 CPU; leaf 7 is read only where reported.
    let leaf7 = (__cpuid_count(0, 0).eax >= 7).then(|| __cpuid_count(7, 0).edx);
    let edx = leaf7.unwrap_or(0);
    if edx & (1 << 24) == 0 || edx & (1 << 22) == 0 {
        return Err("the CPU lacks AMX-TILE and AMX-BF16".into());
    }
    // OSXSAVE (CPUID leaf 1, ECX bit 27): the system uses XSAVE, so XGETBV may be executed.
    if __cpuid_count(1, 0).ecx & (1 << 27) == 0 {
        return Err("the system does not save extended CPU state (no OSXSAVE)".into());
    }
    // SAFETY: XGETBV is available where OSXSAVE is set (checked above).
    let xcr0 = unsafe { xcr0() };
    if xcr0 & (0b11 << 17) != 0b11 << 17 {
        return Err("the system does not save the AMX tile state (XCR0)".into());
    }
    #[cfg(target_os = "linux")]
    super::unix::request_tile_data()?;
    Ok(())
}

/// XCR0, the state components the system saves.
///
/// # Safety
/// The CPU must support XGETBV (CPUID.1:ECX.OSXSAVE).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "xsave")]
unsafe fn xcr0() -> u64 {
    std::arch::x86_64::_xgetbv(0)
}

#[cfg(not(target_arch = "x86_64"))]
fn ask_amx_tiles() -> Result<(), String> {
    Err("AMX needs an x86-64 CPU".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpuinfo_gives_the_first_processors_model_and_flags() {
        let text = "processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: fpu sse2 avx2\n\n\
                    processor\t: 1\nmodel name\t: other\nflags\t\t: fpu\n";
        let cpu = parse_cpuinfo(text);
        assert_eq!(cpu.model.as_deref(), Some("AMD EPYC"));
        assert_eq!(cpu.flags, ["fpu", "sse2", "avx2"]);
        assert_eq!(parse_cpuinfo(""), Cpu::default());
        let arm = "processor\t: 0\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd\n";
        assert_eq!(parse_cpuinfo(arm).flags, ["fp", "asimd"]);
        assert_eq!(parse_cpuinfo(arm).model, None);
    }

    #[test]
    fn this_cpu_names_the_flags_its_kernels_dispatch_on() {
        let cpu = cpu();
        #[cfg(target_arch = "x86_64")]
        assert!(cpu.flags.iter().any(|f| f == "sse2"), "{cpu:?}");
        // The flags asked of the CPU are always among those reported (under qemu-user,
        // /proc/cpuinfo is the host's and is not used).
        for f in detected_flags() {
            assert!(cpu.flags.contains(&f), "{f} detected but not in {cpu:?}");
        }
        // Every name asked about is one `has_flag` answers (a typo would read as absent).
        #[cfg(target_arch = "x86_64")]
        assert!(has_flag("sse2"));
        #[cfg(target_arch = "aarch64")]
        assert!(has_flag("asimd"));
    }
}
