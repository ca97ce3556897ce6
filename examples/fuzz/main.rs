//! A mutation fuzzer for every parser t2tf exposes to files from users: volumes (.vti, .vtk,
//! .raw), transfer functions (.json, .xml, .ct), PNG, CLIP config.json, safetensors and
//! PyTorch checkpoints. Stable Rust (no cargo-fuzz, which needs nightly): inputs are test
//! fixtures mutated at random (bit flips, interesting bytes, chunk copies and deletions,
//! truncation, digit runs replaced by huge or negative numbers), each run under
//! `catch_unwind` in a process whose address space is capped, so a panic or an allocation
//! abort is a finding. Inputs whose outcome differs from every earlier one (a coarse stand-in
//! for coverage: the error's words) join the corpus; `--save-corpus` writes them to
//! tests/fuzz_corpus/TARGET/, which tests/volume/fuzz_replay.rs replays in CI.
//!
//! The `*_large` targets start from presets of 10⁶ points made in code (too large to commit)
//! and read them as `optimize --init` does.
//!
//! ```sh
//! cargo run --release --example fuzz -- vti --iterations 1000000
//! cargo run --release --example fuzz -- --all --iterations 20000 --save-corpus
//! ```

mod targets;

use std::collections::HashSet;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use targets::{corpus_dir, signature, Target, TARGETS};

/// At most this many corpus files are kept per target (CI replays them all).
const MAX_CORPUS: usize = 48;

struct Options {
    targets: Vec<&'static Target>,
    iterations: u64,
    seed: u64,
    memory_mib: u64,
    save_corpus: bool,
}

fn parse_args() -> Result<Options> {
    let mut o = Options {
        targets: Vec::new(),
        iterations: 10_000,
        seed: 1,
        memory_mib: 4096,
        save_corpus: false,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |flag: &str| args.next().with_context(|| format!("{flag} needs a value"));
        match a.as_str() {
            "--all" => o.targets = TARGETS.iter().collect(),
            "--iterations" => o.iterations = value("--iterations")?.parse()?,
            "--seed" => o.seed = value("--seed")?.parse()?,
            "--memory-mib" => o.memory_mib = value("--memory-mib")?.parse()?,
            "--save-corpus" => o.save_corpus = true,
            name => match targets::target(name) {
                Some(t) => o.targets.push(t),
                None => {
                    let names: Vec<&str> = TARGETS.iter().map(|t| t.name).collect();
                    bail!(
                        "unknown target {name:?}; targets: {}, or --all",
                        names.join(", ")
                    )
                }
            },
        }
    }
    if o.targets.is_empty() {
        bail!("name a target or --all (usage in examples/fuzz/main.rs)");
    }
    Ok(o)
}

/// Cap the address space, so a parser that believes a header's size aborts here (a finding)
/// rather than take the machine's memory. Unix only: Windows has no such limit.
#[cfg(not(unix))]
fn cap_memory(_mib: u64) {}

/// Cap the address space, so a parser that believes a header's size aborts here (a finding)
/// rather than take the machine's memory.
#[cfg(unix)]
fn cap_memory(mib: u64) {
    let bytes = mib.saturating_mul(1 << 20);
    let lim = libc::rlimit {
        rlim_cur: bytes,
        rlim_max: bytes,
    };
    // SAFETY: setrlimit reads the struct we pass; no memory is shared.
    unsafe { libc::setrlimit(libc::RLIMIT_AS, &lim) };
}

fn mutate(input: &mut Vec<u8>, others: &[Vec<u8>], rng: &mut ChaCha8Rng) {
    const INTERESTING: [u8; 8] = [0, 1, 0x7f, 0x80, 0xff, b'-', b'9', b'"'];
    for _ in 0..rng.random_range(1..=4) {
        let len = input.len();
        match rng.random_range(0..8) {
            0 if len > 0 => {
                let i = rng.random_range(0..len);
                input[i] ^= 1 << rng.random_range(0..8);
            }
            1 if len > 0 => {
                let i = rng.random_range(0..len);
                input[i] = INTERESTING[rng.random_range(0..INTERESTING.len())];
            }
            2 if len > 1 => {
                // Delete a chunk.
                let a = rng.random_range(0..len);
                let b = (a + rng.random_range(1..=64)).min(len);
                input.drain(a..b);
            }
            3 if len > 1 => {
                // Copy a chunk elsewhere.
                let a = rng.random_range(0..len);
                let b = (a + rng.random_range(1..=64)).min(len);
                let chunk = input[a..b].to_vec();
                let at = rng.random_range(0..=input.len());
                input.splice(at..at, chunk);
            }
            4 if len > 0 => input.truncate(rng.random_range(0..len)),
            5 => {
                // A run of digits becomes a huge, negative or zero number.
                let digits: Vec<usize> = (0..len).filter(|&i| input[i].is_ascii_digit()).collect();
                if let Some(&i) = digits.get(rng.random_range(0..digits.len().max(1))) {
                    let j = (i..len)
                        .find(|&j| !input[j].is_ascii_digit())
                        .unwrap_or(len);
                    let pick = [
                        "0",
                        "-1",
                        "4294967296",
                        "18446744073709551615",
                        "1e308",
                        "99999999999",
                    ];
                    let with = pick[rng.random_range(0..pick.len())].as_bytes().to_vec();
                    input.splice(i..j, with);
                }
            }
            6 if !others.is_empty() => {
                // Splice in a piece of another input.
                let o = &others[rng.random_range(0..others.len())];
                if !o.is_empty() {
                    let a = rng.random_range(0..o.len());
                    let b = (a + rng.random_range(1..=256)).min(o.len());
                    let at = rng.random_range(0..=input.len());
                    input.splice(at..at, o[a..b].iter().copied());
                }
            }
            _ if len >= 4 => {
                // Overwrite 4 bytes with a little-endian extreme (sizes and offsets in binary
                // headers).
                let i = rng.random_range(0..=len - 4);
                let v: u32 = [0, u32::MAX, 0x7fff_ffff, 0x8000_0000][rng.random_range(0..4)];
                input[i..i + 4].copy_from_slice(&v.to_le_bytes());
            }
            _ => input.push(rng.random()),
        }
    }
}

