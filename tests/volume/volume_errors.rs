//! Bad input gives one-line errors that name the file and the problem, never a panic.

use std::path::{Path, PathBuf};

use t2tf::volume::{self, ReadOptions, ScalarType, Volume};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/volumes")
        .join(name)
}

/// Load `path` expecting an error; check it is one line, names the file, and mentions `needle`.
fn expect_err(path: &Path, opts: &ReadOptions, needle: &str) -> String {
    let e = match volume::load(path, opts) {
        Ok(_) => panic!("{} loaded but should fail with '{needle}'", path.display()),
        Err(e) => e.to_string(),
    };
    assert!(!e.contains('\n'), "not one line: {e}");
    assert!(
        e.starts_with(&path.display().to_string()),
        "does not name the file: {e}"
    );
    assert!(e.contains(needle), "'{e}' lacks '{needle}'");
    e
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn none() -> ReadOptions {
    ReadOptions::default()
}

fn truncated_copy(dir: &Path, name: &str, keep: usize) -> PathBuf {
    let bytes = std::fs::read(fixture(name)).unwrap();
    write(dir, name, &bytes[..keep.min(bytes.len())])
}

#[test]
fn raw_errors() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "cube_4x4x4_uint16.raw", &[0u8; 100]);
    expect_err(
        &p,
        &none(),
        "file holds 100 bytes but 4x4x4 uint16 needs 128 bytes",
    );
    // A huge file of the wrong size fails from its size alone, before it is read (the sparse
    // 8 GiB file would not fit this test's memory budget if it were read).
    let p = d.path().join("huge_4x4x4_uint8.raw");
    std::fs::File::create(&p).unwrap().set_len(8 << 30).unwrap();
    expect_err(
        &p,
        &none(),
        "file holds 8589934592 bytes but 4x4x4 uint8 needs 64 bytes",
    );
    let p = write(d.path(), "cube_4x4x4_uint9.raw", &[0u8; 64]);
    expect_err(&p, &none(), "unknown scalar type 'uint9'");
    let p = write(d.path(), "cube.raw", &[0u8; 64]);
    expect_err(&p, &none(), "give `dims` (X,Y,Z) and `dtype`");
    let zero = ReadOptions {
        dims: Some([4, 0, 4]),
        dtype: Some(ScalarType::U8),
        ..none()
    };
    expect_err(&p, &zero, "contain a zero");
    let nan: Vec<u8> = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::NAN]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let p = write(d.path(), "bad_2x2x1_float32.raw", &nan);
    expect_err(&p, &none(), "every value is NaN or infinite");
    let arr = ReadOptions {
        array: Some("x".into()),
        ..none()
    };
    expect_err(
        &fixture("ramp_7x6x5_uint16.raw"),
        &arr,
        "`array` applies to .vti",
    );
}

#[test]
fn path_errors() {
    let d = tempfile::tempdir().unwrap();
    expect_err(d.path(), &none(), "is a directory");
    expect_err(
        &d.path().join("missing_4x4x4_uint8.raw"),
        &none(),
        "no such file",
    );
    let p = write(d.path(), "volume.nrrd", b"NRRD0004\n");
    expect_err(&p, &none(), "unknown extension '.nrrd'");
    let p = write(d.path(), "volume", b"");
    expect_err(&p, &none(), "no file extension");
    let dims = ReadOptions {
        dims: Some([5, 4, 3]),
        ..none()
    };
    expect_err(
        &fixture("ascii_float32.vti"),
        &dims,
        "`dims` applies to .raw",
    );
}

