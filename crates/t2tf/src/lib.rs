//! t2tf: text to transfer function.
//!
//! The pipeline (see ARCHITECTURE.md) flows one way through one crate per stage:
//! `t2tf-volume` → `t2tf-tf` → `t2tf-render` → `t2tf-clip` → [`optimize`] → `t2tf-formats`,
//! all standing on `t2tf-core`. This crate is the pipeline: [`pipeline`] runs the main job
//! (load a volume and a model, optimize, write the output set) and re-exports each stage under
//! the name it has in the docs (`t2tf::volume`, `t2tf::render`, …), so one dependency reaches
//! everything. The command-line interface is the repository root's package `t2tf-cli`
//! (src/lib.rs, src/commands), not part of this API.
//!
//! The benchmarks (`examples/bench_*`) need a few internals more; those are exported only
//! through the `bench` module, which exists with the `bench` feature
//! (`cargo run --release --features bench --example bench_clip`).

#![warn(missing_docs)]

#[cfg(feature = "bench")]
pub mod bench;
pub mod hints;
pub mod optimize;
pub mod pipeline;

pub use t2tf_clip as clip;
pub use t2tf_clip::hub;
pub use t2tf_core::{error, fs, image, input, memory, platform, units};
pub use t2tf_formats as formats;
pub use t2tf_render as render;
pub use t2tf_render::{background, camera};
pub use t2tf_tf as tf;
pub use t2tf_volume as volume;
