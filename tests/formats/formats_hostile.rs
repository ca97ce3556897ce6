//! Presets that would write files no parser reads or that hold non-finite numbers: names with
//! control characters or markup are written as XML 1.0 allows, a range wider than a double
//! measures is refused before anything is written, and a NUL in a `.vti` header is refused.

use std::path::Path;

use t2tf::formats::{read_preset, write_preset, Preset};
use t2tf::volume::{decode_bytes, ReadOptions};

fn preset(dir: &Path, name: &str, lo: f64, hi: f64) -> Preset {
    let p = dir.join("in.json");
    let json = serde_json::json!([{
        "Name": name,
        "ColorSpace": "RGB",
        "RGBPoints": [lo, 1, 0, 0, hi, 0, 0, 1],
        "Points": [lo, 0, 0.5, 0, hi, 1, 0.5, 0],
    }]);
    std::fs::write(&p, json.to_string()).unwrap();
    read_preset(&p, None).unwrap()
}

#[test]
fn names_with_control_characters_and_markup_round_trip_through_xml() {
    let dir = tempfile::tempdir().unwrap();
    let name = "bone\u{1}\u{7} </ColorMap> & \"skin\"\ttab";
    let p = preset(dir.path(), name, 0.0, 100.0);
    let xml = dir.path().join("out.xml");
    write_preset(&xml, &p).unwrap();
    let text = std::fs::read_to_string(&xml).unwrap();
    assert!(
        !text.chars().any(|c| c == '\u{1}' || c == '\u{7}'),
        "{text}"
    );
    // Any XML parser reads it back, and the name keeps everything XML can hold (an attribute's
    // tab reads back as a space: XML's attribute-value normalization).
    let back = read_preset(&xml, None).unwrap();
    assert_eq!(back.tf.name, "bone </ColorMap> & \"skin\" tab");
    assert_eq!(back.tf.rgb_points.len(), 2);
}

#[test]
fn ranges_no_double_measures_are_refused_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let p = preset(dir.path(), "wide", -1e308, 1e308);
    for ext in ["ct", "json", "xml"] {
        let out = dir.path().join(format!("out.{ext}"));
        let e = write_preset(&out, &p).unwrap_err().to_string();
        assert!(e.contains("wider than a double"), "{ext}: {e}");
        assert!(!out.exists(), "{ext}: a refused file was written");
    }
    // Wide but measurable: written, and every number in the file is finite.
    let p = preset(dir.path(), "wide", -1e307, 1e307);
    let out = dir.path().join("ok.ct");
    write_preset(&out, &p).unwrap();
    let text = std::fs::read_to_string(&out).unwrap().to_lowercase();
    assert!(!text.contains("nan") && !text.contains("inf"), "{text}");
}

#[test]
fn a_nul_in_a_vti_header_is_refused() {
    let vti = "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" \
        byte_order=\"LittleEndian\">\n<ImageData WholeExtent=\"0 1 0 0 0 0\" Origin=\"0 0 0\" \
        Spacing=\"1 1 1\">\n<Piece Extent=\"0 1 0 0 0 0\"><PointData Scalars=\"v\">\n<DataArray \
        type=\"UInt8\" Name=\"v\" format=\"ascii\">0 1</DataArray>\n</PointData></Piece>\
        </ImageData></VTKFile>";
    let ok = decode_bytes(
        Path::new("a.vti"),
        vti.as_bytes().to_vec(),
        &ReadOptions::default(),
    );
    assert!(ok.is_ok(), "{:?}", ok.err());
    let with_nul = vti.replacen("Name=\"v\"", "Name=\"v\0\"", 1);
    let e = decode_bytes(
        Path::new("a.vti"),
        with_nul.into_bytes(),
        &ReadOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("NUL"), "{e}");
}
