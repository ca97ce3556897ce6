//! The streaming build of a volume's statistics and mip pyramid over a [`Source`].
//!
//! [`stream`] reads level 0's z-slices in order and, from each, adds to the statistics,
//! level 0's brick ranges and the pyramid's `Reducer`, which makes every coarser level's
//! slices and brick ranges as it goes. Memory beyond the levels held is one slice of level 0
//! and a few slices per coarser level. Level 0 is never held by the stream: it is read from the
//! source when asked for (`Level::data`, `Level::read_box`).
//!
//! Levels are filtered in one of two [`Units`]:
//! - **8/16-bit integers: one pass.** The slices go in as the codes' own values (exact in
//!   f32), and the codes are counted on the way; the finite range, the histogram and the
//!   normalization follow from the counts at the end, and only then are the held levels and
//!   all brick ranges normalized (normalizing is non-decreasing, so a brick's normalized
//!   min is its min normalized). Values up to 65535 in f32 keep ≥ 2⁻⁸ of a code, far below a
//!   16-bit rounding step.
//! - **Other types: two passes.** The range must be known before a value is normalized: wide
//!   integers and floats lose their precision in f32 data units (a range of [10⁶, 10⁶ + 1]),
//!   so the statistics come first, then the slices go in normalized.
//!
//! Filtered levels without NaN are rounded to 16 bits (`pyramid::Samples::Round16`): held so,
//! read so from the source (`Level::read_box`), with brick ranges of the rounded values. It is
//! what the renderer stores for them anyway, and it halves the held levels' memory.
//! `Volume::from_buffer` is this build over the decoded values with every level held.

use std::sync::Arc;
use t2tf_core::memory::Budget;

use super::pyramid::{self, BrickGridBuilder, Level, LevelSource, Narrow, Reducer, Samples};
use super::source::Source;
use super::stats::{code_histogram, code_stats, code_value, small_codes, Stats};
use super::{
    buffer::for_each_value, half_scale, normalize_value, ByteOrder, Geometry, ScalarType,
    VolumeError,
};

/// How a source's values become normalized samples (docs/DESIGN.md, "Conventions").
#[derive(Debug)]
pub(crate) struct Norm {
    norm_range: [f64; 2],
    scale: f64,
    /// For 8/16-bit codes: the sample of every code.
    lut: Option<Vec<f32>>,
}

impl Norm {
    pub(super) fn new(ty: ScalarType, norm_range: [f64; 2]) -> Norm {
        let scale = half_scale(norm_range);
        let lut = small_codes(ty).map(|codes| {
            (0..codes)
                .map(|c| normalize_value(code_value(ty, c), norm_range, scale).0)
                .collect()
        });
        Norm {
            norm_range,
            scale,
            lut,
        }
    }

    /// A value in data units normalized (NaN stays NaN). For a code this is its table entry:
    /// the same f64 formula on the same number.
    #[inline]
    pub(super) fn apply(&self, v: f32) -> f32 {
        if v.is_nan() {
            f32::NAN
        } else {
            normalize_value(v as f64, self.norm_range, self.scale).0
        }
    }

    /// Normalized samples of values `start..start + out.len()` of `src` into `out`. For wider
    /// types (no table) it also counts each finite value's bin into `histogram` when given;
    /// 8/16-bit sources have their histogram from the code counts.
    pub(crate) fn read(
        &self,
        src: &Source,
        start: usize,
        out: &mut [f32],
        mut histogram: Option<&mut Vec<u64>>,
    ) -> Result<(), VolumeError> {
        let (ty, order) = (src.ty(), src.order());
        let mut i = 0;
        src.for_bytes(start..start + out.len(), |bytes| {
            if let Some(lut) = &self.lut {
                i += lookup(ty, order, bytes, lut, &mut out[i..], None);
                return;
            }
            for_each_value(ty, order, bytes, |v| {
                out[i] = if v.is_finite() {
                    let (t, bin) = normalize_value(v, self.norm_range, self.scale);
                    if let Some(h) = histogram.as_deref_mut() {
                        h[bin] += 1;
                    }
                    t
                } else {
                    f32::NAN
                };
                i += 1;
            });
        })
    }
}

