//! Writing and reading transfer functions in the formats ParaView and VisIt open, and the
//! scripts that open a volume with them. Every file is written atomically.
//!
//! The common form is [`ExportTf`] (data units). Each TF file format is one file here that
//! implements [`TfFormat`], listed once in [`FORMATS`]: ParaView JSON preset (`.json`),
//! ParaView XML colour map (`.xml`), VisIt colour table (`.ct`). The scripts are
//! `NAME_paraview.py` (pvpython) and `NAME_visit.py` (VisIt CLI).

#![warn(missing_docs)]

mod error;
mod export_tf;
mod paraview_json;
mod paraview_script;
mod paraview_xml;
mod points;
mod preset;
mod sampling;
mod series_script;
mod visit_ct;
mod visit_script;

use error::read_text;
pub use error::FormatError;
pub use export_tf::{load_tf, ExportTf};
pub use paraview_json::{from_paraview_json, to_paraview_json, to_paraview_library};
pub use paraview_script::paraview_script;
pub use paraview_xml::to_paraview_xml;
pub use preset::Preset;
pub use sampling::{preset_lut, ParaViewTables, Sampling, LUT_SIZE};
use t2tf_core::fs::atomic_write_bytes;
pub use visit_ct::to_visit_ct;
pub use visit_script::{freeform_opacity, visit_script};

use std::path::{Path, PathBuf};

use t2tf_render::camera::ParaViewCamera;
use t2tf_tf::ControlPoints;
use t2tf_volume::Volume;

/// A transfer-function file format: one file of this module with a unit struct implementing
/// this trait, and one entry in [`FORMATS`]. Everything that reads or writes TF files — the
/// path-based functions below, [`write_all`], `t2tf convert` — goes through the table, so
/// nothing else names a format. The impls look alike (a name, extensions, and methods that
/// hand over to the file's reader and writer): that is the trait's shape, not repeated logic.
pub trait TfFormat: Sync {
    /// What the format is called in messages ("ParaView JSON preset").
    fn name(&self) -> &'static str;
    /// File extensions, lower case without the dot; [`write_all`] uses the first.
    fn extensions(&self) -> &'static [&'static str];
    /// The preset `name` (or the file's only one) in its own colour space.
    fn read_preset(
        &self,
        text: &str,
        path: &Path,
        name: Option<&str>,
    ) -> Result<Preset, FormatError>;
    /// The file's text for a preset, in its colour space where the format has one.
    fn write_preset(&self, preset: &Preset) -> String;
    /// The file's text as the RGB-linear TF the renderer and VisIt see: by default the
    /// file's only preset, densified (see [`Preset::rgb_linear`]).
    fn read_tf(&self, text: &str, path: &Path) -> Result<ExportTf, FormatError> {
        Ok(self.read_preset(text, path, None)?.rgb_linear())
    }
    /// The file's text for an RGB TF: by default the TF as an RGB preset.
    fn write_tf(&self, tf: &ExportTf) -> String {
        self.write_preset(&Preset::rgb(tf.clone()))
    }
    /// What `t2tf convert --list` shows of the file. The default, for formats that hold one
    /// map, is that map's name and colour space.
    fn list(&self, text: &str, path: &Path) -> Result<Vec<PresetSummary>, FormatError> {
        let p = self.read_preset(text, path, None)?;
        Ok(vec![PresetSummary {
            name: p.tf.name,
            space: Some(p.space.paraview_name().to_string()),
            counts: None,
        }])
    }
}

/// What `t2tf convert --list` shows of one preset.
#[derive(Clone, Debug, PartialEq)]
pub struct PresetSummary {
    /// The preset's name.
    pub name: String,
    /// ParaView's name of its colour space; `None` for a categorical preset
    /// (IndexedColors/Annotations without RGBPoints).
    pub space: Option<String>,
    /// Colour and opacity points of the preset as t2tf reads it ([`PointCounts::of`]); `None`
    /// for a file of one map, whose listing shows only the name and colour space.
    pub counts: Option<PointCounts>,
}

/// How many colour and opacity points a preset has as t2tf reads it: what `t2tf convert
/// --list` shows of a file and `t2tf convert` reports of what it wrote, counted alike.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointCounts {
    /// Colour points.
    pub colour: usize,
    /// Opacity points. A ParaView opacity point whose midpoint is not 0.5 is read as two: the
    /// point, and the point at its midpoint that makes the curve linear.
    pub opacity: usize,
}

impl PointCounts {
    /// The points of `tf`.
    pub fn of(tf: &ExportTf) -> PointCounts {
        PointCounts {
            colour: tf.rgb_points.len(),
            opacity: tf.opacity_points.len(),
        }
    }
}

/// Every TF format, in the order [`write_all`] writes them and messages list them.
pub static FORMATS: &[&dyn TfFormat] = &[
    &paraview_json::ParaViewJson,
    &paraview_xml::ParaViewXml,
    &visit_ct::VisItCt,
];

