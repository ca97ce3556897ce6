//! Releasing a memory map's pages behind a pass: shared by the mapped and the block-decoded
//! sources (`source`, `blocks`).

use std::ops::Range;

/// Stop counting the pages of `map` in `range` as this process's memory (`MADV_DONTNEED`).
pub(super) fn dont_need(map: &memmap2::Mmap, range: Range<usize>) {
    // Only whole pages inside the range, so neighbouring values' pages stay. The system's
    // page size (4 KiB on x86-64, 16/64 KiB on some ARM systems, where a 4 KiB-aligned range
    // would make madvise fail and nothing be released).
    // SAFETY: sysconf only reads a system constant.
    let page = match unsafe { libc::sysconf(libc::_SC_PAGESIZE) } {
        p if p > 0 => p as usize,
        _ => 4096,
    };
    let first = range.start.div_ceil(page) * page;
    let end = range.end.min(map.len()) / page * page;
    if end > first {
        // SAFETY: the map is a read-only shared file mapping: after MADV_DONTNEED the pages
        // read back from the file unchanged, so no reference sees other bytes. A failure
        // only means the pages stay counted.
        let _ = unsafe {
            map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, first, end - first)
        };
    }
}
