//! VTK XML ImageData (`.vti`) in every encoding VTK writes: `ascii`, inline `binary` (base64),
//! and `appended` (raw or base64), each uncompressed or compressed with zlib, LZ4 or LZMA, with
//! UInt32 or UInt64 block headers, little- or big-endian.
//!
//! Why not `vtkio` (0.7.0-rc2, the only version with the XML reader): checked by hand on this
//! repository's fixtures (vtkio built with its `xml`, `flate2` and `lz4` features):
//! - `appended_raw_uint16.vti` (appended raw: what ParaView saves unless "Encode Appended
//!   Data" is ticked; VTK 9.7's writer itself defaults to appended base64 + zlib) fails with
//!   "unknown variant `raw`, expected `base64`";
//! - `binary_float64_lzma.vti` (a compression it was not built for) imports as Ok with an
//!   empty point-data list: the array is dropped silently, so a caller cannot tell a bad file
//!   from an empty one;
//! - its legacy parser fails on `legacy_binary_uint16.vtk` ("Parse error: Tag":
//!   `unsigned_short` is unknown to 0.7) and keeps ASCII COLOR_SCALARS as the /255 floats.
//!
//! Per the project's crate notes it also keeps origin and spacing as f32 and ignores
//! `Direction` (not re-checked here). One reader here covers every case with exact f64
//! geometry and an error for anything it cannot read.
//!
//! The XML before `<AppendedData` is parsed with quick-xml; appended raw bytes follow the first
//! `_` after that tag and `offset` attributes count from the byte after it. Binary arrays are
//! decoded in [`super::vti_blocks`].

use std::borrow::Cow;
use std::path::Path;

use quick_xml::events::{BytesStart, Event};
use quick_xml::Reader;

use super::source::{At, Located};
use super::vti_blocks::{base64_streams, header_int, unpack, BlockError, Compressor, Layout};
use super::Budget;
use super::{ByteOrder, Decoded, Geometry, ScalarType, SourceFormat, TypedBuffer, VolumeError};

/// Why a `.vti` file could not be read. Each message is one line (quoted file text may hold
/// newlines; [`VolumeError::file`] folds them) and the reader adds the file's path.
#[derive(Debug, thiserror::Error)]
pub(crate) enum VtiError {
    #[error("the XML part is not valid UTF-8 ({0})")]
    XmlNotUtf8(std::str::Utf8Error),
    #[error("the XML part holds a NUL byte at byte {position}, which XML does not allow")]
    Nul { position: usize },
    #[error("malformed XML near byte {position}: {error}")]
    MalformedXml {
        position: u64,
        error: quick_xml::Error,
    },
    #[error("is a VTK XML '{found}' file, not ImageData (only image data can be volume rendered)")]
    NotImageData { found: String },
    #[error("unknown byte_order '{0}'")]
    UnknownByteOrder(String),
    #[error("unknown header_type '{0}'")]
    UnknownHeaderType(String),
    #[error("unknown compressor '{0}'")]
    UnknownCompressor(String),
    #[error("Direction {0:?} is not the identity: rotated image data is not supported")]
    Rotated([f64; 9]),
    #[error("DataArray '{name}' has no type attribute")]
    NoType { name: String },
    #[error("DataArray '{name}': NumberOfComponents '{value}' is not a count")]
    BadComponents { name: String, value: String },
    #[error("DataArray '{name}': offset '{value}' is not a count")]
    BadOffset { name: String, value: String },
    #[error("not a VTK XML file: no <VTKFile> element")]
    NoVtkFile,
    #[error(
        "has {pieces} pieces with different extents: only single-piece image data is \
         supported (merge the pieces in ParaView and save again)"
    )]
    PiecesDiffer { pieces: usize },
    #[error("no Extent on <Piece> or WholeExtent on <ImageData>")]
    NoExtent,
    #[error("extent {extent:?} is empty along axis {axis} (zero dimensions)")]
    EmptyExtent { extent: [i64; 6], axis: usize },
    #[error("extent {0:?} too large")]
    ExtentTooLarge([i64; 6]),
    #[error("array '{0}' is cell data; only point data can be volume rendered")]
    CellData(String),
    #[error("no point-data array named '{name}' (point-data arrays: {available})")]
    NoArrayNamed { name: String, available: String },
    #[error("no point-data arrays to render")]
    NoPointArrays,
    #[error("no point-data arrays to render (cell-data arrays: {0})")]
    OnlyCellArrays(String),
    #[error("<AppendedData> tag is not closed")]
    AppendedNotClosed,
    #[error("<AppendedData> tag is not valid text")]
    AppendedNotText,
    #[error("malformed tag '{0}'")]
    MalformedTag(String),
    #[error("<AppendedData> encoding '{0}' is not raw or base64")]
    AppendedEncoding(String),
    #[error("<AppendedData> has no '_' marker before its data")]
    NoMarker,
    #[error("malformed attribute: {0}")]
    MalformedAttribute(quick_xml::events::attributes::AttrError),
    #[error("malformed attribute {key}: {error}")]
    MalformedAttributeValue {
        key: String,
        error: quick_xml::Error,
    },
    #[error("{what} '{text}' is not {count} numbers")]
    NotNumbers {
        what: &'static str,
        text: String,
        count: usize,
    },
    /// The array error is part of the message (not a `source`), like every reader message.
    #[error("array '{name}': {error}")]
    Array { name: String, error: ArrayError },
}