/// The supported extensions for messages and help: ".json, .xml or .ct".
pub fn extension_list() -> String {
    let exts: Vec<String> = FORMATS
        .iter()
        .flat_map(|f| f.extensions())
        .map(|e| format!(".{e}"))
        .collect();
    match exts.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        _ => exts.concat(),
    }
}

/// The format `path`'s extension names (case-insensitive).
pub fn format_of(path: &Path) -> Result<&'static dyn TfFormat, FormatError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    ext.and_then(|ext| {
        FORMATS
            .iter()
            .copied()
            .find(|f| f.extensions().contains(&ext.as_str()))
    })
    .ok_or_else(|| {
        FormatError::file(
            path,
            format!(
                "unknown transfer-function format (expected {})",
                extension_list()
            ),
        )
    })
}

/// A preset read from a file that holds one map: `name`, when given, must be that map's.
pub(crate) fn only_preset(
    preset: Preset,
    path: &Path,
    name: Option<&str>,
) -> Result<Preset, FormatError> {
    match name {
        Some(n) if n != preset.tf.name => Err(FormatError::about(
            path,
            "preset",
            format!("has no preset \"{n}\"; it holds \"{}\"", preset.tf.name),
        )),
        _ => Ok(preset),
    }
}

/// The largest TF file read unless the caller raises the cap (`--max-preset-size`): a
/// larger one is refused before it is read. ParaView's whole preset library is 224 KiB
/// (`tests/fixtures/paraview/paraview_library.json`);
/// 64 MiB holds some 800,000 points of a JSON preset.
pub const DEFAULT_MAX_PRESET_SIZE: u64 = 64 << 20;

/// Read a TF file of any supported format (at most [`DEFAULT_MAX_PRESET_SIZE`]).
pub fn read_tf(path: &Path) -> Result<ExportTf, FormatError> {
    let format = format_of(path)?;
    format.read_tf(&read_text(path, DEFAULT_MAX_PRESET_SIZE)?, path)
}

/// Read the preset `name` (or the file's only one) in its own colour space. XML and .ct
/// files hold one map; `name` must then be absent or equal to it. At most
/// [`DEFAULT_MAX_PRESET_SIZE`] bytes: [`read_preset_within`] takes another cap.
pub fn read_preset(path: &Path, name: Option<&str>) -> Result<Preset, FormatError> {
    read_preset_within(path, name, DEFAULT_MAX_PRESET_SIZE)
}

/// [`read_preset`] of a file of at most `max_size` bytes; a larger one is refused
/// ([`FormatError::TooLarge`]) before it is read.
pub fn read_preset_within(
    path: &Path,
    name: Option<&str>,
    max_size: u64,
) -> Result<Preset, FormatError> {
    let format = format_of(path)?;
    format.read_preset(&read_text(path, max_size)?, path, name)
}

/// The presets of a TF file of at most `max_size` bytes, for `t2tf convert --list`.
pub fn list_presets(path: &Path, max_size: u64) -> Result<Vec<PresetSummary>, FormatError> {
    let format = format_of(path)?;
    format.list(&read_text(path, max_size)?, path)
}

/// Write a preset in the format its extension names: JSON and XML keep its colour space,
/// a VisIt table (RGB only) gets the densified colours.
pub fn write_preset(path: &Path, preset: &Preset) -> Result<(), FormatError> {
    let format = format_of(path)?;
    check_range(path, &preset.tf)?;
    write_text(path, &format.write_preset(preset))
}

/// Write `tfs` as one ParaView JSON library (atomically): ParaView's *Import Presets* adds
/// each of them.
pub fn write_library(path: &Path, tfs: &[ExportTf]) -> Result<(), FormatError> {
    for tf in tfs {
        check_range(path, tf)?;
    }
    // A name in an output folder t2tf owns: a symlink there is replaced, never followed.
    let text = paraview_json::to_paraview_library(tfs);
    Ok(t2tf_core::fs::atomic_replace_bytes(path, text.as_bytes())?)
}

/// Write a TF file in the format its extension names (atomically).
pub fn write_tf(path: &Path, tf: &ExportTf) -> Result<(), FormatError> {
    let format = format_of(path)?;
    check_range(path, tf)?;
    write_text(path, &format.write_tf(tf))
}

/// A TF whose data range no double spans (±1e308: the width overflows) would come out with
/// `inf` and `NaN` positions in a `.ct` and in resampled colours: refused before writing.
fn check_range(path: &Path, tf: &ExportTf) -> Result<(), FormatError> {
    let [lo, hi] = tf.data_range();
    if (hi - lo).is_finite() || tf.rgb_points.is_empty() && tf.opacity_points.is_empty() {
        return Ok(());
    }
    Err(FormatError::about(
        path,
        "rescale",
        format!(
            "the transfer function spans {lo:e} to {hi:e}, wider than a double can measure; \
             rescale it first (`rescale`)"
        ),
    ))
}

