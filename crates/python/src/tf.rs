//! `t2tf.TransferFunction` (a preset in data units: load, save, sample) and `t2tf.render`
//! (one view of a volume with it, as `t2tf render` draws it).

use std::path::{Path, PathBuf};

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;

use t2tf::camera::{Camera, Orbit, UpAxis};
use t2tf::formats::{
    preset_lut, read_preset_within, write_preset, ExportTf, Preset, Sampling,
    DEFAULT_MAX_PRESET_SIZE,
};
use t2tf::memory::Budget;
use t2tf::render::{CpuBackend, RenderOptions};

use crate::errors;

/// A transfer function: colour and opacity points in data units, in the colour space its
/// file gave (ParaView presets may interpolate in Lab, HSV, …).
#[pyclass(name = "TransferFunction", module = "t2tf", frozen)]
#[derive(Clone)]
pub struct PyTransferFunction {
    pub preset: Preset,
}

impl PyTransferFunction {
    /// An RGB transfer function (what the optimizer makes).
    pub fn rgb(tf: ExportTf) -> PyTransferFunction {
        PyTransferFunction {
            preset: Preset {
                tf,
                space: t2tf::tf::ColorSpace::Rgb,
                hsv_wrap: false,
                extra: Default::default(),
            },
        }
    }
}

#[pymethods]
impl PyTransferFunction {
    /// Read a ParaView JSON preset (.json), ParaView XML colour map (.xml) or VisIt colour
    /// table (.ct) at `path`; `preset` picks one of a file that holds several (None: its
    /// only one). Files larger than `max_preset_size` bytes (default 64 MiB) are refused
    /// before they are read.
    #[staticmethod]
    #[pyo3(
        signature = (path, preset = None, *, max_preset_size = DEFAULT_MAX_PRESET_SIZE),
        text_signature = "(path, preset=None, *, max_preset_size=67108864)"
    )]
    fn load(
        path: PathBuf,
        preset: Option<&str>,
        max_preset_size: u64,
    ) -> PyResult<PyTransferFunction> {
        let preset = read_preset_within(&path, preset, max_preset_size).map_err(errors::format)?;
        Ok(PyTransferFunction { preset })
    }

    /// A transfer function from `rgb_points`, rows (value, r, g, b), and `opacity_points`,
    /// rows (value, opacity), in data units, ascending, colours and opacities in [0, 1];
    /// `name` is the preset's name; the opacity is for `unit_distance` world units (None:
    /// the volume's mean spacing where it is used).
    #[staticmethod]
    #[pyo3(
        signature = (rgb_points, opacity_points = Vec::new(), *, name = "tf".to_string(), unit_distance = None),
        text_signature = "(rgb_points, opacity_points=(), *, name='tf', unit_distance=None)"
    )]
    fn from_points(
        rgb_points: Vec<[f64; 4]>,
        opacity_points: Vec<[f64; 2]>,
        name: String,
        unit_distance: Option<f64>,
    ) -> PyResult<PyTransferFunction> {
        let tf = ExportTf {
            rgb_points: rgb_points
                .iter()
                .map(|&[x, r, g, b]| (x, [r, g, b]))
                .collect(),
            opacity_points: opacity_points.iter().map(|&[x, o]| (x, o)).collect(),
            unit_distance,
            name,
        };
        tf.validate(Path::new(&tf.name)).map_err(errors::format)?;
        Ok(PyTransferFunction::rgb(tf))
    }

    /// Write it to `path` in the format the extension names (.json, .xml or .ct), as `t2tf
    /// convert` does (atomically).
    #[pyo3(text_signature = "($self, path)")]
    fn save(&self, path: PathBuf) -> PyResult<()> {
        write_preset(&path, &self.preset).map_err(errors::format)
    }

    /// The preset's name.
    #[getter]
    fn name(&self) -> &str {
        &self.preset.tf.name
    }

    /// (first, last) data value of its points.
    #[getter]
    fn range(&self) -> (f64, f64) {
        let [lo, hi] = self.preset.tf.data_range();
        (lo, hi)
    }

    /// ScalarOpacityUnitDistance its opacities are meant for (world units), if it says.
    #[getter]
    fn unit_distance(&self) -> Option<f64> {
        self.preset.tf.unit_distance
    }

    /// Colour points as an array of rows (value, r, g, b), in the preset's colour space.
    #[getter]
    fn rgb_points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows: Vec<f64> = self
            .preset
            .tf
            .rgb_points
            .iter()
            .flat_map(|(x, c)| [*x, c[0], c[1], c[2]])
            .collect();
        PyArray1::from_vec(py, rows).reshape([self.preset.tf.rgb_points.len(), 4])
    }

    /// Opacity points as an array of rows (value, opacity).
    #[getter]
    fn opacity_points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let pts = &self.preset.tf.opacity_points;
        let rows: Vec<f64> = pts.iter().flat_map(|(x, o)| [*x, *o]).collect();
        PyArray1::from_vec(py, rows).reshape([pts.len(), 2])
    }

    /// `n` evenly spaced data values over `range` and the colour and opacity there:
    /// `(values (n,), rgba (n, 4))`, colours in RGB whatever the preset's colour space,
    /// opacity 1 where the preset has no opacity points.
    #[pyo3(signature = (n = 256), text_signature = "($self, n=256)")]
    fn sample<'py>(&self, py: Python<'py>, n: usize) -> PyResult<Sampled<'py>> {
        // A table ParaView or VTK could hold (their lookup tables stop at 2^24 entries).
        const MAX_SAMPLES: usize = 1 << 24;
        if !(2..=MAX_SAMPLES).contains(&n) {
            return Err(errors::settings(format!(
                "sample needs between 2 and {MAX_SAMPLES} values, got {n}"
            )));
        }
        let (values, rgba) = self.preset.rgb_linear().sample(n);
        let rgba: Vec<f64> = rgba.into_iter().flatten().collect();
        let rgba = PyArray1::from_vec(py, rgba).reshape([n, 4])?;
        Ok((PyArray1::from_vec(py, values), rgba))
    }

    fn __repr__(&self) -> String {
        let tf = &self.preset.tf;
        format!(
            "TransferFunction(name={:?}, range={:?}, {} colour points, {} opacity points)",
            tf.name,
            self.range(),
            tf.rgb_points.len(),
            tf.opacity_points.len()
        )
    }
}

