//! Level 0 of a `.vti` array stored in compressed blocks, or as base64 text, read from a
//! memory map of the file one block at a time, so volumes larger than memory can be read.
//!
//! VTK's binary layout (`vtkXMLWriter`, see [`super::vti_blocks`]) compresses an array in
//! blocks of `blocksize` bytes, each on its own, after a header `[nblocks, blocksize,
//! lastblocksize, csize_0 … csize_{n-1}]`: the header is a table from which any block can be
//! found and decompressed alone. [`table`] reads it once; [`Blocks`] decodes the blocks that
//! values are asked for through a small LRU cache ([`CACHE_BYTES`]), so a pass over a file of
//! any size holds a bounded amount of decoded data. Base64 text (appended or inline) maps
//! byte `o` of the encoded stream to characters `4·⌊o/3⌋…`, so a range of it decodes alone
//! too; uncompressed base64 data is cut into blocks of [`TEXT_BLOCK`] bytes the same way.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use base64::Engine;

use super::vti_blocks::{header_int, inflate, BlockError, Compressor, Layout};
use super::VolumeError;

/// Bytes of decoded blocks the cache holds at most (32 MiB: a thousand of VTK's default
/// 32 KiB blocks, enough for the rows of a brick batch and a slice of a large volume).
pub(crate) const CACHE_BYTES: usize = 32 << 20;

/// Largest block read block by block; files with larger blocks (one block for the whole
/// array, as some writers make) are decoded whole, where every read would decode it all.
pub(crate) const MAX_BLOCK: usize = 8 << 20;

/// Decoded bytes per block of uncompressed base64 data (a multiple of 3: whole characters).
const TEXT_BLOCK: usize = 3 << 18;

/// Where an array's data stream (after its header) lies in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Text {
    /// Raw bytes: byte `o` of the stream is the file's byte `start + o`.
    Raw { start: usize },
    /// Base64 text from character `start`: byte `o` of the data is byte `skip + o` of the
    /// decoded text (`skip` is the header's length when header and data share one stream,
    /// 0 when the data is a stream of its own).
    Base64 { start: usize, skip: usize },
}

/// The block table of an array, read from its header ([`table`]).
#[derive(Clone, Debug)]
pub(crate) struct Table {
    /// The array's name, for errors.
    array: String,
    /// How the reader words a block that does not decode, given the array's name and what is
    /// wrong (the words of its whole decode; the reader says, so this module needs none of
    /// its types).
    wording: fn(&str, String) -> String,
    data: Text,
    compressor: Compressor,
    /// Decoded bytes per block (the last may be shorter).
    block: usize,
    /// Decoded bytes of the array.
    total: usize,
    /// Compressed blocks: where each starts in the data stream, and the stream's end
    /// (`nblocks + 1` entries). Empty for uncompressed data.
    ends: Vec<u64>,
    /// One past the last file byte of the array (its last base64 character or raw byte).
    pub(crate) end: usize,
}

impl Table {
    fn blocks(&self) -> usize {
        self.total.div_ceil(self.block)
    }

    /// Decoded byte range of block `b`.
    fn span(&self, b: usize) -> Range<usize> {
        b * self.block..((b + 1) * self.block).min(self.total)
    }

    /// Data stream byte range of block `b`.
    fn stored(&self, b: usize) -> Range<usize> {
        if self.ends.is_empty() {
            return self.span(b);
        }
        self.ends[b] as usize..self.ends[b + 1] as usize
    }
}

