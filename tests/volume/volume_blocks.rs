//! Volumes larger than memory, block-decoded: `.vti` arrays stored in compressed blocks (zlib, LZ4,
//! LZMA; appended raw, appended base64, inline base64) or as uncompressed base64 are read block by
//! block from a map of the file, not decoded whole. A load through the block source equals the
//! in-memory build of the decoded values bit for bit; `read_box` equals slicing level 0; a corrupt
//! block is an error naming the file and the block; `t2tf info` equals the load's statistics and
//! summarizes a compressed file whose decoded values do not fit its address space.

use std::io::Write;
use std::path::{Path, PathBuf};

use base64::Engine;
use t2tf::volume::{self, ByteOrder, ReadOptions, ScalarType, Volume};

use crate::volume_stream::{assert_same, bits, encode};

const SHARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/volumes");

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/volumes")
}

/// How the generated file stores its array.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Encoding {
    AppendedRaw,
    AppendedBase64,
    Inline,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Compressor {
    None,
    Zlib,
    Lz4,
}

/// A VTK XML ImageData file as `vtkXMLImageDataWriter` lays it out: one point-data array
/// `v` of `ty` (values already in `order`), `block` bytes per compressed block, the header
/// integers UInt64 when `header64`; base64 encodes the header and the data as two streams.
#[allow(clippy::too_many_arguments)]
fn write_vti(
    path: &Path,
    dims: [usize; 3],
    ty: ScalarType,
    order: ByteOrder,
    data: &[u8],
    encoding: Encoding,
    compressor: Compressor,
    block: usize,
    header64: bool,
) {
    let int = |v: usize| -> Vec<u8> {
        match (header64, order) {
            (false, ByteOrder::Little) => (v as u32).to_le_bytes().to_vec(),
            (false, ByteOrder::Big) => (v as u32).to_be_bytes().to_vec(),
            (true, ByteOrder::Little) => (v as u64).to_le_bytes().to_vec(),
            (true, ByteOrder::Big) => (v as u64).to_be_bytes().to_vec(),
        }
    };
    let (header, body): (Vec<u8>, Vec<u8>) = match compressor {
        Compressor::None => (int(data.len()), data.to_vec()),
        c => {
            let chunks: Vec<Vec<u8>> = data
                .chunks(block)
                .map(|b| match c {
                    Compressor::Zlib => {
                        let mut z = flate2::write::ZlibEncoder::new(
                            Vec::new(),
                            flate2::Compression::fast(),
                        );
                        z.write_all(b).unwrap();
                        z.finish().unwrap()
                    }
                    _ => lz4_flex::block::compress(b),
                })
                .collect();
            let mut header = [chunks.len(), block, data.len() % block]
                .iter()
                .flat_map(|&v| int(v))
                .collect::<Vec<u8>>();
            for c in &chunks {
                header.extend(int(c.len()));
            }
            (header, chunks.concat())
        }
    };
    let b64 = base64::engine::general_purpose::STANDARD;
    let [nx, ny, nz] = dims;
    let extent = format!("0 {} 0 {} 0 {}", nx - 1, ny - 1, nz - 1);
    let type_name = match ty {
        ScalarType::U8 => "UInt8",
        ScalarType::U16 => "UInt16",
        ScalarType::F32 => "Float32",
        ScalarType::F64 => "Float64",
        other => panic!("{other:?} not generated"),
    };
    let compressor_attr = match compressor {
        Compressor::None => "",
        Compressor::Zlib => " compressor=\"vtkZLibDataCompressor\"",
        Compressor::Lz4 => " compressor=\"vtkLZ4DataCompressor\"",
    };
    let order_name = match order {
        ByteOrder::Little => "LittleEndian",
        ByteOrder::Big => "BigEndian",
    };
    let header_type = if header64 { "UInt64" } else { "UInt32" };
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    write!(
        out,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" \
         byte_order=\"{order_name}\" header_type=\"{header_type}\"{compressor_attr}>\n  \
         <ImageData WholeExtent=\"{extent}\" Origin=\"0 0 0\" Spacing=\"1 0.5 2\">\n  \
         <Piece Extent=\"{extent}\">\n    <PointData Scalars=\"v\">\n"
    )
    .unwrap();
    // A second array first, so the chosen one is not at offset 0 of the appended data.
    let other = [0u8; 8];
    let other_stream = match encoding {
        Encoding::AppendedBase64 => {
            let mut s = b64.encode(int(8)).into_bytes();
            s.extend(b64.encode(other).into_bytes());
            s
        }
        _ => [int(8), other.to_vec()].concat(),
    };
    match encoding {
        Encoding::Inline => {
            write!(
                out,
                "      <DataArray type=\"{type_name}\" Name=\"v\" format=\"binary\">\n        \
                 {}{}\n      </DataArray>\n",
                b64.encode(&header),
                b64.encode(&body)
            )
            .unwrap();
            write!(
                out,
                "    </PointData>\n  </Piece>\n  </ImageData>\n</VTKFile>\n"
            )
            .unwrap();
        }
        Encoding::AppendedRaw | Encoding::AppendedBase64 => {
            let (enc, stream) = if encoding == Encoding::AppendedRaw {
                ("raw", [header, body].concat())
            } else {
                let mut s = b64.encode(&header).into_bytes();
                s.extend(b64.encode(&body).into_bytes());
                ("base64", s)
            };
            write!(
                out,
                "      <DataArray type=\"UInt8\" Name=\"pad\" format=\"appended\" \
                 offset=\"0\"/>\n      <DataArray type=\"{type_name}\" Name=\"v\" \
                 format=\"appended\" offset=\"{}\"/>\n    </PointData>\n  </Piece>\n  \
                 </ImageData>\n  <AppendedData encoding=\"{enc}\">\n   _",
                other_stream.len()
            )
            .unwrap();
            out.write_all(&other_stream).unwrap();
            out.write_all(&stream).unwrap();
            write!(out, "\n  </AppendedData>\n</VTKFile>\n").unwrap();
        }
    }
    out.flush().unwrap();
}

