//! Bad TF files give one-line errors that name the file and the problem, never a panic.

use std::path::Path;

use t2tf::formats::{load_tf, read_tf};
use t2tf::volume::{Geometry, TypedBuffer, Volume};

/// Write `text` to `name` in a temp dir and return the error of reading it.
fn error_of(name: &str, text: &str) -> String {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join(name);
    std::fs::write(&p, text).unwrap();
    let e = read_tf(&p).expect_err(text).to_string();
    assert!(
        e.starts_with(&p.display().to_string()),
        "error does not name the file: {e}"
    );
    assert!(!e.contains('\n'), "not one line: {e}");
    e
}

fn expect(name: &str, text: &str, needle: &str) {
    let e = error_of(name, text);
    assert!(e.contains(needle), "{name}: expected \"{needle}\" in: {e}");
}

#[test]
fn bad_json_presets() {
    expect("a.json", "{not json", "is not valid JSON");
    expect("a.json", "42", "expected an array of objects");
    expect(
        "a.json",
        "[{\"Name\":\"x\"}]",
        "no preset with \"RGBPoints\"",
    );
    expect("a.json", "[{\"RGBPoints\":[0,0,0]}]", "has 3 numbers");
    expect(
        "a.json",
        "[{\"RGBPoints\":[0,0,0,\"red\"]}]",
        "\"RGBPoints\"[3] is not a number",
    );
    expect(
        "a.json",
        "[{\"RGBPoints\":[1,0,0,0, 0,1,1,1]}]",
        "below the previous point",
    );
    expect("a.json", "[{\"RGBPoints\":[0,0,0,2]}]", "is not in [0, 1]");
    expect(
        "a.json",
        "[{\"RGBPoints\":[0,0,0,0],\"Points\":[0,1.5,0.5,0]}]",
        "opacity 1.5 is not in [0, 1]",
    );
    expect(
        "a.json",
        "[{\"RGBPoints\":[0,0,0,0],\"Points\":[0,1,0.5,0.3]}]",
        "sharpness 0.3 is not supported",
    );
    expect(
        "a.json",
        "[{\"ColorSpace\":\"XYZ\",\"RGBPoints\":[0,0,0,0]}]",
        "colour space",
    );
}

#[test]
fn bad_xml_and_ct() {
    expect(
        "a.xml",
        "<ColorMaps><ColorMap name='x'><Point x='0' r='1' g='0'/>",
        "has no \"b\"",
    );
    expect(
        "a.xml",
        "<ColorMaps><ColorMap name='x'><Point x='z' r='1' g='0' b='0'/>",
        "not a finite number",
    );
    expect("a.xml", "<ColorMaps></ColorMaps>", "has no <ColorMap>");
    expect(
        "a.xml",
        "<ColorMaps><ColorMap name='x'></ColorMap></ColorMaps>",
        "no <Point>",
    );
    expect(
        "a.xml",
        "<ColorMaps><ColorMap name='x' <",
        "is not valid XML",
    );
    expect(
        "a.ct",
        "<Object name=\"Other\"/>",
        "is not a VisIt colour table",
    );
    expect(
        "a.ct",
        "<Object name=\"ColorTable\"><Object name=\"ColorControlPointList\"><Object name=\"ColorControlPoint\">\
         <Field name=\"colors\" type=\"unsignedCharArray\" length=\"4\">1 2 300 4</Field>\
         <Field name=\"position\" type=\"float\">0</Field></Object></Object></Object>",
        "are not 3 or 4 values in 0..255",
    );
    expect(
        "a.ct",
        "<Object name=\"ColorTable\"><Object name=\"ColorControlPointList\"><Object name=\"ColorControlPoint\">\
         <Field name=\"position\" type=\"float\">0</Field></Object></Object></Object>",
        "control point 0 has no colors",
    );
}

#[test]
fn unreadable_paths() {
    let d = tempfile::tempdir().unwrap();
    let e = read_tf(&d.path().join("missing.json"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.json"), "{e}");
    let dir = d.path().join("dir.json");
    std::fs::create_dir(&dir).unwrap();
    let e = read_tf(&dir).unwrap_err().to_string();
    assert!(e.contains("is a directory"), "{e}");
    expect("a.txt", "", "unknown transfer-function format");
    let bin = d.path().join("b.json");
    std::fs::write(&bin, [0xff, 0xfe, 0x00]).unwrap();
    assert!(read_tf(&bin).unwrap_err().to_string().contains("not UTF-8"));
}

#[test]
fn colour_only_file_cannot_be_rendered() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("c.json");
    std::fs::write(&p, "[{\"RGBPoints\":[0,0,0,0, 1,1,1,1]}]").unwrap();
    let g = Geometry {
        dims: [2, 2, 2],
        spacing: [1.0; 3],
        origin: [0.0; 3],
    };
    let v = Volume::from_buffer(
        Path::new("v"),
        g,
        &TypedBuffer::from_f64(vec![0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0]),
    )
    .unwrap();
    let e = format!("{:#}", load_tf(&p, &v, None).unwrap_err());
    assert!(e.contains("has no opacity points"), "{e}");
    std::fs::write(
        &p,
        "[{\"RGBPoints\":[0,0,0,0, 1,1,1,1],\"Points\":[0,0,0.5,0, 1,1,0.5,0]}]",
    )
    .unwrap();
    let e = format!("{:#}", load_tf(&p, &v, Some(-1.0)).unwrap_err());
    assert!(
        e.contains("c.json") && e.contains("unit distance -1 is not positive"),
        "{e}"
    );
}
