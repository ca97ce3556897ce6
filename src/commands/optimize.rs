//! `t2tf optimize`: the flags of Algorithm 1 with the paper's defaults, and their validation.
//!
//! The run itself is the library's (`t2tf::pipeline`): `run` validates everything it can before
//! loading the volume and CLIP, claims the output folder, shows progress, turns Ctrl-C into a
//! stop after the current step, and prints errors with the flags that fix them.

use std::path::{Path, PathBuf};

use std::ops::ControlFlow;

use anyhow::{bail, Context, Result};

use crate::memory::Budget;
use crate::optimize::series::SeriesSteps;
use crate::optimize::settings::{defaults, Settings};
use crate::pipeline::{self, Event, Job, Target, ValidJob};
use crate::progress::{Progress, ProgressMode, StepReport};
use crate::volume;
use crate::{flags, signals, ModelArgs, VolumeArgs};

/// Output folder when `--out` is not given.
use crate::pipeline::naming::{batch_names, DEFAULT_OUT};

/// Optimize a transfer function so renderings of VOLUME match a text prompt.
#[derive(clap::Args, Debug, Clone)]
#[command(
    after_help = "Example:\n  t2tf optimize bonsai_256x256x256_uint8.raw --prompt \"a potted tree\" --out bonsai-tf"
)]
pub struct OptimizeArgs {
    /// The volume (.vti, legacy .vtk, or .raw named NAME_XxYxZ_DTYPE.raw), or a time series:
    /// a .pvd or .series file, or a quoted pattern such as 'name_*.vti': one TF for all
    /// its steps
    pub volume: PathBuf,

    /// More files of a time series that begins with VOLUME (ordered as ParaView orders a
    /// file series)
    #[arg(value_name = "MORE")]
    pub more_volumes: Vec<PathBuf>,

    #[command(flatten)]
    pub volume_args: VolumeArgs,

    #[command(flatten)]
    pub series: crate::SeriesArgs,

