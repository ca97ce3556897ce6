//! Sampling one level: the bricked grid's index arithmetic, trilinear interpolation and LUT
//! classification, in scalar code. The march (`march.rs`) and the vector paths (`simd.rs`) both
//! build on this module, which imports neither (so there is no import loop between them).

use super::bricked::{BrickValues, BRICK_POINTS, BRICK_VALUES};
use super::skip::Blocks;
use t2tf_core::math::fast_exp;
use t2tf_tf::Lut;
use t2tf_volume::BRICK_CELLS;

/// A level's samples (brick by brick, `bricked::BrickedData`, or the resident bricks of a
/// `cache::BrickCache`) with the index arithmetic precomputed.
pub(crate) struct Grid<'a> {
    pub(super) values: BrickValues<'a>,
    /// Per brick, the slot of `values` holding it (a brick cache); `None`: brick b is at
    /// slot b (the whole level).
    pub(super) slots: Option<&'a [u32]>,
    /// Normalized value per unit of a stored value.
    pub(super) scale: f32,
    /// Largest valid coordinate per axis: dims − 1.
    pub(super) max_coord: [f32; 3],
    /// Largest cell index per axis: max(dims − 2, 0).
    pub(super) max_cell: [u32; 3],
    /// Bricks along x, and in an xy-layer.
    pub(super) brick_stride: [usize; 2],
    /// [super-blocks, bricks]: checked coarse to fine before sampling.
    pub(super) blocks: &'a [Blocks; 2],
}

impl<'a> Grid<'a> {
    /// The grid of a level with `dims` points whose bricks are `values` (stored `q`, value
    /// `q · scale`), brick b at slot `slots[b]` (`None`: at slot b), with its block tables.
    pub(crate) fn new(
        dims: [usize; 3],
        (values, scale): (BrickValues<'a>, f32),
        slots: Option<&'a [u32]>,
        blocks: &'a [Blocks; 2],
    ) -> Grid<'a> {
        let c = blocks[1].counts;
        if let Some(t) = slots {
            // `Table` reads it unchecked: one entry per brick of these dims.
            assert_eq!(t.len(), c.iter().product::<usize>(), "one slot per brick");
        }
        Grid {
            values,
            slots,
            scale,
            max_coord: dims.map(|n| (n - 1) as f32),
            max_cell: dims.map(|n| n.saturating_sub(2) as u32),
            brick_stride: [c[0], c[0] * c[1]],
            blocks,
        }
    }

    /// Whether every index into the values, and every brick number of a slot table, fits
    /// the signed 32-bit lanes of an AVX2 gather (2³¹ values: a 1290³-point level in 8 bits
    /// is past it). Larger levels take the scalar path, whose index arithmetic is 64-bit
    /// ([`value_index`]).
    pub(crate) fn gathers_fit(&self) -> bool {
        let table_fits = self.slots.is_none_or(|t| t.len() <= i32::MAX as usize);
        self.values.len() <= i32::MAX as usize && table_fits
    }
}

/// Where each brick's values start in a grid's values: the march is compiled once per layout,
/// so the whole level's copy ([`InPlace`]) keeps its arithmetic and a brick cache ([`Table`])
/// adds one table load (one more gather with AVX2) per sample.
pub(super) trait Slots: Copy + GatherSlots {
    /// Index of the first value of brick `brick`.
    fn first_value(self, brick: usize) -> usize;
}

/// Brick b at slot b: a whole level's bricked copy.
#[derive(Clone, Copy)]
pub(super) struct InPlace;

impl Slots for InPlace {
    #[inline(always)]
    fn first_value(self, brick: usize) -> usize {
        brick * BRICK_VALUES
    }
}

/// Brick b at slot `table[b]`: a brick cache (slot 0 holds zeros, for bricks not loaded).
#[derive(Clone, Copy)]
pub(super) struct Table<'a>(pub(super) &'a [u32]);

