//! The main job as a library: load a volume and a model, optimize a transfer function for a
//! prompt (Algorithm 1 with the paper's defaults), and write the output set `t2tf optimize`
//! writes. The binary is flag parsing, progress printing and error printing around this;
//! the Python module and the ParaView plugin call the same functions.
//!
//! Nothing here reads a process-wide setting: the memory budget, the model's compute
//! settings and the thread pool the caller runs it in are values the caller chooses, and a
//! run stops when the step callback says so (the binary turns Ctrl-C into that).
//!
//! ```no_run
//! # fn main() -> Result<(), t2tf::pipeline::PipelineError> {
//! use std::ops::ControlFlow;
//! use std::path::Path;
//! use t2tf::pipeline::{optimize, Job, Model, ModelOptions, Target};
//!
//! let volume = t2tf::volume::load(Path::new("head.vti"), &Default::default())?;
//! let model = Model::load(&ModelOptions::new("openai/clip-vit-base-patch32"))?;
//! let job = Job::new(Target::Prompt("the teeth of a CT head".into())).validate()?;
//! let result = optimize(&volume, &model, &job, &mut |_event| ControlFlow::Continue(()))?;
//! result.write(Path::new("teeth"), "teeth")?;
//! # Ok(()) }
//! ```

mod model;
mod outputs;

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

pub use model::{Model, ModelOptions};
pub use outputs::check_name;

use crate::camera::{Camera, Orbit, ParaViewCamera, UpAxis};
use crate::image::Image;
use crate::memory::Budget;
use crate::optimize::adapters::{ClipModel, PaperTf, VolumeRenderer};
use crate::optimize::captions::{self, CacheOutcome, CaptionPool};
use crate::optimize::driver::{self, Finished, Models, Positive};
use crate::optimize::report::{Report, StepLog, VolumeInfo};
use crate::optimize::settings::{Settings, ValidSettings};
use crate::optimize::tf_plot::Curve;
use crate::render::{CpuBackend, RenderOptions};
use crate::tf::ControlPoints;
use crate::volume::Volume;

/// Entries of the LUT the optimizer's renderer samples (one per histogram bin).
pub const LUT_SIZE: usize = 256;

/// Views in preview.png and in the final CLIP scores.
pub const PREVIEW_VIEWS: usize = 4;

