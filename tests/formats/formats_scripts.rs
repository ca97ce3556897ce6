//! write_all and the generated pvpython / VisIt scripts (content, Python syntax, atomicity).
//! Running the pvpython script in ParaView is tests/paraview/paraview.rs.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use t2tf::camera::ParaViewCamera;
use t2tf::formats::{freeform_opacity, paraview_script, visit_script, write_all, ExportTf};
use t2tf::tf::ControlPoints;
use t2tf::volume::{
    ByteOrder, Geometry, ScalarType, Series, SeriesStep, SourceFormat, TypedBuffer, Volume,
    VolumeSource,
};

/// An 8×6×5 volume with an origin and uneven spacing, said to come from a raw file in
/// `format` (also the placeholder test's volume).
pub(crate) fn volume(format: SourceFormat) -> Volume {
    let g = Geometry {
        dims: [8, 6, 5],
        spacing: [0.5, 1.0, 2.0],
        origin: [-1.0, 2.0, 3.5],
    };
    let values: Vec<f64> = (0..g.voxel_count())
        .map(|i| (i % 17) as f64 * 10.0)
        .collect();
    let mut v = Volume::from_buffer(Path::new("v"), g, &TypedBuffer::from_f64(values)).unwrap();
    v.source = Some(VolumeSource {
        path: PathBuf::from("data/vol_8x6x5_uint16.raw"),
        format,
    });
    v
}

fn raw(t: ScalarType) -> SourceFormat {
    SourceFormat::Raw {
        scalar_type: t,
        byte_order: ByteOrder::Big,
    }
}

fn cp() -> ControlPoints {
    ControlPoints::evenly_spaced(vec![0.0, 30.0, 200.0, 10.0], vec![[0.2, 0.4, 0.6]; 4]).unwrap()
}

/// `python3 -m py_compile` the script (syntax only). Tests calling this are ignored where the
/// build found no python3 (`cfg(t2tf_python)`, build.rs).
fn compiles(path: &Path) {
    let o = Command::new("python3")
        .arg("-m")
        .arg("py_compile")
        .arg(path)
        .output()
        .expect("run python3 (build.rs found it, or T2TF_REQUIRE_PYTHON requires it)");
    assert!(
        o.status.success(),
        "{} is not valid Python: {}",
        path.display(),
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn write_all_writes_every_output_atomically() {
    let v = volume(raw(ScalarType::U16));
    let d = tempfile::tempdir().unwrap();
    let view = ParaViewCamera::front(&v.geometry, 3.0);
    let files = write_all(d.path(), "vol", &cp(), &v, &view, [1.0, 1.0, 1.0], None).unwrap();
    let mut names: Vec<String> = std::fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "vol.ct",
            "vol.json",
            "vol.xml",
            "vol_paraview.py",
            "vol_visit.py"
        ],
        "exactly the outputs, no temporary files left"
    );
    let pv = std::fs::read_to_string(files.paraview_script.as_ref().unwrap()).unwrap();
    for needle in [
        "pvs.ImageReader(FileNames=[path])",
        "reader.DataScalarType = \"unsigned short\"",
        "reader.DataByteOrder = \"BigEndian\"",
        "reader.DataExtent = [0, 7, 0, 5, 0, 4]",
        "reader.DataSpacing = [0.5, 1.0, 2.0]",
        "reader.DataOrigin = [-1.0, 2.0, 3.5]",
        "lut.AutomaticRescaleRangeMode = \"Never\"",
        "disp.ScalarOpacityUnitDistance = UNIT_DISTANCE",
        "pvs._DisableFirstRenderCameraReset()",
        "view.UseColorPaletteForBackground = 0",
        "CAMERA_VIEW_ANGLE = 45.0",
        "UNIT_DISTANCE = 1.1666666666666667",
        "--screenshot",
    ] {
        assert!(pv.contains(needle), "pvpython script lacks {needle}\n{pv}");
    }
    // The volume path is absolute so the script runs from anywhere.
    let abs = std::path::absolute("data/vol_8x6x5_uint16.raw").unwrap();
    assert!(pv.contains(&serde_json::to_string(abs.to_str().unwrap()).unwrap()));

    let vi = std::fs::read_to_string(files.visit_script.as_ref().unwrap()).unwrap();
    for needle in [
        "AddPlot(\"Volume\", VARIABLE)",
        "atts.opacityMode = atts.FreeformMode",
        "atts.useColorVarMin = 1",
        "COLOR_MIN = 0.0",
        "COLOR_MAX = 160.0",
        // uint16 has no exact BOV type: a .vti copy typed UInt16, big-endian like the file.
        "BOV_HEADER = None",
        r#"type=\"UInt16\""#,
        r#"byte_order=\"BigEndian\""#,
        r#"Origin=\"-1.0 2.0 3.5\" Spacing=\"0.5 1.0 2.0\""#,
        "VTI_ORDER = \">\"",
        "VTI_BYTES = 480",
        "VIEW_ANGLE = 45.0",
    ] {
        assert!(vi.contains(needle), "VisIt script lacks {needle}");
    }
    let freeform = vi.split("FREEFORM_OPACITY = (").nth(1).unwrap();
    let freeform = freeform.split(",)").next().unwrap();
    assert_eq!(freeform.split(", ").count(), 256);
    assert_eq!(files.tf.opacity_points.first().unwrap().0, 0.0);
}

