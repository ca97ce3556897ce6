//! `NAME_visit.py`: a VisIt CLI script for a Volume plot with the TF (docs/DESIGN.md: opacity
//! via `freeformOpacity`, 256 values, since a colour table's alpha is used only in colour-table
//! opacity mode; colour range via `useColorVarMin/Max`). VisIt is not packaged for Debian, so
//! this is written from VisIt's documented CLI API and file formats and checked in tests as
//! text and by running its data-preparation part with stand-ins for VisIt's functions.
//!
//! Raw volumes reach VisIt unchanged in value: VisIt's BOV reader documents the `DATA_FORMAT`
//! values BYTE, SHORT, INT, FLOAT and DOUBLE (VisIt user manual, "The BOV file format"), i.e.
//! signed 16- and 32-bit integers only, so uint16, uint32 and int8 data would wrap through a
//! BOV header. For those the script writes a VTK XML `.vti` (which VisIt opens natively with
//! its VTK reader) holding the raw file's bytes as they are, typed exactly (`UInt16`, ...).
//! The `.bov` header or `.vti` copy is written beside the script (the run's output folder, or
//! the temporary folder if that is not writable), never beside the volume, whose folder may be
//! read-only.

use std::fmt::Write as _;

use super::paraview_script::{one_line, py_list, py_str, source_path};
use super::{ExportTf, FormatError};
use t2tf_render::camera::ParaViewCamera;
use t2tf_tf::interpolate;
use t2tf_volume::{ByteOrder, ScalarType, SourceFormat, Volume};

/// Number of freeform opacity entries VisIt's Volume plot takes.
pub(crate) const FREEFORM_SAMPLES: usize = 256;

/// The 256 freeform opacities (0..255) over the TF's data range, evenly spaced.
pub fn freeform_opacity(tf: &ExportTf) -> Vec<u8> {
    let [lo, hi] = tf.data_range();
    let o: Vec<(f64, [f64; 1])> = tf.opacity_points.iter().map(|&(x, o)| (x, [o])).collect();
    (0..FREEFORM_SAMPLES)
        .map(|i| {
            if o.is_empty() {
                return 255;
            }
            let x = lo + (hi - lo) * i as f64 / (FREEFORM_SAMPLES - 1) as f64;
            (interpolate(&o, x)[0].clamp(0.0, 1.0) * 255.0).round() as u8
        })
        .collect()
}

