//! Writing and reading transfer functions in the formats ParaView and VisIt open, and the
//! scripts that open a volume with them. Every file is written atomically.
//!
//! The common form is [`ExportTf`] (data units). Files: ParaView JSON preset (`.json`),
//! ParaView XML colour map (`.xml`), VisIt colour table (`.ct`), and the scripts
//! `NAME_paraview.py` (pvpython) and `NAME_visit.py` (VisIt CLI).

mod error;
mod export_tf;
mod paraview_json;
mod paraview_script;
mod paraview_xml;
mod points;
mod preset;
mod visit_ct;
mod visit_script;

pub use crate::fs::{atomic_write, atomic_write_bytes};
pub use error::{read_text, FormatError};
pub use export_tf::{load_tf, ExportTf};
pub use paraview_json::{
    from_paraview_json, list_paraview_json, preset_from_paraview_json, preset_to_paraview_json,
    to_paraview_json, PresetSummary,
};
pub use paraview_script::paraview_script;
pub use paraview_xml::{
    from_paraview_xml, preset_from_paraview_xml, preset_to_paraview_xml, to_paraview_xml,
};
pub use preset::Preset;
pub use visit_ct::{from_visit_ct, to_visit_ct};
pub use visit_script::{freeform_opacity, visit_script, FREEFORM_SAMPLES};

use std::path::{Path, PathBuf};

use crate::tf::ControlPoints;
use crate::volume::Volume;

/// A camera for the generated scripts, in world units (the renderer's camera converts into
/// it). `view_angle_deg` is the vertical field of view (DESIGN.md: 45°).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScriptView {
    pub position: [f64; 3],
    pub focal_point: [f64; 3],
    pub view_up: [f64; 3],
    pub view_angle_deg: f64,
}

impl ScriptView {
    /// Looking at the volume's centre along −y from `distance` bounding radii, z up, 45°.
    pub fn front(volume: &Volume, distance: f64) -> ScriptView {
        let c = volume.geometry.center();
        let r = volume.geometry.bounding_radius();
        ScriptView {
            position: [c[0], c[1] - distance * r, c[2]],
            focal_point: c,
            view_up: [0.0, 0.0, 1.0],
            view_angle_deg: 45.0,
        }
    }
}

/// The TF file formats, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TfFormat {
    ParaViewJson,
    ParaViewXml,
    VisItCt,
}

impl TfFormat {
    pub fn from_path(path: &Path) -> Result<TfFormat, FormatError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("json") => Ok(TfFormat::ParaViewJson),
            Some("xml") => Ok(TfFormat::ParaViewXml),
            Some("ct") => Ok(TfFormat::VisItCt),
            _ => Err(FormatError::file(
                path,
                "unknown transfer-function format (expected .json, .xml or .ct)",
            )),
        }
    }
}

/// Read a TF file of any supported format.
pub fn read_tf(path: &Path) -> Result<ExportTf, FormatError> {
    let format = TfFormat::from_path(path)?;
    let text = read_text(path)?;
    match format {
        TfFormat::ParaViewJson => from_paraview_json(&text, path),
        TfFormat::ParaViewXml => from_paraview_xml(&text, path),
        TfFormat::VisItCt => from_visit_ct(&text, path),
    }
}

/// Read the preset `name` (or the file's only one) in its own colour space. XML and .ct
/// files hold one map; `name` must then be absent or equal to it.
pub fn read_preset(path: &Path, name: Option<&str>) -> Result<Preset, FormatError> {
    let format = TfFormat::from_path(path)?;
    let text = read_text(path)?;
    let preset = match format {
        TfFormat::ParaViewJson => return preset_from_paraview_json(&text, path, name),
        TfFormat::ParaViewXml => preset_from_paraview_xml(&text, path)?,
        TfFormat::VisItCt => Preset::rgb(from_visit_ct(&text, path)?),
    };
    match name {
        Some(n) if n != preset.tf.name => Err(FormatError::file(
            path,
            format!("has no preset \"{n}\"; it holds \"{}\"", preset.tf.name),
        )),
        _ => Ok(preset),
    }
}

/// Write a preset in the format its extension names: JSON and XML keep its colour space,
/// a VisIt table (RGB only) gets the densified colours.
pub fn write_preset(path: &Path, preset: &Preset) -> anyhow::Result<()> {
    let text = match TfFormat::from_path(path)? {
        TfFormat::ParaViewJson => preset_to_paraview_json(preset),
        TfFormat::ParaViewXml => preset_to_paraview_xml(preset),
        TfFormat::VisItCt => to_visit_ct(&preset.rgb_linear()),
    };
    atomic_write_bytes(path, text.as_bytes())
}

/// Write a TF file in the format its extension names (atomically).
pub fn write_tf(path: &Path, tf: &ExportTf) -> anyhow::Result<()> {
    let text = match TfFormat::from_path(path)? {
        TfFormat::ParaViewJson => to_paraview_json(tf),
        TfFormat::ParaViewXml => to_paraview_xml(tf),
        TfFormat::VisItCt => to_visit_ct(tf),
    };
    atomic_write_bytes(path, text.as_bytes())
}

/// The files [`write_all`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct WrittenFiles {
    pub json: PathBuf,
    pub xml: PathBuf,
    pub ct: PathBuf,
    /// `None` when the volume has no source file to reopen.
    pub paraview_script: Option<PathBuf>,
    /// `None` without a source file, or for a raw type VisIt's BOV reader lacks.
    pub visit_script: Option<PathBuf>,
    /// What was exported (data units, simplified, unique name).
    pub tf: ExportTf,
}

/// Write every TF output for one result into `dir`: `NAME.json`, `NAME.xml`, `NAME.ct`,
/// `NAME_paraview.py`, `NAME_visit.py`. `unit_distance` defaults to the mean voxel spacing.
pub fn write_all(
    dir: &Path,
    name: &str,
    cp: &ControlPoints,
    volume: &Volume,
    view: &ScriptView,
    background: [f64; 3],
    unit_distance: Option<f64>,
) -> anyhow::Result<WrittenFiles> {
    if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
        anyhow::bail!("output name \"{name}\" must be a plain file name");
    }
    cp.validate()
        .map_err(|e| anyhow::anyhow!("cannot export transfer function {name}: {e}"))?;
    let tf = ExportTf::from_control_points(name, cp, volume, unit_distance);
    let path = |suffix: &str| dir.join(format!("{name}{suffix}"));
    let (json, xml, ct) = (path(".json"), path(".xml"), path(".ct"));
    atomic_write_bytes(&json, to_paraview_json(&tf).as_bytes())?;
    atomic_write_bytes(&xml, to_paraview_xml(&tf).as_bytes())?;
    atomic_write_bytes(&ct, to_visit_ct(&tf).as_bytes())?;
    let mut written = WrittenFiles {
        json,
        xml,
        ct,
        paraview_script: None,
        visit_script: None,
        tf: tf.clone(),
    };
    if volume.source.is_some() {
        let script = format!("{name}_paraview.py");
        let p = dir.join(&script);
        let text = paraview_script(&tf, volume, view, background, &script)?;
        atomic_write_bytes(&p, text.as_bytes())?;
        written.paraview_script = Some(p);
        let script = format!("{name}_visit.py");
        if let Ok(text) = visit_script(&tf, volume, view, background, &script) {
            let p = dir.join(&script);
            atomic_write_bytes(&p, text.as_bytes())?;
            written.visit_script = Some(p);
        }
    }
    Ok(written)
}
