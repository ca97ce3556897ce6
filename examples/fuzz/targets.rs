//! The parsers the fuzzer drives, one function per target: bytes in, `Ok`/`Err` out, and a
//! short "signature" of the outcome (the error's first words) to tell behaviours apart.
//! Shared with tests/volume/fuzz_replay.rs (through `#[path]`), which replays the committed corpus.

use std::path::{Path, PathBuf};

/// A fuzz target: its name, the seed files it starts from, and the parser.
pub struct Target {
    pub name: &'static str,
    /// Seed files: test fixtures of this format (relative to the repository root).
    pub seeds: &'static [&'static str],
    /// Seeds made in code: inputs too large to commit (a preset of 10⁶ points).
    pub generated: Option<fn() -> Vec<u8>>,
    /// File name the bytes are given (the extension picks the reader).
    pub file_name: &'static str,
    pub run: fn(&Path) -> Result<(), String>,
}

fn volume(path: &Path) -> Result<(), String> {
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    let opts = t2tf::volume::ReadOptions::default();
    let decoded = t2tf::volume::decode_bytes(path, bytes, &opts).map_err(|e| e.to_string())?;
    t2tf::volume::Volume::from_buffer(path, decoded.geometry, &decoded.buffer)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

fn raw_named(path: &Path) -> Result<(), String> {
    volume(path)
}

fn transfer_function(path: &Path) -> Result<(), String> {
    t2tf::formats::read_tf(path)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// A preset as `optimize --init` takes it: read (with the file cap raised to 1 GiB, so that
/// the parser sees the whole input), simplified, and held to the control-point limit.
fn init_preset(path: &Path) -> Result<(), String> {
    t2tf::pipeline::InitTf::read(path, None, 1 << 30)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// Points of the generated presets.
pub const LARGE_POINTS: usize = 1_000_000;

/// A TF of [`LARGE_POINTS`] colour and opacity points whose opacity alternates 0, 1 (no point
/// can be dropped) and whose colours cycle, so that neither simplification nor the limit of
/// a start can shortcut the parse.
fn large_tf() -> t2tf::formats::ExportTf {
    let n = LARGE_POINTS;
    let x = |i: usize| i as f64 / (n - 1) as f64;
    t2tf::formats::ExportTf {
        name: "large".into(),
        rgb_points: (0..n)
            .map(|i| (x(i), [(i % 7) as f64 / 7.0, (i % 3) as f64 / 3.0, 0.5]))
            .collect(),
        opacity_points: (0..n).map(|i| (x(i), (i % 2) as f64)).collect(),
        unit_distance: None,
    }
}

fn large_json() -> Vec<u8> {
    t2tf::formats::to_paraview_json(&large_tf()).into_bytes()
}

fn large_xml() -> Vec<u8> {
    t2tf::formats::to_paraview_xml(&large_tf()).into_bytes()
}

fn large_ct() -> Vec<u8> {
    t2tf::formats::to_visit_ct(&large_tf()).into_bytes()
}

fn png(path: &Path) -> Result<(), String> {
    t2tf::image::Image::load_png(path)
        .map(|_| ())
        .map_err(|e| format!("{e:#}"))
}

fn clip_config(path: &Path) -> Result<(), String> {
    let text = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
    t2tf::clip::ClipConfig::from_json(&text)
        .map(|_| ())
        .map_err(|e| e.0)
}

fn checkpoint(path: &Path) -> Result<(), String> {
    let ck = t2tf::clip::Checkpoint::open(&[path.to_path_buf()]).map_err(|e| e.to_string())?;
    // Read every tensor as the shape it has: exercises offsets, strides and dtypes.
    for name in ck.names() {
        if let Some(shape) = ck.shape(name) {
            let _ = ck.get(name, &shape);
        }
    }
    Ok(())
}

/// Every target, in the order `--all` runs them.
pub const TARGETS: &[Target] = &[
    Target {
        name: "vti",
        seeds: &[
            "tests/fixtures/volumes/ascii_float32.vti",
            "tests/fixtures/volumes/appended_raw_uint16.vti",
            "tests/fixtures/volumes/appended_raw_float32_lzma.vti",
            "tests/fixtures/volumes/binary_int16_zlib.vti",
            "tests/fixtures/volumes/binary_uint64_lz4.vti",
            "tests/fixtures/volumes/appended_base64_float32_lz4.vti",
            "tests/fixtures/volumes/bigendian_int64_zlib.vti",
            "tests/fixtures/fuzz_seeds/hostile_uint64_overflow.vti",
            "tests/fixtures/fuzz_seeds/hostile_int64_overflow.vti",
            "tests/fixtures/fuzz_seeds/hostile_nul_in_header.vti",
            "tests/fixtures/fuzz_seeds/hostile_lzma_bomb.vti",
        ],
        generated: None,
        file_name: "fuzz.vti",
        run: volume,
    },
    Target {
        name: "vtk",
        seeds: &[
            "tests/fixtures/volumes/legacy_ascii_float32.vtk",
            "tests/fixtures/volumes/legacy_binary_uint16.vtk",
            "tests/fixtures/volumes/legacy_sections_binary.vtk",
            "tests/fixtures/volumes/legacy_v42_ascii_int32.vtk",
            "tests/fixtures/fuzz_seeds/hostile_uint64_overflow.vtk",
            "tests/fixtures/fuzz_seeds/hostile_int64_overflow.vtk",
        ],
        generated: None,
        file_name: "fuzz.vtk",
        run: volume,
    },
    Target {
        name: "raw",
        seeds: &["tests/fixtures/volumes/ramp_7x6x5_uint16.raw"],
        generated: None,
        file_name: "ramp_7x6x5_uint16.raw",
        run: raw_named,
    },
    Target {
        name: "json",
        seeds: &[
            "tests/fixtures/paraview/paraview_written_preset.json",
            "tests/fixtures/fuzz_seeds/hostile_preset.json",
        ],
        generated: None,
        file_name: "fuzz.json",
        run: transfer_function,
    },
    Target {
        name: "xml",
        seeds: &[
            "tests/fixtures/fuzz_seeds/preset.xml",
            "tests/fixtures/fuzz_seeds/hostile_preset.xml",
        ],
        generated: None,
        file_name: "fuzz.xml",
        run: transfer_function,
    },
    Target {
        name: "ct",
        seeds: &["tests/fixtures/fuzz_seeds/preset.ct"],
        generated: None,
        file_name: "fuzz.ct",
        run: transfer_function,
    },
    Target {
        name: "json_large",
        seeds: &[],
        generated: Some(large_json),
        file_name: "fuzz.json",
        run: init_preset,
    },
    Target {
        name: "xml_large",
        seeds: &[],
        generated: Some(large_xml),
        file_name: "fuzz.xml",
        run: init_preset,
    },
    Target {
        name: "ct_large",
        seeds: &[],
        generated: Some(large_ct),
        file_name: "fuzz.ct",
        run: init_preset,
    },
    Target {
        name: "png",
        seeds: &[
            "tests/fixtures/fuzz_seeds/small.png",
            "tests/fixtures/fuzz_seeds/hostile_1x1000000.png",
            "tests/fixtures/fuzz_seeds/hostile_100000x1.png",
        ],
        generated: None,
        file_name: "fuzz.png",
        run: png,
    },
    Target {
        name: "config",
        seeds: &[
            "tests/fixtures/clip/quick_gelu/config.json",
            "tests/fixtures/clip/odd_shapes/config.json",
        ],
        generated: None,
        file_name: "config.json",
        run: clip_config,
    },
    Target {
        name: "safetensors",
        seeds: &["tests/fixtures/fuzz_seeds/small.safetensors"],
        generated: None,
        file_name: "model.safetensors",
        run: checkpoint,
    },
    Target {
        name: "torch",
        seeds: &[
            "tests/fixtures/clip/torch/state_dict.bin",
            "tests/fixtures/clip/torch/deflated.bin",
        ],
        generated: None,
        file_name: "pytorch_model.bin",
        run: checkpoint,
    },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// The corpus folder of a target (committed inputs CI replays).
pub fn corpus_dir(root: &Path, target: &Target) -> PathBuf {
    root.join("tests/fuzz_corpus").join(target.name)
}

/// What an outcome looked like, coarsely: "ok", or the error's text with the file name and
/// numbers blanked, so that two inputs failing for the same reason share a signature.
pub fn signature(outcome: &Result<(), String>) -> String {
    match outcome {
        Ok(()) => "ok".into(),
        Err(e) => e
            .split(':')
            .skip(1)
            .collect::<Vec<_>>()
            .join(":")
            .chars()
            .map(|c| if c.is_ascii_digit() { '#' } else { c })
            .take(80)
            .collect(),
    }
}
