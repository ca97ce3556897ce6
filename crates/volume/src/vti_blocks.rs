//! Binary arrays of VTK XML files (inline base64 or appended data), uncompressed or in
//! compressed blocks.
//!
//! Binary layout (VTK's `vtkXMLWriter`): an uncompressed array is `[nbytes]` then the bytes; a
//! compressed one is `[nblocks, blocksize, lastblocksize, csize_0 … csize_{n-1}]` then the
//! blocks, each compressed on its own (zlib stream, raw LZ4 block, or `.xz` stream for LZMA).
//! Header integers have the file's `header_type` (UInt32 when absent) and byte order. Inline
//! base64 encodes header and data either as one stream or as two padded streams, so base64 is
//! decoded stream by stream (see [`base64_streams`]).

use base64::Engine;

use super::Budget;
use super::ByteOrder;

/// Why a binary array's bytes could not be decoded. Each message is one line; the reader adds
/// the file and array names.
#[derive(Debug, thiserror::Error)]
pub(super) enum BlockError {
    #[error("base64 data has {chars} characters, not a multiple of 4 (truncated?)")]
    Base64Length { chars: usize },
    #[error("invalid base64 data: {0}")]
    Base64(base64::DecodeError),
    #[error("the data ends inside its block header (truncated?)")]
    HeaderTruncated,
    #[error("header value {value} is too large")]
    HeaderValueTooLarge { value: u64 },
    #[error("its header says {declared} bytes but the extent needs {needed}")]
    LengthMismatch { declared: usize, needed: usize },
    #[error("needs {declared} bytes but only {available} follow its header (truncated?)")]
    DataTruncated { declared: usize, available: usize },
    /// Only where the data stream is shorter than its block table says (`blocks::Blocks`).
    #[error("the data ends before byte {end} (truncated?)")]
    StreamShort { end: usize },
    #[error("block header sizes overflow")]
    BlockSizesOverflow,
    #[error("its block header says {declared} bytes but the extent needs {needed}")]
    BlockTotalMismatch { declared: usize, needed: usize },
    /// The declared size does not fit in memory.
    #[error(transparent)]
    Memory(#[from] t2tf_core::memory::MemoryError),
    #[error("compressed block {block} of {nblocks} is cut short (truncated?)")]
    BlockTruncated { block: usize, nblocks: usize },
    /// The inflate error is part of the message (not a `source`), like every reader message.
    #[error("block {block} of {nblocks}: {error}")]
    Inflate {
        block: usize,
        nblocks: usize,
        error: InflateError,
    },
}

/// Why one compressed block could not be decompressed.
#[derive(Debug, thiserror::Error)]
pub(super) enum InflateError {
    #[error("uncompressed data has no blocks")]
    NotCompressed,
    #[error("zlib: {0}")]
    Zlib(flate2::DecompressError),
    #[error("zlib stream does not end within {want} bytes")]
    ZlibNotEnded { want: usize },
    #[error("lz4: {0}")]
    Lz4(lz4_flex::block::DecompressError),
    #[error("lzma: decompresses to more than {want} bytes")]
    LzmaTooLong { want: usize },
    #[error("lzma: {0}")]
    Lzma(std::io::Error),
    #[error("decompressed to {got} bytes, expected {want}")]
    WrongSize { got: usize, want: usize },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Compressor {
    None,
    Zlib,
    Lz4,
    Lzma,
}

/// How binary arrays are laid out in this file.
#[derive(Clone, Copy, Debug)]
pub(super) struct Layout {
    pub order: ByteOrder,
    pub header_size: usize,
    pub compressor: Compressor,
}

/// Decode base64 text that may be several padded streams back to back (VTK encodes the
/// header and the data of a compressed array separately). Whitespace is ignored.
pub(super) fn base64_streams(text: &[u8]) -> Result<Vec<u8>, BlockError> {
    let clean: Vec<u8> = text
        .iter()
        .copied()
        .filter(|b| !b.is_ascii_whitespace())
        .collect();
    if !clean.len().is_multiple_of(4) {
        return Err(BlockError::Base64Length { chars: clean.len() });
    }
    let engine = base64::engine::general_purpose::STANDARD;
    let mut out = Vec::with_capacity(clean.len() / 4 * 3);
    let mut start = 0;
    for g in (0..clean.len()).step_by(4) {
        if clean[g + 3] == b'=' {
            engine
                .decode_vec(&clean[start..g + 4], &mut out)
                .map_err(BlockError::Base64)?;
            start = g + 4;
        }
    }
    engine
        .decode_vec(&clean[start..], &mut out)
        .map_err(BlockError::Base64)?;
    Ok(out)
}

/// One header integer at `at`.
pub(super) fn header_int(stream: &[u8], at: usize, layout: Layout) -> Result<usize, BlockError> {
    let h = layout.header_size;
    let b = stream.get(at..at + h).ok_or(BlockError::HeaderTruncated)?;
    let v = match (h, layout.order) {
        (4, ByteOrder::Little) => u32::from_le_bytes(b.try_into().expect("4 bytes")) as u64,
        (4, ByteOrder::Big) => u32::from_be_bytes(b.try_into().expect("4 bytes")) as u64,
        (_, ByteOrder::Little) => u64::from_le_bytes(b.try_into().expect("8 bytes")),
        (_, ByteOrder::Big) => u64::from_be_bytes(b.try_into().expect("8 bytes")),
    };
    usize::try_from(v).map_err(|_| BlockError::HeaderValueTooLarge { value: v })
}

/// Header + (compressed) blocks → exactly `nbytes` of array data.
pub(super) fn unpack(
    stream: &[u8],
    layout: Layout,
    nbytes: usize,
    budget: Budget,
) -> Result<Vec<u8>, BlockError> {
    let h = layout.header_size;
    if layout.compressor == Compressor::None {
        let len = header_int(stream, 0, layout)?;
        if len != nbytes {
            return Err(BlockError::LengthMismatch {
                declared: len,
                needed: nbytes,
            });
        }
        let data = stream
            .get(h..h + len)
            .ok_or_else(|| BlockError::DataTruncated {
                declared: len,
                available: stream.len().saturating_sub(h),
            })?;
        return Ok(data.to_vec());
    }

    let nblocks = header_int(stream, 0, layout)?;
    let block = header_int(stream, h, layout)?;
    let last = header_int(stream, 2 * h, layout)?;
    let total = match nblocks {
        0 => 0,
        _ => (nblocks - 1)
            .checked_mul(block)
            .and_then(|t| t.checked_add(if last == 0 { block } else { last }))
            .ok_or(BlockError::BlockSizesOverflow)?,
    };
    if total != nbytes {
        return Err(BlockError::BlockTotalMismatch {
            declared: total,
            needed: nbytes,
        });
    }
    budget.check(
        "the array's decompressed data",
        u64::try_from(total).ok(),
        1,
        "the file declares more data than fits",
    )?;
    let mut sizes = Vec::with_capacity(nblocks.min(1 << 20));
    for b in 0..nblocks {
        sizes.push(header_int(stream, (3 + b) * h, layout)?);
    }
    let mut pos = (3 + nblocks) * h;
    let mut out = vec![0u8; total];
    for (b, &csize) in sizes.iter().enumerate() {
        let input = stream
            .get(pos..pos.saturating_add(csize))
            .ok_or(BlockError::BlockTruncated { block: b, nblocks })?;
        pos += csize;
        let start = b * block;
        let dst = &mut out[start..(start + block).min(total)];
        inflate(layout.compressor, input, dst).map_err(|error| BlockError::Inflate {
            block: b,
            nblocks,
            error,
        })?;
    }
    Ok(out)
}

/// The largest LZMA dictionary a block may declare: VTK's presets use at most 64 MiB, and a
/// hostile header could otherwise make the decoder allocate gigabytes before any output.
const LZMA_DICT_LIMIT_KIB: u32 = 64 * 1024;

/// Read `reader` into `dst` and one byte past it: the bytes it gave, or `None` when it has
/// more than `dst` holds. The decoder streams, so a small input that expands without limit
/// costs `dst` and nothing more.
fn read_bounded(mut reader: impl std::io::Read, dst: &mut [u8]) -> std::io::Result<Option<usize>> {
    let mut len = 0;
    while len < dst.len() {
        match reader.read(&mut dst[len..]) {
            Ok(0) => return Ok(Some(len)),
            Ok(n) => len += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    // Full: the stream must end here (this read also checks its integrity).
    let mut more = [0u8; 1];
    loop {
        match reader.read(&mut more) {
            Ok(0) => return Ok(Some(len)),
            Ok(_) => return Ok(None),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
}

/// Decompress one block into exactly `dst.len()` bytes.
pub(super) fn inflate(c: Compressor, input: &[u8], dst: &mut [u8]) -> Result<(), InflateError> {
    let want = dst.len();
    let got = match c {
        Compressor::None => return Err(InflateError::NotCompressed),
        Compressor::Zlib => {
            let mut z = flate2::Decompress::new(true);
            let status = z
                .decompress(input, dst, flate2::FlushDecompress::Finish)
                .map_err(InflateError::Zlib)?;
            if status != flate2::Status::StreamEnd {
                return Err(InflateError::ZlibNotEnded { want });
            }
            z.total_out() as usize
        }
        Compressor::Lz4 => {
            lz4_flex::block::decompress_into(input, dst).map_err(InflateError::Lz4)?
        }
        Compressor::Lzma => {
            // VTK's LZMA compressor writes .xz streams (lzma_easy_buffer_encode), decoded as
            // a stream into the declared size: a small stream can expand without limit.
            let xz = lzma_rust2::XzReader::new_mem_limit(input, false, LZMA_DICT_LIMIT_KIB);
            read_bounded(xz, dst)
                .map_err(InflateError::Lzma)?
                .ok_or(InflateError::LzmaTooLong { want })?
        }
    };
    if got != want {
        return Err(InflateError::WrongSize { got, want });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_concatenated_streams_decode_like_one() {
        let e = base64::engine::general_purpose::STANDARD;
        let (a, b) = (b"head1".as_slice(), b"the data!!".as_slice());
        let two = format!("{}\n  {}", e.encode(a), e.encode(b));
        assert_eq!(base64_streams(two.as_bytes()).unwrap(), [a, b].concat());
        let one = e.encode([a, b].concat());
        assert_eq!(base64_streams(one.as_bytes()).unwrap(), [a, b].concat());
        assert!(base64_streams(b"abc").is_err());
        assert!(base64_streams(b"a*cd").is_err());
    }

    #[test]
    fn header_int_reads_both_sizes_and_orders() {
        let l = |order, header_size| Layout {
            order,
            header_size,
            compressor: Compressor::None,
        };
        let s = [1u8, 0, 0, 0, 0, 0, 0, 2];
        assert_eq!(header_int(&s, 0, l(ByteOrder::Little, 4)).unwrap(), 1);
        assert_eq!(header_int(&s, 0, l(ByteOrder::Big, 4)).unwrap(), 1 << 24);
        assert_eq!(header_int(&s, 4, l(ByteOrder::Big, 4)).unwrap(), 2);
        assert_eq!(
            header_int(&s, 0, l(ByteOrder::Big, 8)).unwrap(),
            (1 << 56) + 2
        );
        assert!(header_int(&s, 4, l(ByteOrder::Little, 8)).is_err());
    }

    /// `data` as an .xz stream (VTK's default is preset 6; the lower ones encode faster).
    fn xz_preset(data: &[u8], preset: u32) -> Vec<u8> {
        use std::io::Write;
        let opts = lzma_rust2::XzOptions::with_preset(preset);
        let mut w = lzma_rust2::XzWriter::new(Vec::new(), opts).unwrap();
        w.write_all(data).unwrap();
        w.finish().unwrap()
    }

    fn xz(data: &[u8]) -> Vec<u8> {
        xz_preset(data, 6)
    }

    #[test]
    fn lzma_round_trips_and_refuses_corruption() {
        let data: Vec<u8> = (0..100_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let packed = xz(&data);
        let mut dst = vec![0u8; data.len()];
        inflate(Compressor::Lzma, &packed, &mut dst).unwrap();
        assert_eq!(dst, data);
        // Shorter than declared.
        let mut long = vec![0u8; data.len() + 1];
        assert!(inflate(Compressor::Lzma, &packed, &mut long).is_err());
        // A flipped byte in the middle: an error, never a panic.
        let mut bad = packed.clone();
        let mid = bad.len() / 2;
        bad[mid] ^= 0x55;
        assert!(inflate(Compressor::Lzma, &bad, &mut dst).is_err());
    }

    /// An expansion far past the declared size is read only as far as the declared size:
    /// the decoder consumes a sliver of the stream and never makes the rest.
    #[test]
    fn lzma_bomb_is_read_only_to_the_declared_size() {
        struct Counting<'a>(&'a [u8], std::rc::Rc<std::cell::Cell<usize>>);
        impl std::io::Read for Counting<'_> {
            fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
                let n = self.0.read(buf)?;
                self.1.set(self.1.get() + n);
                Ok(n)
            }
        }
        // 64 MiB of pseudo-random bytes from a short repeating pattern compress to little.
        let pattern: Vec<u8> = (0..4096u32)
            .map(|i| ((i * 2654435761) >> 13) as u8)
            .collect();
        let bomb = xz_preset(&pattern.repeat(1 << 14), 0);
        let mut dst = vec![0u8; 512];
        let read = std::rc::Rc::new(std::cell::Cell::new(0));
        let reader = lzma_rust2::XzReader::new(Counting(&bomb, read.clone()), false);
        assert_eq!(read_bounded(reader, &mut dst).unwrap(), None);
        assert_eq!(&dst[..], &pattern[..512]);
        assert!(
            read.get() * 10 < bomb.len(),
            "read {} of {} bytes",
            read.get(),
            bomb.len()
        );
    }

    #[test]
    fn lzma_stops_at_the_declared_size() {
        // A small stream that expands to 1 MiB, declared as 512 bytes.
        let xz = xz_preset(&vec![0u8; 1 << 20], 0);
        let mut dst = vec![0u8; 512];
        let e = inflate(Compressor::Lzma, &xz, &mut dst)
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than 512 bytes"), "{e}");
    }
}