    /// What the renderings should show, e.g. "a potted tree". Repeat it for one TF per
    /// prompt in one run (model, volume and captions loaded once): each goes to its own
    /// sub-folder of --out, named from the prompt, and OUT/presets.json holds all of them.
    #[arg(
        long = "prompt",
        value_name = "TEXT",
        required_unless_present = "reference_image"
    )]
    pub prompts: Vec<String>,

    /// Start from this TF file (ParaView .json/.xml, VisIt .ct) instead of the paper's
    /// initialization: a refine. About 50 steps reach what 300 give, in about a fifth of the time
    /// (BENCHMARKS.md, "Design loop"); with 0 steps it writes the start itself. A TF with
    /// opacity keeps its data values; a colour map without opacity (a library preset) is
    /// spread over the data range, as ParaView applies it, with the paper's densities.
    #[arg(long, value_name = "FILE")]
    pub init: Option<PathBuf>,

    /// The preset of --init's file to start from: needed when the file holds several (`t2tf
    /// convert --list FILE` lists them); a file of one preset needs none.
    #[arg(long, value_name = "NAME", requires = "init")]
    pub preset: Option<String>,

    #[command(flatten)]
    pub preset_file: crate::PresetFileArgs,

    /// Keep the TF over the data range MIN,MAX as it starts (repeatable): those points get
    /// no gradient while the rest is optimized.
    #[arg(long = "lock", value_name = "MIN,MAX", value_parser = parse_range, allow_hyphen_values = true)]
    pub locks: Vec<[f64; 2]>,

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

    // Numbers are read signed (`allow_negative_numbers`), so a negative one reaches the
    // validation, which says what is wrong, instead of clap taking it for a flag.
    /// Optimization steps.
    #[arg(long, default_value_t = defaults::STEPS as i128, allow_negative_numbers = true)]
    pub steps: i128,

    /// Random views per step (their gradients are averaged).
    #[arg(long, default_value_t = defaults::VIEWS as i128, allow_negative_numbers = true)]
    pub views: i128,

    /// Initial learning rate (annealed linearly to 0).
    #[arg(long, default_value_t = defaults::LR, allow_negative_numbers = true)]
    pub lr: f64,

    /// SGD momentum.
    #[arg(long, default_value_t = defaults::MOMENTUM, allow_negative_numbers = true)]
    pub momentum: f64,

    /// Weight of the Beta prior on final transmittance (data dependent).
    #[arg(long, default_value_t = defaults::PRIOR_WEIGHT, allow_negative_numbers = true)]
    pub prior_weight: f64,

    /// a = b of the Beta(a, b) prior; below 1 favours clear or opaque rays.
    #[arg(long, default_value_t = defaults::PRIOR_AB, allow_negative_numbers = true)]
    pub prior_ab: f64,

    /// First step (0-based) with the prior switched on.
    #[arg(long, default_value_t = defaults::PRIOR_START as i128, allow_negative_numbers = true)]
    pub prior_start: i128,

    /// λ1: L1 weight on control-point densities.
    #[arg(long, default_value_t = defaults::L1, allow_negative_numbers = true)]
    pub l1: f64,

    /// λ2: L2 weight of colours towards 0.5.
    #[arg(long, default_value_t = defaults::L2, allow_negative_numbers = true)]
    pub l2: f64,

    /// Control points of the transfer function.
    #[arg(
        long,
        value_name = "N",
        default_value_t = defaults::CONTROL_POINTS as i128,
        allow_negative_numbers = true
    )]
    pub control_points: i128,

    /// Caption file (one per line) replacing the built-in negative pool.
    #[arg(long, value_name = "FILE")]
    pub negatives_file: Option<PathBuf>,

    /// Negatives drawn from the pool per step.
    #[arg(long, default_value_t = defaults::NEGATIVES_PER_STEP as i128, allow_negative_numbers = true)]
    pub negatives_per_step: i128,

    /// Seed of views, backgrounds, negatives and initial colours (same seed and threads ⇒
    /// same TF).
    #[arg(long, default_value_t = defaults::SEED as i128, allow_negative_numbers = true)]
    pub seed: i128,

    /// Use the CLIP embedding of this picture as the positive instead of a prompt.
    #[arg(long, value_name = "PNG", conflicts_with = "prompts")]
    pub reference_image: Option<PathBuf>,

    /// Ray-marching step in voxels of the level used; default: the renderer's.
    #[arg(long, allow_negative_numbers = true)]
    pub step_size: Option<f64>,

    /// Mip level to render from (0 = full resolution); default: chosen from the pixel size.
    #[arg(long, allow_negative_numbers = true)]
    pub level: Option<i128>,

    /// Cast rays at this image side and upsample to CLIP's input size (the background stays
    /// sharp): a cheaper render for a blurrier view (BENCHMARKS.md). Default: CLIP's size.
    #[arg(long, value_name = "PIXELS", allow_negative_numbers = true)]
    pub render_size: Option<i128>,

    /// How progress is shown on stderr: a bar on a terminal and a line every few seconds
    /// otherwise (auto), or one JSON object per line for programs (json).
    #[arg(long, value_enum, default_value = "auto")]
    pub progress: ProgressMode,

    /// Worker threads; default: all cores (more than the logical CPUs are capped).
    #[arg(long, allow_negative_numbers = true)]
    pub threads: Option<i128>,

    /// Memory budget for sizes read from files and flags (e.g. 512M, 16G); default: what
    /// the system has available (MemAvailable, within `ulimit -v`).
    #[arg(
        long,
        value_name = "SIZE",
        value_parser = crate::memory::parse_size,
        allow_hyphen_values = true
    )]
    pub max_memory: Option<u64>,
}

/// A count flag's value: 0 or more, else an error naming the flag and the value (as
/// `render` words it); a value past what the library takes is its to refuse, with its limit.
fn count(flag: &str, value: i128) -> Result<usize> {
    if value < 0 {
        bail!("--{flag} {value} must be 0 or more");
    }
    usize::try_from(value).map_err(|_| anyhow::anyhow!("--{flag} {value} is too large"))
}

/// An optional count flag's value ([`count`]).
fn count_opt(flag: &str, value: Option<i128>) -> Result<Option<usize>> {
    value.map(|v| count(flag, v)).transpose()
}

