//! A level's samples regrouped brick by brick, each brick with its one-point apron, and stored
//! in as few bytes as represent them exactly — the layout of the renderer's inner loop.
//!
//! Why: in the x-fastest f32 layout a trilinear sample's eight corners sit in four rows up to
//! a slice apart (256 KiB for a 256³ volume), a ray marching in depth touches new cache lines
//! at almost every step, and the renderer's sampling waits on memory (BENCHMARKS.md). Here
//! brick b holds the `(BRICK_CELLS + 1)³` points its cells touch (its own and the first layer
//! of its +x/+y/+z neighbours) contiguously: every corner of every cell in the brick is within
//! 729 values, rays of one image tile reuse the same bricks from L1/L2, and a sample never
//! needs a neighbouring brick. Level 0 of an integer volume whose range spans at most 255
//! (65535) steps is stored as `u8` (`u16`): value = q · scale, exactly as normalized (to
//! within 1e-6); a 256³ `uint8` volume then takes 23 MiB (it fits the L3 cache) instead of
//! 64 MiB of f32. Filtered mip levels are rounded to 16 bits ([`Narrow::Round16`]); level 0
//! of a float volume, and any level with NaN, stays f32. Built once per level, when the CPU
//! backend prepares it (`render::cpu`).
//!
//! The copy lives in an anonymous mapping advised for transparent huge pages (Linux): a ray
//! enters a new brick every few samples, and with 4 KiB pages that is a TLB miss once the
//! volume outgrows the TLB's reach. Elsewhere, or when the mapping fails, it is a heap vector.
//!
//! Points past the level's last point (the apron of a partial last brick, or the second point
//! of a one-point axis) repeat the last point, so the corner offsets are the same everywhere;
//! the renderer clamps cells so that such a point is only ever read with weight 0 — or, on a
//! one-point axis, where the x-fastest layout reuses the point itself, with the same value.
//! Each buffer has [`PAD`] values more than its bricks need: AVX2 gathers read 4 bytes at a
//! corner's address, 3 bytes past the last `u8` corner.

use rayon::prelude::*;

use crate::backend::RenderError;
use t2tf_volume::{BrickGrid, Level, Narrow, BRICK_CELLS};

/// Points per brick side: its cells plus one.
pub(crate) const BRICK_POINTS: usize = BRICK_CELLS + 1;
/// Values per brick.
pub(crate) const BRICK_VALUES: usize = BRICK_POINTS * BRICK_POINTS * BRICK_POINTS;
/// Zero values after the last brick (see the module docs).
pub(crate) const PAD: usize = 4;

