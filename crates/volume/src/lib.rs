//! Volumes: reading `.raw`, `.vti` and legacy `.vtk` files into one normalized [`Volume`].
//!
//! Readers (`raw`, `vti`, `legacy`) decode a file into a [`TypedBuffer`] (the file's own scalar
//! type and byte order, untouched) plus [`Geometry`], or locate its values in the file where
//! they lie there contiguously. [`load`] streams them from a `source` (a memory map, else the
//! decoded bytes; `stream`): values normalized to [0, 1] by the finite min/max
//! (docs/DESIGN.md, "Conventions"), NaN/Inf voxels kept as NaN (the renderer treats them as
//! empty), the histogram, and the mip pyramid with per-brick value ranges for empty-space
//! skipping, in one pass for 8/16-bit data and two for other types. Only the coarse levels
//! are held, in 16 bits where they hold no NaN; level 0 (and any level finer than 512³) is
//! made when asked for ([`Level::try_data`]) or read box by box ([`Level::read_box`]).
//! [`Volume::from_buffer`] is the same build over values already in memory, holding every
//! level.

#![warn(missing_docs)]

mod blocks;
mod buffer;
mod legacy;
mod pages;
mod pyramid;
mod raw;
mod read;
mod series;
mod source;
mod stats;
mod stream;
mod summary;
mod vti;
mod vti_blocks;

pub use buffer::{ByteOrder, ScalarType, TextValueError, TypedBuffer, UnknownScalarType};
pub use pyramid::Narrow;
pub use pyramid::{BrickGrid, Level, LevelCell, BRICK_CELLS};
pub use read::{decode, decode_bytes, load, Decoded, ReadOptions};
pub use series::{is_series_path, Series, SeriesStats, SeriesStep, TimeSelection};
pub use summary::{summarize, Summary};

use std::path::{Path, PathBuf};
use std::sync::Arc;

pub use t2tf_core::memory::Budget;

/// Values another owner keeps in memory (e.g. a NumPy array of a Python caller), which a
/// volume reads in place for as long as it lives ([`Volume::from_shared_within`]).
pub type SharedBytes = Arc<dyn AsRef<[u8]> + Send + Sync>;

/// Number of histogram bins over the normalized value range.
pub const HISTOGRAM_BINS: usize = 256;

/// Where a volume came from, with what a ParaView or VisIt script needs to open the same file.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeSource {
    /// The file.
    pub path: PathBuf,
    /// Its format and reader settings.
    pub format: SourceFormat,
}

/// The file format and the reader settings that decode it.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceFormat {
    /// Headerless raw array, x fastest.
    Raw {
        /// The values' type.
        scalar_type: ScalarType,
        /// The values' byte order.
        byte_order: ByteOrder,
    },
    /// VTK XML ImageData; `array` is the point-data array that was read.
    Vti {
        /// The array's name.
        array: String,
    },
    /// Legacy VTK STRUCTURED_POINTS; `array` is the scalars' name.
    LegacyVtk {
        /// The scalars' name.
        array: String,
    },
}

/// Grid geometry in VTK ImageData terms: point (i, j, k) sits at `origin + (i, j, k) * spacing`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geometry {
    /// Points per axis.
    pub dims: [usize; 3],
    /// World distance between neighbouring points, per axis.
    pub spacing: [f64; 3],
    /// World position of point (0, 0, 0).
    pub origin: [f64; 3],
}

impl Geometry {
    /// Number of points.
    pub fn voxel_count(&self) -> usize {
        self.dims.iter().product()
    }

    /// World-space extent of the box: `(dims - 1) * spacing` per axis.
    pub fn extent(&self) -> [f64; 3] {
        std::array::from_fn(|a| (self.dims[a].saturating_sub(1)) as f64 * self.spacing[a])
    }

    /// The box's longest side `L`: one unit of normalized length (docs/DESIGN.md density units).
    /// A degenerate box (every side zero) counts as 1 so densities stay finite.
    pub fn longest_side(&self) -> f64 {
        let l = self.extent().into_iter().fold(0.0, f64::max);
        if l > 0.0 {
            l
        } else {
            1.0
        }
    }

    /// World position of the box centre.
    pub fn center(&self) -> [f64; 3] {
        let e = self.extent();
        std::array::from_fn(|a| self.origin[a] + 0.5 * e[a])
    }

