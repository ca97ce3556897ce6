//! VisIt colour tables (`.ct`): `<Object name="ColorTable">` → `ColorControlPointList` →
//! `ColorControlPoint` with `colors` (RGBA, 4 unsigned chars) and `position` in [0, 1].
//!
//! The format has no data range and 8-bit colours, so a round trip keeps colours and opacity
//! to ±0.5/255. We add two fields VisIt's reader skips (it looks its fields up by name):
//! the data range the positions span and the unit distance, so our reader restores data units.

use std::path::Path;

use quick_xml::events::{BytesStart, Event};
use quick_xml::Reader;

use super::paraview_xml::{attr, number};
use super::points::{merge, rgb_map, split, MergedPoint};
use super::{only_preset, ExportTf, FormatError, Preset, TfFormat};

const RANGE_FIELD: &str = "t2tfDataRange";
const UNIT_DISTANCE_FIELD: &str = "t2tfScalarOpacityUnitDistance";

/// VisIt colour tables (`.ct`): one RGB table per file, 8-bit colours and alpha.
pub(crate) struct VisItCt;

// Shaped like paraview_json.rs's and paraview_xml.rs's impls: one entry of the `TfFormat`
// table each.
impl TfFormat for VisItCt {
    fn name(&self) -> &'static str {
        "VisIt colour table"
    }

    fn extensions(&self) -> &'static [&'static str] {
        &["ct"]
    }

    fn read_preset(
        &self,
        text: &str,
        path: &Path,
        name: Option<&str>,
    ) -> Result<Preset, FormatError> {
        only_preset(Preset::rgb(from_visit_ct(text, path)?), path, name)
    }

    /// The table interpolates in RGB only: other colour spaces are densified first.
    fn write_preset(&self, preset: &Preset) -> String {
        to_visit_ct(&preset.rgb_linear())
    }

    /// The table's points as they are: densifying would blur its jumps (repeated positions).
    fn read_tf(&self, text: &str, path: &Path) -> Result<ExportTf, FormatError> {
        from_visit_ct(text, path)
    }

    /// The TF's points as they are (see `read_tf`).
    fn write_tf(&self, tf: &ExportTf) -> String {
        to_visit_ct(tf)
    }
}

fn byte(v: f64) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// The table: colours from the TF, alpha from its opacity (255 when it has none).
pub fn to_visit_ct(tf: &ExportTf) -> String {
    let [lo, hi] = tf.data_range();
    let span = if hi > lo { hi - lo } else { 1.0 };
    let mut s = String::from("<?xml version=\"1.0\"?>\n<Object name=\"ColorTable\">\n");
    s.push_str("    <Field name=\"Version\" type=\"string\">3.3.0</Field>\n");
    s.push_str(&format!(
        "    <Field name=\"{RANGE_FIELD}\" type=\"doubleArray\" length=\"2\">{lo:?} {hi:?} </Field>\n"
    ));
    if let Some(u) = tf.unit_distance {
        s.push_str(&format!(
            "    <Field name=\"{UNIT_DISTANCE_FIELD}\" type=\"double\">{u:?}</Field>\n"
        ));
    }
    s.push_str("    <Object name=\"ColorControlPointList\">\n");
    for p in merge(tf, &rgb_map(tf), false) {
        let a = p.opacity.map_or(255, byte);
        let [r, g, b] = p.rgb.map(byte);
        // VisIt stores positions as float: f32 precision is what the format holds.
        let pos = (((p.x - lo) / span).clamp(0.0, 1.0)) as f32;
        s.push_str("        <Object name=\"ColorControlPoint\">\n");
        s.push_str(&format!(
            "            <Field name=\"colors\" type=\"unsignedCharArray\" length=\"4\">{r} {g} {b} {a} </Field>\n"
        ));
        s.push_str(&format!(
            "            <Field name=\"position\" type=\"float\">{pos:?}</Field>\n"
        ));
        s.push_str("        </Object>\n");
    }
    s.push_str("    </Object>\n</Object>\n");
    s
}

/// Read a `.ct`; positions map onto the stored data range, else onto [0, 1].
pub(crate) fn from_visit_ct(text: &str, path: &Path) -> Result<ExportTf, FormatError> {
    let mut ct = CtReader::default();
    let mut reader = Reader::from_str(text);
    loop {
        let event = reader
            .read_event()
            .map_err(|e| FormatError::file(path, format!("is not valid XML: {e}")))?;
        match event {
            Event::Start(e) => ct.start(&e, path)?,
            Event::Text(t) if ct.field.is_some() => ct.field_text.push_str(&t),
            Event::End(e) => match e.name().as_ref() {
                "Field" => ct.end_field(path)?,
                "Object" => ct.end_object(path)?,
                _ => {}
            },
            Event::Eof => break,
            _ => {}
        }
    }
    ct.finish(path)
}

