//! `t2tf convert` end to end through the binary.

use std::path::Path;
use std::process::Command;

use t2tf::formats::read_tf;

fn t2tf(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(args)
        .output()
        .expect("run t2tf");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

fn fixture() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/paraview/paraview_written_preset.json")
        .to_string_lossy()
        .into_owned()
}

#[test]
fn converts_between_all_formats_and_rescales() {
    let d = tempfile::tempdir().unwrap();
    let p = |n: &str| d.path().join(n).to_string_lossy().into_owned();
    let original = read_tf(Path::new(&fixture())).unwrap();

    let (ok, out) = t2tf(&["convert", &fixture(), &p("a.xml")]);
    assert!(ok, "{out}");
    assert!(out.contains("3 colour points, 3 opacity points"), "{out}");
    let (ok, out) = t2tf(&["convert", &p("a.xml"), &p("b.json")]);
    assert!(ok, "{out}");
    let back = read_tf(Path::new(&p("b.json"))).unwrap();
    assert_eq!(back, original, "json → xml → json is exact");

    let (ok, out) = t2tf(&["convert", &fixture(), &p("c.ct"), "--rescale", "-100,100"]);
    assert!(ok, "{out}");
    let ct = read_tf(Path::new(&p("c.ct"))).unwrap();
    assert_eq!(ct.data_range(), [-100.0, 100.0]);
    // 10.0 sat at (10 + 2.5) / 42.75 of the old range.
    let x = -100.0 + 200.0 * 12.5 / 42.75;
    assert!(
        ct.rgb_points.iter().any(|&(px, _)| (px - x).abs() < 1e-4),
        "{:?}",
        ct.rgb_points
    );
}

#[test]
fn bad_input_fails_with_a_clear_message() {
    let d = tempfile::tempdir().unwrap();
    let out_json = d.path().join("o.json").to_string_lossy().into_owned();
    let (ok, out) = t2tf(&["convert", "/nonexistent/in.json", &out_json]);
    assert!(!ok && out.contains("/nonexistent/in.json"), "{out}");
    let (ok, out) = t2tf(&["convert", &fixture(), "out.png"]);
    assert!(
        !ok && out.contains("out.png") && out.contains("expected .json, .xml or .ct"),
        "{out}"
    );
    let (ok, out) = t2tf(&["convert", &fixture(), &out_json, "--rescale", "5,1"]);
    assert!(!ok && out.contains("must be below"), "{out}");
    assert!(!Path::new(&out_json).exists());
    let (ok, out) = t2tf(&["convert", "--help"]);
    assert!(
        ok && out.contains("Examples:") && out.contains("--rescale"),
        "{out}"
    );
}