#[test]
fn vti_errors() {
    let d = tempfile::tempdir().unwrap();
    // Appended raw data cut short; compressed blocks cut short; inline base64 cut short.
    let p = truncated_copy(d.path(), "appended_raw_uint16.vti", 1000);
    expect_err(&p, &none(), "truncated");
    let p = truncated_copy(d.path(), "appended_raw_float64_zlib.vti", 1400);
    expect_err(&p, &none(), "truncated");
    let p = truncated_copy(d.path(), "binary_uint8.vti", 400);
    expect_err(&p, &none(), "array 'values'");

    let head = r#"<?xml version="1.0"?><VTKFile type="ImageData" version="1.0">
        <ImageData WholeExtent="0 1 0 1 0 1" Origin="0 0 0" Spacing="1 1 1">
        <Piece Extent="0 1 0 1 0 1"><PointData>"#;
    let tail = "</PointData></Piece></ImageData></VTKFile>";
    let doc = |body: &str| format!("{head}{body}{tail}");
    let ok = r#"<DataArray type="Float32" Name="a" format="ascii">1 2 3 4 5 6 7 8</DataArray>"#;
    assert!(volume::load(&write(d.path(), "ok.vti", doc(ok).as_bytes()), &none()).is_ok());

    let p = write(
        d.path(),
        "bad.vti",
        doc(&ok.replace("</DataArray>", "</Data>")).as_bytes(),
    );
    expect_err(&p, &none(), "malformed XML");
    let p = write(d.path(), "few.vti", doc(&ok.replace(" 8<", "<")).as_bytes());
    expect_err(&p, &none(), "holds 7 values but the extent needs 8");
    let p = write(
        d.path(),
        "nan.vti",
        doc(&ok.replace("1 2", "x 2")).as_bytes(),
    );
    expect_err(&p, &none(), "'x' is not a number");
    let p = write(
        d.path(),
        "type.vti",
        doc(&ok.replace("Float32", "String")).as_bytes(),
    );
    expect_err(&p, &none(), "type 'String'");
    let p = write(d.path(), "empty.vti", doc("").as_bytes());
    expect_err(&p, &none(), "no point-data arrays");
    let zero = doc(ok).replace("0 1 0 1 0 1", "0 1 0 -1 0 1");
    let p = write(d.path(), "zero.vti", zero.as_bytes());
    expect_err(&p, &none(), "zero dimensions");
    let nan = ok.replace("1 2 3 4 5 6 7 8", "nan inf -inf nan nan nan nan nan");
    let p = write(d.path(), "allnan.vti", doc(&nan).as_bytes());
    expect_err(&p, &none(), "every value is NaN");
    let poly = doc(ok).replace("ImageData", "PolyData");
    let p = write(d.path(), "poly.vti", poly.as_bytes());
    expect_err(&p, &none(), "'PolyData' file, not ImageData");
    let rotated = doc(ok).replace(
        "Spacing=\"1 1 1\"",
        "Spacing=\"1 1 1\" Direction=\"0 1 0 -1 0 0 0 0 1\"",
    );
    let p = write(d.path(), "rotated.vti", rotated.as_bytes());
    expect_err(&p, &none(), "is not the identity");
    let second = "</PointData></Piece><Piece Extent=\"0 1 0 1 1 2\"><PointData>";
    let tiled = doc(&format!("{ok}{second}{ok}"));
    let p = write(d.path(), "tiled.vti", tiled.as_bytes());
    expect_err(&p, &none(), "has 2 pieces with different extents");
    let p = write(d.path(), "garbage.vti", &[0xff, 0xfe, 0, 1, 2, 3]);
    expect_err(&p, &none(), "garbage.vti");
    let p = write(d.path(), "empty_file.vti", b"");
    expect_err(&p, &none(), "no <VTKFile>");

    let arrays = fixture("arrays.vti");
    let pick = |n: &str| ReadOptions {
        array: Some(n.into()),
        ..none()
    };
    expect_err(
        &arrays,
        &pick("nope"),
        "no point-data array named 'nope' (point-data arrays: temperature, density, velocity, last)",
    );
    expect_err(&arrays, &pick("cell_id"), "is cell data");
    expect_err(&arrays, &pick("velocity"), "has 3 components");
}

