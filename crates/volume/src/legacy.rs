//! Legacy VTK `.vtk` files, `DATASET STRUCTURED_POINTS`, ASCII or BINARY (big-endian).
//!
//! Layout (VTK's "File Formats" document, versions 2.0 … 5.1): four header lines, then keyword
//! sections. Point data arrays are `SCALARS name type [ncomp]` (+ optional `LOOKUP_TABLE`),
//! `COLOR_SCALARS name ncomp` (what VTK's writer uses for uint8 scalars: ASCII values are
//! value/255 floats, BINARY values are unsigned chars), and `FIELD` arrays
//! (`name ncomp ntuples type`). Sections we do not render (CELL_DATA, VECTORS, NORMALS,
//! TENSORS, TEXTURE_COORDINATES, LOOKUP_TABLE, METADATA) are parsed only to skip them.

use std::path::Path;

use super::source::{At, Located};
use super::{ByteOrder, Decoded, Geometry, ScalarType, SourceFormat, TypedBuffer, VolumeError};

/// Why a legacy `.vtk` file could not be read. Each message is one line; the reader adds the
/// file's path.
#[derive(Debug, thiserror::Error)]
pub(crate) enum LegacyError {
    #[error("not a legacy VTK file: the first line is not '# vtk DataFile Version x.x'")]
    NotLegacy,
    /// Only from `locate`, which then lets `decode` parse (and report on) the file.
    #[error("ASCII values cannot be mapped")]
    AsciiNotMapped,
    #[error("line 3 must be ASCII or BINARY, found '{0}'")]
    BadEncodingLine(String),
    #[error("'{line}' is missing a field")]
    MissingField { line: String },
    #[error("'{value}' in '{line}' is not a count")]
    NotACount { value: String, line: String },
    #[error("'{value}' in '{line}' is not a number")]
    NotANumber { value: String, line: String },
    #[error("'{0}' contains a zero")]
    ZeroDimension(String),
    #[error("LOOKUP_TABLE: {0}")]
    LookupTable(ReadError),
    #[error("unexpected line '{line}' (near byte {byte})")]
    UnexpectedLine { line: String, byte: usize },
    #[error("DATASET {0} is not supported: only STRUCTURED_POINTS (image data)")]
    UnsupportedDataset(String),
    #[error("{0} comes before DIMENSIONS")]
    SectionBeforeDimensions(String),
    #[error("DIMENSIONS {0:?} are too large")]
    DimensionsTooLarge([usize; 3]),
    #[error(
        "POINT_DATA {count} does not match DIMENSIONS {}x{}x{} ({points} points)",
        .dims[0], .dims[1], .dims[2]
    )]
    PointCountMismatch {
        count: usize,
        dims: [usize; 3],
        points: usize,
    },
    /// An attribute section (`SCALARS`, `VECTORS`, …) whose values cannot be read.
    #[error("{key} {name}: {error}")]
    Attribute {
        key: String,
        name: String,
        error: ReadError,
    },
    #[error("FIELD ends before its arrays")]
    FieldEnds,
    #[error("FIELD array line '{0}' needs 'name ncomp ntuples type'")]
    FieldLine(String),
    #[error("FIELD array {name}: {error}")]
    FieldArray { name: String, error: ReadError },
    #[error(
        "array '{name}' is {key} with {ncomp} components: only single-component scalars can \
         be rendered"
    )]
    NotScalar {
        name: String,
        key: String,
        ncomp: usize,
    },
    #[error("no 'DATASET STRUCTURED_POINTS' line")]
    NoDataset,
    #[error("no DIMENSIONS line")]
    NoDimensions,
    #[error("array '{0}' is cell data; only point data can be volume rendered")]
    CellData(String),
    #[error("no point-data array named '{name}' (point-data arrays: {available})")]
    NoArrayNamed { name: String, available: String },
    #[error("no point data (POINT_DATA with SCALARS) to render")]
    NoPointData,
    #[error("array '{name}': {error}")]
    Unrenderable { name: String, error: Unrenderable },
}

