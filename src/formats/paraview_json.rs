//! ParaView JSON presets: a top-level array of objects with `RGBPoints` (x, r, g, b) and
//! opacity `Points` (x, o, midpoint, sharpness) quadruples (what ParaView's own
//! `ExportTransferFunction` writes; a real one is the reader's test fixture).

use std::path::Path;

use serde_json::{json, Value};

use super::{ExportTf, FormatError};

/// Key carrying the unit distance; ParaView ignores keys it does not know (tested).
const UNIT_DISTANCE_KEY: &str = "t2tfScalarOpacityUnitDistance";

/// The preset as strict JSON (serde_json prints the shortest repr that reads back exactly).
pub fn to_paraview_json(tf: &ExportTf) -> String {
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
        "ColorSpace": "RGB",
        "RGBPoints": rgb,
    });
    if !opacity.is_empty() {
        preset["Points"] = json!(opacity);
    }
    if let Some(u) = tf.unit_distance {
        preset[UNIT_DISTANCE_KEY] = json!(u);
    }
    let mut s = serde_json::to_string_pretty(&json!([preset])).expect("JSON of numbers");
    s.push('\n');
    s
}

/// Parse a preset file's text. A file with several presets yields the first one that has
/// `RGBPoints`. Opacity `Points` with sharpness 0 and any midpoint are exact (the midpoint
/// becomes an extra point at half the opacity step); sharpness ≠ 0 is rejected.
pub fn from_paraview_json(text: &str, path: &Path) -> Result<ExportTf, FormatError> {
    let err = |m: String| FormatError::file(path, m);
    let root: Value =
        serde_json::from_str(text).map_err(|e| err(format!("is not valid JSON: {e}")))?;
    let presets: Vec<&Value> = match &root {
        Value::Array(a) => a.iter().collect(),
        Value::Object(_) => vec![&root],
        _ => {
            return Err(err(
                "is not a ParaView preset (expected an array of objects)".into(),
            ))
        }
    };
    let preset = presets
        .into_iter()
        .find(|p| p.get("RGBPoints").is_some())
        .ok_or_else(|| err("has no preset with \"RGBPoints\"".into()))?;
    let name = preset
        .get("Name")
        .and_then(Value::as_str)
        .unwrap_or("t2tf")
        .to_string();
    if let Some(space) = preset.get("ColorSpace").and_then(Value::as_str) {
        if !space.eq_ignore_ascii_case("rgb") {
            // Colours would be interpolated in another space between points; we would
            // render something else than ParaView shows.
            return Err(err(format!(
                "colour space \"{space}\" is not supported (only RGB)"
            )));
        }
    }
    let rgb = quadruples(preset, "RGBPoints", path)?;
    let rgb_points = rgb.iter().map(|q| (q[0], [q[1], q[2], q[3]])).collect();
    let mut opacity_points = Vec::new();
    if preset.get("Points").is_some() {
        let pts = quadruples(preset, "Points", path)?;
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
            opacity_points.push((x, o));
            // ParaView's midpoint m puts half the step at fraction m of the segment.
            if let Some(next) = pts.get(i + 1) {
                if mid != 0.5 && next[0] > x {
                    opacity_points.push((x + mid * (next[0] - x), 0.5 * (o + next[1])));
                }
            }
        }
    }
    let unit_distance = match preset.get(UNIT_DISTANCE_KEY) {
        None => None,
        Some(v) => Some(
            v.as_f64()
                .ok_or_else(|| err(format!("\"{UNIT_DISTANCE_KEY}\" is not a number")))?,
        ),
    };
    let tf = ExportTf {
        name,
        rgb_points,
        opacity_points,
        unit_distance,
    };
    tf.validate(path)?;
    Ok(tf)
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
