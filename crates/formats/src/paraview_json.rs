//! ParaView JSON presets: a top-level array of objects with `RGBPoints` (x, r, g, b) and
//! opacity `Points` (x, o, midpoint, sharpness) quadruples (what ParaView's own
//! `ExportTransferFunction` writes; a real one is the reader's test fixture).

use std::path::Path;

use serde_json::{json, Value};

use super::{ExportTf, FormatError, PointCounts, Preset, PresetSummary, TfFormat};
use t2tf_tf::ColorSpace;

/// ParaView JSON presets (`.json`): one file can hold many, in any colour space.
pub(crate) struct ParaViewJson;

impl TfFormat for ParaViewJson {
    fn name(&self) -> &'static str {
        "ParaView JSON preset"
    }

    fn extensions(&self) -> &'static [&'static str] {
        &["json"]
    }

    fn read_preset(
        &self,
        text: &str,
        path: &Path,
        name: Option<&str>,
    ) -> Result<Preset, FormatError> {
        preset_from_paraview_json(text, path, name)
    }

    fn list(&self, text: &str, path: &Path) -> Result<Vec<PresetSummary>, FormatError> {
        list_paraview_json(text, path)
    }

    fn write_preset(&self, preset: &Preset) -> String {
        preset_to_paraview_json(preset)
    }
}

/// Key carrying the unit distance; ParaView ignores keys it does not know (tested).
const UNIT_DISTANCE_KEY: &str = "t2tfScalarOpacityUnitDistance";

/// Keys the reader interprets; every other key of a preset is kept in [`Preset::extra`].
const KNOWN_KEYS: [&str; 7] = [
    "Name",
    "ColorSpace",
    "HSVWrap",
    "RGBPoints",
    "Points",
    UNIT_DISTANCE_KEY,
    PARAVIEW_UNIT_DISTANCE_KEY,
];

/// The unit distance under the name of ParaView's volume property, accepted on read.
const PARAVIEW_UNIT_DISTANCE_KEY: &str = "ScalarOpacityUnitDistance";

/// An RGB preset as strict JSON (serde_json prints the shortest repr that reads back exactly).
pub fn to_paraview_json(tf: &ExportTf) -> String {
    preset_to_paraview_json(&Preset::rgb(tf.clone()))
}

/// The preset as strict JSON, with its colour space and the keys it kept.
pub(crate) fn preset_to_paraview_json(p: &Preset) -> String {
    let tf = &p.tf;
    let rgb: Vec<f64> = tf
        .rgb_points
        .iter()
        .flat_map(|&(x, c)| [x, c[0], c[1], c[2]])
        .collect();
    let opacity: Vec<f64> = tf
        .opacity_points
        .iter()
        .flat_map(|&(x, o)| [x, o, 0.5, 0.0])
        .collect();
    let mut preset = json!({
        "Name": tf.name,
        "Creator": "t2tf",
        "ColorSpace": p.space.paraview_name(),
        "RGBPoints": rgb,
    });
    if p.space == ColorSpace::Hsv {
        preset["HSVWrap"] = json!(p.hsv_wrap as i32);
    }
    if !opacity.is_empty() {
        preset["Points"] = json!(opacity);
    }
    if let Some(u) = tf.unit_distance {
        preset[UNIT_DISTANCE_KEY] = json!(u);
    }
    for (k, v) in &p.extra {
        preset[k] = v.clone();
    }
    let mut s = serde_json::to_string_pretty(&json!([preset])).expect("JSON of numbers");
    s.push('\n');
    s
}

/// Several RGB presets in one ParaView JSON file: *Import Presets* adds each of them.
pub fn to_paraview_library(tfs: &[ExportTf]) -> String {
    let presets: Vec<serde_json::Value> = tfs
        .iter()
        .flat_map(|tf| match serde_json::from_str(&to_paraview_json(tf)) {
            Ok(serde_json::Value::Array(items)) => items,
            _ => unreachable!("to_paraview_json writes an array"),
        })
        .collect();
    let mut s = serde_json::to_string_pretty(&presets).expect("JSON of numbers");
    s.push('\n');
    s
}

/// Every preset of a JSON file (a top-level array, or one object).
fn preset_values<'a>(root: &'a Value, path: &Path) -> Result<Vec<&'a Value>, FormatError> {
    match root {
        Value::Array(a) if a.iter().all(Value::is_object) && !a.is_empty() => {
            Ok(a.iter().collect())
        }
        Value::Object(_) => Ok(vec![root]),
        _ => Err(FormatError::file(
            path,
            "is not a ParaView preset (expected an array of objects)",
        )),
    }
}

