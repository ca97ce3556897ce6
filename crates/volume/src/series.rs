//! Time series of volumes, as ParaView reads them: a `.pvd` collection (`DataSet` entries
//! with `timestep` attributes), a `.series` file (ParaView's JSON file-series format), or a
//! list of files (a glob, or names given one by one) grouped as ParaView groups a file
//! series: ordered by the number in their names, the time of each its index.
//!
//! A series is opened as a list of steps (time, file); nothing is read until asked. Its
//! statistics ([`Series::scan`]) are streamed one step at a time through [`summarize`]: the
//! range over all steps, then the histogram over that range, so memory does not grow with
//! the series. A step is then loaded ([`Series::load_step`]) normalized over the series'
//! range, so that one transfer function means the same at every time.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use quick_xml::events::Event;
use quick_xml::Reader;

use super::summary::histogram_over;
use super::{load, norm_range, summarize, ReadOptions, Volume, VolumeError, HISTOGRAM_BINS};

/// Collections larger than this are refused before they are read: a `.pvd` or `.series`
/// file is a short list of names.
const MAX_COLLECTION_BYTES: u64 = 64 << 20;

/// One time step: its time value and its file.
#[derive(Clone, Debug, PartialEq)]
pub struct SeriesStep {
    /// The time ParaView shows for the step (a `.pvd`'s `timestep`, a `.series` file's
    /// `time`, else the step's index in the group).
    pub time: f64,
    /// The step's volume file.
    pub path: PathBuf,
}

/// A time series: its steps in time order, and the collection file that named them.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// The `.pvd` or `.series` file the series was read from; `None` for a list of files.
    pub collection: Option<PathBuf>,
    /// The steps used, in increasing time (a selection keeps the collection's times).
    pub steps: Vec<SeriesStep>,
    /// Steps in the whole series before any selection.
    pub total_steps: usize,
}

/// Which steps of a series a run uses. Both empty: all of them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TimeSelection {
    /// Steps whose time is in `[t0, t1]`.
    pub range: Option<[f64; 2]>,
    /// Steps by index in the series (0 = first), in any order, each once.
    pub indices: Option<Vec<usize>>,
}

/// A series' statistics over its steps, streamed one step at a time.
#[derive(Clone, Debug)]
pub struct SeriesStats {
    /// Finite min and max over every step (data units).
    pub range: [f64; 2],
    /// The range that maps to [0, 1] for every step (`range`, widened when constant).
    pub norm_range: [f64; 2],
    /// Each step's own finite range, in step order.
    pub step_ranges: Vec<[f64; 2]>,
    /// NaN/Inf values over all steps.
    pub non_finite: usize,
    /// Counts over [`HISTOGRAM_BINS`] equal bins of `norm_range`, all steps together.
    pub histogram: Vec<u64>,
}

/// Whether `path` names a series rather than one volume: a `.pvd` or `.series` file, or a
/// glob pattern (`*`, `?` or `[` in its file name).
pub fn is_series_path(path: &Path) -> bool {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let lower = name.to_ascii_lowercase();
    lower.ends_with(".pvd") || lower.ends_with(".series") || name.contains(['*', '?', '['])
}

impl Series {
    /// The series named by `paths`: one `.pvd`, `.series` or glob pattern, or several files
    /// (ordered as ParaView orders a file series).
    pub fn open(paths: &[PathBuf]) -> Result<Series, VolumeError> {
        let series = match paths {
            [] => return Err(VolumeError::file(Path::new(""), "no volume file given")),
            [one] => {
                let lower = one.to_string_lossy().to_ascii_lowercase();
                if lower.ends_with(".pvd") {
                    read_pvd(one)?
                } else if lower.ends_with(".series") {
                    read_series_json(one)?
                } else if is_series_path(one) {
                    from_files(expand_glob(one)?, one)?
                } else {
                    from_files(vec![one.clone()], one)?
                }
            }
            many => from_files(many.to_vec(), &many[0])?,
        };
        Ok(series)
    }

