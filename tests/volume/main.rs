//! Integration tests: volume readers: fixtures, shared volumes, errors, hostile files, the fuzz corpus.
//!
//! One test binary per area (`cargo test --release --test volume`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

mod fuzz_replay;
mod hostile_volumes;
#[cfg(unix)]
#[path = "../limits_util/mod.rs"]
mod limits_util;
mod volume_blocks;
mod volume_errors;
mod volume_fixtures;
#[cfg(unix)]
mod volume_large_cli;
mod volume_series;
mod volume_shared;
mod volume_stream;
