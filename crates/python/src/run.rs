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

/// A CLIP model loaded once, to run several optimizations with.
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

/// Load a CLIP model: a Hugging Face Hub id (downloaded into the Hub cache on first use)
/// or a folder with config.json, tokenizer.json and the weights; None: the default.
#[pyfunction]
#[pyo3(signature = (model = None, *, tokenizer = None, revision = None, precision = "f32", max_memory = None))]
pub fn load_model(
    py: Python<'_>,
    model: Option<PathBuf>,
    tokenizer: Option<PathBuf>,
    revision: Option<String>,
    precision: &str,
    max_memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<PyModel> {
    let precision =
        Precision::resolve(precision).map_err(|e| errors::settings(format!("precision: {e}")))?;
    let mut opts = ModelOptions::new(model.map_or_else(
        || t2tf::clip::DEFAULT_MODEL.to_string(),
        |m| m.to_string_lossy().into_owned(),
    ));
    if let Some(r) = revision {
        opts.revision = r;
    }
    opts.tokenizer = tokenizer;
    opts.compute = Compute::new(precision);
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
) -> PyResult<Arc<Model>> {
    if let Some(m) = model.and_then(|m| m.cast::<PyModel>().ok()) {
        if tokenizer.is_some() || revision.is_some() || precision != "f32" {
            return Err(errors::settings(
                "tokenizer, revision and precision are the loaded model's: give them to load_model",
            ));
        }
        return Ok(m.get().model.clone());
    }
    let path = model.map(|m| m.extract::<PathBuf>()).transpose()?;
    let loaded = load_model(py, path, tokenizer, revision, precision, max_memory)?;
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
            "caption_cache" => job.caption_cache = value.extract()?,
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

/// Optimize a transfer function so renderings of `volume` match `prompt` (or, with
/// `reference_image`, a picture). See the package docs for every keyword.
#[pyfunction]
#[pyo3(signature = (volume, prompt = None, *, negatives = Vec::new(), steps = defaults::STEPS as i64, views = defaults::VIEWS as i64, seed = defaults::SEED, model = None, tokenizer = None, revision = None, precision = "f32", threads = None, progress = None, reference_image = None, max_memory = None, init = None, preset = None, lock = Vec::new(), **settings))]
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
    let volume = crate::volume::volume_arg(py, volume)?;
    let init = init_tf(init, preset)?;
    let mut jobs = Vec::with_capacity(targets.len());
    for target in &targets {
        let mut job = Job::new(target.clone());
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
    let volume = &volume.get().volume;
    if let Some(job) = jobs.first() {
        job.check_volume(volume).map_err(errors::pipeline)?;
    }
    let model = model_for(py, model, tokenizer, revision, precision, max_memory)?;
    let mut results = Vec::with_capacity(jobs.len());
    for (job, target) in jobs.iter().zip(targets) {
        let name = default_name(&target, None)?;
        let optimized = run_with_events(
            py,
            &pool,
            volume,
            &model,
            job,
            progress.as_ref().map(|p| p.clone_ref(py)),
        )?;
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