/// Odd boxes of level 0 read from the source (before it is made) equal slices of `want`.
fn assert_boxes(loaded: &Volume, want: &Volume, what: &str) {
    let level = &loaded.levels[0];
    let d = level.dims;
    let data = want.levels[0].data();
    let boxes = [
        ([0, 0, 0], d),
        ([1, 2, 3], [d[0] - 1, d[1], d[2] - 1]),
        (
            [d[0] / 3, 1, d[2] / 2],
            [d[0] / 3 + 1, d[1] - 1, d[2] / 2 + 2],
        ),
        ([d[0] - 1, d[1] - 1, d[2] - 1], d),
    ];
    for (lo, hi) in boxes {
        let lo: [usize; 3] = std::array::from_fn(|a| lo[a].min(hi[a]));
        let len: usize = (0..3).map(|a| hi[a] - lo[a]).product();
        let mut out = vec![0.0f32; len];
        level.read_box(lo, hi, &mut out).unwrap();
        let mut expect = Vec::with_capacity(len);
        for z in lo[2]..hi[2] {
            for y in lo[1]..hi[1] {
                let at = (z * d[1] + y) * d[0];
                expect.extend_from_slice(&data[at + lo[0]..at + hi[0]]);
            }
        }
        assert!(bits(&out) == bits(&expect), "{what}: box {lo:?}..{hi:?}");
    }
    assert!(!level.is_materialized(), "{what}: read_box made level 0");
}

