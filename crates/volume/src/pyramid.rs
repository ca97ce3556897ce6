//! Mip pyramid (2× reductions) and per-brick value ranges.
//!
//! Every level spans the same world box as level 0: an axis of `d` points becomes `ceil(d/2)`
//! points with the spacing stretched so that `(d' - 1) * spacing'` equals `(d - 1) * spacing`.
//! Axes of 1 or 2 points are not reduced. Values are filtered with a tent of the reduction's
//! width; NaN (empty) samples are left out of the filter, and a point is NaN only when all of
//! its contributors are.
//!
//! Bricks partition the *cells* of a level into blocks of `BRICK_CELLS`³; a brick's min/max
//! covers every point its cells touch, so any trilinear sample inside the brick lies within
//! [min, max] and a TF that is zero on that interval makes the whole brick empty.

use std::collections::VecDeque;
use std::sync::{Arc, OnceLock};

use super::{Geometry, VolumeError};

/// Cells per brick side.
pub const BRICK_CELLS: usize = 8;

/// Slices of at least this many points are reduced on several threads (bit-identical).
const PAR_POINTS: usize = 1 << 16;

/// Stop reducing once every axis has at most this many points.
const MIN_LEVEL_POINTS: usize = 8;

/// One level of the pyramid. Its shape and brick ranges are known from the start; its
/// samples are made when first asked for ([`Level::try_data`]) unless the volume was built
/// holding them.
#[derive(Clone, Debug)]
pub struct Level {
    /// Points per axis.
    pub dims: [usize; 3],
    /// World spacing at this level (origin is the volume's).
    pub spacing: [f64; 3],
    /// The samples, shared by the level's clones and never changed once made: a renderer
    /// backend may keep a copy in its own layout for as long as this cell lives (it tells
    /// the levels apart by it, `render::cpu`).
    cell: Arc<LevelCell>,
    /// Per-brick value ranges, for empty-space skipping.
    pub bricks: BrickGrid,
    /// How exactly the values can be stored in fewer bits than f32.
    narrow: Narrow,
}

/// A level's samples as held.
#[derive(Debug)]
pub(crate) enum Samples {
    /// Normalized values (level 0, and filtered levels holding NaN).
    F32(Vec<f32>),
    /// A filtered level without NaN, rounded to 16 bits ([`round16`]): half the memory of
    /// f32, and exactly what the renderer stores for such a level (`render::cpu::bricked`,
    /// `Encoding::Round16`), so renders do not change.
    Round16(Packed16),
}

/// 16-bit samples packed two to a word of the f32 allocation they were filtered into, so
/// that rounding a level needs no second allocation: a 512³ level would otherwise hold its
/// 512 MiB of f32 and 256 MiB of 16-bit samples at once, the peak of a large volume's load.
#[derive(Debug)]
pub(crate) struct Packed16 {
    /// The allocation, `len.div_ceil(2)` words holding the samples in memory order.
    words: Vec<f32>,
    len: usize,
}

impl Packed16 {
    /// `values` (normalized) rounded to 16 bits in place, then the allocation shrunk to half
    /// (`realloc` shrinks in place). Sample i is written over bytes 2i..2i + 2, which belong
    /// to value i / 2 ≤ i, already read.
    pub(crate) fn round(mut values: Vec<f32>) -> Packed16 {
        let len = values.len();
        let view: &mut [u16] = bytemuck::cast_slice_mut(&mut values);
        for i in 0..len {
            let (lo, hi) = (view[2 * i].to_ne_bytes(), view[2 * i + 1].to_ne_bytes());
            view[i] = round16(f32::from_ne_bytes([lo[0], lo[1], hi[0], hi[1]]));
        }
        values.truncate(len.div_ceil(2));
        values.shrink_to_fit();
        Packed16 { words: values, len }
    }

    /// The samples.
    pub(crate) fn samples(&self) -> &[u16] {
        &bytemuck::cast_slice(&self.words)[..self.len]
    }
}

impl Samples {
    /// Values `at..at + out.len()` as normalized f32 into `out`.
    fn copy_to(&self, at: usize, out: &mut [f32]) {
        match self {
            Samples::F32(d) => out.copy_from_slice(&d[at..at + out.len()]),
            Samples::Round16(q) => {
                let n = out.len();
                for (o, &q) in out.iter_mut().zip(&q.samples()[at..at + n]) {
                    *o = unround16(q);
                }
            }
        }
    }
}

/// Normalized value per unit of a level rounded to 16 bits (the renderer's `Round16` scale).
pub(crate) const ROUND16_SCALE: f32 = 1.0 / 65535.0;

/// A normalized value in [0, 1] rounded to 16 bits: `round(v · 65535)`, the renderer's
/// `Encoding::Round16` (error ≤ 2⁻¹⁷ of the range, 1/512 of a 256-entry LUT's cell).
#[inline]
pub(crate) fn round16(v: f32) -> u16 {
    (v * 65535.0).round() as u16
}

/// The normalized value of a 16-bit rounded sample: `q · ROUND16_SCALE`, which [`round16`]
/// maps back to `q` (tested for every q).
#[inline]
pub(crate) fn unround16(q: u16) -> f32 {
    q as f32 * ROUND16_SCALE
}

/// What makes a level's samples when they are not held (`stream::Streamed`: the file's
/// values, their normalization and the level shapes). The pyramid names only this trait, so
/// imports run one way: the stream builds levels, levels do not know the stream.
pub(crate) trait LevelSource: std::fmt::Debug + Send + Sync {
    /// The samples of level `level`, made by reading the source (after a memory check).
    fn materialize(&self, level: usize) -> Result<Samples, VolumeError>;
    /// Level `level`'s values in the box [`lo`, `hi`) into `out` (x fastest), the held
    /// level's bits, without holding it.
    fn read_box(
        &self,
        level: usize,
        lo: [usize; 3],
        hi: [usize; 3],
        out: &mut [f32],
    ) -> Result<(), VolumeError>;
    /// Stop counting the source's mapped pages as this process's memory.
    fn release(&self);
    /// Whether the values are read from a memory map of the file as stored.
    fn is_mapped(&self) -> bool;
}

