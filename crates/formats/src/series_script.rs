//! The pvpython and VisIt scripts for a volume that is one step of a time series
//! (`Volume::series`): they open the whole series with the one TF (its data range is the
//! series' range, never rescaled per step) and step through its times (docs/DESIGN.md
//! "ParaView facts").
//!
//! ParaView: a `.pvd` or `.series` collection is opened as ParaView opens it (`OpenDataFile`,
//! all its steps); when only some of its steps were used, `ExtractTimeSteps` keeps those and
//! the animation plays only them. A list of files goes to the reader as a list (`.vti`, legacy
//! `.vtk`, and raw files, which ParaView 5.11's ImageReader reads as one time step per file).
//! Step `i` of the script is step `i` of the series as t2tf used it (`STEP_TIMES[i]`,
//! `STEP_FILES[i]`); the script finds ParaView's time for it by order, so a list of `.vti`
//! files whose `TimeValue` ParaView shows works as well as one whose times are indices.
//!
//! VisIt: a `.visit` file (one file per line after `!NBLOCKS 1`) listing the steps in time
//! order, written at run time beside the script (else in the temporary folder); raw steps go
//! through a BOV header each (its `TIME` the step's time) or, for the types BOV would not keep,
//! a `.vti` copy each, as for one volume.

use std::fmt::Write as _;

use super::paraview_script::{
    one_line, py_list, py_str, script_path, source_path, write_open_reader, write_tf_constants,
    SHOW,
};
use super::visit_script::{
    visit_about, visit_constants, VISIT_ARG, VISIT_HERE, VISIT_PLOT, VISIT_WRITE_VTI,
};
use super::{ExportTf, FormatError};
use t2tf_render::camera::ParaViewCamera;
use t2tf_volume::{Series, SourceFormat, Volume};

/// A series as a script names it: absolute UTF-8 paths, the steps t2tf used and their times.
pub(crate) struct SeriesFiles {
    /// The `.pvd`/`.series` file, when the script opens the series through it.
    pub collection: Option<String>,
    /// The steps used, in time order.
    pub files: Vec<String>,
    /// Their times (t2tf's: the collection's times, else the file's index in the group).
    pub times: Vec<f64>,
    /// Steps in the whole series.
    pub total: usize,
}

impl SeriesFiles {
    /// The series' paths; a raw series is always opened as its list of files (a reader needs
    /// the raw files' layout, which no collection carries).
    pub fn new(series: &Series, format: &SourceFormat) -> Result<SeriesFiles, FormatError> {
        let collection = match (&series.collection, format) {
            (Some(c), SourceFormat::Vti { .. } | SourceFormat::LegacyVtk { .. }) => {
                Some(script_path(c)?)
            }
            _ => None,
        };
        Ok(SeriesFiles {
            collection,
            files: series
                .steps
                .iter()
                .map(|s| script_path(&s.path))
                .collect::<Result<_, _>>()?,
            times: series.steps.iter().map(|s| s.time).collect(),
            total: series.total_steps,
        })
    }

    /// Whether the script opens every step the collection holds but shows only some.
    pub fn is_selection(&self) -> bool {
        self.collection.is_some() && self.files.len() < self.total
    }

    /// One line for the scripts' headers: how many steps, at which times, from what.
    pub fn summary(&self) -> String {
        let n = self.files.len();
        let (first, last) = (self.times[0], self.times[n - 1]);
        let of = if n < self.total {
            format!("{n} of {} time steps", self.total)
        } else if n == 1 {
            "1 time step".to_string()
        } else {
            format!("{n} time steps")
        };
        format!("{of}, times {first:?} to {last:?}")
    }

    /// `COLLECTION`, `STEP_FILES`, `STEP_TIMES`, `TOTAL_STEPS` as Python constants.
    pub fn write_constants(&self, w: &mut String) {
        let collection = self.collection.as_deref().map_or("None".into(), py_str);
        let _ = writeln!(w, "COLLECTION = {collection}");
        self.write_steps(w);
        let _ = writeln!(w, "TOTAL_STEPS = {}", self.total);
    }

    /// `STEP_FILES` (one per line) and `STEP_TIMES` as Python constants.
    pub fn write_steps(&self, w: &mut String) {
        let files: String = self
            .files
            .iter()
            .map(|f| format!("    {},\n", py_str(f)))
            .collect();
        let times = py_list(self.times.iter().copied());
        let _ = write!(w, "STEP_FILES = [\n{files}]\nSTEP_TIMES = {times}\n");
    }
}

