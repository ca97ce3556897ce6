//! Streaming loads: `volume::load` streams its levels from a source (a memory map of the file where
//! the format allows it) and equals the in-memory build (`Volume::from_buffer` of the decoded
//! values) bit for bit: statistics, every level's samples and brick ranges. Level 0 of a loaded
//! volume is read from the source, not held, until asked for; `Level::read_box` equals slicing
//! `Level::data`.

use std::path::{Path, PathBuf};

use t2tf::volume::{self, ByteOrder, Level, ReadOptions, ScalarType, Volume};

const SHARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/volumes");

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/volumes")
}

pub(crate) fn bits(d: &[f32]) -> Vec<u32> {
    d.iter().map(|v| v.to_bits()).collect()
}

/// The file loaded (streamed) and decoded then built in memory.
fn both(path: &Path, opts: &ReadOptions) -> (Volume, Volume) {
    let loaded = volume::load(path, opts).unwrap_or_else(|e| panic!("{e}"));
    let d = volume::decode(path, opts).unwrap();
    let built = Volume::from_buffer(path, d.geometry, &d.buffer).unwrap();
    (loaded, built)
}

/// Statistics, and per level: shape, brick ranges and samples, bit for bit.
pub(crate) fn assert_same(a: &Volume, b: &Volume, what: &str) {
    assert_eq!(a.geometry, b.geometry, "{what}");
    assert_eq!(a.scalar_type, b.scalar_type, "{what}");
    assert_eq!(
        a.range.map(f64::to_bits),
        b.range.map(f64::to_bits),
        "{what}"
    );
    assert_eq!(a.norm_range, b.norm_range, "{what}");
    assert_eq!(a.non_finite, b.non_finite, "{what}");
    assert_eq!(a.histogram, b.histogram, "{what}");
    assert_eq!(a.levels.len(), b.levels.len(), "{what}: level count");
    for (l, (x, y)) in a.levels.iter().zip(&b.levels).enumerate() {
        assert_eq!(
            (x.dims, x.spacing),
            (y.dims, y.spacing),
            "{what}: level {l}"
        );
        assert_eq!(x.bricks.counts, y.bricks.counts, "{what}: level {l}");
        assert_eq!(
            bits(&x.bricks.min),
            bits(&y.bricks.min),
            "{what}: level {l} min"
        );
        assert_eq!(
            bits(&x.bricks.max),
            bits(&y.bricks.max),
            "{what}: level {l} max"
        );
        assert_eq!(x.bricks.uniform, y.bricks.uniform, "{what}: level {l}");
        assert!(
            bits(x.data()) == bits(y.data()),
            "{what}: level {l} samples differ"
        );
    }
}

#[test]
fn streaming_equals_in_memory_on_every_shared_volume() {
    let Ok(entries) = std::fs::read_dir(SHARED) else {
        panic!("{SHARED} must exist beside the repository");
    };
    let mut checked = 0;
    for e in entries.flatten() {
        let path = e.path();
        if path.extension().and_then(|x| x.to_str()) != Some("raw") {
            continue;
        }
        let (loaded, built) = both(&path, &ReadOptions::default());
        // Streamed: level 0 is read from the file's map, not held, until asked for.
        assert!(!loaded.levels[0].is_materialized(), "{}", path.display());
        assert!(loaded.levels[1..].iter().all(Level::is_materialized));
        assert_same(&loaded, &built, &path.display().to_string());
        assert!(loaded.levels[0].is_materialized());
        checked += 1;
    }
    assert!(checked >= 7, "only {checked} shared volumes");
}

/// `values` stored as `ty` in `order` (integers as the low bytes of their two's complement).
pub(crate) fn encode(values: &[f64], ty: ScalarType, order: ByteOrder) -> Vec<u8> {
    let mut out = Vec::with_capacity(values.len() * ty.size());
    for &v in values {
        let mut b = match ty {
            ScalarType::F32 => (v as f32).to_le_bytes().to_vec(),
            ScalarType::F64 => v.to_le_bytes().to_vec(),
            _ => (v as i64).to_le_bytes()[..ty.size()].to_vec(),
        };
        if order == ByteOrder::Big {
            b.reverse();
        }
        out.extend_from_slice(&b);
    }
    out
}

/// Sizes 1, 2, 3 and 127 per axis; float data with NaN, Inf and both zeros, and integer data
/// of every width in both byte orders.
#[test]
fn streaming_equals_in_memory_on_odd_sizes_with_nans() {
    let dir = tempfile::tempdir().unwrap();
    let sizes = [1usize, 2, 3, 127];
    let mut cases = Vec::new();
    for &x in &sizes {
        for &y in &sizes {
            for &z in &sizes {
                if x * y * z <= 127 * 127 * 3 {
                    cases.push([x, y, z]);
                }
            }
        }
    }
    cases.push([127, 127, 127]);
    for (c, dims) in cases.into_iter().enumerate() {
        let n: usize = dims.iter().product();
        // Rotate the type per case to keep the run short while covering all of them.
        let ty = ScalarType::ALL[c % ScalarType::ALL.len()];
        let order = if c % 3 == 0 {
            ByteOrder::Big
        } else {
            ByteOrder::Little
        };
        let float = ty.integer_range().is_none();
        let mut values: Vec<f64> = (0..n)
            .map(|i| {
                let v = ((i * 7919) % 251) as f64;
                if float {
                    v / 7.0 - 9.0
                } else if ty.integer_range().unwrap().0 < 0.0 {
                    v - 100.0
                } else {
                    v
                }
            })
            .collect();
        if float {
            for i in (0..n).step_by(97) {
                values[i] = f64::NAN;
            }
            if n > 4 {
                values[1] = f64::NEG_INFINITY;
                values[2] = 0.0;
                values[3] = -0.0;
            }
        }
        if values.iter().all(|v| !v.is_finite()) {
            values[0] = 1.0;
        }
        let path = dir.path().join(format!(
            "v{c}_{}x{}x{}_{}.raw",
            dims[0],
            dims[1],
            dims[2],
            ty.scivis_name()
        ));
        std::fs::write(&path, encode(&values, ty, order)).unwrap();
        let opts = ReadOptions {
            byte_order: Some(order),
            ..Default::default()
        };
        let (loaded, built) = both(&path, &opts);
        assert_same(&loaded, &built, &format!("{dims:?} {ty} {order:?}"));
    }
}

