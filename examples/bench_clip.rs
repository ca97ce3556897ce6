//! CLIP speed benchmark with ViT-B/32 shapes and random weights made here (timings do not
//! depend on values):
//!   1. GEMM microbenchmark of the shapes the model runs, in GFLOPS, against the peak measured
//!      in the same run (large square product), f32 and f16;
//!   2. image encoder forward + input backward for a batch of 3 views at 224²;
//!   3. text encoder for 128 typical short captions;
//!   4. reduced precision: embedding and gradient error when weights are rounded to bf16 / f16.
//!
//! Run from the repository root (the tokenizer is read from ../shared/data/clip):
//!     cargo run --release --example bench_clip [-- --reps N] [--engine packed|crate] [--image-only]

use std::path::Path;
use std::time::Instant;

use gemm::Parallelism;
use t2tf::clip::matmul::{matmul, Mat, Op};
use t2tf::clip::packed::{self, Engine};
use t2tf::clip::{
    cosine_grad, Clip, ClipConfig, ClipError, ClipTokenizer, RandomSource, TensorSource,
};
use t2tf::image::Image;

/// CPU seconds (user + system, all threads) this process has used so far, from
/// /proc/self/stat (clock ticks of 1/100 s). On a machine shared with other jobs, CPU time /
/// threads estimates what the wall time would be on an idle machine (an upper bound: idle
/// rayon workers spin a little).
fn cpu_seconds() -> f64 {
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

/// GFLOPS of the same product with B packed once beforehand (`clip::packed`, what `Linear`
/// does with its weights at load time); `bt` only changes how B is given, not the packed copy.
fn packed_gflops(m: usize, n: usize, k: usize, reps: usize) -> f64 {
    let a = vec![0.5f32; m * k];
    let b = packed::PackedB::from_rows(&vec![0.25f32; k * n], k, n);
    let mut c = vec![0.0f32; m * n];
    let (best, _) = time_reps(reps, || {
        packed::gemm(&mut c, n, &a, k, m, &b, 0..k, 0..n, None, false)
    });
    2.0 * (m * n * k) as f64 / best / 1e9
}

fn gemm_f16_gflops(m: usize, n: usize, k: usize, reps: usize) -> f64 {
    use gemm::f16;
    let a = vec![f16::from_f32(0.5); m * k];
    let b = vec![f16::from_f32(0.25); k * n];
    let mut c = vec![f16::from_f32(0.0); m * n];
    let threads = rayon::current_num_threads();
    let (best, _) = time_reps(reps, || unsafe {
        // SAFETY: row-major m×k, k×n and m×n buffers of exactly these sizes.
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            n as isize,
            false,
            a.as_ptr(),
            1,
            k as isize,
            b.as_ptr(),
            1,
            n as isize,
            f16::from_f32(1.0),
            f16::from_f32(1.0),
            false,
            false,
            false,
            Parallelism::Rayon(threads),
        )
    });
    2.0 * (m * n * k) as f64 / best / 1e9
}

/// A tensor source that rounds another's values through a 16-bit float format.
struct Rounded<'a> {
    inner: &'a dyn TensorSource,
    bf16: bool,
}