/// `find_file(path)`, the file or the one of its name beside the script, and
/// `pick_steps(argv)`, the steps `--time`/`--step` ask for (all without them), shared by both
/// scripts.
const PICK_AND_FIND: &str = r#"def find_file(path):
    """The file's path; if it moved, look for the file of that name beside this script."""
    if os.path.exists(path):
        return path
    here = os.path.dirname(os.path.abspath(globals().get("__file__", ".")))
    beside = os.path.join(here, os.path.basename(path))
    if os.path.exists(beside):
        return beside
    sys.exit("t2tf script: file not found: " + path)


def pick_steps(time, step):
    """Indices into STEP_TIMES to show: step I, the step nearest time T, else every step."""
    if step is not None:
        if not 0 <= step < len(STEP_TIMES):
            sys.exit("t2tf script: --step %d: the steps are 0 to %d" % (step, len(STEP_TIMES) - 1))
        return [step]
    if time is not None:
        return [min(range(len(STEP_TIMES)), key=lambda i: abs(STEP_TIMES[i] - time))]
    return list(range(len(STEP_TIMES)))


def picture_name(path, step, single):
    """PATH itself for one chosen step; else PATH_0000.png, PATH_0001.png, ... by step."""
    if single:
        return path
    root, ext = os.path.splitext(path)
    return "%s_%04d%s" % (root, step, ext or ".png")
"#;

