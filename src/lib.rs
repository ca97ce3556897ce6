//! t2tf: text to transfer function.
//!
//! The pipeline (see ARCHITECTURE.md) flows one way through these modules:
//! `volume` → `tf` → `camera`/`background` → `render` → `clip` → `optimize` → `formats`.
//! The command-line interface is the binary's (src/main.rs, src/cli), not part of this API.
//!
//! The public API is what the binary, the tests and `examples/demo_recover` and
//! `examples/fuzz` use. The benchmarks (`examples/bench_*`) need a few internals more; those
//! are `pub(crate)` and exported only through the `bench` module, which exists with the
//! `bench` feature (`cargo run --release --features bench --example bench_clip`).

#![warn(missing_docs)]

pub mod background;
#[cfg(feature = "bench")]
pub mod bench;
pub mod camera;
pub mod clip;
pub mod formats;
pub mod fs;
pub mod hub;
pub mod image;
#[cfg(test)]
mod import_loops;
pub(crate) mod math;
pub mod memory;
pub mod optimize;
pub mod progress;
pub mod render;
pub mod signals;
pub mod tf;
pub mod units;
pub mod volume;
