//! Headerless `.raw` arrays, x fastest, named in the Open SciVis style `NAME_XxYxZ_DTYPE.raw`.
//! Flags override the name; without a parsable name, `--dims` and `--dtype` are required.

use std::path::Path;

use super::{UnknownScalarType, VolumeError};

/// Why a raw file's name, flags or size do not give a readable array. Each message is one
/// line; [`VolumeError::file`] adds the file's path.
#[derive(Debug, thiserror::Error)]
pub(crate) enum RawError {
    /// A dimension in the name that does not fit in `usize`.
    #[error("dimension '{0}' in the file name is too large")]
    NameDimensionTooLarge(String),
    /// The name's type part is not a scalar type.
    #[error("file name: {0}")]
    NameType(UnknownScalarType),
    /// `--dims` given (or named) but no scalar type.
    #[error("the scalar type `dtype` is missing: the name does not give it (e.g. uint8)")]
    MissingDtype,
    /// `--dtype` given (or named) but no dimensions.
    #[error("the dimensions `dims` are missing: the name does not give them (X,Y,Z)")]
    MissingDims,
    /// Neither flags nor a parsable name.
    #[error(
        "name does not follow NAME_XxYxZ_DTYPE.raw (e.g. head_256x256x99_uint8.raw): give \
         `dims` (X,Y,Z) and `dtype`"
    )]
    NoLayout,
    /// A zero dimension.
    #[error("dimensions {}x{}x{} contain a zero", .0[0], .0[1], .0[2])]
    ZeroDimension([usize; 3]),
    /// Dimensions whose byte count overflows.
    #[error("dimensions {0:?} are too large")]
    TooLarge([usize; 3]),
    /// The file's size is not the array's.
    #[error(
        "file holds {len} bytes but {}x{}x{} {dtype} needs {need} bytes",
        .dims[0], .dims[1], .dims[2]
    )]
    SizeMismatch {
        /// The file's size in bytes.
        len: u64,
        /// Points per axis.
        dims: [usize; 3],
        /// The scalar type.
        dtype: ScalarType,
        /// The bytes the array needs.
        need: u64,
    },
}
use super::{ByteOrder, Decoded, Geometry, ReadOptions, ScalarType, SourceFormat, TypedBuffer};

/// Dims and scalar type from an Open SciVis file name, if it follows the pattern.
/// `Ok(None)`: the name has no `_XxYxZ_TYPE` tail; `Err`: it has one with a bad part.
pub(crate) fn parse_name(stem: &str) -> Result<Option<([usize; 3], ScalarType)>, RawError> {
    let mut parts = stem.rsplitn(3, '_');
    let (Some(dtype), Some(dims), Some(_name)) = (parts.next(), parts.next(), parts.next()) else {
        return Ok(None);
    };
    let fields: Vec<&str> = dims.split('x').collect();
    if fields.len() != 3
        || fields
            .iter()
            .any(|f| f.is_empty() || !f.bytes().all(|b| b.is_ascii_digit()))
    {
        return Ok(None);
    }
    let mut d = [0usize; 3];
    for (slot, f) in d.iter_mut().zip(&fields) {
        *slot = f
            .parse()
            .map_err(|_| RawError::NameDimensionTooLarge(f.to_string()))?;
    }
    let t = dtype.parse::<ScalarType>().map_err(RawError::NameType)?;
    Ok(Some((d, t)))
}

/// Dims and scalar type from the flags, else the file name.
pub(super) fn layout(
    path: &Path,
    opts: &ReadOptions,
) -> Result<([usize; 3], ScalarType), VolumeError> {
    layout_inner(path, opts).map_err(|e| VolumeError::file(path, e.to_string()))
}

fn layout_inner(path: &Path, opts: &ReadOptions) -> Result<([usize; 3], ScalarType), RawError> {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    let named = match parse_name(stem) {
        Ok(n) => n,
        // A bad name only matters when the flags do not replace what it would give.
        Err(e) if opts.dims.is_none() || opts.dtype.is_none() => return Err(e),
        Err(_) => None,
    };
    let dims = opts.dims.or(named.map(|n| n.0));
    let dtype = opts.dtype.or(named.map(|n| n.1));
    let (dims, dtype) = match (dims, dtype) {
        (Some(dims), Some(dtype)) => (dims, dtype),
        // One flag given: name the other rather than repeat the naming rule.
        (Some(_), None) => return Err(RawError::MissingDtype),
        (None, Some(_)) => return Err(RawError::MissingDims),
        (None, None) => return Err(RawError::NoLayout),
    };
    if dims.contains(&0) {
        return Err(RawError::ZeroDimension(dims));
    }
    Ok((dims, dtype))
}

/// Check that a file of `len` bytes holds exactly the array the name/flags describe. Run on
/// the file's size before reading it, so a wrong guess about a huge file fails at once.
pub fn check_size(path: &Path, opts: &ReadOptions, len: u64) -> Result<(), VolumeError> {
    let (dims, dtype) = layout(path, opts)?;
    let need = dims
        .iter()
        .try_fold(dtype.size() as u64, |acc, &d| acc.checked_mul(d as u64))
        .ok_or_else(|| VolumeError::file(path, RawError::TooLarge(dims).to_string()))?;
    if len != need {
        let e = RawError::SizeMismatch {
            len,
            dims,
            dtype,
            need,
        };
        return Err(VolumeError::file(path, e.to_string()));
    }
    Ok(())
}

/// The geometry, scalar type and byte order the name and flags give a raw file (its size
/// not checked): what [`decode`], the memory-mapped load and `summarize` all use.
pub(super) fn header(
    path: &Path,
    opts: &ReadOptions,
) -> Result<(Geometry, ScalarType, ByteOrder), VolumeError> {
    let (dims, dtype) = layout(path, opts)?;
    let geometry = Geometry {
        dims,
        spacing: opts.spacing.unwrap_or([1.0; 3]),
        origin: [0.0; 3],
    };
    Ok((
        geometry,
        dtype,
        opts.byte_order.unwrap_or(ByteOrder::Little),
    ))
}

/// Decode `bytes` (the whole file) as a raw array.
pub fn decode(path: &Path, bytes: Vec<u8>, opts: &ReadOptions) -> Result<Decoded, VolumeError> {
    check_size(path, opts, bytes.len() as u64)?;
    let (geometry, dtype, byte_order) = header(path, opts)?;
    Ok(Decoded {
        geometry,
        buffer: TypedBuffer::new(dtype, byte_order, bytes),
        format: SourceFormat::Raw {
            scalar_type: dtype,
            byte_order,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_scivis_names() {
        assert_eq!(
            parse_name("aneurism_256x256x256_uint8").unwrap(),
            Some(([256, 256, 256], ScalarType::U8))
        );
        assert_eq!(
            parse_name("my_big_head_3x4x5_float64").unwrap(),
            Some(([3, 4, 5], ScalarType::F64))
        );
        assert_eq!(parse_name("volume").unwrap(), None);
        assert_eq!(parse_name("a_b_c").unwrap(), None);
        assert_eq!(parse_name("a_4x4_uint8").unwrap(), None);
        let e = parse_name("a_4x4x4_uint9").unwrap_err().to_string();
        assert!(e.contains("uint9"), "{e}");
        assert!(parse_name("a_4x4x99999999999999999999999_uint8").is_err());
    }
}
