//! Integration tests: real ParaView (pvpython under xvfb): presets, scripts, plugin, render parity.
//!
//! One test binary per area (`cargo test --release --test paraview`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

// ParaView's tests drive Linux's pvpython under Xvfb: Unix only (a cross build for Windows
// compiles none of them).
#[cfg(unix)]
#[path = "../paraview_util/mod.rs"]
mod paraview_util;

#[cfg(unix)]
mod paraview;
#[cfg(unix)]
mod paraview_apply;
#[cfg(unix)]
mod paraview_library;
#[cfg(unix)]
mod paraview_match;
#[cfg(unix)]
mod paraview_parity;
#[cfg(unix)]
mod paraview_plugin;
#[cfg(unix)]
mod paraview_series;
#[cfg(unix)]
mod paraview_tables;
