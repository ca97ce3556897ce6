//! Where level 0's values come from: the file's own scalar type and byte order.
//!
//! A [`Source`] holds the values as the file stores them: a memory map of the file where they
//! lie there contiguously and uncompressed (`.raw`, appended raw `.vti`, legacy BINARY `.vtk`),
//! decoded block by block from a map of the file where it stores them in compressed blocks or
//! base64 text (`.vti`, [`super::blocks`]), else the decoded bytes (a [`TypedBuffer`]). Readers
//! of the values ([`Source::for_bytes`]) see whole values in order; `stream` normalizes them
//! and builds the pyramid. Pages of a memory map are released behind each pass
//! (`MADV_DONTNEED`: the file's pages stay in the page cache, they only stop counting as this
//! process's memory).

use std::ops::Range;
use std::path::{Path, PathBuf};

use super::blocks::{Blocks, Table};
use super::stats::{code_stats, count_codes, small_codes, MinMax, Stats};
use super::{
    buffer::for_each_value, ByteOrder, Geometry, ScalarType, SharedBytes, TypedBuffer, VolumeError,
};

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

/// Bytes another owner keeps in memory (`SharedBytes`); opaque to `Debug`.
struct Shared(SharedBytes);

impl std::fmt::Debug for Shared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Shared({} bytes)", (*self.0).as_ref().len())
    }
}

/// Where the bytes are.
#[derive(Debug)]
enum Bytes {
    /// `len × size` bytes from `offset` of a memory-mapped file.
    Map { map: memmap2::Mmap, offset: usize },
    /// Decoded into memory.
    Memory(TypedBuffer),
    /// In memory another owner shares (a NumPy array), read in place.
    Shared(Shared),
    /// Decoded block by block from a memory map of the file (compressed or base64 `.vti`).
    /// Boxed: its table and cache make it much larger than the other variants.
    Blocks(Box<Blocks>),
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
        let file = t2tf_core::input::open(path).map_err(io)?;
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
                    t2tf_core::units::human_bytes(len as u128)
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

    /// Values of type `ty` in `order` that another owner keeps in memory, read in place.
    pub(crate) fn shared(
        path: &Path,
        ty: ScalarType,
        order: ByteOrder,
        bytes: SharedBytes,
    ) -> Source {
        let len = (*bytes).as_ref().len() / ty.size();
        Source {
            path: path.to_path_buf(),
            ty,
            order,
            bytes: Bytes::Shared(Shared(bytes)),
            len,
        }
    }

    /// Values of a `.vti` array read block by block from `map`, the file at `path`.
    pub(crate) fn blocks(
        path: &Path,
        ty: ScalarType,
        order: ByteOrder,
        count: usize,
        map: memmap2::Mmap,
        table: Table,
    ) -> Source {
        let blocks = Blocks::new(path, map, table);
        debug_assert_eq!(blocks.len(), count * ty.size());
        Source {
            path: path.to_path_buf(),
            ty,
            order,
            bytes: Bytes::Blocks(Box::new(blocks)),
            len: count,
        }
    }

