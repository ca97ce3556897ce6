//! `t2tf.optimize`, `t2tf.load_model` and the `t2tf.Result` of a run.
//!
//! The run computes on a thread of its own, in a rayon pool built as the CLI builds it (so
//! the same settings, seed and threads give the CLI's TF bit for bit), with the GIL
//! released. The caller's thread waits for the run's events and calls the Python progress
//! callback with each, holding the GIL only then; between events it checks for Ctrl-C every
//! 100 ms. A callback returning False stops the run after the current step (the result is
//! that step's TF); Ctrl-C, or an exception in the callback, stops it the same way and is
//! then raised.

use std::ffi::OsString;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use clap::Parser;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use t2tf::clip::{Compute, Precision};
use t2tf::memory::Budget;
use t2tf::optimize::report::StepLog;
use t2tf::optimize::settings::{defaults, Settings};
use t2tf::pipeline::{self, Event, Job, Model, ModelOptions, Optimized, Target, ValidJob};

use crate::errors::{self, OutputError};
use crate::tf::{rgb8, PyTransferFunction};
use crate::volume::PyVolume;

/// How often the waiting thread checks for Ctrl-C between events.
const SIGNAL_POLL: Duration = Duration::from_millis(100);

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

/// The TF base name `t2tf optimize` would choose for `target` (and `--out`), by its own rule.
fn default_name(target: &Target, out: Option<&Path>) -> PyResult<String> {
    // `--flag=VALUE`, so a value starting with '-' is not read as a flag.
    let flag = |name: &str, value: &std::ffi::OsStr| {
        let mut arg = OsString::from(format!("--{name}="));
        arg.push(value);
        arg
    };
    let mut argv: Vec<OsString> = vec!["t2tf".into(), "optimize".into(), "volume".into()];
    argv.push(match target {
        Target::Prompt(p) => flag("prompt", p.as_ref()),
        Target::Image(i) => flag("reference-image", i.as_os_str()),
    });
    if let Some(o) = out {
        argv.push(flag("out", o.as_os_str()));
    }
    let parsed = t2tf_cli::Cli::try_parse_from(argv)
        .map_err(|e| errors::settings(e.to_string().trim().to_string()))?;
    match parsed.command {
        t2tf_cli::Command::Optimize(a) => {
            a.tf_name().map_err(|e| errors::settings(format!("{e:#}")))
        }
        _ => unreachable!("parsed as optimize"),
    }
}

/// Optimize a transfer function so renderings of `volume` match `prompt` (or, with
/// `reference_image`, a picture). See the package docs for every keyword.
#[pyfunction]
#[pyo3(signature = (volume, prompt = None, *, negatives = Vec::new(), steps = defaults::STEPS, views = defaults::VIEWS, seed = defaults::SEED, model = None, tokenizer = None, revision = None, precision = "f32", threads = None, progress = None, reference_image = None, max_memory = None, **settings))]
#[allow(clippy::too_many_arguments)] // each is one keyword of the Python function
pub fn optimize(
    py: Python<'_>,
    volume: Py<PyVolume>,
    prompt: Option<String>,
    negatives: Vec<String>,
    steps: usize,
    views: usize,
    seed: u64,
    model: Option<&Bound<'_, PyAny>>,
    tokenizer: Option<PathBuf>,
    revision: Option<String>,
    precision: &str,
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    reference_image: Option<PathBuf>,
    max_memory: Option<&Bound<'_, PyAny>>,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<OptimizeResult> {
    let target = match (prompt, reference_image) {
        (Some(p), None) => Target::Prompt(p),
        (None, Some(r)) => Target::Image(r),
        (Some(_), Some(_)) => {
            return Err(errors::settings(
                "give a prompt or a reference_image, not both",
            ))
        }
        (None, None) => {
            return Err(errors::settings(
                "say what the renderings should show: a prompt (or a reference_image)",
            ))
        }
    };
    let mut job = Job::new(target.clone());
    job.negatives = negatives;
    job.settings.steps = steps;
    job.settings.views = views;
    job.settings.seed = seed;
    job.budget = budget(max_memory)?;
    apply_settings(&mut job, settings)?;
    let job = job.validate().map_err(errors::pipeline)?;
    if threads == Some(0) {
        return Err(errors::settings("threads must be at least 1"));
    }
    let pool = t2tf_cli::thread_pool(threads).map_err(|e| errors::settings(format!("{e:#}")))?;
    let model = model_for(py, model, tokenizer, revision, precision, max_memory)?;
    let name = default_name(&target, None)?;
    let optimized = run_with_events(py, &pool, &volume.get().volume, &model, &job, progress)?;
    Ok(OptimizeResult {
        optimized,
        target,
        name,
    })
}

