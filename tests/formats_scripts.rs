//! write_all and the generated pvpython / VisIt scripts (content, Python syntax, atomicity).
//! Running the pvpython script in ParaView is tests/paraview.rs.

use std::path::{Path, PathBuf};
use std::process::Command;

use t2tf::formats::{
    freeform_opacity, paraview_script, visit_script, write_all, ExportTf, ScriptView,
};
use t2tf::tf::ControlPoints;
use t2tf::volume::{
    ByteOrder, Geometry, ScalarType, SourceFormat, TypedBuffer, Volume, VolumeSource,
};

fn volume(format: SourceFormat) -> Volume {
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

/// `python3 -m py_compile` the script (syntax only; python3 may be absent, then skip).
fn compiles(path: &Path) {
    match Command::new("python3")
        .arg("-m")
        .arg("py_compile")
        .arg(path)
        .output()
    {
        Ok(o) => assert!(
            o.status.success(),
            "{} is not valid Python: {}",
            path.display(),
            String::from_utf8_lossy(&o.stderr)
        ),
        Err(_) => eprintln!(
            "python3 not found: syntax check of {} skipped",
            path.display()
        ),
    }
}

#[test]
fn write_all_writes_every_output_atomically() {
    let v = volume(raw(ScalarType::U16));
    let d = tempfile::tempdir().unwrap();
    let view = ScriptView::front(&v, 3.0);
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
    compiles(files.paraview_script.as_ref().unwrap());

    let vi = std::fs::read_to_string(files.visit_script.as_ref().unwrap()).unwrap();
    for needle in [
        "AddPlot(\"Volume\", VARIABLE)",
        "atts.opacityMode = atts.FreeformMode",
        "atts.useColorVarMin = 1",
        "COLOR_MIN = 0.0",
        "COLOR_MAX = 160.0",
        "DATA_FORMAT: SHORT",
        "DATA_ENDIAN: BIG",
        "BRICK_ORIGIN: -1.0 2.0 3.5",
        "VIEW_ANGLE = 45.0",
    ] {
        assert!(vi.contains(needle), "VisIt script lacks {needle}");
    }
    compiles(files.visit_script.as_ref().unwrap());
    let freeform = vi.split("FREEFORM_OPACITY = (").nth(1).unwrap();
    let freeform = freeform.split(",)").next().unwrap();
    assert_eq!(freeform.split(", ").count(), 256);
    assert_eq!(files.tf.opacity_points.first().unwrap().0, 0.0);
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
    let view = ScriptView::front(&volume(raw(ScalarType::U8)), 2.0);
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
