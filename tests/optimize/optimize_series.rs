//! One TF for a time series: the views render the time steps the schedule gives them, a
//! series of one step is that volume, and the report, preview and exported range cover the
//! series.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::Command;

use t2tf::clip::Compute;
use t2tf::optimize::adapters::VolumeRenderer;
use t2tf::optimize::series::SeriesSteps;
use t2tf::optimize::{Renderer, Settings, View};
use t2tf::pipeline::{self, Event, Job, Model, ModelOptions, Target};
use t2tf::render::{CpuBackend, RenderOptions};
use t2tf::tf::ControlPoints;
use t2tf::volume::{ReadOptions, Series};

const VOLUME: &str = "../shared/data/volumes/neghip_64x64x64_uint8.raw";
const MODEL: &str = "tests/fixtures/clip/quick_gelu";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const PROMPT: &str = "a molecule in red";

/// Three steps of neghip whose values drift: step s is min(v + 40 s, 255), a pattern that
/// brightens over time as a simulation's field does.
fn drifting_series(dir: &Path) -> Vec<PathBuf> {
    let base = std::fs::read(VOLUME).unwrap();
    (0..3)
        .map(|s| {
            let bytes: Vec<u8> = base.iter().map(|&v| v.saturating_add(40 * s)).collect();
            let path = dir.join(format!("neghip_{s}_64x64x64_uint8.raw"));
            std::fs::write(&path, bytes).unwrap();
            path
        })
        .collect()
}

fn model() -> Model {
    Model::load(&ModelOptions {
        tokenizer: Some(PathBuf::from(TOKENIZER)),
        compute: Compute::default(),
        ..ModelOptions::new(MODEL)
    })
    .unwrap()
}

fn job(steps: usize, cache: &Path) -> pipeline::ValidJob {
    let mut job = Job::new(Target::Prompt(PROMPT.into()));
    job.settings.steps = steps;
    job.settings.negatives_per_step = 16;
    job.caption_cache = Some(cache.to_path_buf());
    job.validate().unwrap()
}

fn go(_: Event) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

fn open(files: &[PathBuf], keep: usize) -> SeriesSteps {
    let series = Series::open(files).unwrap();
    SeriesSteps::open(series, ReadOptions::default(), keep, &mut |_| {}).unwrap()
}

#[test]
fn each_view_renders_its_time_step() {
    let dir = tempfile::tempdir().unwrap();
    let steps = open(&drifting_series(dir.path()), 2);
    let first = steps.representative().unwrap().clone();
    let backend = CpuBackend::new(Default::default());
    let renderer = VolumeRenderer {
        backend: &backend,
        volume: &first,
        series: Some(&steps),
        options: RenderOptions::default(),
        up: Default::default(),
        size: 32,
        render_size: 32,
        jitter: false,
    };
    assert_eq!(renderer.time_steps(), 3);
    let lut = ControlPoints {
        x: vec![0.0, 0.5, 1.0],
        sigma: vec![0.0, 40.0, 80.0],
        rgb: vec![[0.9, 0.2, 0.1]; 3],
    }
    .to_lut(256);
    let view = |time| View {
        time,
        ..View::initial(&Settings::default())
    };
    let images: Vec<Vec<f32>> = (0..3)
        .map(|t| renderer.render(&lut, &view(t)).unwrap().0.data.clone())
        .collect();
    assert_ne!(images[0], images[2], "time steps 0 and 2 render alike");
    // View time 2 is step 2 as a volume of its own, normalized over the series' range.
    let step2 = steps.step(2).unwrap();
    let alone = VolumeRenderer {
        volume: &step2,
        series: None,
        ..renderer
    };
    assert_eq!(
        images[2],
        alone.render(&lut, &view(0)).unwrap().0.data.clone()
    );
    // Capacity 2: three steps drawn in turn were loaded three times; drawing them again in
    // the order 2, 1 finds both in the cache.
    assert_eq!(steps.loads(), 3);
    renderer.render(&lut, &view(2)).unwrap();
    renderer.render(&lut, &view(1)).unwrap();
    assert_eq!(steps.loads(), 3);
}

#[test]
fn a_series_of_one_step_is_that_volume() {
    let dir = tempfile::tempdir().unwrap();
    let files = drifting_series(dir.path());
    let model = model();
    let job = job(4, &dir.path().join("cache"));
    let one = open(&files[1..2], 4);
    let by_series = pipeline::optimize_series(&one, &model, &job, &mut go).unwrap();
    let volume = pipeline::load_volume(&files[1], &Default::default()).unwrap();
    let by_volume = pipeline::optimize(&volume, &model, &job, &mut go).unwrap();
    assert_eq!(by_series.control_points(), by_volume.control_points());
    assert_eq!(
        by_series.transfer_function("tf"),
        by_volume.transfer_function("tf")
    );
}