impl Slots for Table<'_> {
    #[inline(always)]
    fn first_value(self, brick: usize) -> usize {
        debug_assert!(brick < self.0.len(), "brick outside the slot table");
        // SAFETY: `brick` comes from a cell clamped into the grid (see `trilinear`), so it is
        // below the brick count, which is the table's length (`Grid::new` asserts it).
        // Unchecked for the same reason as `trilinear`'s loads.
        (unsafe { *self.0.get_unchecked(brick) }) as usize * BRICK_VALUES
    }
}

/// A stored value type of the bricked data.
pub(super) trait Voxel: Copy + Into<f32> + Gather {}
impl Voxel for u8 {}
impl Voxel for u16 {}
impl Voxel for f32 {}

/// A ray in a level's index space, clipped to the box at `a`: sample n sits at `a + u · bd`
/// with u = n + jitter (u = s / δ, s the world distance from the entry point).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ray {
    pub(super) a: [f32; 3],
    /// b · δ: the index-space step from one sample to the next.
    pub(super) bd: [f32; 3],
    /// 1 / (b · δ) per axis (0 where b is 0): block exits in sample units without divisions.
    pub(super) inv_bd: [f32; 3],
    /// Number of segments; segment n is [n δ, min((n + 1) δ, length)].
    pub(super) segments: u32,
    pub(super) delta: f32,
    pub(super) delta_last: f32,
    /// Where in its segment each sample sits, in [0, 1) (0.5 without jitter).
    pub(super) jitter: f32,
}

impl Ray {
    /// Number of segments (and samples) of the ray.
    #[cfg(test)]
    pub(crate) fn segments(&self) -> u32 {
        self.segments
    }
}

/// Loading the corner pairs (i, i + 1) of 8 samples at once, per stored type (implemented for
/// AVX2 in `simd.rs`).
#[cfg(target_arch = "x86_64")]
pub(crate) trait Gather {
    /// Values at `idx + off` and `idx + off + 1` per lane, as f32 (integers exactly).
    ///
    /// # Safety
    /// AVX2; every index + off + 1, and for `u8` the 2 bytes after it, inside the slice
    /// that `ptr` starts (`bricked::PAD`).
    unsafe fn pair(
        ptr: *const Self,
        idx: std::arch::x86_64::__m256i,
        off: i32,
    ) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256);
}

/// [`Slots::first_value`] of 8 bricks at once (implemented for AVX2 in `simd.rs`).
#[cfg(target_arch = "x86_64")]
pub(crate) trait GatherSlots {
    /// The first value's index of each lane's brick.
    ///
    /// # Safety
    /// AVX2; every lane a brick of the grid (below a slot table's length), and every result
    /// within i32 (`Grid::gathers_fit`).
    unsafe fn first_values(self, brick: std::arch::x86_64::__m256i) -> std::arch::x86_64::__m256i;
}

/// Elsewhere no layout gathers.
#[cfg(not(target_arch = "x86_64"))]
pub(crate) trait GatherSlots {}
#[cfg(not(target_arch = "x86_64"))]
impl GatherSlots for InPlace {}
#[cfg(not(target_arch = "x86_64"))]
impl GatherSlots for Table<'_> {}

/// Elsewhere no stored type gathers.
#[cfg(not(target_arch = "x86_64"))]
pub(crate) trait Gather {}
#[cfg(not(target_arch = "x86_64"))]
impl Gather for u8 {}
#[cfg(not(target_arch = "x86_64"))]
impl Gather for u16 {}
#[cfg(not(target_arch = "x86_64"))]
impl Gather for f32 {}

/// Constants of one march shared by every ray of a view.
pub(crate) struct MarchParams<'a> {
    pub(crate) grid: Grid<'a>,
    pub(crate) lut: &'a Lut,
    /// 1 / L (L = the box's longest side, docs/DESIGN.md density units).
    pub(crate) inv_l: f32,
    /// Stop once T falls below this (0 = never).
    pub(crate) stop_below: f32,
    /// Interpolate and classify with AVX2 or NEON (`simd::available()`); results are
    /// bit-identical. Always false off x86-64 and aarch64.
    #[cfg_attr(
        not(any(target_arch = "x86_64", target_arch = "aarch64")),
        allow(dead_code)
    )]
    pub(crate) simd: bool,
}