/// `table[code]` of each 8/16-bit value in `bytes` into `out`, counting the codes into
/// `counts` when given; returns the number of values.
#[inline]
fn lookup(
    ty: ScalarType,
    order: ByteOrder,
    bytes: &[u8],
    table: &[f32],
    out: &mut [f32],
    mut counts: Option<&mut [u64]>,
) -> usize {
    let mut put = |o: &mut f32, c: usize| {
        *o = table[c];
        if let Some(k) = counts.as_deref_mut() {
            k[c] += 1;
        }
    };
    if ty.size() == 1 {
        for (o, &b) in out.iter_mut().zip(bytes) {
            put(o, b as usize);
        }
        return bytes.len();
    }
    for (o, c) in out.iter_mut().zip(bytes.chunks_exact(2)) {
        let b = [c[0], c[1]];
        let code = match order {
            ByteOrder::Little => u16::from_le_bytes(b),
            ByteOrder::Big => u16::from_be_bytes(b),
        };
        put(o, code as usize);
    }
    bytes.len() / 2
}

/// What the levels are filtered in (module docs).
#[derive(Debug)]
enum Units {
    /// 8/16-bit codes: each code's value as f32 (the table), normalized after filtering.
    Codes(Vec<f32>),
    /// Normalized values.
    Normalized,
}

impl Units {
    fn of(ty: ScalarType) -> Units {
        match small_codes(ty) {
            Some(codes) => Units::Codes((0..codes).map(|c| code_value(ty, c) as f32).collect()),
            None => Units::Normalized,
        }
    }

    /// Values `start..start + out.len()` of `src` in these units into `out`, counting codes
    /// into `counts` when given (codes only).
    fn read(
        &self,
        src: &Source,
        norm: Option<&Norm>,
        start: usize,
        out: &mut [f32],
        mut counts: Option<&mut [u64]>,
    ) -> Result<(), VolumeError> {
        match self {
            Units::Codes(table) => {
                let (ty, order) = (src.ty(), src.order());
                let mut i = 0;
                src.for_bytes(start..start + out.len(), |bytes| {
                    i += lookup(
                        ty,
                        order,
                        bytes,
                        table,
                        &mut out[i..],
                        counts.as_deref_mut(),
                    );
                })
            }
            Units::Normalized => norm
                .expect("normalized units have the range first")
                .read(src, start, out, None),
        }
    }
}

/// A source with its normalization and level shapes: what a lazy level is made from.
#[derive(Debug)]
pub(crate) struct Streamed {
    pub(crate) source: Source,
    pub(crate) norm: Norm,
    /// Points per axis and spacing of every level ([`pyramid::level_shapes`]).
    pub(crate) shapes: Vec<([usize; 3], [f64; 3])>,
    units: Units,
    /// Per level: rounded to 16 bits (a filtered level without NaN).
    rounded: Vec<bool>,
    /// What a level made on demand is checked against.
    budget: Budget,
}

impl Streamed {
    /// A value of level `level` filtered in [`Units`], made final: normalized, then rounded
    /// to 16 bits where the level is. Held samples, boxes read from the source and brick
    /// ranges (it is non-decreasing) all go through it, so they agree bit for bit.
    #[inline]
    fn final_value(&self, level: usize, v: f32) -> f32 {
        let v = match self.units {
            Units::Codes(_) => self.norm.apply(v),
            Units::Normalized => v,
        };
        if self.rounded[level] {
            pyramid::unround16(pyramid::round16(v))
        } else {
            v
        }
    }

    /// A held level's samples from its filtered values (in [`Units`]).
    fn samples(&self, level: usize, mut values: Vec<f32>) -> Samples {
        for v in values.iter_mut() {
            *v = self.final_value(level, *v);
        }
        if self.rounded[level] {
            Samples::Round16(pyramid::Packed16::round(values))
        } else {
            Samples::F32(values)
        }
    }

    /// Level `level`'s filtered values in [`Units`] in the box [`lo`, `hi`).
    fn reduce_box(
        &self,
        level: usize,
        lo: [usize; 3],
        hi: [usize; 3],
        out: &mut [f32],
    ) -> Result<(), VolumeError> {
        if level == 0 {
            return self.read_rows(lo, hi, out, |start, row| {
                self.units
                    .read(&self.source, Some(&self.norm), start, row, None)
            });
        }
        let (input, output) = (self.shapes[level - 1].0, self.shapes[level].0);
        pyramid::reduce_box(input, output, lo, hi, out, |l, h, buf| {
            self.reduce_box(level - 1, l, h, buf)
        })
    }

