//! Does one TF fitted over a time series hold for time steps it never saw better than a TF
//! fitted on one step? An offline answer with pictures as the target (as `demo_recover`), on a
//! real simulation: the 3D Gray–Scott series of `tests/fixtures/series/make_gray_scott.py`.
//!
//! A fixed target TF renders reference pictures (`--target`: `late`, the default, a faint red
//! haze, faint blue and yellow, and opaque magenta over the highest values, which the first
//! step barely reaches; `early`, opaque bands over values every step holds; `bands`, three
//! sharp bands off the fitted TF's grid). The even time steps are the training steps, the odd
//! ones are held out. From the same starts (the paper's initialization, seeds 0..`--seeds`)
//! and the same 8 training cameras, `recover::descend` fits a TF of `--points` control points
//! to the training pictures with a pixel loss, once per learning rate of `--lr`; per start the
//! fit with the lowest final training loss is kept. The methods:
//!
//! - **series**: the 8 cameras' views spread over the training steps (view i renders training
//!   step i mod n): the cost of one step's fit;
//! - with `--every`, **series, every view at every step**: the 8 cameras at each training step
//!   (n× the renders);
//! - **step 0 only** (a user designing on the first step) and **middle step only**.
//!
//! Every method reads the steps normalized over the whole series' range (`SeriesSteps`), so a
//! TF means the same data values at every step. Each kept fit is rendered from 4 cameras never
//! trained on, at every step, and compared with the target's renders (PSNR); the table gives,
//! per method, the mean over starts (and the range of the held-out mean over starts).
//!
//! ```sh
//! cargo run --release --example demo_series -- [SERIES] [--size 48] [--steps 8]
//!     [--render 96] [--iters 300] [--lr 100,300] [--seeds 3] [--points 16]
//!     [--target late|early|bands] [--every] [--threads N] [--out sheet.png]
//! ```
//!
//! SERIES: a `.pvd`, `.series` or a folder holding `gray_scott.pvd`; without it the series is
//! made in a temporary folder by `pvpython tests/fixtures/series/make_gray_scott.py DIR
//! --size S --steps T` (run from the repository root). `--out` writes a sheet: one row per
//! held-out step, the target then each method (the first start's fit), from one held-out
//! camera. About 6 minutes with the defaults on 2 cores.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use t2tf::camera::UpAxis;
use t2tf::image::Image;
use t2tf::optimize::adapters::{PaperTf, VolumeRenderer};
use t2tf::optimize::recover::{descend, pixel_loss, psnr};
use t2tf::optimize::series::SeriesSteps;
use t2tf::optimize::{initialize, Background, Parameterization, Renderer, Settings, View};
use t2tf::render::RenderOptions;
use t2tf::tf::ControlPoints;
use t2tf::volume::{ReadOptions, Series};

/// LUT entries, as `t2tf optimize` uses.
const LUT: usize = 256;
/// Training cameras, held-out cameras.
const TRAIN_CAMERAS: usize = 8;
const HELD_CAMERAS: usize = 4;

/// The target TFs. `early` and `late` are on the fitted TFs' own control points (16, evenly
/// spaced, so they are representable): a faint red haze over the low values of the reaction
/// fronts and blue in the middle; `late` adds opaque magenta for the highest values, which
/// only the later steps reach, `early` yellow over values every step holds. `bands`: three
/// sharp bands off that grid (blue, green, orange), which 16 points only approximate.
fn target_tf(which: &str) -> ControlPoints {
    let red = [0.9, 0.2, 0.15];
    let blue = [0.15, 0.35, 0.95];
    if which == "bands" {
        let (green, orange, clear) = ([0.2, 0.85, 0.3], [1.0, 0.55, 0.1], [0.0; 3]);
        return ControlPoints {
            x: vec![
                0.0, 0.25, 0.30, 0.38, 0.43, 0.55, 0.60, 0.68, 0.73, 0.84, 0.88, 1.0,
            ],
            sigma: vec![
                0.0, 0.0, 60.0, 60.0, 0.0, 0.0, 100.0, 100.0, 0.0, 0.0, 220.0, 220.0,
            ],
            rgb: vec![
                clear, blue, blue, blue, clear, green, green, green, clear, orange, orange, orange,
            ],
        };
    }
    // σ at the 16 points x = i / 15.
    let (sigma, rgb) = if which == "late" {
        // Faint haze and blue, so that the magenta of the reaction cores (x ≥ 0.87) shows.
        let yellow = [1.0, 0.85, 0.2];
        let magenta = [0.85, 0.1, 0.8];
        let mut rgb = vec![red; 4];
        rgb.extend([blue; 5]);
        rgb.extend([yellow; 4]);
        rgb.extend([magenta; 3]);
        let sigma = vec![
            0.0, 5.0, 5.0, 0.0, 0.0, 0.0, 12.0, 12.0, 0.0, 0.0, 15.0, 15.0, 0.0, 0.0, 255.0, 255.0,
        ];
        (sigma, rgb)
    } else {
        let yellow = [1.0, 0.85, 0.2];
        let mut rgb = vec![red; 4];
        rgb.extend([blue; 5]);
        rgb.extend([yellow; 7]);
        let sigma = vec![
            0.0, 20.0, 20.0, 0.0, 0.0, 0.0, 50.0, 50.0, 0.0, 0.0, 0.0, 0.0, 120.0, 200.0, 255.0,
            255.0,
        ];
        (sigma, rgb)
    };
    ControlPoints {
        x: (0..16).map(|i| i as f64 / 15.0).collect(),
        sigma,
        rgb,
    }
}