#[cfg(unix)]
#[test]
fn scripts_name_the_volume_by_its_canonical_path() {
    // `t2tf optimize ../shared/x.raw` run from a subfolder: the scripts name the file without
    // the `..`, and through a symlink its target.
    let d = tempfile::tempdir().unwrap();
    let data = d.path().join("data");
    let out = d.path().join("out");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::create_dir_all(&out).unwrap();
    let file = data.join("vol_8x6x5_uint16.raw");
    std::fs::write(&file, vec![0u8; 8 * 6 * 5 * 2]).unwrap();
    let link = d.path().join("link.raw");
    std::os::unix::fs::symlink(&file, &link).unwrap();
    let canonical = std::fs::canonicalize(&file).unwrap();
    let quoted = serde_json::to_string(canonical.to_str().unwrap()).unwrap();
    for given in [out.join("../data/vol_8x6x5_uint16.raw"), link] {
        let mut v = volume(raw(ScalarType::U16));
        v.source.as_mut().unwrap().path = given.clone();
        let view = ParaViewCamera::front(&v.geometry, 3.0);
        let files = write_all(&out, "vol", &cp(), &v, &view, [1.0; 3], None).unwrap();
        for script in [files.paraview_script, files.visit_script] {
            let text = std::fs::read_to_string(script.unwrap()).unwrap();
            assert!(
                text.contains(&quoted),
                "{}: lacks {quoted}",
                given.display()
            );
            assert!(!text.contains("/../"), "{}", given.display());
        }
    }
}

#[test]
#[cfg_attr(not(t2tf_python), ignore = "needs python3")]
fn generated_scripts_are_valid_python() {
    let v = volume(raw(ScalarType::U16));
    let d = tempfile::tempdir().unwrap();
    let view = ParaViewCamera::front(&v.geometry, 3.0);
    let files = write_all(d.path(), "vol", &cp(), &v, &view, [1.0, 1.0, 1.0], None).unwrap();
    compiles(files.paraview_script.as_ref().unwrap());
    compiles(files.visit_script.as_ref().unwrap());
}

#[test]
fn freeform_opacity_samples_the_opacity_curve() {
    let tf = ExportTf {
        name: "f".into(),
        rgb_points: vec![(0.0, [0.0; 3]), (255.0, [1.0; 3])],
        opacity_points: vec![(0.0, 0.0), (255.0, 1.0)],
        unit_distance: None,
    };
    let f = freeform_opacity(&tf);
    assert_eq!(f.len(), 256);
    assert!(
        f.iter().enumerate().all(|(i, &v)| v as usize == i),
        "identity ramp"
    );
}