impl OptimizeArgs {
    /// The optimizer settings these flags describe; a negative count is an error naming its
    /// flag (the library checks the rest).
    pub fn settings(&self) -> Result<Settings> {
        let seed = u64::try_from(self.seed).map_err(|_| {
            anyhow::anyhow!(
                "--seed {} must be a whole number from 0 to {}",
                self.seed,
                u64::MAX
            )
        })?;
        Ok(Settings {
            steps: count("steps", self.steps)?,
            views: count("views", self.views)?,
            lr: self.lr,
            momentum: self.momentum,
            prior_weight: self.prior_weight,
            prior_a: self.prior_ab,
            prior_b: self.prior_ab,
            prior_start: count("prior-start", self.prior_start)?,
            l1: self.l1,
            l2: self.l2,
            control_points: count("control-points", self.control_points)?,
            negatives_per_step: count("negatives-per-step", self.negatives_per_step)?,
            seed,
            ..Settings::default()
        })
    }

    /// `--threads` (a negative count is an error naming it).
    pub fn threads(&self) -> Result<Option<usize>> {
        count_opt("threads", self.threads)
    }

    /// The library's jobs these flags describe: one per prompt (or the reference image's).
    pub fn jobs(&self, init: Option<&pipeline::InitTf>) -> Result<Vec<Job>> {
        let targets: Vec<Target> = match &self.reference_image {
            Some(r) => vec![Target::Image(r.clone())],
            None => self.prompts.iter().cloned().map(Target::Prompt).collect(),
        };
        targets
            .into_iter()
            .map(|t| self.job(t, init.cloned()))
            .collect()
    }

    fn job(&self, target: Target, init: Option<pipeline::InitTf>) -> Result<Job> {
        let mut job = Job::new(target);
        job.caption_cache = crate::optimize::captions::cache_dir();
        job.init = init;
        job.locks = self.locks.clone();
        job.negatives = self.negatives.clone();
        job.negatives_file = self.negatives_file.clone();
        job.settings = self.settings()?;
        job.up = self.up;
        job.step_size = self.step_size.map(|s| s as f32);
        job.level = count_opt("level", self.level)?;
        job.render_size = count_opt("render-size", self.render_size)?;
        job.budget = Budget::new(self.max_memory);
        Ok(job)
    }

    /// Whether this run makes one TF per prompt (several `--prompt`).
    pub fn is_batch(&self) -> bool {
        self.prompts.len() > 1
    }

    /// The TF base name: `--name`, or a slug of the prompt (or the reference image's stem);
    /// the library's rule ([`pipeline::naming::tf_name`]). A batch names each TF (and its
    /// sub-folder) from its prompt (`batch_names`).
    pub fn tf_name(&self) -> Result<String> {
        let target = match (self.prompts.first(), &self.reference_image) {
            (Some(p), _) => pipeline::Target::Prompt(p.clone()),
            (None, Some(r)) => pipeline::Target::Image(r.clone()),
            (None, None) => pipeline::Target::Prompt(String::new()),
        };
        pipeline::naming::tf_name(self.name.as_deref(), Some(&self.out), &target).map_err(|e| {
            match &self.name {
                Some(_) => anyhow::anyhow!("--name: {e}"),
                None => anyhow::anyhow!("{e}; choose another --out or give --name"),
            }
        })
    }

    /// Everything that can be checked before loading the volume and the model, checked once:
    /// the flags the library does not see, then the library's job.
    pub fn validate(self) -> Result<ValidArgs> {
        // The settings' bounds (threads, step and render size, …) are the library's to check
        // (`pipeline::check_threads`, `Job::validate`); here only what the flags add.
        // The flags' own numbers first: a negative count says so before anything is read.
        self.settings()?;
        pipeline::check_threads(self.threads()?).map_err(flags::pipeline)?;
        if self.out.exists() && !self.out.is_dir() {
            bail!("{}: --out exists and is not a folder", self.out.display());
        }
        let init = match &self.init {
            Some(f) => Some(
                pipeline::InitTf::read(f, self.preset.as_deref(), self.preset_file.limit())
                    .map_err(|e| anyhow::anyhow!("--init: {}", flags::pipeline(e)))?,
            ),
            None => None,
        };
        let names = if self.is_batch() {
            if self.name.is_some() {
                bail!(
                    "--name names one TF; with several --prompt each TF is named from its prompt"
                );
            }
            let names = batch_names(&self.prompts).map_err(flags::pipeline)?;
            crate::fs::replaceable(&self.out.join("presets.json"))?;
            names
        } else {
            vec![self.tf_name()?]
        };
        // Every file the runs will write, checked before the volume and the model load: a
        // folder or FIFO in the way would otherwise be found only after the last step.
        for name in &names {
            let folder = if self.is_batch() {
                batch_folder(&self.out, name)?
            } else {
                self.out.clone()
            };
            pipeline::check_outputs(&folder, name).map_err(flags::pipeline)?;
        }
        let jobs = self
            .jobs(init.as_ref())?
            .into_iter()
            .map(|j| j.validate().map_err(flags::pipeline))
            .collect::<Result<Vec<_>>>()?;
        Ok(ValidArgs {
            args: self,
            runs: jobs.into_iter().zip(names).collect(),
        })
    }
}

