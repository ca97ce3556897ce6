//! ParaView XML colour maps: `<ColorMaps><ColorMap name= space="RGB"><Point x= o= r= g= b=/>`.
//! ParaView's import keeps only the colours (DESIGN.md); `o` is still written for the tools
//! that read it, and for our own reader.

use std::path::Path;

use quick_xml::escape::escape;
use quick_xml::events::{BytesStart, Event};
use quick_xml::{Reader, XmlVersion};

use super::points::{merge, split, MergedPoint};
use super::{ExportTf, FormatError};

/// Attribute carrying the unit distance (ParaView ignores unknown attributes; tested).
const UNIT_DISTANCE_ATTR: &str = "t2tfScalarOpacityUnitDistance";

pub fn to_paraview_xml(tf: &ExportTf) -> String {
    let mut s = String::from("<ColorMaps>\n");
    s.push_str(&format!(
        "  <ColorMap name=\"{}\" space=\"RGB\"",
        escape(tf.name.as_str())
    ));
    if let Some(u) = tf.unit_distance {
        s.push_str(&format!(" {UNIT_DISTANCE_ATTR}=\"{u:?}\""));
    }
    s.push_str(">\n");
    for p in merge(tf) {
        s.push_str(&format!("    <Point x=\"{:?}\"", p.x));
        if let Some(o) = p.opacity {
            s.push_str(&format!(" o=\"{o:?}\""));
        }
        s.push_str(&format!(
            " r=\"{:?}\" g=\"{:?}\" b=\"{:?}\"/>\n",
            p.rgb[0], p.rgb[1], p.rgb[2]
        ));
    }
    s.push_str("  </ColorMap>\n</ColorMaps>\n");
    s
}

/// Read the first `<ColorMap>` of a file.
pub fn from_paraview_xml(text: &str, path: &Path) -> Result<ExportTf, FormatError> {
    let err = |m: String| FormatError::file(path, m);
    let mut reader = Reader::from_str(text);
    let mut name: Option<String> = None;
    let mut unit_distance = None;
    let mut points: Vec<MergedPoint> = Vec::new();
    let mut in_map = false;
    loop {
        let event = reader
            .read_event()
            .map_err(|e| err(format!("is not valid XML: {e}")))?;
        match event {
            Event::Start(e) | Event::Empty(e) => match e.name().as_ref() {
                "ColorMap" if name.is_none() => {
                    in_map = true;
                    let space = attr(&e, "space", path)?.unwrap_or_else(|| "RGB".into());
                    if !space.eq_ignore_ascii_case("rgb") {
                        return Err(err(format!(
                            "colour space \"{space}\" is not supported (only RGB)"
                        )));
                    }
                    name = Some(attr(&e, "name", path)?.unwrap_or_else(|| "t2tf".into()));
                    unit_distance = attr(&e, UNIT_DISTANCE_ATTR, path)?
                        .map(|v| number(&v, UNIT_DISTANCE_ATTR, path))
                        .transpose()?;
                }
                "Point" if in_map => {
                    let i = points.len();
                    let get = |key: &str| -> Result<Option<f64>, FormatError> {
                        attr(&e, key, path)?
                            .map(|v| number(&v, &format!("Point {i} attribute {key}"), path))
                            .transpose()
                    };
                    let need = |key: &str| {
                        get(key)?.ok_or_else(|| err(format!("Point {i} has no \"{key}\"")))
                    };
                    points.push(MergedPoint {
                        x: need("x")?,
                        rgb: [need("r")?, need("g")?, need("b")?],
                        opacity: get("o")?,
                    });
                }
                _ => {}
            },
            Event::End(e) if e.name().as_ref() == "ColorMap" => in_map = false,
            Event::Eof => break,
            _ => {}
        }
    }
    let name = name.ok_or_else(|| err("has no <ColorMap> element".into()))?;
    if points.is_empty() {
        return Err(err("its <ColorMap> has no <Point> elements".into()));
    }
    let (rgb_points, opacity_points) = split(&points);
    let tf = ExportTf {
        name,
        rgb_points,
        opacity_points,
        unit_distance,
    };
    tf.validate(path)?;
    Ok(tf)
}

pub(crate) fn attr(e: &BytesStart, key: &str, path: &Path) -> Result<Option<String>, FormatError> {
    for a in e.attributes() {
        let a = a.map_err(|x| FormatError::file(path, format!("bad XML attribute: {x}")))?;
        if a.key.as_ref() == key {
            let v = a
                .normalized_value(XmlVersion::Implicit1_0)
                .map_err(|x| FormatError::file(path, format!("bad value of \"{key}\": {x}")))?;
            return Ok(Some(v.into_owned()));
        }
    }
    Ok(None)
}

pub(crate) fn number(s: &str, what: &str, path: &Path) -> Result<f64, FormatError> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| FormatError::file(path, format!("{what} = \"{s}\" is not a finite number")))
}