    /// The steps `selection` picks, in time order; an empty pick is an error naming what
    /// the series holds.
    pub fn select(&self, selection: &TimeSelection) -> Result<Series, VolumeError> {
        let mut keep: Vec<bool> = vec![true; self.steps.len()];
        if let Some(indices) = &selection.indices {
            keep = vec![false; self.steps.len()];
            for &i in indices {
                if i >= self.steps.len() {
                    return Err(VolumeError::file(
                        self.named(),
                        format!(
                            "`time_steps`: step {i} does not exist; the series has steps 0 to {}",
                            self.steps.len() - 1
                        ),
                    ));
                }
                if keep[i] {
                    return Err(VolumeError::file(
                        self.named(),
                        format!("`time_steps`: step {i} is named twice"),
                    ));
                }
                keep[i] = true;
            }
        }
        if let Some([t0, t1]) = selection.range {
            if !(t0.is_finite() && t1.is_finite() && t0 <= t1) {
                return Err(VolumeError::file(
                    self.named(),
                    format!("`time_range` must be two finite times T0 <= T1, got {t0},{t1}"),
                ));
            }
            for (k, s) in keep.iter_mut().zip(&self.steps) {
                *k &= (t0..=t1).contains(&s.time);
            }
        }
        let steps: Vec<SeriesStep> = self
            .steps
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(s, _)| s.clone())
            .collect();
        if steps.is_empty() {
            let (first, last) = (self.steps[0].time, self.steps[self.steps.len() - 1].time);
            return Err(VolumeError::file(
                self.named(),
                format!(
                    "no time step selected: the series has {} steps at times {first} to {last}",
                    self.steps.len()
                ),
            ));
        }
        Ok(Series {
            collection: self.collection.clone(),
            steps,
            total_steps: self.total_steps,
        })
    }

    /// The file errors about the whole series name: its collection, else its first file.
    pub fn named(&self) -> &Path {
        self.collection.as_deref().unwrap_or(&self.steps[0].path)
    }

    /// Whether every step of the series is used.
    pub fn is_whole(&self) -> bool {
        self.steps.len() == self.total_steps
    }

    /// The series' statistics, one step at a time (each step's file opened as `t2tf info`
    /// opens it, no volume built): a pass over every step for the range, then one for the
    /// histogram over it (the counts the steps' loads make, bit for bit). `on_step(i)` is
    /// called as step `i` is read. The steps must share their grid: a series whose dims
    /// differ is refused, naming the step.
    pub fn scan(
        &self,
        opts: &ReadOptions,
        on_step: &mut dyn FnMut(usize),
    ) -> Result<SeriesStats, VolumeError> {
        let mut step_ranges = Vec::with_capacity(self.steps.len());
        let mut non_finite = 0;
        let mut first_dims = None;
        for (i, step) in self.steps.iter().enumerate() {
            on_step(i);
            let s = summarize(&step.path, opts)?;
            match first_dims {
                None => first_dims = Some(s.geometry.dims),
                Some(d) if d != s.geometry.dims => {
                    return Err(VolumeError::file(
                        &step.path,
                        format!(
                            "the series' steps differ in size: {:?} points here, {:?} in the \
                             first step",
                            s.geometry.dims, d
                        ),
                    ))
                }
                Some(_) => {}
            }
            step_ranges.push(s.range);
            non_finite += s.non_finite;
        }
        let range = step_ranges
            .iter()
            .fold([f64::INFINITY, f64::NEG_INFINITY], |r, s| {
                [r[0].min(s[0]), r[1].max(s[1])]
            });
        let norm = norm_range(range[0], range[1]);
        let mut histogram = vec![0u64; HISTOGRAM_BINS];
        for step in &self.steps {
            for (h, k) in histogram
                .iter_mut()
                .zip(histogram_over(&step.path, opts, norm)?)
            {
                *h += k;
            }
        }
        Ok(SeriesStats {
            range,
            norm_range: norm,
            step_ranges,
            non_finite,
            histogram,
        })
    }

    /// Step `index` as a volume normalized over `norm_range` (the series' [`SeriesStats`]),
    /// knowing it is a step of this series (`Volume::series`).
    pub fn load_step(
        self: &Arc<Self>,
        index: usize,
        norm_range: [f64; 2],
        opts: &ReadOptions,
    ) -> Result<Volume, VolumeError> {
        let step = &self.steps[index];
        let opts = ReadOptions {
            norm_range: Some(norm_range),
            ..opts.clone()
        };
        let mut volume = load(&step.path, &opts)?;
        volume.series = Some(self.clone());
        Ok(volume)
    }
}

