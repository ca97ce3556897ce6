//! Benchmark of the whole optimization (Algorithm 1, the paper's defaults) with ViT-B/32-shaped
//! random CLIP weights made here (speed does not depend on the values) on the 256³ aneurism:
//!   1. wall and CPU time per phase of the default run (300 steps × 3 views, seed 0);
//!   2. speed against error: other settings against that default run with the same seed. Error
//!      is (a) the TF distance, RMS over the normalized range of the ParaView opacity (the
//!      exported unit distance) and of the colour, and (b) the PSNR of renders of the final TF
//!      from four held-out views (never sampled by the loop: fixed yaws at pitch 0.1, white
//!      background, default render options) against the default run's renders.
//!
//! The loop is `optimize::initialize` + `optimize::optimize` on the real renderer, CLIP and TF
//! adapters, exactly what `t2tf optimize` runs; the caption pool (the built-in one) is encoded
//! once and shared by all rows, as the on-disk cache makes it for repeated CLI runs.
//!
//! Run from the repository root (volume and tokenizer are read from ../shared/data):
//!     cargo run --release --features bench --example bench_optimize -- [FLAGS]
//! Flags (the full table is CPU heavy; run subsets):
//!     --steps-list 50,100,200,300   steps of the steps × views grid (default: this list)
//!     --views-list 1,3              views of the grid (default: this list)
//!     --step-sizes 2                extra rows at the default steps/views with this render step
//!     --levels 1                    extra rows at the default steps/views on this mip level
//!     --render-sizes 160            extra rows casting rays at this image side (upsampled to
//!                                   CLIP's 224; the "image precision" of the table)
//!     --runs "steps=100,views=1,step=2;seed=1"   extra rows, any of steps, views, step,
//!                                   level, render, seed, lr (unset keys keep the defaults)
//!     --no-grid                     skip the steps × views grid
//!     --quick                       a smoke test: reference 20 steps × 1 view, one 10-step row
//!     --steps N                     the default run with N steps instead of the paper's 300
//!                                   (error measurements on a busy machine)
//!     --threads N                   rayon threads (default: rayon's choice)
//!     --out DIR                     write the held-out renders of every row as PNGs
//!     --reference-tf FILE           save the default run's TF there, or, if FILE exists, read
//!                                   it instead of running the default again
//!     --precision f32|bf16|auto     CLIP's precision, as `t2tf optimize --precision` (default
//!                                   f32); the pool's embeddings are cached per precision
//!     --copies 1|2                  packed copies of each image-tower weight (default: what
//!                                   `t2tf optimize` keeps on this CPU, `Compute::prefers_one_copy`)
//!     --compare-tfs A.json B.json   no optimization: the distance between two saved TFs
//!                                   (`--reference-tf` files of two runs, e.g. f32 and bf16, or
//!                                   1 and 2 threads): opacity and colour RMS and the PSNR of
//!                                   B's held-out renders against A's
//!
//! Timings on a shared machine are noisy: the CPU column (user + system of this process,
//! from /proc) divided by the thread count estimates the wall time on an idle machine.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use t2tf::camera::UpAxis;
use t2tf::clip::packed::Precision;
use t2tf::clip::{Clip, ClipConfig, ClipTokenizer, Compute, RandomSource};
use t2tf::image::Image;
use t2tf::optimize::adapters::{ClipModel, PaperTf, VolumeRenderer};
use t2tf::optimize::captions::{self, CaptionPool};
use t2tf::optimize::{
    initialize, optimize, PhaseTimes, Problem, Renderer, Settings, Targets, View,
};
use t2tf::render::RenderOptions;
use t2tf::tf::{default_unit_distance, sigma_to_opacity, ControlPoints};
use t2tf::volume::{ByteOrder, Geometry, ScalarType, TypedBuffer, Volume};

/// LUT entries, as `t2tf optimize` uses.
const LUT_SIZE: usize = 256;
const PROMPT: &str = "a CT angiography of blood vessels";
const HELD_OUT: usize = 4;

