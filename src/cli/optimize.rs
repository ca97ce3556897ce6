//! `t2tf optimize`: the flags of Algorithm 1 with the paper's defaults, and their validation.
//!
//! The loop itself is `crate::optimize::optimize`; `run` validates everything it can before
//! loading the volume and CLIP, then binds them to the loop through `optimize::adapters`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use super::{ModelArgs, VolumeArgs};
use crate::image::Image;
use crate::optimize::captions::{self, CacheOutcome, CaptionPool};
use crate::optimize::driver::{self, Finished, Job, Models, Positive, TextEncoder};
use crate::optimize::report::{ModelInfo, Report, StepLog, VolumeInfo};
use crate::optimize::settings::{defaults, Settings, ValidSettings};
use crate::optimize::tf_plot::Curve;
use crate::optimize::{ImageEncoder, Parameterization, Renderer};
use crate::progress::{Progress, ProgressMode, StepReport};
use crate::tf::ControlPoints;

/// Output folder when `--out` is not given.
const DEFAULT_OUT: &str = "t2tf-output";

/// Optimize a transfer function so renderings of VOLUME match a text prompt.
#[derive(clap::Args, Debug, Clone)]
#[command(
    after_help = "Example: t2tf optimize bonsai_256x256x256_uint8.raw --prompt \"a potted tree\" --out bonsai-tf"
)]
pub struct OptimizeArgs {
    /// The volume (.vti, legacy .vtk, or .raw named NAME_XxYxZ_DTYPE.raw).
    pub volume: PathBuf,

    #[command(flatten)]
    pub volume_args: VolumeArgs,

    /// What the renderings should show, e.g. "a potted tree".
    #[arg(long, required_unless_present = "reference_image")]
    pub prompt: Option<String>,

    /// What to suppress (repeatable); default: "a blank image".
    #[arg(long = "negative", value_name = "TEXT")]
    pub negatives: Vec<String>,

    /// Output folder (created if missing).
    #[arg(long, default_value = DEFAULT_OUT)]
    pub out: PathBuf,

    /// Base name of the TF files; default: the --out folder's name, or, without --out, made
    /// from the prompt.
    #[arg(long)]
    pub name: Option<String>,

    #[command(flatten)]
    pub model: ModelArgs,

    /// World axis pointing up in the views: x, y, z, -x, -y or -z (the orbit turns around it).
    #[arg(long, default_value = "z", allow_hyphen_values = true)]
    pub up: crate::camera::UpAxis,

    /// Optimization steps.
    #[arg(long, default_value_t = defaults::STEPS)]
    pub steps: usize,

    /// Random views per step (their gradients are averaged).
    #[arg(long, default_value_t = defaults::VIEWS)]
    pub views: usize,

    /// Initial learning rate (annealed linearly to 0).
    #[arg(long, default_value_t = defaults::LR)]
    pub lr: f64,

    /// SGD momentum.
    #[arg(long, default_value_t = defaults::MOMENTUM)]
    pub momentum: f64,

    /// Weight of the Beta prior on final transmittance (data dependent).
    #[arg(long, default_value_t = defaults::PRIOR_WEIGHT)]
    pub prior_weight: f64,

    /// a = b of the Beta(a, b) prior; below 1 favours clear or opaque rays.
    #[arg(long, default_value_t = defaults::PRIOR_AB)]
    pub prior_ab: f64,

    /// First step (0-based) with the prior switched on.
    #[arg(long, default_value_t = defaults::PRIOR_START)]
    pub prior_start: usize,

    /// λ1: L1 weight on control-point densities.
    #[arg(long, default_value_t = defaults::L1)]
    pub l1: f64,

    /// λ2: L2 weight of colours towards 0.5.
    #[arg(long, default_value_t = defaults::L2)]
    pub l2: f64,

    /// Control points of the transfer function.
    #[arg(long, value_name = "N", default_value_t = defaults::CONTROL_POINTS)]
    pub control_points: usize,