    /// Half the box diagonal: the radius the camera distance is measured in.
    pub fn bounding_radius(&self) -> f64 {
        let e = self.extent();
        let r = 0.5 * (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        if r > 0.0 {
            r
        } else {
            0.5
        }
    }
}

/// Why a volume could not be made. Readers wrap these with the file's path.
#[derive(Debug, thiserror::Error)]
pub enum VolumeError {
    /// A file that cannot be read as a volume.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it (one line).
        message: String,
    },
    /// The file could not be read. The io error is part of the message rather than a
    /// `source`, so the CLI's `{:#}` cause chain prints it once, on one line.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        error: std::io::Error,
    },
}

impl VolumeError {
    /// An error about `path`. The message is kept to one line of bounded length, since parser
    /// errors may quote the file's own text (newlines included).
    pub fn file(path: &Path, message: impl Into<String>) -> Self {
        const MAX_CHARS: usize = 300;
        let message: String = message.into();
        let mut one_line = message
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect::<Vec<_>>()
            .join(" ");
        if let Some((cut, _)) = one_line.char_indices().nth(MAX_CHARS) {
            one_line.truncate(cut);
            one_line.push('…');
        }
        VolumeError::File {
            path: path.to_path_buf(),
            message: one_line,
        }
    }
}

/// A scalar volume ready to render: normalized samples, statistics and the mip pyramid.
#[derive(Clone, Debug)]
pub struct Volume {
    /// Points per axis, spacing and origin.
    pub geometry: Geometry,
    /// The scalar type of the file the values came from.
    pub scalar_type: ScalarType,
    /// Finite min and max of the original values (data units). Equal for a constant volume.
    pub range: [f64; 2],
    /// The data range that maps to [0, 1]: `range`, widened to `range ± 0.5` for a constant
    /// volume so that every exported TF still has a non-empty x range.
    pub norm_range: [f64; 2],
    /// Count of NaN/Inf voxels (stored as NaN in the normalized data: empty space).
    pub non_finite: usize,
    /// Counts of normalized values in `HISTOGRAM_BINS` equal bins over [0, 1].
    pub histogram: Vec<u64>,
    /// Mip pyramid; `levels[0]` holds the full-resolution normalized samples.
    pub levels: Vec<Level>,
    /// The file this volume was read from, if any.
    pub source: Option<VolumeSource>,
    /// The time series this volume is one step of (`Series::load_step`), normalized over
    /// the series' range; scripts then open the series.
    pub series: Option<Arc<Series>>,
}

impl Volume {
    /// Normalize a decoded buffer into a volume. `name` names the data in errors. What it
    /// makes is checked against what the system has ([`Budget::system`]).
    pub fn from_buffer(
        name: &Path,
        geometry: Geometry,
        buffer: &TypedBuffer,
    ) -> Result<Volume, VolumeError> {
        Self::from_buffer_within(name, geometry, buffer, Budget::system())
    }

    /// [`Volume::from_buffer`] within `budget`.
    pub fn from_buffer_within(
        name: &Path,
        geometry: Geometry,
        buffer: &TypedBuffer,
        budget: Budget,
    ) -> Result<Volume, VolumeError> {
        check_in_memory(name, &geometry, buffer.len(), budget)?;
        let source = source::Source::memory(name, buffer.clone());
        let ty = buffer.scalar_type();
        Self::streamed(name, geometry, ty, source, stream::Hold::All, budget, None)
    }

    /// [`Volume::from_buffer_within`] over values of type `scalar_type` in `byte_order` that
    /// stay where they are: the volume keeps `bytes` and reads level 0 from them (no copy of
    /// the values in their own type). They must not change while the volume lives; the
    /// statistics and coarse levels are computed now.
    pub fn from_shared_within(
        name: &Path,
        geometry: Geometry,
        scalar_type: ScalarType,
        byte_order: ByteOrder,
        bytes: SharedBytes,
        budget: Budget,
    ) -> Result<Volume, VolumeError> {
        Self::from_shared_over(name, geometry, scalar_type, byte_order, bytes, budget, None)
    }

    /// [`Volume::from_shared_within`], normalized over `norm_range` when given instead of
    /// the values' own range (the steps of a series in memory share one; it must hold every
    /// finite value).
    pub fn from_shared_over(
        name: &Path,
        geometry: Geometry,
        scalar_type: ScalarType,
        byte_order: ByteOrder,
        bytes: SharedBytes,
        budget: Budget,
        norm_range: Option<[f64; 2]>,
    ) -> Result<Volume, VolumeError> {
        let len = (*bytes).as_ref().len();
        if len % scalar_type.size() != 0 {
            return Err(VolumeError::file(
                name,
                format!("{len} bytes are not a whole number of {scalar_type} values"),
            ));
        }
        check_in_memory(name, &geometry, len / scalar_type.size(), budget)?;
        let source = source::Source::shared(name, scalar_type, byte_order, bytes);
        Self::streamed(
            name,
            geometry,
            scalar_type,
            source,
            stream::Hold::All,
            budget,
            norm_range,
        )
    }