    /// Level 0's rows of the box [`lo`, `hi`), each read by `read(first value, row)`.
    fn read_rows(
        &self,
        lo: [usize; 3],
        hi: [usize; 3],
        out: &mut [f32],
        read: impl Fn(usize, &mut [f32]) -> Result<(), VolumeError>,
    ) -> Result<(), VolumeError> {
        let w = hi[0] - lo[0];
        let rows = pyramid::box_rows(self.shapes[0].0, lo, hi);
        for (row, at) in out.chunks_exact_mut(w.max(1)).zip(rows) {
            // A usize index: the values lie in this process's memory (a map or a buffer).
            read(at as usize, row)?;
        }
        Ok(())
    }
}

impl LevelSource for Streamed {
    /// The samples of level `level`, made by streaming over the source again (the levels
    /// between it and level 0 are reduced slice by slice and not kept). The memory budget is
    /// checked first.
    fn materialize(&self, level: usize) -> Result<Samples, VolumeError> {
        let dims = self.shapes[level].0;
        let bytes = if self.rounded[level] { 2 } else { 4 };
        self.budget
            .check(
                format!(
                    "mip level {level} ({}x{}x{} points, {})",
                    dims[0],
                    dims[1],
                    dims[2],
                    if bytes == 2 { "16-bit" } else { "f32" }
                ),
                t2tf_core::memory::product(&dims),
                bytes,
                "render at a coarser `level` or use a smaller volume",
            )
            .map_err(|e| VolumeError::file(self.source.path(), e.to_string()))?;
        let [nx, ny, nz] = self.shapes[0].0;
        let area = nx * ny;
        if level == 0 {
            let mut out = vec![0.0f32; self.source.len()];
            for (z, slice) in out.chunks_mut(area).enumerate() {
                self.norm.read(&self.source, z * area, slice, None)?;
                self.source.release(z * area..(z + 1) * area);
            }
            return Ok(Samples::F32(out));
        }
        let mut reducer = Reducer::new(&self.shapes[..=level], |l| l == level);
        let mut slice = vec![0.0f32; area];
        for z in 0..nz {
            let norm = Some(&self.norm);
            self.units
                .read(&self.source, norm, z * area, &mut slice, None)?;
            self.source.release(z * area..(z + 1) * area);
            reducer.push(&slice, |_, _| {});
        }
        let values = reducer.finish().pop().flatten().unwrap_or_default();
        Ok(self.samples(level, values))
    }

    /// Samples of level `level` in the box [`lo`, `hi`) (x fastest) without holding the
    /// level: level 0's rows are read from the source, a coarser level is reduced from the box
    /// of the finer one that its filter reads (`pyramid::reduce_box`: the streamed level's
    /// values bit for bit), then normalized and rounded as a held level is. 64-bit index
    /// math: level 0 may hold more than 2³² points.
    fn read_box(
        &self,
        level: usize,
        lo: [usize; 3],
        hi: [usize; 3],
        out: &mut [f32],
    ) -> Result<(), VolumeError> {
        if level == 0 {
            return self.read_rows(lo, hi, out, |start, row| {
                self.norm.read(&self.source, start, row, None)
            });
        }
        self.reduce_box(level, lo, hi, out)?;
        for v in out.iter_mut() {
            *v = self.final_value(level, *v);
        }
        Ok(())
    }

    fn release(&self) {
        self.source.release(0..self.source.len());
    }

    fn is_mapped(&self) -> bool {
        self.source.is_mapped()
    }
}

/// The statistics and levels of a volume streamed from a source.
pub(crate) struct Streaming {
    pub(crate) stats: Stats,
    pub(crate) levels: Vec<Level>,
}

/// Which levels a stream holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Hold {
    /// The coarse levels that fit half the memory budget ([`keep`]).
    Fit,
    /// Every level but level 0 (`Volume::from_buffer`: the values are in memory already).
    All,
}

/// Build a volume's statistics and levels from `source` (module docs). `None` when no value
/// is finite.
pub(crate) fn stream(
    geometry: Geometry,
    declared: ScalarType,
    source: Source,
    hold: Hold,
    budget: Budget,
    fixed: Option<[f64; 2]>,
) -> Result<Option<Streaming>, VolumeError> {
    let shapes = pyramid::level_shapes(geometry);
    let kept = match hold {
        Hold::Fit => keep(&shapes, budget.available()),
        Hold::All => (0..shapes.len()).map(|l| l > 0).collect(),
    };
    stream_keeping(geometry, declared, source, shapes, &kept, budget, fixed)
}