/// A sample's value through the LUT.
#[derive(Clone, Copy)]
pub(super) struct Classified {
    /// LUT entry below the value and the weight of the entry above.
    pub(super) j: u32,
    pub(super) w: f32,
    pub(super) rgb: [f32; 3],
    /// Optical depth σ · δ / L of one sample, and e^(−τ).
    pub(super) tau: f32,
    pub(super) ext: f32,
}

/// Look `v` up in the LUT for a segment of normalized length `delta_norm`; `None` for NaN
/// (any NaN corner makes the sample NaN, since 0 · NaN is NaN: empty space).
#[inline(always)]
pub(super) fn classify(lut: &[[f32; 4]], v: f32, delta_norm: f32) -> Option<Classified> {
    if v.is_nan() {
        return None;
    }
    // max/min, not clamp: the same operations as the AVX2 path, with no panic branch.
    #[allow(clippy::manual_clamp)]
    let x = v.max(0.0).min(1.0) * (lut.len() - 1) as f32;
    // SAFETY: x ∈ [0, len − 1] (not NaN), so the conversion is in range.
    let j = unsafe { x.to_int_unchecked::<u32>() }.min(lut.len() as u32 - 2);
    let w = x - j as f32;
    let (e0, e1) = (lut[j as usize], lut[j as usize + 1]);
    let tau = lerp(e0[0], e1[0], w) * delta_norm;
    Some(Classified {
        j,
        w,
        rgb: [
            lerp(e0[1], e1[1], w),
            lerp(e0[2], e1[2], w),
            lerp(e0[3], e1[3], w),
        ],
        tau,
        ext: fast_exp(-tau),
    })
}

/// Samples per chunk of the march's sample runs: one AVX2 register of f32.
pub(super) const CHUNK: usize = 8;

/// A chunk of samples interpolated and classified, as structure of arrays. NaN samples have
/// τ = 0 (and the class of value 0); [`Chunk::get`] returns `None` for them.
#[derive(Default)]
pub(super) struct Chunk {
    pub(crate) v: [f32; CHUNK],
    pub(crate) j: [u32; CHUNK],
    pub(crate) w: [f32; CHUNK],
    pub(crate) rgb: [[f32; CHUNK]; 3],
    pub(crate) tau: [f32; CHUNK],
    pub(crate) ext: [f32; CHUNK],
}

impl Chunk {
    #[inline(always)]
    pub(super) fn get(&self, i: usize) -> Option<Classified> {
        (!self.v[i].is_nan()).then(|| Classified {
            j: self.j[i],
            w: self.w[i],
            rgb: [self.rgb[0][i], self.rgb[1][i], self.rgb[2][i]],
            tau: self.tau[i],
            ext: self.ext[i],
        })
    }
}

/// Samples n … n + CHUNK − 1 of `ray`, interpolated and classified in scalar code (what
/// `simd` does with AVX2, operation for operation).
// The parameters of `simd::interpolate_classify` and its AVX2 twin: the march calls whichever
// the CPU allows with the same arguments.
#[inline(always)]
pub(super) fn interpolate_classify_scalar<T: Voxel, S: Slots>(
    p: &MarchParams,
    (d, slots): (&[T], S),
    ray: &Ray,
    n: u32,
    delta_norm: f32,
    out: &mut Chunk,
) {
    let (g, lut) = (&p.grid, &p.lut.entries[..]);
    let (a, bd, jit) = (ray.a, ray.bd, ray.jitter);
    for i in 0..CHUNK {
        let u = (n + i as u32) as f32 + jit;
        let v = trilinear(
            g,
            (d, slots),
            a[0] + u * bd[0],
            a[1] + u * bd[1],
            a[2] + u * bd[2],
        );
        let k = classify(lut, v, delta_norm).unwrap_or_else(|| {
            let mut k = classify(lut, 0.0, delta_norm).expect("0 is not NaN");
            k.tau = 0.0;
            k.ext = 1.0;
            k
        });
        out.v[i] = v;
        out.j[i] = k.j;
        out.w[i] = k.w;
        for c in 0..3 {
            out.rgb[c][i] = k.rgb[c];
        }
        out.tau[i] = k.tau;
        out.ext[i] = k.ext;
    }
}