fn parse(text: &str, path: &Path) -> Result<Value, FormatError> {
    serde_json::from_str(text)
        .map_err(|e| FormatError::file(path, format!("is not valid JSON: {e}")))
}

fn name_of(p: &Value) -> String {
    p.get("Name")
        .and_then(Value::as_str)
        .unwrap_or("t2tf")
        .to_string()
}

/// The presets of a file, in file order, for `t2tf convert --list`.
fn list_paraview_json(text: &str, path: &Path) -> Result<Vec<PresetSummary>, FormatError> {
    let root = parse(text, path)?;
    let count = |p: &Value, k: &str| {
        p.get(k)
            .and_then(Value::as_array)
            .map_or(0, |a| a.len() / 4)
    };
    Ok(preset_values(&root, path)?
        .into_iter()
        .map(|p| PresetSummary {
            name: name_of(p),
            space: p.get("RGBPoints").map(|_| {
                p.get("ColorSpace")
                    .and_then(Value::as_str)
                    .unwrap_or("RGB")
                    .to_string()
            }),
            // The points as the preset is read (and converted), so the listing and `convert`
            // count alike; a preset t2tf cannot read shows what the file stores.
            counts: Some(match read_one(p, path) {
                Ok(preset) => PointCounts::of(&preset.tf),
                Err(_) => PointCounts {
                    colour: count(p, "RGBPoints"),
                    opacity: count(p, "Points"),
                },
            }),
        })
        .collect())
}

/// Parse a preset file's text as the RGB-linear TF the renderer and VisIt see (colours in
/// another space are densified, see [`Preset::rgb_linear`]). A file with several presets
/// is refused with their names: pick one with [`read_preset`](super::read_preset).
pub fn from_paraview_json(text: &str, path: &Path) -> Result<ExportTf, FormatError> {
    Ok(preset_from_paraview_json(text, path, None)?.rgb_linear())
}

/// The preset called `name` (or the only one) of a preset file, in its own colour space.
/// Opacity `Points` with sharpness 0 and any midpoint are exact (the midpoint becomes an
/// extra point at half the opacity step); sharpness ≠ 0 is rejected.
pub(crate) fn preset_from_paraview_json(
    text: &str,
    path: &Path,
    name: Option<&str>,
) -> Result<Preset, FormatError> {
    let root = parse(text, path)?;
    let presets = preset_values(&root, path)?;
    let preset = choose(&presets, name, path)?;
    read_one(preset, path)
}

/// Pick the preset named `name`, or the only one; otherwise say which names there are.
fn choose<'a>(
    presets: &[&'a Value],
    name: Option<&str>,
    path: &Path,
) -> Result<&'a Value, FormatError> {
    let names: Vec<String> = presets.iter().map(|p| name_of(p)).collect();
    let listing = || {
        let shown: Vec<String> = names.iter().take(20).map(|n| format!("\"{n}\"")).collect();
        let more = names.len().saturating_sub(20);
        let tail = if more > 0 {
            format!(" and {more} more")
        } else {
            String::new()
        };
        format!("{}{tail}", shown.join(", "))
    };
    match name {
        None if presets.len() == 1 => Ok(presets[0]),
        None => Err(FormatError::about(
            path,
            "preset",
            format!(
                "holds {} presets; pick one as `preset`: {}",
                presets.len(),
                listing()
            ),
        )),
        Some(n) => {
            let mut hits: Vec<usize> = (0..names.len()).filter(|&i| names[i] == n).collect();
            // ParaView's library names some maps twice, once continuous and once categorical.
            if hits.len() > 1 {
                hits.retain(|&i| presets[i].get("RGBPoints").is_some());
            }
            match hits.as_slice() {
                [i] => Ok(presets[*i]),
                [] => Err(FormatError::about(
                    path,
                    "preset",
                    format!("has no preset \"{n}\"; it holds {}", listing()),
                )),
                _ => Err(FormatError::about(
                    path,
                    "preset",
                    format!("holds {} presets named \"{n}\"", hits.len()),
                )),
            }
        }
    }
}

