//! CLIP speed benchmark with ViT-B/32 shapes and random weights made here (timings do not
//! depend on values), one row per way of running the weight products that this CPU has — the
//! `gemm` crate and every SIMD micro-kernel of `clip::packed` (f32 and bf16) — all measured in
//! the same run, interleaved, against the f32 GEMM peak measured in that run (the `gemm`
//! crate's best of 2048³ / 1536³, before and after):
//!   1. GEMM microbenchmark of the shapes the model runs, in GFLOPS;
//!   2. image encoder forward + input backward for a batch of 3 views at 224²;
//!   3. text encoder for 128 typical short captions;
//!   4. bf16: embedding and input-gradient error against f32 (relative L2, worst view);
//!   5. the caption pool's first use: the built-in 6,000 negatives (`data/captions.txt`)
//!      tokenized and embedded in one call, as `t2tf optimize` does before its first step when
//!      the on-disk cache has no entry for the model (`--pool`/`--pool-only`, one rep: it is
//!      seconds long), and the same captions in 256-caption calls in file order; the one
//!      call's work (distinct prefixes, FLOP) against a GEMM peak measured right after it.
//!
//! Run from the repository root (the tokenizer is read from ../shared/data/clip):
//!     cargo run --release --features bench --example bench_clip [-- --reps N] [--image-only] [--pool]
//!         [--pool-only] [--only crate|avx2|avx512f|bf16|amx] [--engine packed|crate] [--amx-emulated]
//! `--image-only` runs just the image loop (for profilers); `--pool` adds section 5,
//! `--amx-emulated` adds the AMX path's error in section 4 through its software model (one
//! untimed pass: for CPUs without AMX),
//! `--pool-only` runs only it; `--only` keeps one setup (and `--engine` is `--only` for the
//! detected f32 kernel or the crate).

use std::path::Path;
use std::time::Instant;

use t2tf::bench::{best_kernel, matmul, Mat, Op};
use t2tf::clip::packed::{self, Engine, Kernel, Precision};
use t2tf::clip::{cosine_grad, Clip, ClipConfig, ClipError, ClipTokenizer, Compute, RandomSource};
use t2tf::image::Image;

/// CPU seconds this process's threads have run so far: the sum of the nanosecond run times in
/// /proc/self/task/*/schedstat (the rayon workers live as long as the process), else user +
/// system time from /proc/self/stat (ticks of 1/100 s, too coarse for a 0.1 s product). On a
/// machine shared with other jobs, CPU time / threads estimates the wall time on an idle one
/// (a lower bound where threads wait on each other, an upper one where idle workers spin).
fn cpu_seconds() -> f64 {
    let from_schedstat = std::fs::read_dir("/proc/self/task").ok().and_then(|dir| {
        let mut ns = 0u64;
        let mut any = false;
        for task in dir.flatten() {
            let text = std::fs::read_to_string(task.path().join("schedstat")).ok()?;
            ns += text.split_whitespace().next()?.parse::<u64>().ok()?;
            any = true;
        }
        any.then_some(ns as f64 * 1e-9)
    });
    if let Some(s) = from_schedstat {
        return s;
    }
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    // rest[0] is field 3 (the state letter), so utime is rest[11] and stime rest[12].
    let f: Vec<&str> = rest.split_whitespace().collect();
    let field = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok());
    match (field(11), field(12)) {
        (Some(u), Some(s)) => (u + s) / 100.0,
        _ => f64::NAN,
    }
}

/// Wall times of the image forward, backward and both, and the CPU seconds they used.
#[derive(Default)]
struct ImageRuns {
    fwd: Vec<f64>,
    bwd: Vec<f64>,
    tot: Vec<f64>,
    cpu: f64,
}

fn best_and_median(mut times: Vec<f64>) -> (f64, f64) {
    times.sort_by(f64::total_cmp);
    (times[0], times[times.len() / 2])
}

