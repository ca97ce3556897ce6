//! SIGINT, SIGTERM and SIGHUP ask a long run to stop: the first one raises the [`stop_flag`] (the loop
//! ends after its current step and the result is written), a second one exits at once. The
//! signal is remembered so the process can exit with 128 + its number, as shells expect.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::OnceLock;

/// Raised by the first stop signal (read it through [`stop_flag`], which installs the
/// handlers).
static STOP: AtomicBool = AtomicBool::new(false);
/// The first stop signal received (0: none).
static SIGNAL: AtomicI32 = AtomicI32::new(0);

/// The stop flag: SIGINT, SIGTERM or SIGHUP raise it, which ends the loop after the current
/// step with that step's TF; the handlers are installed on first use (a warning on stderr
/// if the system refuses them).
pub fn stop_flag() -> &'static AtomicBool {
    static INSTALLED: OnceLock<()> = OnceLock::new();
    INSTALLED.get_or_init(|| {
        if let Err(e) = install() {
            errln!("t2tf: warning: Ctrl-C will not stop cleanly: {e}");
        }
    });
    &STOP
}

/// Install the handlers (idempotent). Returns an error text if the system refused.
fn install() -> Result<(), String> {
    #[cfg(unix)]
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

#[cfg(unix)]
extern "C" fn on_signal(sig: libc::c_int) {
    if STOP.swap(true, Ordering::SeqCst) {
        // Second signal: the user does not want to wait for the step to finish.
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(128 + sig) };
    }
    SIGNAL.store(sig, Ordering::SeqCst);
    if sig == libc::SIGHUP {
        detach_terminal_stderr();
    }
}

/// After a hang-up, writes to the lost terminal fail and would abort the run before it saves:
/// send stderr to /dev/null instead (only when it is a terminal; pipes and files stay).
#[cfg(unix)]
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

/// The stop signal received, if any.
pub fn received() -> Option<i32> {
    match SIGNAL.load(Ordering::SeqCst) {
        0 => None,
        s => Some(s),
    }
}

/// The conventional name of a stop signal, for messages.
pub fn name(sig: i32) -> &'static str {
    #[cfg(unix)]
    match sig {
        libc::SIGINT => return "SIGINT",
        libc::SIGTERM => return "SIGTERM",
        libc::SIGHUP => return "SIGHUP",
        _ => {}
    }
    let _ = sig;
    "a signal"
}
