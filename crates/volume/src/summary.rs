//! What `t2tf info` reports about a volume file, computed without making the volume: no f32
//! copy, no pyramid. The file is opened as a load opens it (`read::open`: a memory map, a
//! block-decoded `.vti`, or the values decoded in memory) and its statistics are the load's
//! first pass (`Source::stats`), plus a histogram pass for types wider than 16 bits; passes
//! over a map release its pages behind them, so memory stays bounded whatever the file's
//! size. The numbers equal those of [`super::load`] bit for bit: the same per-value formula
//! (`normalize_value`), the same range rule, and the level shapes of `pyramid`.

use std::path::Path;

use super::buffer::for_each_value;
use super::source::Source;
use super::{
    check_geometry, denormalize, half_scale, normalize_value, pyramid, Geometry, ReadOptions,
    ScalarType, VolumeError, VolumeSource, HISTOGRAM_BINS,
};

/// A volume file's statistics, as [`super::Volume`] would hold them after a load.
// The statistics fields repeat `Volume`'s on purpose: both are public structs the CLI and
// library users read field by field (`Volume` is used across the crate); one shared struct
// would change every caller of `Volume` outside `volume/`.
#[derive(Clone, Debug)]
pub struct Summary {
    /// Points per axis, spacing and origin.
    pub geometry: Geometry,
    /// The scalar type of the file.
    pub scalar_type: ScalarType,
    /// Finite min and max (data units).
    pub range: [f64; 2],
    /// The data range that maps to [0, 1] (`Volume::norm_range`).
    pub norm_range: [f64; 2],
    /// Count of NaN/Inf values.
    pub non_finite: usize,
    /// Counts of normalized values in `HISTOGRAM_BINS` equal bins over [0, 1].
    pub histogram: Vec<u64>,
    /// Points per axis of every mip level a load would build, level 0 first.
    pub levels: Vec<[usize; 3]>,
    /// Bytes a load holds for level 0 (`Level::memory_bytes`).
    pub level0_bytes: usize,
    /// Bytes a load holds for levels 1 and up.
    pub pyramid_bytes: usize,
    /// The file and how it was read.
    pub source: VolumeSource,
}

impl Summary {
    /// Map a normalized value in [0, 1] back to data units (as `Volume::denormalize`).
    pub fn denormalize(&self, t: f64) -> f64 {
        denormalize(self.norm_range, t)
    }
}

/// Summarize the volume file at `path` read with `opts`.
pub fn summarize(path: &Path, opts: &ReadOptions) -> Result<Summary, VolumeError> {
    // The source a load reads (`read::open`: the checks and errors of `load`).
    let (geometry, scalar_type, format, source) = super::read::open(path, opts)?;
    check_geometry(path, &geometry, source.len())?;
    let Some((mut stats, _)) = source.stats()? else {
        return Err(VolumeError::file(
            path,
            "every value is NaN or infinite: nothing to render",
        ));
    };
    if stats.histogram.is_empty() {
        // Wider types: `stats` finds the range; their bins need a second pass (a load counts
        // them while normalizing, `stream`).
        stats.histogram = histogram(&source, stats.norm_range)?;
    }
    let levels: Vec<[usize; 3]> = pyramid::level_shapes(geometry)
        .into_iter()
        .map(|(d, _)| d)
        .collect();
    let bytes: Vec<usize> = levels.iter().map(|&d| pyramid::level_bytes(d)).collect();
    Ok(Summary {
        geometry,
        scalar_type,
        range: stats.range,
        norm_range: stats.norm_range,
        non_finite: stats.non_finite,
        histogram: stats.histogram,
        levels,
        level0_bytes: bytes[0],
        pyramid_bytes: bytes[1..].iter().sum(),
        source: VolumeSource {
            path: path.to_path_buf(),
            format,
        },
    })
}

/// The histogram of the file at `path` over `norm_range` instead of its own range (a step
/// of a series, binned over the series' range): the counts a load with
/// `ReadOptions::norm_range` makes, bit for bit, without making the volume.
pub(crate) fn histogram_over(
    path: &Path,
    opts: &ReadOptions,
    norm_range: [f64; 2],
) -> Result<Vec<u64>, VolumeError> {
    let (geometry, _, _, source) = super::read::open(path, opts)?;
    check_geometry(path, &geometry, source.len())?;
    if super::stats::small_codes(source.ty()).is_some() {
        if let Some((_, Some(counts))) = source.stats()? {
            return Ok(super::stats::code_histogram(
                source.ty(),
                &counts,
                norm_range,
            ));
        }
    }
    histogram(&source, norm_range)
}

/// Counts of the finite values in `HISTOGRAM_BINS` equal bins over `norm_range`.
fn histogram(source: &Source, norm_range: [f64; 2]) -> Result<Vec<u64>, VolumeError> {
    let (ty, order) = (source.ty(), source.order());
    let parts = source.par_fold(
        || Histogram::new(norm_range),
        |h, bytes| for_each_value(ty, order, bytes, |v| h.add(v)),
    )?;
    let mut counts = vec![0u64; HISTOGRAM_BINS];
    for p in parts {
        for (c, k) in counts.iter_mut().zip(p.counts) {
            *c += k;
        }
    }
    Ok(counts)
}

