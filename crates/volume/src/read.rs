//! Opening a volume file: checks on the path, dispatch by extension, then normalization.

use std::path::Path;
use t2tf_core::memory::Budget;

use super::source::{At, Located, Source};
use super::{
    legacy, raw, vti, ByteOrder, Geometry, ScalarType, SourceFormat, TypedBuffer, Volume,
    VolumeError, VolumeSource,
};

/// Reader settings from the command line. Every field is optional: `None` means "what the
/// file says" (or the `.raw` defaults: little-endian, spacing 1, origin 0).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReadOptions {
    /// `.raw` only: points per axis (overrides the file name).
    pub dims: Option<[usize; 3]>,
    /// `.raw` only: scalar type (overrides the file name).
    pub dtype: Option<ScalarType>,
    /// Spacing for `.raw`; for `.vti`/`.vtk` it replaces the file's spacing.
    pub spacing: Option<[f64; 3]>,
    /// `.raw` only: byte order of the values (default little-endian).
    pub byte_order: Option<ByteOrder>,
    /// `.vti`/`.vtk` only: the point-data array to read (default: the active scalars, else
    /// the first array).
    pub array: Option<String>,
    /// What the reader may allocate for sizes the file declares (default: what the system
    /// has, [`Budget::system`]).
    pub budget: Budget,
    /// Normalize over this data range instead of the file's own finite range (the steps of
    /// a series share one, [`crate::Series::scan`]). It must hold every finite value.
    pub norm_range: Option<[f64; 2]>,
}

/// A decoded file before normalization: geometry, values in the file's own type, and how a
/// ParaView/VisIt script reopens it.
#[derive(Clone, Debug)]
pub struct Decoded {
    /// Points per axis, spacing and origin.
    pub geometry: Geometry,
    /// The values in the file's own type and byte order.
    pub buffer: TypedBuffer,
    /// How a ParaView or VisIt script reopens the file.
    pub format: SourceFormat,
}

/// Read and normalize the volume at `path`; sets `Volume::source`. Level 0 is read from a
/// memory map of the file where the format allows it (`source`), else decoded into memory;
/// either way its f32 samples are made only when asked for.
pub fn load(path: &Path, opts: &ReadOptions) -> Result<Volume, VolumeError> {
    let (geometry, declared, format, source) = open(path, opts)?;
    let mut volume = Volume::from_source(
        path,
        geometry,
        declared,
        source,
        opts.budget,
        opts.norm_range,
    )?;
    volume.source = Some(VolumeSource {
        path: path.to_path_buf(),
        format,
    });
    Ok(volume)
}

/// The geometry, declared type, format and values' source of the file at `path`.
pub(super) fn open(
    path: &Path,
    opts: &ReadOptions,
) -> Result<(Geometry, ScalarType, SourceFormat, Source), VolumeError> {
    let meta = file_metadata(path)?;
    let kind = reader_for(path, opts)?;
    if kind == Kind::Raw {
        raw::check_size(path, opts, meta.len())?;
        let (geometry, dtype, byte_order) = raw::header(path, opts)?;
        let source = Source::map(path, dtype, byte_order, 0, geometry.voxel_count())?;
        let format = SourceFormat::Raw {
            scalar_type: dtype,
            byte_order,
        };
        return Ok((geometry, dtype, format, source));
    }
    if let Some((loc, map)) = locate(path, kind, opts) {
        let source = match loc.at {
            At::Offset(offset) => Source::map(path, loc.ty, loc.order, offset, loc.count)?,
            At::Blocks(table) => Source::blocks(path, loc.ty, loc.order, loc.count, map, table),
        };
        let mut geometry = loc.geometry;
        if let Some(spacing) = opts.spacing {
            geometry.spacing = spacing;
        }
        return Ok((geometry, loc.ty, loc.format, source));
    }
    let d = decode(path, opts)?;
    let declared = d.buffer.scalar_type();
    Ok((
        d.geometry,
        declared,
        d.format,
        Source::memory(path, d.buffer),
    ))
}

/// Which reader handles `path`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Raw,
    Vti,
    Legacy,
}

/// Read the file at `path` into its typed values and geometry, without normalizing.
pub fn decode(path: &Path, opts: &ReadOptions) -> Result<Decoded, VolumeError> {
    let meta = file_metadata(path)?;
    // Name, flags and (for .raw) the size are checked before a possibly large file is read.
    if reader_for(path, opts)? == Kind::Raw {
        raw::check_size(path, opts, meta.len())?;
    }
    opts.budget
        .check(
            "reading the volume file",
            Some(meta.len()),
            1,
            "use a smaller volume",
        )
        .map_err(|e| VolumeError::file(path, e.to_string()))?;
    let bytes = t2tf_core::input::read(path).map_err(|e| VolumeError::Io {
        path: path.to_path_buf(),
        error: e,
    })?;
    decode_bytes(path, bytes, opts)
}