/// The stored values of all bricks, one after the other: brick `b` at
/// `[b * BRICK_VALUES..][..BRICK_VALUES]`, local point (i, j, k) at
/// `i + BRICK_POINTS * (j + BRICK_POINTS * k)`; bricks numbered as in [`BrickGrid`].
#[derive(Clone, Copy, Debug)]
pub enum BrickValues<'a> {
    /// Stored `q`, normalized value `q · scale` (integer volumes spanning ≤ 255 steps).
    U8(&'a [u8]),
    /// Stored `q`, normalized value `q · scale` (≤ 65535 steps, or a rounded mip level).
    U16(&'a [u16]),
    /// The normalized values themselves.
    F32(&'a [f32]),
}

impl BrickValues<'_> {
    /// Stored values (bricks and padding).
    pub(crate) fn len(&self) -> usize {
        match self {
            BrickValues::U8(v) => v.len(),
            BrickValues::U16(v) => v.len(),
            BrickValues::F32(v) => v.len(),
        }
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> usize {
        match self {
            BrickValues::U8(v) => std::mem::size_of_val(*v),
            BrickValues::U16(v) => std::mem::size_of_val(*v),
            BrickValues::F32(v) => std::mem::size_of_val(*v),
        }
    }
}

/// A level's bricks; the normalized value of stored `q` is `q · scale`.
pub(crate) struct BrickedData {
    storage: Storage,
    scale: f32,
}

/// Bricks in 8, 16 or 32 bits: a level's whole copy, or a brick cache's arena (`cache.rs`).
pub(crate) enum Storage {
    U8(Buffer<u8>),
    U16(Buffer<u16>),
    F32(Buffer<f32>),
}

impl Storage {
    /// `len` zero values of `encoding`'s width.
    pub(crate) fn zeros(encoding: Encoding, len: usize) -> Storage {
        match encoding.bytes() {
            1 => Storage::U8(Buffer::zeros(len)),
            2 => Storage::U16(Buffer::zeros(len)),
            _ => Storage::F32(Buffer::zeros(len)),
        }
    }

    /// The stored values.
    pub(crate) fn values(&self) -> BrickValues<'_> {
        match self {
            Storage::U8(b) => BrickValues::U8(b.as_slice()),
            Storage::U16(b) => BrickValues::U16(b.as_slice()),
            Storage::F32(b) => BrickValues::F32(b.as_slice()),
        }
    }
}

impl BrickedData {
    /// The bricks of a level with `dims` points and brick ranges `grid`, stored as `narrow`
    /// allows. The values come from `read` (`Level::read_box`: the normalized values of the
    /// points in [lo, hi), x fastest), one slab of a brick layer (9 points deep) at a time, so
    /// no f32 copy of the whole level is needed; layers are built in parallel.
    pub(crate) fn build<R>(
        dims: [usize; 3],
        grid: &BrickGrid,
        narrow: Narrow,
        read: &R,
    ) -> Result<BrickedData, RenderError>
    where
        R: Fn([usize; 3], [usize; 3], &mut [f32]) -> Result<(), RenderError> + Sync,
    {
        let count = grid.counts.iter().product::<usize>() * BRICK_VALUES + PAD;
        let encoding = Encoding::of(narrow);
        // Narrow storage is tried first and given up (for f32) at the first value that it does
        // not represent: the same decision as checking every value first, in one pass.
        let storage = match encoding {
            Encoding::F32 => None,
            e if e.bytes() == 1 => Buffer::build(count, dims, grid, e, read)?.map(Storage::U8),
            e => Buffer::build(count, dims, grid, e, read)?.map(Storage::U16),
        };
        Ok(match storage {
            Some(storage) => BrickedData {
                storage,
                scale: encoding.scale(),
            },
            None => {
                let f32s = Buffer::build(count, dims, grid, Encoding::F32, read)?;
                BrickedData {
                    storage: Storage::F32(f32s.expect("every f32 is stored as itself")),
                    scale: 1.0,
                }
            }
        })
    }

    /// The stored values.
    pub(crate) fn values(&self) -> BrickValues<'_> {
        self.storage.values()
    }

    /// Normalized value per unit of a stored value.
    pub(crate) fn scale(&self) -> f32 {
        self.scale
    }

    /// Bytes held.
    pub(crate) fn memory_bytes(&self) -> usize {
        self.values().bytes()
    }
}

/// How a level's values are stored: `q` in 8 or 16 bits with value `q / d`, or f32.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Encoding {
    /// `q = round(v · d)`, kept only if every value is k / d for an integer k ∈ [0, d] to
    /// within 1e-6 (level 0 of an integer volume, [`Narrow::Exact`]).
    Exact(u32),
    /// `q = round(v · 65535)`, kept only if no value is NaN (a filtered level,
    /// [`Narrow::Round16`]).
    Round16,
    /// The normalized values themselves.
    F32,
}

impl Encoding {
    /// What `narrow` allows.
    pub(crate) fn of(narrow: Narrow) -> Encoding {
        match narrow {
            Narrow::Exact(d) if d > 0 => Encoding::Exact(d),
            Narrow::Round16 => Encoding::Round16,
            Narrow::Exact(_) | Narrow::No => Encoding::F32,
        }
    }

    fn denominator(self) -> u32 {
        match self {
            Encoding::Exact(d) => d,
            Encoding::Round16 => u16::MAX as u32,
            Encoding::F32 => 1,
        }
    }

    /// Bytes per stored value.
    pub(crate) fn bytes(self) -> usize {
        match self {
            Encoding::F32 => 4,
            e if e.denominator() <= u8::MAX as u32 => 1,
            _ => 2,
        }
    }