/// Why an array that was read cannot be rendered (reported only if it is the one chosen).
#[derive(Debug, thiserror::Error)]
pub(crate) enum Unrenderable {
    #[error("has {0} components: only single-component scalars can be rendered")]
    Components(usize),
    #[error("its type '{0}' is not a numeric type this reader supports")]
    UnsupportedType(String),
}

/// Why an array's values could not be read.
#[derive(Debug, thiserror::Error)]
pub(crate) enum ReadError {
    #[error("value count overflows")]
    ValueCountOverflows,
    #[error("file ends after {read} of {needed} values (truncated?)")]
    Truncated { read: usize, needed: usize },
    #[error("value {index} '{text}' is not a number")]
    NotANumber { index: usize, text: String },
    /// A value outside the declared type's range.
    #[error(transparent)]
    TextValues(#[from] Box<super::TextValueError>),
    #[error("binary data of an unsupported type cannot be skipped")]
    BinaryUnsupported,
    #[error("byte count overflows")]
    ByteCountOverflows,
    #[error("needs {len} bytes of binary data but the file has {available} left (truncated?)")]
    BinaryTruncated { len: usize, available: usize },
}

/// Which data section the arrays being read belong to.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Section {
    /// Dataset-level FIELD data (before POINT_DATA/CELL_DATA).
    Dataset,
    Point,
    Cell,
}

/// An array found in the point data: its values, or why it cannot be rendered.
struct Found {
    name: String,
    values: Result<TypedBuffer, Unrenderable>,
    /// Where its binary values start in the file and how many there are, when read by
    /// [`locate`].
    at: Option<(usize, usize)>,
}

/// A cursor over the file's bytes: header lines are text, binary data follows a newline.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// [`locate`]: binary arrays are stepped over, not copied; `last_binary` says where the
    /// last one started and its value count.
    lazy: bool,
    last_binary: Option<(usize, usize)>,
}

impl<'a> Cursor<'a> {
    /// The next line (without its newline), `None` at end of file.
    fn raw_line(&mut self) -> Option<&'a str> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let rest = &self.bytes[self.pos..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += (end + 1).min(rest.len());
        // Header lines are ASCII; anything else cannot be a keyword and is reported as such.
        Some(
            std::str::from_utf8(&rest[..end])
                .unwrap_or("<binary bytes>")
                .trim(),
        )
    }

    /// The next non-blank line.
    fn line(&mut self) -> Option<&'a str> {
        loop {
            match self.raw_line() {
                Some("") => continue,
                other => return other,
            }
        }
    }

    /// The next whitespace-separated ASCII token.
    fn token(&mut self) -> Option<&'a str> {
        let rest = &self.bytes[self.pos.min(self.bytes.len())..];
        let start = rest.iter().position(|b| !b.is_ascii_whitespace())?;
        let len = rest[start..]
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(rest.len() - start);
        self.pos += start + len;
        std::str::from_utf8(&rest[start..start + len]).ok()
    }

    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.bytes.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }
}

/// Legacy type names (VTK's `vtkDataReader`) to scalar types; `None` for types we cannot read.
fn legacy_type(name: &str) -> Option<ScalarType> {
    Some(match name.to_ascii_lowercase().as_str() {
        "unsigned_char" => ScalarType::U8,
        "char" | "signed_char" => ScalarType::I8,
        "unsigned_short" => ScalarType::U16,
        "short" => ScalarType::I16,
        "unsigned_int" => ScalarType::U32,
        "int" => ScalarType::I32,
        // VTK writes `long` as 64 bits in binary files on LP64 systems (and reads it so).
        "unsigned_long" | "vtktypeuint64" | "unsigned_long_long" => ScalarType::U64,
        "long" | "vtktypeint64" | "long_long" => ScalarType::I64,
        // vtkDataWriter converts vtkIdType to 32-bit int for legacy files.
        "vtkidtype" => ScalarType::I32,
        "float" => ScalarType::F32,
        "double" => ScalarType::F64,
        _ => return None,
    })
}

/// Parse the legacy file `bytes`; `want` names the point-data array to read.
pub fn decode(path: &Path, bytes: &[u8], want: Option<&str>) -> Result<Decoded, VolumeError> {
    let err = |e: LegacyError| VolumeError::file(path, e.to_string());
    parse(bytes, want, false).map(|(d, _)| d).map_err(err)
}

