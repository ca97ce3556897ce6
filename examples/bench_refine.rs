//! The design loop's costs through the library (`t2tf::pipeline`), with CLIP of ViT-B/32's
//! shapes and random weights (written to a temporary `model.safetensors` and loaded as a user's
//! model is), on the 256³ aneurism of ../shared:
//!
//! - **Refining**: a fresh default run (300 steps) for prompt A gives a TF; refines of it for
//!   prompt B with N steps are compared with a 300-step refine (the reference) by PSNR of
//!   renders from 4 held-out views: speed against error.
//! - **Batches**: 5 prompts in one call sequence (volume and model loaded once, the caption
//!   pool embedded once) against 5 separate runs (each loading the volume and the model).
//!
//!     cargo run --release --features bench --example bench_refine -- [--quick] [--threads N]
//!
//! `--quick` divides every step count by 10 (a smoke test). Timings on a shared machine are
//! noisy: compare the rows of one run.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use t2tf::camera::UpAxis;
use t2tf::image::Image;
use t2tf::optimize::adapters::VolumeRenderer;
use t2tf::optimize::{Renderer, Settings};
use t2tf::pipeline::{self, InitTf, Job, Model, ModelOptions, Optimized, Target};
use t2tf::render::RenderOptions;
use t2tf::volume::Volume;

const HELD_OUT: usize = 4;
const PROMPT_A: &str = "a CT angiography of blood vessels";
const PROMPT_B: &str = "an aneurism in red, the vessels faint";
const BATCH: [&str; 5] = [
    "bone",
    "skin",
    "blood vessels",
    "an aneurism",
    "soft tissue",
];

#[path = "common/random_model.rs"]
mod random_model;
use random_model::write_model;

/// The run's TF from the held-out views at 224², default render options.
fn held_out(volume: &Volume, run: &Optimized) -> anyhow::Result<Image> {
    let eval = VolumeRenderer {
        backend: t2tf::render::shared_backend(),
        volume,
        series: None,
        options: RenderOptions::default(),
        up: UpAxis::Z,
        size: 224,
        render_size: 224,
        jitter: false,
    };
    let lut = run.control_points().to_lut(pipeline::PARAVIEW_TABLE);
    let images = t2tf::bench::held_out_views(&Settings::default(), HELD_OUT)
        .iter()
        .map(|v| eval.render(&lut, v).map(|r| r.0))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("held-out render: {e}"))?;
    Ok(Image::grid(&images, images.len()))
}

fn run(
    volume: &Volume,
    model: &Model,
    prompt: &str,
    steps: usize,
    init: Option<&InitTf>,
    cache: &Path,
) -> anyhow::Result<(Optimized, f64)> {
    let mut job = Job::new(Target::Prompt(prompt.into()));
    job.settings.steps = steps;
    job.init = init.cloned();
    job.caption_cache = Some(cache.to_path_buf());
    let job = job.validate()?;
    let t0 = Instant::now();
    let r = pipeline::optimize(volume, model, &job, &mut |_| ControlFlow::Continue(()))?;
    Ok((r, t0.elapsed().as_secs_f64()))
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    if let Some(i) = args.iter().position(|a| a == "--threads") {
        let n: usize = args.get(i + 1).and_then(|v| v.parse().ok()).unwrap_or(0);
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()?;
    }
    let scale = |n: usize| if quick { n.div_ceil(10) } else { n };
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let volume_path = shared.join("data/volumes/aneurism_256x256x256_uint8.raw");
    let tmp = tempfile::tempdir()?;
    let model_dir = tmp.path().join("vit-b32-random");
    std::fs::create_dir_all(&model_dir)?;
    write_model(&model_dir, &shared)?;
    let cache = tmp.path().join("cache");
    let load = || -> anyhow::Result<(Volume, Model)> {
        let volume = t2tf::volume::load(&volume_path, &Default::default())?;
        let model = Model::load(&ModelOptions::new(model_dir.to_string_lossy()))?;
        Ok((volume, model))
    };
    println!(
        "threads {}; CPU: {}; ViT-B/32 shapes, random weights; 256³ aneurism",
        rayon::current_num_threads(),
        t2tf::optimize::report::MachineInfo::detect()
            .cpu_model
            .unwrap_or_default()
    );
    let (volume, model) = load()?;

    // Refining.
    let (fresh, fresh_s) = run(&volume, &model, PROMPT_A, scale(300), None, &cache)?;
    println!(
        "fresh run, {} steps: {fresh_s:.1} s (caption pool embedded in it)",
        scale(300)
    );
    let start = InitTf {
        preset: t2tf::formats::Preset {
            tf: fresh.transfer_function("start"),
            space: t2tf::tf::ColorSpace::Rgb,
            hsv_wrap: false,
            extra: Default::default(),
        },
        source: PathBuf::from("(the fresh run)"),
    };
    let (reference, ref_s) = run(&volume, &model, PROMPT_B, scale(300), Some(&start), &cache)?;
    let reference_img = held_out(&volume, &reference)?;
    let (fresh_b, fresh_b_s) = run(&volume, &model, PROMPT_B, scale(300), None, &cache)?;
    println!(
        "\n| run for prompt B | steps | wall (s) | render fwd+bwd per step (s) | CLIP per step (s) | held-out PSNR vs the 300-step refine (dB) |"
    );
    println!("|---|---|---|---|---|---|");
    let phases = |r: &Optimized| {
        let t = &r.report.timings;
        let n = r.steps_run().max(1) as f64;
        (
            (t.render + t.render_backward) / n,
            (t.clip_forward + t.clip_backward) / n,
        )
    };
    let row = |what: &str, r: &Optimized, s: f64, psnr: &str| {
        let (render, clip) = phases(r);
        println!(
            "| {what} | {} | {s:.1} | {render:.3} | {clip:.3} | {psnr} |",
            r.steps_run()
        );
    };
    row("fresh", &fresh_b, fresh_b_s, "—");
    row("refine (reference)", &reference, ref_s, "reference");
    for n in [0, 10, 25, 50, 100] {
        let (r, s) = run(&volume, &model, PROMPT_B, scale(n), Some(&start), &cache)?;
        let p = t2tf::image::psnr(&held_out(&volume, &r)?, &reference_img);
        row("refine", &r, s, &format!("{p:.1}"));
    }

    // Batches: one model and volume for 5 prompts, against 5 separate runs.
    let steps = scale(50);
    let t0 = Instant::now();
    for p in BATCH {
        run(&volume, &model, p, steps, None, &cache)?;
    }
    let batch_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    for p in BATCH {
        let (volume, model) = load()?;
        run(&volume, &model, p, steps, None, &cache)?;
    }
    let separate_s = t0.elapsed().as_secs_f64();
    println!("\n| 5 prompts × {steps} steps | wall (s) | per prompt (s) |");
    println!("|---|---|---|");
    println!("| one batch | {batch_s:.1} | {:.1} |", batch_s / 5.0);
    println!(
        "| 5 separate runs | {separate_s:.1} | {:.1} |",
        separate_s / 5.0
    );
    Ok(())
}