#[inline(always)]
fn lerp(a: f32, b: f32, w: f32) -> f32 {
    a + w * (b - a)
}

/// Index coordinate `p` on axis `ax` clamped into the box [0, dims − 1] (max/min: the
/// non-NaN operand, the same operations as the AVX2 path).
#[inline(always)]
fn clamp_coord(g: &Grid, p: f32, ax: usize) -> f32 {
    p.max(0.0).min(g.max_coord[ax])
}

/// The cell holding the clamped coordinate `p` (from [`clamp_coord`]) on axis `ax`.
#[inline(always)]
fn cell_of_clamped(g: &Grid, p: f32, ax: usize) -> u32 {
    // SAFETY: p ∈ [0, dims − 1] and not NaN (`clamp_coord`), so the conversion is in range.
    // Unchecked because the checked `as` costs a few instructions per axis in the innermost
    // loop.
    unsafe { p.to_int_unchecked::<u32>() }.min(g.max_cell[ax])
}

/// The cell holding index coordinate `p` on axis `ax`, clamped into the grid.
#[inline(always)]
pub(super) fn cell(g: &Grid, p: f32, ax: usize) -> u32 {
    cell_of_clamped(g, clamp_coord(g, p, ax), ax)
}

/// The trilinear sample of `d` (the grid's values, bricks at `slots`) at index position
/// (x, y, z), clamped into the box first, as a normalized value.
#[inline(always)]
pub(super) fn trilinear<T: Voxel, S: Slots>(
    g: &Grid,
    (d, slots): (&[T], S),
    x: f32,
    y: f32,
    z: f32,
) -> f32 {
    let (x, y, z) = (
        clamp_coord(g, x, 0),
        clamp_coord(g, y, 1),
        clamp_coord(g, z, 2),
    );
    let (cx, cy, cz) = (
        cell_of_clamped(g, x, 0),
        cell_of_clamped(g, y, 1),
        cell_of_clamped(g, z, 2),
    );
    let (fx, fy, fz) = (x - cx as f32, y - cy as f32, z - cz as f32);
    let base = value_index(g.brick_stride, slots, [cx, cy, cz]);
    let (sy, sz) = (BRICK_POINTS, BRICK_POINTS * BRICK_POINTS);
    debug_assert!(
        base + 1 + sy + sz < d.len(),
        "trilinear: cell outside the grid"
    );
    // SAFETY: c ≤ max_cell = dims − 2 per axis, so the brick (c >> 3) is below the brick count
    // ⌈(dims − 1)/8⌉ (both from the same dims, `Grid::new`; the index is computed in 64 bits,
    // so it does not wrap on levels of more than 2³² values), its slot is inside `data` (the
    // whole level, or a cache's slot table, which only holds slots of its arena), and the
    // local corner (c & 7) + 1 ≤ 8 < BRICK_POINTS: every corner lies in the brick's
    // BRICK_VALUES, inside `data`.
    // Unchecked because a bounds check is a branch, which keeps the chunk loop from
    // vectorising: this is the renderer's innermost loop.
    let at = |i: usize| -> f32 { unsafe { *d.get_unchecked(i) }.into() };
    let c00 = lerp(at(base), at(base + 1), fx);
    let c10 = lerp(at(base + sy), at(base + sy + 1), fx);
    let c01 = lerp(at(base + sz), at(base + sz + 1), fx);
    let c11 = lerp(at(base + sz + sy), at(base + sz + sy + 1), fx);
    lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz) * g.scale
}