/// A block that does not decode, worded as [`decode`] words it (the block source's errors).
fn block_error(array: &str, message: String) -> String {
    VtiError::Array {
        name: array.to_string(),
        error: ArrayError::Decode(message),
    }
    .to_string()
}

/// Why the selected array's values could not be read.
#[derive(Debug, thiserror::Error)]
pub(crate) enum ArrayError {
    #[error(
        "has {0} components: only single-component scalars can be rendered (pick another \
         with --array)"
    )]
    Components(usize),
    #[error("type '{0}' is not a numeric type (expected Int8 … UInt64, Float32, Float64)")]
    UnknownType(String),
    #[error("size overflows")]
    SizeOverflows,
    /// The extent does not fit in memory.
    #[error(transparent)]
    Memory(#[from] t2tf_core::memory::MemoryError),
    #[error("holds more than the {0} values its extent needs")]
    TooManyValues(usize),
    #[error("value {index} '{text}' is not a number")]
    NotANumber { index: usize, text: String },
    #[error("holds {found} values but the extent needs {needed}")]
    ValueCount { found: usize, needed: usize },
    /// A value outside the declared type's range.
    #[error(transparent)]
    TextValues(#[from] Box<super::buffer::TextValueError>),
    /// Binary data that cannot be decoded.
    #[error(transparent)]
    Block(#[from] BlockError),
    #[error("format is appended but the file has no <AppendedData>")]
    NoAppendedData,
    #[error("appended array has no offset attribute")]
    NoOffset,
    #[error("offset {offset} is past the end of the appended data ({len} bytes; truncated?)")]
    OffsetPastEnd { offset: usize, len: usize },
    #[error("unknown format '{0}' (expected ascii, binary or appended)")]
    UnknownFormat(String),
    /// A block that does not decode, found when its values are read (`blocks::Blocks`).
    #[error("{0}")]
    Decode(String),
}

/// One point-data array as declared in the XML.
struct ArrayDecl<'a> {
    name: String,
    type_name: String,
    components: usize,
    format: String,
    offset: Option<usize>,
    /// Inline content (ascii numbers or base64).
    text: Cow<'a, str>,
}

/// Parse the `.vti` file `bytes`; `want` names the point-data array to read.
pub fn decode(
    path: &Path,
    bytes: &[u8],
    want: Option<&str>,
    budget: Budget,
) -> Result<Decoded, VolumeError> {
    decode_inner(bytes, want, budget).map_err(|e| VolumeError::file(path, e.to_string()))
}

fn decode_inner(bytes: &[u8], want: Option<&str>, budget: Budget) -> Result<Decoded, VtiError> {
    // Appended data is not XML: cut it off before parsing.
    let split = find(bytes, b"<AppendedData").unwrap_or(bytes.len());
    let xml = std::str::from_utf8(&bytes[..split]).map_err(VtiError::XmlNotUtf8)?;
    let appended = if split < bytes.len() {
        Some(appended_section(&bytes[split..])?)
    } else {
        None
    };

    let h = parse_header(xml)?;
    let (dims, origin) = grid(&h)?;
    let n: usize = dims.iter().product();
    let decl = select(&h, want)?;
    let buffer = read_array(decl, n, h.layout, appended.as_ref(), budget).map_err(|error| {
        VtiError::Array {
            name: decl.name.clone(),
            error,
        }
    })?;
    Ok(Decoded {
        geometry: Geometry {
            dims,
            spacing: h.spacing,
            origin,
        },
        buffer,
        format: SourceFormat::Vti {
            array: decl.name.clone(),
        },
    })
}

/// Where the array `want` (as [`decode`] chooses it) lies in a `.vti` file when its values can
/// be read without decoding it whole: appended raw uncompressed data is contiguous after its
/// length header ([`At::Offset`], mapped); compressed blocks (appended raw, appended base64 or
/// inline base64) and uncompressed base64 are read block by block ([`At::Blocks`]). `None`
/// for ASCII and multi-component arrays, for base64 text with whitespace inside (other
/// writers wrap lines: the whole decode skips it, random access by character cannot), for
/// blocks larger than [`super::blocks::MAX_BLOCK`], and for any file [`decode`] rejects (it
/// then reports why).
pub(super) fn locate(bytes: &[u8], want: Option<&str>) -> Option<Located> {
    let split = find(bytes, b"<AppendedData").unwrap_or(bytes.len());
    let xml = std::str::from_utf8(&bytes[..split]).ok()?;
    let app = match split < bytes.len() {
        true => Some(appended_section(&bytes[split..]).ok()?),
        false => None,
    };
    let h = parse_header(xml).ok()?;
    let (dims, origin) = grid(&h).ok()?;
    let decl = select(&h, want).ok()?;
    if decl.components != 1 {
        return None;
    }
    let ty: ScalarType = decl.type_name.parse().ok()?;
    let count: usize = dims.iter().product();
    let nbytes = count.checked_mul(ty.size())?;
    // Distance of a slice of `bytes` from the file's first byte.
    let pos = |s: &[u8]| s.as_ptr() as usize - bytes.as_ptr() as usize;
    // Only whitespace from `end` to `limit`: the text held nothing the table did not count.
    let clean = |end: usize, limit: usize| {
        bytes
            .get(end..limit)
            .is_some_and(|t| t.iter().all(u8::is_ascii_whitespace))
    };
    let table = |start, base64| {
        let name = &decl.name;
        super::blocks::table(bytes, start, base64, h.layout, nbytes, name, block_error)
    };
    let at = match decl.format.as_str() {
        "appended" => {
            let app = app?;
            let offset = decl.offset?;
            let start = app.data.get(offset..)?;
            if app.base64 {
                let t = table(pos(start), true)?;
                // The array's text ends where the next array's starts, else with the section.
                let next = h.offsets.iter().filter(|&&o| o > offset).min();
                let limit = match next {
                    Some(&o) => pos(app.data) + o,
                    None => pos(app.data) + app.data.len(),
                };
                if !clean(t.end, limit) {
                    return None;
                }
                At::Blocks(t)
            } else if h.layout.compressor != Compressor::None {
                At::Blocks(table(pos(start), false)?)
            } else {
                // The checks `unpack` makes: the length header names exactly the array, all
                // present.
                let len = header_int(start, 0, h.layout).ok()?;
                let values = h.layout.header_size.checked_add(len)?;
                if len != nbytes || start.len() < values {
                    return None;
                }
                At::Offset((pos(start) + h.layout.header_size) as u64)
            }
        }
        "binary" => {
            // Text borrowed from the file (not joined from several XML text events).
            let Cow::Borrowed(text) = &decl.text else {
                return None;
            };
            let body = text.trim_start_matches(|c: char| c.is_ascii_whitespace());
            let t = table(pos(body.as_bytes()), true)?;
            if !clean(t.end, pos(text.as_bytes()) + text.len()) {
                return None;
            }
            At::Blocks(t)
        }
        _ => return None,
    };
    Some(Located {
        geometry: Geometry {
            dims,
            spacing: h.spacing,
            origin,
        },
        ty,
        order: h.layout.order,
        count,
        format: SourceFormat::Vti {
            array: decl.name.clone(),
        },
        at,
    })
}

/// What the XML part of the file declares.
struct Header<'a> {
    layout: Layout,
    /// The piece's extent (else WholeExtent): first and last point index per axis.
    extent: [i64; 6],
    /// Where point index (0, 0, 0) sits (not the extent's first point).
    origin: [f64; 3],
    spacing: [f64; 3],
    /// `<PointData Scalars=...>`: the active scalars.
    active: Option<String>,
    /// Point-data arrays of the first piece, in file order.
    arrays: Vec<ArrayDecl<'a>>,
    cell_names: Vec<String>,
    /// The `offset` of every appended DataArray (any piece, point or cell data): where each
    /// array's text ends (`locate`).
    offsets: Vec<usize>,
}