    /// Normalized value per unit of a stored value.
    pub(crate) fn scale(self) -> f32 {
        1.0 / self.denominator() as f32
    }

    /// `v` as stored `q` (as f32), and whether the encoding represents it.
    #[inline(always)]
    fn quantize(self, v: f32) -> (f32, bool) {
        let d = self.denominator() as f32;
        let k = (v * d).round();
        let ok = match self {
            Encoding::Exact(_) => (0.0..=d).contains(&k) && (k * (1.0 / d) - v).abs() <= 1e-6,
            _ => !v.is_nan(),
        };
        (k, ok)
    }
}

impl std::fmt::Debug for BrickedData {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "BrickedData({} bytes, scale {})",
            self.memory_bytes(),
            self.scale
        )
    }
}

impl Clone for BrickedData {
    fn clone(&self) -> BrickedData {
        let storage = match &self.storage {
            Storage::U8(b) => Storage::U8(b.clone()),
            Storage::U16(b) => Storage::U16(b.clone()),
            Storage::F32(b) => Storage::F32(b.clone()),
        };
        BrickedData {
            storage,
            scale: self.scale,
        }
    }
}

/// Values for which all-zero bytes are a valid value (so zero-filled pages are initialized),
/// made from a normalized value as an [`Encoding`] says.
pub(crate) trait Stored: Copy + Default + Send + Sync {
    /// `v` stored under `e` (of this type's width), and whether `e` represents it.
    fn store(v: f32, e: Encoding) -> (Self, bool);
}
impl Stored for u8 {
    #[inline(always)]
    fn store(v: f32, e: Encoding) -> (u8, bool) {
        let (q, ok) = e.quantize(v);
        (q as u8, ok)
    }
}
impl Stored for u16 {
    #[inline(always)]
    fn store(v: f32, e: Encoding) -> (u16, bool) {
        let (q, ok) = e.quantize(v);
        (q as u16, ok)
    }
}
impl Stored for f32 {
    #[inline(always)]
    fn store(v: f32, _: Encoding) -> (f32, bool) {
        (v, true)
    }
}

/// Fill `dst` (one brick) with the points of the brick whose first point is `origin`, in a
/// level of `dims` points, from `boxed`: the values of a box of the level starting at
/// `box_lo`, `box_n[0]` × `box_n[1]` points per layer, holding every point the brick needs.
/// Points past the level's last repeat it (module docs). Returns whether every value was
/// represented (see [`Stored::store`]).
#[inline]
pub(crate) fn fill_brick<T: Stored>(
    dst: &mut [T],
    (origin, dims): ([usize; 3], [usize; 3]),
    boxed: &[f32],
    (box_lo, box_n): ([usize; 3], [usize; 2]),
    encoding: Encoding,
) -> bool {
    let mut ok = true;
    for k in 0..BRICK_POINTS {
        let z = (origin[2] + k).min(dims[2] - 1) - box_lo[2];
        for j in 0..BRICK_POINTS {
            let y = (origin[1] + j).min(dims[1] - 1) - box_lo[1];
            let row = &boxed[box_n[0] * (y + box_n[1] * z)..][..box_n[0]];
            let dst = &mut dst[BRICK_POINTS * (j + BRICK_POINTS * k)..][..BRICK_POINTS];
            for (i, v) in dst.iter_mut().enumerate() {
                let (q, good) =
                    T::store(row[(origin[0] + i).min(dims[0] - 1) - box_lo[0]], encoding);
                *v = q;
                ok &= good;
            }
        }
    }
    ok
}

/// `len` values in huge-page-advised memory where the platform offers it.
pub(crate) enum Buffer<T> {
    #[cfg(target_os = "linux")]
    Mapped(memmap2::MmapMut, usize, std::marker::PhantomData<T>),
    Heap(Vec<T>),
}

impl<T: Stored> Buffer<T> {
    pub(crate) fn zeros(len: usize) -> Buffer<T> {
        #[cfg(target_os = "linux")]
        if let Ok(map) = memmap2::MmapMut::map_anon(len.max(1) * std::mem::size_of::<T>()) {
            // Advice only: without it (or without THP in the kernel) the pages are just small.
            let _ = map.advise(memmap2::Advice::HugePage);
            return Buffer::Mapped(map, len, std::marker::PhantomData);
        }
        Buffer::Heap(vec![T::default(); len])
    }