/// A level's samples, made at most once: opaque outside this crate, where only its identity
/// matters (a renderer keys its copies of a level by it, [`Level::cell`]).
#[derive(Debug)]
pub struct LevelCell {
    /// The samples, x fastest; NaN = empty.
    samples: OnceLock<Samples>,
    /// Samples held as [`Samples::Round16`] in f32, made only for a caller that asks for the
    /// whole level as f32 ([`Level::try_data`]; the renderer reads boxes instead).
    as_f32: OnceLock<Vec<f32>>,
    /// What makes them when they are not held: the source and this level's index.
    origin: Option<(Arc<dyn LevelSource>, usize)>,
    /// Held while the samples are made, so that threads asking at once make one copy.
    making: std::sync::Mutex<()>,
}

impl Level {
    /// A level holding `data`.
    #[cfg(test)]
    fn new(dims: [usize; 3], spacing: [f64; 3], data: Vec<f32>, narrow: Narrow) -> Level {
        Level {
            dims,
            spacing,
            bricks: BrickGrid::build(dims, &data),
            cell: Arc::new(LevelCell {
                samples: OnceLock::from(Samples::F32(data)),
                as_f32: OnceLock::new(),
                origin: None,
                making: Default::default(),
            }),
            narrow,
        }
    }

    /// Level `index` of a streamed volume, holding `samples` if given, else made from
    /// `streamed` when asked for.
    pub(super) fn lazy(
        dims: [usize; 3],
        spacing: [f64; 3],
        bricks: BrickGrid,
        narrow: Narrow,
        samples: Option<Samples>,
        streamed: &Arc<dyn LevelSource>,
        index: usize,
    ) -> Level {
        let cell = LevelCell {
            samples: samples.map(OnceLock::from).unwrap_or_default(),
            as_f32: OnceLock::new(),
            origin: Some((streamed.clone(), index)),
            making: Default::default(),
        };
        Level {
            dims,
            spacing,
            bricks,
            cell: Arc::new(cell),
            narrow,
        }
    }

    /// Normalized samples, x fastest; NaN = empty. Made on first use.
    ///
    /// # Panics
    /// When they cannot be made (they do not fit the memory budget): callers that may ask for
    /// a level larger than memory use [`Level::try_data`] or [`Level::read_box`].
    pub fn data(&self) -> &[f32] {
        match self.try_data() {
            Ok(d) => d,
            Err(e) => panic!("{e}"),
        }
    }

    /// Normalized samples, x fastest; NaN = empty. Made on first use (reading the source
    /// again); an error when they do not fit the memory budget. A level held in 16 bits
    /// (`Samples::Round16`) makes an f32 copy of itself for this.
    pub fn try_data(&self) -> Result<&[f32], VolumeError> {
        match self.try_samples()? {
            Samples::F32(d) => Ok(d),
            Samples::Round16(q) => Ok(self
                .cell
                .as_f32
                .get_or_init(|| q.samples().iter().map(|&q| unround16(q)).collect())),
        }
    }

    /// Whether the samples are held (made, or built with the level).
    pub fn is_materialized(&self) -> bool {
        self.cell.samples.get().is_some()
    }

    /// Whether the held samples are rounded to 16 bits (`Samples::Round16`); `None` when
    /// they are not held.
    #[cfg(test)]
    pub(crate) fn is_16_bit(&self) -> Option<bool> {
        self.cell
            .samples
            .get()
            .map(|s| matches!(s, Samples::Round16(_)))
    }

    /// Whether the samples, when not held, are read from a memory map of the volume's file
    /// (`.raw`, appended raw `.vti`, BINARY `.vtk`) rather than from decoded bytes.
    pub fn is_mapped(&self) -> bool {
        self.cell
            .origin
            .as_ref()
            .is_some_and(|(s, _)| s.is_mapped())
    }

    fn try_samples(&self) -> Result<&Samples, VolumeError> {
        if let Some(d) = self.cell.samples.get() {
            return Ok(d);
        }
        let (streamed, index) = self
            .cell
            .origin
            .as_ref()
            .expect("a level without samples has a source");
        // A panic while making them leaves nothing behind the lock: ignore the poison.
        let _making = self.cell.making.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(d) = self.cell.samples.get() {
            return Ok(d);
        }
        let samples = streamed.materialize(*index)?;
        Ok(self.cell.samples.get_or_init(|| samples))
    }

    /// What identifies this level's samples without making them: the same allocation for
    /// every clone of the level, dropped with the last one.
    pub fn cell(&self) -> &Arc<LevelCell> {
        &self.cell
    }

    /// Stop counting the pages of a memory-mapped source that [`Level::read_box`] touched as
    /// this process's memory (`MADV_DONTNEED`; the values stay readable, from the page cache
    /// or the file; a block-decoded source keeps its bounded cache of decoded blocks). Nothing
    /// for a level whose samples are held or a decoded source. Random box reads of a file
    /// larger than memory (a level-0 render through the brick cache) call it between batches,
    /// so the file's pages do not add up in the process's memory.
    pub fn release_source(&self) {
        if let (None, Some((streamed, _))) = (self.cell.samples.get(), &self.cell.origin) {
            streamed.release();
        }
    }