    /// Caption file (one per line) replacing the built-in negative pool.
    #[arg(long, value_name = "FILE")]
    pub negatives_file: Option<PathBuf>,

    /// Negatives drawn from the pool per step.
    #[arg(long, default_value_t = defaults::NEGATIVES_PER_STEP)]
    pub negatives_per_step: usize,

    /// Seed of views, backgrounds, negatives and initial colours (same seed and threads ⇒
    /// same TF).
    #[arg(long, default_value_t = defaults::SEED)]
    pub seed: u64,

    /// Use the CLIP embedding of this picture as the positive instead of a prompt.
    #[arg(long, value_name = "PNG", conflicts_with = "prompt")]
    pub reference_image: Option<PathBuf>,

    /// Ray-marching step in voxels of the level used; default: the renderer's.
    #[arg(long)]
    pub step_size: Option<f64>,

    /// Mip level to render from (0 = full resolution); default: chosen from the pixel size.
    #[arg(long)]
    pub level: Option<usize>,

    /// Cast rays at this image side and upsample to CLIP's input size (the background stays
    /// sharp): a cheaper render for a blurrier view (BENCHMARKS.md). Default: CLIP's size.
    #[arg(long, value_name = "PIXELS")]
    pub render_size: Option<usize>,

    /// How progress is shown on stderr: a bar on a terminal and a line every few seconds
    /// otherwise (auto), or one JSON object per line for programs (json).
    #[arg(long, value_enum, default_value = "auto")]
    pub progress: ProgressMode,

    /// Worker threads; default: all cores (more than the logical CPUs are capped).
    #[arg(long)]
    pub threads: Option<usize>,

    /// Memory budget for sizes read from files and flags (e.g. 512M, 16G); default: what
    /// the system has available (MemAvailable, within `ulimit -v`).
    #[arg(long, value_name = "SIZE", value_parser = crate::memory::parse_size)]
    pub max_memory: Option<u64>,
}

impl OptimizeArgs {
    /// The optimizer settings these flags describe.
    pub fn settings(&self) -> Settings {
        Settings {
            steps: self.steps,
            views: self.views,
            lr: self.lr,
            momentum: self.momentum,
            prior_weight: self.prior_weight,
            prior_a: self.prior_ab,
            prior_b: self.prior_ab,
            prior_start: self.prior_start,
            l1: self.l1,
            l2: self.l2,
            control_points: self.control_points,
            negatives_per_step: self.negatives_per_step,
            seed: self.seed,
            ..Settings::default()
        }
    }

    /// The TF base name: `--name`, or a slug of the prompt (or the reference image's stem).
    pub fn tf_name(&self) -> Result<String> {
        if let Some(n) = &self.name {
            let ok = !n.is_empty()
                && n != "."
                && n != ".."
                && n.chars().all(|c| !c.is_control() && c != '/' && c != '\\');
            if !ok {
                bail!("--name {n:?}: must be a plain file name (no slashes, not empty)");
            }
            return Ok(n.clone());
        }
        // A folder the user named says what the run is for: `--out aneurism-tf` writes
        // aneurism-tf.json, not files named after the prompt.
        if self.out != Path::new(DEFAULT_OUT) {
            let folder = self.out.file_name().map(|f| slug(&f.to_string_lossy()));
            if let Some(f) = folder.filter(|f| !f.is_empty()) {
                return Ok(f);
            }
        }
        let source = match (&self.prompt, &self.reference_image) {
            (Some(p), _) => p.clone(),
            (None, Some(r)) => r
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            (None, None) => String::new(),
        };
        Ok(slug(&source))
    }