/// Where the chosen array of a `.vti` or `.vtk` file lies, when its values can be read
/// without decoding the file whole (the readers' `locate`), with the file's map (what a
/// block-decoded source reads); `None` otherwise, or when the file cannot be mapped
/// (`decode` then reads it and reports any error).
fn locate(path: &Path, kind: Kind, opts: &ReadOptions) -> Option<(Located, memmap2::Mmap)> {
    let file = t2tf_core::input::open(path).ok()?;
    // SAFETY: read only; the file changing underneath is unsupported (see `Source::map`).
    let map = unsafe { memmap2::Mmap::map(&file) }.ok()?;
    let want = opts.array.as_deref();
    let loc = match kind {
        Kind::Vti => vti::locate(&map, want),
        Kind::Legacy => legacy::locate(&map, want),
        Kind::Raw => None,
    }?;
    // The header's pages (all of an inline array's text) stop counting as this process's.
    super::pages::dont_need(&map, 0..map.len());
    Some((loc, map))
}

/// Why a path and its flags do not pick a reader. The reader adds the file's path.
#[derive(Debug, thiserror::Error)]
enum PathError {
    #[error("no such file")]
    NoSuchFile,
    #[error("is a directory, not a volume file (.raw, .vti or .vtk)")]
    Directory,
    #[error(
        "no file extension: expected .raw, .vti or .vtk (or give `dims` and `dtype` to read \
         headerless raw data)"
    )]
    NoExtension,
    #[error(
        "unknown extension '.{0}': expected .raw, .vti or .vtk (or give `dims` and `dtype` to \
         read headerless raw data)"
    )]
    UnknownExtension(String),
    #[error("{0} applies to .raw files only; this file describes itself")]
    RawOnlyFlag(&'static str),
    #[error("`array` applies to .vti and .vtk files; a .raw file holds one array")]
    ArrayOnRaw,
}

impl PathError {
    fn at(self, path: &Path) -> VolumeError {
        VolumeError::file(path, self.to_string())
    }
}

/// The file's metadata; an error when it is missing or a directory.
pub(super) fn file_metadata(path: &Path) -> Result<std::fs::Metadata, VolumeError> {
    let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => PathError::NoSuchFile.at(path),
        _ => VolumeError::Io {
            path: path.to_path_buf(),
            error: e,
        },
    })?;
    if meta.is_dir() {
        return Err(PathError::Directory.at(path));
    }
    // A FIFO would block the read, a device would be read forever.
    t2tf_core::input::regular(&meta).map_err(|e| VolumeError::file(path, e.to_string()))?;
    Ok(meta)
}

/// Decode the contents of a file named `path` (the name picks the reader, the `.raw` dims and
/// type, and is quoted in errors) without touching the file system.
pub fn decode_bytes(
    path: &Path,
    bytes: Vec<u8>,
    opts: &ReadOptions,
) -> Result<Decoded, VolumeError> {
    let mut decoded = match reader_for(path, opts)? {
        Kind::Raw => raw::decode(path, bytes, opts)?,
        Kind::Vti => vti::decode(path, &bytes, opts.array.as_deref(), opts.budget)?,
        Kind::Legacy => legacy::decode(path, &bytes, opts.array.as_deref())?,
    };
    if let Some(spacing) = opts.spacing {
        decoded.geometry.spacing = spacing;
    }
    Ok(decoded)
}

/// The reader for `path` by extension, after checking that the flags fit it.
fn reader_for(path: &Path, opts: &ReadOptions) -> Result<Kind, VolumeError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let kind = match ext.as_str() {
        "raw" => Kind::Raw,
        "vti" => Kind::Vti,
        "vtk" => Kind::Legacy,
        // Headerless data under any other name when a raw flag says how to read it (the raw
        // reader names a missing --dims or --dtype).
        _ if opts.dims.is_some() || opts.dtype.is_some() => Kind::Raw,
        "" => return Err(PathError::NoExtension.at(path)),
        other => return Err(PathError::UnknownExtension(other.to_string()).at(path)),
    };
    if kind != Kind::Raw {
        let raw_only = [
            (opts.dims.is_some(), "`dims`"),
            (opts.dtype.is_some(), "`dtype`"),
            (opts.byte_order.is_some(), "`byte_order`"),
        ];
        if let Some((_, flag)) = raw_only.iter().find(|(given, _)| *given) {
            return Err(PathError::RawOnlyFlag(flag).at(path));
        }
    } else if opts.array.is_some() {
        return Err(PathError::ArrayOnRaw.at(path));
    }
    Ok(kind)
}
