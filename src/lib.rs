//! t2tf: text to transfer function.
//!
//! The pipeline (see ARCHITECTURE.md) flows one way through these modules:
//! `volume` → `tf` → `camera`/`background` → `render` → `clip` → `optimize` → `formats`.
//! `cli` is the thin layer the binary calls into.

pub mod background;
pub mod camera;
pub mod cli;
pub mod clip;
pub mod formats;
pub mod fs;
pub mod hub;
pub mod image;
pub mod math;
pub mod memory;
pub mod optimize;
pub mod progress;
pub mod render;
pub mod signals;
pub mod tf;
pub mod units;
pub mod volume;