    /// Stream `source` into a volume (`stream` module docs): the statistics and every level's
    /// brick ranges are computed now, the coarse levels are held, level 0 and any level finer
    /// than 512³ are made when asked for. Bit for bit what [`Volume::from_buffer`] gives for
    /// the same values. `norm_range`: normalize over this range instead of the values' own
    /// (`ReadOptions::norm_range`).
    pub(crate) fn from_source(
        name: &Path,
        geometry: Geometry,
        scalar_type: ScalarType,
        source: source::Source,
        budget: Budget,
        norm_range: Option<[f64; 2]>,
    ) -> Result<Volume, VolumeError> {
        Self::streamed(
            name,
            geometry,
            scalar_type,
            source,
            stream::Hold::Fit,
            budget,
            norm_range,
        )
    }

    /// The volume of `source`, holding the levels `hold` says.
    fn streamed(
        name: &Path,
        geometry: Geometry,
        scalar_type: ScalarType,
        source: source::Source,
        hold: stream::Hold,
        budget: Budget,
        norm_range: Option<[f64; 2]>,
    ) -> Result<Volume, VolumeError> {
        check_geometry(name, &geometry, source.len())?;
        let Some(s) = stream::stream(geometry, scalar_type, source, hold, budget, norm_range)?
        else {
            return Err(GeometryError::NoFiniteValues.at(name));
        };
        Ok(Volume {
            geometry,
            scalar_type,
            range: s.stats.range,
            norm_range: s.stats.norm_range,
            non_finite: s.stats.non_finite,
            histogram: s.stats.histogram,
            levels: s.levels,
            source: None,
            series: None,
        })
    }

    /// Full-resolution normalized samples, x fastest (NaN = empty). Made on first use; panics
    /// when they do not fit the memory budget (see [`Level::try_data`]).
    pub fn data(&self) -> &[f32] {
        self.levels[0].data()
    }

    /// Points per axis of level 0.
    pub fn dims(&self) -> [usize; 3] {
        self.geometry.dims
    }

    /// Map a normalized value in [0, 1] back to data units.
    pub fn denormalize(&self, t: f64) -> f64 {
        denormalize(self.norm_range, t)
    }

    /// Bytes the normalized data and the pyramid take with every level made
    /// ([`Level::memory_bytes`]).
    pub fn memory_bytes(&self) -> usize {
        self.levels.iter().map(Level::memory_bytes).sum()
    }
}

/// Before a volume is built over `values` values in memory: the geometry fits them, and
/// level 0's f32 copy and the coarser levels with their brick ranges fit `budget` (a
/// renderer's copies are checked where they are made).
fn check_in_memory(
    name: &Path,
    geometry: &Geometry,
    values: usize,
    budget: Budget,
) -> Result<(), VolumeError> {
    check_geometry(name, geometry, values)?;
    let bytes = pyramid::level_shapes(*geometry)
        .iter()
        .try_fold(0u64, |acc, (dims, _)| {
            t2tf_core::memory::product(dims)?;
            acc.checked_add(pyramid::level_bytes(*dims) as u64)
        });
    budget
        .check(
            format!(
                "{}x{}x{} points",
                geometry.dims[0], geometry.dims[1], geometry.dims[2]
            ),
            bytes,
            1,
            "use a smaller volume or crop it",
        )
        .map_err(|e| VolumeError::file(name, e.to_string()))
}

/// `t` in [0, 1] in data units for the normalization range `norm_range`.
fn denormalize([lo, hi]: [f64; 2], t: f64) -> f64 {
    let width = hi - lo;
    if width.is_finite() {
        lo + t * width
    } else {
        // f64 data spanning more than f64's range: interpolate without the width.
        lo * (1.0 - t) + hi * t
    }
}

/// Why decoded data cannot be made into a volume. The caller adds the file's path.
#[derive(Debug, thiserror::Error)]
enum GeometryError {
    #[error("every value is NaN or infinite: nothing to render")]
    NoFiniteValues,
    #[error("dimensions {0:?} contain a zero")]
    ZeroDimension([usize; 3]),
    #[error(
        "holds {values} values but dimensions {}x{}x{} need {needed}",
        .dims[0], .dims[1], .dims[2]
    )]
    ValueCount {
        values: usize,
        dims: [usize; 3],
        needed: usize,
    },
    #[error("spacing {spacing:?} and origin {origin:?} must be finite, spacing positive")]
    BadSpacing { spacing: [f64; 3], origin: [f64; 3] },
    #[error(
        "spacing {spacing:?} with origin {origin:?} gives a box of {extent:?} that single \
         precision cannot represent; give a spacing near 1 with --spacing X,Y,Z"
    )]
    BoxUnrepresentable {
        spacing: [f64; 3],
        origin: [f64; 3],
        extent: [f64; 3],
    },
}

