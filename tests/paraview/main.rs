//! Integration tests: real ParaView (pvpython under xvfb): presets, scripts, plugin, render parity.
//!
//! One test binary per area (`cargo test --release --test paraview`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

#[path = "../paraview_util/mod.rs"]
mod paraview_util;

mod paraview;
mod paraview_apply;
mod paraview_library;
mod paraview_match;
mod paraview_parity;
mod paraview_plugin;
mod paraview_tables;