    /// `count` values: the bricks of a level (brick layer by brick layer, each from one slab
    /// read by `read`) stored under `encoding`, then zeros. `None` when a value is not
    /// represented.
    fn build<R>(
        count: usize,
        dims: [usize; 3],
        grid: &BrickGrid,
        encoding: Encoding,
        read: &R,
    ) -> Result<Option<Buffer<T>>, RenderError>
    where
        R: Fn([usize; 3], [usize; 3], &mut [f32]) -> Result<(), RenderError> + Sync,
    {
        let c = grid.counts;
        let layer = c[0] * c[1] * BRICK_VALUES;
        let mut buffer = Buffer::zeros(count);
        let ok = buffer.as_mut_slice()[..layer * c[2]]
            .par_chunks_exact_mut(layer)
            .enumerate()
            .map(|(bk, out)| {
                let z0 = bk * BRICK_CELLS;
                let z1 = (z0 + BRICK_POINTS).min(dims[2]);
                let mut slab = vec![0.0f32; dims[0] * dims[1] * (z1 - z0)];
                read([0, 0, z0], [dims[0], dims[1], z1], &mut slab)?;
                let mut ok = true;
                for (b, brick) in out.chunks_exact_mut(BRICK_VALUES).enumerate() {
                    let origin = [b % c[0], b / c[0], bk].map(|x| x * BRICK_CELLS);
                    let slab_box = ([0, 0, z0], [dims[0], dims[1]]);
                    ok &= fill_brick(brick, (origin, dims), &slab, slab_box, encoding);
                }
                Ok(ok)
            })
            .try_reduce(|| true, |a, b| Ok(a && b))?;
        Ok(ok.then_some(buffer))
    }

    pub(crate) fn as_slice(&self) -> &[T] {
        match self {
            #[cfg(target_os = "linux")]
            // SAFETY: the mapping is page-aligned (so aligned for T), `len` values long, zero-
            // filled by the kernel (a valid T: `Stored`), and borrowed as long as the slice.
            Buffer::Mapped(m, len, _) => unsafe {
                std::slice::from_raw_parts(m.as_ptr().cast(), *len)
            },
            Buffer::Heap(v) => v,
        }
    }

    pub(crate) fn as_mut_slice(&mut self) -> &mut [T] {
        match self {
            #[cfg(target_os = "linux")]
            // SAFETY: as in `as_slice`, borrowed mutably.
            Buffer::Mapped(m, len, _) => unsafe {
                std::slice::from_raw_parts_mut(m.as_mut_ptr().cast(), *len)
            },
            Buffer::Heap(v) => v,
        }
    }
}

impl<T: Stored> Clone for Buffer<T> {
    fn clone(&self) -> Buffer<T> {
        let src = self.as_slice();
        let mut b = Buffer::zeros(src.len());
        b.as_mut_slice().copy_from_slice(src);
        b
    }
}

