//! [`Preset`]: a colour map as a file holds it — the colour points in their own colour space
//! plus the keys t2tf does not interpret — so that converting between ParaView JSON and XML
//! keeps what ParaView would show, and targets that interpolate only in RGB (VisIt tables,
//! the renderer's LUT) get a densified RGB-linear copy.

use serde_json::{Map, Value};

use super::ExportTf;
use t2tf_tf::{ColorMap, ColorSpace, EXPORT_TOLERANCE};

/// One preset of a file.
#[derive(Clone, Debug, PartialEq)]
pub struct Preset {
    /// Points in data units; `tf.rgb_points` are interpolated in `space`, not in RGB.
    pub tf: ExportTf,
    /// The colour space `tf.rgb_points` are interpolated in.
    pub space: ColorSpace,
    /// HSV only: ParaView's `HSVWrap`.
    pub hsv_wrap: bool,
    /// JSON keys kept verbatim for JSON output (`NanColor`, `AboveRangeColor`,
    /// `UseAboveRangeColor`, `Annotations`, `Creator`, `DefaultMap`, …). The XML writer keeps
    /// the NaN/above/below colours; VisIt tables have no place for any of them.
    pub extra: Map<String, Value>,
}

impl Preset {
    /// An RGB preset with nothing else.
    pub fn rgb(tf: ExportTf) -> Preset {
        Preset {
            tf,
            space: ColorSpace::Rgb,
            hsv_wrap: false,
            extra: Map::new(),
        }
    }

    /// The colour points with their colour space and HSV wrap.
    pub fn color_map(&self) -> ColorMap {
        ColorMap {
            points: self.tf.rgb_points.clone(),
            space: self.space,
            hsv_wrap: self.hsv_wrap,
        }
    }

    /// The TF with colours as an RGB-linear polyline within [`EXPORT_TOLERANCE`] of what
    /// ParaView computes (what VisIt tables and the renderer interpolate).
    pub fn rgb_linear(&self) -> ExportTf {
        ExportTf {
            rgb_points: self.color_map().rgb_linear(EXPORT_TOLERANCE),
            ..self.tf.clone()
        }
    }

    /// A colour kept in `extra` under `key` (three numbers), if present and well formed.
    pub(crate) fn extra_color(&self, key: &str) -> Option<[f64; 3]> {
        let a = self.extra.get(key)?.as_array()?;
        let v: Vec<f64> = a.iter().filter_map(Value::as_f64).collect();
        (v.len() >= 3).then(|| [v[0], v[1], v[2]])
    }
}
