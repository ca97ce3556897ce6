//! Resource limits for the `t2tf` processes a test starts (shared by the `cli` and `volume`
//! test binaries through `#[path]`).

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
