//! Colour spaces against ParaView's own numbers: each fixture preset was written by
//! ParaView's `ExportTransferFunction` and sampled with VTK's `GetColor`/`GetValue` by
//! tests/fixtures/paraview/make_colorspace_presets.py (colorspace_samples.json). t2tf must
//! reproduce those 1024 colours and opacities reading the file, after json → xml → json,
//! and (8-bit) after json → .ct.

use std::path::{Path, PathBuf};

use crate::colorspace_goldens::{goldens, Golden};

use t2tf::formats::{read_preset, read_tf, write_preset, ExportTf};
use t2tf::tf::{interpolate, ColorSpace};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/paraview")
}

/// Max abs colour and opacity error of an RGB-linear TF against the goldens.
fn errors_linear(tf: &ExportTf, g: &Golden) -> (f64, f64) {
    let o: Vec<(f64, [f64; 1])> = tf.opacity_points.iter().map(|&(x, o)| (x, [o])).collect();
    let (mut ec, mut eo) = (0.0f64, 0.0f64);
    for (i, &x) in g.x.iter().enumerate() {
        let c = interpolate(&tf.rgb_points, x);
        (0..3).for_each(|k| ec = ec.max((c[k] - g.rgb[i][k]).abs()));
        eo = eo.max((interpolate(&o, x)[0] - g.opacity[i]).abs());
    }
    (ec, eo)
}

#[test]
fn every_colour_space_matches_paraview_samples() {
    let dir = tempfile::tempdir().unwrap();
    let gs = goldens();
    assert_eq!(
        gs.len(),
        7,
        "one fixture per space (HSV twice: with and without wrap)"
    );
    for g in &gs {
        let path = fixtures().join(&g.file);
        let preset = read_preset(&path, None).unwrap();
        assert_ne!(
            preset.space == ColorSpace::Rgb,
            !g.file.contains("RGB"),
            "{}",
            g.file
        );
        // Direct evaluation in the preset's own space.
        let colors = preset.color_map().colors_at(&g.x);
        let direct = colors
            .iter()
            .zip(&g.rgb)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
            .fold(0.0, f64::max);
        // json → xml → json keeps the space.
        let xml = dir.path().join("a.xml");
        let json = dir.path().join("b.json");
        write_preset(&xml, &preset).unwrap();
        write_preset(&json, &read_preset(&xml, None).unwrap()).unwrap();
        let back = read_preset(&json, None).unwrap();
        // XML shares positions between colour and opacity; Diverging and CIEDE2000 are not
        // kept by added points, so with opacity points of their own they go RGB-linear.
        let kept = !matches!(
            preset.space,
            ColorSpace::Diverging | ColorSpace::LabCiede2000
        );
        assert_eq!(
            back.space,
            if kept { preset.space } else { ColorSpace::Rgb },
            "{}",
            g.file
        );
        let colors = back.color_map().colors_at(&g.x);
        let round = colors
            .iter()
            .zip(&g.rgb)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
            .fold(0.0, f64::max);
        // The RGB-linear form (renderer) and json → .ct (8-bit, RGB only).
        let (lin_c, lin_o) = errors_linear(&read_tf(&path).unwrap(), g);
        let ct = dir.path().join("c.ct");
        write_preset(&ct, &preset).unwrap();
        let (ct_c, ct_o) = errors_linear(&read_tf(&ct).unwrap(), g);
        eprintln!(
            "{:32} direct {:.2e}  json→xml→json {:.2e}  rgb-linear {:.2e} (opacity {:.1e})  .ct {:.2e} (opacity {:.1e})  [units of 1/255: {:.2} {:.2} {:.2} {:.2}]",
            g.file, direct, round, lin_c, lin_o, ct_c, ct_o,
            direct * 255.0, round * 255.0, lin_c * 255.0, ct_c * 255.0
        );
        assert!(direct <= 1.0 / 255.0, "{}: {direct}", g.file);
        assert!(round <= 1.0 / 255.0, "{}: {round}", g.file);
        assert!(
            lin_c <= 1.0 / 255.0 && lin_o <= 1e-9,
            "{}: {lin_c} {lin_o}",
            g.file
        );
        assert!(
            ct_c <= 2.0 / 255.0 && ct_o <= 2.0 / 255.0,
            "{}: {ct_c} {ct_o}",
            g.file
        );
    }
}
