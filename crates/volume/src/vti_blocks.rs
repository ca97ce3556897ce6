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
// Alike in shape to VtiError (thiserror variants): these are the binary blocks' errors, which
// vti.rs wraps with the array's name; kept apart so the block decoder stands alone.
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
    Lzma(lzma_rs::error::Error),
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

/// A writer into a fixed slice that fails (and notes it) once more than fits is written.
struct Bounded<'a> {
    dst: &'a mut [u8],
    len: usize,
    over: bool,
}

impl std::io::Write for Bounded<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let Some(room) = self.dst.get_mut(self.len..self.len + buf.len()) else {
            self.over = true;
            return Err(std::io::Error::other("more data than declared"));
        };
        room.copy_from_slice(buf);
        self.len += buf.len();
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
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
            // VTK's LZMA compressor writes .xz streams (lzma_easy_buffer_encode).
            // Bounded by the declared size: a small stream can expand without limit.
            let mut out = Bounded {
                dst,
                len: 0,
                over: false,
            };
            let r = lzma_rs::xz_decompress(&mut std::io::Cursor::new(input), &mut out);
            if out.over {
                return Err(InflateError::LzmaTooLong { want });
            }
            r.map_err(InflateError::Lzma)?;
            out.len
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

    #[test]
    fn lzma_stops_at_the_declared_size() {
        // A small stream that expands to 1 MiB, declared as 512 bytes.
        let mut xz = Vec::new();
        lzma_rs::xz_compress(&mut &vec![0u8; 1 << 20][..], &mut xz).unwrap();
        let mut dst = vec![0u8; 512];
        let e = inflate(Compressor::Lzma, &xz, &mut dst)
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than 512 bytes"), "{e}");
    }
}