/// Where the array `want` (as [`decode`] chooses it) lies in a BINARY legacy file: its
/// big-endian values are contiguous there and can be read from a memory map. `None` for an
/// ASCII file and for any file [`decode`] rejects (it then reports why).
pub(super) fn locate(bytes: &[u8], want: Option<&str>) -> Option<Located> {
    let (d, at) = parse(bytes, want, true).ok()?;
    let (ty, order, _) = d.buffer.raw();
    let (offset, count) = at?;
    Some(Located {
        geometry: d.geometry,
        ty,
        order,
        count,
        format: d.format,
        at: At::Offset(offset as u64),
    })
}

/// The header and the chosen array (empty and located by its offset when `lazy`).
fn parse(
    bytes: &[u8],
    want: Option<&str>,
    lazy: bool,
) -> Result<(Decoded, Option<(usize, usize)>), LegacyError> {
    let mut c = Cursor {
        bytes,
        pos: 0,
        lazy,
        last_binary: None,
    };
    let ascii = header(&mut c)?;
    // An ASCII file cannot be mapped: `locate` stops here rather than parse every number
    // that `decode` parses again.
    if ascii && lazy {
        return Err(LegacyError::AsciiNotMapped);
    }
    let mut p = Parser {
        c,
        ascii,
        want,
        dims: None,
        spacing: [1.0; 3],
        origin: [0.0; 3],
        dataset_seen: false,
        section: Section::Dataset,
        count: 0,
        names: Vec::new(),
        cell_names: Vec::new(),
        chosen: None,
        fallback: None,
    };
    while let Some(line) = p.c.line() {
        if p.keyword(line)? == Flow::Done {
            break;
        }
    }
    p.finish()
}

/// The first three lines: the version line, the title, and ASCII or BINARY (`true` for ASCII).
fn header(c: &mut Cursor<'_>) -> Result<bool, LegacyError> {
    let first = c.raw_line().unwrap_or("");
    if !first.starts_with("# vtk DataFile Version") {
        return Err(LegacyError::NotLegacy);
    }
    let _title = c.raw_line();
    match c.line().map(str::to_ascii_uppercase).as_deref() {
        Some("ASCII") => Ok(true),
        Some("BINARY") => Ok(false),
        other => Err(LegacyError::BadEncodingLine(
            other.unwrap_or("end of file").to_string(),
        )),
    }
}

/// Whether to read on after a keyword section.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Flow {
    More,
    /// The array to render has been found.
    Done,
}

/// What the keyword sections have told so far.
struct Parser<'a, 'w> {
    c: Cursor<'a>,
    ascii: bool,
    want: Option<&'w str>,
    dims: Option<[usize; 3]>,
    spacing: [f64; 3],
    origin: [f64; 3],
    dataset_seen: bool,
    section: Section,
    /// Tuples in the current section.
    count: usize,
    names: Vec<String>,
    cell_names: Vec<String>,
    chosen: Option<Found>,
    /// Without --array: the first SCALARS/COLOR_SCALARS (VTK's active scalars) wins; a FIELD
    /// array is kept as the fallback.
    fallback: Option<Found>,
}

/// One keyword line split into its fields, with the parsers every section uses.
struct Line<'l> {
    text: &'l str,
    key: String,
    args: Vec<&'l str>,
}

impl<'l> Line<'l> {
    fn new(text: &'l str) -> Line<'l> {
        let mut words = text.split_ascii_whitespace();
        let key = words.next().unwrap_or("").to_ascii_uppercase();
        Line {
            text,
            key,
            args: words.collect(),
        }
    }

    fn arg(&self, i: usize) -> Result<&'l str, LegacyError> {
        self.args
            .get(i)
            .copied()
            .ok_or_else(|| LegacyError::MissingField {
                line: self.text.to_string(),
            })
    }

    fn num(&self, i: usize) -> Result<usize, LegacyError> {
        let a = self.arg(i)?;
        a.parse().map_err(|_| LegacyError::NotACount {
            value: a.to_string(),
            line: self.text.to_string(),
        })
    }