/// `n` cameras around the volume; training ones on checkerboards (a colour equal to a flat
/// background would look transparent), held-out ones at other angles on dark gray.
fn cameras(n: usize, offset: f64, pitch: f64, textured: bool) -> Vec<View> {
    (0..n)
        .map(|i| View {
            yaw: std::f64::consts::TAU * (i as f64 + offset) / n as f64,
            pitch: if i % 2 == 0 { pitch } else { -pitch },
            distance: 2.6,
            background: if textured {
                Background::Checkerboard { seed: i as u64 }
            } else {
                Background::Gray { level: 0.15 }
            },
            seed: 0,
            time: 0,
        })
        .collect()
}

fn at(views: &[View], time: usize) -> Vec<View> {
    views.iter().map(|v| View { time, ..v.clone() }).collect()
}

fn render_all(r: &VolumeRenderer, cp: &ControlPoints, views: &[View]) -> Result<Vec<Image>> {
    let lut = cp.to_lut(LUT);
    views
        .iter()
        .map(|v| {
            r.render(&lut, v)
                .map(|x| x.0)
                .map_err(|e| anyhow::anyhow!("render: {e}"))
        })
        .collect()
}

struct Args {
    series: Option<PathBuf>,
    size: usize,
    steps: usize,
    render: usize,
    iters: usize,
    lrs: Vec<f64>,
    every: bool,
    target: String,
    points: usize,
    seeds: usize,
    threads: Option<usize>,
    out: Option<PathBuf>,
}

fn parse() -> Result<Args> {
    let mut a = Args {
        series: None,
        size: 48,
        steps: 8,
        render: 96,
        iters: 300,
        lrs: vec![100.0, 300.0],
        every: false,
        target: "late".into(),
        points: 16,
        seeds: 3,
        threads: None,
        out: None,
    };
    let mut args = std::env::args().skip(1);
    while let Some(x) = args.next() {
        let mut num = |name: &str| -> Result<usize> {
            args.next()
                .with_context(|| format!("{name} needs a number"))?
                .parse()
                .with_context(|| format!("{name} needs a number"))
        };
        match x.as_str() {
            "--size" => a.size = num("--size")?,
            "--steps" => a.steps = num("--steps")?,
            "--render" => a.render = num("--render")?,
            "--iters" => a.iters = num("--iters")?,
            "--threads" => a.threads = Some(num("--threads")?),
            "--lr" => {
                a.lrs = args
                    .next()
                    .context("--lr needs a list")?
                    .split(',')
                    .map(str::parse)
                    .collect::<Result<_, _>>()
                    .context("--lr needs numbers: LR[,LR...]")?
            }
            "--every" => a.every = true,
            "--points" => a.points = num("--points")?,
            "--seeds" => a.seeds = num("--seeds")?.max(1),
            "--target" => {
                a.target = args.next().unwrap_or_default();
                if !["late", "early", "bands"].contains(&a.target.as_str()) {
                    bail!("--target takes late, early or bands");
                }
            }
            "--out" => a.out = Some(args.next().context("--out needs a path")?.into()),
            s if s.starts_with("--") => bail!(
                "unknown flag {s} (SERIES, --size, --steps, --render, --iters, --lr, --every, \
                 --target, --threads, --out)"
            ),
            s => a.series = Some(s.into()),
        }
    }
    Ok(a)
}

