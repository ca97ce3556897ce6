//! `t2tf.optimize` and `t2tf.load_model`: the job and the model from Python's arguments,
//! run in a rayon pool built as the CLI builds it, so the same volume, settings, seed and
//! threads give the CLI's TF bit for bit (`events` runs it and forwards its progress).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use t2tf::clip::{Compute, Precision};
use t2tf::formats;
use t2tf::memory::Budget;
use t2tf::optimize::settings::{defaults, Settings};
use t2tf::pipeline::{self, Job, Model, ModelOptions, Target};

use crate::errors;
use crate::events::run_with_events;
use crate::result::OptimizeResult;
use crate::tf::PyTransferFunction;

/// A CLIP model loaded once, to run several optimizations with: what `load_model` returns
/// and `optimize(model=...)` takes. `id` is the Hub id or folder it was loaded from.
#[pyclass(name = "Model", module = "t2tf", frozen)]
pub struct PyModel {
    model: Arc<Model>,
}

#[pymethods]
impl PyModel {
    /// The Hub id or folder it was loaded from.
    #[getter]
    fn id(&self) -> &str {
        &self.model.info().id
    }

    fn __repr__(&self) -> String {
        format!("Model({:?})", self.model.info().id)
    }
}

/// A memory budget from bytes (int) or a size like "16G"; None: what the system has.
fn budget(max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<Budget> {
    let bytes = match max_memory {
        None => None,
        Some(m) => Some(match m.extract::<u64>() {
            Ok(b) => b,
            Err(_) => {
                let text: String = m.extract()?;
                t2tf::memory::parse_size(&text)
                    .map_err(|e| errors::settings(format!("max_memory: {e}")))?
            }
        }),
    };
    Ok(Budget::new(bytes))
}

/// Load a CLIP model once, to run several optimizations with (`optimize(model=...)`).
///
/// Parameters:
///     model: a Hugging Face Hub id (downloaded into the Hugging Face cache on first use)
///         or a local folder with config.json, tokenizer.json and the weights; None:
///         DEFAULT_MODEL.
///     tokenizer: a tokenizer.json to use instead of the model's own; None: its own.
///     revision: branch, tag, pull-request ref or commit of a Hub model; None: main.
///     precision: number format of CLIP's products: "auto" (bf16 where this CPU has a
///         bf16 kernel, AMX or AVX512_BF16, and a calibration kept per CPU measures it
///         faster, else f32), "f32" (bit-reproducible) or "bf16".
///     max_memory: memory budget for the weights, bytes (int) or a size like "16G";
///         None: what the system has.
///
/// Raises ModelError when the model cannot be found or loaded.
#[pyfunction]
#[pyo3(
    signature = (model = None, *, tokenizer = None, revision = None, precision = "auto", max_memory = None),
    text_signature = "(model=None, *, tokenizer=None, revision=None, precision='auto', max_memory=None)"
)]
pub fn load_model(
    py: Python<'_>,
    model: Option<PathBuf>,
    tokenizer: Option<PathBuf>,
    revision: Option<String>,
    precision: &str,
    max_memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<PyModel> {
    load_model_reporting(py, model, tokenizer, revision, precision, max_memory, None)
}

/// `load_model`, with a download's progress given to `progress` (a run's callback) as
/// `{"event": "download", …}` dicts, or shown on stderr as the command shows it.
fn load_model_reporting(
    py: Python<'_>,
    model: Option<PathBuf>,
    tokenizer: Option<PathBuf>,
    revision: Option<String>,
    precision: &str,
    max_memory: Option<&Bound<'_, PyAny>>,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyModel> {
    let compute = compute(precision)?;
    let mut opts = ModelOptions::new(model.map_or_else(
        || t2tf::clip::DEFAULT_MODEL.to_string(),
        |m| m.to_string_lossy().into_owned(),
    ));
    if let Some(r) = revision {
        opts.revision = r;
    }
    opts.tokenizer = tokenizer;
    opts.compute = compute;
    // The `HF_*` variables, read here at the edge as the command reads them.
    opts.hub = match progress {
        Some(callback) => t2tf::hub::HubSettings {
            on_event: Some(crate::events::download_sink(callback)),
            ..t2tf::hub::HubSettings::from_env()
        },
        None => t2tf_cli::download_progress::on_stderr(t2tf::hub::HubSettings::from_env()),
    };
    opts.budget = budget(max_memory)?;
    let model = py.detach(|| Model::load(&opts)).map_err(errors::pipeline)?;
    Ok(PyModel {
        model: Arc::new(model),
    })
}

/// The model `optimize` was given: a loaded one, else loaded now from the keywords.
fn model_for(
    py: Python<'_>,
    model: Option<&Bound<'_, PyAny>>,
    tokenizer: Option<PathBuf>,
    revision: Option<String>,
    precision: &str,
    max_memory: Option<&Bound<'_, PyAny>>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Arc<Model>> {
    if let Some(m) = model.and_then(|m| m.cast::<PyModel>().ok()) {
        if tokenizer.is_some() || revision.is_some() || precision != "auto" {
            return Err(errors::settings(
                "tokenizer, revision and precision are the loaded model's: give them to load_model",
            ));
        }
        return Ok(m.get().model.clone());
    }
    let path = model.map(|m| m.extract::<PathBuf>()).transpose()?;
    let loaded = load_model_reporting(
        py, path, tokenizer, revision, precision, max_memory, progress,
    )?;
    Ok(loaded.model)
}

/// The paper's settings and the render options `optimize` takes as keywords, as the CLI's
/// flags of the same names set them.
fn apply_settings(job: &mut Job, extra: Option<&Bound<'_, PyDict>>) -> PyResult<()> {
    let Some(extra) = extra else {
        return Ok(());
    };
    let s: &mut Settings = &mut job.settings;
    for (key, value) in extra.iter() {
        let key: String = key.extract()?;
        match key.as_str() {
            "lr" => s.lr = value.extract()?,
            "momentum" => s.momentum = value.extract()?,
            "prior_weight" => s.prior_weight = value.extract()?,
            "prior_ab" => {
                s.prior_a = value.extract()?;
                s.prior_b = s.prior_a;
            }
            "prior_start" => s.prior_start = value.extract()?,
            "l1" => s.l1 = value.extract()?,
            "l2" => s.l2 = value.extract()?,
            "control_points" => s.control_points = value.extract()?,
            "negatives_per_step" => s.negatives_per_step = value.extract()?,
            "negatives_file" => job.negatives_file = value.extract()?,
            "up" => {
                let up: String = value.extract()?;
                job.up = up
                    .parse()
                    .map_err(|e| errors::settings(format!("up: {}", errors::message(&e))))?;
            }
            // The CLI reads the step as f64 and hands the library an f32: the same here.
            "step_size" => job.step_size = value.extract::<Option<f64>>()?.map(|v| v as f32),
            "level" => job.level = value.extract()?,
            "render_size" => job.render_size = value.extract()?,
            // True: the user's cache folder (the default); False or None: no cache.
            "caption_cache" => {
                job.caption_cache = match value.extract::<bool>() {
                    Ok(true) => t2tf::optimize::captions::cache_dir(),
                    Ok(false) => None,
                    Err(_) => value.extract()?,
                }
            }
            _ => {
                return Err(pyo3::exceptions::PyTypeError::new_err(format!(
                    "optimize() got an unexpected keyword argument '{key}'"
                )))
            }
        }
    }
    Ok(())
}

/// The TF base name `t2tf optimize` would choose for `target` (and `--out`): the library's
/// rule, which the CLI follows too.
pub fn default_name(target: &Target, out: Option<&Path>) -> PyResult<String> {
    t2tf::pipeline::naming::tf_name(None, out, target).map_err(errors::pipeline)
}

/// Optimize a transfer function so renderings of `volume` match `prompt` (Algorithm 1 with
/// the paper's defaults; each keyword is the `t2tf optimize` flag of that name).
///
/// Returns a Result; a list of prompts returns a list of Results, one run per prompt with
/// the model and the volume loaded once (the same seed gives each prompt the TF of its own
/// run).
///
/// Parameters:
///     volume: a Volume, a volume file's path (read as read_volume reads it), a 3-D
///         array indexed [z, y, x], or a Series (one TF for all its steps).
///     prompt: what the renderings should show, e.g. "a potted tree"; or a list of them.
///     negatives: captions to suppress; empty: "a blank image".
///     steps: SGD steps; 0: the result is the start (the initialization, or init).
///     views: random views per step, their gradients averaged.
///     seed: seed of the views, backgrounds, negatives and initial colours.
///     model: a Hub id, a local model folder or a loaded Model; None: DEFAULT_MODEL. A
///         run of 0 steps from an init with opacity loads none.
///     tokenizer: a tokenizer.json to use instead of the model's own.
///     revision: branch, tag, pull-request ref or commit of a Hub model; None: main.
///     precision: number format of CLIP's products: "auto" (the default: bf16 where this
///         CPU runs it faster, else f32), "f32" (bit-reproducible) or "bf16".
///     threads: worker threads; None: one per CPU. The same volume, settings, seed and
///         threads give the CLI's TF bit for bit.
///     progress: a function called with a dict per event (see below); returning False
///         stops the run.
///     reference_image: a PNG whose CLIP embedding is matched instead of a prompt.
///     max_memory: memory budget, bytes (int) or a size like "16G"; None: what the
///         system has.
///     init: a TF to start from instead of the paper's initialization: a TF file's path
///         or a TransferFunction (such as an earlier result's).
///     preset: the preset of init's file to start from, when it holds several.
///     lock: data ranges [(min, max), ...] whose TF stays as it starts.
///     lr: initial learning rate, annealed linearly to 0.
///     momentum: SGD momentum, in [0, 1).
///     prior_weight: weight of the Beta prior on the rays' final transmittance.
///     prior_ab: a = b of the Beta(a, b) prior; below 1 favours clear or opaque rays.
///     prior_start: first step (0-based) with the prior switched on.
///     l1: weight of the L1 term on the control points' densities.
///     l2: weight of the L2 term pulling colours towards 0.5.
///     control_points: control points of the TF.
///     negatives_per_step: negatives drawn from the caption pool per step.
///     negatives_file: a caption file (one per line) replacing the built-in pool.
///     up: the world axis pointing up in the views: x, y, z, -x, -y or -z.
///     step_size: ray-marching step in voxels; None: the renderer's.
///     level: mip level to render from (0: full resolution); None: chosen from the
///         pixel size.
///     render_size: cast rays at this image side and upsample to CLIP's; None: CLIP's
///         size.
///     caption_cache: the folder caption embeddings are cached in; True: the user's
///         cache folder; False or None: not cached.
///
/// Progress events: {"event": "phase", "phase": ...} as a phase begins; after each step
/// {"event": "step", "step": 1-based, "total": the run's steps, "loss": the loss, and its
/// parts "clip", "prior", "l1", "l2", with "prompt_probability", "lr", ...};
/// {"event": "warning", "message": ...}; and while a model downloads (files of 10 MiB or
/// more), {"event": "download", "file": ..., "state": "started" | "progress" | "finished" |
/// "stopped", "done": bytes, "total": bytes or None}, which cannot stop the download
/// (without a callback, downloads are shown on stderr). Returning False stops the run after that step
/// and the partial result is returned (its `interrupted` is True). Ctrl-C, or an exception
/// raised by `progress`, also stops the run after the current step and is then raised;
/// the partial result is dropped.
#[pyfunction]
#[pyo3(
    signature = (volume, prompt = None, *, negatives = Vec::new(), steps = defaults::STEPS as i64, views = defaults::VIEWS as i64, seed = defaults::SEED, model = None, tokenizer = None, revision = None, precision = "auto", threads = None, progress = None, reference_image = None, max_memory = None, init = None, preset = None, lock = Vec::new(), **settings),
    text_signature = "(volume, prompt=None, *, negatives=(), steps=300, views=3, seed=0, model=None, tokenizer=None, revision=None, precision='auto', threads=None, progress=None, reference_image=None, max_memory=None, init=None, preset=None, lock=(), lr=10.0, momentum=0.75, prior_weight=0.02, prior_ab=0.5, prior_start=100, l1=2e-05, l2=0.0008, control_points=32, negatives_per_step=128, negatives_file=None, up='z', step_size=None, level=None, render_size=None, caption_cache=True)"
)]
#[allow(clippy::too_many_arguments)] // each is one keyword of the Python function
pub fn optimize<'py>(
    py: Python<'py>,
    volume: &Bound<'py, PyAny>,
    prompt: Option<&Bound<'py, PyAny>>,
    negatives: Vec<String>,
    steps: i64,
    views: i64,
    seed: u64,
    model: Option<&Bound<'_, PyAny>>,
    tokenizer: Option<PathBuf>,
    revision: Option<String>,
    precision: &str,
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    reference_image: Option<PathBuf>,
    max_memory: Option<&Bound<'_, PyAny>>,
    init: Option<&Bound<'_, PyAny>>,
    preset: Option<String>,
    lock: Vec<(f64, f64)>,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    // What report.json records of the call, before the arguments are consumed.
    let call = Call {
        volume,
        prompt,
        negatives: &negatives,
        counts: (steps, views, seed),
        model,
        tokenizer: tokenizer.as_deref(),
        revision: revision.as_deref(),
        precision,
        threads,
        reference_image: reference_image.as_deref(),
        max_memory,
        init,
        preset: preset.as_deref(),
        lock: &lock,
        settings,
    }
    .to_json(py)?;
    // Several prompts: one run each with the model and the volume shared, a list back.
    let prompts: Option<Vec<String>> =
        match prompt {
            None => None,
            Some(p) => match p.extract::<String>() {
                Ok(one) => Some(vec![one]),
                Err(_) => Some(p.extract::<Vec<String>>().map_err(|_| {
                    errors::settings("prompt must be a string or a list of strings")
                })?),
            },
        };
    let many = prompt.is_some_and(|p| p.extract::<String>().is_err());
    let targets: Vec<Target> = match (prompts, reference_image) {
        (Some(ps), None) if !ps.is_empty() => ps.into_iter().map(Target::Prompt).collect(),
        (None, Some(r)) => vec![Target::Image(r)],
        (Some(_), Some(_)) => {
            return Err(errors::settings(
                "give a prompt or a reference_image, not both",
            ))
        }
        _ => {
            return Err(errors::settings(
                "say what the renderings should show: a prompt (or a reference_image)",
            ))
        }
    };
    // Counts as Python ints: a negative one is a settings error, not an OverflowError.
    let count = |name: &str, v: i64| {
        usize::try_from(v)
            .map_err(|_| errors::settings(format!("{name} must be 0 or more, got {v}")))
    };
    let (steps, views) = (count("steps", steps)?, count("views", views)?);
    // A Series: one TF for all its steps; else a volume (a Volume, a file, an array).
    let series = volume
        .cast::<crate::series::PySeries>()
        .ok()
        .map(|s| s.clone().unbind());
    let volume = match series {
        Some(_) => None,
        None => Some(crate::volume::volume_arg(py, volume)?),
    };
    let init = init_tf(init, preset)?;
    let mut jobs = Vec::with_capacity(targets.len());
    for target in &targets {
        let mut job = Job::new(target.clone());
        job.caption_cache = t2tf::optimize::captions::cache_dir();
        job.negatives = negatives.clone();
        job.settings.steps = steps;
        job.settings.views = views;
        job.settings.seed = seed;
        job.budget = budget(max_memory)?;
        job.init = init.clone();
        job.locks = lock.iter().map(|&(a, b)| [a, b]).collect();
        apply_settings(&mut job, settings)?;
        jobs.push(job.validate().map_err(errors::pipeline)?);
    }
    // At most the logical CPUs, as the CLI's `--threads` (more only adds switching).
    let pool = pipeline::workers(threads).map_err(errors::pipeline)?.pool;
    let scene = match (&series, &volume) {
        (Some(s), _) => pipeline::Scene::Series(&s.get().steps),
        (None, Some(v)) => pipeline::Scene::Volume(&v.get().volume),
        (None, None) => unreachable!("a series or a volume was made above"),
    };
    if let Some(job) = jobs.first() {
        // A series' first step is read here (once), without the GIL.
        let checked = py.detach(|| job.check_volume(scene.volume()?));
        checked.map_err(errors::pipeline)?;
    }
    // A run of 0 steps from a TF with opacity is that TF: no model is resolved or loaded
    // (a loaded one given is used all the same).
    let given = model.and_then(|m| m.cast::<PyModel>().ok());
    let model = if given.is_some() || jobs.iter().any(|j| j.needs_model()) {
        Some(model_for(
            py,
            model,
            tokenizer,
            revision,
            precision,
            max_memory,
            progress.as_ref().map(|p| p.clone_ref(py)),
        )?)
    } else {
        None
    };
    let cwd = std::env::current_dir()
        .ok()
        .map(|d| d.display().to_string());
    let mut results = Vec::with_capacity(jobs.len());
    for (job, target) in jobs.iter().zip(targets) {
        let name = default_name(&target, None)?;
        let mut optimized = run_with_events(
            py,
            &pool,
            scene,
            model.as_deref(),
            job,
            progress.as_ref().map(|p| p.clone_ref(py)),
        )?;
        optimized.report.python_call = Some(call.clone());
        optimized.report.cwd = cwd.clone();
        results.push(OptimizeResult {
            optimized,
            target,
            name,
        });
    }
    if many {
        Ok(pyo3::types::PyList::new(py, results)?.into_any())
    } else {
        Ok(Bound::new(py, results.remove(0))?.into_any())
    }
}