    fn vec3(&self) -> Result<[f64; 3], LegacyError> {
        let mut v = [0.0; 3];
        for (a, slot) in v.iter_mut().enumerate() {
            let s = self.arg(a)?;
            *slot = s.parse().map_err(|_| LegacyError::NotANumber {
                value: s.to_string(),
                line: self.text.to_string(),
            })?;
        }
        Ok(v)
    }
}

impl Parser<'_, '_> {
    /// Handle one keyword line and the data that follows it.
    fn keyword(&mut self, text: &str) -> Result<Flow, LegacyError> {
        let l = Line::new(text);
        match l.key.as_str() {
            "DATASET" => self.dataset(&l)?,
            "DIMENSIONS" => {
                let d = [l.num(0)?, l.num(1)?, l.num(2)?];
                if d.contains(&0) {
                    return Err(LegacyError::ZeroDimension(l.text.to_string()));
                }
                self.dims = Some(d);
            }
            "SPACING" | "ASPECT_RATIO" => self.spacing = l.vec3()?,
            "ORIGIN" => self.origin = l.vec3()?,
            "POINT_DATA" | "CELL_DATA" => self.data_section(&l)?,
            "SCALARS" | "COLOR_SCALARS" => return self.scalars(&l),
            "FIELD" => return self.field(&l),
            "VECTORS" | "NORMALS" | "TENSORS" | "TENSORS6" | "TEXTURE_COORDINATES" => {
                self.other_attribute(&l)?
            }
            "LOOKUP_TABLE" => {
                // A colour table of `size` RGBA entries (floats in ASCII, bytes in BINARY).
                let size = l.num(1)?;
                read_array(&mut self.c, self.ascii, Some(ScalarType::U8), size, 4, true)
                    .map_err(LegacyError::LookupTable)?;
            }
            "METADATA" => {
                // Version 5.1 metadata blocks end at a blank line.
                while let Some(l) = self.c.raw_line() {
                    if l.is_empty() {
                        break;
                    }
                }
            }
            _ => {
                return Err(LegacyError::UnexpectedLine {
                    line: truncate(text),
                    byte: self.c.pos,
                })
            }
        }
        Ok(Flow::More)
    }

    /// `DATASET kind`: only image data.
    fn dataset(&mut self, l: &Line) -> Result<(), LegacyError> {
        let kind = l.arg(0)?.to_ascii_uppercase();
        if kind != "STRUCTURED_POINTS" {
            return Err(LegacyError::UnsupportedDataset(kind));
        }
        self.dataset_seen = true;
        Ok(())
    }

    /// `POINT_DATA n` / `CELL_DATA n`: the section the next arrays belong to.
    fn data_section(&mut self, l: &Line) -> Result<(), LegacyError> {
        let key = &l.key;
        let d = self
            .dims
            .ok_or_else(|| LegacyError::SectionBeforeDimensions(key.clone()))?;
        self.count = l.num(0)?;
        let count = self.count;
        self.section = if key == "POINT_DATA" {
            let n = d
                .iter()
                .try_fold(1usize, |a, &x| a.checked_mul(x))
                .ok_or(LegacyError::DimensionsTooLarge(d))?;
            if count != n {
                return Err(LegacyError::PointCountMismatch {
                    count,
                    dims: d,
                    points: n,
                });
            }
            Section::Point
        } else {
            Section::Cell
        };
        Ok(())
    }

    /// `SCALARS name type [ncomp]` (+ `LOOKUP_TABLE`) or `COLOR_SCALARS name ncomp`.
    fn scalars(&mut self, l: &Line) -> Result<Flow, LegacyError> {
        let key = &l.key;
        let name = l.arg(0)?.to_string();
        let color = key == "COLOR_SCALARS";
        let (ty, ncomp) = if color {
            (Some(ScalarType::U8), l.num(1)?)
        } else {
            (
                legacy_type(l.arg(1)?),
                if l.args.len() > 2 { l.num(2)? } else { 1 },
            )
        };
        // The optional LOOKUP_TABLE line belongs to SCALARS.
        if !color {
            let save = self.c.pos;
            match self.c.line() {
                Some(t) if t.to_ascii_uppercase().starts_with("LOOKUP_TABLE") => {}
                _ => self.c.pos = save,
            }
        }
        let values =
            read_array(&mut self.c, self.ascii, ty, self.count, ncomp, color).map_err(|error| {
                LegacyError::Attribute {
                    key: key.clone(),
                    name: name.clone(),
                    error,
                }
            })?;
        if self.section == Section::Point {
            let at = self.c.last_binary;
            let f = found(&name, l.arg(1).unwrap_or("?"), ncomp, values, at);
            self.names.push(name.clone());
            if pick(
                self.want,
                &name,
                true,
                &mut self.chosen,
                &mut self.fallback,
                f,
            ) {
                return Ok(Flow::Done);
            }
        } else if self.section == Section::Cell {
            self.cell_names.push(name);
        }
        Ok(Flow::More)
    }

