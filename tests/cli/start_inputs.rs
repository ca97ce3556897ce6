//! What a run starts from, checked before any work: transfer-function files past the size cap
//! (`--max-preset-size`, 64 MiB by default) are refused before they are read, by every command
//! that reads one; an `optimize --init` preset of more points than a run has control points is
//! simplified, or refused before the model loads; a `--lock` too narrow for the data range is
//! refused before the model loads, its numbers as given. Every file is made by the test.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const VOLUME: &str = "tests/fixtures/volumes/ramp_7x6x5_uint16.raw";

fn t2tf(args: &[&str], extra: &[&Path]) -> (i32, String) {
    let out: Output = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .args(extra)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    (out.status.code().unwrap_or(-1), err)
}

/// A sparse 3 GiB file named `big.json`: nothing on disk, so reading it would cost 3 GiB of
/// memory and seconds; refusing it costs neither.
fn sparse_preset(dir: &Path) -> PathBuf {
    let p = dir.join("big.json");
    std::fs::File::create(&p).unwrap().set_len(3 << 30).unwrap();
    p
}

/// A JSON preset over the ramp's range 0..65535 with `n` colour and `n` opacity points, the
/// opacity alternating 0, 1 (every point is needed) or, with `smooth`, a sine (few are).
fn many_points(dir: &Path, n: usize, smooth: bool) -> PathBuf {
    let x = |i: usize| 65535.0 * i as f64 / (n - 1) as f64;
    let o = |i: usize| {
        if smooth {
            0.5 + 0.5 * (6.0 * i as f64 / n as f64).sin()
        } else {
            (i % 2) as f64
        }
    };
    let rgb: Vec<f64> = (0..n).flat_map(|i| [x(i), 0.2, 0.5, 0.8]).collect();
    let points: Vec<f64> = (0..n).flat_map(|i| [x(i), o(i), 0.5, 0.0]).collect();
    let p = dir.join(format!("many_{n}_{smooth}.json"));
    let json = serde_json::json!([{
        "Name": "many", "ColorSpace": "RGB", "RGBPoints": rgb, "Points": points,
    }]);
    std::fs::write(&p, json.to_string()).unwrap();
    p
}

/// `optimize --init init` into `out` with a model that does not exist: what is said before
/// the model would load.
fn optimize_from(init: &Path, out: &Path) -> (i32, String) {
    let args = [
        "optimize",
        VOLUME,
        "--prompt",
        "x",
        "--model",
        "no/such/model",
        "--out",
    ];
    t2tf(&args, &[out, Path::new("--init"), init])
}

fn one_line_naming(err: &str, needles: &[&str]) {
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} missing from: {err}");
    }
}

#[test]
fn a_preset_file_over_the_cap_is_refused_before_it_is_read_by_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let big = sparse_preset(dir.path());
    let out = dir.path().join("out");
    let said = [
        "big.json: is 3.0 GiB, more than the 64.0 MiB a transfer-function file may be",
        "--max-preset-size SIZE",
    ];
    let (code, err) = t2tf(&["convert"], &[&big, &out.with_extension("xml")]);
    assert_eq!(code, 1, "{err}");
    one_line_naming(&err, &said);
    let (code, err) = t2tf(&["convert", "--list"], &[&big]);
    assert_eq!(code, 1, "{err}");
    one_line_naming(&err, &said);
    let (code, err) = t2tf(
        &["render", VOLUME, "--size", "8", "--out"],
        &[&out.with_extension("png"), Path::new("--tf"), &big],
    );
    assert_eq!(code, 1, "{err}");
    one_line_naming(&err, &said);
    // Before the model: the model named here does not exist.
    let (code, err) = optimize_from(&big, &out);
    assert_eq!(code, 1, "{err}");
    one_line_naming(&err, &said);
    assert!(!err.contains("no/such/model"), "{err}");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "only big.json"
    );
}