fn time_reps(reps: usize, mut f: impl FnMut()) -> (f64, f64) {
    f(); // warm-up
    let times = (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .collect();
    best_and_median(times)
}

/// GFLOPS of `C[m×n] = A[m×k] · op(B)`, B stored `[n, k]` (weights) when `bt`.
fn gemm_gflops(m: usize, n: usize, k: usize, bt: bool, reps: usize) -> f64 {
    let a = vec![0.5f32; m * k];
    let b = vec![0.25f32; k * n];
    let mut c = vec![0.0f32; m * n];
    let (bm, op) = if bt {
        (Mat::new(&b, k), Op::T)
    } else {
        (Mat::new(&b, n), Op::N)
    };
    let (best, _) = time_reps(reps, || {
        matmul(&mut c, n, Mat::new(&a, k), Op::N, bm, op, m, n, k, false)
    });
    2.0 * (m * n * k) as f64 / best / 1e9
}

/// The f32 FMA peak of the cores: a loop of independent FMAs on registers only (12 chains, the
/// widest f32 vectors the CPU has), on `threads` threads at once, best of 3. No GEMM reaches it
/// (loads, packing, memory); it is the ceiling against which a GEMM's efficiency reads the
/// same on every machine, where a library's GEMM is a moving yardstick.
fn fma_peak_gflops(threads: usize) -> (f64, &'static str) {
    const ITERS: usize = 20_000_000;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        #[target_feature(enable = "avx512f")]
        unsafe fn zmm(iters: usize) -> f32 {
            let (x, y) = std::hint::black_box((_mm512_set1_ps(0.999), _mm512_set1_ps(1e-3)));
            let mut acc = [_mm512_set1_ps(1.0); 12];
            for _ in 0..std::hint::black_box(iters) {
                for a in acc.iter_mut() {
                    *a = _mm512_fmadd_ps(*a, x, y);
                }
            }
            acc.iter().map(|a| _mm512_reduce_add_ps(*a)).sum()
        }
        #[target_feature(enable = "avx2,fma")]
        unsafe fn ymm(iters: usize) -> f32 {
            let (x, y) = std::hint::black_box((_mm256_set1_ps(0.999), _mm256_set1_ps(1e-3)));
            let mut acc = [_mm256_set1_ps(1.0); 12];
            for _ in 0..std::hint::black_box(iters) {
                for a in acc.iter_mut() {
                    *a = _mm256_fmadd_ps(*a, x, y);
                }
            }
            let mut lanes = [0.0f32; 8];
            acc.iter().fold(0.0, |s, a| {
                _mm256_storeu_ps(lanes.as_mut_ptr(), *a);
                s + lanes.iter().sum::<f32>()
            })
        }
        let (run, width, isa): (fn(usize) -> f32, usize, _) =
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: AVX-512F checked just above.
                (|n| unsafe { zmm(n) }, 16, "AVX-512F zmm")
            } else if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: AVX2 and FMA checked just above.
                (|n| unsafe { ymm(n) }, 8, "AVX2+FMA ymm")
            } else {
                return (f64::NAN, "no FMA");
            };
        let mut best = 0.0f64;
        for _ in 0..3 {
            let t = Instant::now();
            let sum: f32 = std::thread::scope(|s| {
                let hs: Vec<_> = (0..threads).map(|_| s.spawn(|| run(ITERS))).collect();
                hs.into_iter().map(|h| h.join().unwrap_or(0.0)).sum()
            });
            std::hint::black_box(sum);
            let flops = (threads * ITERS * 12 * width * 2) as f64;
            best = best.max(flops / t.elapsed().as_secs_f64() / 1e9);
        }
        (best, isa)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (threads, ITERS);
        (f64::NAN, "not measured on this architecture")
    }
}

/// The f32 GEMM peak of this run: the `gemm` crate's best of 2048³ and 1536³ by wall time,
/// and by CPU time (FLOPs per CPU second × threads, the best rep): on a shared machine the
/// CPU-time figure is what the cores deliver while this process runs, whatever the wall time.
fn peak_gflops(threads: usize) -> (f64, f64) {
    let (mut wall, mut cpu) = (0.0f64, 0.0f64);
    for n in [2048usize, 1536] {
        let a = vec![0.5f32; n * n];
        let b = vec![0.25f32; n * n];
        let mut c = vec![0.0f32; n * n];
        let flops = 2.0 * (n * n * n) as f64;
        for rep in 0..4 {
            let c0 = cpu_seconds();
            let t = Instant::now();
            matmul(
                &mut c,
                n,
                Mat::new(&a, n),
                Op::N,
                Mat::new(&b, n),
                Op::N,
                n,
                n,
                n,
                false,
            );
            let (dt, dc) = (t.elapsed().as_secs_f64(), cpu_seconds() - c0);
            if rep > 0 {
                wall = wall.max(flops / dt / 1e9);
                // CPU time has 10 ms ticks: only trust reps long enough to resolve.
                if dc > 0.05 {
                    cpu = cpu.max(flops / (dc / threads as f64) / 1e9);
                }
            }
        }
    }
    (wall, cpu)
}