/// One preset object → [`Preset`].
fn read_one(preset: &Value, path: &Path) -> Result<Preset, FormatError> {
    let name = name_of(preset);
    let err = |m: String| FormatError::file(path, format!("preset \"{name}\": {m}"));
    if preset.get("RGBPoints").is_none() {
        let categorical = ["IndexedColors", "Annotations"]
            .iter()
            .any(|k| preset.get(k).is_some());
        return Err(err(if categorical {
            "is categorical (IndexedColors/Annotations, no RGBPoints): t2tf handles continuous maps only".into()
        } else {
            "has no \"RGBPoints\": no preset with \"RGBPoints\" to read".into()
        }));
    }
    let space = match preset.get("ColorSpace") {
        None => ColorSpace::Rgb,
        Some(v) => {
            let s = v
                .as_str()
                .ok_or_else(|| err(format!("\"ColorSpace\" is not a string: {v}")))?;
            // ParaView's JSON presets name Lab "Lab"; the one library preset spelled "CIELAB"
            // (Blue - Green - Orange) is applied by ParaView in RGB, as its ColorSpace
            // property knows no such value: read it as ParaView shows it.
            if s == "CIELAB" {
                ColorSpace::Rgb
            } else {
                ColorSpace::parse(s).ok_or_else(|| err(format!(
                    "colour space \"{s}\" is not one ParaView writes (RGB, HSV, Lab, CIELAB, Diverging, Lab/CIEDE2000, Step)"
                )))?
            }
        }
    };
    let hsv_wrap = match preset.get("HSVWrap") {
        None => false,
        Some(v) => v
            .as_bool()
            .or_else(|| v.as_f64().map(|x| x != 0.0))
            .ok_or_else(|| err(format!("\"HSVWrap\" is not 0 or 1: {v}")))?,
    };
    let rgb = quadruples(preset, "RGBPoints", path)?;
    let rgb_points = rgb.iter().map(|q| (q[0], [q[1], q[2], q[3]])).collect();
    let opacity_points = if preset.get("Points").is_some() {
        opacity_points(&quadruples(preset, "Points", path)?, path)?
    } else {
        Vec::new()
    };
    let tf = ExportTf {
        name,
        rgb_points,
        opacity_points,
        unit_distance: unit_distance(preset, path)?,
    };
    tf.validate(path)?;
    let extra = preset
        .as_object()
        .map(|o| {
            o.iter()
                .filter(|(k, _)| !KNOWN_KEYS.contains(&k.as_str()))
                .map(|(k, v)| (k.clone(), v.clone()))
                .collect()
        })
        .unwrap_or_default();
    Ok(Preset {
        tf,
        space,
        hsv_wrap,
        extra,
    })
}

/// Opacity quadruples (x, o, midpoint, sharpness) as points of a linear curve.
fn opacity_points(pts: &[[f64; 4]], path: &Path) -> Result<Vec<(f64, f64)>, FormatError> {
    let err = |m: String| FormatError::file(path, m);
    let mut out = Vec::new();
    for (i, q) in pts.iter().enumerate() {
        let (x, o, mid, sharp) = (q[0], q[1], q[2], q[3]);
        if sharp != 0.0 {
            return Err(err(format!(
                "opacity point {i}: sharpness {sharp} is not supported (only 0: linear)"
            )));
        }
        if !(0.0..1.0).contains(&mid) {
            return Err(err(format!(
                "opacity point {i}: midpoint {mid} is not in [0, 1)"
            )));
        }
        out.push((x, o));
        // ParaView's midpoint m puts half the step at fraction m of the segment.
        if let Some(next) = pts.get(i + 1) {
            if mid != 0.5 && next[0] > x {
                out.push((x + mid * (next[0] - x), 0.5 * (o + next[1])));
            }
        }
    }
    Ok(out)
}

/// The unit distance from t2tf's key or ParaView's; it must be a positive finite number.
fn unit_distance(preset: &Value, path: &Path) -> Result<Option<f64>, FormatError> {
    for key in [UNIT_DISTANCE_KEY, PARAVIEW_UNIT_DISTANCE_KEY] {
        if let Some(v) = preset.get(key) {
            return match v.as_f64() {
                Some(u) if u.is_finite() && u > 0.0 => Ok(Some(u)),
                _ => Err(FormatError::file(
                    path,
                    format!("\"{key}\" is {v}; it must be a positive number (world units)"),
                )),
            };
        }
    }
    Ok(None)
}

/// The numbers of `key` as quadruples, with errors naming the key and index.
fn quadruples(preset: &Value, key: &str, path: &Path) -> Result<Vec<[f64; 4]>, FormatError> {
    let err = |m: String| FormatError::file(path, m);
    let arr = preset
        .get(key)
        .and_then(Value::as_array)
        .ok_or_else(|| err(format!("\"{key}\" is not an array")))?;
    if arr.len() % 4 != 0 || arr.is_empty() {
        return Err(err(format!(
            "\"{key}\" has {} numbers, expected a non-zero multiple of 4 (x, and 3 values)",
            arr.len()
        )));
    }
    let mut nums = Vec::with_capacity(arr.len());
    for (i, v) in arr.iter().enumerate() {
        let n = v
            .as_f64()
            .ok_or_else(|| err(format!("\"{key}\"[{i}] is not a number: {v}")))?;
        nums.push(n);
    }
    Ok(nums
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect())
}