/// The arguments of an `optimize` call, for report.json: each keyword as given, paths made
/// absolute, a loaded model by the folder or id it came from, a volume by its file.
struct Call<'a, 'py> {
    volume: &'a Bound<'py, PyAny>,
    prompt: Option<&'a Bound<'py, PyAny>>,
    negatives: &'a [String],
    counts: (i64, i64, u64),
    model: Option<&'a Bound<'a, PyAny>>,
    tokenizer: Option<&'a Path>,
    revision: Option<&'a str>,
    precision: &'a str,
    threads: Option<usize>,
    reference_image: Option<&'a Path>,
    max_memory: Option<&'a Bound<'a, PyAny>>,
    init: Option<&'a Bound<'a, PyAny>>,
    preset: Option<&'a str>,
    lock: &'a [(f64, f64)],
    settings: Option<&'a Bound<'a, PyDict>>,
}

impl Call<'_, '_> {
    fn to_json(&self, py: Python<'_>) -> PyResult<serde_json::Value> {
        use serde_json::{json, Value};
        let path = |p: &Path| Value::String(absolute(p));
        let volume = match self.volume.cast::<crate::volume::PyVolume>() {
            Ok(v) => v.get().path().map_or(Value::Null, |p| path(&p)),
            Err(_) if self.volume.cast::<crate::series::PySeries>().is_ok() => {
                let s = self.volume.cast::<crate::series::PySeries>()?;
                let s = s.get().steps.series();
                match &s.collection {
                    Some(c) => path(c),
                    None => Value::String("(a series)".into()),
                }
            }
            Err(_) => match self.volume.extract::<PathBuf>() {
                Ok(p) => path(&p),
                Err(_) => Value::String("(an array)".into()),
            },
        };
        let model = match self.model {
            None => Value::Null,
            Some(m) => match m.cast::<PyModel>() {
                Ok(loaded) => {
                    let info = loaded.get().model.info();
                    Value::String(info.folder.clone().unwrap_or_else(|| info.id.clone()))
                }
                Err(_) => {
                    let given: PathBuf = m.extract()?;
                    if given.is_dir() {
                        path(&given)
                    } else {
                        Value::String(given.to_string_lossy().into_owned())
                    }
                }
            },
        };
        let init = match self.init {
            None => Value::Null,
            Some(i) if i.cast::<PyTransferFunction>().is_ok() => {
                Value::String("(a TransferFunction)".into())
            }
            Some(i) => i.extract::<PathBuf>().map_or(Value::Null, |p| path(&p)),
        };
        let (steps, views, seed) = self.counts;
        let mut call = json!({
            "volume": volume,
            "prompt": self.prompt.map(|p| any_json(py, p)).transpose()?,
            "negatives": self.negatives,
            "steps": steps,
            "views": views,
            "seed": seed,
            "model": model,
            "tokenizer": self.tokenizer.map(path),
            "revision": self.revision,
            "precision": self.precision,
            "threads": self.threads,
            "reference_image": self.reference_image.map(path),
            "max_memory": self.max_memory.map(|m| any_json(py, m)).transpose()?,
            "init": init,
            "preset": self.preset,
            "lock": self.lock,
        });
        if let Some(extra) = self.settings {
            for (key, value) in extra.iter() {
                let key: String = key.extract()?;
                let v = match key.as_str() {
                    "negatives_file" | "caption_cache"
                        if !value.is_instance_of::<pyo3::types::PyBool>() =>
                    {
                        match value.extract::<Option<PathBuf>>() {
                            Ok(Some(p)) => path(&p),
                            _ => any_json(py, &value)?,
                        }
                    }
                    _ => any_json(py, &value)?,
                };
                call[key] = v;
            }
        }
        Ok(call)
    }
}