/// What the reader has gathered while walking the XML: a table is nested `<Object>`s whose
/// values are `<Field name=…>` texts.
#[derive(Default)]
struct CtReader {
    /// Names of the open `<Object>`s, innermost last.
    objects: Vec<String>,
    /// The `<Field>` being read, and its text so far.
    field: Option<String>,
    field_text: String,
    /// The open control point's fields.
    colors: Option<[f64; 4]>,
    position: Option<f64>,
    /// Finished control points: RGBA in 0..255, position.
    raw: Vec<([f64; 4], f64)>,
    /// t2tf's own fields of the table.
    range: Option<[f64; 2]>,
    unit_distance: Option<f64>,
    saw_table: bool,
}

impl CtReader {
    fn start(&mut self, e: &BytesStart, path: &Path) -> Result<(), FormatError> {
        match e.name().as_ref() {
            "Object" => {
                let n = attr(e, "name", path)?.unwrap_or_default();
                self.saw_table |= n == "ColorTable";
                self.objects.push(n);
            }
            "Field" => {
                self.field = attr(e, "name", path)?;
                self.field_text.clear();
            }
            _ => {}
        }
        Ok(())
    }

    /// A finished `<Field>`: kept when it is one the table or a control point defines.
    fn end_field(&mut self, path: &Path) -> Result<(), FormatError> {
        let name = self.field.take().unwrap_or_default();
        let nums = || -> Result<Vec<f64>, FormatError> {
            self.field_text
                .split_whitespace()
                .map(|v| number(v, &format!("field \"{name}\""), path))
                .collect()
        };
        match (self.objects.last().map(String::as_str), name.as_str()) {
            (Some("ColorControlPoint"), "colors") => {
                let v = nums()?;
                if !(v.len() == 3 || v.len() == 4) || v.iter().any(|c| !(0.0..=255.0).contains(c)) {
                    return Err(FormatError::file(
                        path,
                        format!(
                            "control point {}: colors \"{}\" are not 3 or 4 values in 0..255",
                            self.raw.len(),
                            self.field_text.trim()
                        ),
                    ));
                }
                self.colors = Some([v[0], v[1], v[2], *v.get(3).unwrap_or(&255.0)]);
            }
            (Some("ColorControlPoint"), "position") => self.position = nums()?.first().copied(),
            (Some("ColorTable"), RANGE_FIELD) => {
                let v = nums()?;
                if v.len() != 2 || v[1] < v[0] {
                    return Err(FormatError::file(
                        path,
                        format!("\"{RANGE_FIELD}\" is not \"min max\""),
                    ));
                }
                self.range = Some([v[0], v[1]]);
            }
            (Some("ColorTable"), UNIT_DISTANCE_FIELD) => {
                self.unit_distance = nums()?.first().copied();
            }
            _ => {}
        }
        Ok(())
    }

    /// A closing `</Object>`: a control point needs both its fields.
    fn end_object(&mut self, path: &Path) -> Result<(), FormatError> {
        if self.objects.pop().as_deref() != Some("ColorControlPoint") {
            return Ok(());
        }
        let i = self.raw.len();
        let missing =
            |what: &str| FormatError::file(path, format!("control point {i} has no {what}"));
        let c = self.colors.take().ok_or_else(|| missing("colors"))?;
        let p = self.position.take().ok_or_else(|| missing("position"))?;
        self.raw.push((c, p));
        Ok(())
    }

    /// The TF the table describes, its points sorted and mapped onto the data range.
    fn finish(mut self, path: &Path) -> Result<ExportTf, FormatError> {
        if !self.saw_table {
            return Err(FormatError::file(
                path,
                "is not a VisIt colour table (no <Object name=\"ColorTable\">)",
            ));
        }
        if self.raw.is_empty() {
            return Err(FormatError::file(path, "has no ColorControlPoint"));
        }
        // VisIt sorts control points by position itself; do the same (stable for equal ones).
        self.raw.sort_by(|a, b| a.1.total_cmp(&b.1));
        let [lo, hi] = self.range.unwrap_or([0.0, 1.0]);
        let points: Vec<MergedPoint> = self
            .raw
            .iter()
            .map(|(c, p)| MergedPoint {
                x: lo + p * (hi - lo),
                rgb: [c[0] / 255.0, c[1] / 255.0, c[2] / 255.0],
                opacity: Some(c[3] / 255.0),
            })
            .collect();
        let (rgb_points, opacity_points) = split(&points);
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "t2tf".into());
        let tf = ExportTf {
            name,
            rgb_points,
            opacity_points,
            unit_distance: self.unit_distance,
        };
        tf.validate(path)?;
        Ok(tf)
    }
}