    /// Whether the values are read as they lie in a memory map of the file (not decoded:
    /// block-decoded sources map the file too, but are not "mapped" in this sense).
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
        let size = self.ty.size();
        let all = match &self.bytes {
            Bytes::Map { map, offset } => &map[*offset..*offset + self.len * size],
            Bytes::Memory(b) => b.raw().2,
            Bytes::Shared(s) => &(*s.0).as_ref()[..self.len * size],
            Bytes::Blocks(b) => return b.for_bytes(range.start * size..range.end * size, size, f),
        };
        f(&all[range.start * size..range.end * size]);
        Ok(())
    }

    /// Stop counting the mapped pages of values `range` as this process's memory, and drop
    /// the decoded blocks of a block-decoded source there (nothing for decoded sources).
    /// Called behind sequential passes and between the renderer's random box reads
    /// (`Level::release_source`); the values stay readable.
    pub(crate) fn release(&self, range: Range<usize>) {
        let size = self.ty.size();
        match &self.bytes {
            Bytes::Map { map, offset } => {
                super::pages::dont_need(map, offset + range.start * size..offset + range.end * size)
            }
            Bytes::Blocks(b) => b.release(range.start * size..range.end * size),
            Bytes::Memory(_) | Bytes::Shared(_) => {}
        }
    }

    /// Finite range, non-finite count and (for 8/16-bit codes) histogram: the first pass.
    /// `None` when no value is finite; an error when the values cannot be read.
    pub(super) fn stats(&self) -> Result<Option<SourceStats>, VolumeError> {
        let (ty, order) = (self.ty, self.order);
        if let Some(codes) = small_codes(ty) {
            // Counts are integers: the split changes nothing in the result.
            let tables = self.par_fold(
                || vec![0u64; codes],
                |c, bytes| count_codes(ty, order, bytes, c),
            )?;
            let mut counts = vec![0u64; codes];
            for t in tables {
                for (c, k) in counts.iter_mut().zip(t) {
                    *c += k;
                }
            }
            return Ok(Some((code_stats(ty, &counts), Some(counts))));
        }
        // In index order: min/max of ±0 depend on the order, and `normalize` goes in it.
        let mut acc = MinMax::default();
        for block in blocks(self.len) {
            self.for_bytes(block.clone(), |b| {
                for_each_value(ty, order, b, |v| acc.add(v))
            })?;
            self.release(block);
        }
        if acc.norm_range().is_none() {
            return Ok(None);
        }
        Ok(Some((acc.stats(Vec::new()), None)))
    }

    /// Every value's bytes folded into one state per thread (made once by `init`), in blocks
    /// of [`BLOCK_VALUES`] released behind the pass; each thread folds a share of each block,
    /// in no particular order between threads.
    pub(super) fn par_fold<T: Send>(
        &self,
        init: impl Fn() -> T,
        fold: impl Fn(&mut T, &[u8]) + Sync,
    ) -> Result<Vec<T>, VolumeError> {
        use rayon::prelude::*;
        let threads = rayon::current_num_threads().max(1);
        let mut states: Vec<T> = (0..threads).map(|_| init()).collect();
        for block in blocks(self.len) {
            let share = block.len().div_ceil(threads);
            states
                .par_iter_mut()
                .enumerate()
                .try_for_each(|(t, state)| {
                    let s = (block.start + t * share).min(block.end);
                    let e = (s + share).min(block.end);
                    self.for_bytes(s..e, |b| fold(state, b))
                })?;
            self.release(block);
        }
        Ok(states)
    }
}

/// The ranges of [`BLOCK_VALUES`] values that cover `len` values.
fn blocks(len: usize) -> impl Iterator<Item = Range<usize>> {
    (0..len)
        .step_by(BLOCK_VALUES)
        .map(move |s| s..(s + BLOCK_VALUES).min(len))
}

/// What [`Source::stats`] finds: the statistics and, for 8/16-bit codes, each code's count.
pub(super) type SourceStats = (Stats, Option<Vec<u64>>);

/// Where a file's chosen array lies when its values can be read without decoding it whole
/// (`vti::locate`, `legacy::locate`).
pub(crate) struct Located {
    pub(crate) geometry: Geometry,
    /// The stored type (what the file declares).
    pub(crate) ty: ScalarType,
    pub(crate) order: ByteOrder,
    /// Number of values.
    pub(crate) count: usize,
    pub(crate) format: super::SourceFormat,
    pub(crate) at: At,
}

/// How the located values lie in the file.
pub(crate) enum At {
    /// Contiguous and uncompressed from this byte offset: mapped ([`Source::map`]).
    Offset(u64),
    /// In compressed blocks or base64 text: decoded block by block ([`Source::blocks`]).
    Blocks(Table),
}