/// An event that can cross to the caller's thread.
enum Owned {
    Phase(String),
    Step {
        step: usize,
        total: usize,
        log: StepLog,
    },
    Warning(String),
}

impl Owned {
    fn of(e: Event) -> Owned {
        match e {
            Event::Phase(p) => Owned::Phase(p.to_string()),
            Event::Step { step, total, log } => Owned::Step {
                step,
                total,
                log: log.clone(),
            },
            Event::Warning(w) => Owned::Warning(w.to_string()),
        }
    }

    /// The dict the progress callback receives.
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        match self {
            Owned::Phase(p) => {
                d.set_item("event", "phase")?;
                d.set_item("phase", p)?;
            }
            Owned::Step { step, total, log } => {
                let fields = serde_json::to_value(log).expect("a StepLog serializes");
                if let Ok(obj) = json_to_py(py, &fields)?.cast_into::<PyDict>() {
                    d.update(obj.as_mapping())?;
                }
                d.set_item("event", "step")?;
                // 1-based, as the CLI's progress counts (the log's own index is 0-based).
                d.set_item("step", step)?;
                d.set_item("steps", total)?;
                d.set_item("loss", log.total)?;
            }
            Owned::Warning(w) => {
                d.set_item("event", "warning")?;
                d.set_item("message", w)?;
            }
        }
        Ok(d)
    }
}

/// A JSON value as Python's `json.loads` gives it.
fn json_to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    let text = PyString::new(py, &v.to_string());
    py.import("json")?.call_method1("loads", (text,))
}