/// GFLOPS of the same product with B packed once beforehand for `kernel` (what `Linear`
/// does with its weights at load time), activations packed (bf16: rounded) in the timing.
fn packed_gflops(kernel: Kernel, m: usize, n: usize, k: usize, reps: usize) -> f64 {
    let a = vec![0.5f32; m * k];
    let b = packed::PackedB::from_rows_for(kernel, &vec![0.25f32; k * n], k, n);
    let mut c = vec![0.0f32; m * n];
    let (best, _) = time_reps(reps, || {
        packed::gemm(&mut c, n, &a, k, m, &b, 0..k, 0..n, None, false)
    });
    2.0 * (m * n * k) as f64 / best / 1e9
}

/// One way of running the weight products: the `gemm` crate or a packed micro-kernel.
#[derive(Clone, Copy, PartialEq)]
enum Setup {
    Crate,
    Packed(Kernel),
}

impl Setup {
    fn name(self) -> String {
        match self {
            Setup::Crate => "gemm crate, f32".into(),
            Setup::Packed(k) => format!("packed, {}", k.name()),
        }
    }
    fn short(self) -> &'static str {
        match self {
            Setup::Crate => "crate",
            Setup::Packed(Kernel::Avx2Fma) => "avx2",
            Setup::Packed(Kernel::Avx512F) => "avx512f",
            Setup::Packed(Kernel::Avx512Bf16) => "bf16",
            Setup::Packed(Kernel::Portable) => "portable",
            Setup::Packed(Kernel::PortableBf16) => "portable-bf16",
            Setup::Packed(Kernel::Amx) => "amx",
            Setup::Packed(Kernel::AmxEmulated) => "amx-emulated",
        }
    }
    fn precision(self) -> Precision {
        match self {
            Setup::Crate => Precision::F32,
            Setup::Packed(k) => k.precision(),
        }
    }
    fn build(self, cfg: &ClipConfig) -> Result<Clip, ClipError> {
        let compute = match self {
            Setup::Crate => Compute::default().with_engine(Engine::Crate),
            Setup::Packed(k) => Compute::default().with_kernel(k).ok_or_else(|| {
                ClipError::Missing(format!("kernel {}: not on this CPU", k.name()))
            })?,
        };
        Clip::from_source_with(cfg.clone(), &RandomSource::new(7), compute)
    }
}

/// Every setup this CPU runs, and a line for each one it skips.
fn setups() -> (Vec<Setup>, Vec<String>) {
    let mut run = vec![Setup::Crate];
    let mut skipped = Vec::new();
    for k in Kernel::ALL {
        match (k, k.missing()) {
            (Kernel::Portable | Kernel::PortableBf16 | Kernel::AmxEmulated, _) => {
                skipped.push(format!(
                "{}: scalar reference (tested in tests/clip/clip_kernels.rs, too slow to time here)",
                k.name()
            ))
            }
            (Kernel::Amx, Some(_)) => skipped.push(format!(
                "{}: not run here: {}",
                k.name(),
                packed::amx_status().err().unwrap_or_default()
            )),
            (_, Some(what)) => skipped.push(format!("{}: this CPU lacks {what}", k.name())),
            (_, None) => run.push(Setup::Packed(k)),
        }
    }
    (run, skipped)
}