/// [`stream`], holding the levels `kept` says; normalized over `fixed` when given.
fn stream_keeping(
    geometry: Geometry,
    declared: ScalarType,
    source: Source,
    shapes: Vec<([usize; 3], [f64; 3])>,
    kept: &[bool],
    budget: Budget,
    fixed: Option<[f64; 2]>,
) -> Result<Option<Streaming>, VolumeError> {
    // Held whatever is kept: every level's brick ranges (`level_bytes` less the samples, plus
    // the builder's NaN flag per brick of about 512 points), and a slice of level 0 as f32
    // with the reducer's few; the kept levels in f32 until the pass ends.
    let held: u64 = shapes
        .iter()
        .map(|(d, _)| {
            let samples = 4 * d.iter().product::<usize>() as u64;
            pyramid::level_bytes(*d) as u64 - samples + samples.div_ceil(4 * 512)
        })
        .sum::<u64>()
        + 16 * (geometry.dims[0] * geometry.dims[1]) as u64
        + kept
            .iter()
            .zip(&shapes)
            .filter(|(k, _)| **k)
            .map(|(_, s)| pyramid::level_bytes(s.0) as u64)
            .sum::<u64>();
    budget
        .check(
            "the volume's brick ranges and coarse mip levels",
            Some(held),
            1,
            "use a smaller volume",
        )
        .map_err(|e| VolumeError::file(source.path(), e.to_string()))?;

    let units = Units::of(source.ty());
    // Two passes for normalized units: the statistics first.
    let first = match units {
        Units::Normalized => match source.stats()? {
            Some((mut stats, _)) => {
                if let Some(f) = fixed {
                    check_within(&source, stats.range, f)?;
                    stats.norm_range = f;
                }
                Some((Norm::new(source.ty(), stats.norm_range), stats))
            }
            None => return Ok(None),
        },
        Units::Codes(_) => None,
    };
    let [nx, ny, nz] = geometry.dims;
    let area = nx * ny;
    let mut grids: Vec<BrickGridBuilder> =
        shapes.iter().map(|s| BrickGridBuilder::new(s.0)).collect();
    let mut reducer = Reducer::new(&shapes, |l| kept[l]);
    let mut counts = small_codes(source.ty()).map(|codes| vec![0u64; codes]);
    let mut histogram = first.is_some().then(|| vec![0u64; super::HISTOGRAM_BINS]);
    let mut slice = vec![0.0f32; area];
    for z in 0..nz {
        match &first {
            Some((norm, _)) => norm.read(&source, z * area, &mut slice, histogram.as_mut())?,
            None => units.read(&source, None, z * area, &mut slice, counts.as_deref_mut())?,
        }
        source.release(z * area..(z + 1) * area);
        let (grid0, rest) = grids.split_first_mut().expect("level 0 exists");
        grid0.push(&slice);
        reducer.push(&slice, |l, s| rest[l - 1].push(s));
    }
    let (norm, stats) = match (first, counts) {
        (Some((norm, mut stats)), _) => {
            stats.histogram = histogram.expect("counted with the first pass");
            (norm, stats)
        }
        (None, Some(counts)) => {
            let mut stats = code_stats(source.ty(), &counts);
            if let Some(f) = fixed {
                check_within(&source, stats.range, f)?;
                stats.norm_range = f;
                stats.histogram = code_histogram(source.ty(), &counts, f);
            }
            (Norm::new(source.ty(), stats.norm_range), stats)
        }
        (None, None) => unreachable!("code units count codes"),
    };
    let rounded: Vec<bool> = grids
        .iter()
        .enumerate()
        .map(|(l, g)| l > 0 && !g.has_nan())
        .collect();
    let narrow = narrow_for(declared, stats.norm_range);
    let streamed = Arc::new(Streamed {
        source,
        norm,
        shapes: shapes.clone(),
        units,
        rounded,
        budget,
    });
    let mut data = reducer.finish();
    let levels = shapes
        .iter()
        .zip(grids)
        .enumerate()
        .map(|(l, ((dims, spacing), grid))| {
            let narrow = if l == 0 { narrow } else { Narrow::Round16 };
            let mut grid = grid.finish();
            grid.map(|v| streamed.final_value(l, v));
            let samples = if l == 0 { None } else { data[l - 1].take() };
            let samples = samples.map(|values| streamed.samples(l, values));
            let source: Arc<dyn LevelSource> = streamed.clone();
            Level::lazy(*dims, *spacing, grid, narrow, samples, &source, l)
        })
        .collect();
    Ok(Some(Streaming { stats, levels }))
}