/// `t2tf info`'s numbers equal the load's.
// Alike to summary.rs's unit test `summary_equals_load` (generated .raw of every type), which
// lives in the library's test binary; this one runs on the .vti fixtures and shared volumes.
fn assert_summary(path: &Path, opts: &ReadOptions, v: &Volume) {
    let s = volume::summarize(path, opts).unwrap_or_else(|e| panic!("{e}"));
    let what = path.display().to_string();
    assert_eq!(s.geometry, v.geometry, "{what}");
    assert_eq!(s.scalar_type, v.scalar_type, "{what}");
    assert_eq!(
        s.range.map(f64::to_bits),
        v.range.map(f64::to_bits),
        "{what}"
    );
    assert_eq!(s.norm_range, v.norm_range, "{what}");
    assert_eq!(s.non_finite, v.non_finite, "{what}");
    assert_eq!(s.histogram, v.histogram, "{what}");
    assert_eq!(s.source, v.source.clone().unwrap(), "{what}");
    let dims: Vec<[usize; 3]> = v.levels.iter().map(|l| l.dims).collect();
    assert_eq!(s.levels, dims, "{what}");
}

/// Values with NaN and infinities for the float types, a ramp for the integers.
fn values(n: usize, ty: ScalarType) -> Vec<f64> {
    let mut v: Vec<f64> = (0..n).map(|i| ((i * 7919) % 1013) as f64).collect();
    if matches!(ty, ScalarType::F32 | ScalarType::F64) {
        for (i, x) in v.iter_mut().enumerate() {
            *x = *x * 0.37 - 100.0;
            if i % 97 == 5 {
                *x = f64::NAN;
            }
        }
        v[11] = f64::INFINITY;
        v[12] = -0.0;
    } else if ty == ScalarType::U8 {
        v.iter_mut().for_each(|x| *x %= 256.0);
    }
    v
}

/// Every generated layout: the load (block-decoded) equals the in-memory build of the decoded
/// values, its boxes equal slices of level 0, and the summary equals the load. Block sizes
/// not a multiple of the value size, one block and many, both byte orders, both header types.
#[test]
fn generated_files_load_like_the_in_memory_build() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [37, 29, 23];
    let n: usize = dims.iter().product();
    let mut checked = 0;
    let types = [
        ScalarType::U8,
        ScalarType::U16,
        ScalarType::F32,
        ScalarType::F64,
    ];
    for (t, ty) in types.into_iter().enumerate() {
        let vals = values(n, ty);
        for order in [ByteOrder::Little, ByteOrder::Big] {
            let data = encode(&vals, ty, order);
            for (e, encoding) in [
                Encoding::AppendedRaw,
                Encoding::AppendedBase64,
                Encoding::Inline,
            ]
            .into_iter()
            .enumerate()
            {
                // Not a multiple of 2, 4 or 8; a page; one block for the whole array.
                for (b, block) in [1001, 4096, data.len()].into_iter().enumerate() {
                    let compressor = match (t + e + b) % 3 {
                        0 => Compressor::Zlib,
                        1 => Compressor::Lz4,
                        // Uncompressed appended raw is mapped, not block-decoded.
                        _ if encoding == Encoding::AppendedRaw => Compressor::Zlib,
                        _ => Compressor::None,
                    };
                    let header64 = (t + b) % 2 == 1;
                    let what = format!("{ty:?} {order:?} {encoding:?} {compressor:?} {block}");
                    let path = dir.path().join(format!("g{checked}.vti"));
                    write_vti(
                        &path, dims, ty, order, &data, encoding, compressor, block, header64,
                    );
                    let opts = ReadOptions::default();
                    let loaded =
                        volume::load(&path, &opts).unwrap_or_else(|e| panic!("{what}: {e}"));
                    assert!(!loaded.levels[0].is_mapped(), "{what}");
                    let d = volume::decode(&path, &opts).unwrap();
                    let built = Volume::from_buffer(&path, d.geometry, &d.buffer).unwrap();
                    assert_boxes(&loaded, &built, &what);
                    assert_same(&loaded, &built, &what);
                    assert_summary(&path, &opts, &loaded);
                    checked += 1;
                }
            }
        }
    }
    assert_eq!(checked, 4 * 2 * 3 * 3);
}