/// What `TransferFunction.sample` returns: the values and the RGBA rows.
type Sampled<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

/// One view of `volume` with `tf`, as `t2tf render` draws it: the exact TF through the
/// renderer's LUT, the final-picture step and level, an orbit camera. Returns an array of
/// uint8 (size, size, 3), row 0 at the top.
///
/// Parameters:
///     volume: a Volume, a volume file's path or a 3-D array indexed [z, y, x].
///     tf: a TransferFunction, or a TF file's path (its only preset).
///     yaw: the camera's angle around the up axis, in degrees.
///     pitch: the camera's angle above the horizontal plane, in degrees.
///     distance: the camera's distance from the centre, in bounding radii.
///     size: the picture's side in pixels.
///     up: the world axis pointing up: x, y, z, -x, -y or -z.
///     background: gray, gray:V (V in [0, 1]), white, black, checkerboard, noise or
///         fourier.
///     seed: seed of the noise and fourier backgrounds.
///     unit_distance: the world distance tf's opacities are for; None: the TF's own,
///         else the volume's mean spacing.
#[pyfunction]
#[pyo3(
    signature = (volume, tf, *, yaw = 30.0, pitch = 10.0, distance = 2.5, size = 512, up = "z", background = "gray:0.3", seed = 0, unit_distance = None),
    text_signature = "(volume, tf, *, yaw=30.0, pitch=10.0, distance=2.5, size=512, up='z', background='gray:0.3', seed=0, unit_distance=None)"
)]
#[allow(clippy::too_many_arguments)] // each is one keyword of the Python function
pub fn render<'py>(
    py: Python<'py>,
    volume: &Bound<'py, PyAny>,
    tf: &Bound<'py, PyAny>,
    yaw: f64,
    pitch: f64,
    distance: f64,
    size: usize,
    up: &str,
    background: &str,
    seed: u64,
    unit_distance: Option<f64>,
) -> PyResult<Bound<'py, PyAny>> {
    if size == 0 || size > 8192 {
        return Err(errors::settings(format!(
            "size {size} must be between 1 and 8192"
        )));
    }
    let up: UpAxis = up
        .parse()
        .map_err(|e| errors::settings(format!("up: {}", errors::message(&e))))?;
    let bg = t2tf::background::from_name(background, size, size, seed)
        .map_err(|e| errors::settings(format!("background: {}", errors::message(&e))))?;
    let volume = crate::volume::volume_arg(py, volume)?;
    let v = &volume.get().volume;
    let tf = tf_arg(tf)?;
    let name = Path::new(&tf.preset.tf.name);
    let lut =
        preset_lut(&tf.preset, name, v, unit_distance, Sampling::Exact).map_err(errors::format)?;
    let orbit = Orbit {
        yaw: yaw.to_radians(),
        pitch: pitch.to_radians(),
        distance,
        up,
    };
    let camera = Camera::orbit(&v.geometry, orbit).map_err(|e| errors::render(&e, e.hint()))?;
    let image = py
        .detach(|| {
            let backend = CpuBackend::new(Budget::system());
            backend.render(v, &lut, &camera, &bg, &RenderOptions::final_quality())
        })
        .map_err(|e| errors::render(&e, e.hint()))?
        .image;
    rgb8(py, &image)
}

/// What `render` takes as a transfer function: a `TransferFunction`, or a TF file's path (its
/// only preset, as `TransferFunction.load` reads it).
fn tf_arg(value: &Bound<'_, PyAny>) -> PyResult<PyTransferFunction> {
    if let Ok(tf) = value.cast::<PyTransferFunction>() {
        return Ok(tf.get().clone());
    }
    let path: PathBuf = value
        .extract()
        .map_err(|_| errors::settings("tf must be a t2tf.TransferFunction or a TF file's path"))?;
    PyTransferFunction::load(path, None, DEFAULT_MAX_PRESET_SIZE)
}

/// An RGB image as a uint8 array (height, width, 3).
pub fn rgb8<'py>(py: Python<'py>, image: &t2tf::image::Image) -> PyResult<Bound<'py, PyAny>> {
    let bytes = image.to_rgb8();
    Ok(PyArray1::from_vec(py, bytes)
        .reshape([image.height, image.width, 3])?
        .into_any())
}