/// A `.pvd` collection: `<DataSet timestep=".." part=".." file=".."/>` entries, files
/// relative to the collection's folder. Several parts at one time (a multiblock) are refused.
fn read_pvd(path: &Path) -> Result<Series, VolumeError> {
    let text = read_collection(path)?;
    let mut reader = Reader::from_str(&text);
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut steps = Vec::new();
    let mut collection = false;
    loop {
        let event = reader
            .read_event()
            .map_err(|e| VolumeError::file(path, format!("not a valid .pvd (XML): {e}")))?;
        let tag = match &event {
            Event::Start(t) | Event::Empty(t) => t,
            Event::Eof => break,
            _ => continue,
        };
        let attr = |name: &str| -> Result<Option<String>, VolumeError> {
            for a in tag.attributes() {
                let a =
                    a.map_err(|e| VolumeError::file(path, format!("bad XML attribute: {e}")))?;
                if a.key.as_ref() == name {
                    let v = a
                        .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                        .map_err(|e| VolumeError::file(path, format!("bad XML attribute: {e}")))?;
                    return Ok(Some(v.into_owned()));
                }
            }
            Ok(None)
        };
        match tag.name().as_ref() {
            "VTKFile" => {
                if attr("type")?.as_deref() != Some("Collection") {
                    return Err(VolumeError::file(
                        path,
                        "not a ParaView collection (the VTKFile's type is not \"Collection\")",
                    ));
                }
                collection = true;
            }
            "DataSet" => {
                let file = attr("file")?.ok_or_else(|| {
                    VolumeError::file(path, "a DataSet entry has no `file` attribute")
                })?;
                let time = match attr("timestep")? {
                    Some(t) => t
                        .trim()
                        .parse::<f64>()
                        .ok()
                        .filter(|t| t.is_finite())
                        .ok_or_else(|| {
                            VolumeError::file(path, format!("timestep {t:?} is not a number"))
                        })?,
                    None => steps.len() as f64,
                };
                let part = attr("part")?.unwrap_or_else(|| "0".into());
                steps.push((time, part, dir.join(file)));
            }
            _ => {}
        }
    }
    if !collection {
        return Err(VolumeError::file(
            path,
            "not a ParaView collection (no VTKFile element)",
        ));
    }
    let parts: std::collections::BTreeSet<&str> = steps.iter().map(|s| s.1.as_str()).collect();
    if parts.len() > 1 {
        return Err(VolumeError::file(
            path,
            "the collection has several parts per time step (a multiblock); t2tf reads one \
             image per time step",
        ));
    }
    let steps = steps
        .into_iter()
        .map(|(time, _, path)| SeriesStep { time, path })
        .collect();
    finish(steps, Some(path.to_path_buf()), path)
}

/// A `.series` file: `{"file-series-version": "1.0", "files": [{"name": .., "time": ..}]}`,
/// names relative to its folder.
fn read_series_json(path: &Path) -> Result<Series, VolumeError> {
    let text = read_collection(path)?;
    let bad = |what: &str| VolumeError::file(path, format!("not a ParaView .series file: {what}"));
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(&format!("invalid JSON ({e})")))?;
    let files = json
        .get("files")
        .and_then(|f| f.as_array())
        .ok_or_else(|| bad("no \"files\" list"))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut steps = Vec::with_capacity(files.len());
    for (i, f) in files.iter().enumerate() {
        let name = f
            .get("name")
            .and_then(|n| n.as_str())
            .ok_or_else(|| bad(&format!("entry {i} has no \"name\"")))?;
        let time = match f.get("time") {
            None => i as f64,
            Some(t) => t
                .as_f64()
                .filter(|t| t.is_finite())
                .ok_or_else(|| bad(&format!("entry {i}'s \"time\" is not a number")))?,
        };
        steps.push(SeriesStep {
            time,
            path: dir.join(name),
        });
    }
    finish(steps, Some(path.to_path_buf()), path)
}

/// A collection file's text, refused when it is not a small regular file.
fn read_collection(path: &Path) -> Result<String, VolumeError> {
    let mut file =
        t2tf_core::input::open(path).map_err(|e| VolumeError::file(path, e.to_string()))?;
    let len = file.metadata().map(|m| m.len()).unwrap_or(0);
    if len > MAX_COLLECTION_BYTES {
        return Err(VolumeError::file(
            path,
            format!("{len} bytes is too large for a list of time steps"),
        ));
    }
    let mut text = String::new();
    std::io::Read::read_to_string(&mut file, &mut text)
        .map_err(|e| VolumeError::file(path, format!("cannot read it as text: {e}")))?;
    Ok(text)
}

