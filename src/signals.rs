//! SIGINT, SIGTERM and SIGHUP (on Windows: Ctrl-C, Ctrl-Break and closing the console) ask a
//! long run to stop: the first one raises the [`stop_flag`] (the loop ends after its current
//! step and the result is written), a second one exits at once. The signal is remembered so
//! the process can exit with 128 + its number, as shells expect.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::OnceLock;

#[cfg(unix)]
mod unix;
#[cfg(unix)]
use unix as os;
#[cfg(windows)]
mod windows;
#[cfg(windows)]
use windows as os;

/// Raised by the first stop signal (read it through [`stop_flag`], which installs the
/// handlers).
static STOP: AtomicBool = AtomicBool::new(false);
/// The first stop signal received (0: none).
static SIGNAL: AtomicI32 = AtomicI32::new(0);

/// The stop flag: SIGINT, SIGTERM or SIGHUP (Ctrl-C, Ctrl-Break or closing the console on
/// Windows) raise it, which ends the loop after the current
/// step with that step's TF; the handlers are installed on first use (a warning on stderr
/// if the system refuses them).
pub fn stop_flag() -> &'static AtomicBool {
    static INSTALLED: OnceLock<()> = OnceLock::new();
    INSTALLED.get_or_init(|| {
        if let Err(e) = os::install() {
            errln!("t2tf: warning: Ctrl-C will not stop cleanly: {e}");
        }
    });
    &STOP
}

/// Record stop signal `sig`: `false` when one came before (the caller exits at once).
fn raise(sig: i32) -> bool {
    if STOP.swap(true, Ordering::SeqCst) {
        return false;
    }
    SIGNAL.store(sig, Ordering::SeqCst);
    true
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
    os::name(sig)
}
