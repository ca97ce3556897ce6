//! `t2tf.Volume` and `t2tf.read_volume`: a volume from a NumPy array indexed [z, y, x]
//! (x fastest, as VTK and raw files store it) or from a file.
//!
//! A C-contiguous array of a type volumes hold (8 to 64-bit integers, float32, float64, in
//! either byte order) is read in place: the volume keeps a reference to it and reads its
//! memory, so a VTK array from `vtk_to_numpy` is not copied. Anything else (Fortran order,
//! strided views, bool, float16, nested lists) is first made a C-contiguous array by NumPy.

use std::path::{Path, PathBuf};

use numpy::{PyArrayDescrMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::IntoPyDict;

use t2tf::memory::Budget;
use t2tf::volume::{ByteOrder, Geometry, ReadOptions, ScalarType, SharedBytes, Volume};

use crate::errors::{self, VolumeError};

/// What errors call a volume made from an array.
const ARRAY_NAME: &str = "(numpy array)";

/// A scalar volume, ready to render and optimize for: `Volume(values, spacing=(1, 1, 1),
/// origin=(0, 0, 0))` with `values` a 3-D array indexed [z, y, x] (x fastest, as VTK and raw
/// files store it) of integers or floats (NaN and Inf are empty space), `spacing` and
/// `origin` (x, y, z) in world units. A C-contiguous array of uint8 to uint64, int8 to int64,
/// float32 or float64 (either byte order) is read in place, not copied: do not change it
/// while the volume lives. Other arrays are copied to a C-contiguous one first.
#[pyclass(name = "Volume", module = "t2tf", frozen)]
pub struct PyVolume {
    pub volume: Volume,
    /// The C-contiguous array the values are read from (in-memory volumes).
    array: Option<Py<PyAny>>,
    /// The file and how it was read (file volumes), for `to_numpy`.
    file: Option<(PathBuf, ReadOptions)>,
}

/// The memory of a C-contiguous NumPy array, shared with a volume. The array is kept alive
/// by the reference held here; the volume reads the memory while the GIL may be released,
/// as any NumPy extension that releases it does (changing the array meanwhile is not
/// supported, see `Volume`'s docs).
struct ArrayBytes {
    _owner: Py<PyAny>,
    ptr: *const u8,
    len: usize,
}

// SAFETY: the pointer is into the buffer of the array `_owner` keeps alive; it is only read.
unsafe impl Send for ArrayBytes {}
// SAFETY: as above: shared reads only.
unsafe impl Sync for ArrayBytes {}

impl AsRef<[u8]> for ArrayBytes {
    fn as_ref(&self) -> &[u8] {
        if self.len == 0 {
            return &[];
        }
        // SAFETY: `ptr` points at `len` bytes of the array's data, alive while `_owner` is.
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }
}

/// The scalar type and byte order of a NumPy dtype a volume reads in place, if it is one.
fn volume_type(array: &Bound<'_, PyUntypedArray>) -> Option<(ScalarType, ByteOrder)> {
    let d = array.dtype();
    let ty = match (d.kind(), d.itemsize()) {
        (b'u', 1) => ScalarType::U8,
        (b'i', 1) => ScalarType::I8,
        (b'u', 2) => ScalarType::U16,
        (b'i', 2) => ScalarType::I16,
        (b'u', 4) => ScalarType::U32,
        (b'i', 4) => ScalarType::I32,
        (b'u', 8) => ScalarType::U64,
        (b'i', 8) => ScalarType::I64,
        (b'f', 4) => ScalarType::F32,
        (b'f', 8) => ScalarType::F64,
        _ => return None,
    };
    let native = if cfg!(target_endian = "little") {
        ByteOrder::Little
    } else {
        ByteOrder::Big
    };
    let order = match d.is_native_byteorder() {
        Some(false) => match native {
            ByteOrder::Little => ByteOrder::Big,
            ByteOrder::Big => ByteOrder::Little,
        },
        _ => native,
    };
    Some((ty, order))
}

/// `values` as a C-contiguous 3-D array of a type [`volume_type`] knows: itself where it is
/// one, else NumPy's C-contiguous copy (bool as uint8, float16 as float32, other floats as
/// float64).
fn c_array<'py>(values: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyUntypedArray>> {
    let np = values.py().import("numpy")?;
    let array = match values.cast::<PyUntypedArray>() {
        Ok(a) => a.clone(),
        Err(_) => np.call_method1("asarray", (values,))?.cast_into()?,
    };
    if array.ndim() != 3 {
        return Err(VolumeError::new_err(format!(
            "a volume needs a 3-D array indexed [z, y, x], got shape {:?}",
            array.shape()
        )));
    }
    if volume_type(&array).is_some() {
        if array.is_c_contiguous() {
            return Ok(array);
        }
        return np
            .call_method1("ascontiguousarray", (&array,))?
            .cast_into()
            .map_err(Into::into);
    }
    let d = array.dtype();
    let target = match (d.kind(), d.itemsize()) {
        (b'b', _) => "uint8",
        (b'f', 2) => "float32",
        (b'f', _) => "float64",
        _ => {
            return Err(VolumeError::new_err(format!(
                "a volume needs integers or floats, got an array of dtype {}",
                d.str()?
            )))
        }
    };
    let kwargs = [("dtype", target)].into_py_dict(values.py())?;
    np.call_method("ascontiguousarray", (&array,), Some(&kwargs))?
        .cast_into()
        .map_err(Into::into)
}