/// The flags of one run after [`OptimizeArgs::validate`], the only way to build them.
#[derive(Debug)]
pub struct ValidArgs {
    args: OptimizeArgs,
    /// Each run's job and TF base name ([`OptimizeArgs::tf_name`], `batch_names`).
    runs: Vec<(ValidJob, String)>,
}

impl ValidArgs {
    /// The flags as given.
    pub fn args(&self) -> &OptimizeArgs {
        &self.args
    }
}

/// `MIN,MAX` as two numbers (`--lock`).
fn parse_range(text: &str) -> Result<[f64; 2], String> {
    let parse = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|_| format!("{text:?} is not MIN,MAX (two numbers, e.g. 120,400)"))
    };
    match text.split_once(',') {
        Some((a, b)) => Ok([parse(a)?, parse(b)?]),
        None => Err(format!(
            "{text:?} is not MIN,MAX (two numbers, e.g. 120,400)"
        )),
    }
}

/// A batch prompt's sub-folder of `out`: a folder or nothing yet, never a symlink (nothing
/// inside an output folder is followed) or another kind of file. Checked before any work and
/// again before writing.
fn batch_folder(out: &Path, name: &str) -> Result<PathBuf> {
    let dir = out.join(name);
    match std::fs::symlink_metadata(&dir) {
        Ok(m) if m.file_type().is_symlink() => bail!(
            "{}: is a symlink; t2tf follows no link inside its output folder: remove it or choose another --out",
            dir.display()
        ),
        Ok(m) if !m.is_dir() => bail!(
            "{}: exists and is not a folder: remove it or choose another --out",
            dir.display()
        ),
        _ => Ok(dir),
    }
}

/// Load the volume and CLIP, run the optimization with progress and Ctrl-C handling, write
/// every output.
pub fn run(args: OptimizeArgs) -> Result<()> {
    // First, so a SIGTERM at any later moment ends with a truthful account of what was
    // written (a result, or nothing).
    let stop = signals::stop_flag();
    let invocation = Invocation::now();
    if !Path::new(&args.volume).exists() && !volume::is_series_path(&args.volume) {
        bail!("{}: no such file", args.volume.display());
    }
    let volume_path = args.volume.clone();
    let run = args
        .validate()
        .with_context(|| volume_path.display().to_string())?;
    let args = run.args();
    let lock = claim_output(&args.out)?;
    let budget = Budget::new(args.max_memory);
    let pool = crate::thread_pool(args.threads()?)?;
    let sets_written = pool.install(|| -> Result<usize> {
        // A series keeps the views of a step and one more loaded: consecutive steps share
        // all their views' time steps but one (`optimize::schedule::assign_times`).
        let keep = run
            .runs
            .first()
            .map_or(1, |(job, _)| job.settings().views + 1);
        let input = args.input(budget, keep)?;
        // Locks and the init's range against the data, before the model loads.
        if let Some((job, _)) = run.runs.first() {
            job.check_volume(input.scene().volume().map_err(flags::pipeline)?)
                .map_err(flags::pipeline)
                .with_context(|| args.volume.display().to_string())?;
        }
        // A run of 0 steps from a TF with opacity is that TF: no model is resolved or loaded.
        let model = if run.runs.iter().any(|(job, _)| job.needs_model()) {
            Some(args.model.load(budget)?)
        } else {
            None
        };
        let batch = args.is_batch();
        // A batch's presets.json lists this run's finished prompts, rewritten after each: the
        // previous run's goes first, so a run killed part way leaves no library that names
        // sub-folders it did not write (checked replaceable in `validate`).
        let library = args.out.join("presets.json");
        if batch {
            crate::fs::remove_name(&library)?;
        }
        let mut written = Vec::with_capacity(run.runs.len());
        for (i, (job, name)) in run.runs.iter().enumerate() {
            if stop.load(std::sync::atomic::Ordering::SeqCst) {
                errln!(
                    "t2tf: stopped: {} of {} prompts not run",
                    run.runs.len() - i,
                    run.runs.len()
                );
                break;
            }
            if batch {
                if let Target::Prompt(p) = &job.job().target {
                    errln!("prompt {} of {}: {p:?}", i + 1, run.runs.len());
                }
            }
            let out = if batch {
                batch_folder(&args.out, name)?
            } else {
                args.out.clone()
            };
            let run = One {
                args,
                invocation: &invocation,
                job,
                model: model.as_ref(),
                stop,
            };
            written.push(run.optimize(&input, &out, name)?);
            if batch {
                crate::formats::write_library(&library, &written)?;
            }
        }
        if batch && !written.is_empty() {
            errln!(
                "wrote {} presets to {} (ParaView: Choose Preset > Import)",
                written.len(),
                library.display()
            );
        }
        Ok(written.len())
    })?;
    // Released (and its file removed) here: `exit` below runs no destructor.
    drop(lock);
    if let Some(sig) = signals::received() {
        if sets_written == 0 {
            errln!(
                "t2tf: stopped by {} before a run started: nothing was written",
                signals::name(sig)
            );
        } else {
            errln!(
                "t2tf: stopped by {}: the TF of the last finished step was written to {}",
                signals::name(sig),
                args.out.display()
            );
        }
        std::process::exit(128 + sig);
    }
    Ok(())
}