    /// `FIELD name n` and its n arrays (`name ncomp ntuples type`, or `NULL_ARRAY`).
    fn field(&mut self, l: &Line) -> Result<Flow, LegacyError> {
        let n_arrays = l.num(1)?;
        for _ in 0..n_arrays {
            let head = self.c.line().ok_or(LegacyError::FieldEnds)?;
            let f: Vec<&str> = head.split_ascii_whitespace().collect();
            if f.first() == Some(&"NULL_ARRAY") {
                continue;
            }
            if f.len() < 4 {
                return Err(LegacyError::FieldLine(head.to_string()));
            }
            let parse = |s: &str| {
                s.parse::<usize>().map_err(|_| LegacyError::NotACount {
                    value: s.to_string(),
                    line: head.to_string(),
                })
            };
            let (ncomp, ntuples) = (parse(f[1])?, parse(f[2])?);
            let values = read_array(
                &mut self.c,
                self.ascii,
                legacy_type(f[3]),
                ntuples,
                ncomp,
                false,
            )
            .map_err(|error| LegacyError::FieldArray {
                name: f[0].to_string(),
                error,
            })?;
            if self.section == Section::Point && ntuples == self.count {
                let fnd = found(f[0], f[3], ncomp, values, self.c.last_binary);
                self.names.push(f[0].to_string());
                if pick(
                    self.want,
                    f[0],
                    false,
                    &mut self.chosen,
                    &mut self.fallback,
                    fnd,
                ) {
                    return Ok(Flow::Done);
                }
            } else if self.section == Section::Cell {
                self.cell_names.push(f[0].to_string());
            }
        }
        Ok(if self.chosen.is_some() {
            Flow::Done
        } else {
            Flow::More
        })
    }

    /// VECTORS, NORMALS, TENSORS(6), TEXTURE_COORDINATES: read to be skipped (or to say why
    /// the array asked for cannot be rendered).
    fn other_attribute(&mut self, l: &Line) -> Result<(), LegacyError> {
        let key = &l.key;
        let (ncomp, ty) = match key.as_str() {
            "TEXTURE_COORDINATES" => (l.num(1)?, l.arg(2)?),
            "TENSORS" => (9, l.arg(1)?),
            "TENSORS6" => (6, l.arg(1)?),
            _ => (3, l.arg(1)?),
        };
        let name = l.arg(0)?.to_string();
        read_array(
            &mut self.c,
            self.ascii,
            legacy_type(ty),
            self.count,
            ncomp,
            false,
        )
        .map_err(|error| LegacyError::Attribute {
            key: key.clone(),
            name: name.clone(),
            error,
        })?;
        if self.section == Section::Point {
            if self.want == Some(name.as_str()) {
                return Err(LegacyError::NotScalar {
                    name,
                    key: key.clone(),
                    ncomp,
                });
            }
            self.names.push(name);
        } else if self.section == Section::Cell {
            self.cell_names.push(name);
        }
        Ok(())
    }

