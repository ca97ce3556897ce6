//! Resource limits for the `t2tf` processes a test starts (shared by the `cli` and `volume`
//! test binaries through `#[path]`).

#![allow(dead_code)] // each test binary uses its own subset

use std::process::Command;

/// `cmd` run under an address-space limit of `bytes` (`RLIMIT_AS`, as `ulimit -v` sets it), so
/// an allocation the budget should have refused aborts the child instead of passing.
pub fn limit_address_space(cmd: &mut Command, bytes: u64) -> &mut Command {
    use std::os::unix::process::CommandExt;
    // SAFETY: setrlimit is async-signal-safe and touches no memory of the parent.
    unsafe {
        cmd.pre_exec(move || {
            let lim = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        })
    }
}

/// `t2tf info --json` on `path` under an address-space limit of `bytes`, with one malloc arena
/// (each thread's arena reserves address space it may never use): its report, once it is
/// checked that the run succeeded and that the histogram counts all `points` points.
pub fn info_within(path: &std::path::Path, bytes: u64, points: u64) -> serde_json::Value {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_t2tf"));
    cmd.env("MALLOC_ARENA_MAX", "1");
    cmd.arg("info").arg(path).arg("--json");
    let out = limit_address_space(&mut cmd, bytes).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "t2tf info failed: {stderr}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let counts: u64 = report["histogram"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["count"].as_u64().unwrap())
        .sum();
    assert_eq!(counts, points, "{report}");
    report
}

/// `cmd` run with files limited to `bytes` (`RLIMIT_FSIZE`, as `ulimit -f` sets it) and
/// SIGXFSZ ignored, so a write past it fails with EFBIG ("File too large") as a write to a
/// full disk fails with ENOSPC: the same error path, without filling a disk.
pub fn limit_file_size(cmd: &mut Command, bytes: u64) -> &mut Command {
    use std::os::unix::process::CommandExt;
    // SAFETY: signal and setrlimit are async-signal-safe and touch no memory of the parent;
    // an ignored signal stays ignored across exec.
    unsafe {
        cmd.pre_exec(move || {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let lim = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        })
    }
}