/// One run of a (batch) command: its flags, how it was asked for, its job and model.
struct One<'a> {
    args: &'a OptimizeArgs,
    invocation: &'a Invocation,
    job: &'a ValidJob,
    /// `None` for a job that needs no model ([`ValidJob::needs_model`]).
    model: Option<&'a pipeline::Model>,
    stop: &'a std::sync::atomic::AtomicBool,
}

impl One<'_> {
    /// The run with progress on stderr, its output set written to `out` with TF files
    /// `name`; returns the TF. A signal stops the run after the current step (its TF is the
    /// result).
    fn optimize(&self, input: &Input, out: &Path, name: &str) -> Result<crate::formats::ExportTf> {
        let (args, job, stop) = (self.args, self.job, self.stop);
        let steps = job.settings().steps;
        let mut progress = Progress::new(args.progress, steps);
        let mut on_event = |e: Event| {
            match e {
                Event::Phase(what) => progress.phase(what),
                Event::Step { log, .. } => progress.step(&StepReport {
                    loss: log.total,
                    clip: log.clip,
                    prompt_probability: log.prompt_probability,
                }),
                Event::Warning(w) => {
                    progress.suspend(|| errln!("t2tf: warning: {w}"));
                }
            }
            // A signal (also one received while loading) stops the run after this step.
            if stop.load(std::sync::atomic::Ordering::SeqCst) {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        };
        let result = pipeline::optimize_scene(input.scene(), self.model, job, &mut on_event);
        let mut result = result
            .map_err(flags::pipeline)
            .with_context(|| args.volume.display().to_string())?;
        progress.finish();
        if result.interrupted() {
            errln!(
                "stopped after {} of {} steps: writing the TF of the last step",
                result.steps_run(),
                steps
            );
        }
        result.report.argv = Some(self.invocation.argv.clone());
        result.report.cwd = self.invocation.cwd.clone();
        let report = result.write(out, name).map_err(flags::pipeline)?;
        errln!("wrote {} files to {}", report.outputs.len(), out.display());
        progress.done(out, &report.outputs, result.interrupted());
        Ok(result.transfer_function(name))
    }
}

/// What a run optimizes for: one volume, or a time series.
enum Input {
    Volume(Box<crate::volume::Volume>),
    Series(Box<SeriesSteps>),
}

impl Input {
    fn scene(&self) -> pipeline::Scene<'_> {
        match self {
            Input::Volume(v) => pipeline::Scene::Volume(v),
            Input::Series(s) => pipeline::Scene::Series(s),
        }
    }
}

