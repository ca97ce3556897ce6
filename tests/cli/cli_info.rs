//! `t2tf info` through the binary: output on good files, exit code and one-line errors on bad.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn t2tf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .output()
        .expect("run t2tf")
}

fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/volumes")
        .join(name)
        .display()
        .to_string()
}

fn stdout(o: &Output) -> String {
    assert!(
        o.status.success(),
        "t2tf failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout.clone()).unwrap()
}

/// A failing run: non-zero exit, stderr exactly one line naming `file` and containing `needle`.
fn fails(args: &[&str], file: &str, needle: &str) {
    let o = t2tf(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{args:?} succeeded");
    assert_ne!(o.status.code(), Some(101), "panicked: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    assert!(err.contains(file), "does not name {file}: {err}");
    assert!(err.contains(needle), "lacks '{needle}': {err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn prints_geometry_range_and_histogram() {
    let out = stdout(&t2tf(&[
        "info",
        &fixture("ascii_float32.vti"),
        "--bins",
        "8",
    ]));
    assert!(out.contains("dims        7 x 6 x 5 (210 points)"), "{out}");
    assert!(out.contains("spacing     0.5 0.25 2"), "{out}");
    assert!(out.contains("origin      0 2 5.5"), "{out}");
    assert!(out.contains("dtype       float32"), "{out}");
    assert!(out.contains("range       -30.5 .. 83.5"), "{out}");
    assert!(out.contains("non-finite  0"), "{out}");
    assert!(out.contains("array 'values'"), "{out}");
    // Eight histogram rows whose counts add up to every voxel.
    let counts: Vec<u64> = out
        .lines()
        .filter(|l| l.contains(" .. ") && l.contains('|'))
        .map(|l| l.rsplit('|').next().unwrap().trim().parse().unwrap())
        .collect();
    assert_eq!(counts.len(), 8);
    assert_eq!(counts.iter().sum::<u64>(), 210);
}

#[test]
fn json_output_and_raw_flags() {
    let bin = fixture("unnamed.bin");
    let out = stdout(&t2tf(&[
        "info",
        &bin,
        "--dims",
        "5,4,3",
        "--dtype",
        "int16",
        "--spacing",
        "0.5,0.25,2",
        "--json",
    ]));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["dims"], serde_json::json!([5, 4, 3]));
    assert_eq!(v["spacing"], serde_json::json!([0.5, 0.25, 2.0]));
    assert_eq!(v["dtype"], "int16");
    assert_eq!(v["format"], "raw");
    assert_eq!(v["byte_order"], "little");
    assert_eq!(v["range"], serde_json::json!([-602.0, 100.0]));
    assert_eq!(v["memory"]["value_bytes"], 120);
    assert_eq!(v["memory"]["file_bytes"], 120);
    let total: u64 = v["histogram"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["count"].as_u64().unwrap())
        .sum();
    assert_eq!(total, 60);

    let be = fixture("ramp_be_5x4x3_float32.raw");
    let out = stdout(&t2tf(&["info", &be, "--byte-order", "big", "--json"]));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["range"], serde_json::json!([-30.5, 28.0]));
    assert_eq!(v["byte_order"], "big");

    let arrays = fixture("arrays.vti");
    let out = stdout(&t2tf(&[
        "info",
        &arrays,
        "--array",
        "temperature",
        "--json",
    ]));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["array"], "temperature");
    assert_eq!(v["dtype"], "int16");
}

#[test]
fn help_has_an_example() {
    let out = stdout(&t2tf(&["info", "--help"]));
    assert!(out.contains("Example:"), "{out}");
    assert!(out.contains("--dims") && out.contains("--byte-order") && out.contains("--array"));
}

#[test]
fn bad_input_is_one_line_naming_the_file() {
    let d = tempfile::tempdir().unwrap();
    let put = |name: &str, bytes: &[u8]| -> String {
        let p: PathBuf = d.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p.display().to_string()
    };
    let short = put("short_4x4x4_uint16.raw", &[0; 100]);
    fails(&["info", &short], &short, "needs 128 bytes");
    let dtype = put("t_4x4x4_float16.raw", &[0; 128]);
    fails(&["info", &dtype], &dtype, "unknown scalar type 'float16'");
    let xml = put(
        "bad.vti",
        b"<VTKFile type=\"ImageData\"><ImageData></Piece></VTKFile>",
    );
    fails(&["info", &xml], &xml, "malformed XML");
    let nan = put(
        "nan_2x1x1_float64.raw",
        &[f64::NAN.to_le_bytes(), f64::INFINITY.to_le_bytes()].concat(),
    );
    fails(&["info", &nan], &nan, "NaN");
    let dir = d.path().display().to_string();
    fails(&["info", &dir], &dir, "is a directory");
    let missing = d.path().join("nope.vti").display().to_string();
    fails(&["info", &missing], &missing, "no such file");
    let arrays = fixture("arrays.vti");
    fails(
        &["info", &arrays, "--array", "nope"],
        &arrays,
        "no point-data array named 'nope'",
    );
    // An OS error (a file used as a directory): printed once, on the same line.
    // Windows says the path is not found.
    let os_word = if cfg!(windows) {
        "no such file"
    } else {
        "Not a directory"
    };
    let under_file = format!("{}/x_2x2x2_uint8.raw", fixture("unnamed.bin"));
    fails(&["info", &under_file], &under_file, os_word);
    let o = t2tf(&["info", &under_file]);
    assert_eq!(
        String::from_utf8_lossy(&o.stderr).matches(os_word).count(),
        1
    );
    let vti = std::fs::read(fixture("appended_raw_float64_zlib.vti")).unwrap();
    let cut = put("cut.vti", &vti[..vti.len() - 200]);
    fails(&["info", &cut], &cut, "truncated");
    let legacy = std::fs::read_to_string(fixture("legacy_ascii_two.vtk")).unwrap();
    let zero = put(
        "zero.vtk",
        legacy
            .replace("DIMENSIONS 5 4 3", "DIMENSIONS 5 4 0")
            .as_bytes(),
    );
    fails(&["info", &zero], &zero, "contains a zero");
    let raw = fixture("ramp_7x6x5_uint16.raw");
    fails(
        &["info", &raw, "--array", "a"],
        &raw,
        "--array applies to .vti",
    );
    let ext = put("v.mhd", b"ObjectType = Image\n");
    fails(&["info", &ext], &ext, "unknown extension");
    let bin = fixture("unnamed.bin");
    fails(
        &["info", &bin, "--dims", "5,4,3", "--dtype", "int32"],
        &bin,
        "needs 240 bytes",
    );

    // Flag syntax errors come from clap: non-zero exit, naming the flag value.
    let o = t2tf(&["info", &bin, "--dims", "5,4", "--dtype", "int16"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("three"));
}

/// `t2tf info` works on every real volume shipped beside the repository.
#[test]
fn info_on_every_shared_volume() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/volumes");
    let mut seen = 0;
    for entry in std::fs::read_dir(dir).expect("../shared/data/volumes exists") {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("raw") {
            continue;
        }
        let p = path.display().to_string();
        let v: serde_json::Value = serde_json::from_str(&stdout(&t2tf(&["info", &p, "--json"])))
            .unwrap_or_else(|e| panic!("{p}: {e}"));
        // NAME_XxYxZ_DTYPE.raw: the reported dims and type are the name's.
        let stem = path.file_stem().unwrap().to_str().unwrap();
        let mut parts = stem.rsplitn(3, '_');
        let (dtype, dims) = (parts.next().unwrap(), parts.next().unwrap());
        let dims: Vec<u64> = dims.split('x').map(|d| d.parse().unwrap()).collect();
        assert_eq!(v["dims"], serde_json::json!(dims), "{p}");
        assert_eq!(v["dtype"], dtype, "{p}");
        assert_eq!(v["non_finite"], 0, "{p}");
        assert!(v["range"][1].as_f64() > v["range"][0].as_f64(), "{p}");
        seen += 1;
    }
    assert!(seen >= 7, "only {seen} volumes");
}
