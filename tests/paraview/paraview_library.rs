//! Every preset of ParaView's library with colour points, sampled by ParaView itself: pvpython
//! applies each preset (`ApplyPreset`, not discretized) and asks its
//! `vtkColorTransferFunction` for the colour at 1024 points across the preset's range. t2tf,
//! reading the same presets from the exported library (tests/fixtures/paraview), must give the
//! same colours within 1/255 everywhere: evaluated in the preset's own colour space, and as the
//! RGB-linear polyline the renderer and the `.ct` format get.
//!
//! Without pvpython this test is ignored, unless T2TF_REQUIRE_PARAVIEW=1.

use crate::paraview_util;

use std::path::Path;

use paraview_util::{pvpython, repo, require_paraview};
use t2tf::formats::read_preset;
use t2tf::tf::interpolate;

const SAMPLES: usize = 1024;

/// ParaView's side: one pvpython run over the whole library, samples written as JSON.
const SCRIPT: &str = r#"
import json, sys
from paraview.simple import GetColorTransferFunction
library, out_path, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
with open(library) as f:
    presets = json.load(f)
lut = GetColorTransferFunction('t2tf_library_check')
out = {}
for p in presets:
    points = p.get('RGBPoints')
    if not points:
        continue
    name = p['Name']
    if not lut.ApplyPreset(name, False):
        raise SystemExit('ParaView has no preset named %r' % name)
    lut.Discretize = 0
    lut.UpdateVTKObjects()
    ctf = lut.GetClientSideObject()
    xs = points[0::4]
    lo, hi = min(xs), max(xs)
    samples = [lo + (hi - lo) * i / (n - 1) for i in range(n)]
    rgb = []
    for x in samples:
        c = [0.0, 0.0, 0.0]
        ctf.GetColor(x, c)
        rgb.append(c)
    out[name] = {'space': str(lut.ColorSpace), 'x': samples, 'rgb': rgb}
with open(out_path, 'w') as f:
    json.dump(out, f)
"#;

fn max_error(ours: &[[f64; 3]], theirs: &[[f64; 3]]) -> (f64, usize) {
    let mut worst = (0.0f64, 0);
    for (i, (a, b)) in ours.iter().zip(theirs).enumerate() {
        let e = (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max);
        if e > worst.0 {
            worst = (e, i);
        }
    }
    worst
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn every_library_preset_matches_paraviews_own_sampling() {
    require_paraview("every_library_preset_matches_paraviews_own_sampling");
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("sample_library.py");
    std::fs::write(&script, SCRIPT).unwrap();
    let library = repo().join("tests/fixtures/paraview/paraview_library.json");
    let out = dir.path().join("samples.json");
    pvpython(
        &script,
        &[
            library.to_str().unwrap(),
            out.to_str().unwrap(),
            &SAMPLES.to_string(),
        ],
    );
    let samples: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let samples = samples.as_object().unwrap();
    assert!(
        samples.len() >= 100,
        "only {} presets sampled",
        samples.len()
    );
    let mut failures = Vec::new();
    for (name, s) in samples {
        let xs: Vec<f64> = paraview_util::floats(&s["x"]);
        let theirs: Vec<[f64; 3]> = s["rgb"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| {
                let c = paraview_util::floats(c);
                [c[0], c[1], c[2]]
            })
            .collect();
        let preset =
            read_preset(Path::new(&library), Some(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let direct = preset.color_map().colors_at(&xs);
        let linear = preset.rgb_linear();
        let linear: Vec<[f64; 3]> = xs
            .iter()
            .map(|&x| interpolate(&linear.rgb_points, x))
            .collect();
        let (e_direct, i_direct) = max_error(&direct, &theirs);
        let (e_linear, i_linear) = max_error(&linear, &theirs);
        if e_direct > 1.0 / 255.0 || e_linear > 1.0 / 255.0 {
            failures.push(format!(
                "{name} ({}): direct {:.2}/255 at x = {} (ours {:?}, ParaView {:?}); RGB-linear {:.2}/255 at x = {}",
                s["space"],
                e_direct * 255.0,
                xs[i_direct],
                direct[i_direct],
                theirs[i_direct],
                e_linear * 255.0,
                xs[i_linear]
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} presets differ from ParaView by more than 1/255:\n{}",
        failures.len(),
        samples.len(),
        failures.join("\n")
    );
}
