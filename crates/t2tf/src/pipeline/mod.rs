//! The main job as a library: load a volume and a model, optimize a transfer function for a
//! prompt (Algorithm 1 with the paper's defaults), and write the output set `t2tf optimize`
//! writes. The binary is flag parsing, progress printing and error printing around this;
//! the Python module and the ParaView plugin call the same functions. A run of 0 steps from
//! a TF with opacity needs no model ([`optimize_without_model`]).
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
pub mod naming;
mod outputs;
mod start;
mod threads;

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

pub use model::{Model, ModelOptions};
pub use outputs::{check_name, check_outputs, output_files};
pub use start::{check_locks, InitTf, PARAVIEW_TABLE};
pub use threads::{check_threads, workers, Workers};

use crate::camera::{Camera, Orbit, ParaViewCamera, UpAxis};
use crate::image::Image;
use crate::memory::Budget;
use crate::optimize::adapters::{ClipModel, PaperTf, VolumeRenderer, PREVIEW_SIZE};
use crate::optimize::captions::{self, CacheOutcome, CaptionPool};
use crate::optimize::driver::{self, Finished, Models, Positive};
use crate::optimize::report::{
    absolute, InputFile, PhaseTimes, Report, StepLog, TimeSeriesInfo, TimeStepInfo, VolumeInfo,
};
use crate::optimize::series::SeriesSteps;
use crate::optimize::settings::{Settings, ValidSettings};
use crate::optimize::tf_plot::Curve;
use crate::optimize::{OptimizeError, Outcome, Parameterization, Renderer, View};
use crate::render::{CpuBackend, RenderOptions};
use crate::tf::ControlPoints;
use crate::volume::{ByteOrder, SourceFormat, Volume};

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
    /// Where caption embeddings are cached; `None`: not cached. [`Job::new`] sets the
    /// platform's per-user cache folder ([`t2tf_core::platform::cache_dir`]); the CLI and the
    /// Python module set the environment's ([`captions::cache_dir`], which honours
    /// `XDG_CACHE_HOME` on every system).
    pub caption_cache: Option<PathBuf>,
    /// Start from this TF instead of the paper's initialization (a refine).
    pub init: Option<InitTf>,
    /// Data ranges [min, max] whose TF stays as the run starts it: their gradient is masked,
    /// so the loss sees them while their points do not move.
    pub locks: Vec<[f64; 2]>,
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
            caption_cache: t2tf_core::platform::cache_dir(),
            init: None,
            locks: Vec::new(),
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
                    "`step_size` must be a positive number of voxels, got {s}"
                )));
            }
        }
        if let Some(r) = self.render_size {
            if !(8..=4096).contains(&r) {
                return Err(PipelineError::Job(format!(
                    "`render_size` must be 8 to 4096 pixels, got {r}"
                )));
            }
        }
        check_locks(&self.locks)?;
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

    /// Whether the run needs a CLIP model. Every run with steps does; one of 0 steps from a
    /// TF with opacity (`Job::init`) does not: its result is that TF. The paper's
    /// initialization, and the densities a colour map without opacity gets, are measured at
    /// CLIP's image size, so a run of 0 steps that needs them needs the model too.
    pub fn needs_model(&self) -> bool {
        self.settings.steps > 0 || self.job.init.as_ref().is_none_or(InitTf::colours_only)
    }

    /// The checks that need the volume (locks inside its data range, the init's range
    /// meeting it): [`optimize`] makes them first; a caller can make them before loading
    /// the model.
    pub fn check_volume(&self, volume: &Volume) -> Result<(), PipelineError> {
        start::check_against(volume, self.job.init.as_ref(), &self.job.locks)
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
    lut_size: usize,
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
        self.control_points()
            .to_lut(self.lut_size)
            .to_control_points()
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
    run(volume, None, Some(model), job, on_event)
}

/// [`optimize`] for a time series: one TF for all its steps. Each view of a step renders a
/// time step of the schedule (`optimize::schedule::assign_times`); the data range, the
/// histogram of the initialization and the exported TF's range are the series'. The report
/// lists the steps with their own final scores; preview.png has one row per time step shown
/// (first, middle, last); the scripts open the series.
pub fn optimize_series(
    series: &SeriesSteps,
    model: &Model,
    job: &ValidJob,
    on_event: &mut dyn FnMut(Event) -> ControlFlow<()>,
) -> Result<Optimized, PipelineError> {
    run(
        series.representative()?,
        Some(series),
        Some(model),
        job,
        on_event,
    )
}