/// The XML part's declarations, gathered element by element ([`HeaderParser`]).
fn parse_header(xml: &str) -> Result<Header<'_>, VtiError> {
    // XML 1.0 has no NUL, not even escaped; a parser that skips one reads what the file's
    // author never wrote.
    if let Some(at) = xml.bytes().position(|b| b == 0) {
        return Err(VtiError::Nul { position: at });
    }
    let mut reader = Reader::from_str(xml);
    let mut p = HeaderParser {
        layout: Layout {
            order: ByteOrder::Little,
            header_size: 4,
            compressor: Compressor::None,
        },
        saw_root: false,
        whole_extent: None,
        piece_extents: Vec::new(),
        pieces: 0,
        origin: [0.0; 3],
        spacing: [1.0; 3],
        active: None,
        in_point: false,
        cell_names: Vec::new(),
        in_cell: false,
        arrays: Vec::new(),
        open_array: None,
        offsets: Vec::new(),
    };
    loop {
        let event = reader
            .read_event()
            .map_err(|error| VtiError::MalformedXml {
                position: reader.error_position(),
                error,
            })?;
        match event {
            Event::Start(ref e) => p.element(e, true)?,
            Event::Empty(ref e) => p.element(e, false)?,
            Event::Text(t) => p.text(t.into_inner()),
            Event::End(ref e) => match e.name().as_ref() {
                "DataArray" => p.open_array = None,
                "PointData" => p.in_point = false,
                "CellData" => p.in_cell = false,
                _ => {}
            },
            Event::Eof => break,
            _ => {}
        }
    }
    p.finish()
}

