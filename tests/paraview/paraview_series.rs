//! The time-series pvpython script in real ParaView (`xvfb-run -a pvpython --dr`), on the
//! Gray–Scott series of tests/fixtures/series written by pvpython into a temporary folder:
//! one picture per time step (the volume visible, inside its box only, growing from the first
//! step to the last), the same pictures whether the series is opened from its `.pvd`, its
//! `.series` file or its list of files, a selection restricted to its steps, raw files read
//! as a series, and ParaView's colour and opacity points equal to the TF's after the time
//! changed (never rescaled, even in a session whose colour map rescaled at every step).
//!
//! Without pvpython these tests say so and pass, unless T2TF_REQUIRE_PARAVIEW=1.

use crate::paraview_util;

use paraview_util::{
    assert_volume_only_inside, floats, projected_box, pvpython, repo, require_paraview, test_tf,
};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use t2tf::camera::ParaViewCamera;
use t2tf::formats::{write_all, ExportTf};
use t2tf::image::{psnr, Image};
use t2tf::volume::{Series, SourceFormat, TimeSelection, Volume};

/// Picture size.
const W: usize = 120;
const H: usize = 96;
const BACKGROUND: [f64; 3] = [0.1, 0.2, 0.3];

/// The Gray–Scott series, 32³ and 4 steps (times 200 … 800), written into `dir` by the
/// fixture's generator; `dtype` float32, or uint8 (raw files too).
fn gray_scott(dir: &Path, dtype: &str) {
    pvpython(
        &repo().join("tests/fixtures/series/make_gray_scott.py"),
        &[
            dir.to_str().unwrap(),
            "--size",
            "32",
            "--steps",
            "4",
            "--dtype",
            dtype,
        ],
    );
}

/// The last used step of the series `path` names (the steps `keep`, else all), normalized
/// over the series' range, as a run over the series loads it.
fn last_step(path: &Path, keep: Option<Vec<usize>>) -> Volume {
    let mut series = Series::open(&[path.to_path_buf()]).unwrap();
    if let Some(indices) = keep {
        series = series
            .select(&TimeSelection {
                range: None,
                indices: Some(indices),
            })
            .unwrap();
    }
    let stats = series.scan(&Default::default(), &mut |_| {}).unwrap();
    let series = Arc::new(series);
    series
        .load_step(
            series.steps.len() - 1,
            stats.norm_range,
            &Default::default(),
        )
        .unwrap()
}

/// An oblique view, so the box projects inside the picture.
fn oblique(v: &Volume) -> ParaViewCamera {
    let c = v.geometry.center();
    let r = v.geometry.bounding_radius();
    ParaViewCamera {
        position: [c[0] + 2.2 * r, c[1] - 2.2 * r, c[2] + 1.0 * r],
        focal_point: c,
        view_up: [0.0, 0.0, 1.0],
        view_angle: 45.0,
    }
}

/// Runs a script (argv[1]) in a session whose colour map for its array (argv[2]) was set to
/// rescale to each time step's range ("Clamp and update every timestep"), as a user's ParaView
/// may be: the script must set it back (AutomaticRescaleRangeMode "Never"), or its TF would
/// follow each step's range (checked: without that line the colours after the last step start
/// at that step's minimum). The script gets the remaining arguments.
const HOSTILE_SESSION: &str = r#"
import runpy, sys
import paraview.simple as pvs
script, array = sys.argv[1], sys.argv[2]
lut = pvs.GetColorTransferFunction(array)
lut.AutomaticRescaleRangeMode = "Clamp and update every timestep"
sys.argv = [script] + sys.argv[3:]
runpy.run_path(script, run_name="__main__")
"#;

/// What one run of a series script left: the exported TF, its pictures, ParaView's state.
struct Run {
    tf: ExportTf,
    shots: Vec<Image>,
    state: serde_json::Value,
    log: String,
}