    /// Everything that can be checked before loading the volume and the model, checked once:
    /// the settings, the names, the caption pool and the user's negatives.
    pub fn validate(self) -> Result<ValidArgs> {
        let settings = self.settings().validate()?;
        if let Some(p) = &self.prompt {
            // Before loading anything; the driver applies the same rule for library callers.
            crate::optimize::driver::check_prompt(p)?;
        }
        if let Some(r) = &self.reference_image {
            if !r.is_file() {
                bail!("{}: --reference-image is not a readable file", r.display());
            }
        }
        if let Some(s) = self.step_size {
            if !(s.is_finite() && s > 0.0) {
                bail!("--step-size must be a positive number of voxels, got {s}");
            }
        }
        if self.threads == Some(0) {
            bail!("--threads must be at least 1");
        }
        if let Some(r) = self.render_size {
            if !(8..=4096).contains(&r) {
                bail!("--render-size must be 8 to 4096 pixels, got {r}");
            }
        }
        if self.out.exists() && !self.out.is_dir() {
            bail!("{}: --out exists and is not a folder", self.out.display());
        }
        let name = self.tf_name()?;
        let pool = match &self.negatives_file {
            Some(f) => CaptionPool::from_file(f)?,
            None => CaptionPool::builtin(),
        };
        // Never empty (the default negative stands in for none), so the contrastive loss
        // always has a negative here; the loop checks that rule for library callers.
        let user_negatives = captions::user_negatives(&self.negatives)?;
        Ok(ValidArgs {
            args: self,
            settings,
            pool,
            user_negatives,
            name,
        })
    }
}

/// The flags of one run after [`OptimizeArgs::validate`], the only way to build them: what
/// `run` and [`execute`] take as given.
#[derive(Debug)]
pub struct ValidArgs {
    args: OptimizeArgs,
    settings: ValidSettings,
    pool: CaptionPool,
    user_negatives: Vec<String>,
    /// The TF base name ([`OptimizeArgs::tf_name`]).
    name: String,
}

impl ValidArgs {
    /// The flags as given.
    pub fn args(&self) -> &OptimizeArgs {
        &self.args
    }

    /// The optimizer settings, validated.
    pub fn settings(&self) -> &ValidSettings {
        &self.settings
    }
}

/// Lower-case words of letters and digits joined by '-', at most 48 characters; "tf" if none.
fn slug(text: &str) -> String {
    let mut s = String::new();
    for word in text
        .split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
    {
        let w = word.to_lowercase();
        if s.len() + w.len() + 1 > 48 {
            break;
        }
        if !s.is_empty() {
            s.push('-');
        }
        s.push_str(&w);
    }
    if s.is_empty() {
        "tf".into()
    } else {
        s
    }
}

/// What `execute` needs to know about the loaded volume and model.
#[derive(Clone, Debug)]
pub struct Loaded {
    /// `Volume::histogram`.
    pub histogram: Vec<u64>,
    pub volume: VolumeInfo,
    pub model: ModelInfo,
    /// Key of the caption-embedding cache: the weights, tokenizer and config hashed together
    /// (`captions::model_key`; `None`: no cache).
    pub weights_hash: Option<Vec<u8>>,
    /// Renderer settings for the report (step size, level, threads, …).
    pub render: serde_json::Value,
    /// Views in preview.png.
    pub preview_views: usize,
    /// What tf.png plots: `Curve::Opacity { unit_over_length: u / L }` with the exported
    /// ScalarOpacityUnitDistance u and `Geometry::longest_side()` L.
    pub tf_curve: Curve,
}

/// Writes the TF files (`NAME.json`, `NAME.xml`, `NAME.ct`, scripts) into the folder and
/// returns the names written. `crate::formats` provides them.
pub type Exporter<'a> = dyn FnMut(&Path, &str, &ControlPoints) -> Result<Vec<String>> + 'a;

