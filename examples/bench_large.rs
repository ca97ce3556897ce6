//! `t2tf info` on a volume larger than memory: a synthetic `uint16` raw file of
//! N³ points is written block by block (never held in memory), then summarized as `t2tf info`
//! does (`volume::summarize`), against the time of one plain sequential read of the same file.
//! Prints a Markdown row for BENCHMARKS.md.
//!
//! With `--optimize`, it then runs the built `t2tf optimize` on the same file (the tiny test
//! CLIP of tests/fixtures/clip, 20 steps; build the binary first) and reports its wall time
//! and peak resident memory (the child's `ru_maxrss`): the target is ≤ 3 GiB for 2048³.
//!
//! ```text
//! cargo build --release --bin t2tf
//! cargo run --release --features bench --example bench_large [-- --n 2048] [--dir DIR] [--keep] [--optimize]
//! ```
//!
//! The default N = 512 (256 MiB) runs in seconds; `--n 2048` is the 16 GiB target case.
//! Both timings read the file after it was just written, so a file that fits the page cache
//! is read from memory both times; a larger one from disk both times. Peak memory is the
//! process's high-water mark (`VmHWM`, Linux), which includes the writer's block.

#[path = "common/peak_memory.rs"]
mod peak_memory;

use std::io::{Read, Write};
use std::path::PathBuf;
use std::time::Instant;

use t2tf::volume::{self, ReadOptions};

/// Bytes written or read at a time.
const BLOCK: usize = 8 << 20;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let n: usize = value("--n").map_or(Ok(512), |s| s.parse())?;
    let keep = args.iter().any(|a| a == "--keep");
    let tmp = tempfile::tempdir()?;
    let dir = value("--dir").map_or_else(|| tmp.path().to_path_buf(), PathBuf::from);
    let path = dir.join(format!("synthetic_{n}x{n}x{n}_uint16.raw"));

    let t = Instant::now();
    write_volume(&path, n)?;
    let bytes = (n * n * n * 2) as f64;
    eprintln!(
        "wrote {} ({:.1} GiB) in {:.1} s",
        path.display(),
        bytes / (1u64 << 30) as f64,
        t.elapsed().as_secs_f64()
    );

    let t = Instant::now();
    let mut file = std::fs::File::open(&path)?;
    let mut buf = vec![0u8; BLOCK];
    while file.read(&mut buf)? > 0 {}
    let read_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let s = volume::summarize(&path, &ReadOptions::default())?;
    let info_s = t.elapsed().as_secs_f64();
    assert_eq!(s.histogram.iter().sum::<u64>(), (n * n * n) as u64);

    println!("| volume | sequential read (s) | summarize (s) | ratio | peak memory |");
    println!("|---|---|---|---|---|");
    println!(
        "| {n}³ uint16 ({:.1} GiB) | {read_s:.2} | {info_s:.2} | {:.2} | {} |",
        bytes / (1u64 << 30) as f64,
        info_s / read_s,
        peak_memory::peak_kib().map_or_else(|| "n/a".into(), |k| format!("{k} kB"))
    );
    if args.iter().any(|a| a == "--optimize") {
        optimize(&path, &dir, n, bytes)?;
    }
    if keep {
        std::mem::forget(tmp);
    } else {
        std::fs::remove_file(&path).ok();
    }
    Ok(())
}

/// A smooth CT-like field: a ball of rising density in a noisy background, 12 bits.
fn write_volume(path: &std::path::Path, n: usize) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::with_capacity(BLOCK, std::fs::File::create(path)?);
    let c = n as f64 / 2.0;
    let mut row = Vec::with_capacity(2 * n);
    for z in 0..n {
        for y in 0..n {
            row.clear();
            for x in 0..n {
                let d = ((x as f64 - c).powi(2) + (y as f64 - c).powi(2) + (z as f64 - c).powi(2))
                    .sqrt()
                    / c;
                let noise = ((x * 7 + y * 13 + z * 29) % 64) as f64;
                let v = if d < 0.8 { 4095.0 * (1.0 - d) } else { noise };
                row.extend_from_slice(&(v as u16).to_le_bytes());
            }
            out.write_all(&row)?;
        }
    }
    out.flush()
}

/// `t2tf optimize` (tiny CLIP, 20 steps) on `path`; prints its row.
fn optimize(
    path: &std::path::Path,
    dir: &std::path::Path,
    n: usize,
    bytes: f64,
) -> anyhow::Result<()> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    // The binary beside this example's folder (target/release/t2tf).
    let exe = std::env::current_exe()?;
    let bin = exe
        .parent()
        .and_then(|p| p.parent())
        .map(|p| p.join("t2tf"))
        .filter(|b| b.is_file())
        .ok_or_else(|| {
            anyhow::anyhow!("build the binary first: cargo build --release --bin t2tf")
        })?;
    let out = dir.join("bench_large_optimize");
    let t = Instant::now();
    let status = std::process::Command::new(&bin)
        .arg("optimize")
        .arg(path)
        .arg("--model")
        .arg(root.join("tests/fixtures/clip/quick_gelu"))
        .arg("--tokenizer")
        .arg(root.join("../shared/data/clip/tokenizer.json"))
        .args([
            "--prompt",
            "a ball",
            "--steps",
            "20",
            "--progress",
            "json",
            "--out",
        ])
        .arg(&out)
        .env("XDG_CACHE_HOME", dir)
        .stdout(std::process::Stdio::null())
        .status()?;
    let secs = t.elapsed().as_secs_f64();
    anyhow::ensure!(status.success(), "t2tf optimize failed: {status}");
    // SAFETY: getrusage writes into the struct it is given.
    let peak_kib = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut u);
        u.ru_maxrss
    };
    println!();
    println!("| volume | t2tf optimize, tiny CLIP, 20 steps (s) | peak memory |");
    println!("|---|---|---|");
    println!(
        "| {n}³ uint16 ({:.1} GiB) | {secs:.1} | {:.1} MiB |",
        bytes / (1u64 << 30) as f64,
        peak_kib as f64 / 1024.0
    );
    std::fs::remove_dir_all(&out).ok();
    Ok(())
}