/// A fixed normalization range must hold the values' own finite range.
fn check_within(source: &Source, range: [f64; 2], fixed: [f64; 2]) -> Result<(), VolumeError> {
    if fixed[0] <= range[0] && range[1] <= fixed[1] {
        return Ok(());
    }
    Err(VolumeError::file(
        source.path(),
        format!(
            "its values span {} to {}, outside the range {} to {} it is normalized over",
            range[0], range[1], fixed[0], fixed[1]
        ),
    ))
}

/// Which levels a stream keeps: the coarse ones that fit half of `budget` bytes (counted as
/// f32, which they are until the pass ends), coarsest first, none above [`KEEP_POINTS`]
/// points (finer than 512³); level 0 never. The others are made when asked for.
pub(crate) fn keep(shapes: &[([usize; 3], [f64; 3])], budget: u64) -> Vec<bool> {
    let mut kept = vec![false; shapes.len()];
    let mut used = 0u64;
    for l in (1..shapes.len()).rev() {
        let dims = shapes[l].0;
        used = used.saturating_add(pyramid::level_bytes(dims) as u64);
        if dims.iter().product::<usize>() > KEEP_POINTS || used > budget / 2 {
            break;
        }
        kept[l] = true;
    }
    kept
}

/// Points of the finest level a stream keeps: 512³ (512 MiB of f32 while streaming, 256 MiB
/// once rounded to 16 bits).
const KEEP_POINTS: usize = 1 << 27;