/// Histogram of the finite values over a known normalization range.
struct Histogram {
    norm_range: [f64; 2],
    scale: f64,
    counts: Vec<u64>,
}

impl Histogram {
    fn new(norm_range: [f64; 2]) -> Histogram {
        Histogram {
            norm_range,
            scale: half_scale(norm_range),
            counts: vec![0; HISTOGRAM_BINS],
        }
    }

    fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.counts[normalize_value(v, self.norm_range, self.scale).1] += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::count_codes;
    use crate::ByteOrder;

    /// Several passes' blocks, a short last one, odd shares: the mapped source's split count
    /// equals a plain count, for both byte orders of 16-bit data and for 8-bit data.
    #[test]
    fn split_count_equals_a_plain_count() {
        let dir = tempfile::tempdir().unwrap();
        let values = (4 << 20) + (2 << 20) + 3; // 16-bit: 2 blocks of the pass, the last short
        let mut x = 0x2545_f491_u32;
        let bytes: Vec<u8> = (0..2 * values)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                (x >> 24) as u8
            })
            .collect();
        let path = dir.path().join("v.raw");
        std::fs::write(&path, &bytes).unwrap();
        for (ty, order, codes) in [
            (ScalarType::U16, ByteOrder::Little, 1 << 16),
            (ScalarType::U16, ByteOrder::Big, 1 << 16),
            (ScalarType::U8, ByteOrder::Little, 1 << 8),
        ] {
            let mut want = vec![0u64; codes];
            count_codes(ty, order, &bytes, &mut want);
            let n = bytes.len() / ty.size();
            let source = Source::map(&path, ty, order, 0, n).unwrap();
            let (_, counts) = source.stats().unwrap().unwrap();
            assert_eq!(counts.unwrap(), want, "{ty:?} {order:?}");
        }
    }

    /// Every type and byte order: the summary equals the loaded volume's statistics, with a
    /// block size that splits the file mid-way.
    #[test]
    fn summary_equals_load() {
        let dir = tempfile::tempdir().unwrap();
        let dims = [13, 11, 7];
        let n: usize = dims.iter().product();
        for ty in ScalarType::ALL {
            for order in [ByteOrder::Little, ByteOrder::Big] {
                let mut values: Vec<f64> = (0..n)
                    .map(|i| {
                        ((i * 7919) % 251) as f64
                            - if ty.integer_range().is_some_and(|r| r.0 < 0.0) {
                                100.0
                            } else {
                                0.0
                            }
                    })
                    .collect();
                if ty.integer_range().is_none() {
                    values[3] = f64::NAN;
                    values[9] = f64::INFINITY;
                    values[10] = 0.125;
                }
                let bytes = encode(&values, ty, order);
                let path = dir
                    .path()
                    .join(format!("v_13x11x7_{}.raw", ty.scivis_name()));
                std::fs::write(&path, &bytes).unwrap();
                let opts = ReadOptions {
                    byte_order: Some(order),
                    ..Default::default()
                };
                let s = summarize(&path, &opts).unwrap();
                let v = super::super::load(&path, &opts).unwrap();
                let what = format!("{ty} {order:?}");
                assert_eq!(s.geometry, v.geometry, "{what}");
                assert_eq!(s.scalar_type, v.scalar_type, "{what}");
                assert_eq!(s.range, v.range, "{what}");
                assert_eq!(s.norm_range, v.norm_range, "{what}");
                assert_eq!(s.non_finite, v.non_finite, "{what}");
                assert_eq!(s.histogram, v.histogram, "{what}");
                assert_eq!(s.source, v.source.clone().unwrap(), "{what}");
                let dims: Vec<[usize; 3]> = v.levels.iter().map(|l| l.dims).collect();
                assert_eq!(s.levels, dims, "{what}");
                assert_eq!(s.level0_bytes, v.levels[0].memory_bytes(), "{what}");
                assert_eq!(s.level0_bytes + s.pyramid_bytes, v.memory_bytes(), "{what}");
            }
        }
    }

    /// `values` stored as `ty` in `order` (values are exact in every type used above).
    fn encode(values: &[f64], ty: ScalarType, order: ByteOrder) -> Vec<u8> {
        macro_rules! enc {
            ($t:ty) => {
                values
                    .iter()
                    .flat_map(|&v| match order {
                        ByteOrder::Little => (v as $t).to_le_bytes().to_vec(),
                        ByteOrder::Big => (v as $t).to_be_bytes().to_vec(),
                    })
                    .collect()
            };
        }
        match ty {
            ScalarType::U8 => enc!(u8),
            ScalarType::I8 => enc!(i8),
            ScalarType::U16 => enc!(u16),
            ScalarType::I16 => enc!(i16),
            ScalarType::U32 => enc!(u32),
            ScalarType::I32 => enc!(i32),
            ScalarType::U64 => enc!(u64),
            ScalarType::I64 => enc!(i64),
            ScalarType::F32 => enc!(f32),
            ScalarType::F64 => enc!(f64),
        }
    }
}
