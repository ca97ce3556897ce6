//! ParaView XML colour maps: `<ColorMaps><ColorMap name= space="RGB"><Point x= o= r= g= b=/>`.
//! ParaView's import keeps only the colours (docs/DESIGN.md "ParaView facts"); `o` is still written for the tools
//! that read it, and for our own reader.

use std::path::Path;

use quick_xml::events::{BytesStart, Event};
use quick_xml::{Reader, XmlVersion};

use super::points::{merge, split, MergedPoint};
use super::{only_preset, ExportTf, FormatError, Preset, TfFormat};
use t2tf_tf::{ColorMap, ColorSpace};

/// Attribute carrying the unit distance (ParaView ignores unknown attributes; tested).
const UNIT_DISTANCE_ATTR: &str = "t2tfScalarOpacityUnitDistance";

/// ParaView XML colour maps (`.xml`): one map per file, in any colour space.
pub(crate) struct ParaViewXml;

impl TfFormat for ParaViewXml {
    fn name(&self) -> &'static str {
        "ParaView XML colour map"
    }

    fn extensions(&self) -> &'static [&'static str] {
        &["xml"]
    }

    fn read_preset(
        &self,
        text: &str,
        path: &Path,
        name: Option<&str>,
    ) -> Result<Preset, FormatError> {
        only_preset(preset_from_paraview_xml(text, path)?, path, name)
    }

    fn write_preset(&self, preset: &Preset) -> String {
        preset_to_paraview_xml(preset)
    }
}

/// An RGB TF as a colour map with opacity in `o`.
pub fn to_paraview_xml(tf: &ExportTf) -> String {
    preset_to_paraview_xml(&Preset::rgb(tf.clone()))
}

/// The colour map in its own colour space (`space=`, ParaView's names). Colours and opacity
/// share positions in this format: where opacity has points of its own, colours are added
/// there, which keeps the curve in RGB, HSV, Lab and Step (linear in their coordinates, or
/// constant); Diverging and Lab/CIEDE2000 are not, so such a map is written RGB-linear.
pub(crate) fn preset_to_paraview_xml(p: &Preset) -> String {
    let same_x = p.tf.opacity_points.is_empty()
        || p.tf
            .opacity_points
            .iter()
            .map(|q| q.0)
            .eq(p.tf.rgb_points.iter().map(|q| q.0));
    let splittable = matches!(
        p.space,
        ColorSpace::Rgb | ColorSpace::Hsv | ColorSpace::Lab | ColorSpace::Step
    );
    let (tf, space) = if same_x || splittable {
        (p.tf.clone(), p.space)
    } else {
        (p.rgb_linear(), ColorSpace::Rgb)
    };
    let map = ColorMap {
        points: tf.rgb_points.clone(),
        space,
        hsv_wrap: p.hsv_wrap,
    };
    let mut s = String::from("<ColorMaps>\n");
    s.push_str(&format!(
        "  <ColorMap name=\"{}\" space=\"{}\"",
        crate::xml_text(&tf.name),
        space.paraview_name()
    ));
    if space == ColorSpace::Hsv && p.hsv_wrap {
        s.push_str(" t2tfHSVWrap=\"1\"");
    }
    if let Some(u) = tf.unit_distance {
        s.push_str(&format!(" {UNIT_DISTANCE_ATTR}=\"{u:?}\""));
    }
    s.push_str(">\n");
    for p in merge(&tf, &map, true) {
        s.push_str(&format!("    <Point x=\"{:?}\"", p.x));
        if let Some(o) = p.opacity {
            s.push_str(&format!(" o=\"{o:?}\""));
        }
        s.push_str(&format!(
            " r=\"{:?}\" g=\"{:?}\" b=\"{:?}\"/>\n",
            p.rgb[0], p.rgb[1], p.rgb[2]
        ));
    }
    if let Some(c) = p.extra_color("NanColor") {
        s.push_str(&format!(
            "    <NaN r=\"{:?}\" g=\"{:?}\" b=\"{:?}\"/>\n",
            c[0], c[1], c[2]
        ));
    }
    s.push_str("  </ColorMap>\n</ColorMaps>\n");
    s
}

/// Read the first `<ColorMap>` of a file in its own colour space.
pub(crate) fn preset_from_paraview_xml(text: &str, path: &Path) -> Result<Preset, FormatError> {
    let err = |m: String| FormatError::file(path, m);
    let mut reader = Reader::from_str(text);
    let mut name: Option<String> = None;
    let mut unit_distance = None;
    let (mut space, mut hsv_wrap) = (ColorSpace::Rgb, false);
    let mut extra = serde_json::Map::new();
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
                    let s = attr(&e, "space", path)?.unwrap_or_else(|| "RGB".into());
                    space = ColorSpace::parse(&s).ok_or_else(|| {
                        err(format!(
                            "colour space \"{s}\" is not one ParaView writes (RGB, HSV, Lab, CIELAB, Diverging, Lab/CIEDE2000, Step)"
                        ))
                    })?;
                    hsv_wrap = attr(&e, "t2tfHSVWrap", path)?.is_some_and(|v| v.trim() == "1");
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
                "NaN" if in_map => {
                    let c = |k: &str| -> Result<f64, FormatError> {
                        let v = attr(&e, k, path)?
                            .ok_or_else(|| err(format!("<NaN> has no \"{k}\"")))?;
                        number(&v, &format!("<NaN> attribute {k}"), path)
                    };
                    extra.insert(
                        "NanColor".into(),
                        serde_json::json!([c("r")?, c("g")?, c("b")?]),
                    );
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
    let (mut rgb_points, opacity_points) = split(&points);
    if space != ColorSpace::Rgb {
        // Points collinear in RGB are not collinear in another space: keep them all.
        rgb_points = points.iter().map(|p| (p.x, p.rgb)).collect();
    }
    let tf = ExportTf {
        name,
        rgb_points,
        opacity_points,
        unit_distance,
    };
    tf.validate(path)?;
    Ok(Preset {
        tf,
        space,
        hsv_wrap,
        extra,
    })
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