#[test]
fn readers_per_source_format_and_missing_source() {
    let tf = ExportTf::from_control_points("t", &cp(), &volume(raw(ScalarType::U8)), None);
    let view = ParaViewCamera::front(&volume(raw(ScalarType::U8)).geometry, 2.0);
    let vti = volume(SourceFormat::Vti {
        array: "density".into(),
    });
    let s = paraview_script(&tf, &vti, &view, [0.0; 3], "t_paraview.py").unwrap();
    assert!(s.contains("pvs.XMLImageDataReader(FileName=[path])"));
    assert!(s.contains("ARRAY = \"density\""));
    let legacy = volume(SourceFormat::LegacyVtk {
        array: "scalars".into(),
    });
    assert!(
        paraview_script(&tf, &legacy, &view, [0.0; 3], "t_paraview.py")
            .unwrap()
            .contains("pvs.LegacyVTKReader(FileNames=[path])")
    );
    // 64-bit integers: ParaView 5.11's ImageReader has no "long long"; "long" is LP64 64-bit.
    let s = paraview_script(
        &tf,
        &volume(raw(ScalarType::I64)),
        &view,
        [0.0; 3],
        "t_paraview.py",
    )
    .unwrap();
    assert!(s.contains("reader.DataScalarType = \"long\""));
    // VisIt's BOV has no 64-bit integers: a clear error, and write_all skips that script.
    let e = visit_script(
        &tf,
        &volume(raw(ScalarType::I64)),
        &view,
        [0.0; 3],
        "t_visit.py",
    )
    .unwrap_err();
    assert!(e.to_string().contains("BOV"), "{e}");
    let mut none = volume(raw(ScalarType::U8));
    none.source = None;
    let e = paraview_script(&tf, &none, &view, [0.0; 3], "t_paraview.py").unwrap_err();
    assert!(e.to_string().contains("not read from a file"));
    let d = tempfile::tempdir().unwrap();
    let files = write_all(d.path(), "x", &cp(), &none, &view, [0.0; 3], None).unwrap();
    assert!(files.paraview_script.is_none() && files.visit_script.is_none());
    assert!(files.json.exists());
    assert!(write_all(d.path(), "../x", &cp(), &none, &view, [0.0; 3], None).is_err());
}

/// Stand-ins for the VisIt CLI functions the script calls, so that its own Python (the
/// database it prepares and opens) runs here. Every VisIt name it uses must be listed: a name
/// missing here is a NameError. The names were checked against VisIt's documentation:
/// OpenDatabase, AddPlot, SetPlotOptions, DrawPlots, GetView3D/SetView3D, AnnotationAttributes/
/// SetAnnotationAttributes, SaveWindowAttributes/SetSaveWindowAttributes/SaveWindow and
/// ColorControlPointList/ColorControlPoint are functions of VisIt's Python CLI (Python
/// Scripting manual); VolumeAttributes' fields opacityMode (FreeformMode), freeformOpacity
/// (256 unsigned chars), opacityAttenuation, useColorVarMin/colorVarMin, useColorVarMax/
/// colorVarMax, useOpacityVarMin/opacityVarMin, useOpacityVarMax/opacityVarMax, lightingFlag
/// and colorControlPoints are the Volume plot's attributes (src/plots/Volume/Volume.xml).
const VISIT_STUBS: &str = r#"
import json, sys
class Stub:
    def __init__(self, *a, **k): pass
    def __getattr__(self, name): return Stub()
    def __call__(self, *a, **k): return Stub()
opened = []
def OpenDatabase(path): opened.append(path)
names = {n: Stub for n in ["AddPlot", "VolumeAttributes", "ColorControlPointList",
    "ColorControlPoint", "SetPlotOptions", "AnnotationAttributes", "SetAnnotationAttributes",
    "DrawPlots", "GetView3D", "SetView3D", "SaveWindowAttributes", "SetSaveWindowAttributes",
    "SaveWindow"]}
script = sys.argv[1]
g = dict(names, OpenDatabase=OpenDatabase, __name__="__main__", __file__=script)
sys.argv = [script]
exec(compile(open(script).read(), script, "exec"), g)
print(json.dumps(opened))
"#;

/// The values VisIt reads from the database the script opens: a `.vti` (read with t2tf's
/// own VTK XML reader), or a `.bov` interpreted as VisIt's BOV documentation defines its
/// DATA_FORMAT values (BYTE unsigned 8-bit, SHORT signed 16-bit, INT signed 32-bit, FLOAT,
/// DOUBLE) and DATA_ENDIAN.
fn values_visit_reads(db: &Path) -> Vec<f64> {
    if db.extension().unwrap() == "vti" {
        let d = t2tf::volume::decode(db, &Default::default()).unwrap();
        let mut v = Vec::new();
        d.buffer.for_each(|x| v.push(x));
        return v;
    }
    assert_eq!(db.extension().unwrap(), "bov", "{}", db.display());
    let header = std::fs::read_to_string(db).unwrap();
    let key = |k: &str| {
        header
            .lines()
            .find_map(|l| l.strip_prefix(&format!("{k}: ")))
            .unwrap_or_else(|| panic!("{k} missing in {header}"))
            .trim()
            .to_string()
    };
    let bytes = std::fs::read(db.with_file_name(key("DATA_FILE"))).unwrap();
    let big = key("DATA_ENDIAN") == "BIG";
    let size = match key("DATA_FORMAT").as_str() {
        "BYTE" => 1,
        "SHORT" => 2,
        "INT" => 4,
        f => panic!("DATA_FORMAT {f} not handled by this test"),
    };
    let read = |b: &[u8]| -> f64 {
        match b.len() {
            1 => b[0] as f64,
            2 => {
                let a = [b[0], b[1]];
                (if big {
                    i16::from_be_bytes(a)
                } else {
                    i16::from_le_bytes(a)
                }) as f64
            }
            _ => {
                let a = [b[0], b[1], b[2], b[3]];
                (if big {
                    i32::from_be_bytes(a)
                } else {
                    i32::from_le_bytes(a)
                }) as f64
            }
        }
    };
    bytes.chunks(size).map(read).collect()
}

