//! The output set of a run, written as one set into a folder: the TF files (`NAME.json`,
//! `NAME.xml`, `NAME.ct`), the pvpython and VisIt scripts, `tf.png`, `preview.png`, and
//! `report.json` last, so the files a `report.json` lists are always its run's.

use std::path::Path;
use std::time::Instant;

use super::{Optimized, PipelineError};
use crate::optimize::driver::{self, OutputError};
use crate::optimize::report::Report;
use crate::optimize::tf_plot::PlotLabels;

/// Names of the files of the set that are not the TF's own (`NAME.…`).
const FIXED: [&str; 3] = ["tf.png", "preview.png", "report.json"];

/// Longest base name: `NAME_paraview.py` must fit a file name of 255 bytes.
const MAX_NAME_BYTES: usize = 255 - "_paraview.py".len();

/// Check a TF base name before any work: a plain file name (no separators, no control
/// characters, not hidden), short enough for every file named from it, and not one that
/// would overwrite another file of the set (`report` would write `report.json`).
pub fn check_name(name: &str) -> Result<(), PipelineError> {
    let bad = |why: &str| Err(PipelineError::Job(format!("output name {name:?}: {why}")));
    if name.is_empty() || name == "." || name == ".." {
        return bad("must not be empty");
    }
    if name
        .chars()
        .any(|c| c.is_control() || c == '/' || c == '\\')
    {
        return bad("must be a plain file name (no slashes or control characters)");
    }
    if name.starts_with('.') {
        return bad("must not start with a dot (hidden files are the run's own)");
    }
    if name.len() > MAX_NAME_BYTES {
        return bad(&format!(
            "is {} bytes long; at most {MAX_NAME_BYTES} fit the file names made from it",
            name.len()
        ));
    }
    let extensions = crate::formats::FORMATS
        .iter()
        .map(|f| f.extensions()[0])
        .chain(["_paraview.py", "_visit.py"]);
    for ext in extensions {
        let file = if ext.starts_with('_') {
            format!("{name}{ext}")
        } else {
            format!("{name}.{ext}")
        };
        if FIXED.iter().any(|f| f.eq_ignore_ascii_case(&file)) {
            return bad(&format!(
                "its file {file} would be overwritten by the run's own"
            ));
        }
    }
    Ok(())
}

/// The files of the set whose TF files are named `name`, in no particular order.
pub fn output_files(name: &str) -> Vec<String> {
    let tf_files = crate::formats::FORMATS
        .iter()
        .map(|f| format!("{name}.{}", f.extensions()[0]));
    let scripts = ["_paraview.py", "_visit.py"].map(|s| format!("{name}{s}"));
    tf_files
        .chain(scripts)
        .chain(FIXED.iter().map(|f| f.to_string()))
        .collect()
}

/// Check before any work that the set named `name` can be written into `out`: the name is
/// valid ([`check_name`]) and nothing in `out` stands where one of its files goes (a folder,
/// a FIFO, a device). A missing `out` holds nothing in the way.
pub fn check_outputs(out: &Path, name: &str) -> Result<(), PipelineError> {
    check_name(name)?;
    for file in output_files(name) {
        crate::fs::replaceable(&out.join(file))?;
    }
    Ok(())
}

impl Optimized {
    /// Write the output set into `out` (created if missing) as one set, the TF files named
    /// `name`. Returns the report as written (with the files listed). The caller keeps other
    /// runs out of `out` (`crate::fs::OutputLock`) if it may be shared.
    pub fn write(&self, out: &Path, name: &str) -> Result<Report, PipelineError> {
        check_outputs(out, name)?;
        std::fs::create_dir_all(out).map_err(|source| OutputError::Folder {
            path: out.to_path_buf(),
            source,
        })?;
        let set = crate::fs::OutputSet::begin(out)?;
        let mut report = self.report.clone();
        let t0 = Instant::now();
        let w = crate::formats::write_all(
            set.dir(),
            name,
            &self.exported_points(),
            &self.volume,
            &self.view,
            [1.0; 3],
            Some(self.unit_distance),
        )?;
        let mut files = vec![w.json, w.xml, w.ct];
        files.extend(w.paraview_script);
        files.extend(w.visit_script);
        report.outputs = files
            .iter()
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect();
        report.timings.output += t0.elapsed().as_secs_f64();
        let labels = PlotLabels {
            title: match (&report.prompt, &report.reference_image) {
                (Some(p), _) => p.clone(),
                (None, Some(image)) => format!("like {image}"),
                (None, None) => name.to_string(),
            },
            data_range: self.volume.norm_range,
        };
        driver::write_outputs(
            set.dir(),
            &mut report,
            &self.finished,
            &self.volume.histogram,
            self.tf_curve,
            &labels,
        )?;
        set.commit(&report.outputs)?;
        Ok(report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_checked_before_any_work() {
        assert!(check_name("teeth").is_ok());
        assert!(check_name("a potted tree").is_ok());
        for bad in [
            "", ".", "..", "a/b", "a\\b", ".t2tf", "x\ny", "report", "REPORT",
        ] {
            assert!(check_name(bad).is_err(), "{bad:?} accepted");
        }
        assert!(check_name(&"n".repeat(MAX_NAME_BYTES)).is_ok());
        let long = check_name(&"n".repeat(300)).unwrap_err().to_string();
        assert!(long.contains("300 bytes"), "{long}");
    }
}