#[test]
fn legacy_errors() {
    let d = tempfile::tempdir().unwrap();
    let p = truncated_copy(d.path(), "legacy_binary_int16.vtk", 400);
    expect_err(&p, &none(), "truncated");
    let p = truncated_copy(d.path(), "legacy_ascii_float32.vtk", 600);
    expect_err(&p, &none(), "truncated");
    let good = std::fs::read_to_string(fixture("legacy_ascii_two.vtk")).unwrap();
    let p = write(
        d.path(),
        "poly.vtk",
        good.replace("STRUCTURED_POINTS", "POLYDATA").as_bytes(),
    );
    expect_err(&p, &none(), "DATASET POLYDATA is not supported");
    let p = write(
        d.path(),
        "zero.vtk",
        good.replace("DIMENSIONS 5 4 3", "DIMENSIONS 5 0 3")
            .as_bytes(),
    );
    expect_err(&p, &none(), "'DIMENSIONS 5 0 3' contains a zero");
    let p = write(
        d.path(),
        "type.vtk",
        good.replace("values short", "values quad").as_bytes(),
    );
    expect_err(&p, &none(), "type 'quad'");
    let p = write(
        d.path(),
        "count.vtk",
        good.replace("POINT_DATA 60", "POINT_DATA 61").as_bytes(),
    );
    expect_err(
        &p,
        &none(),
        "POINT_DATA 61 does not match DIMENSIONS 5x4x3 (60 points)",
    );
    let p = write(d.path(), "junk.vtk", b"hello\n");
    expect_err(&p, &none(), "not a legacy VTK file");
    let pick = ReadOptions {
        array: Some("nope".into()),
        ..none()
    };
    expect_err(
        &fixture("legacy_ascii_two.vtk"),
        &pick,
        "(point-data arrays: values, other)",
    );
    for mode in ["ascii", "binary"] {
        let f = fixture(&format!("legacy_sections_{mode}.vtk"));
        let pick = |n: &str| ReadOptions {
            array: Some(n.into()),
            ..none()
        };
        expect_err(
            &f,
            &pick("cell_scalars"),
            "array 'cell_scalars' is cell data",
        );
        expect_err(&f, &pick("pair"), "array 'pair': has 2 components");
    }
}

/// Every prefix of every fixture, and every fixture with any one byte changed, loads or fails
/// cleanly: no panic, and any error is one line naming the file.
#[test]
fn cut_or_corrupted_fixtures_never_panic() {
    let d = tempfile::tempdir().unwrap();
    let manifest = std::fs::read_to_string(fixture("manifest.json")).unwrap();
    let entries: Vec<serde_json::Value> = serde_json::from_str(&manifest).unwrap();
    for e in &entries {
        let name = e["file"].as_str().unwrap();
        if name.ends_with(".bin") {
            continue; // needs flags; raw sizes are covered above
        }
        let bytes = std::fs::read(fixture(name)).unwrap();
        let p = d.path().join(name);
        let check = |data: &[u8]| {
            // In memory (the file system would dominate the run time); same code path as
            // `load` after the file is read.
            let r = volume::decode_bytes(&p, data.to_vec(), &none())
                .and_then(|x| Volume::from_buffer(&p, x.geometry, &x.buffer));
            if let Err(err) = r {
                let s = err.to_string();
                assert!(
                    !s.contains('\n') && s.starts_with(&p.display().to_string()),
                    "{s}"
                );
            }
        };
        for cut in 0..bytes.len() {
            check(&bytes[..cut]);
        }
        // Shift any byte (breaks text, headers, compressed streams), or turn one of the text
        // part's bytes into a '9' (bigger counts, extents and offsets).
        for at in 0..bytes.len() {
            let mut b = bytes.clone();
            b[at] = bytes[at].wrapping_add(0x5b);
            check(&b);
            if at < 1024 {
                b[at] = b'9';
                check(&b);
            }
        }
    }
}