/// The whole command once the volume and model are loaded: run Algorithm 1 with a progress
/// bar and Ctrl-C handling, export the TF (`export`), then write tf.png, preview.png and
/// report.json. Returns the report.
pub fn execute<R: Renderer, E: ImageEncoder, T: TextEncoder, P: Parameterization>(
    run: &ValidArgs,
    ctx: &Loaded,
    models: &Models<R, E, T, P>,
    export: &mut Exporter,
) -> Result<Report> {
    let ValidArgs {
        args,
        settings,
        pool,
        user_negatives: user,
        name,
    } = run;
    let reference = match &args.reference_image {
        Some(p) => Some(Image::load_png(p)?),
        None => None,
    };
    let positive = match (&reference, &args.prompt) {
        (Some(im), _) => Positive::Image(im),
        (None, Some(p)) => Positive::Prompt(p),
        (None, None) => bail!("give --prompt TEXT or --reference-image PNG"),
    };
    let cache_dir = captions::cache_dir();
    let cache = match (&cache_dir, &ctx.weights_hash) {
        (Some(d), Some(h)) => Some((d.as_path(), h.as_slice())),
        _ => None,
    };
    let job = Job {
        settings,
        positive,
        user_negatives: user,
        pool,
        cache,
        histogram: &ctx.histogram,
        logit_scale: ctx.model.logit_scale,
        preview_views: ctx.preview_views,
    };
    // Not cleared here: a signal received while the volume and model loaded must still stop
    // the run (after one step) and be reported by the exit code.
    let stop = crate::signals::stop_flag();
    let mut progress = Progress::new(args.progress, settings.steps);
    progress.phase("optimizing (caption embeddings are computed first if not cached)");
    let mut on_step = |log: &StepLog, _total: usize| {
        progress.step(&StepReport {
            loss: log.total,
            clip: log.clip,
            prompt_probability: log.prompt_probability,
        });
    };
    let finished = driver::run_job(&job, models, stop, &mut on_step)
        .with_context(|| format!("t2tf optimize {}", args.volume.display()))?;
    progress.finish();
    if finished.outcome.interrupted {
        eprintln!(
            "stopped after {} of {} steps: writing the TF of the last step",
            finished.outcome.steps.len(),
            settings.steps
        );
    }
    if let Some(CacheOutcome::NotStored(why)) = &finished.cache {
        eprintln!("warning: caption embeddings not cached: {why}");
    }
    if !finished.init.reached {
        eprintln!(
            "warning: even the densest TF leaves mean transmittance {:.3} above rho = {}: the volume is thin from this view",
            finished.init.mean_transmittance, settings.rho
        );
    }

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create the output folder", args.out.display()))?;
    // The files go out as one set: staged, then moved in with report.json last.
    let set = crate::fs::OutputSet::begin(&args.out)?;
    let mut report = new_report(run, ctx, &finished);
    let t0 = std::time::Instant::now();
    report.outputs = export(set.dir(), name, &finished.outcome.control_points)?;
    report.timings.output += t0.elapsed().as_secs_f64();
    driver::write_outputs(
        set.dir(),
        &mut report,
        &finished,
        &ctx.histogram,
        ctx.tf_curve,
    )?;
    set.commit(&report.outputs)?;
    eprintln!(
        "wrote {} files to {}",
        report.outputs.len(),
        args.out.display()
    );
    progress.done(&args.out, &report.outputs, finished.outcome.interrupted);
    Ok(report)
}

/// report.json's content before the outputs are written: the flags, what was loaded and what
/// the run found.
fn new_report(run: &ValidArgs, ctx: &Loaded, finished: &Finished) -> Report {
    let args = &run.args;
    let mut report = Report::new(run.settings.clone().into_inner());
    report.prompt = args.prompt.clone();
    report.reference_image = args
        .reference_image
        .as_ref()
        .map(|p| p.display().to_string());
    report.negatives = run.user_negatives.clone();
    report.caption_pool = match &args.negatives_file {
        Some(f) => f.display().to_string(),
        None => "builtin".into(),
    };
    report.caption_pool_size = run.pool.len();
    report.model = ctx.model.clone();
    report.volume = ctx.volume.clone();
    report.render = ctx.render.clone();
    finished.fill_report(&mut report);
    report
}

/// Entries of the LUT the renderer samples (one per histogram bin).
const LUT_SIZE: usize = 256;