/// What the elements read so far declare.
struct HeaderParser<'a> {
    layout: Layout,
    saw_root: bool,
    whole_extent: Option<[i64; 6]>,
    piece_extents: Vec<[i64; 6]>,
    pieces: usize,
    origin: [f64; 3],
    spacing: [f64; 3],
    active: Option<String>,
    in_point: bool,
    cell_names: Vec<String>,
    in_cell: bool,
    arrays: Vec<ArrayDecl<'a>>,
    /// Index into `arrays` of the DataArray whose text is being collected.
    open_array: Option<usize>,
    offsets: Vec<usize>,
}

impl<'a> HeaderParser<'a> {
    /// An opening (`is_start`) or empty element.
    fn element(&mut self, e: &BytesStart<'_>, is_start: bool) -> Result<(), VtiError> {
        if e.name().as_ref() == "DataArray" {
            if let Some(o) = attr(e, "offset")?.and_then(|o| o.trim().parse().ok()) {
                self.offsets.push(o);
            }
        }
        match e.name().as_ref() {
            "VTKFile" => self.root(e)?,
            "ImageData" => self.image_data(e)?,
            "Piece" => {
                self.pieces += 1;
                if let Some(x) = attr(e, "Extent")? {
                    self.piece_extents
                        .push(numbers::<i64, 6>(&x, "Piece Extent")?);
                }
            }
            "PointData" => {
                self.active = attr(e, "Scalars")?;
                self.in_point = is_start;
            }
            "CellData" => self.in_cell = is_start,
            // Arrays of pieces after the first are not read (see the piece check in `finish`).
            "DataArray" if self.in_point && self.pieces <= 1 => self.data_array(e, is_start)?,
            "DataArray" if self.in_cell => {
                self.cell_names.push(attr(e, "Name")?.unwrap_or_default());
            }
            _ => {}
        }
        Ok(())
    }