/// `text` for an XML attribute or element: characters XML 1.0 cannot hold (control characters
/// other than tab, line feed and carriage return; U+FFFE and U+FFFF) removed, the rest escaped.
pub(crate) fn xml_text(text: &str) -> String {
    let allowed: String = text
        .chars()
        .filter(|&c| !c.is_control() || matches!(c, '\t' | '\n' | '\r'))
        .filter(|&c| c != '\u{fffe}' && c != '\u{ffff}')
        .collect();
    quick_xml::escape::escape(allowed.as_str()).into_owned()
}

/// Write `text` atomically through `t2tf_core::fs`, its message (which names the file) kept.
fn write_text(path: &Path, text: &str) -> Result<(), FormatError> {
    Ok(atomic_write_bytes(path, text.as_bytes())?)
}

/// The files [`write_all`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct WrittenFiles {
    /// `NAME.json` (ParaView JSON preset).
    pub json: PathBuf,
    /// `NAME.xml` (ParaView XML colour map).
    pub xml: PathBuf,
    /// `NAME.ct` (VisIt colour table).
    pub ct: PathBuf,
    /// Every TF file, one per entry of [`FORMATS`] and in its order (`json`, `xml` and `ct`
    /// among them).
    pub tf_files: Vec<PathBuf>,
    /// `None` when the volume has no source file to reopen.
    pub paraview_script: Option<PathBuf>,
    /// `None` without a source file, or for a raw type VisIt's BOV reader lacks.
    pub visit_script: Option<PathBuf>,
    /// What was exported (data units, simplified, unique name).
    pub tf: ExportTf,
}

impl WrittenFiles {
    /// Every file written: the TF files, then the scripts.
    pub fn all(&self) -> Vec<&Path> {
        self.tf_files
            .iter()
            .chain(&self.paraview_script)
            .chain(&self.visit_script)
            .map(PathBuf::as_path)
            .collect()
    }
}

/// Write every TF output for one result into `dir`: `NAME.EXT` for each of [`FORMATS`]
/// (`.json`, `.xml`, `.ct`), `NAME_paraview.py`, `NAME_visit.py`. `unit_distance` defaults
/// to the mean voxel spacing.
pub fn write_all(
    dir: &Path,
    name: &str,
    cp: &ControlPoints,
    volume: &Volume,
    view: &ParaViewCamera,
    background: [f64; 3],
    unit_distance: Option<f64>,
) -> Result<WrittenFiles, FormatError> {
    if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
        return Err(FormatError::Message(format!(
            "output name \"{name}\" must be a plain file name"
        )));
    }
    cp.validate().map_err(|e| {
        FormatError::Message(format!("cannot export transfer function {name}: {e}"))
    })?;
    let tf = ExportTf::from_control_points(name, cp, volume, unit_distance);
    let path = |suffix: &str| dir.join(format!("{name}{suffix}"));
    let mut tf_files = Vec::with_capacity(FORMATS.len());
    for format in FORMATS {
        let p = path(&format!(".{}", format.extensions()[0]));
        write_text(&p, &format.write_tf(&tf))?;
        tf_files.push(p);
    }
    let mut written = WrittenFiles {
        json: path(".json"),
        xml: path(".xml"),
        ct: path(".ct"),
        tf_files,
        paraview_script: None,
        visit_script: None,
        tf: tf.clone(),
    };
    if volume.source.is_some() {
        let script = format!("{name}_paraview.py");
        let p = dir.join(&script);
        write_text(
            &p,
            &paraview_script(&tf, volume, view, background, &script)?,
        )?;
        written.paraview_script = Some(p);
        let script = format!("{name}_visit.py");
        // A volume VisIt cannot open (e.g. a 64-bit integer raw file) gets no VisIt script.
        if let Ok(text) = visit_script(&tf, volume, view, background, &script) {
            let p = dir.join(&script);
            write_text(&p, &text)?;
            written.visit_script = Some(p);
        }
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_names_each_extension_once() {
        let exts: Vec<&str> = FORMATS
            .iter()
            .flat_map(|f| f.extensions())
            .copied()
            .collect();
        let mut unique = exts.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), exts.len(), "{exts:?}");
        assert!(FORMATS.iter().all(|f| !f.extensions().is_empty()));
        assert_eq!(extension_list(), ".json, .xml or .ct");
    }

    #[test]
    fn format_of_reads_the_extension_in_any_case() {
        assert_eq!(
            format_of(Path::new("a/B.JSON")).unwrap().name(),
            "ParaView JSON preset"
        );
        assert_eq!(
            format_of(Path::new("x.Xml")).unwrap().name(),
            "ParaView XML colour map"
        );
        assert_eq!(
            format_of(Path::new("t.ct")).unwrap().name(),
            "VisIt colour table"
        );
        let e = format_of(Path::new("t.png")).err().map(|e| e.to_string());
        assert_eq!(
            e.as_deref(),
            Some("t.png: unknown transfer-function format (expected .json, .xml or .ct)")
        );
        assert!(format_of(Path::new("json")).is_err());
    }
}