/// The table of the binary array whose header starts at file byte (or base64 character)
/// `start` of `file`, holding `nbytes` bytes, laid out as `layout`. `None` when it cannot be
/// read block by block (a malformed header, blocks larger than [`MAX_BLOCK`], data past the
/// end of the file): the whole decode then reads it, or reports why it cannot.
pub(crate) fn table(
    file: &[u8],
    start: usize,
    base64: bool,
    layout: Layout,
    nbytes: usize,
    array: &str,
    wording: fn(&str, String) -> String,
) -> Option<Table> {
    let h = layout.header_size;
    let header = Text::Base64 { start, skip: 0 };
    let int = |i: usize| -> Option<usize> {
        let at = i * h;
        let bytes = if base64 {
            stream(file, header, at, h).ok()?
        } else {
            Cow::Borrowed(file.get(start.checked_add(at)?..)?.get(..h)?)
        };
        header_int(&bytes, 0, layout).ok()
    };
    let (block, ends, header_len) = if layout.compressor == Compressor::None {
        if int(0)? != nbytes {
            return None;
        }
        (TEXT_BLOCK, Vec::new(), h)
    } else {
        let (nblocks, block, last) = (int(0)?, int(1)?, int(2)?);
        // The checks of `unpack`: the blocks hold exactly the array.
        let total = match nblocks {
            0 => 0,
            _ => (nblocks - 1)
                .checked_mul(block)?
                .checked_add(if last == 0 { block } else { last })?,
        };
        if total != nbytes || nbytes == 0 || block > MAX_BLOCK || block == 0 {
            return None;
        }
        if last > block {
            return None;
        }
        let header_len = nblocks.checked_add(3)?.checked_mul(h)?;
        // The header must fit in what follows `start`, before it is read into a table.
        if header_len > file.len().saturating_sub(start) {
            return None;
        }
        let header_bytes = if base64 {
            stream(file, header, 0, header_len).ok()?
        } else {
            Cow::Borrowed(&file[start..start + header_len])
        };
        let mut ends = Vec::with_capacity(nblocks + 1);
        let mut at = 0u64;
        ends.push(0);
        for b in 0..nblocks {
            at = at.checked_add(header_int(&header_bytes, (3 + b) * h, layout).ok()? as u64)?;
            ends.push(at);
        }
        (block, ends, header_len)
    };
    let stored = ends.last().map_or(nbytes, |&e| e as usize);
    let (data, end) = if base64 {
        // One stream (header and data encoded together) or two (each padded): a header whose
        // length is not a multiple of 3 ends in '=' when it is a stream of its own.
        let last_quad = start + 4 * ((header_len - 1) / 3);
        let own = file.get(last_quad..last_quad + 4)?.ends_with(b"=");
        let (s, skip) = if own || header_len.is_multiple_of(3) {
            (start + 4 * header_len.div_ceil(3), 0)
        } else {
            (start, header_len)
        };
        let chars = skip.checked_add(stored)?.div_ceil(3).checked_mul(4)?;
        (Text::Base64 { start: s, skip }, s.checked_add(chars)?)
    } else {
        let s = start + header_len;
        (Text::Raw { start: s }, s.checked_add(stored)?)
    };
    if end > file.len() {
        return None;
    }
    Some(Table {
        array: array.to_string(),
        wording,
        data,
        compressor: layout.compressor,
        block,
        total: nbytes,
        ends,
        end,
    })
}

/// Bytes `at..at + len` of the data stream `text` of `file`.
fn stream(file: &[u8], text: Text, at: usize, len: usize) -> Result<Cow<'_, [u8]>, BlockError> {
    let short = || BlockError::StreamShort { end: at + len };
    match text {
        Text::Raw { start } => {
            let s = start.checked_add(at).ok_or_else(short)?;
            let bytes = file.get(s..s.checked_add(len).ok_or_else(short)?);
            bytes.map(Cow::Borrowed).ok_or_else(short)
        }
        Text::Base64 { start, skip } => {
            let (first, last) = ((skip + at) / 3, (skip + at + len).div_ceil(3));
            let chars = file
                .get(start + 4 * first..start + 4 * last)
                .ok_or_else(short)?;
            let mut out = Vec::with_capacity(3 * (last - first));
            base64::engine::general_purpose::STANDARD
                .decode_vec(chars, &mut out)
                .map_err(BlockError::Base64)?;
            let from = skip + at - 3 * first;
            if out.len() < from + len {
                return Err(short());
            }
            out.truncate(from + len);
            out.drain(..from);
            Ok(Cow::Owned(out))
        }
    }
}

/// A `.vti` array read block by block from a memory map of its file.
pub(crate) struct Blocks {
    path: PathBuf,
    map: memmap2::Mmap,
    table: Table,
    cache: Mutex<Cache>,
}

impl std::fmt::Debug for Blocks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Blocks")
            .field("path", &self.path)
            .field("table", &self.table)
            .finish_non_exhaustive()
    }
}

impl Blocks {
    /// The array `table` describes in `map`, the file at `path` (named in errors).
    pub(crate) fn new(path: &Path, map: memmap2::Mmap, table: Table) -> Blocks {
        Blocks {
            path: path.to_path_buf(),
            map,
            table,
            cache: Mutex::new(Cache::new(CACHE_BYTES)),
        }
    }

