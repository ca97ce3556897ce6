//! A volume's statistics (finite range, non-finite count, histogram) and the 8/16-bit code
//! counts they come from: shared by the load (`source`, `stream`) and `t2tf info`
//! (`summary`), so that both give the same numbers bit for bit.

use super::{half_scale, norm_range, normalize_value, ByteOrder, ScalarType, HISTOGRAM_BINS};

/// Statistics gathered over the values (the fields of the same names of `Volume`).
pub(super) struct Stats {
    pub(super) range: [f64; 2],
    pub(super) norm_range: [f64; 2],
    pub(super) non_finite: usize,
    pub(super) histogram: Vec<u64>,
}

/// Distinct codes of an 8- or 16-bit integer type; `None` for other types.
pub(super) fn small_codes(ty: ScalarType) -> Option<usize> {
    match ty {
        ScalarType::U8 | ScalarType::I8 => Some(1 << 8),
        ScalarType::U16 | ScalarType::I16 => Some(1 << 16),
        _ => None,
    }
}

/// The number a code stands for (its bits read as the type).
pub(super) fn code_value(ty: ScalarType, c: usize) -> f64 {
    match ty {
        ScalarType::I8 => c as u8 as i8 as f64,
        ScalarType::I16 => c as u16 as i16 as f64,
        _ => c as f64,
    }
}

/// Count the codes of the values in `bytes`.
pub(super) fn count_codes(ty: ScalarType, order: ByteOrder, bytes: &[u8], counts: &mut [u64]) {
    if ty.size() == 1 {
        for &b in bytes {
            counts[b as usize] += 1;
        }
        return;
    }
    for c in bytes.chunks_exact(2) {
        let b = [c[0], c[1]];
        let code = match order {
            ByteOrder::Little => u16::from_le_bytes(b),
            ByteOrder::Big => u16::from_be_bytes(b),
        };
        counts[code as usize] += 1;
    }
}

/// Range and histogram from code counts (integers are always finite).
pub(super) fn code_stats(ty: ScalarType, counts: &[u64]) -> Stats {
    let mut acc = MinMax::default();
    for (c, _) in counts.iter().enumerate().filter(|(_, &k)| k > 0) {
        acc.add(code_value(ty, c));
    }
    let nr = acc.norm_range().expect("a volume has at least one value");
    let scale = half_scale(nr);
    let mut histogram = vec![0u64; HISTOGRAM_BINS];
    for (c, &k) in counts.iter().enumerate().filter(|(_, &k)| k > 0) {
        histogram[normalize_value(code_value(ty, c), nr, scale).1] += k;
    }
    acc.stats(histogram)
}

/// The histogram of 8/16-bit code counts over `norm_range` (`code_stats` bins over the
/// codes' own range).
pub(super) fn code_histogram(ty: ScalarType, counts: &[u64], norm_range: [f64; 2]) -> Vec<u64> {
    let scale = half_scale(norm_range);
    let mut histogram = vec![0u64; HISTOGRAM_BINS];
    for (c, &k) in counts.iter().enumerate().filter(|(_, &k)| k > 0) {
        histogram[normalize_value(code_value(ty, c), norm_range, scale).1] += k;
    }
    histogram
}

/// The finite range and the count of other values.
pub(super) struct MinMax {
    lo: f64,
    hi: f64,
    finite: usize,
    non_finite: usize,
}

impl Default for MinMax {
    fn default() -> MinMax {
        MinMax {
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
            finite: 0,
            non_finite: 0,
        }
    }
}

impl MinMax {
    pub(super) fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.lo = self.lo.min(v);
            self.hi = self.hi.max(v);
            self.finite += 1;
        } else {
            self.non_finite += 1;
        }
    }

    /// `None` when no value is finite.
    pub(super) fn norm_range(&self) -> Option<[f64; 2]> {
        (self.finite > 0).then(|| norm_range(self.lo, self.hi))
    }

    pub(super) fn stats(&self, histogram: Vec<u64>) -> Stats {
        Stats {
            range: [self.lo, self.hi],
            norm_range: norm_range(self.lo, self.hi),
            non_finite: self.non_finite,
            histogram,
        }
    }
}
