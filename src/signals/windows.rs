//! Windows: the console's control handler (`SetConsoleCtrlHandler`) for Ctrl-C, Ctrl-Break and
//! closing the console (or logging off, or shutting down).
//!
//! Written against `windows-sys` rather than with the `ctrlc` crate: on a close event Windows
//! ends the process as soon as the handler returns, and `ctrlc`'s handler returns at once. Here
//! the handler waits instead, so the run can finish its step and write its TF within the grace
//! period Windows gives (5 s after a close; the process's exit ends the wait).

use windows_sys::core::BOOL;
use windows_sys::Win32::Foundation::TRUE;
use windows_sys::Win32::System::Console::{
    SetConsoleCtrlHandler, CTRL_BREAK_EVENT, CTRL_CLOSE_EVENT, CTRL_C_EVENT, CTRL_LOGOFF_EVENT,
    CTRL_SHUTDOWN_EVENT,
};

/// The numbers the C runtime gives these events (`signal.h`: SIGINT 2, SIGBREAK 21), and 1
/// (SIGHUP's) for a close, so exit codes read as on Unix: 130 after Ctrl-C.
const SIGINT: i32 = 2;
const SIGBREAK: i32 = 21;
const SIGHUP: i32 = 1;

/// Install the handler. Returns an error text if the system refused.
pub(super) fn install() -> Result<(), String> {
    // SAFETY: registers a function with the signature the system expects; it only touches
    // atomics and sleeps.
    if unsafe { SetConsoleCtrlHandler(Some(on_event), TRUE) } == 0 {
        return Err(std::io::Error::last_os_error().to_string());
    }
    Ok(())
}

/// Runs on a thread the system starts for the event.
unsafe extern "system" fn on_event(event: u32) -> BOOL {
    let (sig, closing) = match event {
        CTRL_C_EVENT => (SIGINT, false),
        CTRL_BREAK_EVENT => (SIGBREAK, false),
        CTRL_CLOSE_EVENT | CTRL_LOGOFF_EVENT | CTRL_SHUTDOWN_EVENT => (SIGHUP, true),
        _ => return 0,
    };
    if !super::raise(sig) && !closing {
        // Second Ctrl-C: the user does not want to wait for the step to finish.
        std::process::exit(128 + sig);
    }
    if closing {
        // Windows ends the process when this returns: wait for the run to write its TF and
        // exit (which ends this thread), up to the system's grace period.
        std::thread::sleep(std::time::Duration::from_secs(10));
    }
    TRUE
}

/// What stopped the run, for messages.
pub(super) fn name(sig: i32) -> &'static str {
    match sig {
        SIGINT => "Ctrl-C",
        SIGBREAK => "Ctrl-Break",
        SIGHUP => "the console closing",
        _ => "a console event",
    }
}
