//! `t2tf.Series` and `t2tf.read_series`: a time series to optimize one transfer function for,
//! from files (a `.pvd` or `.series` collection, a glob pattern, a list of files) or from
//! NumPy arrays with their times.

use std::path::{Path, PathBuf};

use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;

use t2tf::memory::Budget;
use t2tf::optimize::series::SeriesSteps;
use t2tf::volume::{ReadOptions, Series, TimeSelection, Volume};

use crate::errors;
use crate::volume::{geometry, shared_array, triple};

/// What errors call a series made from arrays.
const ARRAYS_NAME: &str = "(numpy arrays)";

/// Steps of a series kept loaded while a run draws from it: the views of a step and one more
/// (`optimize::schedule::assign_times`) for the default 3 views, and room for more views.
const KEEP_LOADED: usize = 8;

/// A time series of volumes, to optimize one transfer function for all its steps
/// (`optimize(series, prompt)`): from `read_series`, or `Series.from_arrays`. Its data range
/// is that of all its steps, so the TF means the same data values at every time.
#[pyclass(name = "Series", module = "t2tf", frozen)]
pub struct PySeries {
    pub steps: SeriesSteps,
}

#[pymethods]
impl PySeries {
    /// A series of 3-D arrays indexed [z, y, x] (as `Volume` takes one), all of one shape,
    /// at `times` (increasing; None: 0, 1, 2, …), with `spacing` and `origin` (x, y, z) in
    /// world units (None: 1, 1, 1 and 0, 0, 0). Each array is read in place where its
    /// layout allows, as `Volume` reads one: do not change them while the series lives.
    #[staticmethod]
    #[pyo3(
        signature = (arrays, times = None, *, spacing = None, origin = None),
        text_signature = "(arrays, times=None, *, spacing=None, origin=None)"
    )]
    fn from_arrays(
        py: Python<'_>,
        arrays: Vec<Bound<'_, PyAny>>,
        times: Option<Vec<f64>>,
        spacing: Option<&Bound<'_, PyAny>>,
        origin: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PySeries> {
        let spacing = spacing.map_or(Ok([1.0; 3]), |s| triple("spacing", s))?;
        let origin = origin.map_or(Ok([0.0; 3]), |o| triple("origin", o))?;
        let times = times.unwrap_or_else(|| (0..arrays.len()).map(|i| i as f64).collect());
        if times.len() != arrays.len() {
            return Err(errors::settings(format!(
                "{} arrays but {} times: give one time per array",
                arrays.len(),
                times.len()
            )));
        }
        let mut shared = Vec::with_capacity(arrays.len());
        for a in &arrays {
            let (array, ty, order, bytes) = shared_array(a)?;
            shared.push((geometry(array.shape(), spacing, origin), ty, order, bytes));
        }
        let name = Path::new(ARRAYS_NAME);
        let budget = Budget::system();
        let steps = py
            .detach(|| {
                // The range of every step first (each array's own statistics), then each
                // normalized over the range of all of them.
                let mut range = [f64::INFINITY, f64::NEG_INFINITY];
                for (g, ty, order, bytes) in &shared {
                    let v = Volume::from_shared_over(
                        name,
                        *g,
                        *ty,
                        *order,
                        bytes.clone(),
                        budget,
                        None,
                    )?;
                    range = [range[0].min(v.range[0]), range[1].max(v.range[1])];
                }
                let norm = if range[1] > range[0] {
                    range
                } else {
                    [range[0] - 0.5, range[0] + 0.5]
                };
                let volumes = shared
                    .into_iter()
                    .zip(&times)
                    .map(|((g, ty, order, bytes), &t)| {
                        Volume::from_shared_over(name, g, ty, order, bytes, budget, Some(norm))
                            .map(|v| (t, v))
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                SeriesSteps::from_volumes(ARRAYS_NAME, volumes)
            })
            .map_err(errors::volume)?;
        Ok(PySeries { steps })
    }

    /// The time of each step used.
    #[getter]
    fn times(&self) -> Vec<f64> {
        self.steps.series().steps.iter().map(|s| s.time).collect()
    }

    /// The file of each step used (None for a series of arrays).
    #[getter]
    fn files(&self) -> Option<Vec<PathBuf>> {
        (!self.steps.in_memory()).then(|| {
            self.steps
                .series()
                .steps
                .iter()
                .map(|s| s.path.clone())
                .collect()
        })
    }

    /// The `.pvd` or `.series` file the series was read from, if any.
    #[getter]
    fn collection(&self) -> Option<PathBuf> {
        self.steps.series().collection.clone()
    }

    /// (min, max) of the finite values over every step used: the TF's data range.
    #[getter]
    fn range(&self) -> (f64, f64) {
        let [lo, hi] = self.steps.stats().range;
        (lo, hi)
    }

    /// Each step's own (min, max).
    #[getter]
    fn step_ranges(&self) -> Vec<(f64, f64)> {
        self.steps
            .stats()
            .step_ranges
            .iter()
            .map(|r| (r[0], r[1]))
            .collect()
    }

    fn __len__(&self) -> usize {
        self.steps.len()
    }

    fn __repr__(&self) -> String {
        let s = self.steps.series();
        let [lo, hi] = self.steps.stats().range;
        let from = s
            .collection
            .as_ref()
            .map_or_else(|| "files or arrays".into(), |c| c.display().to_string());
        format!(
            "Series({} of {} steps from {from}, times {} to {}, range {lo}..{hi})",
            s.steps.len(),
            s.total_steps,
            s.steps[0].time,
            s.steps[s.steps.len() - 1].time
        )
    }
}

/// Read a time series as `t2tf optimize` reads one: a ParaView `.pvd` or `.series` file, a
/// glob pattern ("run_*.vti"), or a list of files (ordered as ParaView orders a file series;
/// a VTK XML file's TimeValue is its time, else its index).
///
/// Parameters:
///     paths: the collection, the pattern, or a list of files.
///     time_range: (t0, t1): only the steps whose time is in [t0, t1].
///     time_steps: only these steps, by index (0 = first).
///     array: the point-data array of .vti/.vtk files; None: the active scalars.
///     spacing: grid spacing (x, y, z), replacing the files'.
///
/// The steps' statistics are read now, one step at a time; their values when a run draws
/// them.
#[pyfunction]
#[pyo3(
    signature = (paths, *, time_range = None, time_steps = None, array = None, spacing = None),
    text_signature = "(paths, *, time_range=None, time_steps=None, array=None, spacing=None)"
)]
pub fn read_series(
    py: Python<'_>,
    paths: &Bound<'_, PyAny>,
    time_range: Option<(f64, f64)>,
    time_steps: Option<Vec<usize>>,
    array: Option<String>,
    spacing: Option<&Bound<'_, PyAny>>,
) -> PyResult<PySeries> {
    let paths: Vec<PathBuf> = match paths.extract::<PathBuf>() {
        Ok(one) => vec![one],
        Err(_) => paths.extract::<Vec<PathBuf>>().map_err(|_| {
            errors::settings("paths must be a path, a glob pattern or a list of paths")
        })?,
    };
    let spacing = spacing.map(|s| triple("spacing", s)).transpose()?;
    let opts = ReadOptions {
        spacing,
        array,
        ..ReadOptions::default()
    };
    let selection = TimeSelection {
        range: time_range.map(|(a, b)| [a, b]),
        indices: time_steps,
    };
    let steps = py
        .detach(|| {
            let series = Series::open(&paths)?.select(&selection)?;
            SeriesSteps::open(series, opts, KEEP_LOADED, &mut |_| {})
        })
        .map_err(errors::volume)?;
    Ok(PySeries { steps })
}
