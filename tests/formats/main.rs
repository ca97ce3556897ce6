//! Integration tests: TF formats and presets: conversion, round trips, colour spaces, errors.
//!
//! One test binary per area (`cargo test --release --test formats`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

#[path = "../colorspace_goldens/mod.rs"]
mod colorspace_goldens;

mod formats_convert;
mod formats_errors;
mod formats_hostile;
mod formats_placeholders;
mod formats_roundtrip;
mod formats_scripts;
mod presets_colorspaces;
mod presets_library;
mod tf_hard_cases;