/// Load the volume and CLIP, run Algorithm 1, write every output.
pub fn run(args: OptimizeArgs) -> Result<()> {
    use crate::optimize::adapters::{ClipModel, PaperTf, VolumeRenderer};
    if !Path::new(&args.volume).exists() {
        bail!("{}: volume file not found", args.volume.display());
    }
    let volume_path = args.volume.clone();
    let run = args
        .validate()
        .with_context(|| format!("t2tf optimize {}", volume_path.display()))?;
    let args = run.args();
    let _lock = claim_output_and_process(args)?;
    let volume = args.volume_args.load(&args.volume)?;
    let LoadedModel {
        clip,
        precision,
        info: model_info,
        cache_key,
    } = load_model(args)?;
    let g = volume.geometry;
    let unit = crate::tf::default_unit_distance(&g);
    let options = crate::render::RenderOptions {
        step: args
            .step_size
            .map_or(crate::render::DEFAULT_STEP, |s| s as f32),
        level: args.level,
        ..Default::default()
    };
    let renderer = VolumeRenderer {
        volume: &volume,
        options,
        up: args.up,
        size: clip.image_size(),
        render_size: args.render_size.unwrap_or(clip.image_size()),
        jitter: false,
    };
    let ctx = Loaded {
        histogram: volume.histogram.clone(),
        volume: VolumeInfo {
            path: args.volume.display().to_string(),
            dims: g.dims,
            spacing: g.spacing,
            range: volume.range,
            non_finite_voxels: volume.non_finite,
        },
        model: model_info,
        weights_hash: Some(cache_key.to_vec()),
        render: serde_json::json!({
            "step_voxels": options.step,
            "level": options.level,
            "image_size": clip.image_size(),
            "render_size": renderer.render_size,
            "lut_size": LUT_SIZE,
            "threads": rayon::current_num_threads(),
            // Which matrix kernel CLIP runs on this CPU (chosen at run time).
            "clip_engine": crate::clip::packed::with_precision(
                precision,
                crate::clip::packed::describe,
            ),
        }),
        preview_views: 4,
        tf_curve: Curve::Opacity {
            unit_over_length: unit / g.longest_side(),
        },
    };
    let view = script_view(run.settings(), ctx.preview_views, &g, renderer.up)?;
    let mut export = |dir: &Path, name: &str, cp: &ControlPoints| -> Result<Vec<String>> {
        // Export the TF the renderer sampled (its LUT), not the raw control points: they
        // differ where points collapsed within one LUT cell; simplification keeps it small.
        let sampled = cp.to_lut(LUT_SIZE).to_control_points();
        let w =
            crate::formats::write_all(dir, name, &sampled, &volume, &view, [1.0; 3], Some(unit))?;
        let mut names = vec![w.json, w.xml, w.ct];
        names.extend(w.paraview_script);
        names.extend(w.visit_script);
        Ok(names
            .iter()
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect())
    };
    let clip_model = ClipModel(&clip);
    let tf = PaperTf {
        k: args.control_points,
        lut_size: LUT_SIZE,
    };
    let models = Models {
        renderer: &renderer,
        image_encoder: &clip_model,
        text_encoder: &clip_model,
        tf: &tf,
    };
    execute(&run, &ctx, &models, &mut export)?;
    if let Some(sig) = crate::signals::received() {
        eprintln!(
            "t2tf: stopped by {}: the TF of the last finished step was written to {}",
            crate::signals::name(sig),
            args.out.display()
        );
        std::process::exit(128 + sig);
    }
    Ok(())
}

/// Before any work: --out is ours (locked against a second run, which proves it can be
/// created and written), what killed runs left there is cleaned up, the stop handlers are in
/// place, and the memory budget and thread pool are set. The lock holds while it lives.
fn claim_output_and_process(args: &OptimizeArgs) -> Result<crate::fs::OutputLock> {
    let lock = crate::fs::OutputLock::acquire(&args.out)?;
    for name in crate::fs::clean_stale(&args.out)? {
        eprintln!("t2tf: cleaned up {name}, left in --out by an interrupted run");
    }
    // Installed now, so a SIGTERM while loading still ends with a written result.
    crate::signals::stop_flag();
    crate::memory::set_limit(args.max_memory);
    if let Some(t) = args.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(crate::memory::thread_count(t))
            .build_global()
            .context("--threads: cannot start the thread pool")?;
    }
    Ok(lock)
}