/// What a run optimizes a TF for: one volume, or the steps of a time series.
#[derive(Clone, Copy, Debug)]
pub enum Scene<'a> {
    /// One volume.
    Volume(&'a Volume),
    /// A time series (one TF for all its steps, [`optimize_series`]).
    Series(&'a SeriesSteps),
}

impl Scene<'_> {
    /// The volume, or the one that stands for the series (`SeriesSteps::representative`):
    /// what the checks of a job against the data read ([`ValidJob::check_volume`]).
    pub fn volume(&self) -> Result<&Volume, PipelineError> {
        match self {
            Scene::Volume(v) => Ok(v),
            Scene::Series(s) => Ok(s.representative()?),
        }
    }
}

/// [`optimize`] or [`optimize_series`] on `scene`; with no model, a job that needs none
/// ([`optimize_without_model`]).
pub fn optimize_scene(
    scene: Scene,
    model: Option<&Model>,
    job: &ValidJob,
    on_event: &mut dyn FnMut(Event) -> ControlFlow<()>,
) -> Result<Optimized, PipelineError> {
    if model.is_none() && job.needs_model() {
        return Err(PipelineError::Job(
            "only a run of 0 steps from a TF with opacity needs no CLIP model".into(),
        ));
    }
    let series = match scene {
        Scene::Volume(_) => None,
        Scene::Series(s) => Some(s),
    };
    run(scene.volume()?, series, model, job, on_event)
}

/// [`optimize`] for a job that needs no model ([`ValidJob::needs_model`] is false: 0 steps
/// from a TF with opacity): the result is the start itself. Its TF files and preview are
/// those [`optimize`] writes with a model whose image size is at most the preview's
/// (`optimize::adapters::PREVIEW_SIZE`); its report has no model and no CLIP scores, and
/// the start's mean transmittance measured at the preview's size. A job that needs a model
/// is an error.
pub fn optimize_without_model(
    volume: &Volume,
    job: &ValidJob,
    on_event: &mut dyn FnMut(Event) -> ControlFlow<()>,
) -> Result<Optimized, PipelineError> {
    optimize_scene(Scene::Volume(volume), None, job, on_event)
}

