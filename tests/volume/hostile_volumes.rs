//! Hostile volume values: ASCII integers that do not fit the declared type are refused,
//! float64 data near ±f64::MAX normalizes to finite values, and spacings whose box single
//! precision cannot hold are refused. Every file is made by the test.

#[cfg(unix)]
use crate::limits_util::info_within;
use std::path::Path;

use t2tf::volume::{decode_bytes, ReadOptions, Volume};

fn load(name: &str, text: &str) -> Result<Volume, String> {
    let path = Path::new(name);
    let d = decode_bytes(path, text.as_bytes().to_vec(), &ReadOptions::default())
        .map_err(|e| e.to_string())?;
    Volume::from_buffer(path, d.geometry, &d.buffer).map_err(|e| e.to_string())
}

fn legacy(ty: &str, values: &str) -> String {
    format!(
        "# vtk DataFile Version 3.0\nt\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 2 2\n\
         SPACING 1 1 1\nORIGIN 0 0 0\nPOINT_DATA 8\nSCALARS v {ty} 1\nLOOKUP_TABLE default\n{values}\n"
    )
}

fn vti(ty: &str, values: &str) -> String {
    format!(
        r#"<?xml version="1.0"?>
<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian">
<ImageData WholeExtent="0 1 0 1 0 1" Origin="0 0 0" Spacing="1 1 1">
<Piece Extent="0 1 0 1 0 1"><PointData Scalars="v">
<DataArray type="{ty}" Name="v" format="ascii">{values}</DataArray>
</PointData></Piece></ImageData></VTKFile>"#
    )
}

#[test]
fn ascii_integers_must_fit_their_declared_type() {
    let bad = "0 1 2 300 4 5 6 -5";
    let e = load("a.vtk", &legacy("unsigned_char", bad)).unwrap_err();
    assert!(e.contains("300") && e.contains("UInt8"), "{e}");
    let e = load("a.vti", &vti("UInt8", bad)).unwrap_err();
    assert!(e.contains("300"), "{e}");
    let e = load("a.vti", &vti("Int16", "0 1 2 3 4 5 6 2.5")).unwrap_err();
    assert!(e.contains("2.5"), "{e}");
    load("a.vti", &vti("UInt8", "0 1 2 255 4 5 6 7")).unwrap();
    load("a.vti", &vti("Float32", bad)).unwrap();
}

/// 64-bit integers are checked from their text: as f64, 2⁶⁴ and u64::MAX are one number.
#[test]
fn ascii_64_bit_integers_are_checked_exactly() {
    let max = "0 1 2 3 4 5 6 18446744073709551615";
    load("a.vti", &vti("UInt64", max)).unwrap();
    load("a.vtk", &legacy("unsigned_long", max)).unwrap();
    for (ty, legacy_ty, value) in [
        ("UInt64", "unsigned_long", "18446744073709551616"),
        ("UInt64", "unsigned_long", "-1"),
        ("Int64", "long", "9223372036854775808"),
        ("Int64", "long", "-9223372036854775809"),
    ] {
        let values = format!("0 1 2 3 4 5 6 {value}");
        // The value as written and the type's bounds exactly (not 2⁶⁴ for u64::MAX).
        let bounds = match ty {
            "UInt64" => "(0 to 18446744073709551615)",
            _ => "(-9223372036854775808 to 9223372036854775807)",
        };
        let said =
            format!("value 7 ({value}) is not an integer its declared type {ty} holds {bounds}");
        let e = load("a.vti", &vti(ty, &values)).unwrap_err();
        assert!(e.contains(&said), "{ty} {value}: {e}");
        let e = load("a.vtk", &legacy(legacy_ty, &values)).unwrap_err();
        assert!(e.contains(&said), "{legacy_ty} {value}: {e}");
    }
    // Other types: the bounds as integers, the value as short as it round-trips.
    let e = load("a.vti", &vti("UInt32", "0 1 2 3 4 5 6 1e300")).unwrap_err();
    assert!(
        e.contains(
            "value 7 (1e300) is not an integer its declared type UInt32 holds (0 to 4294967295)"
        ),
        "{e}"
    );
    load(
        "a.vti",
        &vti(
            "Int64",
            "0 1 2 3 4 5 -9223372036854775808 9223372036854775807",
        ),
    )
    .unwrap();
}

#[test]
fn float64_beyond_f32_range_normalizes_to_finite_values() {
    let v = load(
        "a.vti",
        &vti("Float64", "-1.7e308 1.7e308 0 1e300 -1e300 5 6 7"),
    )
    .unwrap();
    assert!(v.data().iter().all(|x| x.is_finite()), "{:?}", v.data());
    assert_eq!(v.data()[0], 0.0);
    assert_eq!(v.data()[1], 1.0);
    for t in [0.0, 0.25, 0.5, 1.0] {
        assert!(v.denormalize(t).is_finite(), "{t}");
    }
    assert_eq!(v.histogram.iter().sum::<u64>(), 8);
}

#[test]
fn spacings_that_single_precision_cannot_hold_are_refused() {
    for s in ["1e300 1 1", "1e-300 1e-300 1e-300", "1 1e-60 1"] {
        let text = vti("UInt8", "0 1 2 3 4 5 6 7")
            .replace("Spacing=\"1 1 1\"", &format!("Spacing=\"{s}\""));
        let e = load("a.vti", &text).unwrap_err();
        assert!(e.contains("single precision"), "{s}: {e}");
    }
}

#[cfg(unix)]
/// `t2tf info` on a 512³ uint8 file (128 MiB) under an address-space limit of
/// 384 MiB, below the 512 MiB of its f32 copy alone: the file is streamed, nothing the size
/// of the volume is allocated, and the statistics are those of the whole file.
#[test]
fn info_streams_a_volume_larger_than_its_address_space_allows() {
    use std::io::Write;
    const N: usize = 512;
    const LIMIT: u64 = 384 << 20;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(format!("big_{N}x{N}x{N}_uint8.raw"));
    let mut file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    // Value (x + y + z) mod 256: every value occurs, 0 and 255 included.
    let mut slice = vec![0u8; N * N];
    for z in 0..N {
        for (i, v) in slice.iter_mut().enumerate() {
            *v = ((i % N + i / N + z) % 256) as u8;
        }
        file.write_all(&slice).unwrap();
    }
    file.into_inner().unwrap().sync_all().unwrap();

    let report = info_within(&path, LIMIT, (N * N * N) as u64);
    assert_eq!(report["dims"], serde_json::json!([N, N, N]));
    assert_eq!(report["range"], serde_json::json!([0.0, 255.0]));
    assert_eq!(report["pyramid"][1], serde_json::json!([256, 256, 256]));
}