    /// Normalized samples of the points in the box [`lo`, `hi`) into `out` (x fastest, then
    /// y, then z; `out.len()` is the box's point count). Read from the held samples when
    /// there are, else from the source (nothing is kept): level 0's values, or a coarser
    /// level's reduced from level 0's box, equal to the held level's bit for bit.
    ///
    /// # Panics
    /// When the box is not inside the level or `out` is not its size.
    pub fn read_box(
        &self,
        lo: [usize; 3],
        hi: [usize; 3],
        out: &mut [f32],
    ) -> Result<(), VolumeError> {
        assert!(
            (0..3).all(|a| lo[a] <= hi[a] && hi[a] <= self.dims[a]),
            "box {lo:?}..{hi:?} outside a level of {:?} points",
            self.dims
        );
        let w = hi[0] - lo[0];
        let (h, d) = (hi[1] - lo[1], hi[2] - lo[2]);
        assert_eq!(out.len(), w * h * d, "box {lo:?}..{hi:?} and output size");
        match (self.cell.samples.get(), &self.cell.origin) {
            (None, Some((streamed, level))) => streamed.read_box(*level, lo, hi, out),
            _ => {
                let samples = self.try_samples()?;
                for (row, at) in out
                    .chunks_exact_mut(w.max(1))
                    .zip(box_rows(self.dims, lo, hi))
                {
                    samples.copy_to(at as usize, row);
                }
                Ok(())
            }
        }
    }

    /// How the values may be stored in fewer bits (see [`Narrow`]).
    pub fn narrow(&self) -> Narrow {
        self.narrow
    }

    /// Memory the samples and the brick ranges take once the samples are made, as f32: an
    /// upper bound, since a level held in 16 bits (`Samples::Round16`) takes half of its
    /// samples' share (a renderer's copies not included); see [`Level::is_materialized`] for
    /// whether they are made.
    pub fn memory_bytes(&self) -> usize {
        level_bytes(self.dims)
    }

    /// Index of point (i, j, k) in [`Level::data`].
    #[cfg(test)]
    #[inline]
    fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }
}

/// How a level's values may be stored in fewer bits than f32 (a property of the data: the
/// renderer's bricked copy uses it, `render::cpu::bricked`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Narrow {
    /// Level 0 of an integer volume: its normalized values should be k / D for integers
    /// k ≤ D (checked where used; a value that is not keeps the level in f32).
    Exact(u32),
    /// A filtered mip level, an approximation already: may be rounded to 16 bits (error ≤
    /// 2⁻¹⁷ of the range, 1/512 of a 256-entry LUT's cell), unless it holds NaN.
    Round16,
    /// f32 (float volumes' level 0).
    No,
}

/// Index of the first point of every x-row of the box [`lo`, `hi`) in a level of `dims`
/// points, in order (z outer). 64-bit: a level may hold more than 2³² points.
pub(super) fn box_rows(
    dims: [usize; 3],
    lo: [usize; 3],
    hi: [usize; 3],
) -> impl Iterator<Item = u64> {
    let [nx, ny, _] = dims.map(|d| d as u64);
    (lo[2]..hi[2]).flat_map(move |k| {
        (lo[1]..hi[1]).map(move |j| lo[0] as u64 + nx * (j as u64 + ny * k as u64))
    })
}

/// What [`Level::memory_bytes`] gives for a level of `dims` points, without building it.
pub(super) fn level_bytes(dims: [usize; 3]) -> usize {
    let bricks: usize = dims
        .map(|d| d.saturating_sub(1).max(1).div_ceil(BRICK_CELLS))
        .iter()
        .product();
    4 * (dims.iter().product::<usize>() + 2 * bricks) + bricks
}

/// Min/max of the normalized value per brick of `BRICK_CELLS`³ cells.
#[derive(Clone, Debug)]
pub struct BrickGrid {
    /// Bricks per axis.
    pub counts: [usize; 3],
    /// Per brick, x fastest. An all-NaN brick has min = +inf, max = -inf.
    pub min: Vec<f32>,
    /// Per brick, x fastest: the largest value (−inf for an all-NaN brick).
    pub max: Vec<f32>,
    /// Per brick: every point it touches is finite and equal (min == max, no NaN), so every
    /// sample inside it has that value and the renderer can step across it in one go.
    pub uniform: Vec<bool>,
}

impl BrickGrid {
    /// The ranges of a level with `dims` points holding `data` (x fastest).
    pub fn build(dims: [usize; 3], data: &[f32]) -> BrickGrid {
        let mut b = BrickGridBuilder::new(dims);
        for slice in data.chunks_exact(dims[0] * dims[1]).take(dims[2]) {
            b.push(slice);
        }
        b.finish()
    }

    /// Index of brick (bi, bj, bk) in the per-brick vectors.
    #[inline]
    pub fn index(&self, bi: usize, bj: usize, bk: usize) -> usize {
        bi + self.counts[0] * (bj + self.counts[1] * bk)
    }

    /// The ranges of the level's values mapped by `f`, a non-decreasing function (the
    /// normalization of code units, the rounding to 16 bits): the min (max) of the mapped
    /// values is the mapped min (max). The ±inf of all-NaN bricks stay. `uniform` stays: a
    /// brick that was not uniform may become equal at its ends, and is then only not skipped.
    pub(super) fn map(&mut self, f: impl Fn(f32) -> f32) {
        for v in self.min.iter_mut().chain(self.max.iter_mut()) {
            if v.is_finite() {
                *v = f(*v);
            }
        }
    }
}

/// A [`BrickGrid`] made from a level's z-slices, pushed in order (so a level need not be
/// held to have its ranges).
pub(crate) struct BrickGridBuilder {
    dims: [usize; 3],
    counts: [usize; 3],
    min: Vec<f32>,
    max: Vec<f32>,
    nan: Vec<bool>,
    /// The next slice's z.
    k: usize,
}