/// Where corner (0, 0, 0) of cell `c` lies in the bricked values (brick `c >> 3` at its slot
/// in `slots`, local point `c & 7`), for bricks `stride` = [along x, per xy-layer]. In 64-bit
/// arithmetic: a level can hold more than 2³² values (a 1626³-point level has 2³² bricked
/// values), and a 32-bit index would wrap onto another brick.
#[inline(always)]
pub(super) fn value_index<S: Slots>(stride: [usize; 2], slots: S, c: [u32; 3]) -> usize {
    const P: usize = BRICK_POINTS;
    const MASK: u32 = BRICK_CELLS as u32 - 1;
    let brick = brick_of_cell(stride, c);
    let local = (c[0] & MASK) as usize + P * ((c[1] & MASK) as usize + P * (c[2] & MASK) as usize);
    slots.first_value(brick) + local
}

/// The brick holding cell `c`, for bricks `stride` = [along x, per xy-layer] (64-bit, as
/// [`value_index`]).
#[inline(always)]
pub(super) fn brick_of_cell(stride: [usize; 2], c: [u32; 3]) -> usize {
    const SHIFT: u32 = BRICK_CELLS.trailing_zeros();
    (c[0] >> SHIFT) as usize
        + stride[0] * (c[1] >> SHIFT) as usize
        + stride[1] * (c[2] >> SHIFT) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The index of the last corner of a level with more than 2³² bricked values, against the
    /// same arithmetic in u128 (nothing is allocated).
    #[test]
    fn value_index_is_64_bit() {
        let dims = [2001usize, 1897, 1801];
        let counts = dims.map(|d| (d - 1).div_ceil(BRICK_CELLS));
        let stride = [counts[0], counts[0] * counts[1]];
        let values: usize = counts.iter().product::<usize>() * BRICK_VALUES;
        assert!(values > 1 << 32, "the level must exceed 32-bit indices");
        let last = dims.map(|d| (d - 2) as u32);
        let reference = |c: [u32; 3]| -> u128 {
            let b = c.map(|x| (x as usize / BRICK_CELLS) as u128);
            let l = c.map(|x| (x as usize % BRICK_CELLS) as u128);
            let p = BRICK_POINTS as u128;
            let brick = b[0] + counts[0] as u128 * (b[1] + counts[1] as u128 * b[2]);
            brick * BRICK_VALUES as u128 + l[0] + p * (l[1] + p * l[2])
        };
        for c in [[0, 0, 0], [7, 8, 9], [1234, 17, 1700], last] {
            assert_eq!(
                value_index(stride, InPlace, c) as u128,
                reference(c),
                "cell {c:?}"
            );
        }
        // The last cell's corner (1, 1, 1) is the last value of the last brick.
        let i = value_index(stride, InPlace, last) + 1 + BRICK_POINTS + BRICK_POINTS * BRICK_POINTS;
        assert_eq!(i, values - 1);
        assert!(i > u32::MAX as usize);
    }

    /// Through a brick cache's slot table the same cell is found in 64 bits: the brick number
    /// of the last cell of a level past 2³² values, and its slot's values (the table is
    /// allocated: 54 MB).
    #[test]
    fn slot_table_index_is_64_bit() {
        let dims = [2001usize, 1897, 1801];
        let counts = dims.map(|d| (d - 1).div_ceil(BRICK_CELLS));
        let stride = [counts[0], counts[0] * counts[1]];
        let bricks: usize = counts.iter().product();
        let last = dims.map(|d| (d - 2) as u32);
        assert_eq!(brick_of_cell(stride, last), bricks - 1);
        let mut table = vec![0u32; bricks];
        // A slot past 2³² / 729 so that its first value is past 2³².
        table[bricks - 1] = 6_000_000;
        let local = value_index(stride, InPlace, last) - (bricks - 1) * BRICK_VALUES;
        let i = value_index(stride, Table(&table), last);
        assert_eq!(i, 6_000_000 * BRICK_VALUES + local);
        assert!(i > u32::MAX as usize);
        // A brick that is not loaded reads slot 0 (zeros).
        assert_eq!(value_index(stride, Table(&table), [0, 0, 0]), 0);
    }
}
