//! Which blocks of a level the march may cross without sampling: empty blocks (the TF gives
//! them no density) are jumped over, uniform blocks (every point one value) are crossed in one
//! step.
//!
//! A trilinear sample inside a brick lies in the brick's [min, max] (see `volume::BrickGrid`),
//! and the LUT is linear between entries, so σ on [min, max] is bounded by the largest entry
//! among those whose cells overlap the range. A prefix count of entries with σ above the
//! threshold answers "is σ ≤ threshold on [min, max]" in O(1) per brick.
//!
//! Two block sizes: the pyramid's bricks (8³ cells) and super-blocks of 4³ bricks (32³ cells),
//! checked first. In mostly-empty volumes most of a ray crosses super-blocks, so it needs about
//! a quarter of the steps it would need brick by brick.

use t2tf_tf::Lut;
use t2tf_volume::{BrickGrid, BRICK_CELLS};

/// Bricks per super-block side.
const SUPER: usize = 4;
const _: () = assert!(BRICK_CELLS.is_power_of_two() && SUPER.is_power_of_two());

/// Per-block flags of one block size over a level.
pub(crate) struct Blocks {
    /// Cells per block side.
    pub(crate) cells: usize,
    /// log2(cells): block coordinates are shifts, not divisions, in the march's inner loop.
    pub(crate) shift: u32,
    /// Blocks per axis.
    pub(crate) counts: [usize; 3],
    /// The TF has σ ≤ threshold on every sample of the block (or every point is NaN).
    pub(crate) empty: Vec<bool>,
    /// The value of every sample in the block when they are all equal, NaN otherwise.
    pub(crate) value: Vec<f32>,
}

/// [super-blocks, bricks] of a level with brick ranges `grid` for `lut`. `skip` false marks nothing empty; `uniform`
/// false marks nothing uniform (tests compare against sample-by-sample marching).
pub(crate) fn blocks(
    grid: &BrickGrid,
    lut: &Lut,
    skip: bool,
    threshold: f32,
    uniform: bool,
) -> [Blocks; 2] {
    let b = grid;
    let bricks = Blocks {
        cells: BRICK_CELLS,
        shift: BRICK_CELLS.trailing_zeros(),
        counts: b.counts,
        empty: if skip {
            empty_bricks(grid, lut, threshold)
        } else {
            vec![false; b.min.len()]
        },
        value: (0..b.min.len())
            .map(|i| {
                if uniform && b.uniform[i] {
                    b.min[i]
                } else {
                    f32::NAN
                }
            })
            .collect(),
    };
    let counts = b.counts.map(|c| c.div_ceil(SUPER));
    let total = counts.iter().product();
    let (mut empty, mut value) = (vec![true; total], vec![f32::NAN; total]);
    let mut first = vec![true; total];
    let mut same = vec![true; total];
    for k in 0..b.counts[2] {
        for j in 0..b.counts[1] {
            for i in 0..b.counts[0] {
                let fine = b.index(i, j, k);
                let s = i / SUPER + counts[0] * (j / SUPER + counts[1] * (k / SUPER));
                empty[s] &= bricks.empty[fine];
                let v = bricks.value[fine];
                if first[s] {
                    value[s] = v;
                    first[s] = false;
                } else if v != value[s] {
                    same[s] = false; // also true when either is NaN
                }
            }
        }
    }
    for (v, s) in value.iter_mut().zip(&same) {
        if !s {
            *v = f32::NAN;
        }
    }
    let supers = Blocks {
        cells: BRICK_CELLS * SUPER,
        shift: (BRICK_CELLS * SUPER).trailing_zeros(),
        counts,
        empty,
        value,
    };
    [supers, bricks]
}

/// Per brick of `grid`: true when every sample in it has σ ≤ `threshold` (or is NaN).
pub(crate) fn empty_bricks(grid: &BrickGrid, lut: &Lut, threshold: f32) -> Vec<bool> {
    let n = lut.entries.len();
    let scale = (n - 1) as f32;
    // visible[k] = number of entries among the first k whose σ exceeds the threshold.
    let mut visible = Vec::with_capacity(n + 1);
    visible.push(0u32);
    for e in &lut.entries {
        let last = *visible.last().expect("starts non-empty");
        visible.push(last + u32::from(e[0] > threshold));
    }
    let b = grid;
    b.min
        .iter()
        .zip(&b.max)
        .map(|(&lo, &hi)| {
            if lo > hi {
                return true; // every point NaN
            }
            let j0 = ((lo.clamp(0.0, 1.0) * scale).floor() as usize).min(n - 1);
            let j1 = ((hi.clamp(0.0, 1.0) * scale).ceil() as usize).min(n - 1);
            visible[j1 + 1] == visible[j0]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::tests::volume_of as volume;
    use super::*;

    #[test]
    fn bricks_are_empty_exactly_where_the_tf_is_zero_on_their_range() {
        // 17 points along x: two bricks, values 0..0.5 in the first, 0.5..1 in the second.
        let v = volume([17, 2, 2], |i, _, _| i as f64 / 16.0);
        let level = &v.levels[0];
        assert_eq!(level.bricks.counts, [2, 1, 1]);
        // σ zero below 0.6: the first brick [0, 0.5] is empty, the second is not.
        let mut lut = Lut {
            entries: (0..11)
                .map(|j| [if j >= 6 { 5.0 } else { 0.0 }, 1.0, 1.0, 1.0])
                .collect(),
        };
        assert_eq!(empty_bricks(&level.bricks, &lut, 0.0), vec![true, false]);
        // Entry 5 (x = 0.5) becomes visible: the first brick touches it now.
        lut.entries[5][0] = 1.0;
        assert_eq!(empty_bricks(&level.bricks, &lut, 0.0), vec![false, false]);
        // ... unless it is below the threshold.
        assert_eq!(empty_bricks(&level.bricks, &lut, 1.0), vec![true, false]);
    }

    #[test]
    fn super_blocks_summarize_their_bricks() {
        // 65 points along x: 8 bricks, 2 super-blocks. x ≤ 32 is 0 (uniform, empty under a TF
        // that is zero at 0), x > 32 a ramp.
        let v = volume([65, 3, 3], |i, _, _| if i <= 32 { 0.0 } else { i as f64 });
        let lut = Lut {
            entries: vec![[0.0, 0.0, 0.0, 0.0], [7.0, 1.0, 1.0, 1.0]],
        };
        let [supers, bricks] = blocks(&v.levels[0].bricks, &lut, true, 0.0, true);
        assert_eq!((supers.cells, supers.counts), (32, [2, 1, 1]));
        assert_eq!(supers.empty, vec![true, false]);
        assert_eq!(supers.value[0], 0.0);
        assert!(supers.value[1].is_nan());
        assert_eq!(bricks.empty.iter().filter(|&&e| e).count(), 4);
        // Without skipping nothing is empty, and the zero super-block is still uniform.
        let [supers, _] = blocks(&v.levels[0].bricks, &lut, false, 0.0, true);
        assert_eq!(supers.empty, vec![false, false]);
        assert_eq!(supers.value[0], 0.0);
    }
}
