//! Integration tests: the optimizer: loop, driver, CLI, progress, recovery, render size.
//!
//! One test binary per area (`cargo test --release --test optimize`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

#[path = "../colorspace_goldens/mod.rs"]
mod colorspace_goldens;
#[path = "../optimize_toy/mod.rs"]
mod optimize_toy;
#[path = "../render_util/mod.rs"]
mod render_util;

mod optimize_cli;
mod optimize_driver;
mod optimize_e2e;
mod optimize_loop;
mod optimize_pipeline;
mod optimize_preview;
mod optimize_progress;
mod optimize_recovery;
mod optimize_refine;
mod optimize_render_size;
mod optimize_reproduce;
mod optimize_series;
mod optimize_series_recover;