#[test]
fn one_tf_covers_the_series() {
    let dir = tempfile::tempdir().unwrap();
    let files = drifting_series(dir.path());
    let model = model();
    let job = job(6, &dir.path().join("cache"));
    let steps = open(&files, 4);
    let result = pipeline::optimize_series(&steps, &model, &job, &mut go).unwrap();
    let again = pipeline::optimize_series(&open(&files, 4), &model, &job, &mut go).unwrap();
    assert_eq!(
        result.control_points(),
        again.control_points(),
        "not reproducible"
    );

    let ts = result.report.time_series.as_ref().unwrap();
    assert_eq!(ts.total_steps, 3);
    assert_eq!(ts.steps.len(), 3);
    // neghip spans 0..255 and saturates, so every step reaches 255; the series starts at
    // the first step's minimum.
    assert_eq!(ts.range, [steps.stats().step_ranges[0][0], 255.0]);
    assert_eq!(ts.steps.iter().map(|s| s.views).sum::<usize>(), 6 * 3);
    assert!(
        ts.steps.iter().all(|s| s.views > 0),
        "a time step never drawn"
    );
    // About one new step per optimizer step (plus the final scores' pass over all).
    assert!(ts.loads <= 3 + 6 + 3, "{} loads", ts.loads);
    // The run's scores are the mean of the steps' own.
    for (k, score) in result.report.final_scores.iter().enumerate() {
        let mean = ts
            .steps
            .iter()
            .map(|s| s.final_scores[k].cosine)
            .sum::<f64>()
            / 3.0;
        assert!(
            (score.cosine - mean).abs() < 1e-12,
            "{} vs {mean}",
            score.cosine
        );
        assert_eq!(score.caption, ts.steps[0].final_scores[k].caption);
    }
    // The TF spans the series' range (the exports are in data units of every step).
    let tf = result.transfer_function("tf");
    assert_eq!(tf.data_range(), ts.range);
    // preview.png: one row of the preview's orbit per time step shown (first, middle, last).
    let preview = result.preview();
    assert_eq!(preview.height, 3 * preview.width / pipeline::PREVIEW_VIEWS);
}

#[test]
fn the_command_takes_a_pattern_and_selects_steps() {
    let dir = tempfile::tempdir().unwrap();
    drifting_series(dir.path());
    let pattern = dir.path().join("neghip_*_64x64x64_uint8.raw");
    let out = dir.path().join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .arg("optimize")
        .arg(&pattern)
        .args(["--time-steps", "0,2", "--prompt", PROMPT, "--model", MODEL])
        .args([
            "--tokenizer",
            TOKENIZER,
            "--steps",
            "3",
            "--negatives-per-step",
            "8",
        ])
        .arg("--out")
        .arg(&out)
        .env("XDG_CACHE_HOME", dir.path().join("cache"))
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let steps = report["time_series"]["steps"].as_array().unwrap();
    assert_eq!(steps.len(), 2);
    assert_eq!(report["time_series"]["total_steps"], 3);
    assert!(steps[1]["path"].as_str().unwrap().contains("neghip_2_"));

    let info = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .arg("info")
        .arg(&pattern)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("time series: 3 of 3 steps"), "{text}");
    assert!(text.contains("neghip_2_64x64x64_uint8.raw"), "{text}");

    // The time flags on one volume: a one-line error, nothing written.
    let one = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args([
            "optimize",
            VOLUME,
            "--time-range",
            "0,1",
            "--prompt",
            PROMPT,
        ])
        .arg("--out")
        .arg(dir.path().join("none"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&one.stderr);
    assert!(!one.status.success());
    assert!(
        err.contains("time series") && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(!dir.path().join("none").exists());
}

#[test]
fn a_series_in_memory_renders_as_the_same_series_from_files() {
    let dir = tempfile::tempdir().unwrap();
    let files = drifting_series(dir.path());
    let from_files = open(&files, 3);
    let norm = from_files.stats().norm_range;
    let geometry = from_files.representative().unwrap().geometry;
    let volume = |i: usize, range: Option<[f64; 2]>| {
        let bytes: t2tf::volume::SharedBytes =
            std::sync::Arc::new(std::fs::read(&files[i]).unwrap());
        t2tf::volume::Volume::from_shared_over(
            Path::new("array"),
            geometry,
            t2tf::volume::ScalarType::U8,
            t2tf::volume::ByteOrder::Little,
            bytes,
            Default::default(),
            range,
        )
        .unwrap()
    };
    let steps: Vec<(f64, _)> = (0..3)
        .map(|i| (i as f64 * 0.5, volume(i, Some(norm))))
        .collect();
    let held = SeriesSteps::from_volumes("array", steps).unwrap();
    assert_eq!(held.len(), 3);
    assert_eq!(held.stats().range, from_files.stats().range);
    assert_eq!(held.stats().step_ranges, from_files.stats().step_ranges);
    assert_eq!(held.stats().histogram, from_files.stats().histogram);
    for t in 0..3 {
        let (a, b) = (held.step(t).unwrap(), from_files.step(t).unwrap());
        assert_eq!(a.norm_range, b.norm_range);
        let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(a.data()), bits(b.data()), "step {t}");
    }
    assert_eq!(held.loads(), 0);
    // Steps normalized over their own ranges cannot share one TF: refused, naming the step.
    let own: Vec<(f64, _)> = (0..2).map(|i| (i as f64, volume(i, None))).collect();
    let err = SeriesSteps::from_volumes("array", own)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("time step 1") && err.contains("same range"),
        "{err}"
    );
}