/// CPU seconds (user + system, all threads) of this process, from /proc/self/stat.
// bench_clip's `cpu_seconds` falls back to this; it reads schedstat first for sub-tick precision,
// which a run of minutes does not need (and schedstat misses threads that have exited).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    // rest[0] is field 3 (state), so utime (field 14) is rest[11] and stime rest[12].
    let f: Vec<&str> = rest.split_whitespace().collect();
    let field = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok());
    match (field(11), field(12)) {
        (Some(u), Some(s)) => (u + s) / 100.0,
        _ => f64::NAN,
    }
}

fn load_avg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

/// One row of the table: the settings that differ from the default run.
#[derive(Clone, Debug, PartialEq)]
struct Row {
    steps: usize,
    views: usize,
    step: f32,
    level: Option<usize>,
    /// Ray-casting image side (`VolumeRenderer::render_size`); None = CLIP's input size.
    render: Option<usize>,
    seed: u64,
    lr: f64,
}

impl Row {
    fn default_run() -> Row {
        let s = Settings::default();
        Row {
            steps: s.steps,
            views: s.views,
            step: t2tf::render::DEFAULT_STEP,
            level: None,
            render: None,
            seed: s.seed,
            lr: s.lr,
        }
    }

    /// `key=value` pairs separated by ',' over the default run.
    fn parse(spec: &str) -> Result<Row, String> {
        let mut r = Row::default_run();
        for kv in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (k, v) = kv
                .split_once('=')
                .ok_or_else(|| format!("--runs: '{kv}' is not key=value"))?;
            let bad = |e: &dyn std::fmt::Display| format!("--runs: {k}={v}: {e}");
            match k {
                "steps" => r.steps = v.parse().map_err(|e| bad(&e))?,
                "views" => r.views = v.parse().map_err(|e| bad(&e))?,
                "step" => r.step = v.parse().map_err(|e| bad(&e))?,
                "level" => r.level = Some(v.parse().map_err(|e| bad(&e))?),
                "render" => r.render = Some(v.parse().map_err(|e| bad(&e))?),
                "seed" => r.seed = v.parse().map_err(|e| bad(&e))?,
                "lr" => r.lr = v.parse().map_err(|e| bad(&e))?,
                _ => return Err(format!("--runs: unknown key '{k}'")),
            }
        }
        Ok(r)
    }

    fn settings(&self) -> Settings {
        Settings {
            steps: self.steps,
            views: self.views,
            seed: self.seed,
            lr: self.lr,
            ..Settings::default()
        }
    }

    fn options(&self) -> RenderOptions {
        RenderOptions {
            step: self.step,
            level: self.level,
            ..RenderOptions::default()
        }
    }

    fn label(&self) -> String {
        let level = self.level.map_or("auto".into(), |l| l.to_string());
        let render = self.render.map_or("224 (CLIP)".into(), |r| r.to_string());
        format!(
            "| {} | {} | {} | {} | {} | {} | {} |",
            self.steps, self.views, self.step, level, render, self.lr, self.seed
        )
    }
}

/// What one run gives.
struct Result1 {
    cp: ControlPoints,
    times: PhaseTimes,
    wall: f64,
    cpu: f64,
    final_clip: f64,
    held_out: Vec<Image>,
}

fn list<T: std::str::FromStr>(args: &[String], flag: &str) -> Result<Option<Vec<T>>, String> {
    let Some(i) = args.iter().position(|a| a == flag) else {
        return Ok(None);
    };
    let v = args
        .get(i + 1)
        .ok_or_else(|| format!("{flag} needs a value"))?;
    v.split(',')
        .map(|s| s.trim().parse::<T>())
        .collect::<Result<Vec<T>, _>>()
        .map(Some)
        .map_err(|_| format!("{flag}: cannot parse '{v}'"))
}

/// Held-out views (`t2tf::bench::held_out_views`).
fn held_out_views(s: &Settings) -> Vec<View> {
    t2tf::bench::held_out_views(s, HELD_OUT)
}

/// PSNR (dB) of the views pooled: `t2tf::image::psnr` of the views side by side.
fn psnr(a: &[Image], b: &[Image]) -> f64 {
    t2tf::image::psnr(&Image::grid(a, a.len()), &Image::grid(b, b.len()))
}