    /// `<VTKFile>`: the file type and how binary data is laid out.
    fn root(&mut self, e: &BytesStart<'_>) -> Result<(), VtiError> {
        let a = |key: &str| attr(e, key);
        self.saw_root = true;
        let ty = a("type")?.unwrap_or_default();
        if ty != "ImageData" {
            return Err(VtiError::NotImageData { found: ty });
        }
        self.layout.order = match a("byte_order")?.as_deref() {
            None | Some("LittleEndian") => ByteOrder::Little,
            Some("BigEndian") => ByteOrder::Big,
            Some(o) => return Err(VtiError::UnknownByteOrder(o.to_string())),
        };
        self.layout.header_size = match a("header_type")?.as_deref() {
            None | Some("UInt32") => 4,
            Some("UInt64") => 8,
            Some(h) => return Err(VtiError::UnknownHeaderType(h.to_string())),
        };
        self.layout.compressor = match a("compressor")?.as_deref() {
            None | Some("") => Compressor::None,
            Some("vtkZLibDataCompressor") => Compressor::Zlib,
            Some("vtkLZ4DataCompressor") => Compressor::Lz4,
            Some("vtkLZMADataCompressor") => Compressor::Lzma,
            Some(c) => return Err(VtiError::UnknownCompressor(c.to_string())),
        };
        Ok(())
    }

    /// `<ImageData>`: extent, origin, spacing; a direction other than the identity is refused.
    fn image_data(&mut self, e: &BytesStart<'_>) -> Result<(), VtiError> {
        let a = |key: &str| attr(e, key);
        if let Some(w) = a("WholeExtent")? {
            self.whole_extent = Some(numbers::<i64, 6>(&w, "WholeExtent")?);
        }
        if let Some(o) = a("Origin")? {
            self.origin = numbers::<f64, 3>(&o, "Origin")?;
        }
        if let Some(s) = a("Spacing")? {
            self.spacing = numbers::<f64, 3>(&s, "Spacing")?;
        }
        if let Some(d) = a("Direction")? {
            let d = numbers::<f64, 9>(&d, "Direction")?;
            let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
            if d.iter().zip(identity).any(|(x, y)| (x - y).abs() > 1e-9) {
                return Err(VtiError::Rotated(d));
            }
        }
        Ok(())
    }

    /// A point-data `<DataArray>` of the first piece.
    fn data_array(&mut self, e: &BytesStart<'_>, is_start: bool) -> Result<(), VtiError> {
        let a = |key: &str| attr(e, key);
        let name = a("Name")?.unwrap_or_else(|| format!("array{}", self.arrays.len()));
        let Some(type_name) = a("type")? else {
            return Err(VtiError::NoType { name });
        };
        let components = match a("NumberOfComponents")? {
            None => 1,
            Some(c) => match c.trim().parse() {
                Ok(n) => n,
                Err(_) => return Err(VtiError::BadComponents { name, value: c }),
            },
        };
        let format = a("format")?.unwrap_or_else(|| "ascii".into());
        let offset = match a("offset")? {
            None => None,
            Some(o) => match o.trim().parse() {
                Ok(n) => Some(n),
                Err(_) => return Err(VtiError::BadOffset { name, value: o }),
            },
        };
        if is_start {
            self.open_array = Some(self.arrays.len());
        }
        self.arrays.push(ArrayDecl {
            name,
            type_name,
            components,
            format,
            offset,
            text: Cow::Borrowed(""),
        });
        Ok(())
    }