fn rel_err(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

const ADJ: [&str; 16] = [
    "red",
    "translucent",
    "glowing",
    "white",
    "blue",
    "shiny",
    "dark",
    "golden",
    "soft",
    "bony",
    "metallic",
    "green",
    "orange",
    "foggy",
    "sharp",
    "pale",
];
const NOUN: [&str; 16] = [
    "skull", "engine", "teapot", "foot", "tooth", "fish", "tree", "bonsai", "brain", "heart",
    "lobster", "carp", "chest", "hand", "turbine", "kidney",
];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let arg = |name: &str| std::env::args().skip_while(|a| a != name).nth(1);
    let reps: usize = arg("--reps").map(|s| s.parse()).transpose()?.unwrap_or(5);
    let amx_emulated = std::env::args().any(|a| a == "--amx-emulated");
    let threads = rayon::current_num_threads();
    // `--image-only`: just the image forward + backward loop (for profilers), no GEMM table,
    // text or error sections.
    let image_only = std::env::args().any(|a| a == "--image-only");
    let pool_only = std::env::args().any(|a| a == "--pool-only");
    let pool = pool_only || std::env::args().any(|a| a == "--pool");
    let (mut run, skipped) = setups();
    let only = match arg("--engine").as_deref() {
        None => arg("--only"),
        Some("crate") => Some("crate".to_string()),
        Some("packed") => best_kernel(Precision::F32).map(|k| Setup::Packed(k).short().to_string()),
        Some(e) => return Err(format!("--engine {e}: expected packed or crate").into()),
    };
    if let Some(only) = &only {
        run.retain(|s| s.short() == only);
        if run.is_empty() {
            return Err(format!("--only {only}: not a setup this CPU runs").into());
        }
    }
    println!("threads: {threads}, reps: {reps} (best / median of reps after one warm-up)");
    println!("CPU: {}", packed::cpu_features());
    println!(
        "default (what t2tf builds): {}",
        Compute::default().describe()
    );
    println!(
        "setups timed: {}",
        run.iter().map(|s| s.name()).collect::<Vec<_>>().join("; ")
    );
    for s in &skipped {
        println!("skipped: {s}");
    }
    // What `--precision auto` chooses here, by its own calibration (the setup as the tables
    // name it).
    let auto = Compute::new(Precision::auto())
        .layer_kernel()
        .map_or(Setup::Crate, Setup::Packed);
    match t2tf::clip::bf16_speedup() {
        Some(s) => println!(
            "auto picks: {} (bf16 calibrated at {s:.2}× f32's speed; bf16 needs ≥ {:.2}×)",
            auto.name(),
            t2tf::clip::AUTO_BF16_MIN_SPEEDUP
        ),
        None => println!("auto picks: {} (no bf16 kernel on this CPU)", auto.name()),
    }
    let cfg = ClipConfig::vit_b32();
    if pool_only {
        return pool_first_use(&run, &cfg);
    }

    // 1. GEMM microbenchmark.
    let (peak, peak_cpu) = if image_only {
        (f64::NAN, f64::NAN)
    } else {
        peak_gflops(threads)
    };
    if !image_only {
        println!(
            "\nGEMM peak (gemm crate, 2048³ / 1536³ best): {peak:.0} GFLOPS f32 by wall time, \
             {peak_cpu:.0} by CPU time"
        );
        let mut head = "| shape m×k · (n×k)ᵀ | use |".to_string();
        for s in &run {
            head += &format!(" {} GFLOPS (% of peak) |", s.short());
        }
        println!("{head}");
        println!("|---|---|{}", "---|".repeat(run.len()));
    }
    // bt: the weight is the right operand as stored in the checkpoint ([out, in], transposed);
    // otherwise it is untransposed. `Linear` picks the faster layout for the crate (see
    // clip/layers.rs); packed kernels see the same packed copy either way.
    let shapes: [(usize, usize, usize, bool, &str); 10] = [
        (150, 2304, 768, true, "ViT qkv fwd"),
        (150, 768, 768, true, "ViT out-proj fwd"),
        (150, 3072, 768, true, "ViT fc1 fwd"),
        (150, 768, 3072, false, "ViT fc2 fwd (crate: Wᵀ stored)"),
        (150, 768, 2304, false, "ViT qkv bwd (dy·W)"),
        (150, 3072, 768, true, "ViT fc2 bwd (dy·W; crate: Wᵀ stored)"),
        (150, 768, 3072, false, "ViT fc1 bwd (dy·W)"),
        (147, 768, 3072, false, "patch embedding (crate: Wᵀ stored)"),
        (1137, 2048, 512, true, "text fc1 (128 captions)"),
        (1137, 512, 2048, false, "text fc2 (crate: Wᵀ stored)"),
    ];
    for (m, n, k, bt, what) in shapes.into_iter().filter(|_| !image_only) {
        let mut line = format!("| {m}×{k} · {k}×{n} | {what} |");
        for s in &run {
            let g = match s {
                Setup::Crate => gemm_gflops(m, n, k, bt, reps.max(5)),
                Setup::Packed(kernel) => packed_gflops(*kernel, m, n, k, reps.max(5)),
            };
            line += &format!(" {g:.0} ({:.0} %) |", 100.0 * g / peak);
        }
        println!("{line}");
    }

    // 2. Image encoder, forward + backward, 3 views: every setup, interleaved so that all see
    // the same machine load.
    let t = Instant::now();
    let models: Vec<Clip> = run
        .iter()
        .map(|s| s.build(&cfg))
        .collect::<Result<_, _>>()?;
    println!(
        "\n{} random ViT-B/32 models built in {:.1} s",
        models.len(),
        t.elapsed().as_secs_f64()
    );
    let s = models[0].image_size();
    let views: Vec<Image> = (0..3)
        .map(|v| Image {
            width: s,
            height: s,
            data: (0..s * s * 3)
                .map(|i| ((i * 7 + v * 13) % 256) as f32 / 255.0)
                .collect(),
        })
        .collect();
    let target = vec![0.01f32; cfg.projection_dim];
    let mut runs: Vec<ImageRuns> = run.iter().map(|_| ImageRuns::default()).collect();
    for rep in 0..=reps {
        for (model, runs) in models.iter().zip(&mut runs) {
            let c0 = cpu_seconds();
            let t0 = Instant::now();
            let (emb, cache) = model.encode_images(&views)?;
            let t1 = Instant::now();
            let d: Vec<Vec<f32>> = emb.iter().map(|e| cosine_grad(e, &target)).collect();
            let g = model.image_backward(&cache, &d)?;
            let t2 = Instant::now();
            assert!(g[0].data.iter().all(|v| v.is_finite()));
            if rep > 0 {
                runs.fwd.push((t1 - t0).as_secs_f64());
                runs.bwd.push((t2 - t1).as_secs_f64());
                runs.tot.push((t2 - t0).as_secs_f64());
                runs.cpu += cpu_seconds() - c0;
            }
        }
    }
    let v = &cfg.vision;
    let (b, n, d, i, l) = (3.0, v.num_tokens() as f64, 768.0, 3072.0, 12.0);
    let gp = (v.grid() * v.grid()) as f64;
    // FLOPs actually computed: layers 1..L−1 on all tokens; the last layer projects k, v for
    // all tokens but q, scores, out-proj and MLP for the class tokens only (clip/tower.rs).
    // Backward (input only) repeats every linear product once and attention twice.
    let lin = 2.0 * b * n * (4.0 * d * d + 2.0 * d * i) * (l - 1.0)
        + 2.0 * b * n * 2.0 * d * d
        + 2.0 * b * (2.0 * d * d + 2.0 * d * i)
        + 2.0 * b * gp * 3072.0 * d;
    let att_f = 4.0 * b * n * n * d * (l - 1.0) + 4.0 * b * n * d;
    let flops = 2.0 * lin + att_f + 2.0 * att_f;
    // The machine may be shared: measure the peak again now and compare the image pass with
    // the higher of the two measurements (the conservative choice; both are printed).
    let (peak_after, peak_cpu_after) = if image_only {
        (f64::NAN, f64::NAN)
    } else {
        peak_gflops(threads)
    };
    let img_peak = peak.max(peak_after);
    let img_peak_cpu = peak_cpu.max(peak_cpu_after);
    let peaks = if image_only {
        "GEMM peak not measured (--image-only): no % of peak".to_string()
    } else {
        format!(
            "GEMM peak before {peak:.0}, after {peak_after:.0} GFLOPS: % of the higher, \
             {img_peak:.0} (by CPU time: {peak_cpu:.0} / {peak_cpu_after:.0}, % of \
             {img_peak_cpu:.0})"
        )
    };
    println!(
        "ViT-B/32 image, 3 views at 224², forward + input backward, {:.1} GFLOP; {peaks}",
        flops / 1e9
    );
    println!(
        "| setup | precision | forward best (median) | backward best (median) | fwd+bwd best (median) | \
         GFLOPS | % of peak | CPU s per run (/ threads) | % of peak by CPU time | time vs best f32 | \
         CPU time vs best f32 |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let best_f32 = run
        .iter()
        .zip(&runs)
        .filter(|(s, _)| s.precision() == Precision::F32)
        .map(|(_, r)| r.tot.iter().copied().fold(f64::INFINITY, f64::min))
        .fold(f64::INFINITY, f64::min);
    let best_f32_cpu = run
        .iter()
        .zip(&runs)
        .filter(|(s, _)| s.precision() == Precision::F32)
        .map(|(_, r)| r.cpu / reps as f64)
        .fold(f64::INFINITY, f64::min);
    for (setup, r) in run.iter().zip(runs) {
        let img_cpu = r.cpu / reps as f64;
        let (fb, fm) = best_and_median(r.fwd);
        let (bb, bm) = best_and_median(r.bwd);
        let (tb, tm) = best_and_median(r.tot);
        println!(
            "| {} | {} | {fb:.3} s ({fm:.3}) | {bb:.3} s ({bm:.3}) | **{tb:.3} s** ({tm:.3}) | {:.0} | \
             {} | {img_cpu:.3} ({:.3}) | {} | {:.2}× | {:.2}× |",
            setup.name(),
            setup.precision().name(),
            flops / tb / 1e9,
            percent(flops / tb / 1e9 / img_peak),
            img_cpu / threads as f64,
            percent(flops / (img_cpu / threads as f64) / 1e9 / img_peak_cpu),
            tb / best_f32,
            img_cpu / best_f32_cpu,
        );
    }
    if image_only {
        return Ok(());
    }
    let (fma, isa) = fma_peak_gflops(threads);
    println!(
        "\nFMA peak (registers only, {isa}, {threads} threads): {fma:.0} GFLOPS; the best f32 \
         image pass runs at {:.0} % of it, the GEMM peak above is {:.0} % of it",
        100.0 * flops / best_f32 / 1e9 / fma,
        100.0 * img_peak / fma
    );

    // 3. Text encoder, 128 short captions, with each setup's model.
    let tok_path = Path::new("../shared/data/clip/tokenizer.json");
    let tok = ClipTokenizer::from_file(tok_path, 77)?;
    let captions: Vec<String> = (0..128)
        .map(|k| match k % 4 {
            0 => format!("a {} {}", ADJ[k % 16], NOUN[(k / 4) % 16]),
            1 => format!(
                "a {} {} with {} details",
                ADJ[k % 16],
                NOUN[(k / 3) % 16],
                ADJ[(k / 5) % 16]
            ),
            2 => format!(
                "a volume rendering of a {} {}",
                ADJ[(k / 2) % 16],
                NOUN[k % 16]
            ),
            _ => format!(
                "a {} and {} {} in front of a dark background",
                ADJ[k % 16],
                ADJ[(k / 7) % 16],
                NOUN[(k / 2) % 16]
            ),
        })
        .collect();
    let ids: Vec<Vec<u32>> = captions
        .iter()
        .map(|c| tok.encode(c))
        .collect::<Result<_, _>>()?;
    let tokens: usize = ids.iter().map(Vec::len).sum();
    let (kb, _) = time_reps(reps, || {
        for c in &captions {
            tok.encode(c).expect("tokenize");
        }
    });
    let tc = &cfg.text.tower;
    // Same accounting as above: the last layer does only k, v for all tokens.
    let (td, ti) = (tc.hidden_size as f64, tc.intermediate_size as f64);
    let tflops = 2.0 * tokens as f64 * (4.0 * td * td + 2.0 * td * ti) * 11.0
        + 2.0 * tokens as f64 * 2.0 * td * td
        + 2.0 * 128.0 * (2.0 * td * td + 2.0 * td * ti);
    println!(
        "\ntext, 128 captions ({tokens} tokens, {:.1} mean; tokenizing them {:.1} ms):",
        tokens as f64 / 128.0,
        kb * 1e3
    );
    for (setup, model) in run.iter().zip(&models) {
        let c0 = cpu_seconds();
        let (tb, tm) = time_reps(reps, || {
            model.encode_tokens(&ids).expect("text");
        });
        let txt_cpu = (cpu_seconds() - c0) / (reps + 1) as f64;
        println!(
            "  {}: {tb:.3} s (median {tm:.3}), {:.0} GFLOPS = {:.0} % of peak; CPU {txt_cpu:.3} s per run",
            setup.name(),
            tflops / tb / 1e9,
            100.0 * tflops / tb / 1e9 / img_peak,
        );
    }

    // 4. What bf16 costs in accuracy: each model against the first f32 packed one (or the
    // crate), relative L2 error, worst of the 3 views / 8 captions.
    let reference = run
        .iter()
        .position(|s| Some(*s) == best_kernel(Precision::F32).map(Setup::Packed))
        .unwrap_or(0);
    let (emb32, cache32) = models[reference].encode_images(&views)?;
    let d: Vec<Vec<f32>> = emb32.iter().map(|e| cosine_grad(e, &target)).collect();
    let g32 = models[reference].image_backward(&cache32, &d)?;
    let t32 = models[reference].encode_tokens(&ids[..8])?;
    println!(
        "\nerror against {} (relative L2, worst view / caption):",
        run[reference].name()
    );
    // With `--amx-emulated`, the AMX path's accuracy where the CPU has no AMX: its exact
    // software model, one untimed pass (the emulation is scalar), against the same reference.
    let emulated = if amx_emulated {
        Some(Setup::Packed(Kernel::AmxEmulated).build(&cfg)?)
    } else {
        None
    };
    let rows = run.iter().map(|s| s.name()).zip(&models).chain(
        emulated
            .iter()
            .map(|m| (format!("{} (untimed)", Kernel::AmxEmulated.name()), m)),
    );
    for (name, model) in rows {
        let (e, c) = model.encode_images(&views)?;
        let g = model.image_backward(&c, &d)?;
        let te = model.encode_tokens(&ids[..8])?;
        let worst = |a: &[Vec<f32>], b: &[Vec<f32>]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| rel_err(x, y))
                .fold(0.0, f64::max)
        };
        let gw = g
            .iter()
            .zip(&g32)
            .map(|(x, y)| rel_err(&x.data, &y.data))
            .fold(0.0, f64::max);
        println!(
            "  {name}: image embedding {:.1e}, input gradient {gw:.1e}, text embedding {:.1e}",
            worst(&e, &emb32),
            worst(&te, &t32)
        );
    }
    if pool {
        pool_first_use(&run, &cfg)?;
    }
    Ok(())
}