/// The series named on the command line, or a Gray–Scott series made in `tmp` by pvpython.
fn series_path(a: &Args, tmp: &Path) -> Result<PathBuf> {
    match &a.series {
        Some(p) if p.is_dir() => Ok(p.join("gray_scott.pvd")),
        Some(p) => Ok(p.clone()),
        None => {
            let script = Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("tests/fixtures/series/make_gray_scott.py");
            println!(
                "making a {}³ Gray–Scott series of {} steps with pvpython",
                a.size, a.steps
            );
            let run = Command::new("pvpython")
                .arg(&script)
                .arg(tmp)
                .args([
                    "--size",
                    &a.size.to_string(),
                    "--steps",
                    &a.steps.to_string(),
                ])
                .output()
                .context("pvpython (ParaView's Python) on PATH makes the series")?;
            if !run.status.success() {
                bail!(
                    "make_gray_scott.py failed:\n{}{}",
                    String::from_utf8_lossy(&run.stdout),
                    String::from_utf8_lossy(&run.stderr)
                );
            }
            Ok(tmp.join("gray_scott.pvd"))
        }
    }
}

/// A fitted TF's PSNR against the target at each time step (mean over the held-out cameras).
fn per_step(
    r: &VolumeRenderer,
    cp: &ControlPoints,
    held: &[View],
    targets: &[Vec<Image>],
) -> Result<Vec<f64>> {
    (0..targets.len())
        .map(|t| Ok(psnr(&render_all(r, cp, &at(held, t))?, &targets[t])))
        .collect()
}

