//! Integration tests: the renderer: cases, gradients, defaults, presets.
//!
//! One test binary per area (`cargo test --release --test render`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

#[path = "../render_util/mod.rs"]
mod render_util;

mod render_cache;
mod render_cases;
mod render_defaults;
mod render_grad;
mod render_presets;
mod render_tape;