/// Section 5: the built-in caption pool embedded from scratch with each setup's model, as
/// `t2tf optimize` does on first use of a model (tokenizing included), once in one call and
/// once in 256-caption calls (what `t2tf optimize` did before it made one call). One rep each: seconds long.
fn pool_first_use(run: &[Setup], cfg: &ClipConfig) -> Result<(), Box<dyn std::error::Error>> {
    let pool = t2tf::optimize::captions::CaptionPool::builtin();
    let refs: Vec<&str> = pool.captions().iter().map(String::as_str).collect();
    let tok_path = Path::new("../shared/data/clip/tokenizer.json");
    let batch = 256;
    println!(
        "\ncaption pool first use: {} captions (tokenize + embed; wall, and CPU s / threads):",
        refs.len()
    );
    println!(
        "| setup | one call: wall (CPU / threads) | {batch}-caption calls: wall (CPU / threads) |"
    );
    println!("|---|---|---|");
    let threads = rayon::current_num_threads() as f64;
    let mut one_call = Vec::new();
    for setup in run {
        let mut model = setup.build(cfg)?;
        model.set_tokenizer(ClipTokenizer::from_file(tok_path, cfg.text.max_positions)?);
        let (c0, t0) = (cpu_seconds(), Instant::now());
        let all = model.encode_text(&refs)?;
        let (one_wall, one_cpu) = (t0.elapsed().as_secs_f64(), cpu_seconds() - c0);
        one_call.push((setup.name(), one_wall, one_cpu));
        let (c0, t0) = (cpu_seconds(), Instant::now());
        let mut chunked = Vec::with_capacity(refs.len());
        for c in refs.chunks(batch) {
            chunked.extend(model.encode_text(c)?);
        }
        let (ch_wall, ch_cpu) = (t0.elapsed().as_secs_f64(), cpu_seconds() - c0);
        let worst = all
            .iter()
            .zip(&chunked)
            .map(|(a, b)| rel_err(a, b))
            .fold(0.0, f64::max);
        println!(
            "| {} | {one_wall:.1} s ({:.1} s) | {ch_wall:.1} s ({:.1} s) | (one call vs calls: worst relative difference {worst:.1e})",
            setup.name(),
            one_cpu / threads,
            ch_cpu / threads,
        );
    }
    // The work against the machine's GEMM peak, measured after the pool (the host's speed
    // drifts; the table above is the comparison that holds).
    let tok = ClipTokenizer::from_file(tok_path, cfg.text.max_positions)?;
    let ids = refs
        .iter()
        .map(|c| tok.encode(c))
        .collect::<Result<Vec<_>, _>>()?;
    let (rows, flop) = pool_flop(&ids, cfg);
    let (peak, peak_cpu) = peak_gflops(rayon::current_num_threads());
    println!(
        "pool work: {rows} distinct prefixes, {:.2} TFLOP (weight products and attention, each \
         prefix once); GEMM peak after the pool {peak:.0} GFLOPS ({peak_cpu:.0} by CPU time)",
        flop / 1e12
    );
    for (name, wall, cpu) in one_call {
        let (g, g_cpu) = (flop / wall / 1e9, flop / (cpu / threads) / 1e9);
        println!(
            "  {name}, one call: {g:.0} GFLOPS = {:.0} % of peak ({:.0} % by CPU time)",
            100.0 * g / peak,
            100.0 * g_cpu / peak_cpu
        );
    }
    Ok(())
}

