//! The progress events of a run: the run computes on a thread of its own, in the rayon
//! pool it is given, with the GIL released. The caller's thread waits for the run's events
//! and calls the Python progress callback with each, holding the GIL only then; between
//! events it checks for Ctrl-C every 100 ms. A callback returning False stops the run after
//! the current step (the result is that step's TF); Ctrl-C, or an exception in the
//! callback, stops it the same way and is then raised.

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use t2tf::optimize::report::StepLog;
use t2tf::pipeline::{self, Event, Model, Optimized, ValidJob};

use crate::errors;

/// How often the waiting thread checks for Ctrl-C between events.
const SIGNAL_POLL: Duration = Duration::from_millis(100);

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
                // The loss's parts under their names (clip, prior, l1, l2, ...); the log's
                // own `total` is the loss, given as "loss" below, so that "total" means what
                // it means in the library's `Event::Step`: the steps of the run.
                let fields = serde_json::to_value(log).expect("a StepLog serializes");
                if let Ok(obj) = json_to_py(py, &fields)?.cast_into::<PyDict>() {
                    d.update(obj.as_mapping())?;
                }
                d.set_item("event", "step")?;
                // 1-based, as the CLI's progress counts (the log's own index is 0-based).
                d.set_item("step", step)?;
                d.set_item("total", total)?;
                // The same count under the name the ParaView plugin and older callers read.
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
pub fn json_to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    let text = PyString::new(py, &v.to_string());
    py.import("json")?.call_method1("loads", (text,))
}

/// Run the pipeline on a thread in `pool`, forwarding its events to `progress` on this
/// thread (module docs); without a model for a job that needs none
/// (`ValidJob::needs_model`).
pub fn run_with_events(
    py: Python<'_>,
    pool: &rayon::ThreadPool,
    scene: pipeline::Scene<'_>,
    model: Option<&Model>,
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
                pipeline::optimize_scene(scene, model, job, &mut on_event)
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

/// A Hub download's events for the run's progress callback: `{"event": "download", "file",
/// "state": "started" | "progress" | "finished" | "stopped", "done", "total"}`, and its warnings
/// as `{"event": "warning", "message"}`. Called on the loading thread, which takes the GIL for
/// the call; what the callback returns or raises does not stop a download.
pub fn download_sink(callback: Py<PyAny>) -> t2tf::hub::EventSink {
    use t2tf::hub::HubEvent;
    t2tf::hub::EventSink::new(move |event| {
        Python::attach(|py| {
            let d = PyDict::new(py);
            let filled = (|| -> PyResult<()> {
                match event {
                    HubEvent::Started { file, total } => {
                        d.set_item("event", "download")?;
                        d.set_item("file", file)?;
                        d.set_item("state", "started")?;
                        d.set_item("done", 0)?;
                        d.set_item("total", *total)?;
                    }
                    HubEvent::Progress { file, done, total } => {
                        d.set_item("event", "download")?;
                        d.set_item("file", file)?;
                        d.set_item("state", "progress")?;
                        d.set_item("done", *done)?;
                        d.set_item("total", *total)?;
                    }
                    HubEvent::Finished { file, done, ok } => {
                        d.set_item("event", "download")?;
                        d.set_item("file", file)?;
                        d.set_item("state", if *ok { "finished" } else { "stopped" })?;
                        d.set_item("done", *done)?;
                    }
                    HubEvent::Warning(w) => {
                        d.set_item("event", "warning")?;
                        d.set_item("message", w)?;
                    }
                }
                Ok(())
            })();
            if filled.is_ok() {
                if let Err(e) = callback.bind(py).call1((d,)) {
                    // Said, not raised: the download goes on, and the run's own events will
                    // meet the callback again.
                    e.print(py);
                }
            }
        })
    })
}