/// RMS differences of (ParaView opacity at unit distance u, rgb) over 256 values of [0, 1].
fn tf_distance(a: &ControlPoints, b: &ControlPoints, u_over_l: f64) -> (f64, f64) {
    let (la, lb) = (a.to_lut(LUT_SIZE), b.to_lut(LUT_SIZE));
    let (mut so, mut sc) = (0.0, 0.0);
    for (p, q) in la.entries.iter().zip(&lb.entries) {
        let oa = sigma_to_opacity(p[0] as f64, u_over_l, 1.0);
        let ob = sigma_to_opacity(q[0] as f64, u_over_l, 1.0);
        so += (oa - ob).powi(2);
        sc += (1..4).map(|c| ((p[c] - q[c]) as f64).powi(2)).sum::<f64>() / 3.0;
    }
    let n = la.entries.len() as f64;
    ((so / n).sqrt(), (sc / n).sqrt())
}

/// The reference TF as JSON (x, sigma, rgb; f64 round-trips exactly).
fn write_tf(path: &Path, cp: &ControlPoints) -> anyhow::Result<()> {
    let v = serde_json::json!({ "x": cp.x, "sigma": cp.sigma, "rgb": cp.rgb });
    std::fs::write(path, serde_json::to_string(&v)?)
        .map_err(|e| anyhow::anyhow!("{}: cannot write the reference TF: {e}", path.display()))
}

