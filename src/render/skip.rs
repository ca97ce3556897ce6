//! Empty-space skipping: which bricks of a level the current TF makes invisible.
//!
//! A trilinear sample inside a brick lies in the brick's [min, max] (see `volume::pyramid`),
//! and the LUT is linear between entries, so σ on [min, max] is bounded by the largest entry
//! among those whose cells overlap the range. A prefix count of entries with σ above the
//! threshold answers "is σ ≤ threshold on [min, max]" in O(1) per brick.

use crate::tf::Lut;
use crate::volume::Level;

/// Per brick of `level`: true when every sample in it has σ ≤ `threshold` (or is NaN).
pub(crate) fn empty_bricks(level: &Level, lut: &Lut, threshold: f32) -> Vec<bool> {
    let n = lut.entries.len();
    let scale = (n - 1) as f32;
    // visible[k] = number of entries among the first k whose σ exceeds the threshold.
    let mut visible = Vec::with_capacity(n + 1);
    visible.push(0u32);
    for e in &lut.entries {
        let last = *visible.last().expect("starts non-empty");
        visible.push(last + u32::from(e[0] > threshold));
    }
    let b = &level.bricks;
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
    use super::*;
    use crate::volume::{Geometry, TypedBuffer, Volume};
    use std::path::Path;

    #[test]
    fn bricks_are_empty_exactly_where_the_tf_is_zero_on_their_range() {
        // 17 points along x: two bricks, values 0..0.5 in the first, 0.5..1 in the second.
        let dims = [17, 2, 2];
        let vals: Vec<f64> = (0..68).map(|i| (i % 17) as f64 / 16.0).collect();
        let geometry = Geometry {
            dims,
            spacing: [1.0; 3],
            origin: [0.0; 3],
        };
        let v =
            Volume::from_buffer(Path::new("t"), geometry, &TypedBuffer::from_f64(vals)).unwrap();
        let level = &v.levels[0];
        assert_eq!(level.bricks.counts, [2, 1, 1]);
        // σ zero below 0.6: the first brick [0, 0.5] is empty, the second is not.
        let mut lut = Lut {
            entries: (0..11)
                .map(|j| [if j >= 6 { 5.0 } else { 0.0 }, 1.0, 1.0, 1.0])
                .collect(),
        };
        assert_eq!(empty_bricks(level, &lut, 0.0), vec![true, false]);
        // Entry 5 (x = 0.5) becomes visible: the first brick touches it now.
        lut.entries[5][0] = 1.0;
        assert_eq!(empty_bricks(level, &lut, 0.0), vec![false, false]);
        // ... unless it is below the threshold.
        assert_eq!(empty_bricks(level, &lut, 1.0), vec![true, false]);
    }
}