/// Write the outputs for `v` as `name` into `out` and run its pvpython script with
/// `--screenshot out/NAME.png --size W H --print-tf` and `extra`. `pictures`: the numbered
/// pictures expected (NAME_0000.png, ...), or `None` for one picture named NAME.png.
fn run(v: &Volume, out: &Path, name: &str, extra: &[&str], pictures: Option<usize>) -> Run {
    let files = write_all(out, name, &test_tf(), v, &oblique(v), BACKGROUND, None).unwrap();
    let script = files.paraview_script.expect("script written");
    let shot = out.join(format!("{name}.png"));
    let (w, h) = (W.to_string(), H.to_string());
    let array = match &v.source.as_ref().unwrap().format {
        SourceFormat::Raw { .. } => "ImageFile",
        SourceFormat::Vti { array } | SourceFormat::LegacyVtk { array } => array,
    };
    let driver = out.join("hostile_session.py");
    std::fs::write(&driver, HOSTILE_SESSION).unwrap();
    let mut args = vec![
        script.to_str().unwrap(),
        array,
        "--screenshot",
        shot.to_str().unwrap(),
        "--size",
        &w,
        &h,
        "--print-tf",
    ];
    args.extend(extra);
    let log = pvpython(&driver, &args);
    let numbered = |i: usize| out.join(format!("{name}_{i:04}.png"));
    let paths: Vec<PathBuf> = match pictures {
        Some(n) => {
            assert!(!shot.exists(), "{name}: {} written\n{log}", shot.display());
            assert!(
                !numbered(n).exists(),
                "{name}: more than {n} pictures\n{log}"
            );
            (0..n).map(numbered).collect()
        }
        None => {
            assert!(!numbered(0).exists(), "{name}: numbered pictures\n{log}");
            vec![shot]
        }
    };
    let shots = paths
        .iter()
        .map(|p| Image::load_png(p).unwrap_or_else(|e| panic!("{}: {e}\n{log}", p.display())))
        .collect();
    let state = log
        .lines()
        .find_map(|l| l.strip_prefix("t2tf tf: "))
        .unwrap_or_else(|| panic!("{name}: no --print-tf line\n{log}"));
    Run {
        tf: files.tf,
        shots,
        state: serde_json::from_str(state).unwrap(),
        log: log.clone(),
    }
}

fn assert_close(got: &[f64], want: &[f64], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: {got:?} vs {want:?}");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= 1e-12 * (1.0 + w.abs()),
            "{what}[{i}]: {g} vs {w}"
        );
    }
}

/// Every picture shows the volume inside its box only, the first and the last step differ,
/// and ParaView's transfer functions after the last step are the TF's points, unrescaled,
/// with the TF's unit distance; the animation's times are `times`.
fn check(run: &Run, v: &Volume, name: &str, times: &[f64]) {
    let b = projected_box(v, &oblique(v), W, H);
    for (i, img) in run.shots.iter().enumerate() {
        assert_eq!((img.width, img.height), (W, H), "{name} {i}");
        eprintln!("{name}, picture {i}:");
        assert_volume_only_inside(img, b, BACKGROUND);
    }
    if run.shots.len() > 1 {
        let p = psnr(&run.shots[0], run.shots.last().unwrap());
        eprintln!("{name}: first against last step {p:.1} dB");
        assert!(
            p < 30.0,
            "{name}: the first and last steps look alike ({p:.1} dB)"
        );
    }
    let tf = &run.tf;
    let rgb: Vec<f64> = tf
        .rgb_points
        .iter()
        .flat_map(|&(x, c)| [x, c[0], c[1], c[2]])
        .collect();
    let opacity: Vec<f64> = tf
        .opacity_points
        .iter()
        .flat_map(|&(x, o)| [x, o, 0.5, 0.0])
        .collect();
    let s = &run.state;
    assert_close(&floats(&s["rgb_points"]), &rgb, &format!("{name} colours"));
    assert_close(
        &floats(&s["opacity_points"]),
        &opacity,
        &format!("{name} opacity"),
    );
    assert_eq!(s["rescale_mode"], "Never", "{name}");
    assert_eq!(
        s["unit_distance"].as_f64(),
        Some(tf.unit_distance.unwrap()),
        "{name}"
    );
    // The TF spans the series' range, not the last step's.
    assert_close(
        &[rgb[0], rgb[rgb.len() - 4]],
        &v.norm_range,
        &format!("{name}: the TF's range"),
    );
    assert_eq!(
        floats(&s["scene_times"]),
        times,
        "{name}: the animation's times"
    );
    assert_eq!(
        s["view_time"].as_f64(),
        floats(&s["paraview_times"]).last().copied(),
        "{name}"
    );
}