/// How VisIt reads a raw file of this type exactly: a BOV header of a `DATA_FORMAT` with the
/// same values (BYTE is unsigned 8-bit, SHORT and INT are signed), else a `.vti` copy typed
/// as the file is. 64-bit integers: neither is known to keep them (VisIt converts them), so
/// no script.
enum VisitRaw {
    Bov(&'static str),
    Vti,
}

fn visit_raw(t: ScalarType) -> Option<VisitRaw> {
    match t {
        ScalarType::U8 => Some(VisitRaw::Bov("BYTE")),
        ScalarType::I16 => Some(VisitRaw::Bov("SHORT")),
        ScalarType::I32 => Some(VisitRaw::Bov("INT")),
        ScalarType::F32 => Some(VisitRaw::Bov("FLOAT")),
        ScalarType::F64 => Some(VisitRaw::Bov("DOUBLE")),
        ScalarType::U16 | ScalarType::U32 | ScalarType::I8 => Some(VisitRaw::Vti),
        _ => None,
    }
}

/// A BOV header for the raw file (`file` stands for its absolute path, `time` for its time: Python
/// `%` fields): DATA_SIZE in points, BRICK_SIZE the box's world size, NODAL (values sit on the
/// points), as VisIt's BOV documentation describes the keywords.
fn bov_header(
    g: &t2tf_volume::Geometry,
    fmt: &str,
    order: ByteOrder,
    time: &str,
    file: &str,
) -> String {
    let endian = match order {
        ByteOrder::Little => "LITTLE",
        ByteOrder::Big => "BIG",
    };
    let ext = g.extent();
    format!(
        "TIME: {time}\nDATA_FILE: {file}\nDATA_SIZE: {} {} {}\nDATA_FORMAT: {fmt}\n\
         VARIABLE: scalars\nDATA_ENDIAN: {endian}\nCENTERING: NODAL\n\
         BRICK_ORIGIN: {:?} {:?} {:?}\nBRICK_SIZE: {:?} {:?} {:?}\n",
        g.dims[0],
        g.dims[1],
        g.dims[2],
        g.origin[0],
        g.origin[1],
        g.origin[2],
        ext[0],
        ext[1],
        ext[2]
    )
}

/// The `.vti` text up to the `_` that starts its raw appended data: one point array
/// `scalars` of VTK type `vtk_type` at offset 0, a UInt64 byte count (in the file's byte
/// order) following the `_`, as VTK XML's raw appended encoding lays it out.
fn vti_head(g: &t2tf_volume::Geometry, vtk_type: &str, order: ByteOrder) -> String {
    let ext = format!(
        "0 {} 0 {} 0 {}",
        g.dims[0] - 1,
        g.dims[1] - 1,
        g.dims[2] - 1
    );
    let order = match order {
        ByteOrder::Little => "LittleEndian",
        ByteOrder::Big => "BigEndian",
    };
    format!(
        "<?xml version=\"1.0\"?>\n\
         <VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"{order}\" header_type=\"UInt64\">\n\
         \x20 <ImageData WholeExtent=\"{ext}\" Origin=\"{:?} {:?} {:?}\" Spacing=\"{:?} {:?} {:?}\">\n\
         \x20   <Piece Extent=\"{ext}\">\n\
         \x20     <PointData Scalars=\"scalars\">\n\
         \x20       <DataArray type=\"{vtk_type}\" Name=\"scalars\" format=\"appended\" offset=\"0\"/>\n\
         \x20     </PointData>\n\
         \x20   </Piece>\n\
         \x20 </ImageData>\n\
         \x20 <AppendedData encoding=\"raw\">\n\
         \x20  _",
        g.origin[0], g.origin[1], g.origin[2], g.spacing[0], g.spacing[1], g.spacing[2]
    )
}

/// The script's text. `script_name` is the file name it is written under (its usage header
/// quotes it); `background` is RGB in [0, 1].
// The same arguments as `paraview_script` (one script writer per tool, called side by side
// by `write_all`); the bodies write different languages.
pub fn visit_script(
    tf: &ExportTf,
    volume: &Volume,
    view: &ParaViewCamera,
    background: [f64; 3],
    script_name: &str,
) -> Result<String, FormatError> {
    let (path, format) = source_path(volume)?;
    if let Some(series) = &volume.series {
        return super::series_script::visit(tf, volume, series, view, background, script_name);
    }
    let constants = visit_constants(tf, volume, view, background, format, "0", "%s")?;
    let mut s = String::new();
    let w = &mut s;
    let _ = writeln!(
        w,
        r#"# Generated by t2tf: a VisIt Volume plot with the transfer function "{name}".
#
#   visit -cli -nowin -s {script} [--screenshot OUT.png] [--size W H]
#
{about}import os
import shutil
import struct
import sys
import tempfile

VOLUME = {path}
SCRIPT_NAME = {script_py}
{constants}

{VISIT_ARG}

{VISIT_WRITE_VTI}

{VISIT_HERE}

def database():
    stem = os.path.splitext(os.path.basename(VOLUME))[0]
    if VTI_HEAD is not None:
        name = stem + ".t2tf.vti"
        for folder in (here(), tempfile.gettempdir()):
            vti = os.path.join(folder, name)
            if os.path.exists(vti) and os.path.getmtime(vti) >= os.path.getmtime(VOLUME):
                return vti
            try:
                write_vti(VOLUME, vti)
                return vti
            except OSError:
                continue
        sys.exit("could not write a .vti copy of " + VOLUME)
    if BOV_HEADER is None:
        return VOLUME
    # The header names the volume by its absolute path, so it may live in another folder.
    for folder in (here(), tempfile.gettempdir()):
        bov = os.path.join(folder, stem + ".bov")
        try:
            with open(bov, "w") as f:
                f.write(BOV_HEADER % VOLUME)
            return bov
        except OSError:
            continue
    sys.exit("could not write a .bov header for " + VOLUME)


OpenDatabase(database())
{VISIT_PLOT}shot = arg("--screenshot", 1)
if shot:
    size = arg("--size", 2) or ["512", "512"]
    s = SaveWindowAttributes()
    s.fileName = shot[0]
    s.family = 0
    s.format = s.PNG
    s.width, s.height = int(size[0]), int(size[1])
    s.resConstraint = s.NoConstraint
    SetSaveWindowAttributes(s)
    SaveWindow()
    sys.exit(0)"#,
        name = one_line(&tf.name),
        script = one_line(script_name),
        about = visit_about(tf, volume),
        script_py = py_str(script_name),
        path = py_str(&path),
    );
    Ok(s)
}

/// The header's lines on colour and opacity.
pub(crate) fn visit_about(tf: &ExportTf, volume: &Volume) -> String {
    format!(
        "# Colours: the TF's colour points over [COLOR_MIN, COLOR_MAX] (useColorVarMin/Max).
# Opacity: 256 freeform values (0..255) over the same range; they are per-sample opacities
# for a unit distance of {u:?} world units. VisIt has no unit-distance setting, so its look
# depends on its sample count; ParaView's script reproduces t2tf exactly.
",
        u = tf
            .unit_distance
            .unwrap_or_else(|| t2tf_tf::default_unit_distance(&volume.geometry)),
    )
}

/// `write_vti(volume, path)`: an exact `.vti` copy of a raw file for VisIt.
pub(crate) const VISIT_WRITE_VTI: &str = r#"def write_vti(volume, path):
    # The raw bytes as they are after VTI_HEAD, with their UInt64 byte count (VTK XML's raw
    # appended encoding), so VisIt's VTK reader gets every value exactly.
    size = os.path.getsize(volume)
    if size != VTI_BYTES:
        sys.exit("%s: %d bytes, expected %d" % (volume, size, VTI_BYTES))
    part = path + ".part"
    with open(volume, "rb") as src, open(part, "wb") as dst:
        dst.write(VTI_HEAD.encode("utf-8"))
        dst.write(struct.pack(VTI_ORDER + "Q", size))
        shutil.copyfileobj(src, dst, 1 << 24)
        dst.write(b"\n  </AppendedData>\n</VTKFile>\n")
    os.replace(part, path)
"#;

/// `arg(name, count)`: the `count` command-line values after `name`, or None.
pub(crate) const VISIT_ARG: &str = r#"def arg(name, count):
    if name in sys.argv:
        i = sys.argv.index(name)
        return sys.argv[i + 1:i + 1 + count]
    return None
"#;

/// `here()`: the folder side files go to.
pub(crate) const VISIT_HERE: &str = r#"def here():
    # The folder of this script (the run's output folder): side files go there, not beside
    # the volume, whose folder may be read-only. VisIt's -s may not set __file__; the script's
    # path is then among the arguments.
    path = globals().get("__file__")
    if not path:
        path = next((a for a in sys.argv if os.path.basename(a) == SCRIPT_NAME), None)
    return os.path.dirname(os.path.abspath(path)) if path else os.getcwd()
"#;

/// The Volume plot with the TF, the background and the view, on the open database.
pub(crate) const VISIT_PLOT: &str = r#"AddPlot("Volume", VARIABLE)
atts = VolumeAttributes()
atts.opacityMode = atts.FreeformMode
atts.freeformOpacity = FREEFORM_OPACITY
atts.opacityAttenuation = 1
atts.useColorVarMin = 1
atts.colorVarMin = COLOR_MIN
atts.useColorVarMax = 1
atts.colorVarMax = COLOR_MAX
atts.useOpacityVarMin = 1
atts.opacityVarMin = COLOR_MIN
atts.useOpacityVarMax = 1
atts.opacityVarMax = COLOR_MAX
atts.lightingFlag = 0
points = ColorControlPointList()
for position, rgba in COLOR_POINTS:
    p = ColorControlPoint()
    p.colors = rgba
    p.position = position
    points.AddControlPoints(p)
atts.colorControlPoints = points
SetPlotOptions(atts)
annotation = AnnotationAttributes()
annotation.backgroundMode = annotation.Solid
annotation.backgroundColor = tuple(int(round(255 * c)) for c in BACKGROUND) + (255,)
SetAnnotationAttributes(annotation)
DrawPlots()
view = GetView3D()
view.viewNormal = VIEW_NORMAL
view.focus = VIEW_FOCUS
view.viewUp = VIEW_UP
view.viewAngle = VIEW_ANGLE
view.parallelScale = PARALLEL_SCALE
view.nearPlane, view.farPlane = NEAR_FAR
view.perspective = 1
SetView3D(view)
"#;

/// The constants from `VARIABLE` to `VTI_ORDER`, one per line: the TF, the view, and how a raw
/// file reaches VisIt (`BOV_HEADER` with the Python `%` fields `time` and `file`, or
/// `VTI_HEAD`); an error for a raw type VisIt would not read exactly.
pub(crate) fn visit_constants(
    tf: &ExportTf,
    volume: &Volume,
    view: &ParaViewCamera,
    background: [f64; 3],
    format: &SourceFormat,
    time: &str,
    file: &str,
) -> Result<String, FormatError> {
    let g = &volume.geometry;
    let [lo, hi] = tf.data_range();
    let span = if hi > lo { hi - lo } else { 1.0 };
    let colours: Vec<String> = tf
        .rgb_points
        .iter()
        .map(|&(x, c)| {
            let [r, g, b] = c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8);
            format!("({:?}, ({r}, {g}, {b}, 255))", (x - lo) / span)
        })
        .collect();
    let freeform: Vec<String> = freeform_opacity(tf).iter().map(|v| v.to_string()).collect();
    let d: [f64; 3] = std::array::from_fn(|a| view.position[a] - view.focal_point[a]);
    let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-12);
    let normal = d.map(|v| v / dist);
    let parallel_scale = dist * (0.5 * view.view_angle).to_radians().tan();
    let radius = g.bounding_radius();
    // A raw file reaches VisIt through a BOV header (no copy) or a `.vti` copy (exact types).
    let (mut bov, mut vti, mut vti_bytes, mut vti_order) = (None, None, 0usize, "<");
    let var = match format {
        SourceFormat::Raw {
            scalar_type,
            byte_order,
        } => {
            match visit_raw(*scalar_type) {
                Some(VisitRaw::Bov(fmt)) => bov = Some(bov_header(g, fmt, *byte_order, time, file)),
                Some(VisitRaw::Vti) => {
                    vti = Some(vti_head(g, scalar_type.vtk_xml_name(), *byte_order));
                    vti_bytes = g.voxel_count() * scalar_type.size();
                    if matches!(byte_order, ByteOrder::Big) {
                        vti_order = ">";
                    }
                }
                None => {
                    return Err(FormatError::Message(format!(
                        "VisIt's BOV and VTK readers have no exact {scalar_type} type; no VisIt \
                         script written"
                    )))
                }
            }
            "scalars".to_string()
        }
        SourceFormat::Vti { array } | SourceFormat::LegacyVtk { array } => array.clone(),
    };
    Ok(format!(
        r#"VARIABLE = {var}
COLOR_MIN = {lo:?}
COLOR_MAX = {hi:?}
COLOR_POINTS = [{colours}]
FREEFORM_OPACITY = ({freeform},)
VIEW_NORMAL = {normal}
VIEW_FOCUS = {focus}
VIEW_UP = {up}
VIEW_ANGLE = {angle:?}
PARALLEL_SCALE = {ps:?}
NEAR_FAR = ({near:?}, {far:?})
BACKGROUND = {bg}
BOV_HEADER = {bov}
VTI_HEAD = {vti}
VTI_BYTES = {vti_bytes}
VTI_ORDER = {vti_order}
"#,
        var = py_str(&var),
        colours = colours.join(", "),
        freeform = freeform.join(", "),
        normal = py_list(normal),
        focus = py_list(view.focal_point),
        up = py_list(view.view_up),
        angle = view.view_angle,
        ps = parallel_scale,
        // VisIt's clip planes are distances from the focus along the view normal.
        near = -2.0 * radius,
        far = 2.0 * radius,
        bg = py_list(background),
        bov = bov.as_deref().map_or("None".to_string(), py_str),
        vti = vti.as_deref().map_or("None".to_string(), py_str),
        vti_order = py_str(vti_order),
    ))
}