    /// Text inside the open DataArray, if any.
    fn text(&mut self, chunk: Cow<'a, str>) {
        if let Some(i) = self.open_array {
            let text = &mut self.arrays[i].text;
            if text.is_empty() {
                *text = chunk;
            } else {
                text.to_mut().push_str(&chunk);
            }
        }
    }

    /// The header, once the XML has been read.
    fn finish(self) -> Result<Header<'a>, VtiError> {
        if !self.saw_root {
            return Err(VtiError::NoVtkFile);
        }
        // VTK's writer asked for N pieces of a non-streaming source writes N copies of the
        // whole extent: any one of them is the data. Pieces that tile the extent are not
        // supported.
        if self.piece_extents.windows(2).any(|w| w[0] != w[1]) {
            return Err(VtiError::PiecesDiffer {
                pieces: self.piece_extents.len(),
            });
        }
        let extent = self
            .piece_extents
            .first()
            .copied()
            .or(self.whole_extent)
            .ok_or(VtiError::NoExtent)?;
        Ok(Header {
            layout: self.layout,
            extent,
            origin: self.origin,
            spacing: self.spacing,
            active: self.active,
            arrays: self.arrays,
            cell_names: self.cell_names,
            offsets: self.offsets,
        })
    }
}

/// Points per axis and the world position of the extent's first point.
fn grid(h: &Header<'_>) -> Result<([usize; 3], [f64; 3]), VtiError> {
    let (extent, spacing) = (h.extent, h.spacing);
    let mut origin = h.origin;
    let mut dims = [0usize; 3];
    for a in 0..3 {
        let (lo, hi) = (extent[2 * a], extent[2 * a + 1]);
        if hi < lo {
            return Err(VtiError::EmptyExtent { extent, axis: a });
        }
        dims[a] = usize::try_from(hi - lo + 1).map_err(|_| VtiError::ExtentTooLarge(extent))?;
        // Point (i, j, k) of the extent sits at origin + (i, j, k) * spacing; index 0 of our
        // grid is the extent's first point.
        origin[a] += lo as f64 * spacing[a];
    }
    dims.iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or(VtiError::ExtentTooLarge(extent))?;
    Ok((dims, origin))
}

/// The array to read: `want`, else the active scalars, else the first point-data array.
fn select<'h, 'a>(h: &'h Header<'a>, want: Option<&str>) -> Result<&'h ArrayDecl<'a>, VtiError> {
    let (arrays, cell_names) = (&h.arrays, &h.cell_names);
    let names = || {
        let mut s = arrays
            .iter()
            .map(|a| a.name.as_str())
            .collect::<Vec<_>>()
            .join(", ");
        if s.is_empty() {
            s = "none".into();
        }
        s
    };
    let index = match want {
        Some(w) => arrays.iter().position(|a| a.name == w).ok_or_else(|| {
            if cell_names.iter().any(|c| c == w) {
                VtiError::CellData(w.to_string())
            } else {
                VtiError::NoArrayNamed {
                    name: w.to_string(),
                    available: names(),
                }
            }
        })?,
        None => h
            .active
            .as_deref()
            .and_then(|s| arrays.iter().position(|a| a.name == s))
            .or(if arrays.is_empty() { None } else { Some(0) })
            .ok_or_else(|| {
                if cell_names.is_empty() {
                    VtiError::NoPointArrays
                } else {
                    VtiError::OnlyCellArrays(cell_names.join(", "))
                }
            })?,
    };
    Ok(&arrays[index])
}

/// The appended block: its encoding and the bytes after the `_` marker (up to the closing
/// tag for base64 text; to the end of the file for raw data, whose length the headers give).
struct Appended<'a> {
    base64: bool,
    data: &'a [u8],
}