/// Run the VisIt script's own Python with stand-ins for VisIt; the database it opened.
fn visit_opens(script: &Path, dir: &Path) -> PathBuf {
    let stubs = dir.join("visit_stubs.py");
    std::fs::write(&stubs, VISIT_STUBS).unwrap();
    let out = Command::new("python3")
        .arg(&stubs)
        .arg(script)
        .output()
        .expect("run python3 (build.rs found it, or T2TF_REQUIRE_PYTHON requires it)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let opened: Vec<String> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(opened.len(), 1, "{opened:?}");
    PathBuf::from(&opened[0])
}

#[test]
#[cfg_attr(not(t2tf_python), ignore = "needs python3")]
fn visit_reads_raw_values_exactly() {
    // uint16 values above 32767 (a SHORT BOV header would read them as negative numbers),
    // and int16 / uint8 files, which keep their lossless BOV header, in both byte
    // orders.
    for (t, order) in [
        (ScalarType::U16, ByteOrder::Little),
        (ScalarType::U16, ByteOrder::Big),
        (ScalarType::I16, ByteOrder::Big),
        (ScalarType::U8, ByteOrder::Little),
    ] {
        let d = tempfile::tempdir().unwrap();
        let g = Geometry {
            dims: [8, 6, 5],
            spacing: [0.5, 1.0, 2.0],
            origin: [-1.0, 2.0, 3.5],
        };
        let n = g.voxel_count();
        let (lo, hi) = t.integer_range().unwrap();
        let want: Vec<f64> = (0..n)
            .map(|i| lo + ((i as f64 * 977.0) % (hi - lo + 1.0)))
            .collect();
        let bytes: Vec<u8> = want
            .iter()
            .flat_map(|&v| match (t, order) {
                (ScalarType::U16, ByteOrder::Little) => (v as u16).to_le_bytes().to_vec(),
                (ScalarType::U16, ByteOrder::Big) => (v as u16).to_be_bytes().to_vec(),
                (ScalarType::I16, ByteOrder::Big) => (v as i16).to_be_bytes().to_vec(),
                _ => vec![v as u8],
            })
            .collect();
        // The data and the output in separate folders: the side file VisIt opens must go to
        // the script's folder, as the data folder may be read-only.
        let data = d.path().join("data");
        let out = d.path().join("out");
        std::fs::create_dir_all(&data).unwrap();
        std::fs::create_dir_all(&out).unwrap();
        let raw_path = data.join(format!("vol_8x6x5_{}.raw", t.scivis_name()));
        std::fs::write(&raw_path, &bytes).unwrap();
        let mut vol = volume(SourceFormat::Raw {
            scalar_type: t,
            byte_order: order,
        });
        vol.source.as_mut().unwrap().path = raw_path.clone();
        let tf = ExportTf::from_control_points("t", &cp(), &vol, None);
        let view = ParaViewCamera::front(&vol.geometry, 2.0);
        let script = out.join("t_visit.py");
        std::fs::write(
            &script,
            visit_script(&tf, &vol, &view, [0.0; 3], "t_visit.py").unwrap(),
        )
        .unwrap();
        let db = visit_opens(&script, d.path());
        assert_eq!(db.parent(), Some(out.as_path()), "{}", db.display());
        let in_data: Vec<_> = std::fs::read_dir(&data).unwrap().collect();
        assert_eq!(in_data.len(), 1, "the script wrote into the data folder");
        assert!(want.iter().any(|&v| v > 32767.0) || t != ScalarType::U16);
        let got = values_visit_reads(&db);
        assert_eq!(
            got,
            want,
            "{t:?} {order:?}: VisIt would read other values from {}",
            db.display()
        );
        if t == ScalarType::U16 {
            let geometry = t2tf::volume::decode(&db, &Default::default()).unwrap();
            assert_eq!(geometry.geometry.dims, g.dims);
            assert_eq!(geometry.geometry.spacing, g.spacing);
            assert_eq!(geometry.geometry.origin, g.origin);
            assert_eq!(geometry.buffer.scalar_type(), ScalarType::U16);
            // A second run reuses the copy (it is newer than the raw file).
            assert_eq!(visit_opens(&script, d.path()), db);
        }
    }
}

/// `volume(format)` as the last used step of a time series of `total` files under `dir` (they
/// need not exist): `NAME_%04d.EXT`, at times 200, 400, ... when `collection` (a `.pvd` or
/// `.series` file in `dir`) lists them, else at their index; `keep` are the steps used.
fn series_volume(
    format: SourceFormat,
    dir: &Path,
    collection: Option<&str>,
    keep: &[usize],
    total: usize,
) -> Volume {
    let name = |i: usize| match &format {
        SourceFormat::Raw { scalar_type, .. } => {
            format!("gs_{i:04}_8x6x5_{}.raw", scalar_type.scivis_name())
        }
        SourceFormat::Vti { .. } => format!("gs_{i:04}.vti"),
        SourceFormat::LegacyVtk { .. } => format!("gs_{i:04}.vtk"),
    };
    let time = |i: usize| match collection {
        Some(_) => 200.0 * (i + 1) as f64,
        None => i as f64,
    };
    let steps: Vec<SeriesStep> = keep
        .iter()
        .map(|&i| SeriesStep {
            time: time(i),
            path: dir.join(name(i)),
        })
        .collect();
    let mut v = volume(format);
    v.source.as_mut().unwrap().path = steps.last().unwrap().path.clone();
    v.series = Some(Arc::new(Series {
        collection: collection.map(|c| dir.join(c)),
        steps,
        total_steps: total,
    }));
    v
}

/// `path` as the scripts quote it (absolute; the test paths do not exist, so not canonical).
fn quoted(path: &Path) -> String {
    serde_json::to_string(std::path::absolute(path).unwrap().to_str().unwrap()).unwrap()
}

/// Both scripts for `v`, with the test's TF and view.
fn scripts(v: &Volume) -> (String, String) {
    let tf = ExportTf::from_control_points("gs", &cp(), v, None);
    let view = ParaViewCamera::front(&v.geometry, 2.0);
    (
        paraview_script(&tf, v, &view, [0.0; 3], "gs_paraview.py").unwrap(),
        visit_script(&tf, v, &view, [0.0; 3], "gs_visit.py").unwrap(),
    )
}

fn has_all(text: &str, needles: &[&str], what: &str) {
    for needle in needles {
        assert!(text.contains(needle), "{what} lacks {needle}\n{text}");
    }
}

#[test]
fn series_scripts_open_the_series_with_its_times() {
    let dir = Path::new("data/series");
    let vti = || SourceFormat::Vti { array: "v".into() };
    let files = |v: &Volume| -> Vec<String> {
        v.series
            .as_ref()
            .unwrap()
            .steps
            .iter()
            .map(|s| quoted(&s.path))
            .collect()
    };

    // A whole .pvd: ParaView opens the collection, every step; VisIt a .visit list.
    let pvd = series_volume(vti(), dir, Some("gs.pvd"), &[0, 1, 2, 3], 4);
    let (pv, vi) = scripts(&pvd);
    has_all(
        &pv,
        &[
            "opens a time series in ParaView",
            "The series: 4 time steps, times 200.0 to 800.0. ParaView opens its collection",
            &format!("COLLECTION = {}", quoted(&dir.join("gs.pvd"))),
            "STEP_TIMES = [200.0, 400.0, 600.0, 800.0]",
            "TOTAL_STEPS = 4",
            "ARRAY = \"v\"",
            "reader = pvs.OpenDataFile(find_file(COLLECTION))",
            "steps = pvs.ExtractTimeSteps(Input=reader)",
            "scene.UpdateAnimationUsingDataTimeSteps()",
            "scene.PlayMode = \"Snap To TimeSteps\"",
            "lut.AutomaticRescaleRangeMode = \"Never\"",
            "disp.ScalarOpacityUnitDistance = UNIT_DISTANCE",
            "--screenshot OUT.png saves one picture per\n# step, OUT_0000.png, OUT_0001.png",
            "--time T",
            "--step I",
            "--print-tf",
        ],
        "pvd script",
    );
    for f in files(&pvd) {
        assert!(pv.contains(&format!("    {f},\n")), "{f}");
        assert!(vi.contains(&format!("    {f},\n")), "{f}");
    }
    has_all(
        &vi,
        &[
            "a VisIt Volume plot of a time series",
            "STEP_TIMES = [200.0, 400.0, 600.0, 800.0]",
            "VARIABLE = \"v\"",
            "BOV_HEADER = None",
            "lines = [\"!NBLOCKS 1\"]",
            "OpenDatabase(visit_list())",
            "SetTimeSliderState(step)",
            "atts.useColorVarMin = 1",
        ],
        "pvd VisIt script",
    );
    assert!(!vi.contains("COLLECTION") && !vi.contains("OpenDatabase(database())"));

    // Steps 0 and 3 of the .pvd: the collection still, the animation restricted to them.
    let some = series_volume(vti(), dir, Some("gs.pvd"), &[0, 3], 4);
    let (pv, vi) = scripts(&some);
    has_all(
        &pv,
        &[
            "The series: 2 of 4 time steps, times 200.0 to 800.0. ParaView opens its collection\n\
             # COLLECTION (all its steps) and ExtractTimeSteps keeps the steps t2tf used",
            "STEP_TIMES = [200.0, 800.0]",
            "TOTAL_STEPS = 4",
            "steps.TimeStepIndices = indices",
            "keeper.SuppressedTimeSources = suppressed + [reader]",
        ],
        "selection script",
    );
    has_all(
        &vi,
        &["STEP_TIMES = [200.0, 800.0]"],
        "selection VisIt script",
    );
    for (i, f) in files(&pvd).iter().enumerate() {
        let used = i == 0 || i == 3;
        assert_eq!(pv.contains(f.as_str()), used, "{f}");
        assert_eq!(vi.contains(f.as_str()), used, "{f}");
    }

    // A list of .vti files (times = index), legacy files, and raw files named by a .series:
    // each opened as its list, with the format's reader.
    let list = series_volume(vti(), dir, None, &[0, 1, 2], 3);
    let (pv, _) = scripts(&list);
    has_all(
        &pv,
        &[
            "ParaView opens the list of files\n# STEP_FILES with one reader.",
            "COLLECTION = None",
            "STEP_TIMES = [0.0, 1.0, 2.0]",
            "def open_files(paths):\n    reader = pvs.XMLImageDataReader(FileName=paths)\n    \
             reader.PointArrayStatus = [ARRAY]\n    return reader",
        ],
        "list script",
    );
    let legacy = series_volume(
        SourceFormat::LegacyVtk {
            array: "scalars".into(),
        },
        dir,
        None,
        &[1, 2],
        3,
    );
    let (pv, _) = scripts(&legacy);
    has_all(
        &pv,
        &[
            "The series: 2 of 3 time steps, times 1.0 to 2.0.",
            "reader = pvs.LegacyVTKReader(FileNames=paths)",
            "STEP_TIMES = [1.0, 2.0]",
        ],
        "legacy list script",
    );
    let raw_series = series_volume(raw(ScalarType::U16), dir, Some("gs.raw.series"), &[0, 1], 2);
    let (pv, vi) = scripts(&raw_series);
    has_all(
        &pv,
        &[
            "COLLECTION = None",
            "reader = pvs.ImageReader(FileNames=paths)",
            "reader.DataScalarType = \"unsigned short\"",
            "reader.DataExtent = [0, 7, 0, 5, 0, 4]",
            "        reader.ReadAsImageStack = 0",
            "STEP_TIMES = [200.0, 400.0]",
        ],
        "raw series script",
    );
    has_all(
        &vi,
        &[
            "Each raw step reaches VisIt as a .bov header",
            "BOV_HEADER = None",
            r#"type=\"UInt16\""#,
            "VTI_BYTES = 480",
        ],
        "raw series VisIt script",
    );
    let bov = series_volume(raw(ScalarType::U8), dir, None, &[0, 1], 2);
    let (_, vi) = scripts(&bov);
    assert!(
        vi.contains(r#"BOV_HEADER = "TIME: %(time)s\nDATA_FILE: %(file)s\nDATA_SIZE: 8 6 5\nDATA_FORMAT: BYTE\n"#),
        "{vi}"
    );
    // VisIt has no exact type for 64-bit integers: no script, as for one volume.
    let i64s = series_volume(raw(ScalarType::I64), dir, None, &[0, 1], 2);
    let tf = ExportTf::from_control_points("gs", &cp(), &i64s, None);
    let view = ParaViewCamera::front(&i64s.geometry, 2.0);
    assert!(visit_script(&tf, &i64s, &view, [0.0; 3], "x.py").is_err());

    // A volume that is no series keeps the one-volume scripts.
    let mut one = pvd.clone();
    one.series = None;
    let (pv, vi) = scripts(&one);
    has_all(
        &pv,
        &[
            "opens a volume in ParaView",
            "VOLUME = ",
            "def open_volume(path):\n    reader = pvs.XMLImageDataReader(FileName=[path])",
            "view = show(open_volume(find_volume()), args.size)",
        ],
        "one-volume script",
    );
    has_all(
        &vi,
        &["VOLUME = ", "OpenDatabase(database())"],
        "one-volume VisIt script",
    );
    for (text, what) in [(&pv, "ParaView"), (&vi, "VisIt")] {
        for series_only in [
            "STEP_",
            "COLLECTION",
            "ExtractTimeSteps",
            "AnimationScene",
            "!NBLOCKS",
        ] {
            assert!(!text.contains(series_only), "{what}: {series_only}");
        }
    }
}

#[test]
#[cfg_attr(not(t2tf_python), ignore = "needs python3")]
fn series_scripts_are_valid_python() {
    let d = tempfile::tempdir().unwrap();
    let dir = Path::new("data/series");
    for (i, v) in [
        series_volume(
            SourceFormat::Vti { array: "v".into() },
            dir,
            Some("gs.pvd"),
            &[0, 2],
            3,
        ),
        series_volume(raw(ScalarType::U8), dir, None, &[0, 1, 2], 3),
        series_volume(raw(ScalarType::U16), dir, None, &[0], 1),
    ]
    .iter()
    .enumerate()
    {
        let (pv, vi) = scripts(v);
        for (text, name) in [(pv, "paraview"), (vi, "visit")] {
            let path = d.path().join(format!("s{i}_{name}.py"));
            std::fs::write(&path, text).unwrap();
            compiles(&path);
        }
    }
}

/// Stand-ins for VisIt's CLI functions that record what a series script does with them: the
/// databases it opens, the time slider states it sets (SetTimeSliderState, a function of
/// VisIt's Python CLI) and the file each SaveWindow writes. Arguments after the script are
/// the script's own.
const VISIT_SERIES_STUBS: &str = r#"
import json, sys
class Stub:
    def __init__(self, *a, **k): pass
    def __getattr__(self, name): return Stub()
    def __call__(self, *a, **k): return Stub()
class SaveAtts:
    PNG = "png"
    NoConstraint = "none"
log = {"opened": [], "states": [], "saved": []}
window = {}
def OpenDatabase(path): log["opened"].append(path)
def SetTimeSliderState(state): log["states"].append(state)
def SetSaveWindowAttributes(s): window["name"] = s.fileName
def SaveWindow(): log["saved"].append(window["name"])
names = {n: Stub for n in ["AddPlot", "VolumeAttributes", "ColorControlPointList",
    "ColorControlPoint", "SetPlotOptions", "AnnotationAttributes", "SetAnnotationAttributes",
    "DrawPlots", "GetView3D", "SetView3D"]}
script = sys.argv[1]
g = dict(names, OpenDatabase=OpenDatabase, SetTimeSliderState=SetTimeSliderState,
    SaveWindowAttributes=SaveAtts, SetSaveWindowAttributes=SetSaveWindowAttributes,
    SaveWindow=SaveWindow, __name__="__main__", __file__=script)
sys.argv = [script] + sys.argv[2:]
try:
    exec(compile(open(script).read(), script, "exec"), g)
except SystemExit as e:
    if e.code not in (None, 0):
        raise
print(json.dumps(log))
"#;

/// Run a VisIt series script's own Python with `VISIT_SERIES_STUBS`; what it did.
fn visit_series_run(script: &Path, args: &[&str]) -> serde_json::Value {
    let stubs = script.with_file_name("visit_series_stubs.py");
    std::fs::write(&stubs, VISIT_SERIES_STUBS).unwrap();
    let out = Command::new("python3")
        .arg(&stubs)
        .arg(script)
        .args(args)
        .output()
        .expect("run python3 (build.rs found it, or T2TF_REQUIRE_PYTHON requires it)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
#[cfg_attr(not(t2tf_python), ignore = "needs python3")]
fn visit_opens_a_series_as_a_visit_list_of_its_steps() {
    let d = tempfile::tempdir().unwrap();
    let (data, out) = (d.path().join("data"), d.path().join("out"));
    std::fs::create_dir_all(&data).unwrap();
    std::fs::create_dir_all(&out).unwrap();
    // uint8 raw steps (a BOV header each, its TIME the step's time), uint16 raw steps (a .vti
    // copy each: BOV would wrap them) and .vti steps (listed as they are).
    for (t, ext) in [
        (Some(ScalarType::U8), "raw"),
        (Some(ScalarType::U16), "raw"),
        (None, "vti"),
    ] {
        let format = match t {
            Some(t) => raw(t),
            None => SourceFormat::Vti { array: "v".into() },
        };
        let v = series_volume(format, &data, Some("gs.series"), &[0, 2, 3], 4);
        let steps = v.series.as_ref().unwrap().steps.clone();
        for (k, s) in steps.iter().enumerate() {
            let bytes = t.map_or(1, |t| t.size()) * 8 * 6 * 5;
            std::fs::write(&s.path, vec![k as u8 + 1; bytes]).unwrap();
        }
        let tf = ExportTf::from_control_points("gs", &cp(), &v, None);
        let view = ParaViewCamera::front(&v.geometry, 2.0);
        let script = out.join(format!("{ext}{}_visit.py", t.map_or(0, |t| t.size())));
        let name = script.file_name().unwrap().to_str().unwrap().to_string();
        std::fs::write(
            &script,
            visit_script(&tf, &v, &view, [0.0; 3], &name).unwrap(),
        )
        .unwrap();
        let shot = out.join("shot.png");
        let log = visit_series_run(&script, &["--screenshot", shot.to_str().unwrap()]);
        // The .visit file beside the script: "!NBLOCKS 1", then one database per step.
        let listing = script.with_extension("visit");
        assert_eq!(
            log["opened"],
            serde_json::json!([listing.to_str().unwrap()])
        );
        let text = std::fs::read_to_string(&listing).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], "!NBLOCKS 1");
        assert_eq!(lines.len(), 1 + steps.len(), "{text}");
        // The scripts name files by their canonical paths (a temporary folder may be reached
        // through a link): compare files, not spellings.
        let same = |a: &Path, b: &Path| {
            assert_eq!(
                std::fs::canonicalize(a).unwrap(),
                std::fs::canonicalize(b).unwrap()
            )
        };
        for (k, (line, step)) in lines[1..].iter().zip(&steps).enumerate() {
            let db = Path::new(line);
            assert!(db.is_absolute(), "{line}");
            match t {
                Some(ScalarType::U8) => {
                    same(db.parent().unwrap(), &out);
                    let header = std::fs::read_to_string(db).unwrap();
                    let time = format!("TIME: {:?}\n", step.time);
                    assert!(header.starts_with(&time), "{header}");
                    let file = header.lines().nth(1).unwrap();
                    same(
                        Path::new(file.strip_prefix("DATA_FILE: ").unwrap()),
                        &step.path,
                    );
                    assert_eq!(values_visit_reads(db), vec![k as f64 + 1.0; 240]);
                }
                Some(_) => {
                    same(db.parent().unwrap(), &out);
                    assert!(line.ends_with(".t2tf.vti"), "{line}");
                    let want = (k as f64 + 1.0) * 257.0;
                    assert_eq!(values_visit_reads(db), vec![want; 240]);
                }
                None => same(db, &step.path),
            }
        }
        // One picture per step, numbered; the slider set to each step in turn.
        assert_eq!(log["states"], serde_json::json!([0, 0, 1, 2]));
        let names: Vec<String> = (0..3)
            .map(|i| {
                out.join(format!("shot_{i:04}.png"))
                    .to_str()
                    .unwrap()
                    .to_string()
            })
            .collect();
        assert_eq!(log["saved"], serde_json::json!(names));
        // --time picks the nearest step and saves the name given.
        let log = visit_series_run(
            &script,
            &["--screenshot", shot.to_str().unwrap(), "--time", "750"],
        );
        assert_eq!(log["states"], serde_json::json!([2, 2]));
        assert_eq!(log["saved"], serde_json::json!([shot.to_str().unwrap()]));
        let log = visit_series_run(&script, &["--step", "1"]);
        assert_eq!(log["states"], serde_json::json!([1]));
        assert_eq!(log["saved"], serde_json::json!([]));
        assert_eq!(
            std::fs::read_dir(&data).unwrap().count(),
            3,
            "nothing written beside the data"
        );
        for e in std::fs::read_dir(&data).unwrap() {
            std::fs::remove_file(e.unwrap().path()).unwrap();
        }
    }
}