fn main() -> Result<()> {
    let a = parse()?;
    if let Some(n) = a.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()?;
    }
    let tmp = tempfile::tempdir()?;
    let path = series_path(&a, tmp.path())?;
    let series = Series::open(std::slice::from_ref(&path))?;
    let n = series.steps.len();
    if n < 3 {
        bail!(
            "{}: {n} time steps; the demo needs at least 3",
            path.display()
        );
    }
    // Every step stays loaded: the series is small, and the fits take turns over it.
    let steps = SeriesSteps::open(series, ReadOptions::default(), n, &mut |_| {})?;
    let stats = steps.stats();
    let first = steps.representative()?;
    let d = first.geometry.dims;
    println!(
        "{}: {n} steps of {}×{}×{}, values {:.4} .. {:.4} over the series (each step's: {})",
        path.file_name().unwrap_or_default().to_string_lossy(),
        d[0],
        d[1],
        d[2],
        stats.range[0],
        stats.range[1],
        stats
            .step_ranges
            .iter()
            .map(|r| format!("{:.3}", r[1]))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let r = VolumeRenderer {
        backend: t2tf::render::shared_backend(),
        volume: first,
        series: Some(&steps),
        options: RenderOptions::default(),
        up: UpAxis::Z,
        size: a.render,
        render_size: a.render,
        jitter: false,
    };
    let tf = PaperTf {
        k: a.points,
        lut_size: LUT,
    };
    let train_steps: Vec<usize> = (0..n).step_by(2).collect();
    let held_steps: Vec<usize> = (1..n).step_by(2).collect();
    let train_cams = cameras(TRAIN_CAMERAS, 0.0, 0.2, true);
    let held_cams = cameras(HELD_CAMERAS, 0.37, 0.35, false);
    let target = target_tf(&a.target);
    let held_targets: Vec<Vec<Image>> = (0..n)
        .map(|t| render_all(&r, &target, &at(&held_cams, t)))
        .collect::<Result<_>>()?;

    // The same starts for every method: the paper's initialization over the series, with
    // the seeds 0..seeds (its random colours).
    let starts: Vec<Vec<f64>> = (0..a.seeds as u64)
        .map(|seed| {
            let settings = Settings {
                control_points: a.points,
                seed,
                ..Settings::default()
            };
            Ok(initialize(&r, &tf, &stats.histogram, &settings.validate()?)?.0)
        })
        .collect::<Result<_>>()?;

    let middle = train_steps[train_steps.len() / 2];
    let spread: Vec<View> = train_cams
        .iter()
        .enumerate()
        .map(|(i, v)| View {
            time: train_steps[i % train_steps.len()],
            ..v.clone()
        })
        .collect();
    let every: Vec<View> = train_steps
        .iter()
        .flat_map(|&t| at(&train_cams, t))
        .collect();
    let mut methods: Vec<(String, Vec<View>)> = vec![(
        format!("series: 8 views over steps {train_steps:?}"),
        spread,
    )];
    if a.every {
        methods.push((
            format!("series: 8 views × {} steps", train_steps.len()),
            every,
        ));
    }
    methods.push(("step 0 only: 8 views".into(), at(&train_cams, 0)));
    methods.push((
        format!("step {middle} only (middle): 8 views"),
        at(&train_cams, middle),
    ));
    println!(
        "{} threads; {} descent steps from lr {:?} (each method keeps the lr of its lowest \
         final training loss), {} control points, {}² renders; held out: steps \
         {held_steps:?}, {HELD_CAMERAS} cameras",
        rayon::current_num_threads(),
        a.iters,
        a.lrs,
        a.points,
        a.render
    );
    let mut rows = Vec::new();
    let mut fitted = Vec::new();
    for (name, views) in &methods {
        let targets = views
            .iter()
            .map(|v| render_all(&r, &target, std::slice::from_ref(v)).map(|mut x| x.remove(0)))
            .collect::<Result<Vec<_>>>()?;
        // Per start: the fit of the lr with the lowest final training loss, scored per step.
        let mut per_seed: Vec<(f64, Vec<f64>)> = Vec::new();
        let (mut fits, mut seconds) = (0, 0.0);
        for (seed, p0) in starts.iter().enumerate() {
            let mut best: Option<(f64, f64, Vec<f64>)> = None;
            for &lr in &a.lrs {
                let t0 = Instant::now();
                let mut loss = pixel_loss(&targets);
                let fit = descend(&r, &tf, views, p0.clone(), a.iters, lr, &mut loss);
                seconds += t0.elapsed().as_secs_f64();
                fits += 1;
                // A rate that diverges (a non-finite loss) is one the grid does not keep.
                let Ok((p, losses)) = fit else {
                    println!("{name}: seed {seed}, lr {lr} diverged");
                    continue;
                };
                let last = losses.last().copied().unwrap_or(f64::INFINITY);
                if best.as_ref().is_none_or(|b| last < b.0) {
                    best = Some((last, lr, p));
                }
            }
            let (last, lr, p) = best.context("every learning rate diverged")?;
            let cp = tf.control_points(&p).map_err(|e| anyhow::anyhow!("{e}"))?;
            let scores = per_step(&r, &cp, &held_cams, &held_targets)?;
            println!(
                "{name}: seed {seed}: lr {lr} kept (final training loss {last:.2e}); PSNR per \
                 step {scores:.1?}"
            );
            if seed == 0 {
                fitted.push(cp);
            }
            per_seed.push((lr, scores));
        }
        rows.push((name.clone(), per_seed, seconds / fits as f64));
    }
    let cp0 = tf
        .control_points(&starts[0])
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let start = per_step(&r, &cp0, &held_cams, &held_targets)?;

    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    // Mean over `steps` of `s`, and its worst step.
    let over = |s: &[f64], steps: &[usize]| -> (f64, f64) {
        let v: Vec<f64> = steps.iter().map(|&t| s[t]).collect();
        (mean(&v), v.iter().copied().fold(f64::INFINITY, f64::min))
    };
    println!(
        "\nPSNR (dB) of each fitted TF's renders against the target's from {HELD_CAMERAS} held-out \
         cameras, per step the mean over {} start(s); held-out steps {held_steps:?}, training \
         steps {train_steps:?}\n",
        a.seeds
    );
    println!(
        "| method | held-out steps: mean (worst step) | range over starts | training steps: mean \
         (worst) | lr kept | s per fit |"
    );
    println!("|---|---|---|---|---|---|");
    let (hm, hn) = over(&start, &held_steps);
    let (tm, tn) = over(&start, &train_steps);
    println!("| start (initialization) | {hm:.1} ({hn:.1}) | — | {tm:.1} ({tn:.1}) | — | — |");
    for (name, per_seed, secs) in &rows {
        let by_step: Vec<f64> = (0..n)
            .map(|t| mean(&per_seed.iter().map(|s| s.1[t]).collect::<Vec<_>>()))
            .collect();
        let (hm, hn) = over(&by_step, &held_steps);
        let (tm, tn) = over(&by_step, &train_steps);
        let seeds: Vec<f64> = per_seed.iter().map(|s| over(&s.1, &held_steps).0).collect();
        let (lo, hi) = seeds
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                (l.min(x), h.max(x))
            });
        let lrs: Vec<String> = per_seed.iter().map(|s| s.0.to_string()).collect();
        println!(
            "| {name} | {hm:.1} ({hn:.1}) | {lo:.1}–{hi:.1} | {tm:.1} ({tn:.1}) | {} | {secs:.1} |",
            lrs.join(", ")
        );
    }
    println!(
        "\nstep loads: {} (every step read once, then cached)",
        steps.loads()
    );

    if let Some(out) = &a.out {
        let mut sheet = Vec::new();
        for &t in &held_steps {
            let v = at(&held_cams[..1], t);
            sheet.push(held_targets[t][0].clone());
            for cp in &fitted {
                sheet.extend(render_all(&r, cp, &v)?);
            }
        }
        Image::grid(&sheet, 1 + fitted.len()).save_png(out)?;
        println!(
            "wrote {} (rows: held-out steps; columns: target, then the methods in order)",
            out.display()
        );
    }
    Ok(())
}