/// [`optimize`], with no model only where the job needs none ([`optimize_without_model`]).
fn run(
    volume: &Volume,
    series: Option<&SeriesSteps>,
    model: Option<&Model>,
    job: &ValidJob,
    on_event: &mut dyn FnMut(Event) -> ControlFlow<()>,
) -> Result<Optimized, PipelineError> {
    let j = &job.job;
    job.check_volume(volume)?;
    let clip = model.map(Model::clip);
    let stop = AtomicBool::new(false);
    let mut emit = |e: Event| {
        if on_event(e).is_break() {
            stop.store(true, Ordering::SeqCst);
        }
    };
    if let (Some(clip), Target::Prompt(p)) = (clip, &j.target) {
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
    let g = volume.geometry;
    let options = RenderOptions {
        step: j.step_size.unwrap_or(crate::render::DEFAULT_STEP),
        level: j.level,
        ..Default::default()
    };
    let backend = CpuBackend::new(j.budget);
    // Without CLIP nothing is rendered at its size: the one render that is not a preview
    // (the start's mean transmittance, for the report) is made at the preview's.
    let image_size = clip.map_or(PREVIEW_SIZE, |c| c.image_size());
    let renderer = VolumeRenderer {
        backend: &backend,
        volume,
        series,
        options,
        up: j.up,
        size: image_size,
        render_size: j.render_size.unwrap_or(image_size),
        jitter: false,
    };
    let settings = &job.settings;
    let paper = PaperTf {
        k: settings.control_points,
        lut_size: LUT_SIZE,
    };
    // A fresh run is the paper's; a refine or a run with locks starts from given points (the
    // paper's initialization when there is no init, made here so the locks can cut it).
    // The parameterization: the paper's, or the paper's with a given start and locked ranges
    // (`StartTf`).
    let (tf, planned, paper_init): (Box<dyn Parameterization>, _, _) =
        if j.init.is_none() && j.locks.is_empty() {
            (Box::new(paper), None, None)
        } else {
            // The paper's densities are needed without an init, and for a colour-only one.
            let paper_init = if j.init.as_ref().is_none_or(InitTf::colours_only) {
                Some(crate::optimize::initialize(&renderer, &paper, &volume.histogram, settings)?.1)
            } else {
                None
            };
            let p = start::plan(
                volume,
                j.init.as_ref(),
                paper_init.as_ref().map(|i| &i.control_points),
                &j.locks,
                settings.control_points,
            )?;
            (Box::new(p.tf.clone()), Some(p), paper_init)
        };
    let lut_size = tf.lut_size();
    let unit_distance = planned
        .as_ref()
        .map_or_else(|| crate::tf::default_unit_distance(&g), |p| p.unit_distance);
    let finished = match model {
        Some(model) => {
            let reference = match &j.target {
                Target::Image(p) => Some(Image::load_png_within(p, j.budget)?),
                Target::Prompt(_) => None,
            };
            let positive = match (&reference, &j.target) {
                (Some(im), _) => Positive::Image(im),
                (None, Target::Prompt(p)) => Positive::Prompt(p),
                (None, Target::Image(_)) => unreachable!("the image was loaded above"),
            };
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
                start: planned.as_ref().map(|p| driver::Start {
                    control_points: &p.control_points,
                    init: paper_init.as_ref(),
                }),
            };
            let clip_model = ClipModel(model.clip());
            let models = Models {
                renderer: &renderer,
                image_encoder: &clip_model,
                text_encoder: &clip_model,
                tf: &*tf,
            };
            emit(Event::Phase(
                "optimizing (caption embeddings are computed first if not cached)",
            ));
            let total = settings.steps;
            let mut step = 0;
            driver::run_job(&driver_job, &models, &stop, &mut |log, _| {
                step += 1;
                emit(Event::Step { step, total, log });
            })?
        }
        None => {
            let start = planned.as_ref().ok_or_else(|| {
                PipelineError::Job("a run without a model starts from a given TF".into())
            })?;
            emit(Event::Phase("writing the start (0 steps: no model needed)"));
            start_only(&renderer, &*tf, &start.control_points, settings)?
        }
    };
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
        Target::Image(p) => {
            report.reference_image = Some(p.display().to_string());
            report.reference_image_file = Some(input_file(p, "the reference image")?);
        }
    }
    report.negatives = job.user_negatives.clone();
    report.caption_pool = match &j.negatives_file {
        Some(f) => absolute(f),
        None => "builtin".into(),
    };
    report.negatives_file = match &j.negatives_file {
        Some(f) => Some(input_file(f, "the negatives file")?),
        None => None,
    };
    report.caption_pool_size = job.pool.len();
    report.model = model.map(|m| m.info().clone());
    report.volume = volume_info(volume);
    report.time_series = series.map(|s| time_series_info(s, &finished, settings));
    report.render = serde_json::json!({
        // As given (null: the default).
        "up": j.up.to_string(),
        "step_size": j.step_size,
        "level": j.level,
        "max_memory": j.budget.limit(),
        // As used.
        "step_voxels": options.step,
        "image_size": clip.map(|c| c.image_size()),
        "render_size": clip.map(|_| renderer.render_size),
        "lut_size": lut_size,
        "threads": rayon::current_num_threads(),
        // Which matrix kernel CLIP runs on this CPU (chosen at run time).
        "clip_engine": clip.map(|c| c.compute().describe()),
        "clip_precision": clip.map(|c| c.compute().precision.name()),
        // One or two packed copies of the image tower's weights (memory against backward speed).
        "clip_weight_copies": clip.map(|c| c.compute().backward_weight_copies()),
    });
    finished.fill_report(&mut report);
    if let Some(init) = &j.init {
        let file = init.source.is_file().then_some(init.source.as_path());
        let source = file.map_or_else(|| init.source.display().to_string(), absolute);
        report.init = Some(format!("{source} (preset {})", init.preset.tf.name));
        report.init_file = file
            .map(|f| input_file(f, "the TF started from"))
            .transpose()?;
        report.init_preset = Some(init.preset.tf.name.clone());
    }
    report.locks = j.locks.clone();
    let view = script_view(settings, &g, j.up)?;
    Ok(Optimized {
        report,
        finished,
        volume: volume.clone(),
        view,
        unit_distance,
        lut_size,
        tf_curve: Curve::Opacity {
            unit_over_length: unit_distance / g.longest_side(),
        },
    })
}