impl BrickGridBuilder {
    pub(crate) fn new(dims: [usize; 3]) -> BrickGridBuilder {
        let cells = dims.map(|d| d.saturating_sub(1).max(1));
        let counts = cells.map(|c| c.div_ceil(BRICK_CELLS));
        let total = counts.iter().product();
        BrickGridBuilder {
            dims,
            counts,
            min: vec![f32::INFINITY; total],
            max: vec![f32::NEG_INFINITY; total],
            nan: vec![false; total],
            k: 0,
        }
    }

    /// The bricks of the cells that have point `p` of axis `a` as a corner: cells p − 1 and
    /// p where they exist (two on a shared face, one elsewhere).
    fn bricks_of(&self, p: usize, a: usize) -> std::ops::RangeInclusive<usize> {
        let lo = (p.saturating_sub(1) / BRICK_CELLS).min(self.counts[a] - 1);
        let hi = (p / BRICK_CELLS).min(self.counts[a] - 1);
        lo..=hi
    }

    /// The next z-slice (x fastest). Each brick sees its points in the order of the slices,
    /// then rows, then x, whatever the loop nesting: its min/max (even of ±0) are those of a
    /// point-by-point pass.
    pub(crate) fn push(&mut self, slice: &[f32]) {
        let k = self.k;
        self.k += 1;
        let [nx, _, _] = self.dims;
        let counts = self.counts;
        // The x-range of points of each x-brick: cells bi·B .. bi·B + B, the last to the end.
        let spans: Vec<(usize, usize)> = (0..counts[0])
            .map(|bi| {
                let end = if bi + 1 == counts[0] {
                    nx - 1
                } else {
                    bi * BRICK_CELLS + BRICK_CELLS
                };
                (bi * BRICK_CELLS, end)
            })
            .collect();
        for (j, row) in slice.chunks_exact(nx).enumerate() {
            for bk in self.bricks_of(k, 2) {
                for bj in self.bricks_of(j, 1) {
                    let base = counts[0] * (bj + counts[1] * bk);
                    for (bi, &(start, end)) in spans.iter().enumerate() {
                        let b = base + bi;
                        let (mut lo, mut hi, mut nan) = (self.min[b], self.max[b], self.nan[b]);
                        for &v in &row[start..=end] {
                            if v.is_nan() {
                                nan = true;
                            } else {
                                lo = lo.min(v);
                                hi = hi.max(v);
                            }
                        }
                        (self.min[b], self.max[b], self.nan[b]) = (lo, hi, nan);
                    }
                }
            }
        }
    }

    /// Whether a point pushed so far is NaN.
    pub(crate) fn has_nan(&self) -> bool {
        self.nan.iter().any(|&n| n)
    }

    pub(crate) fn finish(self) -> BrickGrid {
        let uniform = (0..self.min.len())
            .map(|b| !self.nan[b] && self.min[b] == self.max[b])
            .collect();
        BrickGrid {
            counts: self.counts,
            min: self.min,
            max: self.max,
            uniform,
        }
    }
}

/// Points per axis and spacing of every level, level 0 first (module docs).
pub(super) fn level_shapes(geometry: Geometry) -> Vec<([usize; 3], [f64; 3])> {
    let mut shapes = vec![(geometry.dims, geometry.spacing)];
    loop {
        let (prev_dims, prev_spacing) = *shapes.last().expect("level 0 exists");
        if prev_dims.iter().all(|&d| d <= MIN_LEVEL_POINTS) {
            return shapes;
        }
        let dims = prev_dims.map(|d| if d <= 2 { d } else { d.div_ceil(2) });
        let spacing = std::array::from_fn(|a| {
            if dims[a] == prev_dims[a] {
                prev_spacing[a]
            } else {
                prev_spacing[a] * (prev_dims[a] - 1) as f64 / (dims[a] - 1) as f64
            }
        });
        shapes.push((dims, spacing));
    }
}

/// Build all levels from level 0's normalized `data`, every level held in f32: the
/// [`Reducer`] alone, without normalization or rounding (what `stream` adds), for the tests.
#[cfg(test)]
pub(super) fn build(geometry: Geometry, data: Vec<f32>, narrow: Narrow) -> Vec<Level> {
    let shapes = level_shapes(geometry);
    let [nx, ny, nz] = geometry.dims;
    let mut reducer = Reducer::new(&shapes, |_| true);
    for slice in data.chunks_exact(nx * ny).take(nz) {
        reducer.push(slice, |_, _| {});
    }
    let mut levels = vec![Level::new(geometry.dims, geometry.spacing, data, narrow)];
    for ((dims, spacing), data) in shapes[1..].iter().zip(reducer.finish()) {
        let data = data.expect("every level kept");
        levels.push(Level::new(*dims, *spacing, data, Narrow::Round16));
    }
    levels
}

/// Taps of a tent filter of the reduction's width resampling `d` points to `n`: per output
/// point, (source index, weight) in ascending source order — the order the sums are taken in.
fn taps(d: usize, n: usize) -> Taps {
    (0..n).map(|j| tap(d, n, j)).collect()
}

/// The taps of output point `j` ([`taps`]).
fn tap(d: usize, n: usize, j: usize) -> Vec<(usize, f32)> {
    let ratio = (d - 1) as f64 / (n - 1) as f64;
    let x = j as f64 * ratio;
    let lo = (x - ratio).ceil().max(0.0) as usize;
    let hi = ((x + ratio).floor() as usize).min(d - 1);
    (lo..=hi)
        .filter_map(|i| {
            let w = 1.0 - (i as f64 - x).abs() / ratio;
            (w > 0.0).then_some((i, w as f32))
        })
        .collect()
}