fn appended_section(tail: &[u8]) -> Result<Appended<'_>, VtiError> {
    let close = tail
        .iter()
        .position(|&b| b == b'>')
        .ok_or(VtiError::AppendedNotClosed)?;
    let tag = std::str::from_utf8(&tail[..=close]).map_err(|_| VtiError::AppendedNotText)?;
    let mut r = Reader::from_str(tag);
    let encoding = match r.read_event() {
        Ok(Event::Start(e)) | Ok(Event::Empty(e)) => attr(&e, "encoding")?,
        _ => return Err(VtiError::MalformedTag(tag.to_string())),
    };
    let base64 = match encoding.as_deref() {
        Some("raw") => false,
        Some("base64") => true,
        other => {
            return Err(VtiError::AppendedEncoding(
                other.unwrap_or("(missing)").to_string(),
            ))
        }
    };
    let after = &tail[close + 1..];
    let underscore = after
        .iter()
        .position(|&b| b == b'_')
        .ok_or(VtiError::NoMarker)?;
    let mut data = &after[underscore + 1..];
    if base64 {
        if let Some(end) = find(data, b"</AppendedData") {
            data = &data[..end];
        }
    }
    Ok(Appended { base64, data })
}

/// Decode one array into `n` scalars.
fn read_array(
    decl: &ArrayDecl<'_>,
    n: usize,
    layout: Layout,
    appended: Option<&Appended<'_>>,
    budget: Budget,
) -> Result<TypedBuffer, ArrayError> {
    if decl.components != 1 {
        return Err(ArrayError::Components(decl.components));
    }
    let ty: ScalarType = decl
        .type_name
        .parse()
        .map_err(|_| ArrayError::UnknownType(decl.type_name.clone()))?;
    let nbytes = n.checked_mul(ty.size()).ok_or(ArrayError::SizeOverflows)?;
    // ASCII values are parsed into f64 first.
    let held = if decl.format == "ascii" { 8 } else { ty.size() };
    budget.check(
        format!("{n} values of its extent"),
        u64::try_from(n).ok(),
        held as u64,
        "the extent is larger than fits",
    )?;
    match decl.format.as_str() {
        "ascii" => {
            let text: &str = &decl.text;
            let mut values = Vec::with_capacity(n);
            for (i, tok) in text.split_ascii_whitespace().enumerate() {
                if i == n {
                    return Err(ArrayError::TooManyValues(n));
                }
                let v: f64 = tok.parse().map_err(|_| ArrayError::NotANumber {
                    index: i,
                    text: tok.chars().take(40).collect(),
                })?;
                TypedBuffer::check_text_token(tok, i, ty)?;
                values.push(v);
            }
            if values.len() != n {
                return Err(ArrayError::ValueCount {
                    found: values.len(),
                    needed: n,
                });
            }
            TypedBuffer::check_text_values(&values, ty)?;
            Ok(TypedBuffer::from_f64_as(values, ty))
        }
        "binary" => {
            let stream = base64_streams(decl.text.as_bytes())?;
            let data = unpack(&stream, layout, nbytes, budget)?;
            Ok(TypedBuffer::new(ty, layout.order, data))
        }
        "appended" => {
            let app = appended.ok_or(ArrayError::NoAppendedData)?;
            let offset = decl.offset.ok_or(ArrayError::NoOffset)?;
            let start = app.data.get(offset..).ok_or(ArrayError::OffsetPastEnd {
                offset,
                len: app.data.len(),
            })?;
            let data = if app.base64 {
                unpack(&base64_streams(start)?, layout, nbytes, budget)?
            } else {
                unpack(start, layout, nbytes, budget)?
            };
            Ok(TypedBuffer::new(ty, layout.order, data))
        }
        f => Err(ArrayError::UnknownFormat(f.to_string())),
    }
}

/// An attribute's unescaped value.
fn attr(e: &BytesStart<'_>, key: &str) -> Result<Option<String>, VtiError> {
    for a in e.attributes() {
        let a = a.map_err(VtiError::MalformedAttribute)?;
        if a.key.as_ref() == key {
            let v = a
                .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                .map_err(|error| VtiError::MalformedAttributeValue {
                    key: key.to_string(),
                    error,
                })?;
            return Ok(Some(v.into_owned()));
        }
    }
    Ok(None)
}