#[test]
fn the_cap_is_set_by_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let tf = many_points(dir.path(), 20, true);
    let size = std::fs::metadata(&tf).unwrap().len();
    assert!(size > 1000, "{size}");
    let out = dir.path().join("out.xml");
    let (code, err) = t2tf(&["convert", "--max-preset-size", "1000"], &[&tf, &out]);
    assert_eq!(code, 1, "{err}");
    one_line_naming(
        &err,
        &[
            "more than the 1000 B a transfer-function file may be",
            "--max-preset-size",
        ],
    );
    assert!(!out.exists());
    let (code, err) = t2tf(&["convert", "--max-preset-size", "1M"], &[&tf, &out]);
    assert_eq!(code, 0, "{err}");
    assert!(out.exists());
    let (code, err) = t2tf(&["convert", "--max-preset-size", "lots"], &[&tf, &out]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("\"lots\" is not a size"), "{err}");
}

#[test]
fn an_init_preset_of_more_points_than_a_run_has_is_refused_before_the_model_loads() {
    let dir = tempfile::tempdir().unwrap();
    let tf = many_points(dir.path(), 5000, false);
    let out = dir.path().join("out");
    let (code, err) = optimize_from(&tf, &out);
    assert_eq!(code, 1, "{err}");
    one_line_naming(
        &err,
        &[
            "many_5000_false.json: preset \"many\" has 10000 colour and opacity points",
            "a start takes at most 4096",
        ],
    );
    assert!(!err.contains("no/such/model"), "{err}");
    assert!(!out.exists());
}

/// A preset of more points than a run takes, whose curves are smooth, starts from its
/// simplification: at most the limit, every curve within the export tolerance of the file's.
#[test]
fn a_smooth_preset_of_many_points_is_simplified_within_the_export_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let path = many_points(dir.path(), 20_000, true);
    let full = t2tf::formats::read_preset(&path, None).unwrap();
    let init = t2tf::pipeline::InitTf::read(&path, None, 1 << 30).unwrap();
    let (tf, all) = (&init.preset.tf, &full.tf);
    let points = tf.rgb_points.len() + tf.opacity_points.len();
    assert!(points < 1000, "{points} points, from 40000");
    let o: Vec<(f64, [f64; 1])> = tf.opacity_points.iter().map(|&(x, o)| (x, [o])).collect();
    for &(x, want) in &all.opacity_points {
        let e = (t2tf::tf::interpolate(&o, x)[0] - want).abs();
        assert!(e <= t2tf::tf::EXPORT_TOLERANCE, "opacity off by {e} at {x}");
    }
    for &(x, want) in &all.rgb_points {
        let got = t2tf::tf::interpolate(&tf.rgb_points, x);
        for c in 0..3 {
            assert!(
                (got[c] - want[c]).abs() <= t2tf::tf::EXPORT_TOLERANCE,
                "colour at {x}"
            );
        }
    }
}

#[test]
fn a_lock_narrower_than_the_data_range_resolves_is_refused_before_the_model_loads() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let lock = |volume: &str, range: &str| {
        t2tf(
            &[
                "optimize", volume, "--prompt", "x", "--model", "no/such", "--lock", range, "--out",
            ],
            &[&out],
        )
    };
    // The nucleon's range is 0..249: 5e-324 is a double above 0, yet 5e-324 / 249 is 0, so
    // the lock has no width in the run's normalized values.
    let nucleon = "../shared/data/volumes/nucleon_41x41x41_uint8.raw";
    let (code, err) = lock(nucleon, "0,5e-324");
    assert_eq!(code, 1, "{err}");
    one_line_naming(
        &err,
        &["locked range 0,5e-324 is narrower than the data range 0..249 resolves"],
    );
    // Numbers as they were given, not with 323 zeros.
    let (code, err) = lock(VOLUME, "0,5e-324");
    assert_eq!(code, 1, "{err}");
    one_line_naming(
        &err,
        &["locked range 0,5e-324 is outside the data range 7..45607"],
    );
    assert!(!out.exists());
}
