//! Where level 0's values come from: the file's own scalar type and byte order.
//!
//! A [`Source`] holds the values as the file stores them: a memory map of the file where they
//! lie there contiguously and uncompressed (`.raw`, appended raw `.vti`, legacy BINARY `.vtk`),
//! else the decoded bytes (a [`TypedBuffer`]). Readers of the values ([`Source::for_bytes`])
//! see whole values in order; `stream` normalizes them and builds the pyramid. Pages of a
//! memory map are released behind each pass (`MADV_DONTNEED`: the file's pages stay in the
//! page cache, they only stop counting as this process's memory).

use std::ops::Range;
use std::path::{Path, PathBuf};

use super::summary::{code_stats, count_codes, small_codes, MinMax, Stats};
use super::{buffer::for_each_value, ByteOrder, Geometry, ScalarType, TypedBuffer, VolumeError};

/// Values visited at a time by the statistics pass (and released behind it when mapped).
const BLOCK_VALUES: usize = 4 << 20;

/// Level 0's values in the file's own type and byte order.
#[derive(Debug)]
pub(crate) struct Source {
    /// The file, for errors.
    path: PathBuf,
    /// The stored type (f64 for parsed text).
    ty: ScalarType,
    order: ByteOrder,
    bytes: Bytes,
    /// Number of values.
    len: usize,
}

/// Where the bytes are.
#[derive(Debug)]
enum Bytes {
    /// `len × size` bytes from `offset` of a memory-mapped file.
    Map { map: memmap2::Mmap, offset: usize },
    /// Decoded into memory.
    Memory(TypedBuffer),
}

impl Source {
    /// Map `count` values of `ty` in `order` starting `offset` bytes into the file at `path`.
    /// The file must not change while the volume lives (the map would see the change).
    pub(crate) fn map(
        path: &Path,
        ty: ScalarType,
        order: ByteOrder,
        offset: u64,
        count: usize,
    ) -> Result<Source, VolumeError> {
        let io = |error| VolumeError::Io {
            path: path.to_path_buf(),
            error,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        // SAFETY: the map is read only; the file changing underneath is documented above
        // as unsupported (as for any reader that reads a file twice).
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| {
            // Mostly an address-space limit (`ulimit -v`) smaller than the file.
            let len = file.metadata().map_or(0, |m| m.len());
            VolumeError::file(
                path,
                format!(
                    "cannot map its {} into memory ({e}); raise the address-space limit \
                     (ulimit -v) or use a smaller volume",
                    crate::units::human_bytes(len as u128)
                ),
            )
        })?;
        let need = (count as u64)
            .checked_mul(ty.size() as u64)
            .and_then(|n| n.checked_add(offset));
        if need.is_none_or(|n| n > map.len() as u64) {
            return Err(VolumeError::file(
                path,
                format!(
                    "holds {} bytes but {count} {ty} values from byte {offset} need more \
                     (truncated?)",
                    map.len()
                ),
            ));
        }
        Ok(Source {
            path: path.to_path_buf(),
            ty,
            order,
            bytes: Bytes::Map {
                map,
                offset: offset as usize,
            },
            len: count,
        })
    }

    /// Values decoded into memory.
    pub(crate) fn memory(path: &Path, buffer: TypedBuffer) -> Source {
        let (ty, order, _) = buffer.raw();
        Source {
            path: path.to_path_buf(),
            ty,
            order,
            len: buffer.len(),
            bytes: Bytes::Memory(buffer),
        }
    }

    /// Whether the values are read from a memory map of the file.
    pub(crate) fn is_mapped(&self) -> bool {
        matches!(self.bytes, Bytes::Map { .. })
    }

    /// The file the values come from.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// Number of values.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// The stored scalar type (f64 for parsed text).
    pub(crate) fn ty(&self) -> ScalarType {
        self.ty
    }

    /// The stored byte order.
    pub(crate) fn order(&self) -> ByteOrder {
        self.order
    }

    /// Hand the bytes of values `range` to `f`, in order, in one or more pieces of whole
    /// values. An error when they cannot be read (a block that does not decode).
    pub(crate) fn for_bytes(
        &self,
        range: Range<usize>,
        mut f: impl FnMut(&[u8]),
    ) -> Result<(), VolumeError> {
        f(self.bytes(range));
        Ok(())
    }