impl GeometryError {
    fn at(self, path: &Path) -> VolumeError {
        VolumeError::file(path, self.to_string())
    }
}

/// The statistics and the one f32 copy of a buffer: the plain per-value normalization that
/// the streaming build is tested against (`stream`'s tests).
#[cfg(test)]
struct Normalized {
    range: [f64; 2],
    norm_range: [f64; 2],
    non_finite: usize,
    histogram: Vec<u64>,
    data: Vec<f32>,
}

/// What every volume (and every summary) must satisfy: no empty axis, `values` values for the
/// dims, finite positive spacing and finite origin, and a box single precision can hold.
fn check_geometry(name: &Path, geometry: &Geometry, values: usize) -> Result<(), VolumeError> {
    let n = geometry.voxel_count();
    if geometry.dims.contains(&0) {
        return Err(GeometryError::ZeroDimension(geometry.dims).at(name));
    }
    if values != n {
        let e = GeometryError::ValueCount {
            values,
            dims: geometry.dims,
            needed: n,
        };
        return Err(e.at(name));
    }
    for a in 0..3 {
        let s = geometry.spacing[a];
        if !(s.is_finite() && s > 0.0 && geometry.origin[a].is_finite()) {
            let e = GeometryError::BadSpacing {
                spacing: geometry.spacing,
                origin: geometry.origin,
            };
            return Err(e.at(name));
        }
    }

    check_box(name, geometry)
}

/// The renderer works in f32 world coordinates: the box (origin to far corner) must be finite
/// there and each side with more than one point must not vanish, or rays miss the box and the
/// render is blank.
fn check_box(name: &Path, g: &Geometry) -> Result<(), VolumeError> {
    let extent = g.extent();
    let finite = (0..3).all(|a| {
        (g.origin[a] as f32).is_finite() && ((g.origin[a] + extent[a]) as f32).is_finite()
    });
    let sides = (0..3).all(|a| g.dims[a] < 2 || (extent[a] as f32).is_normal());
    if finite && sides {
        return Ok(());
    }
    Err(GeometryError::BoxUnrepresentable {
        spacing: g.spacing,
        origin: g.origin,
        extent,
    }
    .at(name))
}

/// The range that maps to [0, 1]: the finite range, widened by ±0.5 when it is one value.
fn norm_range(lo: f64, hi: f64) -> [f64; 2] {
    if hi > lo {
        [lo, hi]
    } else {
        [lo - 0.5, lo + 0.5]
    }
}

/// `scale` of [`normalize_value`]: 1 / half the range width. Halves, because the width of
/// f64 data near ±f64::MAX overflows (halving is exact, so other data normalize as before).
fn half_scale(norm_range: [f64; 2]) -> f64 {
    1.0 / (norm_range[1] * 0.5 - norm_range[0] * 0.5)
}

/// A finite value's normalized sample and histogram bin (`scale` from [`half_scale`]).
/// Shared by both normalization paths so that they agree bit for bit.
#[inline]
fn normalize_value(v: f64, norm_range: [f64; 2], scale: f64) -> (f32, usize) {
    let t = ((v * 0.5 - norm_range[0] * 0.5) * scale).clamp(0.0, 1.0);
    let bin = ((t * HISTOGRAM_BINS as f64) as usize).min(HISTOGRAM_BINS - 1);
    (t as f32, bin)
}