/// Run one input through a target; a panic becomes `Err("PANIC: …")`.
fn run_one(t: &Target, file: &Path, bytes: &[u8]) -> (Result<(), String>, bool) {
    if std::fs::write(file, bytes).is_err() {
        return (Err("cannot write the input file".into()), false);
    }
    match catch_unwind(AssertUnwindSafe(|| (t.run)(file))) {
        Ok(r) => (r, false),
        Err(p) => {
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            (Err(format!("PANIC: {msg}")), true)
        }
    }
}

struct Summary {
    executions: u64,
    seconds: f64,
    signatures: usize,
    panics: usize,
    saved: usize,
}

fn fuzz(t: &Target, o: &Options, root: &Path, work: &Path) -> Result<Summary> {
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed ^ t.name.len() as u64);
    let mut corpus: Vec<Vec<u8>> = Vec::new();
    for s in t.seeds {
        corpus.push(std::fs::read(root.join(s)).with_context(|| format!("seed {s}"))?);
    }
    corpus.extend(t.generated.map(|make| make()));
    let dir = corpus_dir(root, t);
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for e in entries.flatten() {
            corpus.push(std::fs::read(e.path())?);
        }
    }
    let file = work.join(t.file_name);
    let mut seen: HashSet<String> = HashSet::new();
    let mut panics = 0;
    let mut saved = 0;
    let start = Instant::now();
    for i in 0..o.iterations {
        let mut input = corpus[rng.random_range(0..corpus.len())].clone();
        mutate(&mut input, &corpus, &mut rng);
        let (outcome, panicked) = run_one(t, &file, &input);
        let sig = signature(&outcome);
        if panicked {
            panics += 1;
            let p = work.join(format!("crash-{}-{i}", t.name));
            std::fs::write(&p, &input)?;
            eprintln!(
                "{}: PANIC at execution {i}, input saved to {}: {sig}",
                t.name,
                p.display()
            );
        }
        if seen.insert(sig) {
            if corpus.len() < 4096 {
                corpus.push(input.clone());
            }
            if o.save_corpus && saved < MAX_CORPUS && !panicked {
                std::fs::create_dir_all(&dir)?;
                std::fs::write(dir.join(format!("{:06}", saved)), &input)?;
                saved += 1;
            }
        }
    }
    Ok(Summary {
        executions: o.iterations,
        seconds: start.elapsed().as_secs_f64(),
        signatures: seen.len(),
        panics,
        saved,
    })
}

fn main() -> Result<()> {
    let o = parse_args()?;
    cap_memory(o.memory_mib);
    // Panics are findings, reported once each by `run_one`, not printed by the default hook.
    std::panic::set_hook(Box::new(|_| {}));
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let work = tempfile::tempdir()?;
    println!("| target | executions | seconds | exec/s | outcomes | panics | corpus saved |");
    println!("|---|---|---|---|---|---|---|");
    let mut total_panics = 0;
    for t in &o.targets {
        if o.save_corpus {
            // A fresh corpus per run: the files written are this run's distinct outcomes.
            let _ = std::fs::remove_dir_all(corpus_dir(&root, t));
        }
        let s = fuzz(t, &o, &root, work.path())?;
        total_panics += s.panics;
        println!(
            "| {} | {} | {:.1} | {:.0} | {} | {} | {} |",
            t.name,
            s.executions,
            s.seconds,
            s.executions as f64 / s.seconds.max(1e-9),
            s.signatures,
            s.panics,
            s.saved
        );
    }
    if total_panics > 0 {
        bail!("{total_panics} panics (inputs saved in the temporary folder named above)");
    }
    Ok(())
}