/// The points [`lo`, `hi`) of the level of shape `output` reduced from the level of shape
/// `input`: the box of the input they read (`read(lo, hi, out)` fills it, x fastest) is
/// reduced along x, then y, then z, with the sums of [`Reducer`] in its order, so every value
/// equals the streamed level's bit for bit.
pub(super) fn reduce_box(
    input: [usize; 3],
    output: [usize; 3],
    lo: [usize; 3],
    hi: [usize; 3],
    out: &mut [f32],
    read: impl FnOnce([usize; 3], [usize; 3], &mut [f32]) -> Result<(), VolumeError>,
) -> Result<(), VolumeError> {
    // Per axis: the taps of the wanted outputs, relative to the input box's first point.
    let mut in_lo = lo;
    let mut in_hi = hi;
    let mut axis_taps: [Option<Taps>; 3] = [None, None, None];
    for a in 0..3 {
        if input[a] == output[a] || hi[a] == lo[a] {
            continue;
        }
        let t: Taps = (lo[a]..hi[a])
            .map(|j| tap(input[a], output[a], j))
            .collect();
        in_lo[a] = t
            .iter()
            .filter_map(|t| t.first())
            .map(|t| t.0)
            .min()
            .unwrap_or(0);
        in_hi[a] = t
            .iter()
            .filter_map(|t| t.last())
            .map(|t| t.0 + 1)
            .max()
            .unwrap_or(0);
        let shifted = t
            .into_iter()
            .map(|tj| tj.into_iter().map(|(s, w)| (s - in_lo[a], w)).collect())
            .collect();
        axis_taps[a] = Some(shifted);
    }
    let [bx, by, bz] = std::array::from_fn(|a| in_hi[a] - in_lo[a]);
    let [ox, oy, oz] = std::array::from_fn(|a| hi[a] - lo[a]);
    let mut src = vec![0.0f32; bx * by * bz];
    read(in_lo, in_hi, &mut src)?;
    // x, per input row.
    let xr: Vec<f32> = match &axis_taps[0] {
        None => src,
        Some(t) => src
            .chunks_exact(bx)
            .flat_map(|row| t.iter().map(move |tj| filter(tj, |s| row[s])))
            .collect(),
    };
    // y, per input slice.
    let xy: Vec<f32> = match &axis_taps[1] {
        None => xr,
        Some(t) => {
            let mut o = Vec::with_capacity(ox * oy * bz);
            for slice in xr.chunks_exact(ox * by) {
                for tj in t {
                    for x in 0..ox {
                        o.push(filter(tj, |s| slice[x + ox * s]));
                    }
                }
            }
            o
        }
    };
    // z.
    match &axis_taps[2] {
        None => out.copy_from_slice(&xy),
        Some(t) => {
            let area = ox * oy;
            for (tj, o) in t.iter().zip(out.chunks_exact_mut(area)) {
                for (i, v) in o.iter_mut().enumerate() {
                    *v = filter(tj, |s| xy[i + area * s]);
                }
            }
        }
    }
    debug_assert_eq!(out.len(), ox * oy * oz);
    Ok(())
}

/// One filtered value: the weighted mean of the taps that are not NaN (`at(s)` reads source
/// point s), NaN when all of them are.
#[inline]
fn filter(taps: &[(usize, f32)], at: impl Fn(usize) -> f32) -> f32 {
    let (mut acc, mut wsum) = (0.0f32, 0.0f32);
    for &(s, w) in taps {
        let v = at(s);
        if !v.is_nan() {
            acc += w * v;
            wsum += w;
        }
    }
    if wsum > 0.0 {
        acc / wsum
    } else {
        f32::NAN
    }
}

/// Every coarser level from a level's z-slices, pushed in order. Each slice is reduced along x
/// and y at once; a stage keeps only the few reduced slices its z taps still need, and hands
/// each output slice to the next stage as soon as it is complete. Memory beyond the coarser
/// levels themselves is a few slices per level. Every value is the same sum, in the same
/// order, as reducing whole axes one after the other (x, then y, then z): bit-identical.
pub(crate) struct Reducer {
    stages: Vec<Stage>,
}

/// Per output point of one axis, its (source index, weight) taps ([`taps`]).
type Taps = Vec<Vec<(usize, f32)>>;

/// Reducing one level to the next.
struct Stage {
    /// Points per axis of the level coming in.
    input: [usize; 3],
    /// Points per axis of the level going out.
    output: [usize; 3],
    /// Taps per reduced axis (`None`: the axis keeps its points).
    taps: [Option<Taps>; 3],
    /// Input slices reduced along x and y that later output slices still read: (z, values).
    window: VecDeque<(usize, Vec<f32>)>,
    /// Input slices seen so far.
    seen: usize,
    /// Output slices completed so far.
    done: usize,
    /// The output level, filled slice by slice, when it is kept.
    out: Option<Vec<f32>>,
}

impl Stage {
    fn new(input: [usize; 3], output: [usize; 3], keep: bool) -> Stage {
        Stage {
            input,
            output,
            taps: std::array::from_fn(|a| {
                (output[a] != input[a]).then(|| taps(input[a], output[a]))
            }),
            window: VecDeque::new(),
            seen: 0,
            done: 0,
            out: keep.then(|| Vec::with_capacity(output.iter().product())),
        }
    }

    /// Reduce one x-y slice of the input along x, then y.
    fn reduce_xy(&self, slice: &[f32]) -> Vec<f32> {
        use rayon::prelude::*;
        let [nx, ny, _] = self.input;
        let [ox, oy, _] = self.output;
        // Rows are independent and each value is the same sum whichever thread takes it:
        // large slices are split over threads without changing a bit.
        let par = nx * ny >= PAR_POINTS;
        let xr: Vec<f32> = match &self.taps[0] {
            None => slice.to_vec(),
            Some(t) => {
                let mut xr = vec![0.0f32; ox * ny];
                let row = |(o, row): (&mut [f32], &[f32])| {
                    for (v, tj) in o.iter_mut().zip(t) {
                        *v = filter(tj, |s| row[s]);
                    }
                };
                if par {
                    xr.par_chunks_mut(ox)
                        .zip(slice.par_chunks(nx))
                        .for_each(row);
                } else {
                    xr.chunks_mut(ox).zip(slice.chunks(nx)).for_each(row);
                }
                xr
            }
        };
        match &self.taps[1] {
            None => xr,
            Some(t) => {
                let mut out = vec![0.0f32; ox * oy];
                let row = |(o, tj): (&mut [f32], &Vec<(usize, f32)>)| {
                    for (x, v) in o.iter_mut().enumerate() {
                        *v = filter(tj, |s| xr[x + ox * s]);
                    }
                };
                if par {
                    out.par_chunks_mut(ox).zip(t.par_iter()).for_each(row);
                } else {
                    out.chunks_mut(ox).zip(t).for_each(row);
                }
                out
            }
        }
    }

