//! `t2tf info` on a volume larger than memory (issue #15): a synthetic `uint16` raw file of
//! N³ points is written block by block (never held in memory), then summarized as `t2tf info`
//! does (`volume::summarize`), against the time of one plain sequential read of the same file.
//! Prints a Markdown row for BENCHMARKS.md.
//!
//! ```text
//! cargo run --release --example bench_large [-- --n 2048] [--dir DIR] [--keep]
//! ```
//!
//! The default N = 512 (256 MiB) runs in seconds; `--n 2048` is the issue's 16 GiB target.
//! Both timings read the file after it was just written, so a file that fits the page cache
//! is read from memory both times; a larger one from disk both times. Peak memory is the
//! process's high-water mark (`VmHWM`, Linux), which includes the writer's block.

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
        peak_memory().unwrap_or_else(|| "n/a".into())
    );
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

/// The process's peak resident memory (Linux `VmHWM`).
fn peak_memory() -> Option<String> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    Some(line.trim_start_matches("VmHWM:").trim().to_string())
}