/// Exactly `N` whitespace-separated numbers.
fn numbers<T: std::str::FromStr, const N: usize>(
    s: &str,
    what: &'static str,
) -> Result<[T; N], VtiError> {
    let err = || VtiError::NotNumbers {
        what,
        text: s.to_string(),
        count: N,
    };
    let v: Vec<T> = s
        .split_ascii_whitespace()
        .map(|x| x.parse::<T>())
        .collect::<Result<_, _>>()
        .map_err(|_| err())?;
    v.try_into().map_err(|_| err())
}

/// First occurrence of `needle` in `hay`.
fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// How each fixture's arrays (VTK's own writer made them) are located: every compressed
    /// or base64 single-component array is read block by block.
    #[test]
    fn fixtures_locate_as_blocks_where_compressed_or_base64() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/volumes");
        // (file, array, 'b' blocks / 'o' offset (mapped) / '-' decoded whole)
        let cases = [
            ("appended_base64_float32_lz4.vti", None, 'b'),
            ("appended_base64_int8.vti", None, 'b'),
            ("appended_base64_uint32_zlib.vti", None, 'b'),
            ("appended_raw_float32_lzma.vti", None, 'b'),
            ("appended_raw_float64_zlib.vti", None, 'b'),
            ("appended_raw_int32_lz4.vti", None, 'b'),
            ("appended_raw_uint16.vti", None, 'o'),
            ("arrays.vti", Some("temperature"), 'b'),
            ("arrays.vti", Some("density"), 'b'),
            ("arrays.vti", Some("velocity"), '-'),
            ("arrays.vti", Some("last"), 'b'),
            ("arrays_raw.vti", None, 'o'),
            ("arrays_raw_lz4.vti", None, 'b'),
            ("ascii_float32.vti", None, '-'),
            ("ascii_int16.vti", None, '-'),
            ("bigendian_float32.vti", None, 'b'),
            ("bigendian_int64_zlib.vti", None, 'b'),
            ("binary_float64_lzma.vti", None, 'b'),
            ("binary_int16_zlib.vti", None, 'b'),
            ("binary_uint64_lz4.vti", None, 'b'),
            ("binary_uint8.vti", None, 'b'),
            ("binary_uint8_u64.vti", None, 'b'),
            ("no_active.vti", None, 'b'),
            ("no_active.vti", Some("second"), 'b'),
            ("two_pieces.vti", None, 'b'),
        ];
        for (file, array, want) in cases {
            let bytes = std::fs::read(dir.join(file)).unwrap();
            let got = match locate(&bytes, array).map(|l| l.at) {
                Some(At::Blocks(_)) => 'b',
                Some(At::Offset(_)) => 'o',
                None => '-',
            };
            assert_eq!(got, want, "{file} {array:?}");
        }
    }

    /// Base64 text wrapped in lines (other writers) is decoded whole, not by character.
    #[test]
    fn wrapped_base64_is_decoded_whole() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/volumes");
        let text = std::fs::read_to_string(dir.join("binary_int16_zlib.vti")).unwrap();
        let start = text.find("format=\"binary\"").unwrap();
        let body = text[start..].find('>').unwrap() + start + 1;
        let data = text[body..].trim_start();
        let at = text.len() - data.len() + 40;
        let wrapped = format!("{}\n{}", &text[..at], &text[at..]);
        assert!(locate(wrapped.as_bytes(), None).is_none());
        assert!(locate(text.as_bytes(), None).is_some());
        let a = decode(
            Path::new("w.vti"),
            wrapped.as_bytes(),
            None,
            Budget::system(),
        )
        .unwrap();
        let b = decode(Path::new("w.vti"), text.as_bytes(), None, Budget::system()).unwrap();
        assert_eq!(a.buffer.raw().2, b.buffer.raw().2);
    }
}