fn read_tf(path: &Path) -> anyhow::Result<ControlPoints> {
    let bad = |what: &str| anyhow::anyhow!("{}: not a reference TF: {what}", path.display());
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read: {e}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| bad(&e.to_string()))?;
    let floats = |key: &str| -> anyhow::Result<Vec<f64>> {
        v[key]
            .as_array()
            .ok_or_else(|| bad(key))?
            .iter()
            .map(|x| x.as_f64().ok_or_else(|| bad(key)))
            .collect()
    };
    let rgb = v["rgb"]
        .as_array()
        .ok_or_else(|| bad("rgb"))?
        .iter()
        .map(|c| {
            let c: Vec<f64> = serde_json::from_value(c.clone()).map_err(|e| bad(&e.to_string()))?;
            <[f64; 3]>::try_from(c).map_err(|_| bad("rgb entries need 3 values"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let (x, sigma) = (floats("x")?, floats("sigma")?);
    if x.len() != sigma.len() || x.len() != rgb.len() || x.len() < 2 {
        return Err(bad("x, sigma and rgb differ in length"));
    }
    Ok(ControlPoints { x, sigma, rgb })
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let has = |f: &str| args.iter().any(|a| a == f);
    let err = |e: String| anyhow::anyhow!(e);
    let quick = has("--quick");
    if let Some(t) = list::<usize>(&args, "--threads").map_err(err)? {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t[0])
            .build_global()?;
    }
    let reference_tf: Option<PathBuf> = args
        .iter()
        .position(|a| a == "--reference-tf")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from);
    let out: Option<PathBuf> = args
        .iter()
        .position(|a| a == "--out")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from);
    let precision = match args.iter().position(|a| a == "--precision") {
        Some(i) => {
            let name = args
                .get(i + 1)
                .ok_or_else(|| err("--precision needs a value".into()))?;
            Precision::resolve(name).map_err(|e| err(format!("--precision: {e}")))?
        }
        None => Precision::F32,
    };
    let copies = list::<usize>(&args, "--copies").map_err(err)?.map(|c| c[0]);
    if copies.is_some_and(|c| c != 1 && c != 2) {
        return Err(err("--copies takes 1 or 2".into()));
    }
    let compare: Option<(PathBuf, PathBuf)> = args
        .iter()
        .position(|a| a == "--compare-tfs")
        .map(|i| match (args.get(i + 1), args.get(i + 2)) {
            (Some(a), Some(b)) => Ok((PathBuf::from(a), PathBuf::from(b))),
            _ => Err(err("--compare-tfs needs two TF files".into())),
        })
        .transpose()?;

    // The rows: the default run first (the reference), then the grid and the extra rows.
    let mut reference = Row::default_run();
    let mut rows = Vec::new();
    if quick {
        reference.steps = 20;
        reference.views = 1;
        rows.push(Row {
            steps: 10,
            ..reference.clone()
        });
    } else if let Some(n) = list::<usize>(&args, "--steps").map_err(err)? {
        reference.steps = n[0];
    }
    if !quick && !has("--no-grid") {
        let steps = list::<usize>(&args, "--steps-list")
            .map_err(err)?
            .unwrap_or(vec![50, 100, 200, 300]);
        let views = list::<usize>(&args, "--views-list")
            .map_err(err)?
            .unwrap_or(vec![1, 3]);
        for &v in &views {
            for &s in &steps {
                rows.push(Row {
                    steps: s,
                    views: v,
                    ..Row::default_run()
                });
            }
        }
    }
    for s in list::<f32>(&args, "--step-sizes")
        .map_err(err)?
        .unwrap_or_default()
    {
        rows.push(Row {
            step: s,
            ..reference.clone()
        });
    }
    for r in list::<usize>(&args, "--render-sizes")
        .map_err(err)?
        .unwrap_or_default()
    {
        rows.push(Row {
            render: Some(r),
            ..reference.clone()
        });
    }
    for l in list::<usize>(&args, "--levels")
        .map_err(err)?
        .unwrap_or_default()
    {
        rows.push(Row {
            level: Some(l),
            ..reference.clone()
        });
    }
    if let Some(i) = args.iter().position(|a| a == "--runs") {
        let spec = args
            .get(i + 1)
            .ok_or_else(|| err("--runs needs a value".into()))?;
        for r in spec.split(';').filter(|s| !s.trim().is_empty()) {
            rows.push(Row::parse(r).map_err(err)?);
        }
    }
    rows.retain(|r| *r != reference);

    // Volume, model, text side.
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let path = root.join("data/volumes/aneurism_256x256x256_uint8.raw");
    let bytes = std::fs::read(&path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the volume: {e}", path.display()))?;
    let geometry = Geometry {
        dims: [256; 3],
        spacing: [1.0; 3],
        origin: [0.0; 3],
    };
    let volume = Volume::from_buffer(
        &path,
        geometry,
        &TypedBuffer::new(ScalarType::U8, ByteOrder::Little, bytes),
    )?;
    let cfg = ClipConfig::vit_b32();
    let context = cfg.text.max_positions;
    if let Some((a, b)) = &compare {
        return compare_tfs(&volume, a, b);
    }
    let compute = Compute::new(precision);
    let one_copy = copies.map_or(compute.prefers_one_copy(), |c| c == 1);
    let compute = compute.with_one_copy(one_copy);
    let mut clip = Clip::from_source_with(cfg, &RandomSource::new(7), compute)?;
    clip.set_tokenizer(ClipTokenizer::from_file(
        &root.join("data/clip/tokenizer.json"),
        context,
    )?);
    let threads = rayon::current_num_threads();
    println!(
        "rayon threads: {threads}; ViT-B/32 random weights (seed 7); 256³ aneurism; prompt \"{PROMPT}\"; load average at start {}",
        load_avg()
    );
    // `describe` names the kernel, the precision and the CPU's features.
    println!(
        "CLIP: {}; image tower weights: {}",
        clip.compute().describe(),
        if one_copy { "one copy" } else { "two copies" }
    );

    let pool = CaptionPool::builtin();
    let user = captions::user_negatives(&[])?;
    let (t0, c0) = (Instant::now(), cpu_seconds());
    let positive = clip.encode_text(&[PROMPT])?.remove(0);
    let user_emb = clip.encode_text(&user.iter().map(String::as_str).collect::<Vec<_>>())?;
    // Cached on disk like the CLI's, keyed by what makes the random weights (not a file hash)
    // and the precision (bf16 embeddings differ from f32 ones); f32's key names no precision,
    // so caches already on disk stay valid. The whole pool is one call: the text tower shares
    // common beginnings across the captions of a call (clip/prefix.rs) and bounds its memory
    // itself.
    let key = match precision {
        Precision::F32 => "bench_optimize: ClipConfig::vit_b32, RandomSource::new(7)".to_string(),
        p => format!(
            "bench_optimize: ClipConfig::vit_b32, RandomSource::new(7), {}",
            p.name()
        ),
    };
    let (pool_emb, cached) = t2tf::bench::cached_embeddings(
        captions::cache_dir().as_deref(),
        key.as_bytes(),
        pool.captions(),
        |c: &[String]| -> anyhow::Result<Vec<Vec<f32>>> {
            let refs: Vec<&str> = c.iter().map(String::as_str).collect();
            Ok(clip.encode_text(&refs)?)
        },
    )?;
    let cached = matches!(cached, captions::CacheOutcome::Hit(_));
    println!(
        "text: prompt + {} negatives + pool of {} captions encoded in {:.1} s wall, {:.1} s CPU ({})",
        user.len(),
        pool.len(),
        t0.elapsed().as_secs_f64(),
        cpu_seconds() - c0,
        if cached { "pool from the on-disk cache" } else { "computed, then cached on disk" }
    );
    let targets = Targets {
        positive: &positive,
        pool: &pool_emb,
        user_negatives: &user_emb,
        logit_scale: clip.logit_scale() as f64,
    };
    let model = ClipModel(&clip);
    let u_over_l = default_unit_distance(&volume.geometry) / volume.geometry.longest_side();

    // Held-out renders always with the default render options, so the error is the TF's.
    let render_held_out = |cp: &ControlPoints| held_out_renders(&volume, clip.image_size(), cp);
    let run = |row: &Row| -> anyhow::Result<Result1> {
        let settings = row.settings().validate()?;
        let renderer = VolumeRenderer {
            backend: t2tf::render::shared_backend(),
            volume: &volume,
            series: None,
            options: row.options(),
            up: UpAxis::Z,
            size: clip.image_size(),
            render_size: row.render.unwrap_or(clip.image_size()),
            jitter: false,
        };
        let tf = PaperTf {
            k: settings.control_points,
            lut_size: LUT_SIZE,
        };
        let (t0, c0) = (Instant::now(), cpu_seconds());
        let ti = Instant::now();
        let (params, found) = initialize(&renderer, &tf, &volume.histogram, &settings)?;
        let init = ti.elapsed().as_secs_f64();
        eprintln!(
            "  init: scale {:.3e}, mean T_N {:.3} (reached {}), {} renders",
            found.scale, found.mean_transmittance, found.reached, found.evaluations
        );
        let stop = AtomicBool::new(false);
        let mut progress = |log: &t2tf::optimize::StepLog, total: usize| {
            if (log.step + 1).is_multiple_of(25) || log.step + 1 == total {
                eprintln!(
                    "  step {}/{total}: loss {:.4}, mean T_N {:.3}, {:.0} s",
                    log.step + 1,
                    log.total,
                    log.mean_transmittance,
                    t0.elapsed().as_secs_f64()
                );
            }
        };
        let problem = Problem {
            renderer: &renderer,
            encoder: &model,
            tf: &tf,
            targets,
            settings: &settings,
        };
        let outcome = optimize(&problem, params, &stop, &mut progress)?;
        let wall = t0.elapsed().as_secs_f64();
        let cpu = cpu_seconds() - c0;
        let cp = &outcome.control_points;
        eprintln!(
            "  final σ at the control points: {:?}",
            cp.sigma
                .iter()
                .map(|s| format!("{s:.2}"))
                .collect::<Vec<_>>()
        );
        let mut times = outcome.times.clone();
        times.init = init;
        let held_out = render_held_out(&outcome.control_points)?;
        let n = outcome.steps.len().clamp(1, 25);
        let final_clip = outcome
            .steps
            .iter()
            .rev()
            .take(n)
            .map(|s| s.clip)
            .sum::<f64>()
            / n as f64;
        Ok(Result1 {
            cp: outcome.control_points,
            times,
            wall,
            cpu,
            final_clip,
            held_out,
        })
    };

    let saved = reference_tf.as_ref().filter(|p| p.exists());
    let (r0, ran) = if let Some(p) = saved {
        let cp = read_tf(p)?;
        println!(
            "\nReference TF read from {} (written by an earlier run of the same default settings)",
            p.display()
        );
        let held_out = render_held_out(&cp)?;
        let r = Result1 {
            cp,
            times: PhaseTimes::default(),
            wall: f64::NAN,
            cpu: f64::NAN,
            final_clip: f64::NAN,
            held_out,
        };
        (r, false)
    } else {
        eprintln!("reference run: {reference:?}");
        let r = run(&reference)?;
        if let Some(p) = &reference_tf {
            write_tf(p, &r.cp)?;
        }
        (r, true)
    };
    if ran {
        let t = &r0.times;
        let steps = reference.steps as f64;
        println!(
            "\n### Default run ({} steps × {} views), load average after it {}\n",
            reference.steps,
            reference.views,
            load_avg()
        );
        println!("| phase | wall (s) | per step (s) | share |");
        println!("|---|---|---|---|");
        let loop_total = t.render + t.clip_forward + t.clip_backward + t.render_backward + t.other;
        for (name, v) in [
            ("initialization (density scale search)", t.init),
            ("render forward", t.render),
            ("CLIP image forward", t.clip_forward),
            ("CLIP image backward", t.clip_backward),
            ("render backward", t.render_backward),
            ("other (loss, TF, SGD)", t.other),
        ] {
            println!(
                "| {name} | {v:.1} | {:.3} | {:.1} % |",
                v / steps,
                100.0 * v / (loop_total + t.init)
            );
        }
        println!(
            "| **total** (init + loop) | **{:.1}** | {:.3} | CPU {:.1} s = {:.1} s on {threads} idle cores |",
            r0.wall,
            r0.wall / steps,
            r0.cpu,
            r0.cpu / threads as f64
        );
    }
    if let Some(d) = &out {
        std::fs::create_dir_all(d)?;
        t2tf::bench::tile(&r0.held_out).save_png(&d.join("reference.png"))?;
    }

    println!(
        "\n### Speed against error (against the default run, same seed; {HELD_OUT} held-out views)\n"
    );
    println!("| steps | views | render step (voxels) | level | render size (px) | lr | seed | wall (s) | CPU (s) | CPU / threads (s) | opacity RMS | colour RMS | PSNR held-out (dB) | CLIP loss (last 25 steps) |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let line = |row: &Row, r: &Result1| {
        let (o, c) = tf_distance(&r.cp, &r0.cp, u_over_l);
        println!(
            "{} {:.1} | {:.1} | {:.1} | {o:.2e} | {c:.2e} | {:.1} | {:.4} |",
            row.label(),
            r.wall,
            r.cpu,
            r.cpu / threads as f64,
            psnr(&r.held_out, &r0.held_out),
            r.final_clip
        );
    };
    if ran {
        line(&reference, &r0);
    }
    for (i, row) in rows.iter().enumerate() {
        eprintln!("row {}/{}: {row:?}", i + 1, rows.len());
        let r = run(row)?;
        line(row, &r);
        if let Some(d) = &out {
            t2tf::bench::tile(&r.held_out).save_png(&d.join(format!("row{}.png", i + 1)))?;
        }
    }
    println!("\nload average at the end: {}", load_avg());
    Ok(())
}

/// `cp` rendered from the held-out views at `size`² with the default render options, so the
/// error the tables print is the TF's, not the run's render settings'.
fn held_out_renders(
    volume: &Volume,
    size: usize,
    cp: &ControlPoints,
) -> anyhow::Result<Vec<Image>> {
    let eval = VolumeRenderer {
        backend: t2tf::render::shared_backend(),
        volume,
        series: None,
        options: RenderOptions::default(),
        up: UpAxis::Z,
        size,
        render_size: size,
        jitter: false,
    };
    let lut = cp.to_lut(LUT_SIZE);
    held_out_views(&Settings::default())
        .iter()
        .map(|v| eval.render(&lut, v).map(|r| r.0))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("held-out render: {e}"))
}

/// `--compare-tfs A B`: how far B's TF is from A's, as the table's error columns measure it.
fn compare_tfs(volume: &Volume, a: &Path, b: &Path) -> anyhow::Result<()> {
    let (ta, tb) = (read_tf(a)?, read_tf(b)?);
    let size = ClipConfig::vit_b32().vision.image_size;
    let render = |cp: &ControlPoints| held_out_renders(volume, size, cp);
    let u_over_l = default_unit_distance(&volume.geometry) / volume.geometry.longest_side();
    let (o, c) = tf_distance(&tb, &ta, u_over_l);
    println!(
        "compare {} against {}: opacity RMS {o:.2e}, colour RMS {c:.2e}, PSNR held-out {:.1} dB",
        b.display(),
        a.display(),
        psnr(&render(&tb)?, &render(&ta)?)
    );
    Ok(())
}