/// Two passes over any buffer, value by value; `None` when no value is finite. The reference
/// for `stream` (tests only).
#[cfg(test)]
fn normalize(buffer: &TypedBuffer) -> Option<Normalized> {
    // Pass 1: finite range in f64 (f64 inputs beyond f32's range stay exact here).
    let (mut lo, mut hi, mut non_finite) = (f64::INFINITY, f64::NEG_INFINITY, 0usize);
    buffer.for_each(|v| {
        if v.is_finite() {
            lo = lo.min(v);
            hi = hi.max(v);
        } else {
            non_finite += 1;
        }
    });
    if non_finite == buffer.len() {
        return None;
    }
    let norm_range = norm_range(lo, hi);

    // Pass 2: the one f32 copy, normalized; non-finite voxels become NaN.
    let scale = half_scale(norm_range);
    let mut data = Vec::with_capacity(buffer.len());
    let mut histogram = vec![0u64; HISTOGRAM_BINS];
    buffer.for_each(|v| {
        if v.is_finite() {
            let (t, bin) = normalize_value(v, norm_range, scale);
            histogram[bin] += 1;
            data.push(t);
        } else {
            data.push(f32::NAN);
        }
    });
    Some(Normalized {
        range: [lo, hi],
        norm_range,
        non_finite,
        histogram,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geom(dims: [usize; 3]) -> Geometry {
        Geometry {
            dims,
            spacing: [1.0; 3],
            origin: [0.0; 3],
        }
    }

    #[test]
    fn normalizes_by_finite_range_and_keeps_nan_empty() {
        let values = vec![2.0f64, 4.0, f64::NAN, 6.0, f64::INFINITY, 3.0, 5.0, 4.0];
        let buf = TypedBuffer::from_f64(values);
        let v = Volume::from_buffer(Path::new("t"), geom([2, 2, 2]), &buf).unwrap();
        assert_eq!(v.range, [2.0, 6.0]);
        assert_eq!(v.non_finite, 2);
        assert_eq!(v.data()[0], 0.0);
        assert_eq!(v.data()[1], 0.5);
        assert!(v.data()[2].is_nan());
        assert_eq!(v.data()[3], 1.0);
        assert_eq!(v.histogram.iter().sum::<u64>(), 6);
    }

    #[test]
    fn shared_bytes_give_the_buffers_volume() {
        let values: Vec<u16> = (0..60).map(|i| (i * 997 % 1000) as u16).collect();
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let buf = TypedBuffer::new(ScalarType::U16, ByteOrder::Big, bytes.clone());
        let a = Volume::from_buffer(Path::new("t"), geom([5, 4, 3]), &buf).unwrap();
        let shared: SharedBytes = Arc::new(bytes);
        let b = Volume::from_shared_within(
            Path::new("t"),
            geom([5, 4, 3]),
            ScalarType::U16,
            ByteOrder::Big,
            shared.clone(),
            Budget::system(),
        )
        .unwrap();
        assert_eq!((a.range, &a.histogram), (b.range, &b.histogram));
        assert_eq!(a.data(), b.data());
        let odd: SharedBytes = Arc::new(vec![0u8; 7]);
        let e = Volume::from_shared_within(
            Path::new("t"),
            geom([7, 1, 1]),
            ScalarType::U16,
            ByteOrder::Little,
            odd,
            Budget::system(),
        );
        assert!(e.unwrap_err().to_string().contains("whole number"));
    }

    #[test]
    fn constant_volume_maps_to_middle() {
        let buf = TypedBuffer::from_f64(vec![7.0; 8]);
        let v = Volume::from_buffer(Path::new("t"), geom([2, 2, 2]), &buf).unwrap();
        assert_eq!(v.range, [7.0, 7.0]);
        assert_eq!(v.norm_range, [6.5, 7.5]);
        assert!(v.data().iter().all(|&x| x == 0.5));
    }

    #[test]
    fn huge_f64_range_stays_finite() {
        let buf = TypedBuffer::from_f64(vec![-1e300, 1e300, 0.0, 5.0]);
        let v = Volume::from_buffer(Path::new("t"), geom([4, 1, 1]), &buf).unwrap();
        assert!(v.data().iter().all(|x| x.is_finite()));
        assert_eq!(v.data()[1], 1.0);
    }

    #[test]
    fn file_errors_are_one_bounded_line() {
        let e = VolumeError::file(Path::new("a.vti"), "found `</x\n   </y>`\r\n");
        assert_eq!(e.to_string(), "a.vti: found `</x </y>`");
        let long = VolumeError::file(Path::new("a"), "é".repeat(1000)).to_string();
        assert_eq!(long.chars().count(), "a: ".len() + 300 + 1);
    }

    #[test]
    fn rejects_all_nan_zero_dims_and_size_mismatch() {
        let nan = TypedBuffer::from_f64(vec![f64::NAN; 8]);
        let e = Volume::from_buffer(Path::new("x.raw"), geom([2, 2, 2]), &nan).unwrap_err();
        assert!(e.to_string().starts_with("x.raw: every value"), "{e}");
        let buf = TypedBuffer::from_f64(vec![1.0; 8]);
        assert!(Volume::from_buffer(Path::new("t"), geom([2, 0, 2]), &buf).is_err());
        assert!(Volume::from_buffer(Path::new("t"), geom([2, 2, 3]), &buf).is_err());
    }
}
