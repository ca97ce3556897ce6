//! Renderer speed against error. Not a timed test: prints a Markdown table.
//!
//! ```text
//! cargo run --release --features bench --example bench_render [-- --out DIR] [--quick] [--speed]
//!     [--tf FILE] [--evict-mb N]
//! ```
//!
//! `--speed` times the default options only, each TF through both backward paths alternating
//! (the backend's, which replays what its forward recorded, and the front functions', which
//! march every ray again), and the drawing of each background kind. `--tf FILE` adds a TF
//! saved by `bench_optimize --reference-tf FILE` (the optimizer's own); `--evict-mb N` writes
//! N MiB before each forward and each backward, as CLIP's passes do in the optimizer's loop.
//!
//! Volume: `../shared/data/volumes/aneurism_256x256x256_uint8.raw`, and a 512³ trilinear
//! upsampling of it spanning the same box. Three of the paper's random views (seeded) at
//! 224², a noise background, and two TFs: "sparse" (σ = 0 on the empty background value, as a
//! hand-made vessel TF) and "dense" (the same plus σ = 0.5 everywhere, as during optimization,
//! where σ = 255·(tanh p + 1)/2 is never exactly 0 and no brick can be skipped). The loss
//! gradient fed to the backward is a fixed smooth ∂L/∂I and ∂L/∂T_N.
//!
//! Error columns compare against a reference at 1/8-voxel step on level 0 (no early stop):
//! PSNR of the image, and relative L2 of the LUT gradient. "samples" counts what the forward
//! evaluated: trilinear samples plus one per uniform-brick run (skipped samples not counted).

use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use t2tf::background;
use t2tf::camera::{Camera, UpAxis};
use t2tf::image::Image;
use t2tf::render::cpu::CpuPrepared;
use t2tf::render::{self, Backend, CpuBackend, RenderOptions, Rendered, Shot};
use t2tf::tf::{ControlPoints, Lut, LutGrad};
use t2tf::volume::{ByteOrder, Geometry, ScalarType, TypedBuffer, Volume};

#[path = "common/shared_volumes.rs"]
mod shared_volumes;
use shared_volumes::SHARED_VOLUMES;