/// A 40 × 30 × 20 uint16 little-endian file `name` in `dir` stored as `encoding` in
/// `compressor` blocks of `block` bytes; its path and its values' bytes.
fn u16_file(
    dir: &Path,
    name: &str,
    encoding: Encoding,
    compressor: Compressor,
    block: usize,
) -> (PathBuf, Vec<u8>) {
    let dims = [40, 30, 20];
    let (ty, order) = (ScalarType::U16, ByteOrder::Little);
    let data = encode(&values(dims.iter().product(), ty), ty, order);
    let path = dir.join(name);
    write_vti(
        &path, dims, ty, order, &data, encoding, compressor, block, false,
    );
    (path, data)
}

/// A block that does not decode: the load fails with the whole decode's message, which
/// names the file, the array and the block; a corrupt base64 character names its block.
#[test]
fn a_corrupt_block_is_an_error_naming_the_file_and_block() {
    let dir = tempfile::tempdir().unwrap();
    let (path, data) = u16_file(
        dir.path(),
        "corrupt.vti",
        Encoding::AppendedRaw,
        Compressor::Zlib,
        1001,
    );
    let mut bytes = std::fs::read(&path).unwrap();
    // Near the end of the data: inside the last blocks' zlib streams (past their headers).
    let end = bytes.len() - "\n  </AppendedData>\n</VTKFile>\n".len();
    for b in &mut bytes[end - 40..end - 30] {
        *b ^= 0x5a;
    }
    std::fs::write(&path, &bytes).unwrap();
    let opts = ReadOptions::default();
    let e = volume::load(&path, &opts).unwrap_err().to_string();
    let whole = volume::decode(&path, &opts).unwrap_err().to_string();
    assert_eq!(e, whole);
    let nblocks = data.len().div_ceil(1001);
    assert!(e.contains("corrupt.vti"), "{e}");
    assert!(
        e.contains(&format!("of {nblocks}")) && e.contains("array 'v': block"),
        "{e}"
    );
    assert!(!e.contains('\n'), "{e}");
    // The summary reads the same blocks.
    let s = volume::summarize(&path, &opts).unwrap_err().to_string();
    assert_eq!(s, e);

    let (path, _) = u16_file(
        dir.path(),
        "corrupt64.vti",
        Encoding::Inline,
        Compressor::Lz4,
        4096,
    );
    let mut text = std::fs::read(&path).unwrap();
    let end = text.len()
        - "\n      </DataArray>\n    </PointData>\n  </Piece>\n  </ImageData>\n</VTKFile>\n".len();
    text[end - 100] = b'*';
    std::fs::write(&path, &text).unwrap();
    let e = volume::load(&path, &opts).unwrap_err().to_string();
    assert!(
        e.contains("corrupt64.vti") && e.contains("array 'v': block ") && e.contains("base64"),
        "{e}"
    );
}

/// A block that stops decoding after the load (the file overwritten in place: the map sees
/// it) is an error from `read_box` and `try_data`, naming the file and the block, not a panic.
#[test]
fn a_block_corrupt_after_the_load_is_an_error_from_read_box_and_try_data() {
    use std::io::{Seek, SeekFrom};
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = u16_file(
        dir.path(),
        "late.vti",
        Encoding::AppendedRaw,
        Compressor::Zlib,
        1001,
    );
    let loaded = volume::load(&path, &ReadOptions::default()).unwrap();
    let len = std::fs::metadata(&path).unwrap().len();
    let tail = "\n  </AppendedData>\n</VTKFile>\n".len() as u64;
    let mut f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    f.seek(SeekFrom::Start(len - tail - 40)).unwrap();
    f.write_all(&[0x5a; 10]).unwrap();
    f.sync_all().unwrap();
    let level = &loaded.levels[0];
    let dims = loaded.dims();
    let mut out = vec![0.0f32; dims.iter().product()];
    let e = level
        .read_box([0; 3], dims, &mut out)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("late.vti") && e.contains("array 'v': block"),
        "{e}"
    );
    let e = level.try_data().unwrap_err().to_string();
    assert!(
        e.contains("late.vti") && e.contains("array 'v': block"),
        "{e}"
    );
}