    /// Take the next input slice; returns the output slices it completes, in order.
    fn push(&mut self, slice: &[f32]) -> Vec<Vec<f32>> {
        let xy = self.reduce_xy(slice);
        let z = self.seen;
        self.seen += 1;
        let Some(tz) = &self.taps[2] else {
            self.done += 1;
            if let Some(out) = &mut self.out {
                out.extend_from_slice(&xy);
            }
            return vec![xy];
        };
        self.window.push_back((z, xy));
        let area = self.output[0] * self.output[1];
        let mut done = Vec::new();
        for tj in tz.iter().skip(self.done) {
            if tj.last().map_or(0, |t| t.0) > z {
                break;
            }
            let first = self.window.front().map_or(0, |w| w.0);
            let w = &self.window;
            let mut out = vec![0.0f32; area];
            let fill = |(c, o): (usize, &mut [f32])| {
                for (i, v) in o.iter_mut().enumerate() {
                    *v = filter(tj, |s| w[s - first].1[c * PAR_POINTS + i]);
                }
            };
            if area >= PAR_POINTS {
                use rayon::prelude::*;
                out.par_chunks_mut(PAR_POINTS).enumerate().for_each(fill);
            } else {
                out.chunks_mut(PAR_POINTS).enumerate().for_each(fill);
            }
            if let Some(level) = &mut self.out {
                level.extend_from_slice(&out);
            }
            self.done += 1;
            done.push(out);
        }
        // Drop the slices no later output reads (each output's taps start at or after the
        // previous one's).
        let keep_from = tz
            .get(self.done)
            .and_then(|t| t.first())
            .map_or(z + 1, |t| t.0);
        while self.window.front().is_some_and(|w| w.0 < keep_from) {
            self.window.pop_front();
        }
        done
    }
}

impl Reducer {
    /// A reducer for the levels `shapes` ([`level_shapes`], level 0 first); level 0's slices
    /// go in. Level `l` ≥ 1 is held for [`Reducer::finish`] when `keep(l)`.
    pub(crate) fn new(shapes: &[([usize; 3], [f64; 3])], keep: impl Fn(usize) -> bool) -> Reducer {
        Reducer {
            stages: shapes
                .windows(2)
                .enumerate()
                .map(|(l, w)| Stage::new(w[0].0, w[1].0, keep(l + 1)))
                .collect(),
        }
    }

    /// The next z-slice of level 0 (x fastest); `done(l, slice)` sees every slice of level
    /// `l` ≥ 1 as it is completed, in order.
    pub(crate) fn push(&mut self, slice: &[f32], mut done: impl FnMut(usize, &[f32])) {
        // Level 0's slice is borrowed (no copy of the volume per load); coarser slices are
        // the stages' own outputs.
        let mut pending: Vec<Vec<f32>> = Vec::new();
        for (l, stage) in self.stages.iter_mut().enumerate() {
            let mut next = Vec::new();
            if l == 0 {
                next.extend(stage.push(slice));
            }
            for s in &pending {
                next.extend(stage.push(s));
            }
            for s in &next {
                done(l + 1, s);
            }
            pending = next;
            if pending.is_empty() {
                break;
            }
        }
    }

