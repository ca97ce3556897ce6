//! ParaView's own numbers for the colour-space fixtures: each preset in
//! tests/fixtures/paraview was written by ParaView's `ExportTransferFunction` and sampled with
//! VTK's `GetColor`/`GetValue` (colorspace_samples.json, by make_colorspace_presets.py): 1024
//! colours and opacities over the preset's range, what t2tf must reproduce.

#![allow(dead_code)] // each test binary uses its own subset

use std::path::Path;

/// One fixture file's samples.
pub struct Golden {
    /// The fixture's file name.
    pub file: String,
    /// Data values sampled.
    pub x: Vec<f64>,
    /// ParaView's colour there.
    pub rgb: Vec<[f64; 3]>,
    /// ParaView's opacity there.
    pub opacity: Vec<f64>,
}

/// Every fixture's samples.
pub fn goldens() -> Vec<Golden> {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/paraview/colorspace_samples.json"),
    )
    .unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let nums = |a: &serde_json::Value| -> Vec<f64> {
        a.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    v.as_object()
        .unwrap()
        .iter()
        .map(|(file, s)| Golden {
            file: file.clone(),
            x: nums(&s["x"]),
            rgb: s["rgb"]
                .as_array()
                .unwrap()
                .iter()
                .map(|c| {
                    let c = nums(c);
                    [c[0], c[1], c[2]]
                })
                .collect(),
            opacity: nums(&s["opacity"]),
        })
        .collect()
}