/// CLIP as the run uses it, and what report.json and the caption cache say about it.
struct LoadedModel {
    clip: crate::clip::Clip,
    precision: crate::clip::packed::Precision,
    info: ModelInfo,
    /// Key of the caption-embedding cache (`captions::model_key`).
    cache_key: [u8; 32],
}

/// Resolve and load `--model` at `--precision` (once its weights are known to fit the
/// memory budget), warn about a prompt longer than CLIP reads, and hash the files.
fn load_model(args: &OptimizeArgs) -> Result<LoadedModel> {
    let precision = args.model.precision()?;
    let model = args.model.resolve(precision)?;
    let files = &model.files;
    check_model_size(files)?;
    let clip = model.load()?;
    if let Some(prompt) = args.prompt.as_deref() {
        // CLIP reads at most its context length; a prompt that fills it was cut (the tokenizer
        // truncates as transformers does). Say so rather than optimize for half a sentence.
        let context = clip.config().text.max_positions;
        if clip.tokenize(&[prompt])?[0].len() >= context {
            eprintln!(
                "t2tf: warning: --prompt fills CLIP's {context}-token context; words beyond it are ignored"
            );
        }
    }
    let weights_hash = captions::hash_files(&files.weights)?;
    let hex: String = weights_hash.iter().map(|b| format!("{b:02x}")).collect();
    // Cached caption embeddings belong to the weights, the tokenizer and the config together.
    let mut cache_key = captions::model_key(
        &weights_hash,
        &[files.tokenizer.clone(), files.config.clone()],
    )?;
    if precision != crate::clip::packed::Precision::F32 {
        // Embeddings computed in bf16 differ from f32 ones: their own cache entry, so a later
        // f32 run never reuses them (f32 keeps the key it always had).
        use sha2::Digest;
        let mut h = sha2::Sha256::new();
        h.update(cache_key);
        h.update(format!(" precision={}", precision.name()));
        cache_key = h.finalize().into();
    }
    let info = ModelInfo {
        id: args.model.model.clone(),
        revision: model.revision.clone(),
        weights_sha256: Some(hex),
        logit_scale: clip.logit_scale() as f64,
    };
    Ok(LoadedModel {
        clip,
        precision,
        info,
        cache_key,
    })
}

/// The camera the exported scripts open with: the first of the preview's orbit views.
fn script_view(
    settings: &ValidSettings,
    preview_views: usize,
    g: &crate::volume::Geometry,
    up: crate::camera::UpAxis,
) -> Result<crate::camera::ParaViewCamera> {
    let first = crate::optimize::View::orbit(settings, preview_views)[0].clone();
    let cam = crate::camera::Camera::orbit(
        g,
        crate::camera::Orbit {
            yaw: first.yaw,
            pitch: first.pitch,
            distance: first.distance,
            up,
        },
    )?
    .paraview();
    Ok(cam)
}

/// The model's f32 weights must fit the memory budget before they are read.
fn check_model_size(files: &crate::clip::load::ModelFiles) -> Result<()> {
    let config = crate::clip::ClipConfig::from_file(&files.config)?;
    crate::memory::check(
        "the CLIP model's weights",
        Some(config.f32_bytes()),
        1,
        "choose a smaller --model",
    )?;
    Ok(())
}

/// The analytic stand-ins of the optimizer's integration tests, for `execute`'s test below.
#[cfg(test)]
#[path = "../../tests/optimize_toy/mod.rs"]
mod optimize_toy;