/// Decoded (not mapped) sources stream too: every fixture the readers decode equals its
/// in-memory build.
#[test]
fn streaming_equals_in_memory_on_every_fixture() {
    let mut checked = 0;
    for e in std::fs::read_dir(fixtures()).unwrap().flatten() {
        let path = e.path();
        let ext = path.extension().and_then(|x| x.to_str()).unwrap_or("");
        if !["raw", "vti", "vtk"].contains(&ext) {
            continue;
        }
        let opts = ReadOptions::default();
        // Fixtures that need flags are other tests' business; but the streaming load must
        // fail exactly where decoding and building in memory fails (e.g. no finite value).
        let Ok(d) = volume::decode(&path, &opts) else {
            assert!(volume::load(&path, &opts).is_err(), "{}", path.display());
            continue;
        };
        let built = Volume::from_buffer(&path, d.geometry, &d.buffer);
        let (loaded, built) = match (volume::load(&path, &opts), built) {
            (Ok(l), Ok(b)) => (l, b),
            (Err(a), Err(b)) => {
                assert_eq!(a.to_string(), b.to_string(), "{}", path.display());
                continue;
            }
            (a, b) => panic!("{}: load {a:?}, in memory {b:?}", path.display()),
        };
        assert_same(&loaded, &built, &path.display().to_string());
        let name = path.file_name().unwrap().to_str().unwrap();
        // Mapped: raw files, appended raw uncompressed .vti (the active array, the first
        // array) and BINARY legacy files; every other encoding is decoded.
        let mapped = ext == "raw"
            || ["appended_raw_uint16.vti", "arrays_raw.vti"].contains(&name)
            || name.starts_with("legacy_binary")
            || name == "legacy_sections_binary.vtk";
        assert_eq!(loaded.levels[0].is_mapped(), mapped, "{name}");
        checked += 1;
    }
    assert!(checked >= 30, "only {checked} fixtures");
}

/// Odd boxes, from the source (level 0 not held), from held levels, and after level 0 was
/// made: always the slice of `data()`.
#[test]
fn read_box_equals_slicing_data() {
    let path = Path::new(SHARED).join("walnut_128x96x114_uint16.raw");
    let (loaded, built) = both(&path, &ReadOptions::default());
    let boxes = [
        ([0, 0, 0], [1, 1, 1]),
        ([3, 5, 7], [40, 6, 33]),
        ([127, 95, 113], [128, 96, 114]),
        ([0, 0, 0], [128, 96, 114]),
        ([9, 9, 9], [9, 20, 20]),
        ([17, 1, 100], [128, 95, 101]),
    ];
    let check = |level: &Level, reference: &Level, what: &str| {
        for (lo, hi) in boxes {
            let hi: [usize; 3] = std::array::from_fn(|a| hi[a].min(level.dims[a]));
            let lo: [usize; 3] = std::array::from_fn(|a| lo[a].min(hi[a]));
            let n = (0..3).map(|a| hi[a] - lo[a]).product();
            let mut out = vec![f32::MAX; n];
            level.read_box(lo, hi, &mut out).unwrap();
            let data = reference.data();
            let [nx, ny, _] = reference.dims;
            let mut want = Vec::with_capacity(n);
            for k in lo[2]..hi[2] {
                for j in lo[1]..hi[1] {
                    want.extend_from_slice(&data[lo[0] + nx * (j + ny * k)..][..hi[0] - lo[0]]);
                }
            }
            assert_eq!(bits(&out), bits(&want), "{what} {lo:?}..{hi:?}");
        }
    };
    check(
        &loaded.levels[0],
        &built.levels[0],
        "level 0 from the source",
    );
    assert!(!loaded.levels[0].is_materialized(), "read_box made level 0");
    check(&loaded.levels[1], &built.levels[1], "level 1");
    let _ = loaded.levels[0].data();
    check(&loaded.levels[0], &built.levels[0], "level 0 held");
}

/// A clone shares the samples: making them once makes them for every clone.
#[test]
fn clones_share_one_lazy_level() {
    let path = Path::new(SHARED).join("nucleon_41x41x41_uint8.raw");
    let v = volume::load(&path, &ReadOptions::default()).unwrap();
    let c = v.clone();
    assert!(!c.levels[0].is_materialized());
    let _ = v.data();
    assert!(c.levels[0].is_materialized());
    assert!(std::ptr::eq(v.data().as_ptr(), c.data().as_ptr()));
}