/// The normalized values of the points in [lo, hi) of `level`, x fastest, into `out`: from
/// the level's samples when it holds them, else from its source (level 0 of a memory-mapped
/// file is read in place, `volume::Level::read_box`).
pub(super) fn read_box(
    level: &Level,
    lo: [usize; 3],
    hi: [usize; 3],
    out: &mut [f32],
) -> Result<(), RenderError> {
    level.read_box(lo, hi, out).map_err(RenderError::Source)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The values of the points in [lo, hi) of a level of `dims` points holding `data` (x
    /// fastest), into `out`, x fastest: what `Level::read_box` does over a level's samples.
    fn slice_box(dims: [usize; 3], data: &[f32], lo: [usize; 3], hi: [usize; 3], out: &mut [f32]) {
        let n = [hi[0] - lo[0], hi[1] - lo[1]];
        for (r, dst) in out.chunks_exact_mut(n[0].max(1)).enumerate() {
            let (y, z) = (lo[1] + r % n[1].max(1), lo[2] + r / n[1].max(1));
            dst.copy_from_slice(&data[lo[0] + dims[0] * (y + dims[1] * z)..][..n[0]]);
        }
    }

    fn build(dims: [usize; 3], data: &[f32], grid: &BrickGrid, narrow: Narrow) -> BrickedData {
        let read = |lo, hi, out: &mut [f32]| {
            slice_box(dims, data, lo, hi, out);
            Ok(())
        };
        BrickedData::build(dims, grid, narrow, &read).unwrap()
    }

    fn grid_and_data(dims: [usize; 3], f: impl Fn(usize) -> f32) -> (BrickGrid, Vec<f32>) {
        let data: Vec<f32> = (0..dims.iter().product()).map(f).collect();
        (BrickGrid::build(dims, &data), data)
    }

    #[test]
    fn bricks_hold_their_points_and_aprons() {
        // 11 × 3 × 1 points: two bricks along x, the second partial; one-point z axis.
        let dims = [11, 3, 1];
        let (grid, data) = grid_and_data(dims, |i| i as f32 / 33.0);
        let b = build(dims, &data, &grid, Narrow::No);
        let BrickValues::F32(v) = b.values() else {
            panic!("f32 expected")
        };
        assert_eq!(v.len(), 2 * BRICK_VALUES + PAD);
        let at = |brick: usize, i: usize, j: usize, k: usize| {
            v[brick * BRICK_VALUES + i + BRICK_POINTS * (j + BRICK_POINTS * k)]
        };
        let point = |x: usize, y: usize| data[x.min(10) + 11 * y.min(2)];
        for j in 0..BRICK_POINTS {
            for i in 0..BRICK_POINTS {
                for k in 0..BRICK_POINTS {
                    assert_eq!(at(0, i, j, k), point(i, j));
                    assert_eq!(at(1, i, j, k), point(8 + i, j));
                }
            }
        }
    }

    #[test]
    fn integer_levels_are_stored_narrow_and_exact() {
        let dims = [9, 9, 9];
        for (d, bytes) in [(255u32, 1usize), (4095, 2), (65535, 2)] {
            let (grid, data) = grid_and_data(dims, |i| (i as u32 % (d + 1)) as f32 / d as f32);
            let b = build(dims, &data, &grid, Narrow::Exact(d));
            assert_eq!(b.memory_bytes(), bytes * (BRICK_VALUES + PAD), "D = {d}");
            let q: Vec<f32> = match b.values() {
                BrickValues::U8(v) => v.iter().map(|&q| q as f32).collect(),
                BrickValues::U16(v) => v.iter().map(|&q| q as f32).collect(),
                BrickValues::F32(_) => panic!("narrow storage expected"),
            };
            // Brick 0 holds every point of a 9³ level, x fastest.
            for (i, &v) in data.iter().enumerate() {
                assert!((q[i] * b.scale() - v).abs() <= 1e-6);
            }
        }
        // A value that is not k / D (or a NaN) keeps f32.
        let (grid, mut data) = grid_and_data(dims, |i| (i % 256) as f32 / 255.0);
        data[5] = 0.5;
        let b = build(dims, &data, &grid, Narrow::Exact(255));
        assert!(matches!(b.values(), BrickValues::F32(_)));
        data[5] = f32::NAN;
        let b = build(dims, &data, &grid, Narrow::Exact(255));
        assert!(matches!(b.values(), BrickValues::F32(_)));
        let b = build(dims, &data, &grid, Narrow::Round16);
        assert!(matches!(b.values(), BrickValues::F32(_)));
    }

    #[test]
    fn filtered_levels_round_to_16_bits() {
        let dims = [9, 9, 9];
        let (grid, data) = grid_and_data(dims, |i| ((i as f32) * 0.618_034).fract());
        let b = build(dims, &data, &grid, Narrow::Round16);
        let BrickValues::U16(q) = b.values() else {
            panic!("u16 expected")
        };
        let worst = data
            .iter()
            .zip(q)
            .map(|(&v, &q)| (q as f32 * b.scale() - v).abs())
            .fold(0.0f32, f32::max);
        assert!(
            worst <= 0.5 / 65535.0 + 1e-7,
            "worst rounding error {worst:e}"
        );
    }
}