const SIZE: usize = 224;
const VIEWS: usize = 3;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let out = args
        .iter()
        .position(|a| a == "--out")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from);
    let quick = args.iter().any(|a| a == "--quick");
    let reps = if quick { 1 } else { 5 };

    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/volumes");
    let path = root.join("aneurism_256x256x256_uint8.raw");
    let bytes = std::fs::read(&path)?;
    let geometry = Geometry {
        dims: [256; 3],
        spacing: [1.0; 3],
        origin: [0.0; 3],
    };
    let t0 = Instant::now();
    let v256 = Volume::from_buffer(
        &path,
        geometry,
        &TypedBuffer::new(ScalarType::U8, ByteOrder::Little, bytes.clone()),
    )?;
    eprintln!("256³ loaded in {:.2} s", t0.elapsed().as_secs_f64());

    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let cameras: Vec<Camera> = (0..VIEWS)
        .map(|_| Camera::random(&v256.geometry, UpAxis::Z, &mut rng))
        .collect();
    let backgrounds: Vec<Image> = (0..VIEWS)
        .map(|i| background::from_name("noise", SIZE, SIZE, i as u64).expect("known kind"))
        .collect();
    // A smooth, mostly positive loss gradient (like a perceptual loss's), so the LUT gradient
    // is not a sum of random signs that cancel and its relative error means something.
    let n = (SIZE * SIZE) as f32;
    let d_image: Vec<f32> = (0..SIZE * SIZE * 3)
        .map(|i| {
            let (p, c) = (i / 3, i % 3);
            let (x, y) = (
                (p % SIZE) as f32 / SIZE as f32,
                (p / SIZE) as f32 / SIZE as f32,
            );
            let phase = std::f32::consts::TAU * (1.5 * x + 0.3 * c as f32);
            (1.0 + 0.5 * phase.sin() * (std::f32::consts::TAU * 0.8 * y).cos()) / n
        })
        .collect();
    let d_t: Vec<f32> = (0..SIZE * SIZE)
        .map(|p| (-0.3 + 0.2 * (p as f32 * 0.001).sin()) / n)
        .collect();
    let evict_mb = match args.iter().position(|a| a == "--evict-mb") {
        Some(i) => args
            .get(i + 1)
            .and_then(|m| m.parse().ok())
            .ok_or_else(|| anyhow::anyhow!("--evict-mb needs a number of MiB"))?,
        None => 0,
    };
    let scene = Scene {
        cameras,
        backgrounds,
        d_image,
        d_t,
        evict_mb,
        tape: false,
    };
    let sparse = vessel_tf(0.0);
    let dense = vessel_tf(0.5);

    // A TF saved by `bench_optimize --reference-tf FILE`: the optimizer's own TF, timed
    // beside the two hand-made ones.
    let saved = match args.iter().position(|a| a == "--tf") {
        Some(i) => {
            let file = args
                .get(i + 1)
                .ok_or_else(|| anyhow::anyhow!("--tf needs a file"))?;
            Some(read_tf(Path::new(file))?)
        }
        None => None,
    };

    if args.iter().any(|a| a == "--speed") {
        // Just the default options, for quick before/after comparisons.
        let mut tfs = vec![("sparse", &sparse), ("dense", &dense)];
        if let Some(lut) = &saved {
            tfs.push(("saved", lut));
        }
        // Each TF through both backward paths, alternating: the optimizer's (`Backend`, whose
        // forward records what each ray composited and whose backward replays it) and the
        // front functions' (`render::backward_from`, which marches every ray again).
        for (name, lut) in tfs {
            for round in 0..2 {
                for (path, tape) in [("replay", true), ("re-march", false)] {
                    let scene = Scene {
                        tape,
                        ..scene.clone()
                    };
                    let (run, fwd, both, cpu) =
                        scene.timed(&v256, lut, &RenderOptions::default(), reps)?;
                    println!(
                        "{name}, {path} (round {round}): forward {fwd:.3} s, fwd+bwd {both:.3} s, CPU {cpu:.3} s, {:.2}M samples",
                        run.samples() as f64 / 1e6
                    );
                }
            }
        }
        // The optimizer draws each view's background inside its render phase.
        for kind in ["checkerboard", "noise", "fourier"] {
            let t0 = Instant::now();
            for seed in 0..reps as u64 {
                std::hint::black_box(background::from_name(kind, SIZE, SIZE, seed)?);
            }
            println!(
                "{kind} background at {SIZE}²: {:.4} s",
                t0.elapsed().as_secs_f64() / reps as f64
            );
        }
        return Ok(());
    }
    println!("# Renderer benchmark\n");
    println!(
        "rayon threads: {}; {VIEWS} views at {SIZE}²; times are the median of {reps} runs\n",
        rayon::current_num_threads()
    );
    for (name, lut) in [("sparse", &sparse), ("dense", &dense)] {
        let reference = scene.run(&v256, lut, &reference_opts())?;
        if let Some(dir) = &out {
            std::fs::create_dir_all(dir)?;
            for (i, r) in reference.rendered.iter().enumerate() {
                r.image
                    .save_png(&dir.join(format!("aneurism_{name}_ref_{i}.png")))?;
            }
        }
        println!("## 256³ aneurism, {name} TF: speed against error\n");
        println!("| step (voxels) | level | forward (s) | fwd+bwd (s) | fwd+bwd CPU (s) | samples | Msamples/s (fwd, CPU) | PSNR (dB) | grad rel. L2 |");
        println!("|---|---|---|---|---|---|---|---|---|");
        let steps: &[f32] = if quick {
            &[0.5, 1.0]
        } else {
            &[0.25, 0.5, 1.0, 2.0]
        };
        for &step in steps {
            for level in [Some(0), Some(1), Some(2), None] {
                let opts = RenderOptions {
                    step,
                    level,
                    ..RenderOptions::default()
                };
                let (run, fwd, both, cpu) = scene.timed(&v256, lut, &opts, reps)?;
                let level_name = match level {
                    Some(l) => l.to_string(),
                    None => format!("auto ({})", levels(&run)),
                };
                println!(
                    "| {step} | {level_name} | {fwd:.3} | {both:.3} | {cpu:.3} | {:.2}M | {:.0} | {:.1} | {:.2e} |",
                    run.samples() as f64 / 1e6,
                    // Forward and backward visit the same samples: 2 × samples per CPU-second.
                    2.0 * run.samples() as f64 / cpu / 1e6,
                    run.psnr(&reference),
                    run.grad_error(&reference)
                );
                if let (Some(dir), None) = (&out, level) {
                    for (i, r) in run.rendered.iter().enumerate() {
                        r.image
                            .save_png(&dir.join(format!("aneurism_{name}_step{step}_{i}.png")))?;
                    }
                }
            }
        }
        println!();
        println!("## 256³ aneurism, {name} TF: what skipping and early termination buy (default step, auto level)\n");
        println!(
            "| skipping | early termination | forward (s) | fwd+bwd (s) | fwd+bwd CPU (s) | samples | PSNR (dB) |"
        );
        println!("|---|---|---|---|---|---|---|");
        for (skip, stop) in [(true, 1e-3), (false, 1e-3), (true, 0.0), (false, 0.0)] {
            let opts = RenderOptions {
                skip_empty: skip,
                early_termination: stop,
                ..RenderOptions::default()
            };
            let (run, fwd, both, cpu) = scene.timed(&v256, lut, &opts, reps)?;
            println!(
                "| {} | {} | {fwd:.3} | {both:.3} | {cpu:.3} | {:.2}M | {:.1} |",
                if skip { "on" } else { "off" },
                if stop > 0.0 {
                    format!("T < {stop}")
                } else {
                    "off".into()
                },
                run.samples() as f64 / 1e6,
                run.psnr(&reference)
            );
        }
        println!();
    }

    // Every shared volume at the defaults, dense TF (the optimizer's case): where no brick is
    // uniform (noisy backgrounds, e.g. CT air), every sample is taken.
    println!("## Every shared volume, dense TF, default options\n");
    println!("| volume | level | forward (s) | fwd+bwd (s) | fwd+bwd CPU (s) | samples |");
    println!("|---|---|---|---|---|---|");
    for shared in &SHARED_VOLUMES {
        let (file, v) = (shared.file, shared.load()?);
        let mut rng = ChaCha8Rng::seed_from_u64(2024);
        let views = Scene {
            cameras: (0..VIEWS)
                .map(|_| Camera::random(&v.geometry, UpAxis::Z, &mut rng))
                .collect(),
            ..scene.clone()
        };
        let (run, fwd, both, cpu) = views.timed(&v, &dense, &RenderOptions::default(), reps)?;
        println!(
            "| {file} | {} | {fwd:.3} | {both:.3} | {cpu:.3} | {:.2}M |",
            levels(&run),
            run.samples() as f64 / 1e6
        );
        if let Some(dir) = &out {
            let name = shared.name();
            run.rendered[0]
                .image
                .save_png(&dir.join(format!("{name}_dense_0.png")))?;
        }
    }
    println!();

    // 512³: trilinear upsampling of the same data over the same box.
    let t0 = Instant::now();
    let v512 = upsample_u8(&bytes, 256, 512, &path)?;
    drop(bytes);
    eprintln!("512³ built in {:.2} s", t0.elapsed().as_secs_f64());
    println!("## 512³ upsampled aneurism against 256³ (default options, auto level)\n");
    println!("| volume | TF | level | forward (s) | fwd+bwd (s) | fwd+bwd CPU (s) | PSNR vs 256³ level-0 reference (dB) |");
    println!("|---|---|---|---|---|---|---|");
    for (name, lut) in [("sparse", &sparse), ("dense", &dense)] {
        let reference = scene.run(&v256, lut, &reference_opts())?;
        let opts = RenderOptions::default();
        let mut cpus = Vec::new();
        for (vname, v) in [("256³", &v256), ("512³", &v512)] {
            let (run, fwd, both, cpu) = scene.timed(v, lut, &opts, reps)?;
            cpus.push(cpu);
            println!(
                "| {vname} | {name} | {} | {fwd:.3} | {both:.3} | {cpu:.3} | {:.1} |",
                levels(&run),
                run.psnr(&reference)
            );
        }
        println!(
            "| 512³ / 256³ CPU | {name} | | | | {:.2}× | |",
            cpus[1] / cpus[0]
        );
    }
    Ok(())
}

