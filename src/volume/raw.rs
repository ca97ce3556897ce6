//! Headerless `.raw` arrays, x fastest, named in the Open SciVis style `NAME_XxYxZ_DTYPE.raw`.
//! Flags override the name; without a parsable name, `--dims` and `--dtype` are required.

use std::path::Path;

use super::VolumeError;
use super::{ByteOrder, Decoded, Geometry, ReadOptions, ScalarType, SourceFormat, TypedBuffer};

/// Dims and scalar type from an Open SciVis file name, if it follows the pattern.
/// `Ok(None)`: the name has no `_XxYxZ_TYPE` tail; `Err`: it has one with a bad part.
pub fn parse_name(stem: &str) -> Result<Option<([usize; 3], ScalarType)>, String> {
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
            .map_err(|_| format!("dimension '{f}' in the file name is too large"))?;
    }
    let t = dtype
        .parse::<ScalarType>()
        .map_err(|e| format!("file name: {e}"))?;
    Ok(Some((d, t)))
}

/// Dims and scalar type from the flags, else the file name.
pub(super) fn layout(
    path: &Path,
    opts: &ReadOptions,
) -> Result<([usize; 3], ScalarType), VolumeError> {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    let named = match parse_name(stem) {
        Ok(n) => n,
        // A bad name only matters when the flags do not replace what it would give.
        Err(e) if opts.dims.is_none() || opts.dtype.is_none() => {
            return Err(VolumeError::file(path, e))
        }
        Err(_) => None,
    };
    let dims = opts.dims.or(named.map(|n| n.0));
    let dtype = opts.dtype.or(named.map(|n| n.1));
    let (dims, dtype) = match (dims, dtype) {
        (Some(dims), Some(dtype)) => (dims, dtype),
        // One flag given: name the other rather than repeat the naming rule.
        (Some(_), None) => {
            return Err(VolumeError::file(
                path,
                "--dtype TYPE is missing: the name does not give the scalar type \
                 (e.g. --dtype uint8)",
            ))
        }
        (None, Some(_)) => {
            return Err(VolumeError::file(
                path,
                "--dims X,Y,Z is missing: the name does not give the dimensions",
            ))
        }
        (None, None) => {
            return Err(VolumeError::file(
                path,
                "name does not follow NAME_XxYxZ_DTYPE.raw (e.g. head_256x256x99_uint8.raw): \
                 give --dims X,Y,Z and --dtype TYPE",
            ))
        }
    };
    if dims.contains(&0) {
        return Err(VolumeError::file(
            path,
            format!(
                "dimensions {}x{}x{} contain a zero",
                dims[0], dims[1], dims[2]
            ),
        ));
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
        .ok_or_else(|| VolumeError::file(path, format!("dimensions {dims:?} are too large")))?;
    if len != need {
        return Err(VolumeError::file(
            path,
            format!(
                "file holds {len} bytes but {}x{}x{} {dtype} needs {need} bytes",
                dims[0], dims[1], dims[2]
            ),
        ));
    }
    Ok(())
}

/// Decode `bytes` (the whole file) as a raw array.
pub fn decode(path: &Path, bytes: Vec<u8>, opts: &ReadOptions) -> Result<Decoded, VolumeError> {
    check_size(path, opts, bytes.len() as u64)?;
    let (dims, dtype) = layout(path, opts)?;
    let byte_order = opts.byte_order.unwrap_or(ByteOrder::Little);
    Ok(Decoded {
        geometry: Geometry {
            dims,
            spacing: opts.spacing.unwrap_or([1.0; 3]),
            origin: [0.0; 3],
        },
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
        let e = parse_name("a_4x4x4_uint9").unwrap_err();
        assert!(e.contains("uint9"), "{e}");
        assert!(parse_name("a_4x4x99999999999999999999999_uint8").is_err());
    }
}
