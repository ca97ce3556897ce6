//! `t2tf.Result`: what `t2tf.optimize` returns.

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use t2tf::pipeline::{self, Optimized, Target};

use crate::errors::{self, OutputError};
use crate::events::json_to_py;
use crate::run::default_name;
use crate::tf::{rgb8, PyTransferFunction};

/// What `optimize` returns: the TF, the report, the preview, and `save` for the files
/// `t2tf optimize` writes.
#[pyclass(name = "Result", module = "t2tf", frozen)]
pub struct OptimizeResult {
    pub optimized: Optimized,
    pub target: Target,
    /// The TF's name: the one `t2tf optimize` gives it without --out or --name.
    pub name: String,
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
    #[pyo3(signature = (out_dir, name = None), text_signature = "($self, out_dir, name=None)")]
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
        // Python's spelling of the bool.
        let interrupted = if self.interrupted() { "True" } else { "False" };
        format!(
            "Result(steps_run={}, interrupted={interrupted}, name={:?})",
            self.steps_run(),
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