/// Distinct prefixes and floating-point operations of the text forward `Clip::encode_text`
/// runs for `ids` (ViT-B/32's text tower, `eos_token_id` 2: a caption is pooled at its largest
/// id): each prefix of a caption up to its pooled token is one row of every layer but the last,
/// where keys and values run for every row and the rest for the pooled rows only
/// (`clip::prefix`); attention at each row's prefix length; the projection per caption.
/// Each distinct prefix is counted once, the work a single prefix tree would do.
fn pool_flop(ids: &[Vec<u32>], cfg: &ClipConfig) -> (usize, f64) {
    let t = &cfg.text.tower;
    let (d, i) = (t.hidden_size as f64, t.intermediate_size as f64);
    let mut prefixes = std::collections::HashSet::new();
    let mut ends = std::collections::HashSet::new();
    for c in ids {
        let max = c.iter().copied().max().unwrap_or(0);
        let end = c.iter().position(|&v| v == max).unwrap_or(0);
        for n in 1..=end + 1 {
            prefixes.insert(&c[..n]);
        }
        ends.insert(&c[..end + 1]);
    }
    // Per row and layer: q, k, v, out (4 D²) and the MLP (2 D I); attention 2·2·D per key.
    let row = |len: usize| 2.0 * (4.0 * d * d + 2.0 * d * i) + 4.0 * d * len as f64;
    let body = (t.num_layers.saturating_sub(1)) as f64
        * prefixes.iter().map(|p| row(p.len())).sum::<f64>();
    let last_kv = prefixes.len() as f64 * 2.0 * 2.0 * d * d;
    let last_ends: f64 = ends.iter().map(|p| row(p.len()) - 2.0 * 2.0 * d * d).sum();
    let projection = ends.len() as f64 * 2.0 * d * cfg.projection_dim as f64;
    (prefixes.len(), body + last_kv + last_ends + projection)
}

/// A share as "NN %", or "—" where the peak it divides by was not measured.
fn percent(share: f64) -> String {
    if share.is_finite() {
        format!("{:.0} %", 100.0 * share)
    } else {
        "—".to_string()
    }
}
