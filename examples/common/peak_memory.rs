//! The process's peak resident memory, for the benchmarks that report it. Linux keeps it in
//! `/proc/self/status` (`VmHWM`); elsewhere it is not read (`None`, printed "n/a"): measure
//! with the system's tools there (`/usr/bin/time -l` on macOS, Process Explorer on Windows).

/// Peak resident set of this process in KiB, where the system says (Linux).
pub fn peak_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find_map(|l| l.strip_prefix("VmHWM:"))?;
    line.trim().trim_end_matches("kB").trim().parse().ok()
}