    /// Decoded bytes of the array.
    pub(crate) fn len(&self) -> usize {
        self.table.total
    }

    /// Block `b`, decoded (without the cache).
    fn decode(&self, b: usize) -> Result<Vec<u8>, BlockError> {
        let t = &self.table;
        let stored = t.stored(b);
        let input = stream(&self.map, t.data, stored.start, stored.len())?;
        if t.compressor == Compressor::None {
            return Ok(input.into_owned());
        }
        let mut out = vec![0u8; t.span(b).len()];
        inflate(t.compressor, &input, &mut out).map_err(|error| BlockError::Inflate {
            block: b,
            nblocks: t.blocks(),
            error,
        })?;
        Ok(out)
    }

    /// Block `b`, from the cache or decoded (and cached). The message names the file, the
    /// array and the block, as the whole decode does.
    fn block(&self, b: usize) -> Result<Arc<Vec<u8>>, VolumeError> {
        if let Some(d) = self.lock().get(b) {
            return Ok(d);
        }
        // Decoded outside the lock: other threads decode their blocks meanwhile.
        let data = Arc::new(self.decode(b).map_err(|e| self.error(b, e))?);
        self.lock().insert(b, data.clone());
        Ok(data)
    }

    fn error(&self, b: usize, e: BlockError) -> VolumeError {
        // An uncompressed stream's errors (base64) name the block here; compressed ones do.
        let e = match e {
            e @ BlockError::Inflate { .. } => e.to_string(),
            e => format!("block {b} of {}: {e}", self.table.blocks()),
        };
        VolumeError::file(&self.path, (self.table.wording)(&self.table.array, e))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Cache> {
        // The cache is consistent between calls: a panic elsewhere leaves it usable.
        self.cache.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Hand decoded bytes `range` (whole values of `size` bytes) to `f` in order, in pieces of
    /// whole values; a value split by a block boundary is joined in a small buffer. Ranges
    /// over several blocks decode them in parallel, half the cache's budget at a time.
    pub(crate) fn for_bytes(
        &self,
        range: Range<usize>,
        size: usize,
        mut f: impl FnMut(&[u8]),
    ) -> Result<(), VolumeError> {
        if range.is_empty() {
            return Ok(());
        }
        let block = self.table.block;
        let (first, last) = (range.start / block, (range.end - 1) / block);
        if first == last {
            // One block: the renderer's box reads come here row by row, so no list and no
            // carry (a range inside one block holds whole values).
            let data = self.block(first)?;
            let at = first * block;
            f(&data[range.start - at..range.end - at]);
            return Ok(());
        }
        let window = (CACHE_BYTES / 2 / block).max(1);
        let mut carry = [0u8; 16];
        let mut held = 0;
        for w in (first..=last).step_by(window) {
            let ids = w..(w + window).min(last + 1);
            let decoded: Vec<Arc<Vec<u8>>> = if ids.len() > 1 {
                use rayon::prelude::*;
                ids.clone()
                    .into_par_iter()
                    .map(|b| self.block(b))
                    .collect::<Result<_, _>>()?
            } else {
                vec![self.block(ids.start)?]
            };
            for (b, data) in ids.zip(decoded) {
                let at = b * block;
                let lo = range.start.max(at) - at;
                let hi = range.end.min(at + data.len()) - at;
                let mut piece = &data[lo..hi];
                if held > 0 {
                    let take = (size - held).min(piece.len());
                    carry[held..held + take].copy_from_slice(&piece[..take]);
                    held += take;
                    piece = &piece[take..];
                    if held == size {
                        f(&carry[..size]);
                        held = 0;
                    }
                }
                let whole = piece.len() / size * size;
                if whole > 0 {
                    f(&piece[..whole]);
                }
                let rest = &piece[whole..];
                carry[held..held + rest.len()].copy_from_slice(rest);
                held += rest.len();
            }
        }
        debug_assert_eq!(held, 0, "ranges are whole values");
        Ok(())
    }

    /// Drop the cached blocks that decoded bytes `range` ends (from the one holding its first
    /// byte to the last that ends inside it; not for the whole array, below) and stop counting
    /// the mapped pages of their stored bytes as this process's memory (`MADV_DONTNEED`). A
    /// forward pass releases each block once it is past it, the block it straddles between two
    /// ranges included; a reader that comes back decodes it again.
    pub(crate) fn release(&self, range: Range<usize>) {
        if range.is_empty() {
            return;
        }
        let block = self.table.block;
        let first = range.start / block;
        let end = match range.end >= self.table.total {
            true => self.table.blocks(),
            false => range.end / block,
        };
        if first >= end {
            return;
        }
        // The whole array is released between the renderer's random box reads: the cache
        // (bounded by its budget) stays for the next batch's rows, whose blocks it mostly
        // holds; emptying it there makes a level-0 render of a 512³ zlib file about a third
        // slower. Partial ranges are a forward pass: it is past them.
        if range.start > 0 || range.end < self.table.total {
            self.lock().remove(first..end);
        }
        let (s, e) = (
            self.table.stored(first).start,
            self.table.stored(end - 1).end,
        );
        let (s, e) = match self.table.data {
            Text::Raw { start } => (start + s, start + e),
            Text::Base64 { start, skip } => {
                (start + 4 * (skip + s) / 3, start + 4 * (skip + e) / 3)
            }
        };
        super::pages::dont_need(&self.map, s..e);
    }

    /// Bytes of decoded blocks the cache holds.
    #[cfg(test)]
    fn cached_bytes(&self) -> usize {
        self.lock().bytes
    }
}

/// Decoded blocks, least recently used dropped first, holding at most `budget` bytes.
struct Cache {
    budget: usize,
    bytes: usize,
    clock: u64,
    blocks: HashMap<usize, (u64, Arc<Vec<u8>>)>,
    /// Last use → block.
    order: BTreeMap<u64, usize>,
}

impl Cache {
    fn new(budget: usize) -> Cache {
        Cache {
            budget,
            bytes: 0,
            clock: 0,
            blocks: HashMap::new(),
            order: BTreeMap::new(),
        }
    }

    fn get(&mut self, b: usize) -> Option<Arc<Vec<u8>>> {
        let (used, data) = self.blocks.get_mut(&b)?;
        self.order.remove(used);
        self.clock += 1;
        *used = self.clock;
        self.order.insert(self.clock, b);
        Some(data.clone())
    }

    /// Keep `data` as block `b`, dropping the least recently used blocks to make room; a block
    /// larger than the budget is not kept.
    fn insert(&mut self, b: usize, data: Arc<Vec<u8>>) {
        if data.len() > self.budget || self.blocks.contains_key(&b) {
            return;
        }
        while self.bytes + data.len() > self.budget {
            let Some((_, old)) = self.order.pop_first() else {
                break;
            };
            if let Some((_, d)) = self.blocks.remove(&old) {
                self.bytes -= d.len();
            }
        }
        self.clock += 1;
        self.bytes += data.len();
        self.order.insert(self.clock, b);
        self.blocks.insert(b, (self.clock, data));
    }

    fn remove(&mut self, range: Range<usize>) {
        let gone: Vec<usize> = self
            .blocks
            .keys()
            .copied()
            .filter(|b| range.contains(b))
            .collect();
        for b in gone {
            if let Some((used, d)) = self.blocks.remove(&b) {
                self.order.remove(&used);
                self.bytes -= d.len();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cache_holds_at_most_its_budget_least_recent_out_first() {
        let mut c = Cache::new(100);
        for b in 0..10 {
            c.insert(b, Arc::new(vec![b as u8; 30]));
            assert!(c.bytes <= 100, "{}", c.bytes);
        }
        // Three of 30 bytes fit: 7, 8, 9.
        assert_eq!(c.bytes, 90);
        assert!(c.get(6).is_none() && c.get(7).is_some());
        c.insert(10, Arc::new(vec![0; 30]));
        // 8 was the least recently used (7 was just read).
        assert!(c.get(8).is_none() && c.get(7).is_some() && c.get(9).is_some());
        c.insert(11, Arc::new(vec![0; 101]));
        assert!(c.get(11).is_none(), "larger than the budget: not kept");
        c.remove(0..10);
        assert_eq!(c.bytes, 30);
        assert!(c.get(10).is_some());
        assert_eq!(c.order.len(), c.blocks.len());
    }

    /// Compressed blocks of `block` bytes as VTK lays them out (zlib, UInt32 headers).
    fn vtk_zlib(data: &[u8], block: usize) -> Vec<u8> {
        use std::io::Write;
        let chunks: Vec<Vec<u8>> = data
            .chunks(block)
            .map(|c| {
                let mut z = flate2::write::ZlibEncoder::new(Vec::new(), Default::default());
                z.write_all(c).unwrap();
                z.finish().unwrap()
            })
            .collect();
        let last = data.len() % block;
        let mut out = Vec::new();
        for v in [chunks.len(), block, last] {
            out.extend((v as u32).to_le_bytes());
        }
        for c in &chunks {
            out.extend((c.len() as u32).to_le_bytes());
        }
        for c in &chunks {
            out.extend(c);
        }
        out
    }

    fn blocks_of(file: Vec<u8>, base64: bool, compressor: Compressor, n: usize) -> Blocks {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.bin");
        std::fs::write(&path, &file).unwrap();
        let f = std::fs::File::open(&path).unwrap();
        let map = unsafe { memmap2::Mmap::map(&f) }.unwrap();
        let layout = Layout {
            order: super::super::ByteOrder::Little,
            header_size: 4,
            compressor,
        };
        let t = table(&map, 0, base64, layout, n, "a", |a, m| {
            format!("array '{a}': {m}")
        })
        .unwrap();
        assert_eq!(t.end, file.len());
        Blocks::new(&path, map, t)
    }

    /// A pass over many blocks: the pieces join to the data (values of 3 bytes across
    /// 1000-byte blocks), and the cache never holds more than its budget.
    #[test]
    fn pieces_join_to_the_data_and_the_cache_stays_bounded() {
        let data: Vec<u8> = (0..3_000_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let b = blocks_of(vtk_zlib(&data, 1000), false, Compressor::Zlib, data.len());
        let mut got = Vec::new();
        let mut peak = 0;
        for s in (0..data.len()).step_by(3 * 40_000) {
            let r = s..(s + 3 * 40_000).min(data.len());
            b.for_bytes(r.clone(), 3, |p| {
                assert_eq!(p.len() % 3, 0);
                got.extend_from_slice(p);
            })
            .unwrap();
            peak = peak.max(b.cached_bytes());
            b.release(r);
        }
        assert!(got == data);
        assert!(peak > 0 && peak <= CACHE_BYTES, "{peak}");
        assert_eq!(b.cached_bytes(), 0, "released behind the pass");
        // Odd ranges.
        for (s, e) in [(999, 1002), (3, 6), (2_999_997, 3_000_000), (0, 3_000_000)] {
            let mut got = Vec::new();
            b.for_bytes(s..e, 3, |p| got.extend_from_slice(p)).unwrap();
            assert!(got == data[s..e], "{s}..{e}");
        }
    }

    /// Base64 as VTK writes it: header and data as two padded streams, or as one.
    #[test]
    fn base64_in_one_or_two_streams() {
        let e = base64::engine::general_purpose::STANDARD;
        let data: Vec<u8> = (0..5_000_000u32).map(|i| (i % 253) as u8).collect();
        let len = (data.len() as u32).to_le_bytes();
        let two = format!("{}{}", e.encode(len), e.encode(&data));
        let one = e.encode([&len[..], &data].concat());
        for text in [two, one] {
            let b = blocks_of(text.into_bytes(), true, Compressor::None, data.len());
            let mut got = Vec::new();
            b.for_bytes(7..4_999_999, 1, |p| got.extend_from_slice(p))
                .unwrap();
            assert!(got == data[7..4_999_999]);
        }
        let z = vtk_zlib(&data, 32768);
        let (h, rest) = z.split_at(4 * (3 + data.len().div_ceil(32768)));
        let two = format!("{}{}", e.encode(h), e.encode(rest));
        let b = blocks_of(two.into_bytes(), true, Compressor::Zlib, data.len());
        let mut got = Vec::new();
        b.for_bytes(0..data.len(), 1, |p| got.extend_from_slice(p))
            .unwrap();
        assert!(got == data);
    }

    #[test]
    fn a_corrupt_block_is_an_error_naming_it() {
        let data = vec![5u8; 10_000];
        let mut z = vtk_zlib(&data, 1000);
        let n = z.len();
        z[n - 5] ^= 0xff; // inside the last block's stream
        let b = blocks_of(z, false, Compressor::Zlib, data.len());
        b.for_bytes(0..1000, 1, |_| {}).unwrap();
        let e = b.for_bytes(0..10_000, 1, |_| {}).unwrap_err().to_string();
        assert!(e.contains("array 'a': block 9 of 10"), "{e}");
        assert!(e.contains("b.bin"), "{e}");
    }
}
