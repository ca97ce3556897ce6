//! ParaView's volume lookup tables resolve every exported TF: VTK sizes its opacity and
//! colour tables from the smallest gap between points and, past the GPU's largest texture,
//! warns "… falling back to maximum allowed …" and maps the TF wrongly. Our exporter keeps
//! points `MIN_GAP` of the range apart; a hand-made TF with closer points shows the warning
//! is seen at all in this ParaView.
//!
//! Without pvpython these tests say so and pass, unless T2TF_REQUIRE_PARAVIEW=1.

use crate::paraview_util;

use std::path::Path;

use paraview_util::{neghip, pvpython, require_paraview};
use t2tf::camera::ParaViewCamera;
use t2tf::formats::{paraview_script, write_all, ExportTf};
use t2tf::tf::ControlPoints;

const WARNING: &str = "falling back to maximum allowed";

/// Run a generated script with a small screenshot (rendering builds the tables); its output.
fn render(script: &Path, dir: &Path) -> String {
    let shot = dir.join(format!(
        "{}.png",
        script.file_stem().unwrap().to_str().unwrap()
    ));
    pvpython(
        script,
        &["--screenshot", shot.to_str().unwrap(), "--size", "64", "64"],
    )
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn exported_close_points_fit_paraview_tables() {
    require_paraview("exported_close_points_fit_paraview_tables");
    let v = neghip();
    let view = ParaViewCamera::front(&v.geometry, 2.5);
    let dir = tempfile::tempdir().unwrap();

    // The control: opacity points 1e-4 data units apart over a range of 255 ask VTK for a
    // table of 2^22 entries.
    let close = ExportTf {
        name: "close".into(),
        rgb_points: vec![(0.0, [0.2, 0.4, 0.9]), (255.0, [1.0, 0.9, 0.6])],
        opacity_points: vec![(0.0, 0.0), (100.0, 0.0), (100.0001, 0.8), (255.0, 0.9)],
        unit_distance: Some(1.0),
    };
    let script = dir.path().join("close_paraview.py");
    let text = paraview_script(&close, &v, &view, [0.0; 3], "close_paraview.py").unwrap();
    std::fs::write(&script, text).unwrap();
    let log = render(&script, dir.path());
    assert!(
        log.contains(WARNING),
        "this ParaView did not warn about a hand-made TF with close points:\n{log}"
    );

    // Through our exporter: control points 1e-6 apart (a jump in density and colour) and a
    // jump at one x. Without the spacing, the jump became a ramp 1e-9 of the range wide and
    // ParaView asked for opacity and colour tables of 2^30 entries.
    let cp = ControlPoints {
        x: vec![0.0, 0.4, 0.4 + 1e-6, 0.7, 0.7, 1.0],
        sigma: vec![0.0, 0.0, 200.0, 120.0, 10.0, 255.0],
        rgb: vec![
            [0.1, 0.1, 0.8],
            [0.2, 0.6, 0.9],
            [0.9, 0.8, 0.2],
            [1.0, 0.3, 0.1],
            [0.3, 1.0, 0.3],
            [1.0, 1.0, 1.0],
        ],
    };
    let files = write_all(dir.path(), "near", &cp, &v, &view, [0.0; 3], None).unwrap();
    let log = render(&files.paraview_script.unwrap(), dir.path());
    assert!(!log.contains(WARNING), "ParaView warned:\n{log}");
}
