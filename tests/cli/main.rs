//! Integration tests: the CLI's messages, info, and hostile runs (signals, locks, memory limits).
//!
//! One test binary per area (`cargo test --release --test cli`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

mod cli_cache;
mod cli_colour_only;
mod cli_error_kinds;
mod cli_help;
mod cli_info;
mod cli_messages;
mod cli_streams;
#[cfg(unix)]
mod hostile_cli;
#[cfg(unix)]
#[path = "../limits_util/mod.rs"]
mod limits_util;
mod reap;
#[cfg(unix)]
mod special_inputs;
mod start_inputs;