/// `values` as a volume reads them in place (module docs): the C-contiguous array, its
/// scalar type and byte order, and its memory shared with the volume (which keeps the array
/// alive).
pub(crate) fn shared_array<'py>(
    values: &Bound<'py, PyAny>,
) -> PyResult<(
    Bound<'py, PyUntypedArray>,
    ScalarType,
    ByteOrder,
    SharedBytes,
)> {
    let array = c_array(values)?;
    let (ty, order) = volume_type(&array).expect("c_array gives a volume type");
    // SAFETY: the array is C-contiguous (checked or made so by `c_array`), so its data
    // pointer starts `nbytes` bytes of values; the owner reference keeps them alive.
    let data = unsafe { (*array.as_array_ptr()).fields.data as *const u8 };
    let bytes = ArrayBytes {
        _owner: array.clone().into_any().unbind(),
        ptr: data,
        len: array.len() * ty.size(),
    };
    Ok((array, ty, order, std::sync::Arc::new(bytes)))
}

/// The grid of an array of `shape` [z, y, x]: dims are (x, y, z) in VTK's order. The library
/// checks spacing and origin when it builds the volume.
pub(crate) fn geometry(shape: &[usize], spacing: [f64; 3], origin: [f64; 3]) -> Geometry {
    Geometry {
        dims: [shape[2], shape[1], shape[0]],
        spacing,
        origin,
    }
}

#[pymethods]
impl PyVolume {
    #[new]
    #[pyo3(
        signature = (values, spacing = None, origin = None),
        text_signature = "(values, spacing=None, origin=None)"
    )]
    fn new(
        py: Python<'_>,
        values: &Bound<'_, PyAny>,
        spacing: Option<&Bound<'_, PyAny>>,
        origin: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyVolume> {
        let spacing = spacing.map_or(Ok([1.0; 3]), |s| triple("spacing", s))?;
        let origin = origin.map_or(Ok([0.0; 3]), |o| triple("origin", o))?;
        let (array, ty, order, shared) = shared_array(values)?;
        let g = geometry(array.shape(), spacing, origin);
        let budget = Budget::system();
        let volume = py
            .detach(|| {
                Volume::from_shared_within(Path::new(ARRAY_NAME), g, ty, order, shared, budget)
            })
            .map_err(errors::volume)?;
        Ok(PyVolume {
            volume,
            array: Some(array.into_any().unbind()),
            file: None,
        })
    }

    /// (nz, ny, nx): the shape of the array `to_numpy` returns.
    #[getter]
    fn shape(&self) -> (usize, usize, usize) {
        let [x, y, z] = self.volume.geometry.dims;
        (z, y, x)
    }

    /// World distance between neighbouring points along x, y, z.
    #[getter]
    fn spacing(&self) -> (f64, f64, f64) {
        let [x, y, z] = self.volume.geometry.spacing;
        (x, y, z)
    }

    /// World position of point [0, 0, 0] (x, y, z).
    #[getter]
    fn origin(&self) -> (f64, f64, f64) {
        let [x, y, z] = self.volume.geometry.origin;
        (x, y, z)
    }

    /// (min, max) of the finite values, in data units.
    #[getter]
    fn range(&self) -> (f64, f64) {
        (self.volume.range[0], self.volume.range[1])
    }

    /// NumPy's name of the values' type ("uint8", "float32", …).
    #[getter]
    fn dtype(&self) -> &'static str {
        self.volume.scalar_type.scivis_name()
    }

    /// How many values are NaN or infinite (they render as empty space).
    #[getter]
    fn non_finite(&self) -> usize {
        self.volume.non_finite
    }

    /// The file the volume was read from; None for an array.
    #[getter]
    pub fn path(&self) -> Option<PathBuf> {
        self.file.as_ref().map(|(p, _)| p.clone())
    }

    /// The values in data units as a read-only array indexed [z, y, x]: the array the
    /// volume reads (no copy) for an in-memory volume, the file's values decoded again
    /// (in their own type) for a file.
    fn to_numpy<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let array = match (&self.array, &self.file) {
            (Some(a), _) => a.bind(py).call_method0("view")?,
            (None, Some((path, opts))) => decoded(py, path, opts)?,
            (None, None) => unreachable!("a volume comes from an array or a file"),
        };
        let kwargs = [("write", false)].into_py_dict(py)?;
        array.call_method("setflags", (), Some(&kwargs))?;
        Ok(array)
    }

    fn __repr__(&self) -> String {
        let (z, y, x) = self.shape();
        let from = match &self.file {
            Some((p, _)) => format!(", path={:?}", p.display().to_string()),
            None => String::new(),
        };
        format!(
            "Volume(shape=({z}, {y}, {x}), dtype={}, range={:?}, spacing={:?}{from})",
            self.dtype(),
            self.range(),
            self.spacing()
        )
    }
}