    /// Levels 1.. once every slice of level 0 went in (`None` where not kept).
    pub(crate) fn finish(self) -> Vec<Option<Vec<f32>>> {
        self.stages.into_iter().map(|s| s.out).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pyramid built whole axes one after the other: the reference the streaming
    /// [`Reducer`] must match bit for bit.
    /// Build all levels, level 0 taking ownership of `data` (stored by the renderer as `narrow`
    /// says; filtered levels are [`Narrow::Round16`]).
    fn build_by_axes(geometry: Geometry, data: Vec<f32>, narrow: Narrow) -> Vec<Level> {
        let mut levels = vec![Level::new(geometry.dims, geometry.spacing, data, narrow)];
        loop {
            let prev = levels.last().expect("level 0 exists");
            if prev.dims.iter().all(|&d| d <= MIN_LEVEL_POINTS) {
                break;
            }
            let dims = prev.dims.map(|d| if d <= 2 { d } else { d.div_ceil(2) });
            let spacing = std::array::from_fn(|a| {
                if dims[a] == prev.dims[a] {
                    prev.spacing[a]
                } else {
                    prev.spacing[a] * (prev.dims[a] - 1) as f64 / (dims[a] - 1) as f64
                }
            });
            // Borrow the previous level instead of cloning it: a clone of level 0 would be a
            // second full-size f32 copy at the peak.
            let mut cur = std::borrow::Cow::Borrowed(prev.data());
            let mut cur_dims = prev.dims;
            for axis in 0..3 {
                if dims[axis] != cur_dims[axis] {
                    cur = reduce_axis(&cur, cur_dims, axis, dims[axis]).into();
                    cur_dims[axis] = dims[axis];
                }
            }
            let cur = cur.into_owned();
            levels.push(Level::new(dims, spacing, cur, Narrow::Round16));
        }
        levels
    }

    /// Resample one axis from `dims[axis]` to `n` points with a tent filter of the reduction width.
    fn reduce_axis(src: &[f32], dims: [usize; 3], axis: usize, n: usize) -> Vec<f32> {
        let d = dims[axis];
        if n == d {
            return src.to_vec();
        }
        // Taps per output point: (source index, weight), precomputed once per axis (the
        // reducer's own taps: this reference checks the order of the sums, not the weights).
        let taps = taps(d, n);
        let stride = match axis {
            0 => 1,
            1 => dims[0],
            _ => dims[0] * dims[1],
        };
        let mut out_dims = dims;
        out_dims[axis] = n;
        let out_stride = match axis {
            0 => 1,
            1 => out_dims[0],
            _ => out_dims[0] * out_dims[1],
        };
        let mut out = vec![0.0f32; out_dims.iter().product()];
        // Iterate over all lines along `axis`.
        let (outer, inner) = match axis {
            0 => (dims[1] * dims[2], 1),
            1 => (dims[2], dims[0]),
            _ => (1, dims[0] * dims[1]),
        };
        for o in 0..outer {
            for i in 0..inner {
                let (src_base, dst_base) = match axis {
                    0 => (o * dims[0], o * n),
                    1 => (o * dims[0] * dims[1] + i, o * dims[0] * n + i),
                    _ => (i, i),
                };
                for (j, tj) in taps.iter().enumerate() {
                    let (mut acc, mut wsum) = (0.0f32, 0.0f32);
                    for &(s, w) in tj {
                        let v = src[src_base + s * stride];
                        if !v.is_nan() {
                            acc += w * v;
                            wsum += w;
                        }
                    }
                    out[dst_base + j * out_stride] = if wsum > 0.0 { acc / wsum } else { f32::NAN };
                }
            }
        }
        out
    }

    fn geom(dims: [usize; 3]) -> Geometry {
        Geometry {
            dims,
            spacing: [1.0, 2.0, 0.5],
            origin: [0.0; 3],
        }
    }

    #[test]
    fn levels_keep_the_world_box_and_values_in_range() {
        let dims = [33, 20, 9];
        let n: usize = dims.iter().product();
        let data: Vec<f32> = (0..n).map(|i| (i % 97) as f32 / 96.0).collect();
        let levels = build(geom(dims), data, Narrow::No);
        assert!(levels.len() >= 3);
        for l in &levels {
            for a in 0..3 {
                let ext = (l.dims[a] - 1) as f64 * l.spacing[a];
                let ext0 = (dims[a] - 1) as f64 * geom(dims).spacing[a];
                assert!((ext - ext0).abs() < 1e-9, "{:?}", l.dims);
            }
            assert!(l.data().iter().all(|v| (0.0..=1.0).contains(v)));
        }
        assert_eq!(levels[1].dims, [17, 10, 5]);
    }

    #[test]
    fn linear_ramp_survives_reduction() {
        let dims = [17, 3, 3];
        let data: Vec<f32> = (0..dims.iter().product::<usize>())
            .map(|i| (i % 17) as f32 / 16.0)
            .collect();
        let levels = build(geom(dims), data, Narrow::No);
        let l1 = &levels[1];
        assert_eq!(l1.dims[0], 9);
        for i in 1..8 {
            // Interior points of a linear ramp are reproduced exactly by a symmetric tent.
            assert!((l1.data()[l1.index(i, 1, 1)] - i as f32 / 8.0).abs() < 1e-6);
        }
    }

    #[test]
    fn bricks_bound_every_point_they_touch() {
        let dims = [20, 11, 9];
        let n: usize = dims.iter().product();
        let mut data: Vec<f32> = (0..n).map(|i| ((i * 7919) % 1000) as f32 / 999.0).collect();
        data[5] = f32::NAN;
        let g = BrickGrid::build(dims, &data);
        assert_eq!(g.counts, [3, 2, 1]);
        assert!(g.uniform.iter().all(|&u| !u));
        // A constant block is uniform, unless a NaN touches it.
        let mut flat = vec![0.25f32; n];
        flat[n - 1] = f32::NAN;
        let f = BrickGrid::build(dims, &flat);
        assert!(f.uniform[0] && !f.uniform[f.index(2, 1, 0)]);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let v = data[i + dims[0] * (j + dims[1] * k)];
                    if v.is_nan() {
                        continue;
                    }
                    // The brick of every cell that has this point as a corner.
                    for (ci, cj, ck) in [(i, j, k), (i.wrapping_sub(1), j, k)] {
                        if ci >= dims[0] - 1 || cj >= dims[1] - 1 || ck >= dims[2] - 1 {
                            continue;
                        }
                        let b = g.index(ci / BRICK_CELLS, cj / BRICK_CELLS, ck / BRICK_CELLS);
                        assert!(g.min[b] <= v && v <= g.max[b]);
                    }
                }
            }
        }
    }

    /// The brick ranges point by point, each into every brick it touches: the reference for
    /// the row-wise [`BrickGridBuilder`].
    fn bricks_by_points(dims: [usize; 3], data: &[f32]) -> (Vec<f32>, Vec<f32>, Vec<bool>) {
        let counts = dims.map(|d| d.saturating_sub(1).max(1).div_ceil(BRICK_CELLS));
        let total = counts.iter().product();
        let (mut min, mut max) = (vec![f32::INFINITY; total], vec![f32::NEG_INFINITY; total]);
        let mut nan = vec![false; total];
        let of = |p: usize, a: usize| {
            (p.saturating_sub(1) / BRICK_CELLS).min(counts[a] - 1)
                ..=(p / BRICK_CELLS).min(counts[a] - 1)
        };
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let v = data[i + dims[0] * (j + dims[1] * k)];
                    for bk in of(k, 2) {
                        for bj in of(j, 1) {
                            for bi in of(i, 0) {
                                let b = bi + counts[0] * (bj + counts[1] * bk);
                                if v.is_nan() {
                                    nan[b] = true;
                                } else {
                                    min[b] = min[b].min(v);
                                    max[b] = max[b].max(v);
                                }
                            }
                        }
                    }
                }
            }
        }
        let uniform = (0..total).map(|b| !nan[b] && min[b] == max[b]).collect();
        (min, max, uniform)
    }

    /// Row starts past 2³² points (a level of 70000 × 70000 × 2, not allocated).
    #[test]
    fn box_rows_index_past_32_bits() {
        let dims = [70_000, 70_000, 2];
        let rows: Vec<u64> = box_rows(dims, [5, 69_998, 1], [9, 70_000, 2]).collect();
        let plane = 70_000u64 * 70_000;
        assert!(plane > u32::MAX as u64);
        assert_eq!(
            rows,
            [5 + 69_998 * 70_000 + plane, 5 + 69_999 * 70_000 + plane]
        );
    }

    /// Row by row equals point by point, bit for bit (both zeros, NaN), on odd sizes.
    #[test]
    fn brick_rows_match_point_by_point() {
        let cases = [[1, 1, 1], [2, 3, 1], [9, 17, 33], [17, 8, 9], [33, 20, 9]];
        for dims in cases.into_iter().chain([[64, 3, 2]]) {
            let n: usize = dims.iter().product();
            // Every 11th point from NaN, −0, +0, −0, +0; the rest a scramble of [0, 1].
            let special = [f32::NAN, -0.0, 0.0, -0.0, 0.0];
            let data: Vec<f32> = (0..n)
                .map(|i| {
                    let scrambled = ((i * 7919) % 1013) as f32 / 1012.0;
                    special.get(i % 11).copied().unwrap_or(scrambled)
                })
                .collect();
            let g = BrickGrid::build(dims, &data);
            let (min, max, uniform) = bricks_by_points(dims, &data);
            let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&g.min), bits(&min), "{dims:?}");
            assert_eq!(bits(&g.max), bits(&max), "{dims:?}");
            assert_eq!(g.uniform, uniform, "{dims:?}");
        }
    }

    /// Level by level, bit for bit (NaN where NaN), and the same shapes and spacings.
    fn assert_same_levels(a: &[Level], b: &[Level], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}: level count");
        for (l, (x, y)) in a.iter().zip(b).enumerate() {
            assert_eq!(
                (x.dims, x.spacing),
                (y.dims, y.spacing),
                "{what}: level {l}"
            );
            let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert!(
                bits(x.data()) == bits(y.data()),
                "{what}: level {l} values differ"
            );
        }
    }

    /// The streaming reducer gives the axis-by-axis pyramid exactly, on odd and tiny sizes
    /// (1, 2, 3, 127 points per axis) with NaN voxels.
    #[test]
    fn streaming_matches_axis_by_axis_bit_for_bit() {
        let sizes = [1usize, 2, 3, 127];
        let mut cases: Vec<[usize; 3]> = Vec::new();
        for &x in &sizes {
            for &y in &sizes {
                for &z in &sizes {
                    if x * y * z <= 127 * 127 * 3 {
                        cases.push([x, y, z]);
                    }
                }
            }
        }
        // The last: slices large enough to be reduced on several threads (PAR_POINTS).
        cases.extend([[127, 127, 127], [9, 17, 33], [64, 64, 64], [301, 233, 5]]);
        for dims in cases {
            let n: usize = dims.iter().product();
            let mut data: Vec<f32> = (0..n)
                .map(|i| ((i * 7919) % 1013) as f32 / 1012.0)
                .collect();
            for i in (0..n).step_by(97) {
                data[i] = f32::NAN;
            }
            let g = geom(dims);
            let a = build(g, data.clone(), Narrow::No);
            let b = build_by_axes(g, data, Narrow::No);
            assert_same_levels(&a, &b, &format!("{dims:?}"));
        }
    }

    /// The same on every volume in ../shared/data/volumes (skipped where that folder is absent).
    #[test]
    fn streaming_matches_axis_by_axis_on_shared_volumes() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/volumes");
        let Ok(entries) = std::fs::read_dir(&dir) else {
            eprintln!("no shared volumes: skipped");
            return;
        };
        let mut checked = 0;
        for e in entries.flatten() {
            let path = e.path();
            if path.extension().and_then(|x| x.to_str()) != Some("raw") {
                continue;
            }
            let v = crate::load(&path, &Default::default()).unwrap();
            let l0 = &v.levels[0];
            // The stream's units (`stream` module docs): 8/16-bit codes are filtered as
            // their values and normalized after; other types are filtered normalized.
            let decoded = crate::decode(&path, &Default::default()).unwrap();
            let ty = decoded.buffer.scalar_type();
            let codes = super::super::stats::small_codes(ty).is_some();
            let units = if codes {
                let mut values = Vec::new();
                decoded.buffer.for_each(|x| values.push(x as f32));
                values
            } else {
                l0.data().to_vec()
            };
            let mut reference = build_by_axes(v.geometry, units, l0.narrow());
            let norm = super::super::stream::Norm::new(ty, v.norm_range);
            for (l, level) in reference.iter_mut().enumerate() {
                let mut d = level.data().to_vec();
                if codes {
                    d.iter_mut().for_each(|x| *x = norm.apply(*x));
                }
                if l > 0 && !d.iter().any(|x| x.is_nan()) {
                    d.iter_mut().for_each(|x| *x = unround16(round16(*x)));
                }
                *level = Level::new(level.dims, level.spacing, d, level.narrow());
            }
            assert_same_levels(&v.levels, &reference, &path.display().to_string());
            checked += 1;
        }
        assert!(checked > 0, "no .raw volume in {}", dir.display());
    }
}
