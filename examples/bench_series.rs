//! What a time series costs against one volume of the same size: time per optimizer step and
//! peak memory of `pipeline::optimize_series` on N steps of a 256³ uint8 series, against
//! `pipeline::optimize` on one of its steps, with CLIP of ViT-B/32's shapes and random weights
//! (written to a temporary `model.safetensors` and loaded as a user's model is).
//!
//! The series is the 256³ aneurism of ../shared rolled along x by one voxel per step (step s
//! is the volume translated cyclically by s voxels), written as `.raw` files in a temporary
//! folder (16 MiB a step) or in `--data DIR`, where files already there are reused.
//!
//! Each run is a child process of this one (the program re-executed with `--child`), so that
//! each has its own peak RSS (`common/peak_memory.rs`: Linux's `VmHWM`, n/a elsewhere). A first child embeds
//! the caption pool into the shared caption cache, so neither measured run holds the text
//! tower for the pool. The time per optimizer step is the wall time from the end of the first
//! step to the end of the last, divided by S − 1 (the runs' start, the series' statistics and
//! the final per-step scores are outside it; "run" is the whole call). Loads: steps read from
//! their files during the loop (the run's, with the final scores' pass over every step, in
//! brackets).
//!
//!     cargo run --release --features bench --example bench_series -- [--series 100] [--steps 30]
//!         [--threads N] [--data DIR]
//!
//! `--series` takes a list (`10,100`): one row per length, the files made once for the longest.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use t2tf::optimize::series::SeriesSteps;
use t2tf::pipeline::{self, Event, Job, Model, ModelOptions, Target};
use t2tf::volume::{ReadOptions, Series};

#[path = "common/peak_memory.rs"]
mod peak_memory;
#[path = "common/random_model.rs"]
mod random_model;
use random_model::write_model;

const PROMPT: &str = "a CT angiography of blood vessels";
const SIDE: usize = 256;
const RESULT: &str = "bench_series result:";

fn step_path(dir: &Path, s: usize) -> PathBuf {
    dir.join(format!("aneurism_t{s:04}_{SIDE}x{SIDE}x{SIDE}_uint8.raw"))
}

/// Steps 0..n of the rolled aneurism in `dir`; a file of the right size already there is kept.
fn make_series(dir: &Path, base: &Path, n: usize) -> Result<Vec<PathBuf>> {
    let bytes = std::fs::read(base).with_context(|| {
        format!(
            "{} (the shared volumes beside the repository)",
            base.display()
        )
    })?;
    if bytes.len() != SIDE * SIDE * SIDE {
        bail!("{}: expected {SIDE}³ bytes", base.display());
    }
    let mut made = 0;
    let mut step = vec![0u8; bytes.len()];
    let files = (0..n)
        .map(|s| {
            let path = step_path(dir, s);
            if std::fs::metadata(&path).is_ok_and(|m| m.len() == bytes.len() as u64) {
                return Ok(path);
            }
            for (row, out) in bytes.chunks_exact(SIDE).zip(step.chunks_exact_mut(SIDE)) {
                let k = s % SIDE;
                out[..SIDE - k].copy_from_slice(&row[k..]);
                out[SIDE - k..].copy_from_slice(&row[..k]);
            }
            std::fs::write(&path, &step)?;
            made += 1;
            Ok(path)
        })
        .collect::<Result<Vec<_>>>()?;
    println!(
        "series: {n} steps of {SIDE}³ uint8 in {} ({made} written, {} reused)",
        dir.display(),
        n - made
    );
    Ok(files)
}

/// What a child reports.
struct Measured {
    per_step: f64,
    run: f64,
    peak_kib: u64,
    loop_loads: usize,
    run_loads: usize,
}

/// One run in this process (the child side): `what` is `volume` (the first file), `series`
/// (all files) or `pool` (fill the caption cache: one step on the first file, unmeasured).
fn child(args: &[String]) -> Result<()> {
    let [what, steps, threads, model, cache, files @ ..] = args else {
        bail!("--child WHAT STEPS THREADS MODEL CACHE FILES...");
    };
    let steps: usize = steps.parse()?;
    let threads: usize = threads.parse()?;
    if threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global()?;
    }
    let files: Vec<PathBuf> = files.iter().map(PathBuf::from).collect();
    let model = Model::load(&ModelOptions::new(model.clone()))?;
    let mut job = Job::new(Target::Prompt(PROMPT.into()));
    job.settings.steps = if what == "pool" { 1 } else { steps };
    job.caption_cache = Some(PathBuf::from(cache));
    let job = job.validate()?;
    let keep = job.settings().views + 1;

    let mut marks: Vec<(Instant, usize)> = Vec::new();
    let t0 = Instant::now();
    let (loop_loads, run_loads) = if what == "series" {
        let series = Series::open(&files)?;
        let series_steps = SeriesSteps::open(series, ReadOptions::default(), keep, &mut |_| {})?;
        let mut on_event = |e: Event| {
            if let Event::Step { .. } = e {
                marks.push((Instant::now(), series_steps.loads()));
            }
            ControlFlow::Continue(())
        };
        let r = pipeline::optimize_series(&series_steps, &model, &job, &mut on_event)?;
        let loads = r.report.time_series.as_ref().map_or(0, |t| t.loads);
        (marks.last().map_or(0, |m| m.1), loads)
    } else {
        let volume = pipeline::load_volume(&files[0], &ReadOptions::default())?;
        let mut on_event = |e: Event| {
            if let Event::Step { .. } = e {
                marks.push((Instant::now(), 1));
            }
            ControlFlow::Continue(())
        };
        pipeline::optimize(&volume, &model, &job, &mut on_event)?;
        (1, 1)
    };
    let run = t0.elapsed().as_secs_f64();
    let per_step = match marks.as_slice() {
        [first, .., last] => (last.0 - first.0).as_secs_f64() / (marks.len() - 1) as f64,
        _ => run / steps.max(1) as f64,
    };
    println!(
        "{RESULT} {per_step} {run} {} {loop_loads} {run_loads}",
        peak_memory::peak_kib().unwrap_or(0)
    );
    Ok(())
}