/// Steps sorted by time; times must be distinct.
fn finish(
    mut steps: Vec<SeriesStep>,
    collection: Option<PathBuf>,
    named: &Path,
) -> Result<Series, VolumeError> {
    if steps.is_empty() {
        return Err(VolumeError::file(named, "the series lists no time step"));
    }
    steps.sort_by(|a, b| a.time.total_cmp(&b.time));
    if let Some(w) = steps.windows(2).find(|w| w[0].time == w[1].time) {
        return Err(VolumeError::file(
            named,
            format!(
                "two files at time {}: {} and {}",
                w[0].time,
                w[0].path.display(),
                w[1].path.display()
            ),
        ));
    }
    let total_steps = steps.len();
    Ok(Series {
        collection,
        steps,
        total_steps,
    })
}

/// A list of files as ParaView groups a file series: ordered by the numbers in their names
/// (`a_2` before `a_10`), the time of each its index. The files must share one extension.
fn from_files(mut files: Vec<PathBuf>, named: &Path) -> Result<Series, VolumeError> {
    let ext = |p: &Path| {
        p.extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
    };
    if let Some(odd) = files.iter().find(|f| ext(f) != ext(&files[0])) {
        return Err(VolumeError::file(
            odd,
            format!(
                "a series' files share one format; this one differs from {}",
                files[0].display()
            ),
        ));
    }
    files.sort_by_key(|f| natural_key(f));
    files.dedup();
    // ParaView takes an XML file's `TimeValue` field as its time; where every file has one,
    // so does t2tf (else the index, as ParaView does for files without one).
    let xml = ext(&files[0]).as_deref() == Some("vti");
    let times: Option<Vec<f64>> = xml
        .then(|| files.iter().map(|f| xml_time_value(f)).collect())
        .flatten();
    let steps = files
        .into_iter()
        .enumerate()
        .map(|(i, path)| SeriesStep {
            time: times.as_ref().map_or(i as f64, |t| t[i]),
            path,
        })
        .collect();
    finish(steps, None, named)
}

/// The `TimeValue` a VTK XML file holds in its field data: the value of an ASCII array, or
/// the range VTK writes beside a binary one of one tuple (`RangeMin` = `RangeMax`, 11
/// significant digits). Only the head of the file is read.
fn xml_time_value(path: &Path) -> Option<f64> {
    let mut head = vec![0u8; 64 << 10];
    let mut file = t2tf_core::input::open(path).ok()?;
    let n = std::io::Read::read(&mut file, &mut head).ok()?;
    let text = String::from_utf8_lossy(&head[..n]);
    let end = text.find("<AppendedData").unwrap_or(text.len());
    let mut reader = Reader::from_str(&text[..end]);
    let mut in_time = false;
    loop {
        match reader.read_event().ok()? {
            Event::Start(t) | Event::Empty(t) if t.name().as_ref() == "DataArray" => {
                let get = |key: &str| {
                    t.attributes()
                        .flatten()
                        .find(|a| a.key.as_ref() == key)
                        .and_then(|a| {
                            a.normalized_value(quick_xml::XmlVersion::Implicit1_0)
                                .ok()
                                .map(|v| v.trim().to_string())
                        })
                };
                if get("Name").as_deref() != Some("TimeValue") {
                    continue;
                }
                if get("format").as_deref() == Some("ascii") {
                    in_time = true;
                    continue;
                }
                let (lo, hi) = (get("RangeMin")?, get("RangeMax")?);
                let t = lo.parse::<f64>().ok().filter(|t| t.is_finite())?;
                return (lo == hi && get("NumberOfTuples").as_deref() == Some("1")).then_some(t);
            }
            Event::Text(t) if in_time => {
                let text = t.as_ref().to_string();
                return text.trim().parse::<f64>().ok().filter(|t| t.is_finite());
            }
            Event::Start(t) if t.name().as_ref() == "Piece" => return None,
            Event::Eof => return None,
            _ => {}
        }
    }
}

