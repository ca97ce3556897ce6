//! t2tf: text to transfer function.
//!
//! The pipeline (see ARCHITECTURE.md) flows one way through these modules:
//! `volume` → `tf` → `camera`/`background` → `render` → `clip` → `optimize` → `formats`.
//! The command-line interface is the binary's (src/main.rs, src/cli), not part of this API.

#![warn(missing_docs)]

pub mod background;
pub mod camera;
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