#[cfg(test)]
mod tests {
    use super::optimize_toy::*;
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Wrap {
        #[command(flatten)]
        a: OptimizeArgs,
    }

    fn parse(args: &[&str]) -> Result<OptimizeArgs, clap::Error> {
        let mut v = vec!["t2tf", "vol.raw"];
        v.extend_from_slice(args);
        Wrap::try_parse_from(v).map(|w| w.a)
    }

    #[test]
    fn defaults_are_the_papers() {
        let a = parse(&["--prompt", "a potted tree"]).unwrap();
        assert_eq!(a.settings(), Settings::default());
        assert_eq!(a.model.model, crate::clip::DEFAULT_MODEL);
        assert_eq!(a.tf_name().unwrap(), "a-potted-tree");
        let a = parse(&["--prompt", "a potted tree", "--out", "runs/Bonsai TF"]).unwrap();
        assert_eq!(a.tf_name().unwrap(), "bonsai-tf");
        let a = parse(&[
            "--prompt",
            "a potted tree",
            "--out",
            "runs/x",
            "--name",
            "y",
        ])
        .unwrap();
        assert_eq!(a.tf_name().unwrap(), "y");
    }

    #[test]
    fn flags_reach_the_settings() {
        let a = parse(&[
            "--prompt",
            "x",
            "--steps",
            "50",
            "--views",
            "1",
            "--lr",
            "5",
            "--momentum",
            "0.5",
            "--prior-weight",
            "0.1",
            "--prior-ab",
            "0.3",
            "--prior-start",
            "10",
            "--l1",
            "0",
            "--l2",
            "1e-3",
            "--control-points",
            "8",
            "--negatives-per-step",
            "16",
            "--seed",
            "9",
            "--negative",
            "a human skull",
            "--negative",
            "a human face",
        ])
        .unwrap();
        let s = a.settings();
        assert_eq!((s.steps, s.views, s.lr, s.momentum), (50, 1, 5.0, 0.5));
        assert_eq!(
            (s.prior_weight, s.prior_a, s.prior_b, s.prior_start),
            (0.1, 0.3, 0.3, 10)
        );
        assert_eq!(
            (s.l1, s.l2, s.control_points, s.negatives_per_step, s.seed),
            (0.0, 1e-3, 8, 16, 9)
        );
        assert_eq!(a.negatives.len(), 2);
    }

    #[test]
    fn prompt_or_reference_image_is_required_not_both() {
        assert!(parse(&[]).is_err());
        assert!(parse(&["--reference-image", "a.png"]).is_ok());
        assert!(parse(&["--prompt", "x", "--reference-image", "a.png"]).is_err());
    }

    #[test]
    fn validation_gives_clear_errors() {
        let m = |args: &[&str]| format!("{:#}", parse(args).unwrap().validate().unwrap_err());
        assert!(m(&["--prompt", "  "]).contains("--prompt is empty"));
        assert!(m(&["--prompt", "x", "--views", "0"]).contains("--views"));
        assert!(m(&["--prompt", "x", "--momentum", "1.5"]).contains("--momentum"));
        assert!(m(&["--prompt", "x", "--control-points", "1"]).contains("--control-points"));
        assert!(m(&["--prompt", "x", "--negative", " "]).contains("negative"));
        assert!(m(&["--prompt", "x", "--name", "a/b"]).contains("--name"));
        assert!(m(&["--prompt", "x", "--step-size", "0"]).contains("--step-size"));
        assert!(m(&["--reference-image", "missing.png"]).contains("missing.png"));
        assert!(
            m(&["--prompt", "x", "--negatives-file", "no-such-captions.txt"])
                .contains("no-such-captions.txt")
        );
        // --steps 0 is valid: the result is the initialization.
        parse(&["--prompt", "x", "--steps", "0"])
            .unwrap()
            .validate()
            .unwrap();
    }