/// Every fixture VTK's writer made and every shared volume: `t2tf info` equals the load's
/// statistics; the compressed and base64 fixtures' boxes equal slices of the in-memory build.
#[test]
fn summary_equals_load_on_every_fixture_and_shared_volume() {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(fixtures())
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    let Ok(shared) = std::fs::read_dir(SHARED) else {
        panic!("{SHARED} must exist beside the repository");
    };
    paths.extend(shared.flatten().map(|e| e.path()));
    let mut checked = 0;
    for path in paths {
        let ext = path.extension().and_then(|x| x.to_str()).unwrap_or("");
        if !["raw", "vti", "vtk"].contains(&ext) {
            continue;
        }
        let opts = ReadOptions::default();
        let loaded = match volume::load(&path, &opts) {
            Ok(v) => v,
            Err(e) => {
                // Where the load fails, the summary fails alike.
                let s = volume::summarize(&path, &opts).unwrap_err();
                assert_eq!(s.to_string(), e.to_string(), "{}", path.display());
                continue;
            }
        };
        assert_summary(&path, &opts, &loaded);
        if ext == "vti" {
            let d = volume::decode(&path, &opts).unwrap();
            let built = Volume::from_buffer(&path, d.geometry, &d.buffer).unwrap();
            assert_boxes(&loaded, &built, &path.display().to_string());
        }
        checked += 1;
    }
    assert!(checked >= 35, "only {checked} files");
}

/// Other arrays than the first, by name: block-decoded like the first; a multi-component
/// array is refused as the whole decode refuses it.
#[test]
fn named_arrays_read_like_the_whole_decode() {
    for (file, array) in [
        ("arrays.vti", "density"),
        ("arrays.vti", "last"),
        ("arrays.vti", "velocity"),
        ("no_active.vti", "second"),
        ("arrays_raw_lz4.vti", "density"),
    ] {
        let path = fixtures().join(file);
        let opts = ReadOptions {
            array: Some(array.into()),
            ..Default::default()
        };
        let what = format!("{file} {array}");
        match (volume::load(&path, &opts), volume::decode(&path, &opts)) {
            (Ok(loaded), Ok(d)) => {
                let built = Volume::from_buffer(&path, d.geometry, &d.buffer).unwrap();
                assert_same(&loaded, &built, &what);
                assert_summary(&path, &opts, &loaded);
            }
            (Err(a), Err(b)) => {
                assert_eq!(a.to_string(), b.to_string(), "{what}");
                assert!(a.to_string().contains("components"), "{what}: {a}");
            }
            (a, b) => panic!("{what}: load {:?}, decode {:?}", a.err(), b.err()),
        }
    }
}

#[cfg(unix)]
/// `t2tf info` on a 384³ uint16 zlib `.vti` (108 MiB of values, a few MiB of file) under an
/// address-space limit of 100 MiB, which the decoded values alone exceed: the block source
/// reads it in bounded memory (decoding the whole array would fail here).
#[test]
fn info_on_a_compressed_vti_under_an_address_space_limit() {
    const N: usize = 384;
    const LIMIT: u64 = 100 << 20;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.vti");
    let mut data = Vec::with_capacity(2 * N * N * N);
    for z in 0..N {
        for y in 0..N {
            for x in 0..N {
                data.extend(((x + 2 * y + 3 * z) as u16 % 1000).to_le_bytes());
            }
        }
    }
    write_vti(
        &path,
        [N; 3],
        ScalarType::U16,
        ByteOrder::Little,
        &data,
        Encoding::AppendedRaw,
        Compressor::Zlib,
        32768,
        false,
    );
    drop(data);
    let report = crate::limits_util::info_within(&path, LIMIT, (N * N * N) as u64);
    assert_eq!(report["dims"], serde_json::json!([N, N, N]));
    assert_eq!(report["range"], serde_json::json!([0.0, 999.0]));
}