    /// The bytes of values `range`.
    fn bytes(&self, range: Range<usize>) -> &[u8] {
        let size = self.ty.size();
        let all = match &self.bytes {
            Bytes::Map { map, offset } => &map[*offset..*offset + self.len * size],
            Bytes::Memory(b) => b.raw().2,
        };
        &all[range.start * size..range.end * size]
    }

    /// Stop counting the mapped pages of values `range` as this process's memory (nothing for
    /// decoded sources). Called behind sequential passes and between the renderer's random
    /// box reads (`Level::release_source`); the values stay readable.
    pub(crate) fn release(&self, range: Range<usize>) {
        if let Bytes::Map { map, offset } = &self.bytes {
            let size = self.ty.size();
            let start = offset + range.start * size;
            let len = (range.end - range.start) * size;
            // Only whole pages inside the range, so neighbouring values' pages stay. The
            // system's page size (4 KiB on x86-64, 16/64 KiB on some ARM systems, where a
            // 4 KiB-aligned range would make madvise fail and nothing be released).
            // SAFETY: sysconf only reads a system constant.
            let page = match unsafe { libc::sysconf(libc::_SC_PAGESIZE) } {
                p if p > 0 => p as usize,
                _ => 4096,
            };
            let first = start.div_ceil(page) * page;
            let end = (start + len) / page * page;
            if end > first {
                // SAFETY: the map is a read-only shared file mapping: after MADV_DONTNEED the
                // pages read back from the file unchanged, so no reference sees other bytes.
                // A failure only means the pages stay counted.
                let _ = unsafe {
                    map.unchecked_advise_range(
                        memmap2::UncheckedAdvice::DontNeed,
                        first,
                        end - first,
                    )
                };
            }
        }
    }

    /// Finite range, non-finite count and (for 8/16-bit codes) histogram: the first pass.
    /// `None` when no value is finite; an error when the values cannot be read.
    pub(super) fn stats(&self) -> Result<Option<SourceStats>, VolumeError> {
        let blocks = (0..self.len)
            .step_by(BLOCK_VALUES)
            .map(|s| s..(s + BLOCK_VALUES).min(self.len));
        if let Some(codes) = small_codes(self.ty) {
            use rayon::prelude::*;
            let mut counts = vec![0u64; codes];
            for block in blocks {
                let bytes = self.bytes(block.clone());
                let size = self.ty.size();
                let threads = rayon::current_num_threads().max(1);
                let share = (bytes.len().div_ceil(threads).div_ceil(size) * size).max(size);
                // Counts are integers: the split changes nothing in the result.
                let parts: Vec<Vec<u64>> = bytes
                    .par_chunks(share)
                    .map(|b| {
                        let mut c = vec![0u64; codes];
                        count_codes(self.ty, self.order, b, &mut c);
                        c
                    })
                    .collect();
                for p in parts {
                    for (c, k) in counts.iter_mut().zip(p) {
                        *c += k;
                    }
                }
                self.release(block);
            }
            return Ok(Some((code_stats(self.ty, &counts), Some(counts))));
        }
        // In index order: min/max of ±0 depend on the order, and `normalize` goes in it.
        let mut acc = MinMax::default();
        for block in blocks {
            for_each_value(self.ty, self.order, self.bytes(block.clone()), |v| {
                acc.add(v)
            });
            self.release(block);
        }
        if acc.norm_range().is_none() {
            return Ok(None);
        }
        Ok(Some((acc.stats(Vec::new()), None)))
    }
}

/// What [`Source::stats`] finds: the statistics and, for 8/16-bit codes, each code's count.
pub(super) type SourceStats = (Stats, Option<Vec<u64>>);

/// Where a file's chosen array lies when its values can be mapped: contiguous, uncompressed,
/// in one byte order (`vti::locate`, `legacy::locate`).
pub(crate) struct Located {
    pub(crate) geometry: Geometry,
    /// The stored type (what the file declares).
    pub(crate) ty: ScalarType,
    pub(crate) order: ByteOrder,
    /// Byte offset of the first value in the file.
    pub(crate) offset: u64,
    /// Number of values.
    pub(crate) count: usize,
    pub(crate) format: super::SourceFormat,
}
