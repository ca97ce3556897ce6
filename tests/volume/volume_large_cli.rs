//! A volume larger than memory, through the binary: a generated 512³ uint8 `.raw` file (128 MiB;
//! 512 MiB as f32) is summarized by `t2tf info` and optimized by a short `t2tf optimize` under an
//! address-space limit of 400 MiB, below its f32 size: level 0 is read from the file's map, never
//! made.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Output};

const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const N: usize = 512;
/// Below the 512 MiB of level 0 as f32 (the binary, CLIP and the map of the file included).
const AS_LIMIT: u64 = 400 << 20;

/// A ball of rising density in a noisy background (the `bench_large` field, 8 bits).
fn write_volume(path: &Path) {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let c = N as f64 / 2.0;
    let mut row = vec![0u8; N];
    for z in 0..N {
        for y in 0..N {
            for (x, v) in row.iter_mut().enumerate() {
                let d = ((x as f64 - c).powi(2) + (y as f64 - c).powi(2) + (z as f64 - c).powi(2))
                    .sqrt()
                    / c;
                let noise = ((x * 7 + y * 13 + z * 29) % 32) as f64;
                *v = if d < 0.8 { 255.0 * (1.0 - d) } else { noise } as u8;
            }
            out.write_all(&row).unwrap();
        }
    }
    out.flush().unwrap();
}

/// `t2tf` under the address-space limit.
fn t2tf() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_t2tf"));
    // One malloc arena: each thread's arena reserves address space it may never use.
    cmd.env("MALLOC_ARENA_MAX", "1");
    crate::limits_util::limit_address_space(&mut cmd, AS_LIMIT);
    cmd
}

fn check(out: Output, what: &str) -> String {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{what}: {:?}\n{err}", out.status);
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn info_on_512_cubed_under_an_address_space_limit() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(format!("ball_{N}x{N}x{N}_uint8.raw"));
    write_volume(&path);
    let v = crate::limits_util::info_within(&path, AS_LIMIT, (N * N * N) as u64);
    assert_eq!(v["dims"], serde_json::json!([N, N, N]), "{v}");
}

#[test]
fn optimize_on_512_cubed_under_an_address_space_limit() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(format!("ball_{N}x{N}x{N}_uint8.raw"));
    write_volume(&path);
    let out_dir = dir.path().join("out");
    check(
        t2tf()
            .env("XDG_CACHE_HOME", dir.path())
            .arg("optimize")
            .arg(&path)
            .args(["--model", MODEL, "--tokenizer", TOKENIZER])
            .args(["--prompt", "a ball", "--steps", "2", "--threads", "1"])
            .args(["--render-size", "64", "--progress", "json", "--out"])
            .arg(&out_dir)
            .output()
            .unwrap(),
        "optimize",
    );
    let report = std::fs::read_to_string(out_dir.join("report.json")).unwrap();
    let report: serde_json::Value = serde_json::from_str(&report).unwrap();
    assert_eq!(report["steps_run"], 2, "{report}");
    assert_eq!(
        report["volume"]["dims"],
        serde_json::json!([N, N, N]),
        "{report}"
    );
    // The preview drew the ball: not one flat colour.
    let preview = t2tf::image::Image::load_png(&out_dir.join("preview.png")).unwrap();
    let first = &preview.data[..3];
    assert!(
        preview.data.chunks_exact(3).any(|px| px != first),
        "preview.png is one colour"
    );
}