/// How level 0's samples may be narrowed: integer data spanning at most 65535 steps
/// normalizes to k / span exactly, so the renderer's bricked copy can store k in 8 or 16 bits
/// (render::cpu::bricked).
pub(super) fn narrow_for(scalar_type: ScalarType, norm_range: [f64; 2]) -> Narrow {
    let span = norm_range[1] - norm_range[0];
    let integer = !matches!(scalar_type, ScalarType::F32 | ScalarType::F64);
    if integer && span.fract() == 0.0 && (1.0..=65535.0).contains(&span) {
        Narrow::Exact(span as u32)
    } else {
        Narrow::No
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TypedBuffer;
    use std::path::Path;

    #[test]
    fn keeps_the_coarse_levels_that_fit() {
        let geometry = Geometry {
            dims: [2048, 2048, 2048],
            spacing: [1.0; 3],
            origin: [0.0; 3],
        };
        let shapes = pyramid::level_shapes(geometry);
        assert_eq!(shapes[2].0, [512; 3]);
        // 512³ and coarser: levels 2..; not 1024³ nor level 0.
        let kept = keep(&shapes, 8 << 30);
        assert!(
            !kept[0] && !kept[1] && kept[2..].iter().all(|&k| k),
            "{kept:?}"
        );
        // A small budget keeps only what fits in half of it, coarsest first.
        let kept = keep(&shapes, 200 << 20);
        assert!(!kept[2] && kept[3..].iter().all(|&k| k), "{kept:?}");
        assert_eq!(keep(&shapes, 0), vec![false; shapes.len()]);
    }

    /// Deterministic bytes covering every code region (xorshift).
    fn bytes(n: usize, seed: u64) -> Vec<u8> {
        let mut x = seed;
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 24) as u8
            })
            .collect()
    }

    fn bits(d: &[f32]) -> Vec<u32> {
        d.iter().map(|v| v.to_bits()).collect()
    }

    /// The stream's statistics and level 0 equal the plain per-value normalization
    /// (`volume::normalize`) bit for bit: 8/16-bit types in both byte orders (one pass, codes
    /// counted), with more and fewer values than codes, and the same values stored as f64
    /// (two passes).
    #[test]
    fn stream_equals_the_per_value_normalization() {
        for ty in [
            ScalarType::U8,
            ScalarType::I8,
            ScalarType::U16,
            ScalarType::I16,
        ] {
            for order in [ByteOrder::Little, ByteOrder::Big] {
                for (len, seed) in [(5, 3), (1 << 16, 7), (3 * (1 << 16) + 5, 1)] {
                    let buf = TypedBuffer::new(ty, order, bytes(len * ty.size(), seed));
                    let mut values = Vec::new();
                    buf.for_each(|v| values.push(v));
                    let wide = TypedBuffer::from_f64(values);
                    let reference = super::super::normalize(&wide).unwrap();
                    let geometry = Geometry {
                        dims: [len, 1, 1],
                        spacing: [1.0; 3],
                        origin: [0.0; 3],
                    };
                    let path = Path::new("t");
                    for b in [&buf, &wide] {
                        let v = super::super::Volume::from_buffer(path, geometry, b).unwrap();
                        let what = format!("{ty} {order:?} {len} as {}", b.scalar_type());
                        assert_eq!(v.range, reference.range, "{what}");
                        assert_eq!(v.norm_range, reference.norm_range, "{what}");
                        assert_eq!(v.histogram, reference.histogram, "{what}");
                        assert_eq!(v.non_finite, reference.non_finite, "{what}");
                        assert_eq!(bits(v.data()), bits(&reference.data), "{what}");
                    }
                }
            }
        }
        let constant = [0xff, 0xfe].repeat(1 << 16);
        let buf = TypedBuffer::new(ScalarType::I16, ByteOrder::Big, constant);
        let geometry = Geometry {
            dims: [256, 256, 1],
            spacing: [1.0; 3],
            origin: [0.0; 3],
        };
        let v = super::super::Volume::from_buffer(Path::new("t"), geometry, &buf).unwrap();
        assert_eq!((v.range, v.norm_range), ([-2.0, -2.0], [-2.5, -1.5]));
        assert!(v.data().iter().all(|&x| x == 0.5));
        // Filtered levels hold 0.5 rounded to 16 bits.
        let rounded = pyramid::unround16(pyramid::round16(0.5));
        assert!((rounded - 0.5).abs() <= 0.5 / 65535.0);
        assert!(v.levels[1..]
            .iter()
            .all(|l| l.data().iter().all(|&x| x == rounded)));
    }

    /// Filtered levels of 8/16-bit data: the reducer over the codes' values, then each value
    /// normalized and rounded to 16 bits (module docs), held in 16 bits; their brick ranges
    /// are those of the values held, bit for bit.
    #[test]
    fn code_levels_are_filtered_codes_normalized_and_rounded() {
        let dims = [37, 29, 23];
        let n: usize = dims.iter().product();
        for ty in [ScalarType::U8, ScalarType::I16] {
            let buf = TypedBuffer::new(ty, ByteOrder::Little, bytes(n * ty.size(), 5));
            let geometry = Geometry {
                dims,
                spacing: [1.0, 0.5, 2.0],
                origin: [0.0; 3],
            };
            let v = super::super::Volume::from_buffer(Path::new("t"), geometry, &buf).unwrap();
            let mut codes = Vec::new();
            buf.for_each(|x| codes.push(x as f32));
            let reference = pyramid::build(geometry, codes, Narrow::No);
            let norm = Norm::new(ty, v.norm_range);
            assert!(v.levels.len() >= 3);
            for (l, (level, want)) in v.levels.iter().zip(&reference).enumerate().skip(1) {
                assert_eq!(level.is_16_bit(), Some(true), "{ty} level {l}");
                let expect: Vec<f32> = want
                    .data()
                    .iter()
                    .map(|&c| pyramid::unround16(pyramid::round16(norm.apply(c))))
                    .collect();
                assert_eq!(bits(level.data()), bits(&expect), "{ty} level {l}");
                let grid = pyramid::BrickGrid::build(level.dims, level.data());
                assert_eq!(bits(&level.bricks.min), bits(&grid.min), "{ty} level {l}");
                assert_eq!(bits(&level.bricks.max), bits(&grid.max), "{ty} level {l}");
            }
        }
    }

    /// Packing in place keeps every sample, for odd and even lengths.
    #[test]
    fn packing_in_place_keeps_every_sample() {
        for len in [0usize, 1, 2, 3, 1000, 1001] {
            let values: Vec<f32> = (0..len)
                .map(|i| ((i * 7919) % 1013) as f32 / 1012.0)
                .collect();
            let want: Vec<u16> = values.iter().map(|&v| pyramid::round16(v)).collect();
            assert_eq!(
                pyramid::Packed16::round(values).samples(),
                &want[..],
                "{len}"
            );
        }
    }

    /// Every 16-bit sample reads back as the value the renderer rounds to the same sample.
    #[test]
    fn rounding_to_16_bits_round_trips() {
        for q in 0..=u16::MAX {
            let v = pyramid::unround16(q);
            assert_eq!(pyramid::round16(v), q);
            assert!((0.0..=1.0).contains(&v));
        }
        assert_eq!(pyramid::round16(0.5 / 65535.0 - 1e-9), 0);
        assert_eq!(pyramid::round16(1.0), u16::MAX);
    }

    /// Levels that are not held: `read_box` (reduced from level 0's box on the source) and
    /// `try_data` (a second stream) equal the in-memory pyramid bit for bit, on odd boxes.
    #[test]
    fn levels_not_held_read_like_held_ones() {
        let dims = [37, 29, 23];
        let n: usize = dims.iter().product();
        let mut values: Vec<f64> = (0..n).map(|i| ((i * 7919) % 1013) as f64 - 3.5).collect();
        for i in (0..n).step_by(89) {
            values[i] = f64::NAN;
        }
        let geometry = Geometry {
            dims,
            spacing: [1.0, 0.5, 2.0],
            origin: [0.0; 3],
        };
        let path = Path::new("t");
        // Normalized units (f64 with NaN, two passes) and code units (16-bit, one pass).
        let codes = TypedBuffer::new(ScalarType::I16, ByteOrder::Big, bytes(2 * n, 9));
        for buffer in [TypedBuffer::from_f64(values), codes] {
            not_held_equal_held(path, geometry, buffer);
        }
    }

    fn not_held_equal_held(path: &Path, geometry: Geometry, buffer: TypedBuffer) {
        let ty = buffer.scalar_type();
        let reference = super::super::Volume::from_buffer(path, geometry, &buffer).unwrap();
        let source = Source::memory(path, buffer);
        let shapes = pyramid::level_shapes(geometry);
        let none = vec![false; shapes.len()];
        let s = stream_keeping(geometry, ty, source, shapes, &none, Budget::system(), None)
            .unwrap()
            .unwrap();
        assert_eq!(s.stats.histogram, reference.histogram);
        assert!(s.levels.len() >= 3);
        let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for (l, (level, want)) in s.levels.iter().zip(&reference.levels).enumerate() {
            assert!(!level.is_materialized(), "level {l}");
            let d = level.dims;
            let boxes = [
                ([0, 0, 0], d),
                ([1, 2, 3], [d[0] - 1, d[1], d[2] - 2]),
                (
                    [d[0] / 2, d[1] / 3, d[2] / 2],
                    [d[0] / 2 + 1, d[1] / 3 + 2, d[2]],
                ),
                ([d[0] - 1, d[1] - 1, d[2] - 1], d),
            ];
            for (lo, hi) in boxes {
                let lo: [usize; 3] = std::array::from_fn(|a| lo[a].min(hi[a]));
                let len = (0..3).map(|a| hi[a] - lo[a]).product();
                let mut out = vec![0.0; len];
                level.read_box(lo, hi, &mut out).unwrap();
                let mut expect = Vec::new();
                for at in pyramid::box_rows(d, lo, hi) {
                    expect.extend_from_slice(&want.data()[at as usize..][..hi[0] - lo[0]]);
                }
                assert_eq!(bits(&out), bits(&expect), "level {l} {lo:?}..{hi:?}");
            }
            assert!(!level.is_materialized(), "read_box made level {l}");
            assert_eq!(
                bits(level.try_data().unwrap()),
                bits(want.data()),
                "level {l}"
            );
            assert_eq!(level.is_16_bit(), want.is_16_bit(), "level {l}");
            if l > 0 && ty == ScalarType::I16 {
                assert_eq!(want.is_16_bit(), Some(true), "level {l}");
            }
            assert_eq!(bits(&level.bricks.min), bits(&want.bricks.min), "level {l}");
            assert_eq!(bits(&level.bricks.max), bits(&want.bricks.max), "level {l}");
        }
    }
}