/// The pvpython script for a volume that is one step of `series`.
pub(crate) fn paraview(
    tf: &ExportTf,
    volume: &Volume,
    series: &Series,
    view: &ParaViewCamera,
    background: [f64; 3],
    script_name: &str,
) -> Result<String, FormatError> {
    let (_, format) = source_path(volume)?;
    let files = SeriesFiles::new(series, format)?;
    let mut s = String::new();
    let w = &mut s;
    let opened = match (&files.collection, files.is_selection()) {
        (Some(_), false) => "ParaView opens its collection COLLECTION.",
        (Some(_), true) => {
            "ParaView opens its collection\n# COLLECTION (all its steps) and ExtractTimeSteps \
             keeps the steps t2tf used (STEP_TIMES),\n# the only ones the animation plays."
        }
        (None, _) => "ParaView opens the list of files\n# STEP_FILES with one reader.",
    };
    let _ = writeln!(
        w,
        r#"# Generated by t2tf: opens a time series in ParaView with the transfer function "{name}".
#
#   pvpython {script} [--screenshot OUT.png] [--time T | --step I] [--size W H] [--print-tf]
#   headless: xvfb-run -a pvpython --dr {script} --screenshot OUT.png
#   ParaView GUI: View > Python Shell > Run Script.
#
# The series: {summary}. {opened}
# The animation scene snaps to these time steps. --screenshot OUT.png saves one picture per
# step, OUT_0000.png, OUT_0001.png, ... (numbered as STEP_TIMES); --time T shows only the step
# nearest T (a time of STEP_TIMES), --step I only step I (0 = the first); either saves OUT.png.
# --print-tf prints the colour and opacity points ParaView holds after the last step shown, as
# JSON.
#
# One transfer function for every step: its data range is the series' range, so colour and
# opacity are set directly (not through presets) and never rescaled when the time changes
# (AutomaticRescaleRangeMode "Never"). The opacity is meant for ScalarOpacityUnitDistance =
# UNIT_DISTANCE (world units): VTK then renders opacity 1 - exp(-sigma * step / L), as t2tf
# does. The camera is t2tf's (45 degree view angle).
import argparse
import json
import os
import sys

import paraview.simple as pvs
"#,
        name = one_line(&tf.name),
        script = one_line(script_name),
        summary = files.summary(),
    );
    files.write_constants(w);
    write_tf_constants(w, tf, volume, view, background, format);
    let _ = writeln!(w, "\n{PICK_AND_FIND}\n\ndef open_files(paths):");
    write_open_reader(w, volume, format, "paths");
    if matches!(format, SourceFormat::Raw { .. }) {
        // ParaView 5.11's default; other versions may stack the files into one volume.
        let _ = writeln!(
            w,
            r#"    if reader.GetProperty("ReadAsImageStack") is not None:
        reader.ReadAsImageStack = 0"#
        );
    }
    let _ = writeln!(
        w,
        r#"    return reader


def as_list(values):
    """A TimestepValues property as a list (ParaView gives one value as a number)."""
    if values is None:
        return []
    try:
        return [float(t) for t in values]
    except TypeError:
        return [float(values)]


def timestep_values(source):
    source.UpdatePipelineInformation()
    return as_list(source.TimestepValues)


def open_list():
    """STEP_FILES with one reader, and ParaView's time for each (by order)."""
    reader = open_files([find_file(path) for path in STEP_FILES])
    times = timestep_values(reader)
    if len(times) != len(STEP_FILES):
        # No time from the reader (one file): the steps' own times.
        times = list(STEP_TIMES)
    return reader, times


def open_series():
    """The source to show, and ParaView's time for each step of STEP_TIMES."""
    if COLLECTION is None:
        return open_list()
    try:
        reader = pvs.OpenDataFile(find_file(COLLECTION))
    except RuntimeError:
        reader = None
    if reader is None:
        # ParaView knows a .series file by its full extension (NAME.vti.series).
        print("t2tf script: ParaView has no reader for %s; opening its files" % COLLECTION)
        return open_list()
    # The array to read: PointArrayStatus for the XML readers (.series), PointArrays for .pvd.
    for arrays in ("PointArrayStatus", "PointArrays"):
        if arrays in reader.ListProperties():
            setattr(reader, arrays, [ARRAY])
            break
    times = timestep_values(reader)
    if not times:
        sys.exit("t2tf script: ParaView finds no time steps in " + COLLECTION)
    if len(times) != TOTAL_STEPS:
        print("t2tf script: %s has %d time steps in ParaView, %d for t2tf"
              % (COLLECTION, len(times), TOTAL_STEPS))
    # Each step t2tf used is the collection's step nearest its time.
    indices = [min(range(len(times)), key=lambda i: abs(times[i] - t)) for t in STEP_TIMES]
    if indices == list(range(len(times))):
        return reader, times
    steps = pvs.ExtractTimeSteps(Input=reader)
    steps.SelectionMode = "Select Time Steps"
    steps.TimeStepIndices = indices
    # The animation takes its times from the extracted steps, not the reader's (ParaView 5.11
    # does so itself once ExtractTimeSteps reads the reader).
    keeper = pvs.GetTimeKeeper()
    suppressed = list(keeper.SuppressedTimeSources)
    if reader not in suppressed:
        keeper.SuppressedTimeSources = suppressed + [reader]
    return steps, [times[i] for i in indices]


{SHOW}

def main(argv):
    parser = argparse.ArgumentParser(description="Show a time series with the t2tf transfer function " + TF_NAME)
    parser.add_argument("--screenshot", metavar="PATH", help="save PATH_0000.png, ... (one per time step; PATH itself with --time or --step) and exit")
    parser.add_argument("--time", type=float, metavar="T", help="show only the step nearest time T")
    parser.add_argument("--step", type=int, metavar="I", help="show only step I (0 = the first)")
    parser.add_argument("--size", nargs=2, type=int, metavar=("W", "H"), help="view size in pixels")
    parser.add_argument("--print-tf", action="store_true", help="print ParaView's colour and opacity points at the end, as JSON")
    args, _ = parser.parse_known_args(argv)
    shown = pick_steps(args.time, args.step)
    source, times = open_series()
    scene = pvs.GetAnimationScene()
    scene.UpdateAnimationUsingDataTimeSteps()
    scene.PlayMode = "Snap To TimeSteps"
    scene.AnimationTime = times[shown[0]]
    view = show(source, args.size)
    single = args.time is not None or args.step is not None
    for step in shown:
        scene.AnimationTime = times[step]
        pvs.Render(view)
        if args.screenshot:
            path = picture_name(args.screenshot, step, single)
            size = args.size or list(view.ViewSize)
            pvs.SaveScreenshot(path, view, ImageResolution=size)
            print("t2tf script: wrote %s (step %d, time %r)" % (path, step, STEP_TIMES[step]))
    if args.print_tf:
        lut = pvs.GetColorTransferFunction(ARRAY)
        state = {{
            "rgb_points": list(lut.RGBPoints),
            "opacity_points": list(pvs.GetOpacityTransferFunction(ARRAY).Points),
            "unit_distance": pvs.GetDisplayProperties(source, view).ScalarOpacityUnitDistance,
            "rescale_mode": lut.GetProperty("AutomaticRescaleRangeMode").GetData(),
            "view_time": view.ViewTime,
            "paraview_times": [times[step] for step in shown],
            "scene_times": as_list(pvs.GetTimeKeeper().TimestepValues),
        }}
        print("t2tf tf: " + json.dumps(state))


main(sys.argv[1:])"#
    );
    Ok(s)
}