/// Why a run could not be done. Messages are one line and name what was wrong; none names a
/// command-line flag (the binary adds those where it knows them).
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// Reading the volume.
    #[error(transparent)]
    Volume(#[from] crate::volume::VolumeError),
    /// Finding or loading the model.
    #[error(transparent)]
    Clip(#[from] crate::clip::ClipError),
    /// Something did not fit the memory budget.
    #[error(transparent)]
    Memory(#[from] crate::memory::MemoryError),
    /// The settings, the captions or the loop.
    #[error(transparent)]
    Optimize(#[from] crate::optimize::OptimizeError),
    /// A reference image.
    #[error(transparent)]
    Image(#[from] crate::image::ImageError),
    /// Rendering the script's camera.
    #[error(transparent)]
    Camera(#[from] crate::camera::CameraError),
    /// Writing the TF files and scripts.
    #[error(transparent)]
    Format(#[from] crate::formats::FormatError),
    /// Writing tf.png, preview.png, report.json.
    #[error(transparent)]
    Output(#[from] driver::OutputError),
    /// The output folder.
    #[error(transparent)]
    Fs(#[from] crate::fs::FsError),
    /// A job that cannot run (names the setting).
    #[error("{0}")]
    Job(String),
}

/// What the renders should match.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// A text prompt.
    Prompt(String),
    /// The CLIP embedding of a picture (a PNG file).
    Image(PathBuf),
}

/// One optimization: what to match, against what, with which settings. [`Job::new`] gives
/// the paper's defaults; [`Job::validate`] checks everything that can be checked before the
/// volume and the model are loaded.
#[derive(Clone, Debug)]
pub struct Job {
    /// What the renders should match.
    pub target: Target,
    /// The user's negatives; none means the default "a blank image".
    pub negatives: Vec<String>,
    /// A caption file (one per line) replacing the built-in negative pool.
    pub negatives_file: Option<PathBuf>,
    /// The optimizer's settings (Appendix A's defaults).
    pub settings: Settings,
    /// Which world axis is up in the views.
    pub up: UpAxis,
    /// Ray-marching step in voxels of the level used; `None`: the renderer's.
    pub step_size: Option<f32>,
    /// Mip level to render from; `None`: chosen from the pixel size.
    pub level: Option<usize>,
    /// Rays cast at this image side and upsampled to CLIP's; `None`: CLIP's size.
    pub render_size: Option<usize>,
    /// What the renderer's copies of the volume may take.
    pub budget: Budget,
    /// Where caption embeddings are cached; `None`: not cached. [`Job::new`] sets the user's
    /// cache folder (`$XDG_CACHE_HOME/t2tf`, else `~/.cache/t2tf`).
    pub caption_cache: Option<PathBuf>,
}

impl Job {
    /// The paper's defaults for `target`.
    pub fn new(target: Target) -> Job {
        Job {
            target,
            negatives: Vec::new(),
            negatives_file: None,
            settings: Settings::default(),
            up: UpAxis::default(),
            step_size: None,
            level: None,
            render_size: None,
            budget: Budget::system(),
            caption_cache: captions::cache_dir(),
        }
    }

    /// Check everything that needs neither the volume nor the model: the settings, the
    /// prompt, the reference image's file, the render options, the caption pool and the
    /// negatives.
    pub fn validate(self) -> Result<ValidJob, PipelineError> {
        let settings = self.settings.validate()?;
        match &self.target {
            Target::Prompt(p) => driver::check_prompt(p)?,
            Target::Image(path) => {
                if let Err(e) = crate::input::open(path) {
                    return Err(PipelineError::Job(format!(
                        "{}: the reference image cannot be read: {e}",
                        path.display()
                    )));
                }
            }
        }
        if let Some(s) = self.step_size {
            if !(s.is_finite() && s > 0.0) {
                return Err(PipelineError::Job(format!(
                    "the step size must be a positive number of voxels, got {s}"
                )));
            }
        }
        if let Some(r) = self.render_size {
            if !(8..=4096).contains(&r) {
                return Err(PipelineError::Job(format!(
                    "the render size must be 8 to 4096 pixels, got {r}"
                )));
            }
        }
        let pool = match &self.negatives_file {
            Some(f) => CaptionPool::from_file(f)?,
            None => CaptionPool::builtin(),
        };
        // Never empty (the default negative stands in for none), so the contrastive loss
        // always has a negative.
        let user_negatives = captions::user_negatives(&self.negatives)?;
        Ok(ValidJob {
            job: self,
            settings,
            pool,
            user_negatives,
        })
    }
}

/// A [`Job`] after [`Job::validate`], the only way to make one.
#[derive(Debug)]
pub struct ValidJob {
    job: Job,
    settings: ValidSettings,
    pool: CaptionPool,
    user_negatives: Vec<String>,
}

impl ValidJob {
    /// The job as given.
    pub fn job(&self) -> &Job {
        &self.job
    }

    /// The settings, validated.
    pub fn settings(&self) -> &ValidSettings {
        &self.settings
    }

    /// The negatives the run uses besides the pool's (the default when none were given).
    pub fn user_negatives(&self) -> &[String] {
        &self.user_negatives
    }

    /// The caption pool negatives are drawn from.
    pub fn pool(&self) -> &CaptionPool {
        &self.pool
    }
}

/// What a run reports while it works. The callback returns [`ControlFlow::Break`] to stop the
/// run after the current step (the result is then the TF of that step).
#[derive(Clone, Copy, Debug)]
pub enum Event<'a> {
    /// A phase begins ("optimizing", …).
    Phase(&'a str),
    /// Step `step` (1-based) of `total` is done.
    Step {
        /// Steps done.
        step: usize,
        /// Steps in the run.
        total: usize,
        /// Its losses.
        log: &'a StepLog,
    },
    /// Something the user should know that does not stop the run.
    Warning(&'a str),
}

/// The result of [`optimize`]: the TF, the report, the preview, and what writing the output
/// set needs.
pub struct Optimized {
    /// The run's record (report.json before the output files are listed).
    pub report: Report,
    finished: Finished,
    volume: Volume,
    view: ParaViewCamera,
    unit_distance: f64,
    tf_curve: Curve,
}

impl Optimized {
    /// The optimized TF as the renderer sampled it (normalized positions; σ and RGB).
    pub fn control_points(&self) -> &ControlPoints {
        &self.finished.outcome.control_points
    }

    /// The TF in the volume's data units, as the exported files hold it (named `name`).
    pub fn transfer_function(&self, name: &str) -> crate::formats::ExportTf {
        crate::formats::ExportTf::from_control_points(
            name,
            &self.exported_points(),
            &self.volume,
            Some(self.unit_distance),
        )
    }

    /// The final TF from the preview's orbit views, tiled.
    pub fn preview(&self) -> &Image {
        &self.finished.preview
    }

    /// Whether the run was stopped before its last step.
    pub fn interrupted(&self) -> bool {
        self.finished.outcome.interrupted
    }

    /// Steps run.
    pub fn steps_run(&self) -> usize {
        self.finished.outcome.steps.len()
    }

    /// The camera the exported scripts open with (the preview's first view).
    pub fn camera(&self) -> &ParaViewCamera {
        &self.view
    }

    /// ScalarOpacityUnitDistance of the exported opacity.
    pub fn unit_distance(&self) -> f64 {
        self.unit_distance
    }

    /// What the exports hold: the LUT the renderer sampled, not the raw control points (they
    /// differ where points collapsed within one LUT cell).
    fn exported_points(&self) -> ControlPoints {
        self.control_points().to_lut(LUT_SIZE).to_control_points()
    }
}

/// Run Algorithm 1 for `job` on `volume` with `model`: text embeddings (the pool's cached on
/// disk), initialization, the loop, final scores and the preview. `on_event` sees every
/// phase, step and warning, and stops the run by returning [`ControlFlow::Break`]. Runs on the
/// caller's rayon pool (the global one unless called inside `ThreadPool::install`).
pub fn optimize(
    volume: &Volume,
    model: &Model,
    job: &ValidJob,
    on_event: &mut dyn FnMut(Event) -> ControlFlow<()>,
) -> Result<Optimized, PipelineError> {
    let j = &job.job;
    let clip = model.clip();
    let stop = AtomicBool::new(false);
    let mut emit = |e: Event| {
        if on_event(e).is_break() {
            stop.store(true, Ordering::SeqCst);
        }
    };
    if let Target::Prompt(p) = &j.target {
        // CLIP reads at most its context length; a prompt that fills it was cut (the
        // tokenizer truncates as transformers does). Say so rather than optimize for half a
        // sentence.
        let context = clip.config().text.max_positions;
        if clip.tokenize(&[p])?[0].len() >= context {
            let w = format!(
                "the prompt fills CLIP's {context}-token context; words beyond it are ignored"
            );
            emit(Event::Warning(&w));
        }
    }
    let reference = match &j.target {
        Target::Image(p) => Some(Image::load_png_within(p, j.budget)?),
        Target::Prompt(_) => None,
    };
    let positive = match (&reference, &j.target) {
        (Some(im), _) => Positive::Image(im),
        (None, Target::Prompt(p)) => Positive::Prompt(p),
        (None, Target::Image(_)) => unreachable!("the image was loaded above"),
    };
    let g = volume.geometry;
    let unit_distance = crate::tf::default_unit_distance(&g);
    let options = RenderOptions {
        step: j.step_size.unwrap_or(crate::render::DEFAULT_STEP),
        level: j.level,
        ..Default::default()
    };
    let backend = CpuBackend::new(j.budget);
    let renderer = VolumeRenderer {
        backend: &backend,
        volume,
        options,
        up: j.up,
        size: clip.image_size(),
        render_size: j.render_size.unwrap_or(clip.image_size()),
        jitter: false,
    };
    let settings = &job.settings;
    let cache = j
        .caption_cache
        .as_deref()
        .map(|d| (d, model.cache_key().as_slice()));
    let driver_job = driver::Job {
        settings,
        positive,
        user_negatives: &job.user_negatives,
        pool: &job.pool,
        cache,
        histogram: &volume.histogram,
        logit_scale: model.info().logit_scale,
        preview_views: PREVIEW_VIEWS,
    };
    let clip_model = ClipModel(clip);
    let tf = PaperTf {
        k: settings.control_points,
        lut_size: LUT_SIZE,
    };
    let models = Models {
        renderer: &renderer,
        image_encoder: &clip_model,
        text_encoder: &clip_model,
        tf: &tf,
    };
    emit(Event::Phase(
        "optimizing (caption embeddings are computed first if not cached)",
    ));
    let total = settings.steps;
    let mut step = 0;
    let finished = driver::run_job(&driver_job, &models, &stop, &mut |log, _| {
        step += 1;
        emit(Event::Step { step, total, log });
    })?;
    if let Some(CacheOutcome::NotStored(why)) = &finished.cache {
        emit(Event::Warning(&format!(
            "caption embeddings not cached: {why}"
        )));
    }
    if !finished.init.reached {
        emit(Event::Warning(&format!(
            "even the densest TF leaves mean transmittance {:.3} above rho = {}: the volume is thin from this view",
            finished.init.mean_transmittance, settings.rho
        )));
    }
    let mut report = Report::new(settings.clone().into_inner());
    match &j.target {
        Target::Prompt(p) => report.prompt = Some(p.clone()),
        Target::Image(p) => report.reference_image = Some(p.display().to_string()),
    }
    report.negatives = job.user_negatives.clone();
    report.caption_pool = match &j.negatives_file {
        Some(f) => f.display().to_string(),
        None => "builtin".into(),
    };
    report.caption_pool_size = job.pool.len();
    report.model = model.info().clone();
    report.volume = VolumeInfo {
        path: volume.source.as_ref().map_or_else(
            || "(in memory)".to_string(),
            |s| s.path.display().to_string(),
        ),
        dims: g.dims,
        spacing: g.spacing,
        range: volume.range,
        non_finite_voxels: volume.non_finite,
    };
    report.render = serde_json::json!({
        "step_voxels": options.step,
        "level": options.level,
        "image_size": clip.image_size(),
        "render_size": renderer.render_size,
        "lut_size": LUT_SIZE,
        "threads": rayon::current_num_threads(),
        // Which matrix kernel CLIP runs on this CPU (chosen at run time).
        "clip_engine": clip.compute().describe(),
        "clip_precision": clip.compute().precision.name(),
    });
    finished.fill_report(&mut report);
    let view = script_view(settings, &g, j.up)?;
    Ok(Optimized {
        report,
        finished,
        volume: volume.clone(),
        view,
        unit_distance,
        tf_curve: Curve::Opacity {
            unit_over_length: unit_distance / g.longest_side(),
        },
    })
}

/// The camera the exported scripts open with: the first of the preview's orbit views.
fn script_view(
    settings: &ValidSettings,
    g: &crate::volume::Geometry,
    up: UpAxis,
) -> Result<ParaViewCamera, PipelineError> {
    let first = crate::optimize::View::orbit(settings, PREVIEW_VIEWS)[0].clone();
    let orbit = Orbit {
        yaw: first.yaw,
        pitch: first.pitch,
        distance: first.distance,
        up,
    };
    Ok(Camera::orbit(g, orbit)?.paraview())
}

/// Load a volume file (`.raw`, `.vti`, `.vtk`) as [`crate::volume::load`] does.
pub fn load_volume(
    path: &Path,
    opts: &crate::volume::ReadOptions,
) -> Result<Volume, PipelineError> {
    Ok(crate::volume::load(path, opts)?)
}