/// The LUT (256 entries) of a TF written by `bench_optimize --reference-tf` (JSON with the
/// control points' `x`, `sigma` and `rgb`).
fn read_tf(path: &Path) -> anyhow::Result<Lut> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read: {e}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)?;
    let bad = |key: &str| anyhow::anyhow!("{}: no `{key}` array", path.display());
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
        .map(|c| -> anyhow::Result<[f64; 3]> {
            let c = c
                .as_array()
                .filter(|c| c.len() == 3)
                .ok_or_else(|| bad("rgb"))?;
            let at = |i: usize| c[i].as_f64().ok_or_else(|| bad("rgb"));
            Ok([at(0)?, at(1)?, at(2)?])
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let cp = ControlPoints {
        x: floats("x")?,
        sigma: floats("sigma")?,
        rgb,
    };
    Ok(cp.to_lut(256))
}

/// A vessel TF over normalized values: σ rises from 0 at 0.08 to 150 at 0.4, colour from dark
/// red to pale yellow; `floor` is added to σ everywhere.
fn vessel_tf(floor: f32) -> Lut {
    Lut {
        entries: (0..256)
            .map(|j| {
                let x = j as f32 / 255.0;
                let ramp = ((x - 0.08) / 0.32).clamp(0.0, 1.0);
                [
                    floor + 150.0 * ramp,
                    0.6 + 0.4 * ramp,
                    0.1 + 0.8 * ramp,
                    0.1 + 0.5 * ramp,
                ]
            })
            .collect(),
    }
}

fn reference_opts() -> RenderOptions {
    RenderOptions {
        step: 0.125,
        level: Some(0),
        early_termination: 0.0,
        ..RenderOptions::default()
    }
}

fn levels(run: &Run) -> String {
    let mut l: Vec<usize> = run.rendered.iter().map(|r| r.level).collect();
    l.dedup();
    l.iter()
        .map(|x| x.to_string())
        .collect::<Vec<_>>()
        .join("/")
}

#[derive(Clone)]
struct Scene {
    cameras: Vec<Camera>,
    backgrounds: Vec<Image>,
    d_image: Vec<f32>,
    d_t: Vec<f32>,
    /// MiB written between the forward and the backward (0: none).
    evict_mb: usize,
    /// Through `Backend::forward` and `Backend::backward` (the optimizer's path: the backward
    /// replays the forward's record), else `render::forward` and `render::backward_from`.
    tape: bool,
}

struct Run {
    rendered: Vec<Rendered>,
    grad: LutGrad,
}

/// A view's forward: the result, and with `Scene::tape` the backend's prepared level and tape.
struct Forward {
    rendered: Rendered,
    tape: Option<(CpuPrepared, <CpuBackend as Backend>::Tape)>,
}

impl Run {
    fn samples(&self) -> u64 {
        self.rendered.iter().map(|r| r.samples).sum()
    }

    /// PSNR (dB) of the views pooled: `t2tf::image::psnr` of the views side by side.
    fn psnr(&self, reference: &Run) -> f64 {
        let side_by_side = |run: &Run| {
            let views: Vec<Image> = run.rendered.iter().map(|r| r.image.clone()).collect();
            Image::grid(&views, views.len())
        };
        t2tf::image::psnr(&side_by_side(self), &side_by_side(reference))
    }

    fn grad_error(&self, reference: &Run) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for (a, b) in self.grad.entries.iter().zip(&reference.grad.entries) {
            for c in 0..4 {
                num += (a[c] - b[c]).powi(2);
                den += b[c].powi(2);
            }
        }
        (num / den.max(1e-300)).sqrt()
    }
}