/// A Python value as JSON (`json.dumps`, anything else as its `str`).
fn any_json(py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<serde_json::Value> {
    let kwargs = PyDict::new(py);
    kwargs.set_item("default", py.import("builtins")?.getattr("str")?)?;
    let text: String = py
        .import("json")?
        .call_method("dumps", (value,), Some(&kwargs))?
        .extract()?;
    serde_json::from_str(&text).map_err(|e| errors::Error::new_err(e.to_string()))
}

/// `path` absolute against the current folder, as report.json records it.
fn absolute(path: &Path) -> String {
    t2tf::optimize::report::absolute(path)
}

/// `init=`: a TF file's path (`preset` names one of several in it) or a `TransferFunction`.
fn init_tf(
    init: Option<&Bound<'_, PyAny>>,
    preset: Option<String>,
) -> PyResult<Option<pipeline::InitTf>> {
    let Some(init) = init else {
        if preset.is_some() {
            return Err(errors::settings(
                "preset names a preset of init's file: give init too",
            ));
        }
        return Ok(None);
    };
    if let Ok(tf) = init.cast::<PyTransferFunction>() {
        let source = PathBuf::from("(a TransferFunction)");
        return pipeline::InitTf::new(tf.get().preset.clone(), source)
            .map(Some)
            .map_err(errors::pipeline);
    }
    let path: PathBuf = init.extract().map_err(|_| {
        errors::settings("init must be a TF file's path or a t2tf.TransferFunction")
    })?;
    pipeline::InitTf::read(&path, preset.as_deref(), formats::DEFAULT_MAX_PRESET_SIZE)
        .map(Some)
        .map_err(errors::pipeline)
}

/// `precision` as the command's `--precision` resolves it: `auto`'s calibration kept in the
/// cache folder (every run on a machine picks alike), the choice marked for report.json.
fn compute(precision: &str) -> PyResult<Compute> {
    let cache = t2tf::optimize::captions::cache_dir();
    let chosen = Precision::resolve_cached(precision, cache.as_deref())
        .map_err(|e| errors::settings(format!("precision: {e}")))?;
    Ok(Compute {
        auto: precision == "auto",
        ..Compute::new(chosen)
    })
}
