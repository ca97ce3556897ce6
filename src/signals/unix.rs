//! Unix: `sigaction` for SIGINT, SIGTERM and SIGHUP.

/// Install the handlers (idempotent). Returns an error text if the system refused.
pub(super) fn install() -> Result<(), String> {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: a zeroed sigaction with only the handler set is valid; the handler below
        // touches only atomics and async-signal-safe calls.
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_signal as *const () as libc::sighandler_t;
            action.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut action.sa_mask);
            if libc::sigaction(sig, &action, std::ptr::null_mut()) != 0 {
                return Err(std::io::Error::last_os_error().to_string());
            }
        }
    }
    Ok(())
}

extern "C" fn on_signal(sig: libc::c_int) {
    if !super::raise(sig) {
        // Second signal: the user does not want to wait for the step to finish.
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(128 + sig) };
    }
    if sig == libc::SIGHUP {
        detach_terminal_stderr();
    }
}

/// After a hang-up, writes to the lost terminal fail and would abort the run before it saves:
/// send stderr to /dev/null instead (only when it is a terminal; pipes and files stay).
fn detach_terminal_stderr() {
    // SAFETY: isatty, open, dup2 and close are async-signal-safe; the path is a C literal.
    unsafe {
        if libc::isatty(2) == 1 {
            let fd = libc::open(c"/dev/null".as_ptr(), libc::O_WRONLY);
            if fd >= 0 {
                libc::dup2(fd, 2);
                libc::close(fd);
            }
        }
    }
}

/// The conventional name of a stop signal, for messages.
pub(super) fn name(sig: i32) -> &'static str {
    match sig {
        libc::SIGINT => "SIGINT",
        libc::SIGTERM => "SIGTERM",
        libc::SIGHUP => "SIGHUP",
        _ => "a signal",
    }
}