/// The VisIt script for a volume that is one step of `series`.
pub(crate) fn visit(
    tf: &ExportTf,
    volume: &Volume,
    series: &Series,
    view: &ParaViewCamera,
    background: [f64; 3],
    script_name: &str,
) -> Result<String, FormatError> {
    let (_, format) = source_path(volume)?;
    let files = SeriesFiles::new(series, format)?;
    let constants = visit_constants(tf, volume, view, background, format, "%(time)s", "%(file)s")?;
    let raw = match format {
        SourceFormat::Raw { .. } => {
            "\n# Each raw step reaches VisIt as a .bov header (its TIME the step's time) or, for a type\n\
             # BOV would not keep, a .vti copy, written there too."
        }
        _ => "",
    };
    let mut s = String::new();
    let w = &mut s;
    let _ = writeln!(
        w,
        r#"# Generated by t2tf: a VisIt Volume plot of a time series with the transfer function "{name}".
#
#   visit -cli -nowin -s {script} [--screenshot OUT.png] [--time T | --step I] [--size W H]
#
# The series: {summary}. VisIt opens it as a .visit file listing STEP_FILES
# in time order (after "!NBLOCKS 1"), which this script writes beside itself, else in the
# temporary folder; the time slider's state I is step I of STEP_TIMES.{raw}
# --screenshot OUT.png saves one picture per step, OUT_0000.png, OUT_0001.png, ... (numbered as
# STEP_TIMES); --time T shows only the step nearest T (a time of STEP_TIMES), --step I only step
# I (0 = the first); either saves OUT.png. Colour and opacity keep one range, the series'.
{about}import os
import shutil
import struct
import sys
import tempfile

SCRIPT_NAME = {script_py}"#,
        name = one_line(&tf.name),
        script = one_line(script_name),
        summary = files.summary(),
        about = visit_about(tf, volume),
        script_py = py_str(script_name),
    );
    files.write_steps(w);
    let _ = writeln!(
        w,
        r#"{constants}

{VISIT_ARG}

{PICK_AND_FIND}

{VISIT_WRITE_VTI}

{VISIT_HERE}

def database(volume, time, stem):
    """What VisIt opens for one step: its file, or a .bov header or .vti copy of a raw file."""
    if VTI_HEAD is not None:
        name = stem + ".t2tf.vti"
        for folder in (here(), tempfile.gettempdir()):
            vti = os.path.join(folder, name)
            if os.path.exists(vti) and os.path.getmtime(vti) >= os.path.getmtime(volume):
                return vti
            try:
                write_vti(volume, vti)
                return vti
            except OSError:
                continue
        sys.exit("could not write a .vti copy of " + volume)
    if BOV_HEADER is None:
        return volume
    # The header names the volume by its absolute path, so it may live in another folder.
    for folder in (here(), tempfile.gettempdir()):
        bov = os.path.join(folder, stem + ".bov")
        try:
            with open(bov, "w") as f:
                f.write(BOV_HEADER % {{"time": repr(time), "file": volume}})
            return bov
        except OSError:
            continue
    sys.exit("could not write a .bov header for " + volume)


def visit_list():
    """The .visit file: every step's database, one per line, in time order."""
    lines = ["!NBLOCKS 1"]
    stems = set()
    for i, (path, time) in enumerate(zip(STEP_FILES, STEP_TIMES)):
        volume = os.path.abspath(find_file(path))
        stem = os.path.splitext(os.path.basename(volume))[0]
        if stem in stems:
            stem = "%s_%d" % (stem, i)
        stems.add(stem)
        lines.append(os.path.abspath(database(volume, time, stem)))
    name = os.path.splitext(SCRIPT_NAME)[0] + ".visit"
    for folder in (here(), tempfile.gettempdir()):
        listing = os.path.join(folder, name)
        try:
            with open(listing, "w") as f:
                f.write("\n".join(lines) + "\n")
            return listing
        except OSError:
            continue
    sys.exit("could not write a .visit file for the series")


OpenDatabase(visit_list())
{VISIT_PLOT}time_arg = arg("--time", 1)
step_arg = arg("--step", 1)
shown = pick_steps(float(time_arg[0]) if time_arg else None, int(step_arg[0]) if step_arg else None)
SetTimeSliderState(shown[0])
shot = arg("--screenshot", 1)
if shot:
    size = arg("--size", 2) or ["512", "512"]
    for step in shown:
        SetTimeSliderState(step)
        s = SaveWindowAttributes()
        s.fileName = picture_name(shot[0], step, bool(time_arg or step_arg))
        s.family = 0
        s.format = s.PNG
        s.width, s.height = int(size[0]), int(size[1])
        s.resConstraint = s.NoConstraint
        SetSaveWindowAttributes(s)
        SaveWindow()
    sys.exit(0)"#
    );
    Ok(s)
}