impl TensorSource for Rounded<'_> {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        let v = self.inner.tensor(name, shape)?;
        Ok(if self.bf16 {
            v.into_iter()
                .map(|x| half::bf16::from_f32(x).to_f32())
                .collect()
        } else {
            v.into_iter()
                .map(|x| half::f16::from_f32(x).to_f32())
                .collect()
        })
    }
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
    let reps: usize = std::env::args()
        .skip_while(|a| a != "--reps")
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(5);
    let threads = rayon::current_num_threads();
    // `--image-only`: just the image forward + backward loop (for profilers), no GEMM table,
    // text or precision sections.
    let image_only = std::env::args().any(|a| a == "--image-only");
    let engine = match std::env::args()
        .skip_while(|a| a != "--engine")
        .nth(1)
        .as_deref()
    {
        None => Engine::detect(),
        Some("packed") => Engine::Packed,
        Some("crate") => Engine::Crate,
        Some(e) => return Err(format!("--engine {e}: expected packed or crate").into()),
    };
    println!("threads: {threads}, reps: {reps} (best / median of reps after one warm-up)");

    // 1. GEMM microbenchmark.
    let peak = if image_only {
        f64::NAN
    } else {
        [
            gemm_gflops(2048, 2048, 2048, false, 3),
            gemm_gflops(1536, 1536, 1536, false, 3),
        ]
        .into_iter()
        .fold(0.0, f64::max)
    };
    println!("\nGEMM peak (2048³ / 1536³ best): {peak:.0} GFLOPS f32");
    println!(
        "| shape m×k · (n×k)ᵀ | use | GFLOPS f32 gemm | % of peak | GFLOPS f32 packed | % of peak | GFLOPS f16 gemm |"
    );
    println!("|---|---|---|---|---|---|---|");
    // bt: the weight is the right operand as stored in the checkpoint ([out, in], transposed);
    // otherwise it is untransposed. `Linear` picks the faster layout (see clip/layers.rs).
    let shapes: [(usize, usize, usize, bool, &str); 11] = [
        (150, 2304, 768, true, "ViT qkv fwd"),
        (150, 768, 768, true, "ViT out-proj fwd"),
        (150, 3072, 768, true, "ViT fc1 fwd"),
        (
            150,
            768,
            3072,
            true,
            "ViT fc2 fwd, checkpoint layout (not used)",
        ),
        (150, 768, 3072, false, "ViT fc2 fwd, Wᵀ stored (used)"),
        (150, 768, 2304, false, "ViT qkv bwd (dy·W)"),
        (150, 3072, 768, true, "ViT fc2 bwd (dy·W, Wᵀ stored)"),
        (150, 768, 3072, false, "ViT fc1 bwd (dy·W)"),
        (147, 768, 3072, false, "patch embedding (Wᵀ stored)"),
        (1137, 2048, 512, true, "text fc1 (128 captions)"),
        (1137, 512, 2048, false, "text fc2 (Wᵀ stored)"),
    ];
    for (m, n, k, bt, what) in shapes.into_iter().filter(|_| !image_only) {
        let g = gemm_gflops(m, n, k, bt, reps.max(5));
        let gp = packed_gflops(m, n, k, reps.max(5));
        let g16 = gemm_f16_gflops(m, n, k, 3);
        println!(
            "| {m}×{k} · {k}×{n} | {what} | {g:.0} | {:.0} % | {gp:.0} | {:.0} % | {g16:.0} |",
            100.0 * g / peak,
            100.0 * gp / peak
        );
    }

    // 2. Image encoder, forward + backward, 3 views: the engine of this machine
    // (`packed::Engine::detect()`, or `--engine packed|crate`), and unless `--image-only`
    // the other engine too, runs interleaved so that both see the same machine load.
    let cfg = ClipConfig::vit_b32();
    let t = Instant::now();
    let clip = packed::with_engine(engine, || {
        Clip::from_source(cfg.clone(), &RandomSource::new(7))
    })?;
    println!(
        "\nrandom ViT-B/32 built in {:.1} s; engine {engine:?}",
        t.elapsed().as_secs_f64()
    );
    let other = if engine == Engine::Packed {
        Engine::Crate
    } else {
        Engine::Packed
    };
    let clip_other = if image_only {
        None
    } else {
        Some(packed::with_engine(other, || {
            Clip::from_source(cfg.clone(), &RandomSource::new(7))
        })?)
    };
    let s = clip.image_size();
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
    let mut runs = vec![ImageRuns::default(), ImageRuns::default()];
    for rep in 0..=reps {
        let models = std::iter::once(&clip).chain(clip_other.as_ref());
        for (model, runs) in models.zip(&mut runs) {
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
    // The machine is shared: measure the peak again now and compare the image pass with the
    // higher of the two measurements (the conservative choice; both are printed).
    let peak_after = if image_only {
        f64::NAN
    } else {
        gemm_gflops(2048, 2048, 2048, false, 3).max(gemm_gflops(1536, 1536, 1536, false, 3))
    };
    let img_peak = peak.max(peak_after);
    if !image_only {
        println!(
            "GEMM peak again after the image runs: {peak_after:.0} GFLOPS; image % below is of \
             the higher, {img_peak:.0}"
        );
    }
    let names = [
        format!("{engine:?} engine"),
        format!("{other:?} engine, for comparison"),
    ];
    for (r, name) in runs
        .into_iter()
        .zip(names)
        .filter(|(r, _)| !r.tot.is_empty())
    {
        let img_cpu = r.cpu / reps as f64;
        let (fb, fm) = best_and_median(r.fwd);
        let (bb, bm) = best_and_median(r.bwd);
        let (tb, tm) = best_and_median(r.tot);
        println!(
            "ViT-B/32 image, 3 views ({name}): forward {fb:.3} s (median {fm:.3}), backward {bb:.3} s \
             (median {bm:.3}), total {tb:.3} s (median {tm:.3}); {:.1} GFLOP → {:.0} GFLOPS = {:.0} % of peak; \
             CPU {img_cpu:.3} s per run → idle estimate {:.3} s",
            flops / 1e9,
            flops / tb / 1e9,
            100.0 * flops / tb / 1e9 / img_peak,
            img_cpu / threads as f64
        );
    }
    if image_only {
        return Ok(());
    }

    // 3. Text encoder, 128 short captions.
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
    let c0 = cpu_seconds();
    let (tb, tm) = time_reps(reps, || {
        clip.encode_tokens(&ids).expect("text");
    });
    let txt_cpu = (cpu_seconds() - c0) / (reps + 1) as f64;
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
        "text, 128 captions ({tokens} tokens, {:.1} mean): {tb:.3} s (median {tm:.3}), {:.0} GFLOPS; \
         tokenizing them {:.1} ms; CPU {txt_cpu:.3} s per run → idle estimate {:.3} s",
        tokens as f64 / 128.0,
        tflops / tb / 1e9,
        kb * 1e3,
        txt_cpu / threads as f64
    );

    // 4. Reduced precision: the same model with weights rounded to bf16 / f16.
    let (emb32, cache32) = clip.encode_images(&views)?;
    let d: Vec<Vec<f32>> = emb32.iter().map(|e| cosine_grad(e, &target)).collect();
    let g32 = clip.image_backward(&cache32, &d)?;
    let t32 = clip.encode_tokens(&ids[..8])?;
    for bf16 in [true, false] {
        let name = if bf16 { "bf16" } else { "f16" };
        let r = Clip::from_source(
            cfg.clone(),
            &Rounded {
                inner: &RandomSource::new(7),
                bf16,
            },
        )?;
        let (e, c) = r.encode_images(&views)?;
        let g = r.image_backward(&c, &d)?;
        let te = r.encode_tokens(&ids[..8])?;
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
            "{name} weights: image embedding rel err {:.1e}, input gradient rel err {gw:.1e}, text embedding rel err {:.1e}",
            worst(&e, &emb32),
            worst(&te, &t32)
        );
    }
    Ok(())
}