/// What report.json says of a time series: its steps, how often the run drew each, and the
/// final scores on each.
fn time_series_info(
    series: &SeriesSteps,
    finished: &Finished,
    settings: &ValidSettings,
) -> TimeSeriesInfo {
    let n = series.len();
    let mut views = vec![0usize; n];
    for step in 0..finished.outcome.steps.len() {
        for v in 0..settings.views {
            views[crate::optimize::schedule::time_order(step + v, n, settings.seed)] += 1;
        }
    }
    let s = series.series();
    TimeSeriesInfo {
        collection: s.collection.as_deref().map(absolute),
        total_steps: s.total_steps,
        range: series.stats().range,
        loads: series.loads(),
        steps: s
            .steps
            .iter()
            .enumerate()
            .map(|(i, step)| TimeStepInfo {
                time: step.time,
                path: absolute(&step.path),
                range: series.stats().step_ranges[i],
                views: views[i],
                final_scores: finished.time_scores.get(i).cloned().unwrap_or_default(),
            })
            .collect(),
    }
}

/// What report.json says of the volume: its file absolute, and what its reader decoded.
fn volume_info(volume: &Volume) -> VolumeInfo {
    let g = volume.geometry;
    let mut info = VolumeInfo {
        path: volume
            .source
            .as_ref()
            .map_or_else(|| "(in memory)".to_string(), |s| absolute(&s.path)),
        dims: g.dims,
        spacing: g.spacing,
        range: volume.range,
        non_finite_voxels: volume.non_finite,
        ..VolumeInfo::default()
    };
    if let Some(source) = &volume.source {
        match &source.format {
            SourceFormat::Raw {
                scalar_type,
                byte_order,
            } => {
                info.dtype = Some(scalar_type.to_string());
                info.byte_order = Some(
                    match byte_order {
                        ByteOrder::Little => "little",
                        ByteOrder::Big => "big",
                    }
                    .into(),
                );
            }
            SourceFormat::Vti { array } | SourceFormat::LegacyVtk { array } => {
                info.array = Some(array.clone());
            }
        }
    }
    info
}

/// A file the run read, for report.json: absolute, hashed.
fn input_file(path: &Path, what: &str) -> Result<InputFile, PipelineError> {
    InputFile::read(path).map_err(|e| {
        PipelineError::Job(format!(
            "{}: {what} cannot be read again for report.json: {e}",
            path.display()
        ))
    })
}

/// A run of 0 steps without CLIP: the start's parameters and TF (as the loop returns them
/// after no step), its mean transmittance from the initial view, and the preview.
fn start_only(
    renderer: &VolumeRenderer,
    tf: &dyn Parameterization,
    control_points: &ControlPoints,
    settings: &ValidSettings,
) -> Result<Finished, PipelineError> {
    let mut times = PhaseTimes::default();
    let t0 = Instant::now();
    let (params, init) = crate::optimize::start_from(renderer, tf, control_points, settings)?;
    times.init = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let control_points = tf
        .control_points(&params)
        .map_err(OptimizeError::Parameters)?;
    let lut = control_points.to_lut(tf.lut_size());
    let pictures = View::orbit(settings, PREVIEW_VIEWS)
        .iter()
        .map(|v| renderer.render_preview(&lut, v))
        .collect::<Result<Vec<_>, _>>()
        .map_err(OptimizeError::Renderer)?;
    let preview = driver::tile(&pictures);
    times.other = t0.elapsed().as_secs_f64();
    Ok(Finished {
        outcome: Outcome {
            params,
            control_points,
            steps: Vec::new(),
            times: PhaseTimes::default(),
            interrupted: false,
        },
        init,
        scores: Vec::new(),
        time_scores: Vec::new(),
        times,
        cache: None,
        preview,
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
