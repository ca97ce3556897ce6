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

/// The `--list` line of the preset `name` in `file`: its colour and opacity point counts.
fn listed(file: &str, name: &str) -> (usize, usize) {
    let (ok, out) = t2tf(&["convert", "--list", file]);
    assert!(ok, "{out}");
    let line = out
        .lines()
        .find(|l| l.split('\t').next() == Some(name))
        .unwrap_or_else(|| panic!("{name} not listed: {out}"));
    let count = |what: &str| {
        line.split('\t')
            .find_map(|f| f.strip_suffix(what))
            .and_then(|n| n.trim().parse().ok())
            .unwrap_or_else(|| panic!("no {what}: {line}"))
    };
    (count(" colour points"), count(" opacity points"))
}

/// What `convert` reported writing: (colour, opacity) points.
fn reported(out: &str) -> (usize, usize) {
    let tail = out.split(": ").nth(1).unwrap_or_else(|| panic!("{out}"));
    let n: Vec<usize> = tail
        .split(", ")
        .take(2)
        .map(|p| p.split(' ').next().unwrap().parse().unwrap())
        .collect();
    (n[0], n[1])
}

#[test]
fn list_and_convert_count_the_same_points() {
    // ParaView wrote this preset's third opacity point with midpoint 0.3: 4 stored points, 5
    // as read (the midpoint is a point), which `--list` and `convert` both say.
    let file = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/paraview/colorspace_RGB.json")
        .to_string_lossy()
        .into_owned();
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(
        text.contains("0.29999999999999999"),
        "the fixture has its midpoint"
    );
    assert_eq!(listed(&file, "colorspace_RGB"), (6, 5));
    let d = tempfile::tempdir().unwrap();
    for ext in ["json", "xml", "ct"] {
        let out = d
            .path()
            .join(format!("o.{ext}"))
            .to_string_lossy()
            .into_owned();
        let (ok, said) = t2tf(&["convert", &file, &out]);
        assert!(ok, "{said}");
        assert_eq!(reported(&said), (6, 5), "{said}");
    }
    // A written JSON lists as it was reported.
    let out = d.path().join("o.json").to_string_lossy().into_owned();
    assert_eq!(listed(&out, "colorspace_RGB"), (6, 5));
}

#[test]
fn convert_keeps_the_preset_name_unless_given_one() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o.json").to_string_lossy().into_owned();
    // Moved to another range, the preset keeps its name (no hash appended).
    let (ok, said) = t2tf(&["convert", &fixture(), &out, "--rescale", "0,255"]);
    assert!(ok, "{said}");
    let tf = read_tf(Path::new(&out)).unwrap();
    assert_eq!(tf.name, "ParaViewWritten");
    assert_eq!(tf.data_range(), [0.0, 255.0]);
    assert!(said.contains(", ParaViewWritten: "), "{said}");
    // --name names it, in every format that stores a name.
    for ext in ["json", "xml"] {
        let out = d
            .path()
            .join(format!("n.{ext}"))
            .to_string_lossy()
            .into_owned();
        let (ok, said) = t2tf(&["convert", &fixture(), &out, "--name", "bone and skin"]);
        assert!(ok, "{said}");
        let (ok, listed) = t2tf(&["convert", "--list", &out]);
        assert!(ok && listed.starts_with("bone and skin\t"), "{listed}");
    }
    let (ok, said) = t2tf(&["convert", &fixture(), &out, "--name", " "]);
    assert!(!ok && said.contains("--name is empty"), "{said}");
}
