//! Releasing a memory map's pages behind a pass: shared by the mapped and the block-decoded
//! sources (`source`, `blocks`).

use std::ops::Range;

/// Stop counting the pages of `map` in `range` as this process's memory (`MADV_DONTNEED`
/// where the system has it). Only whole pages inside the range, so neighbouring values'
/// pages stay.
pub(super) fn dont_need(map: &memmap2::Mmap, range: Range<usize>) {
    let page = t2tf_core::platform::page_size();
    let first = range.start.div_ceil(page) * page;
    let end = range.end.min(map.len()) / page * page;
    t2tf_core::platform::release_pages(map, first..end.max(first));
}