/// A file's values in their own type as a NumPy array indexed [z, y, x].
fn decoded<'py>(py: Python<'py>, path: &Path, opts: &ReadOptions) -> PyResult<Bound<'py, PyAny>> {
    use numpy::{PyArray1, PyArrayMethods};
    let d = py
        .detach(|| t2tf::volume::decode(path, opts))
        .map_err(errors::volume)?;
    let [nx, ny, nz] = d.geometry.dims;
    macro_rules! typed {
        ($t:ty) => {{
            let mut v: Vec<$t> = Vec::with_capacity(d.buffer.len());
            // Values of the declared type, as f64 on the way: exact for every type but
            // 64-bit integers beyond 2^53.
            d.buffer.for_each(|x| v.push(x as $t));
            PyArray1::from_vec(py, v).reshape([nz, ny, nx])?.into_any()
        }};
    }
    Ok(match d.buffer.scalar_type() {
        ScalarType::U8 => typed!(u8),
        ScalarType::I8 => typed!(i8),
        ScalarType::U16 => typed!(u16),
        ScalarType::I16 => typed!(i16),
        ScalarType::U32 => typed!(u32),
        ScalarType::I32 => typed!(i32),
        ScalarType::U64 => typed!(u64),
        ScalarType::I64 => typed!(i64),
        ScalarType::F32 => typed!(f32),
        ScalarType::F64 => typed!(f64),
    })
}

/// Three numbers (x, y, z) from any sequence: a tuple, a list, a NumPy array.
pub fn triple(name: &str, value: &Bound<'_, PyAny>) -> PyResult<[f64; 3]> {
    let v: Vec<f64> = value
        .extract()
        .map_err(|_| errors::settings(format!("{name} must be three numbers (x, y, z)")))?;
    <[f64; 3]>::try_from(v.as_slice()).map_err(|_| {
        errors::settings(format!(
            "{name} must be three numbers (x, y, z), got {}",
            v.len()
        ))
    })
}

/// What `optimize` and `render` take as a volume: a `Volume`, a file's path (read as
/// `read_volume` reads it), or an array (as `Volume(array)` takes it).
pub fn volume_arg(py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<Py<PyVolume>> {
    if let Ok(v) = value.cast::<PyVolume>() {
        return Ok(v.clone().unbind());
    }
    let made = if let Ok(path) = value.extract::<PathBuf>() {
        read_volume(py, path, None, None, None, None, None)?
    } else {
        PyVolume::new(py, value, None, None)?
    };
    Py::new(py, made)
}

/// Read a volume file (`.raw`, `.vti`, `.vtk`) as `t2tf optimize` does.
///
/// Parameters:
///     path: the file. A raw file named NAME_XxYxZ_DTYPE.raw describes itself; other
///         raw files need dims and dtype.
///     dims: a raw file's points per axis (x, y, z), x fastest; None: from its name.
///     dtype: a raw file's scalar type ("uint16", np.uint16, ...); None: from its name.
///     spacing: grid spacing (x, y, z) in world units, replacing the file's; None: the
///         file's (1, 1, 1 for a raw file).
///     byte_order: a raw file's byte order, "little" or "big"; None: little.
///     array: the point-data array of a .vti or .vtk file; None: the active scalars,
///         else the first array.
#[pyfunction]
#[pyo3(
    signature = (path, *, dims = None, dtype = None, spacing = None, byte_order = None, array = None),
    text_signature = "(path, *, dims=None, dtype=None, spacing=None, byte_order=None, array=None)"
)]
pub fn read_volume(
    py: Python<'_>,
    path: PathBuf,
    dims: Option<(usize, usize, usize)>,
    dtype: Option<&Bound<'_, PyAny>>,
    spacing: Option<&Bound<'_, PyAny>>,
    byte_order: Option<&str>,
    array: Option<String>,
) -> PyResult<PyVolume> {
    let spacing = spacing.map(|s| triple("spacing", s)).transpose()?;
    let dtype = match dtype {
        None => None,
        // A name, or anything NumPy calls a dtype (np.uint16, np.dtype("<u2")).
        Some(d) => {
            let name: String = match d.extract::<String>() {
                Ok(s) => s,
                Err(_) => py
                    .import("numpy")?
                    .call_method1("dtype", (d,))?
                    .getattr("name")?
                    .extract()?,
            };
            Some(
                name.parse::<ScalarType>()
                    .map_err(|e| errors::volume_option(e.to_string(), "dtype"))?,
            )
        }
    };
    let byte_order = byte_order
        .map(|b| {
            b.parse::<ByteOrder>()
                .map_err(|e| errors::volume_option(e, "byte_order"))
        })
        .transpose()?;
    let opts = ReadOptions {
        dims: dims.map(|(x, y, z)| [x, y, z]),
        dtype,
        spacing,
        byte_order,
        array,
        budget: Budget::system(),
        norm_range: None,
    };
    let volume = py
        .detach(|| t2tf::volume::load(&path, &opts))
        .map_err(errors::volume)?;
    Ok(PyVolume {
        volume,
        array: None,
        file: Some((path, opts)),
    })
}