fn assert_same(a: &Image, b: &Image, what: &str) {
    let p = psnr(a, b);
    assert!(p > 50.0, "{what}: {p:.1} dB");
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn a_series_script_shows_every_step_with_one_tf() {
    require_paraview("a_series_script_shows_every_step_with_one_tf");
    let dir = tempfile::tempdir().unwrap();
    let (data, out) = (dir.path().join("data"), dir.path().join("out"));
    std::fs::create_dir_all(&out).unwrap();
    gray_scott(&data, "float32");
    let times = [200.0, 400.0, 600.0, 800.0];

    // The .pvd (ParaView's own writer, members in a subfolder): one picture per step.
    let pvd = last_step(&data.join("gray_scott.pvd"), None);
    let whole = run(&pvd, &out, "pvd", &[], Some(4));
    check(&whole, &pvd, "pvd", &times);

    // The .series file and the list of files: the same steps, the same pictures. ParaView
    // takes the list's times from the files' TimeValue. A .series file named without the
    // data's extension, which ParaView has no reader for, is opened as its list of files.
    std::fs::copy(
        data.join("gray_scott.vti.series"),
        data.join("plain.series"),
    )
    .unwrap();
    for (name, path) in [
        ("series", data.join("gray_scott.vti.series")),
        ("list", data.join("gray_scott_*.vti")),
        ("plain", data.join("plain.series")),
    ] {
        let v = last_step(&path, None);
        let r = run(&v, &out, name, &[], Some(4));
        check(&r, &v, name, &times);
        assert_eq!(
            r.log.contains("ParaView has no reader for"),
            name == "plain",
            "{name}: {}",
            r.log
        );
        for (i, (a, b)) in r.shots.iter().zip(&whole.shots).enumerate() {
            assert_same(a, b, &format!("{name} against pvd, step {i}"));
        }
    }

    // Steps 0 and 3 of the .pvd: the animation has only their times, and their pictures are
    // the whole series' steps 0 and 3.
    let some = last_step(&data.join("gray_scott.pvd"), Some(vec![0, 3]));
    let r = run(&some, &out, "some", &[], Some(2));
    check(&r, &some, "some", &[200.0, 800.0]);
    assert_same(&r.shots[0], &whole.shots[0], "selection step 0");
    assert_same(&r.shots[1], &whole.shots[3], "selection step 3");

    // --time T: the nearest step only, named as given; the TF still unrescaled.
    let r = run(&pvd, &out, "at", &["--time", "590"], None);
    check(&r, &pvd, "at", &times);
    assert_eq!(floats(&r.state["paraview_times"]), [600.0]);
    assert_same(&r.shots[0], &whole.shots[2], "--time 590");
}

#[test]
#[cfg_attr(not(t2tf_pvpython), ignore = "needs pvpython and xvfb-run")]
fn a_raw_series_script_reads_one_step_per_file() {
    // ParaView 5.11's ImageReader with several FileNames is a time series, one file per step
    // (times 0, 1, ...): the raw uint8 steps show as the .pvd of the same uint8 values does.
    require_paraview("a_raw_series_script_reads_one_step_per_file");
    let dir = tempfile::tempdir().unwrap();
    let (data, out) = (dir.path().join("data"), dir.path().join("out"));
    std::fs::create_dir_all(&out).unwrap();
    gray_scott(&data, "uint8");
    let glob = data.join("raw/gray_scott_*_32x32x32_uint8.raw");

    let raw = last_step(&glob, None);
    assert!(matches!(
        raw.source.as_ref().unwrap().format,
        SourceFormat::Raw { .. }
    ));
    let r = run(&raw, &out, "raw", &[], Some(4));
    check(&r, &raw, "raw", &[0.0, 1.0, 2.0, 3.0]);
    let pvd = last_step(&data.join("gray_scott.pvd"), None);
    assert_eq!(pvd.norm_range, raw.norm_range);
    let vti = run(&pvd, &out, "pvd", &[], Some(4));
    for (i, (a, b)) in r.shots.iter().zip(&vti.shots).enumerate() {
        assert_same(a, b, &format!("raw against pvd, step {i}"));
    }

    // Steps 1 and 3 of the raw files (whose range is the whole series', so the TF is the
    // same): those two files only; --step picks one of them.
    let some = last_step(&glob, Some(vec![1, 3]));
    assert_eq!(some.norm_range, raw.norm_range);
    let s = run(&some, &out, "some", &[], Some(2));
    check(&s, &some, "some", &[0.0, 1.0]);
    assert_same(&s.shots[0], &r.shots[1], "raw selection step 1");
    assert_same(&s.shots[1], &r.shots[3], "raw selection step 3");
    let one = run(&some, &out, "one", &["--step", "1"], None);
    assert_same(&one.shots[0], &r.shots[3], "--step 1");
}