    fn loaded() -> Loaded {
        let mut histogram = vec![100u64; 256];
        histogram[0] = 50_000;
        Loaded {
            histogram,
            volume: VolumeInfo {
                path: "toy".into(),
                dims: [6, 6, 1],
                spacing: [1.0; 3],
                range: [0.0, 1.0],
                non_finite_voxels: 0,
            },
            model: ModelInfo {
                id: "toy".into(),
                revision: None,
                weights_sha256: Some("00".into()),
                logit_scale: 100.0,
            },
            weights_hash: Some(b"toy weights".to_vec()),
            render: serde_json::json!({"step_size": 0.5}),
            preview_views: 4,
            tf_curve: Curve::Opacity {
                unit_over_length: 1.0 / 6.0,
            },
        }
    }

    #[test]
    fn execute_writes_the_outputs_and_reuses_the_caption_cache() {
        let dir = tempfile::tempdir().unwrap();
        // The cache goes under XDG_CACHE_HOME (only this test in this binary reads it).
        std::env::set_var("XDG_CACHE_HOME", dir.path().join("cache"));
        let f = Fixture::new();
        let t = ToyText {
            known: vec![("a red and yellow thing".into(), f.positive.clone())],
            calls: 0.into(),
            texts: 0.into(),
        };
        let out = dir.path().join("red-thing");
        let argv = [
            "t2tf",
            "toy.raw",
            "--prompt",
            "a red and yellow thing",
            "--steps",
            "20",
            "--views",
            "2",
            "--lr",
            "0.05",
            "--control-points",
            "5",
            "--negatives-per-step",
            "16",
            "--out",
            out.to_str().unwrap(),
        ];
        let run = Wrap::try_parse_from(argv).unwrap().a.validate().unwrap();
        let exported = std::cell::RefCell::new(Vec::new());
        let mut export =
            |d: &Path, name: &str, cp: &ControlPoints| -> anyhow::Result<Vec<String>> {
                let file = format!("{name}.json");
                std::fs::write(d.join(&file), format!("{:?}", cp.sigma))?;
                exported.borrow_mut().push(cp.clone());
                Ok(vec![file])
            };
        let models = Models {
            renderer: &f.toy,
            image_encoder: &f.enc,
            text_encoder: &t,
            tf: &TanhTf,
        };
        let report = execute(&run, &loaded(), &models, &mut export).unwrap();
        assert_eq!(report.steps_run, 20);
        assert_eq!(report.negatives, vec!["a blank image"]);
        assert_eq!(report.caption_pool, "builtin");
        assert!(report.caption_pool_size >= 5000);
        assert_eq!(report.render["step_size"], 0.5);
        for name in [
            // Named after the --out folder.
            "red-thing.json",
            "tf.png",
            "preview.png",
            "report.json",
        ] {
            assert!(out.join(name).is_file(), "{name} missing");
            assert!(
                report.outputs.iter().any(|o| o == name),
                "{name} not listed"
            );
        }
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
        assert_eq!(json["prompt"], "a red and yellow thing");
        assert_eq!(json["model"]["id"], "toy");
        assert_eq!(json["settings"]["steps"], 20);
        let done = exported.borrow().clone();
        assert_eq!(done.len(), 1);
        assert_eq!(done[0].len(), 5);
        assert!(done[0]
            .sigma
            .iter()
            .all(|s| s.is_finite() && (0.0..=255.0).contains(s)));
        // The whole pool was encoded once, then cached: a second run encodes only 2 texts.
        let first = t.texts.get();
        assert!(first >= report.caption_pool_size);
        let cached = std::fs::read_dir(dir.path().join("cache/t2tf/text-embeddings"))
            .unwrap()
            .count();
        assert_eq!(cached, 1);
        execute(&run, &loaded(), &models, &mut export).unwrap();
        assert_eq!(t.texts.get() - first, 2);
    }

    #[test]
    fn slugs() {
        assert_eq!(slug("The teeth of a CT head!"), "the-teeth-of-a-ct-head");
        assert_eq!(slug("  ...  "), "tf");
        assert!(slug(&"word ".repeat(40)).len() <= 48);
    }
}