/// Run `what` in a child process and read its result line.
fn measure(
    what: &str,
    steps: usize,
    threads: usize,
    model: &Path,
    cache: &Path,
    files: &[PathBuf],
) -> Result<Measured> {
    let out = Command::new(std::env::current_exe()?)
        .args(["--child", what, &steps.to_string(), &threads.to_string()])
        .arg(model)
        .arg(cache)
        .args(files)
        .output()?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        bail!(
            "the {what} run failed:\n{text}{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let line = text
        .lines()
        .find_map(|l| l.strip_prefix(RESULT))
        .with_context(|| format!("the {what} run printed no result:\n{text}"))?;
    let f: Vec<f64> = line
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let [per_step, run, peak, loop_loads, run_loads] = f[..] else {
        bail!("the {what} run's result: {line}");
    };
    Ok(Measured {
        per_step,
        run,
        peak_kib: peak as u64,
        loop_loads: loop_loads as usize,
        run_loads: run_loads as usize,
    })
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("--child") {
        return child(&args[2..]);
    }
    let (mut lengths, mut steps, mut threads, mut data) = (vec![100usize], 30usize, 0usize, None);
    let mut it = args.iter().skip(1);
    while let Some(a) = it.next() {
        let mut value = || it.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--series" => {
                lengths = value()?
                    .split(',')
                    .map(str::parse)
                    .collect::<Result<_, _>>()?
            }
            "--steps" => steps = value()?.parse()?,
            "--threads" => threads = value()?.parse()?,
            "--data" => data = Some(PathBuf::from(value()?)),
            other => bail!(
                "unknown flag {other} (--series N[,N...], --steps S, --threads N, --data DIR)"
            ),
        }
    }
    if lengths.is_empty() || lengths.contains(&0) || steps == 0 {
        bail!("--series and --steps take positive numbers");
    }
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let tmp = tempfile::tempdir()?;
    let data = data.unwrap_or_else(|| tmp.path().join("series"));
    std::fs::create_dir_all(&data)?;
    let longest = *lengths.iter().max().unwrap_or(&1);
    let files = make_series(
        &data,
        &shared.join("data/volumes/aneurism_256x256x256_uint8.raw"),
        longest,
    )?;
    let model = tmp.path().join("vit-b32-random");
    std::fs::create_dir_all(&model)?;
    write_model(&model, &shared)?;
    let cache = tmp.path().join("cache");
    measure("pool", 1, threads, &model, &cache, &files[..1])?;
    println!(
        "threads {}; CPU: {}; ViT-B/32 shapes, random weights; {steps} optimizer steps, default settings; one child process per row\n",
        if threads > 0 { threads.to_string() } else { format!("{} (rayon's choice)", rayon::current_num_threads()) },
        t2tf::optimize::report::MachineInfo::detect()
            .cpu_model
            .unwrap_or_default()
    );
    let one = measure("volume", steps, threads, &model, &cache, &files[..1])?;
    println!(
        "| input | s per optimizer step | ratio | peak RSS | loads in the loop (run) | run (s) |"
    );
    println!("|---|---|---|---|---|---|");
    // Decimal megabytes; 0 is a system that does not say (`peak_memory`).
    let mb = |kib: u64| match kib {
        0 => "n/a".to_string(),
        k => format!("{:.0} MB", k as f64 * 1024.0 / 1e6),
    };
    println!(
        "| one {SIDE}³ uint8 volume | {:.3} | 1 | {} | — | {:.1} |",
        one.per_step,
        mb(one.peak_kib),
        one.run
    );
    for &n in &lengths {
        let m = measure("series", steps, threads, &model, &cache, &files[..n])?;
        println!(
            "| series of {n} steps | {:.3} | {:.2} | {} | {} ({}) | {:.1} |",
            m.per_step,
            m.per_step / one.per_step,
            mb(m.peak_kib),
            m.loop_loads,
            m.run_loads,
            m.run
        );
    }
    Ok(())
}