    /// The geometry and the chosen array, once the file has been read.
    /// The chosen array, and where its binary values start when the parse is lazy.
    fn finish(self) -> Result<(Decoded, Option<(usize, usize)>), LegacyError> {
        if !self.dataset_seen {
            return Err(LegacyError::NoDataset);
        }
        let dims = self.dims.ok_or(LegacyError::NoDimensions)?;
        let (want, names, cell_names) = (self.want, &self.names, &self.cell_names);
        let f = self.chosen.or(self.fallback).ok_or_else(|| match want {
            Some(w) if cell_names.iter().any(|c| c == w) => LegacyError::CellData(w.to_string()),
            Some(w) => LegacyError::NoArrayNamed {
                name: w.to_string(),
                available: list(names),
            },
            None => LegacyError::NoPointData,
        })?;
        let buffer = match f.values {
            Ok(b) => b,
            Err(error) => {
                return Err(LegacyError::Unrenderable {
                    name: f.name,
                    error,
                })
            }
        };
        let d = Decoded {
            geometry: Geometry {
                dims,
                spacing: self.spacing,
                origin: self.origin,
            },
            buffer,
            format: SourceFormat::LegacyVtk { array: f.name },
        };
        Ok((d, f.at))
    }
}

/// Wrap a read array, turning a multi-component or unreadable one into a deferred error (it
/// matters only if this array is the one chosen).
fn found(
    name: &str,
    type_name: &str,
    ncomp: usize,
    values: Option<TypedBuffer>,
    at: Option<(usize, usize)>,
) -> Found {
    let values = match values {
        _ if ncomp != 1 => Err(Unrenderable::Components(ncomp)),
        Some(v) => Ok(v),
        None => Err(Unrenderable::UnsupportedType(type_name.to_string())),
    };
    Found {
        name: name.to_string(),
        values,
        at,
    }
}

/// Apply the selection rule; `true` when the search is over.
fn pick(
    want: Option<&str>,
    name: &str,
    active: bool,
    chosen: &mut Option<Found>,
    fallback: &mut Option<Found>,
    f: Found,
) -> bool {
    match want {
        Some(w) if w == name => {
            *chosen = Some(f);
            true
        }
        Some(_) => false,
        None if active => {
            *chosen = Some(f);
            true
        }
        None => {
            if fallback.is_none() {
                *fallback = Some(f);
            }
            false
        }
    }
}

/// Read `tuples * ncomp` values. `Ok(None)`: skipped because the type is unsupported (only
/// possible in ASCII, where the values can still be stepped over).
fn read_array(
    c: &mut Cursor<'_>,
    ascii: bool,
    ty: Option<ScalarType>,
    tuples: usize,
    ncomp: usize,
    color: bool,
) -> Result<Option<TypedBuffer>, ReadError> {
    let n = tuples
        .checked_mul(ncomp)
        .ok_or(ReadError::ValueCountOverflows)?;
    if ascii {
        let mut values = Vec::with_capacity(n.min(1 << 24));
        for i in 0..n {
            let tok = c
                .token()
                .ok_or(ReadError::Truncated { read: i, needed: n })?;
            let v: f64 = tok.parse().map_err(|_| ReadError::NotANumber {
                index: i,
                text: truncate(tok),
            })?;
            if let Some(t) = ty {
                TypedBuffer::check_text_token(tok, i, t)?;
            }
            // COLOR_SCALARS text holds byte/255; VTK's reader turns it back into bytes the
            // same way, so data units match what ParaView shows.
            values.push(if color {
                (v * 255.0).round().clamp(0.0, 255.0)
            } else {
                v
            });
        }
        if let Some(t) = ty {
            TypedBuffer::check_text_values(&values, t)?;
        }
        Ok(ty.map(|t| TypedBuffer::from_f64_as(values, t)))
    } else {
        let Some(t) = ty else {
            return Err(ReadError::BinaryUnsupported);
        };
        let len = n
            .checked_mul(t.size())
            .ok_or(ReadError::ByteCountOverflows)?;
        let available = c.bytes.len().saturating_sub(c.pos);
        let data = c
            .take(len)
            .ok_or(ReadError::BinaryTruncated { len, available })?;
        if c.lazy {
            c.last_binary = Some((c.pos - len, n));
            return Ok(Some(TypedBuffer::new(t, ByteOrder::Big, Vec::new())));
        }
        // Legacy binary files are big-endian by definition.
        Ok(Some(TypedBuffer::new(t, ByteOrder::Big, data.to_vec())))
    }
}

fn list(names: &[String]) -> String {
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

/// Keep error messages on one short line.
fn truncate(s: &str) -> String {
    let s: String = s.chars().take(60).collect();
    s.replace(['\n', '\r'], " ")
}