/// Run the pipeline on a thread in `pool`, forwarding its events to `progress` on this
/// thread (module docs).
fn run_with_events(
    py: Python<'_>,
    pool: &rayon::ThreadPool,
    volume: &t2tf::volume::Volume,
    model: &Model,
    job: &ValidJob,
    progress: Option<Py<PyAny>>,
) -> PyResult<Optimized> {
    type Reply = mpsc::SyncSender<bool>;
    let (tx, mut rx) = mpsc::channel::<(Owned, Reply)>();
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let stop = &stop;
        let worker = s.spawn(move || {
            pool.install(|| {
                let mut on_event = |e: Event| {
                    if !stop.load(Ordering::SeqCst) {
                        let (reply_tx, reply_rx) = mpsc::sync_channel(1);
                        let go = tx.send((Owned::of(e), reply_tx)).is_ok()
                            && reply_rx.recv().unwrap_or(false);
                        if !go {
                            stop.store(true, Ordering::SeqCst);
                        }
                    }
                    if stop.load(Ordering::SeqCst) {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                };
                pipeline::optimize(volume, model, job, &mut on_event)
            })
        });
        // The first exception (Ctrl-C, or one the callback raised): raised once the run
        // has stopped.
        let mut raised: Option<PyErr> = None;
        loop {
            let (back, got) = py.detach(move || {
                let got = rx.recv_timeout(SIGNAL_POLL);
                (rx, got)
            });
            rx = back;
            match got {
                Ok((event, reply)) => {
                    if raised.is_none() {
                        match call(py, progress.as_ref(), &event) {
                            Ok(true) => {}
                            Ok(false) => stop.store(true, Ordering::SeqCst),
                            Err(e) => raised = Some(e),
                        }
                    }
                    if raised.is_none() {
                        // Ctrl-C during the callback stops the run after this step.
                        raised = py.check_signals().err();
                    }
                    let go = raised.is_none() && !stop.load(Ordering::SeqCst);
                    let _ = reply.send(go);
                    continue;
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
            if raised.is_none() {
                if let Err(e) = py.check_signals() {
                    stop.store(true, Ordering::SeqCst);
                    raised = Some(e);
                }
            }
        }
        let result = match worker.join() {
            Ok(r) => r,
            Err(panic) => std::panic::resume_unwind(panic),
        };
        match raised {
            Some(e) => Err(e),
            None => result.map_err(errors::pipeline),
        }
    })
}

/// Call `progress` with `event`: whether the run goes on (not if it returned False). An
/// exception it raises is returned.
fn call(py: Python<'_>, progress: Option<&Py<PyAny>>, event: &Owned) -> PyResult<bool> {
    let Some(f) = progress else {
        return Ok(true);
    };
    let ret = f.bind(py).call1((event.to_dict(py)?,))?;
    Ok(!matches!(ret.extract::<bool>(), Ok(false)))
}

/// What `optimize` returns: the TF, the report, the preview, and `save` for the files
/// `t2tf optimize` writes.
#[pyclass(name = "Result", module = "t2tf", frozen)]
pub struct OptimizeResult {
    optimized: Optimized,
    target: Target,
    /// The TF's name: the one `t2tf optimize` gives it without --out or --name.
    name: String,
}

#[pymethods]
impl OptimizeResult {
    /// The optimized TF in the volume's data units, as the written files hold it.
    #[getter]
    fn transfer_function(&self) -> PyTransferFunction {
        PyTransferFunction::rgb(self.optimized.transfer_function(&self.name))
    }

    /// The run's record: what report.json holds (its `outputs` are listed by `save`).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        report_dict(py, &self.optimized.report)
    }

    /// The final TF from the preview's four orbit views, tiled: uint8 (height, width, 3).
    #[getter]
    fn preview<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rgb8(py, self.optimized.preview())
    }

    /// Steps run (fewer than asked for when the run was stopped).
    #[getter]
    fn steps_run(&self) -> usize {
        self.optimized.steps_run()
    }

    /// Whether the run was stopped before its last step.
    #[getter]
    fn interrupted(&self) -> bool {
        self.optimized.interrupted()
    }

    /// ParaView's camera for the first preview view: position, focal_point, view_up,
    /// view_angle (degrees).
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.optimized.camera();
        let d = PyDict::new(py);
        d.set_item("position", c.position)?;
        d.set_item("focal_point", c.focal_point)?;
        d.set_item("view_up", c.view_up)?;
        d.set_item("view_angle", c.view_angle)?;
        Ok(d)
    }

    /// Write the files `t2tf optimize` writes into `out_dir` (created if missing), as one
    /// set, while holding its output lock: NAME.json/.xml/.ct, the pvpython and VisIt
    /// scripts (for a volume read from a file), tf.png, preview.png and report.json.
    /// `name` defaults to the CLI's rule for `--out out_dir`. Returns the report written.
    #[pyo3(signature = (out_dir, name = None))]
    fn save<'py>(
        &self,
        py: Python<'py>,
        out_dir: PathBuf,
        name: Option<String>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let name = match name {
            Some(n) => {
                pipeline::check_name(&n).map_err(errors::pipeline)?;
                n
            }
            None => default_name(&self.target, Some(&out_dir))?,
        };
        if out_dir.exists() && !out_dir.is_dir() {
            return Err(OutputError::new_err(format!(
                "{}: exists and is not a folder",
                out_dir.display()
            )));
        }
        let optimized = &self.optimized;
        let report = py
            .detach(|| {
                let _lock = t2tf::fs::OutputLock::acquire(&out_dir)?;
                t2tf::fs::clean_stale(&out_dir)?;
                optimized.write(&out_dir, &name)
            })
            .map_err(errors::pipeline)?;
        report_dict(py, &report)
    }

    fn __repr__(&self) -> String {
        format!(
            "Result(steps_run={}, interrupted={}, name={:?})",
            self.steps_run(),
            self.interrupted(),
            self.name
        )
    }
}

/// report.json's object as a dict.
fn report_dict<'py>(
    py: Python<'py>,
    report: &t2tf::optimize::report::Report,
) -> PyResult<Bound<'py, PyAny>> {
    let v = serde_json::to_value(report).map_err(|e| errors::Error::new_err(e.to_string()))?;
    json_to_py(py, &v)
}
