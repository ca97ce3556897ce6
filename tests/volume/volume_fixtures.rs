//! Every fixture VTK wrote (tests/fixtures/volumes/manifest.json, from make_fixtures.py) reads
//! back with the right dims, spacing, origin, scalar type, array and every single voxel value.

use std::path::{Path, PathBuf};

use serde_json::Value;
use t2tf::volume::{self, ByteOrder, ReadOptions, ScalarType, SourceFormat};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/volumes")
}

fn triple<T: Copy>(v: &Value, f: impl Fn(&Value) -> Option<T>) -> [T; 3] {
    let a = v.as_array().expect("array of 3");
    [0, 1, 2].map(|i| f(&a[i]).expect("number"))
}

fn options(entry: &Value) -> ReadOptions {
    let o = &entry["options"];
    ReadOptions {
        dims: o
            .get("dims")
            .map(|d| triple(d, |x| x.as_u64().map(|u| u as usize))),
        dtype: o.get("dtype").map(|t| t.as_str().unwrap().parse().unwrap()),
        spacing: o.get("spacing").map(|s| triple(s, Value::as_f64)),
        byte_order: o
            .get("byte_order")
            .map(|b| b.as_str().unwrap().parse::<ByteOrder>().unwrap()),
        array: entry["read_array"].as_str().map(str::to_string),
        ..Default::default()
    }
}

#[test]
fn every_fixture_matches_its_formula_voxel_by_voxel() {
    let text = std::fs::read_to_string(fixtures().join("manifest.json")).unwrap();
    let manifest: Vec<Value> = serde_json::from_str(&text).unwrap();
    assert!(manifest.len() >= 30, "manifest lost entries");
    for entry in &manifest {
        let file = entry["file"].as_str().unwrap();
        let path = fixtures().join(file);
        let opts = options(entry);
        let d = volume::decode(&path, &opts).unwrap_or_else(|e| panic!("{file}: {e}"));
        let dims = triple(&entry["dims"], |x| x.as_u64().map(|u| u as usize));
        let spacing = triple(&entry["spacing"], Value::as_f64);
        let origin = triple(&entry["origin"], Value::as_f64);
        let dtype: ScalarType = entry["dtype"].as_str().unwrap().parse().unwrap();
        assert_eq!(d.geometry.dims, dims, "{file}");
        assert_eq!(d.geometry.spacing, spacing, "{file}");
        assert_eq!(d.geometry.origin, origin, "{file}");
        assert_eq!(d.buffer.scalar_type(), dtype, "{file}");
        match (&d.format, entry["array"].as_str()) {
            (SourceFormat::Vti { array }, Some(want))
            | (SourceFormat::LegacyVtk { array }, Some(want)) => {
                assert_eq!(array, want, "{file}")
            }
            (SourceFormat::Raw { scalar_type, .. }, None) => assert_eq!(*scalar_type, dtype),
            (f, w) => panic!("{file}: format {f:?} but manifest array {w:?}"),
        }

        // value = scale * (i + 10 j + 100 k) + offset, computed in f64 like the generator
        // (every formula there is exact in its type, so equality is exact).
        let (scale, offset) = (
            entry["scale"].as_f64().unwrap(),
            entry["offset"].as_f64().unwrap(),
        );
        let mut index = 0usize;
        let mut bad = Vec::new();
        d.buffer.for_each(|v| {
            let (i, j, k) = (
                index % dims[0],
                (index / dims[0]) % dims[1],
                index / (dims[0] * dims[1]),
            );
            let want = scale * (i + 10 * j + 100 * k) as f64 + offset;
            if v != want && bad.len() < 3 {
                bad.push((i, j, k, v, want));
            }
            index += 1;
        });
        assert_eq!(index, dims.iter().product::<usize>(), "{file}: value count");
        assert!(bad.is_empty(), "{file}: (i, j, k, got, want) {bad:?}");

        // Through `load`: range and source are set.
        let v = volume::load(&path, &opts).unwrap();
        let n = dims[0] * dims[1] * dims[2];
        let corner = |i: usize, j: usize, k: usize| scale * (i + 10 * j + 100 * k) as f64 + offset;
        let (a, b) = (
            corner(0, 0, 0),
            corner(dims[0] - 1, dims[1] - 1, dims[2] - 1),
        );
        assert_eq!(v.range, [a.min(b), a.max(b)], "{file}");
        assert_eq!(v.data().len(), n);
        assert_eq!(v.non_finite, 0);
        let src = v.source.as_ref().expect("source set");
        assert_eq!(src.path, path);
        assert_eq!(src.format, d.format);
    }
}

#[test]
fn raw_fixture_records_byte_order_for_scripts() {
    let path = fixtures().join("ramp_be_5x4x3_float32.raw");
    let opts = ReadOptions {
        byte_order: Some(ByteOrder::Big),
        ..Default::default()
    };
    let v = volume::load(&path, &opts).unwrap();
    assert_eq!(
        v.source.unwrap().format,
        SourceFormat::Raw {
            scalar_type: ScalarType::F32,
            byte_order: ByteOrder::Big
        }
    );
    // Read as little-endian, the same bytes are other (wrong) numbers: the flag matters.
    let le = volume::decode(&path, &ReadOptions::default()).unwrap();
    let mut first = 0.0;
    le.buffer.for_each(|x| {
        if first == 0.0 {
            first = x
        }
    });
    assert_ne!(first, -30.5);
}

#[test]
fn spacing_flag_overrides_the_file() {
    let path = fixtures().join("ascii_float32.vti");
    let opts = ReadOptions {
        spacing: Some([2.0, 3.0, 4.0]),
        ..Default::default()
    };
    assert_eq!(
        volume::decode(&path, &opts).unwrap().geometry.spacing,
        [2.0, 3.0, 4.0]
    );
}

#[test]
fn flags_override_the_raw_file_name() {
    let path = fixtures().join("ramp_7x6x5_uint16.raw");
    let opts = ReadOptions {
        dims: Some([210, 1, 1]),
        dtype: Some(ScalarType::I16),
        ..Default::default()
    };
    let d = volume::decode(&path, &opts).unwrap();
    assert_eq!(d.geometry.dims, [210, 1, 1]);
    assert_eq!(d.buffer.scalar_type(), ScalarType::I16);
    // uint16 values above 32767 read as negative int16: the type flag really applies.
    let mut negative = 0;
    d.buffer.for_each(|v| negative += (v < 0.0) as usize);
    assert!(negative > 0);
    // The name alone gives the other reading.
    let d = volume::decode(&path, &ReadOptions::default()).unwrap();
    assert_eq!(d.geometry.dims, [7, 6, 5]);
    assert_eq!(d.buffer.scalar_type(), ScalarType::U16);
}

#[test]
fn legacy_aspect_ratio_is_spacing() {
    let src = fixtures().join("legacy_ascii_float32.vtk");
    let text = std::fs::read_to_string(&src).unwrap();
    assert!(text.contains("\nSPACING "));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("aspect.vtk");
    std::fs::write(&path, text.replace("\nSPACING ", "\nASPECT_RATIO ")).unwrap();
    let a = volume::decode(&src, &ReadOptions::default()).unwrap();
    let b = volume::decode(&path, &ReadOptions::default()).unwrap();
    assert_eq!(a.geometry, b.geometry);
    assert_eq!(b.geometry.spacing, [0.5, 0.25, 2.0]);
}