impl OptimizeArgs {
    /// The volume or time series the arguments name, read within `budget`. A series'
    /// statistics are streamed over its steps first (with a line per step on a long one).
    fn input(&self, budget: Budget, keep: usize) -> Result<Input> {
        let mut paths = vec![self.volume.clone()];
        paths.extend(self.more_volumes.iter().cloned());
        let Some(series) = self.series.series(&paths).map_err(flags::volume)? else {
            let v = self
                .volume_args
                .load_within(&self.volume, budget)
                .map_err(flags::volume)?;
            return Ok(Input::Volume(Box::new(v)));
        };
        let n = series.steps.len();
        errln!("reading the statistics of {n} time steps");
        let opts = self.volume_args.read_options_within(budget);
        let steps = SeriesSteps::open(series, opts, keep, &mut |_| {}).map_err(flags::volume)?;
        let first = steps.representative().map_err(flags::volume)?;
        self.volume_args
            .warn_thin(&self.volume, first.geometry.dims);
        Ok(Input::Series(Box::new(steps)))
    }
}

/// How the command was asked for, as report.json records it: the command line as given and
/// the folder it started in.
struct Invocation {
    argv: Vec<String>,
    cwd: Option<String>,
}

thread_local! {
    /// The command line of a run started by a caller that is not this process's `main` (the
    /// Python module's `cli_main`, whose process arguments are Python's).
    static COMMAND_LINE: std::cell::RefCell<Option<Vec<std::ffi::OsString>>> =
        const { std::cell::RefCell::new(None) };
}

impl OptimizeArgs {
    /// Say that the `t2tf` command about to run on this thread was given `argv` (program name
    /// first): report.json records it instead of the process's arguments. `None` forgets it.
    pub fn set_command_line(argv: Option<Vec<std::ffi::OsString>>) {
        COMMAND_LINE.with(|c| *c.borrow_mut() = argv);
    }
}

impl Invocation {
    /// This run's: the command line given to [`OptimizeArgs::set_command_line`] on this
    /// thread, else the process's.
    fn now() -> Invocation {
        let given = COMMAND_LINE.with(|c| c.borrow().clone());
        let argv = given.unwrap_or_else(|| std::env::args_os().collect());
        Invocation {
            argv: argv
                .iter()
                .map(|a| a.to_string_lossy().into_owned())
                .collect(),
            cwd: std::env::current_dir()
                .ok()
                .map(|d| d.display().to_string()),
        }
    }
}

/// Before any work: --out is ours (locked against a second run, which proves it can be
/// created and written) and what killed runs left there is cleaned up. The lock holds while
/// it lives.
fn claim_output(out: &Path) -> Result<crate::fs::OutputLock> {
    let lock = crate::fs::OutputLock::acquire(out)?;
    for name in crate::fs::clean_stale(out)? {
        errln!("t2tf: cleaned up {name}, left in --out by an interrupted run");
    }
    Ok(lock)
}

#[cfg(test)]
mod tests {
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
        assert_eq!(a.settings().unwrap(), Settings::default());
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
        let s = a.settings().unwrap();
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
        // Negative numbers reach the validation, which names the flag.
        for (flag, value) in [
            ("--steps", "-5"),
            ("--views", "-1"),
            ("--prior-start", "-2"),
            ("--control-points", "-3"),
            ("--negatives-per-step", "-4"),
            ("--level", "-1"),
            ("--render-size", "-64"),
            ("--threads", "-2"),
        ] {
            let e = m(&["--prompt", "x", flag, value]);
            assert!(
                e.contains(&format!("{flag} {value} must be 0 or more")),
                "{flag}: {e}"
            );
        }
        assert!(m(&["--prompt", "x", "--seed", "-1"])
            .contains("--seed -1 must be a whole number from 0 to 18446744073709551615"));
        assert!(m(&["--prompt", "x", "--step-size", "-1"]).contains("--step-size"));
        assert!(
            m(&["--prompt", "x", "--lr", "-1"]).contains("--lr: must be finite and ≥ 0, got -1")
        );
        // The largest seed still parses.
        let a = parse(&["--prompt", "x", "--seed", "18446744073709551615"]).unwrap();
        assert_eq!(a.settings().unwrap().seed, u64::MAX);
        // --steps 0 is valid: the result is the initialization.
        parse(&["--prompt", "x", "--steps", "0"])
            .unwrap()
            .validate()
            .unwrap();
    }
}