impl Scene {
    /// Forward then backward (from the forward's result) for every view.
    fn run(&self, v: &Volume, lut: &Lut, opts: &RenderOptions) -> anyhow::Result<Run> {
        let forward = self.forward(v, lut, opts)?;
        let grad = self.backward(v, lut, opts, &forward)?;
        let rendered = forward.into_iter().map(|f| f.rendered).collect();
        Ok(Run { rendered, grad })
    }

    fn forward(&self, v: &Volume, lut: &Lut, opts: &RenderOptions) -> anyhow::Result<Vec<Forward>> {
        self.cameras
            .iter()
            .zip(&self.backgrounds)
            .map(|(c, b)| {
                if !self.tape {
                    let rendered = render::forward(v, lut, c, b, opts)?;
                    return Ok(Forward {
                        rendered,
                        tape: None,
                    });
                }
                let backend = render::shared_backend();
                let size = (b.width, b.height);
                let prepared = backend.prepare(v, render::level_for(v, lut, c, size, opts)?)?;
                let shot = self.shot(c, b, opts);
                let (rendered, tape) = backend.forward(&prepared, lut, &shot)?;
                Ok(Forward {
                    rendered,
                    tape: Some((prepared, tape)),
                })
            })
            .collect()
    }

    fn shot<'a>(&self, camera: &'a Camera, bg: &'a Image, opts: &'a RenderOptions) -> Shot<'a> {
        Shot {
            camera,
            background: bg,
            options: opts,
            cast: (bg.width, bg.height),
        }
    }

    fn backward(
        &self,
        v: &Volume,
        lut: &Lut,
        opts: &RenderOptions,
        forward: &[Forward],
    ) -> anyhow::Result<LutGrad> {
        let mut grad = LutGrad::zeros(lut.entries.len());
        for ((c, b), f) in self.cameras.iter().zip(&self.backgrounds).zip(forward) {
            let (d_i, d_t) = (&self.d_image, &self.d_t);
            let g = match &f.tape {
                None => render::backward_from(v, lut, c, &f.rendered, opts, d_i, d_t)?,
                Some((prepared, tape)) => {
                    let shot = self.shot(c, b, opts);
                    render::shared_backend().backward(prepared, lut, &shot, tape, d_i, d_t)?
                }
            };
            t2tf::bench::add_grad(&mut grad, &g);
        }
        Ok(grad)
    }

    /// (last run, median forward seconds, median forward+backward seconds, mean CPU seconds of
    /// forward+backward summed over threads).
    fn timed(
        &self,
        v: &Volume,
        lut: &Lut,
        opts: &RenderOptions,
        reps: usize,
    ) -> anyhow::Result<(Run, f64, f64, f64)> {
        let (mut fwd, mut both) = (Vec::new(), Vec::new());
        let mut last = None;
        let cpu0 = cpu_seconds();
        let mut evict = vec![0u8; self.evict_mb << 20];
        let mut evicted = 0.0;
        for r in 0..reps {
            // As in the optimizer, where CLIP's passes (hundreds of MB of weights and
            // activations) run between the renders: caches hold none of the volume.
            let mut flush = || {
                let c = cpu_seconds();
                evict
                    .iter_mut()
                    .for_each(|b| *b = b.wrapping_add(r as u8 | 1));
                std::hint::black_box(&evict);
                evicted += cpu_seconds() - c;
            };
            flush();
            let t0 = Instant::now();
            let forward = self.forward(v, lut, opts)?;
            let t1 = Instant::now();
            flush();
            let t1b = Instant::now();
            let grad = self.backward(v, lut, opts, &forward)?;
            let rendered = forward.into_iter().map(|f| f.rendered).collect();
            let t2 = Instant::now();
            fwd.push((t1 - t0).as_secs_f64());
            both.push((t1 - t0 + (t2 - t1b)).as_secs_f64());
            last = Some(Run { rendered, grad });
        }
        let cpu = (cpu_seconds() - cpu0 - evicted) / reps as f64;
        let median = |mut x: Vec<f64>| {
            x.sort_by(f64::total_cmp);
            x[x.len() / 2]
        };
        Ok((last.expect("reps ≥ 1"), median(fwd), median(both), cpu))
    }
}