/// A name's text and digit runs, digits compared as numbers: the order of a file series.
fn natural_key(path: &Path) -> Vec<(String, u128)> {
    let name = path.to_string_lossy();
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut digits = c.to_string();
            while let Some(d) = chars.peek().filter(|d| d.is_ascii_digit()) {
                digits.push(*d);
                chars.next();
            }
            key.push((
                std::mem::take(&mut text),
                digits.parse().unwrap_or(u128::MAX),
            ));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

/// The files a glob pattern in the last path component matches (`*`, `?`, `[...]`).
fn expand_glob(pattern: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    let dir = match pattern.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = pattern
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| VolumeError::file(pattern, "the pattern is not UTF-8"))?;
    let matcher = glob::Pattern::new(name)
        .map_err(|e| VolumeError::file(pattern, format!("not a valid pattern: {e}")))?;
    let entries = std::fs::read_dir(&dir)
        .map_err(|e| VolumeError::file(pattern, format!("cannot list {}: {e}", dir.display())))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .filter(|e| e.file_type().is_ok_and(|t| !t.is_dir()))
        .filter(|e| e.file_name().to_str().is_some_and(|n| matcher.matches(n)))
        .map(|e| {
            if pattern.parent().is_some_and(|p| !p.as_os_str().is_empty()) {
                dir.join(e.file_name())
            } else {
                PathBuf::from(e.file_name())
            }
        })
        .collect();
    if files.is_empty() {
        return Err(VolumeError::file(pattern, "no file matches the pattern"));
    }
    files.sort();
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_sort_as_a_file_series() {
        let files: Vec<PathBuf> = ["a_10.vti", "a_2.vti", "a_1.vti"].map(PathBuf::from).into();
        let s = from_files(files, Path::new("a_10.vti")).unwrap();
        let names: Vec<_> = s.steps.iter().map(|s| s.path.to_str().unwrap()).collect();
        assert_eq!(names, ["a_1.vti", "a_2.vti", "a_10.vti"]);
        assert_eq!(s.steps[2].time, 2.0);
    }

    #[test]
    fn selection_by_range_and_index() {
        let steps = (0..5)
            .map(|i| SeriesStep {
                time: i as f64 * 10.0,
                path: PathBuf::from(format!("s{i}.vti")),
            })
            .collect();
        let s = finish(steps, None, Path::new("s")).unwrap();
        let r = s
            .select(&TimeSelection {
                range: Some([10.0, 30.0]),
                indices: None,
            })
            .unwrap();
        assert_eq!(r.steps.len(), 3);
        assert!(!r.is_whole());
        let i = s
            .select(&TimeSelection {
                range: None,
                indices: Some(vec![4, 0]),
            })
            .unwrap();
        assert_eq!(
            i.steps.iter().map(|s| s.time).collect::<Vec<_>>(),
            [0.0, 40.0]
        );
        assert!(s
            .select(&TimeSelection {
                range: Some([41.0, 50.0]),
                indices: None
            })
            .unwrap_err()
            .to_string()
            .contains("times 0 to 40"));
        assert!(s
            .select(&TimeSelection {
                range: None,
                indices: Some(vec![5])
            })
            .is_err());
    }

    #[test]
    fn xml_files_carry_their_time_value() {
        let dir = tempfile::tempdir().unwrap();
        // As vtkXMLImageDataWriter writes a TimeValue: binary with its range, or ASCII.
        let head = |array: &str| {
            format!(
                "<VTKFile type=\"ImageData\" version=\"0.1\">\n<ImageData WholeExtent=\"0 0 0 0 0 \
                 0\">\n<FieldData>\n{array}\n</FieldData>\n<Piece Extent=\"0 0 0 0 0 0\">"
            )
        };
        let binary = "<DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" \
                      format=\"appended\" RangeMin=\"400\"   RangeMax=\"400\"   offset=\"0\" />";
        let ascii = "<DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" \
                     format=\"ascii\">\n 2.5e-3\n</DataArray>";
        let other = "<DataArray type=\"Float64\" Name=\"Other\" NumberOfTuples=\"1\" \
                     format=\"ascii\">7</DataArray>";
        let write = |name: &str, array: &str| {
            let p = dir.path().join(name);
            std::fs::write(&p, head(array)).unwrap();
            p
        };
        assert_eq!(xml_time_value(&write("a.vti", binary)), Some(400.0));
        assert_eq!(xml_time_value(&write("b.vti", ascii)), Some(2.5e-3));
        assert_eq!(xml_time_value(&write("c.vti", other)), None);
        // A list takes the files' times only when every file has one.
        let s = from_files(
            vec![dir.path().join("a.vti"), dir.path().join("b.vti")],
            Path::new("a.vti"),
        )
        .unwrap();
        assert_eq!(
            s.steps.iter().map(|s| s.time).collect::<Vec<_>>(),
            [2.5e-3, 400.0]
        );
        let s = from_files(
            vec![dir.path().join("a.vti"), dir.path().join("c.vti")],
            Path::new("a.vti"),
        )
        .unwrap();
        assert_eq!(
            s.steps.iter().map(|s| s.time).collect::<Vec<_>>(),
            [0.0, 1.0]
        );
    }
}
