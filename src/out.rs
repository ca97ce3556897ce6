//! Every print of the command line. `println!` and `eprintln!` panic when their stream is
//! closed (`t2tf info x.raw | head -1`) or full (`> /dev/full`), which would end a command with
//! a panic and exit 101; these writes fail instead.
//!
//! - stdout ([`outln!`], [`out`]): a failed write is an error of the command,
//!   [`StdoutFailed`]. A reader that left (a broken pipe) ends the command quietly with
//!   status 0, as `head` expects of the programs it reads; any other failure (a full disk) is
//!   one error line on stderr and status 1.
//! - stderr ([`errln!`], [`err`]): progress and warnings are not the work. Once a write to it
//!   fails, stderr is dropped for the rest of the process and the work goes on, so a run whose
//!   log pipe closed still writes its files.
//!
//! The process keeps Rust's default of ignoring SIGPIPE: a closed pipe is an error returned by
//! the write, not a signal that kills a run in the middle of writing its outputs.

use std::fmt;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

/// Writing to stdout failed. The system's error is part of the message and not a `source`:
/// the CLI prints the cause chain, which would say it twice.
#[derive(Debug, thiserror::Error)]
#[error("cannot write to standard output: {0}")]
pub struct StdoutFailed(pub std::io::Error);

impl StdoutFailed {
    /// The reader closed its end: nobody wants the rest, which is no failure of the command.
    pub fn reader_left(&self) -> bool {
        self.0.kind() == std::io::ErrorKind::BrokenPipe
    }
}

/// Write to stdout and flush, so that a failure is seen here and not lost at exit.
pub fn out(args: fmt::Arguments) -> Result<(), StdoutFailed> {
    let mut stdout = std::io::stdout().lock();
    stdout
        .write_fmt(args)
        .and_then(|()| stdout.flush())
        .map_err(StdoutFailed)
}

/// Set once a write to stderr failed: nothing more is tried.
static STDERR_FAILED: AtomicBool = AtomicBool::new(false);

/// Write to stderr, whole (one `write_all` under the lock, so lines from threads never
/// interleave); after the first failure, nothing.
pub fn err(args: fmt::Arguments) {
    if STDERR_FAILED.load(Ordering::Relaxed) {
        return;
    }
    let text = args.to_string();
    if std::io::stderr().lock().write_all(text.as_bytes()).is_err() {
        STDERR_FAILED.store(true, Ordering::Relaxed);
    }
}

/// Whether an error of a command is stdout's reader having left (see the module comment).
pub fn reader_left(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<StdoutFailed>()
            .is_some_and(|s| s.reader_left())
    })
}

/// `println!` to stdout that returns `Result<(), StdoutFailed>` instead of panicking.
macro_rules! outln {
    () => {
        $crate::out::out(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::out::out(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `eprintln!` that never panics: dropped once stderr has failed.
macro_rules! errln {
    ($($arg:tt)*) => {
        $crate::out::err(format_args!("{}\n", format_args!($($arg)*)))
    };
}