/// CPU time (user + system, all threads) of this process so far, from /proc (Linux).
/// Wall times on a shared machine mostly measure the other processes; CPU time divided by
/// the thread count estimates the wall time on an idle machine.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesized command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // USER_HZ is 100 on Linux.
    (tick(11) + tick(12)) / 100.0
}

/// Trilinear upsampling of an `n`³ uint8 volume to `m`³ points over the same box.
fn upsample_u8(src: &[u8], n: usize, m: usize, path: &Path) -> anyhow::Result<Volume> {
    let scale = (n - 1) as f64 / (m - 1) as f64;
    let taps: Vec<(usize, f32)> = (0..m)
        .map(|i| {
            let x = i as f64 * scale;
            let i0 = (x.floor() as usize).min(n - 2);
            (i0, (x - i0 as f64) as f32)
        })
        .collect();
    let mut out = vec![0u8; m * m * m];
    use rayon::prelude::*;
    out.par_chunks_mut(m * m)
        .enumerate()
        .for_each(|(k, slice)| {
            let (k0, wk) = taps[k];
            for (j, row) in slice.chunks_mut(m).enumerate() {
                let (j0, wj) = taps[j];
                for (i, o) in row.iter_mut().enumerate() {
                    let (i0, wi) = taps[i];
                    let at = |a: usize, b: usize, c: usize| {
                        src[(i0 + a) + n * ((j0 + b) + n * (k0 + c))] as f32
                    };
                    let l = |a: f32, b: f32, w: f32| a + w * (b - a);
                    let v = l(
                        l(
                            l(at(0, 0, 0), at(1, 0, 0), wi),
                            l(at(0, 1, 0), at(1, 1, 0), wi),
                            wj,
                        ),
                        l(
                            l(at(0, 0, 1), at(1, 0, 1), wi),
                            l(at(0, 1, 1), at(1, 1, 1), wi),
                            wj,
                        ),
                        wk,
                    );
                    *o = v.round() as u8;
                }
            }
        });
    let g = Geometry {
        dims: [m; 3],
        spacing: [scale; 3],
        origin: [0.0; 3],
    };
    Ok(Volume::from_buffer(
        path,
        g,
        &TypedBuffer::new(ScalarType::U8, ByteOrder::Little, out),
    )?)
}
